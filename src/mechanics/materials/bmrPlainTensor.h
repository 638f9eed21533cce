// 3 x 3 matrices as plain arrays for the constitutive laws inside the force
// kernels' loops, which evaluate one cell or integration point per SIMD lane
// (Eigen's objects do not vectorise across loop iterations), and the
// conversions to Eigen for the laws' uses outside the kernels. Private to the core.
#ifndef bmrPlainTensor_h
#define bmrPlainTensor_h

#include <Eigen/Core>

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

// Passed and returned by value: a local whose address is taken inside
// `omp simd` becomes a per-lane array in memory, which made the element
// kernels twice as slow.
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

} // namespace bmr

#endif
