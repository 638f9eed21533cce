// The compressible Mooney-Rivlin law (private to the core):
//   W = C10 (I1bar - 3) + C01 (I2bar - 3) + kappa/2 (J - 1)^2 + barrier,
//   I1bar = J^-2/3 I1, I2bar = J^-4/3 I2, I2 = (I1^2 - C:C) / 2,
// with mu = 2 (C10 + C01) the small-strain shear modulus and
// secondModulus = 2 C01 (Material::SecondInvariantModulus). It is the
// neo-Hookean law (bmrNeoHookean.h) with mu - secondModulus plus the second
// invariant's stress
//   dW2/dF = secondModulus J^-4/3 (I1 F - F C - 2/3 I2 F^-T),  F C = (F F^T) F.
// CalculiX's *HYPERELASTIC, MOONEY-RIVLIN is the same law with D1 = 2 / kappa.
#ifndef bmrMooneyRivlin_h
#define bmrMooneyRivlin_h

#include "bmrNeoHookean.h"

namespace bmr
{

// scale * P of the Mooney-Rivlin solid; arguments as ScaledFirstPiola's.
// kSecondInvariant false: the neo-Hookean law, secondModulus unused (the
// kernels' instance for models without a Mooney-Rivlin material).
template <bool kSecondInvariant>
inline Matrix3x3
ScaledMooneyRivlinFirstPiola(const Matrix3x3 F,
                             const Matrix3x3 cof,
                             double          J,
                             double          pressure,
                             double          mu,
                             double          secondModulus,
                             double          collapseModulus,
                             double          scale)
{
  if constexpr (!kSecondInvariant)
  {
    return ScaledFirstPiola(F, cof, J, pressure, mu, collapseModulus, scale);
  }
  Matrix3x3 A = ScaledFirstPiola(F, cof, J, pressure, mu - secondModulus, collapseModulus, scale);
  double    left[3][3]; // B = F F^T, whose invariants are C's
  double    I1 = 0.0, squares = 0.0;
  for (int i = 0; i < 3; ++i)
  {
    for (int j = 0; j < 3; ++j)
    {
      left[i][j] = F.m[i][0] * F.m[j][0] + F.m[i][1] * F.m[j][1] + F.m[i][2] * F.m[j][2];
      squares += left[i][j] * left[i][j];
    }
    I1 += left[i][i];
  }
  const double I2 = 0.5 * (I1 * I1 - squares);
  const double inverseCubeRootSquared = InverseCubeRootSquared(J);
  const double factor = scale * secondModulus * inverseCubeRootSquared * inverseCubeRootSquared;
  const double cofactorFactor = 2.0 * I2 / (3.0 * J);
  for (int i = 0; i < 3; ++i)
  {
    for (int j = 0; j < 3; ++j)
    {
      const double FC = left[i][0] * F.m[0][j] + left[i][1] * F.m[1][j] + left[i][2] * F.m[2][j];
      A.m[i][j] += factor * (I1 * F.m[i][j] - FC - cofactorFactor * cof.m[i][j]);
    }
  }
  return A;
}

inline double
MooneyRivlinStrainEnergyDensity(const Eigen::Matrix3d & F,
                                double                  J,
                                double                  volumeRatio,
                                double                  mu,
                                double                  secondModulus,
                                double                  kappa,
                                double                  collapseModulus)
{
  const Eigen::Matrix3d C = F.transpose() * F;
  const double          I2 = 0.5 * (C.trace() * C.trace() - C.squaredNorm());
  const double          inverseCubeRootSquared = InverseCubeRootSquared(J);
  return StrainEnergyDensity(F, J, volumeRatio, mu - secondModulus, kappa, collapseModulus) +
         0.5 * secondModulus * (I2 * inverseCubeRootSquared * inverseCubeRootSquared - 3.0);
}

} // namespace bmr

#endif
