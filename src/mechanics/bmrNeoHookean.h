// Compressible neo-Hookean law shared by the finite-element and meshless force
// models (private to the core): W = mu/2 (J^-2/3 I1 - 3) + kappa/2 (J - 1)^2.
#ifndef bmrNeoHookean_h
#define bmrNeoHookean_h

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <cstring>

namespace bmr
{

// Cofactor matrix cof(F) = J F^-T, columns from cross products of F's columns.
inline Eigen::Matrix3d
Cofactor(const Eigen::Matrix3d & F)
{
  Eigen::Matrix3d cof;
  cof.col(0) = F.col(1).cross(F.col(2));
  cof.col(1) = F.col(2).cross(F.col(0));
  cof.col(2) = F.col(0).cross(F.col(1));
  return cof;
}

// J^(-2/3) without libm's cbrt (a tenth of the kernel's time, and it does not
// vectorise): the single-precision exponent estimate of the cube root refined
// by three Halley steps (cubic convergence): 3.3e-15 relative over 1e-30..1e30.
inline double
InverseCubeRootSquared(double J)
{
  const float  single = static_cast<float>(J);
  std::int32_t bits;
  std::memcpy(&bits, &single, sizeof bits);
  bits = bits / 3 + 709921077;
  float estimate;
  std::memcpy(&estimate, &bits, sizeof estimate);
  double x = estimate;
  for (int k = 0; k < 3; ++k)
  {
    const double x3 = x * x * x;
    x *= (x3 + 2.0 * J) / (2.0 * x3 + J);
  }
  return 1.0 / (x * x);
}

// First Piola-Kirchhoff stress of the compressible neo-Hookean solid,
// W = mu/2 (J^-2/3 I1 - 3) + kappa/2 (J - 1)^2. The volumetric part takes the
// dilatation `volumeRatio` (the element's own J, or the averaged nodal J of the
// ANP tetrahedron); the isochoric part always uses the element's F.
inline Eigen::Matrix3d
FirstPiola(const Eigen::Matrix3d & F, const Eigen::Matrix3d & cof, double J, double volumeRatio, double mu, double kappa)
{
  const double isochoricFactor = mu * InverseCubeRootSquared(J);
  const double I1 = F.squaredNorm();
  return isochoricFactor * F + (kappa * (volumeRatio - 1.0) - isochoricFactor * I1 / (3.0 * J)) * cof;
}

inline double
StrainEnergyDensity(const Eigen::Matrix3d & F, double J, double volumeRatio, double mu, double kappa)
{
  return 0.5 * mu * (F.squaredNorm() * InverseCubeRootSquared(J) - 3.0) +
         0.5 * kappa * (volumeRatio - 1.0) * (volumeRatio - 1.0);
}

} // namespace bmr

#endif
