// Compressible neo-Hookean law shared by the finite-element and meshless force
// models (private to the core): W = mu/2 (J^-2/3 I1 - 3) + kappa/2 (J - 1)^2,
// plus a collapse barrier below half the reference volume (CollapsePressure).
#ifndef bmrNeoHookean_h
#define bmrNeoHookean_h

#include <Eigen/Core>

#include <algorithm>
#include <cmath>

#include <cstdint>
#include <cstring>

namespace bmr
{

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

// Volume ratio below which a cell or integration point resists further collapse.
constexpr double kCollapseVolumeRatio = 0.5;

// Pressure of the collapse barrier at the unit's own volume ratio J: 0 for
// J >= Jc = kCollapseVolumeRatio, -Kc (Jc / J - 1)^2 below (C1 at Jc, unbounded
// as J -> 0). Why: the volumetric term kappa (J - 1) resists collapse with at
// most kappa (4 Pa for CSF of 10 Pa, nu 0.1; 170 Pa for fluid-like CSF), and an
// ANP tetrahedron's own J is not constrained at all, only its nodes' averages;
// so a soft cell squeezed by the tissue around it is crushed until it inverts
// (20-25 mm shifts of Colin27). Physically the fluid has drained and the walls
// of the space meet: below half its volume the cell takes the bulk modulus Kc
// of the tissue around it (SolverSettings::collapseBulkModulus).
inline double
CollapsePressure(double J, double collapseModulus)
{
  const double closing = std::max(0.0, kCollapseVolumeRatio / J - 1.0);
  return -collapseModulus * closing * closing;
}

// The barrier's energy per reference volume: the integral of -CollapsePressure from J to Jc.
inline double
CollapseEnergy(double J, double collapseModulus)
{
  constexpr double Jc = kCollapseVolumeRatio;
  return J >= Jc ? 0.0 : collapseModulus * (Jc * Jc / J - J + 2.0 * Jc * std::log(J / Jc));
}

// The law on plain arrays, for the force kernels' loops that evaluate one
// cell or integration point per SIMD lane (Eigen's objects do not vectorise
// across loop iterations). Passed and returned by value: a local whose address
// is taken inside `omp simd` becomes a per-lane array in memory, which made the
// element kernels twice as slow.
struct Matrix3x3
{
  double m[3][3];
};

// The cofactor matrix cof(F) = J F^-T.
inline Matrix3x3
CofactorOf(const Matrix3x3 F)
{
  Matrix3x3 cof;
  for (int i = 0; i < 3; ++i)
  {
    for (int j = 0; j < 3; ++j)
    {
      const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      cof.m[i][j] = F.m[i1][j1] * F.m[i2][j2] - F.m[i1][j2] * F.m[i2][j1];
    }
  }
  return cof;
}

inline double
DeterminantOf(const Matrix3x3 F, const Matrix3x3 cof)
{
  return F.m[0][0] * cof.m[0][0] + F.m[0][1] * cof.m[0][1] + F.m[0][2] * cof.m[0][2];
}

// scale * P, with the volumetric pressure given (kappa (Jv - 1), or the ANP
// tetrahedron's averaged nodal pressure); the barrier on the unit's own J.
inline Matrix3x3
ScaledFirstPiola(const Matrix3x3 F,
                 const Matrix3x3 cof,
                 double          J,
                 double          pressure,
                 double          mu,
                 double          collapseModulus,
                 double          scale)
{
  const double isochoric = mu * InverseCubeRootSquared(J);
  double       I1 = 0.0;
  for (int i = 0; i < 3; ++i)
  {
    for (int j = 0; j < 3; ++j)
    {
      I1 += F.m[i][j] * F.m[i][j];
    }
  }
  const double cofactorFactor = pressure + CollapsePressure(J, collapseModulus) - isochoric * I1 / (3.0 * J);
  Matrix3x3    A;
  for (int i = 0; i < 3; ++i)
  {
    for (int j = 0; j < 3; ++j)
    {
      A.m[i][j] = scale * (isochoric * F.m[i][j] + cofactorFactor * cof.m[i][j]);
    }
  }
  return A;
}

// Between Eigen's matrices and the plain arrays.
inline Matrix3x3
ToPlain(const Eigen::Matrix3d & matrix)
{
  Matrix3x3 plain;
  Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(&plain.m[0][0]) = matrix;
  return plain;
}

inline Eigen::Matrix3d
ToEigen(const Matrix3x3 & plain)
{
  return Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(&plain.m[0][0]);
}

// The cofactor matrix cof(F) = J F^-T for Eigen's types (CofactorOf).
inline Eigen::Matrix3d
Cofactor(const Eigen::Matrix3d & F)
{
  return ToEigen(CofactorOf(ToPlain(F)));
}

// First Piola-Kirchhoff stress of the compressible neo-Hookean solid,
// W = mu/2 (J^-2/3 I1 - 3) + kappa/2 (J - 1)^2, with the collapse barrier. The
// volumetric part takes the dilatation `volumeRatio` (the element's own J, or
// the averaged nodal J of the ANP tetrahedron); the isochoric part and the
// barrier always use the element's own F and J. The kernels' law, for Eigen's types.
inline Eigen::Matrix3d
FirstPiola(const Eigen::Matrix3d & F,
           const Eigen::Matrix3d & cof,
           double                  J,
           double                  volumeRatio,
           double                  mu,
           double                  kappa,
           double                  collapseModulus)
{
  return ToEigen(ScaledFirstPiola(ToPlain(F), ToPlain(cof), J, kappa * (volumeRatio - 1.0), mu, collapseModulus, 1.0));
}

inline double
StrainEnergyDensity(const Eigen::Matrix3d & F, double J, double volumeRatio, double mu, double kappa,
                    double collapseModulus)
{
  return 0.5 * mu * (F.squaredNorm() * InverseCubeRootSquared(J) - 3.0) +
         0.5 * kappa * (volumeRatio - 1.0) * (volumeRatio - 1.0) + CollapseEnergy(J, collapseModulus);
}

} // namespace bmr

#endif
