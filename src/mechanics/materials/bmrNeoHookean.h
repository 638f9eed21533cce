// The compressible neo-Hookean law of the finite-element and meshless force
// models (private to the core): W = mu/2 (J^-2/3 I1 - 3) + kappa/2 (J - 1)^2,
// plus the collapse barrier below half the reference volume (bmrCollapseBarrier.h).
#ifndef bmrNeoHookean_h
#define bmrNeoHookean_h

#include "bmrCollapseBarrier.h"
#include "bmrPlainTensor.h"

#include <Eigen/Core>

namespace bmr
{

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
