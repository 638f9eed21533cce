// Shape functions of the linear tetrahedron and trilinear hexahedron in the
// reference configuration (private to the core).
#ifndef bmrShape_h
#define bmrShape_h

#include <Eigen/Dense>

#include <algorithm>
#include <limits>

namespace bmr
{

using HexahedronCoordinates = Eigen::Matrix<double, 8, 3>;
using HexahedronGradients = Eigen::Matrix<double, 8, 3>;
using TetrahedronCoordinates = Eigen::Matrix<double, 4, 3>;
using TetrahedronGradients = Eigen::Matrix<double, 4, 3>;

/** Corner offsets of the unit cube in VTK_HEXAHEDRON order. */
constexpr int HexahedronCornerOffsets[8][3] = { { 0, 0, 0 }, { 1, 0, 0 }, { 1, 1, 0 }, { 0, 1, 0 },
                                                { 0, 0, 1 }, { 1, 0, 1 }, { 1, 1, 1 }, { 0, 1, 1 } };

/** The six Kuhn tetrahedra of a grid cube, as corners of HexahedronCornerOffsets.
 *  Each is a monotone path from corner 0 to corner 6, positively oriented for
 *  a unit cube, so every cube face is split along the diagonal from its lowest
 *  to its highest corner and neighbouring cubes' tetrahedra conform. */
constexpr int KuhnTetrahedra[6][4] = { { 0, 1, 2, 6 }, { 0, 5, 1, 6 }, { 0, 2, 3, 6 },
                                       { 0, 3, 7, 6 }, { 0, 4, 5, 6 }, { 0, 7, 4, 6 } };

// Hourglass base vectors xi2 xi3, xi3 xi1, xi1 xi2, xi1 xi2 xi3 at the nodes.
constexpr double kHourglassBase[8][4] = { { 1, 1, 1, -1 },  { 1, -1, -1, 1 }, { -1, -1, 1, -1 }, { -1, 1, -1, 1 },
                                          { -1, -1, 1, 1 }, { -1, 1, -1, -1 }, { 1, 1, 1, 1 },  { 1, -1, -1, -1 } };

/** Natural coordinates of the hexahedron's nodes in VTK order. */
inline const Eigen::Matrix<double, 8, 3> &
HexahedronNaturalCoordinates()
{
  static const Eigen::Matrix<double, 8, 3> xi = [] {
    Eigen::Matrix<double, 8, 3> m;
    m << -1, -1, -1, 1, -1, -1, 1, 1, -1, -1, 1, -1, -1, -1, 1, 1, -1, 1, 1, 1, 1, -1, 1, 1;
    return m;
  }();
  return xi;
}

/** d N_a / d xi at natural point (r, s, t). */
inline HexahedronGradients
HexahedronNaturalGradients(double r, double s, double t)
{
  const auto &        xi = HexahedronNaturalCoordinates();
  HexahedronGradients g;
  for (int a = 0; a < 8; ++a)
  {
    const double ra = 1.0 + xi(a, 0) * r;
    const double sa = 1.0 + xi(a, 1) * s;
    const double ta = 1.0 + xi(a, 2) * t;
    g(a, 0) = 0.125 * xi(a, 0) * sa * ta;
    g(a, 1) = 0.125 * xi(a, 1) * ra * ta;
    g(a, 2) = 0.125 * xi(a, 2) * ra * sa;
  }
  return g;
}

struct HexahedronIntegralsResult
{
  double              volume = 0.0;
  HexahedronGradients b; // b_a = integral of dN_a/dX over the cell (Flanagan-Belytschko)
};

/** Volume and integrated shape-function gradients; 2x2x2 Gauss integrates both
 *  exactly for a trilinear cell (cubic at most in each natural coordinate). */
inline HexahedronIntegralsResult
HexahedronIntegrals(const HexahedronCoordinates & x)
{
  const double              g = 1.0 / std::sqrt(3.0);
  HexahedronIntegralsResult result;
  result.b.setZero();
  for (int i = 0; i < 8; ++i)
  {
    const auto &              xi = HexahedronNaturalCoordinates();
    const HexahedronGradients dNdXi = HexahedronNaturalGradients(g * xi(i, 0), g * xi(i, 1), g * xi(i, 2));
    const Eigen::Matrix3d     jacobian = x.transpose() * dNdXi; // dx/dxi
    const double              detJ = jacobian.determinant();
    result.volume += detJ;
    // dN/dX detJ = dN/dxi adj(J): avoids dividing by a possibly vanishing detJ.
    Eigen::Matrix3d adjugate;
    adjugate.row(0) = jacobian.col(1).cross(jacobian.col(2)).transpose();
    adjugate.row(1) = jacobian.col(2).cross(jacobian.col(0)).transpose();
    adjugate.row(2) = jacobian.col(0).cross(jacobian.col(1)).transpose();
    result.b += dNdXi * adjugate;
  }
  return result;
}

/** Smallest determinant of the trilinear map's Jacobian over the eight corners. */
inline double
HexahedronMinimumCornerJacobian(const HexahedronCoordinates & x)
{
  const auto & xi = HexahedronNaturalCoordinates();
  double       smallest = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 8; ++a)
  {
    const Eigen::Matrix3d jacobian = x.transpose() * HexahedronNaturalGradients(xi(a, 0), xi(a, 1), xi(a, 2));
    smallest = std::min(smallest, jacobian.determinant());
  }
  return smallest;
}

inline double
TetrahedronVolume(const Eigen::Vector3d & a, const Eigen::Vector3d & b, const Eigen::Vector3d & c, const Eigen::Vector3d & d)
{
  return (b - a).cross(c - a).dot(d - a) / 6.0;
}

/** Constant gradients dN_a/dX of the linear tetrahedron (rows) for volume > 0. */
inline TetrahedronGradients
TetrahedronShapeGradients(const TetrahedronCoordinates & x)
{
  Eigen::Matrix3d edges;
  edges.col(0) = (x.row(1) - x.row(0)).transpose();
  edges.col(1) = (x.row(2) - x.row(0)).transpose();
  edges.col(2) = (x.row(3) - x.row(0)).transpose();
  const Eigen::Matrix3d inverse = edges.inverse(); // rows: gradients of N1, N2, N3
  TetrahedronGradients  gradients;
  gradients.row(1) = inverse.row(0);
  gradients.row(2) = inverse.row(1);
  gradients.row(3) = inverse.row(2);
  gradients.row(0) = -(inverse.row(0) + inverse.row(1) + inverse.row(2));
  return gradients;
}

} // namespace bmr

#endif
