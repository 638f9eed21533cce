// Shared helpers of the mechanics tests: analytic neo-Hookean solutions,
// constraint set-up, error measures and small geometric predicates.
//
// Units follow the core's user units: mm, Pa, kg/m^3, s; forces in N.
// A first Piola stress P (Pa) on a reference area A0 (mm^2) gives a force
// P * A0 * 1e-6 N.
#ifndef bmrTestUtilities_h
#define bmrTestUtilities_h

#include "bmrMeshGenerators.h"
#include "bmrModel.h"
#include "bmrSolver.h"

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace bmr
{
namespace test
{

using Matrix3 = Eigen::Matrix3d;

constexpr double PascalSquareMillimetreToNewton = 1e-6; // Pa * mm^2 -> N

// ---------------------------------------------------------------------------
// Analytic neo-Hookean material: W = mu/2 (I1bar - 3) + kappa/2 (J - 1)^2.
// ---------------------------------------------------------------------------
struct NeoHookean
{
  double mu = 0.0;
  double kappa = 0.0;
  /** Bulk modulus of the collapse barrier below half the reference volume
   *  (docs/solver.md): pressure -Kc (0.5 / J - 1)^2 for J < 0.5. The solver
   *  gives every cell at least its own kappa. */
  double collapseModulus = 0.0;

  explicit NeoHookean(const Material & m)
    : mu(m.ShearModulus())
    , kappa(m.BulkModulus())
  {}
  NeoHookean(double shearModulus, double bulkModulus)
    : mu(shearModulus)
    , kappa(bulkModulus)
  {}

  /** Pressure of the collapse barrier (Pa). */
  double CollapsePressure(double J) const
  {
    return J < 0.5 ? -collapseModulus * (0.5 / J - 1.0) * (0.5 / J - 1.0) : 0.0;
  }

  /** Cauchy stress (Pa): sigma = mu J^(-5/3) dev(b) + (kappa (J - 1) + p_collapse(J)) I, b = F F^T. */
  Matrix3 Cauchy(const Matrix3 & F) const
  {
    const double  J = F.determinant();
    const Matrix3 b = F * F.transpose();
    const Matrix3 devB = b - b.trace() / 3.0 * Matrix3::Identity();
    return mu * std::pow(J, -5.0 / 3.0) * devB + (kappa * (J - 1.0) + CollapsePressure(J)) * Matrix3::Identity();
  }

  /** First Piola-Kirchhoff stress (Pa): P = J sigma F^-T. */
  Matrix3 FirstPiola(const Matrix3 & F) const
  {
    return F.determinant() * Cauchy(F) * F.inverse().transpose();
  }

  /** Strain energy density (Pa = J/m^3). */
  double EnergyDensity(const Matrix3 & F) const
  {
    const double J = F.determinant();
    const double I1bar = std::pow(J, -2.0 / 3.0) * (F.transpose() * F).trace();
    // The barrier's energy: the integral of -p_collapse from J to 0.5.
    const double collapse = J < 0.5 ? collapseModulus * (0.25 / J - J + std::log(2.0 * J)) : 0.0;
    return 0.5 * mu * (I1bar - 3.0) + 0.5 * kappa * (J - 1.0) * (J - 1.0) + collapse;
  }
};

/** W = C10 (I1bar - 3) + C01 (I2bar - 3) + kappa/2 (J - 1)^2 in spatial form:
 *  sigma = 2/J dev[(C10 + C01 I1bar) bbar - C01 bbar^2] + kappa (J - 1) I,
 *  bbar = J^-2/3 F F^T (Holzapfel, Nonlinear Solid Mechanics, sec. 6.5). */
struct MooneyRivlin
{
  double C10 = 0.0, C01 = 0.0, kappa = 0.0; // Pa

  explicit MooneyRivlin(const Material & material)
    : C10(0.5 * (1.0 - material.secondInvariantShare) * material.ShearModulus())
    , C01(0.5 * material.secondInvariantShare * material.ShearModulus())
    , kappa(material.BulkModulus())
  {}

  Matrix3 Cauchy(const Matrix3 & F) const
  {
    const double  J = F.determinant();
    const Matrix3 bbar = std::pow(J, -2.0 / 3.0) * F * F.transpose();
    const Matrix3 A = (C10 + C01 * bbar.trace()) * bbar - C01 * bbar * bbar;
    return 2.0 / J * (A - A.trace() / 3.0 * Matrix3::Identity()) + kappa * (J - 1.0) * Matrix3::Identity();
  }

  Matrix3 FirstPiola(const Matrix3 & F) const { return F.determinant() * Cauchy(F) * F.inverse().transpose(); }

  /** Lateral stretch of uniaxial stress along x with axial stretch lambda (bisection on sigma_yy = 0). */
  Matrix3 Uniaxial(double lambda) const
  {
    const auto lateral = [&](double s) { return Cauchy(Eigen::Vector3d(lambda, s, s).asDiagonal())(1, 1); };
    double low = 0.5, high = 2.0;
    if (!(lateral(low) * lateral(high) < 0.0))
    {
      throw std::runtime_error("MooneyRivlin::Uniaxial: no root in [0.5, 2]");
    }
    for (int k = 0; k < 200 && high - low > 1e-15; ++k)
    {
      const double middle = 0.5 * (low + high);
      (lateral(middle) * lateral(low) > 0.0 ? low : high) = middle;
    }
    return Eigen::Vector3d(lambda, 0.5 * (low + high), 0.5 * (low + high)).asDiagonal();
  }
};

/** Lateral stretch s of uniaxial stress with axial stretch lambda:
 *  F = diag(lambda, s, s), sigma_22 = sigma_33 = 0. Newton on
 *  g(s) = mu J^(-5/3) (s^2 - lambda^2) / 3 + kappa (J - 1), J = lambda s^2,
 *  safeguarded to stay positive. */
inline double
UniaxialLateralStretch(double lambda, const NeoHookean & material)
{
  auto g = [&](double s) {
    const double J = lambda * s * s;
    return material.mu * std::pow(J, -5.0 / 3.0) * (s * s - lambda * lambda) / 3.0 + material.kappa * (J - 1.0);
  };
  auto dg = [&](double s) {
    const double J = lambda * s * s;
    const double dJ = 2.0 * lambda * s;
    return material.mu * (-5.0 / 3.0) * std::pow(J, -8.0 / 3.0) * dJ * (s * s - lambda * lambda) / 3.0 +
           material.mu * std::pow(J, -5.0 / 3.0) * 2.0 * s / 3.0 + material.kappa * dJ;
  };
  double s = 1.0 / std::sqrt(lambda); // incompressible guess
  for (int iteration = 0; iteration < 100; ++iteration)
  {
    const double step = g(s) / dg(s);
    double       next = s - step;
    if (next <= 0.0)
    {
      next = 0.5 * s;
    }
    const bool done = std::abs(next - s) < 1e-15 * s;
    s = next;
    if (done)
    {
      break;
    }
  }
  if (!(std::abs(g(s)) < 1e-9 * (material.mu + material.kappa)))
  {
    throw std::runtime_error("UniaxialLateralStretch: Newton did not converge");
  }
  return s;
}

inline Matrix3
UniaxialDeformationGradient(double lambda, const NeoHookean & material)
{
  const double s = UniaxialLateralStretch(lambda, material);
  return Eigen::Vector3d(lambda, s, s).asDiagonal();
}

inline Matrix3
SimpleShearDeformationGradient(double gamma)
{
  Matrix3 F = Matrix3::Identity();
  F(0, 2) = gamma; // x += gamma * z
  return F;
}

inline Matrix3
RotationAboutAxis(const Vector3 & axis, double angleRadians)
{
  return Eigen::AngleAxisd(angleRadians, axis.normalized()).toRotationMatrix();
}

// ---------------------------------------------------------------------------
// Model set-up.
// ---------------------------------------------------------------------------

/** Mean of a cell's node positions (mm). */
inline Vector3
CellCentre(const Model & model, const Cell & cell)
{
  Vector3   centre = Vector3::Zero();
  const int count = NodesPerCell(cell.type);
  for (int a = 0; a < count; ++a)
    centre += model.nodes[cell.nodes[a]] / count;
  return centre;
}

inline Material
MakeMaterial(double youngsModulus, double poissonRatio, double density = 1000.0, const std::string & name = "tissue")
{
  Material m;
  m.name = name;
  m.youngsModulus = youngsModulus;
  m.poissonRatio = poissonRatio;
  m.density = density;
  return m;
}

/** E = 3 kPa, Mooney-Rivlin with C01 / (C10 + C01) = share. */
inline Material
MooneyRivlinMaterial(double share, double poissonRatio = 0.45)
{
  Material material = MakeMaterial(3000.0, poissonRatio);
  material.law = MaterialLaw::MooneyRivlin;
  material.secondInvariantShare = share;
  return material;
}

/** Parenchyma (nu 0.49), a tumour twice as stiff and soft compressible CSF
 *  (10 Pa), as in a brain: a 20 x 20 x 10 mm block on 8 x 8 x 4 grid cells
 *  (times `refinement`), CSF where x < 7 mm, tumour where y > 12 mm, bottom fixed. */
inline Model
BrainMaterialsBlock(GridCells cells, int refinement = 1, double csfPoissonRatio = 0.1)
{
  Model model = MakeBlockMesh(Vector3(20.0, 20.0, 10.0), { 8 * refinement, 8 * refinement, 4 * refinement }, cells,
                              MakeMaterial(3000.0, 0.49));
  model.materials.push_back(MakeMaterial(6000.0, 0.49, 1000.0, "tumour"));
  model.materials.push_back(MakeMaterial(10.0, csfPoissonRatio, 1000.0, "csf"));
  for (Cell & cell : model.cells)
  {
    const Vector3 centre = CellCentre(model, cell);
    cell.material = centre.x() < 7.0 ? 2 : centre.y() > 12.0 ? 1 : 0;
  }
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  return model;
}

/** Symmetry planes of a block from MakeBlockMesh: "xmin" fixed in x, "ymin" in y, "zmin" in z. */
inline void
AddSymmetryConstraints(Model & model)
{
  model.fixedConstraints.push_back({ "xmin", { true, false, false } });
  model.fixedConstraints.push_back({ "ymin", { false, true, false } });
  model.fixedConstraints.push_back({ "zmin", { false, false, true } });
}

/** Uniaxial stress along x: a cube of `length` on 2 x 2 x 2 cells with the
 *  symmetry planes xmin/ymin/zmin, the xmax face moved to stretch lambda in
 *  x only (y, z free). */
inline Model
UniaxialStressBlock(GridCells cells, double lambda, double length, const Material & material)
{
  Model model = MakeBlockMesh(Vector3::Constant(length), { 2, 2, 2 }, cells, material);
  AddSymmetryConstraints(model);
  PrescribedDisplacement pull;
  pull.nodes = model.NodeSet("xmax");
  pull.displacements.assign(pull.nodes.size(), Vector3((lambda - 1.0) * length, 0.0, 0.0));
  pull.components = { true, false, false };
  model.prescribedDisplacements.push_back(pull);
  return model;
}

/** Nodes on any face of a block from MakeBlockMesh, sorted. */
inline std::vector<Index>
BlockBoundaryNodes(const Model & model)
{
  std::set<Index> nodes;
  for (const char * name : { "xmin", "xmax", "ymin", "ymax", "zmin", "zmax" })
  {
    const auto & set = model.nodeSets.at(name);
    nodes.insert(set.begin(), set.end());
  }
  return { nodes.begin(), nodes.end() };
}

/** All nodes not in `excluded`, sorted. */
inline std::vector<Index>
ComplementNodes(const Model & model, const std::vector<Index> & excluded)
{
  std::vector<bool> skip(model.nodes.size(), false);
  for (Index n : excluded)
  {
    skip[n] = true;
  }
  std::vector<Index> result;
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    if (!skip[n])
    {
      result.push_back(static_cast<Index>(n));
    }
  }
  return result;
}

using DisplacementField = std::function<Vector3(const Vector3 &)>;

/** Field u(X) = (F - I) X + c. */
inline DisplacementField
HomogeneousField(const Matrix3 & F, const Vector3 & c = Vector3::Zero())
{
  return [F, c](const Vector3 & X) -> Vector3 { return (F - Matrix3::Identity()) * X + c; };
}

/** Prescribes u(X) on `nodes` in the chosen components (load curve default: smooth). */
inline PrescribedDisplacement &
Prescribe(Model &                    model,
          const std::vector<Index> & nodes,
          const DisplacementField &  field,
          std::array<bool, 3>        components = { true, true, true },
          LoadCurve                  curve = LoadCurve{})
{
  PrescribedDisplacement p;
  p.nodes = nodes;
  p.components = components;
  p.curve = curve;
  for (Index n : nodes)
  {
    p.displacements.push_back(field(model.nodes[n]));
  }
  model.prescribedDisplacements.push_back(p);
  return model.prescribedDisplacements.back();
}

/** Dynamic relaxation settings for near-exact steady states. */
inline SolverSettings
TightRelaxation(double tolerance = 1e-9, int maxSteps = 400000)
{
  SolverSettings settings;
  settings.integrator = Integrator::DynamicRelaxation;
  settings.tolerance = tolerance;
  settings.maxSteps = maxSteps;
  settings.threads = 1;
  return settings;
}

// ---------------------------------------------------------------------------
/** The message of the bmr::Error that `call` throws; empty if it throws none. */
template <typename Call>
std::string
ThrownMessage(Call && call)
{
  try
  {
    call();
  }
  catch (const Error & error)
  {
    return error.what();
  }
  return {};
}

// Measures.
// ---------------------------------------------------------------------------

/** Largest |u_h(X_n) - u(X_n)| over `nodes` (all nodes if empty). */
inline double
MaxNodalError(const Model &                model,
              const std::vector<Vector3> & displacements,
              const DisplacementField &    exact,
              const std::vector<Index> &   nodes = {})
{
  double error = 0.0;
  auto   visit = [&](Index n) { error = std::max(error, (displacements[n] - exact(model.nodes[n])).norm()); };
  if (nodes.empty())
  {
    for (std::size_t n = 0; n < model.nodes.size(); ++n)
      visit(static_cast<Index>(n));
  }
  else
  {
    for (Index n : nodes)
      visit(n);
  }
  return error;
}

/** Largest |u(X_n)| over all nodes of the model. */
inline double
MaxFieldNorm(const Model & model, const DisplacementField & field)
{
  double m = 0.0;
  for (const auto & X : model.nodes)
  {
    m = std::max(m, field(X).norm());
  }
  return m;
}

inline Vector3
SumOver(const std::vector<Vector3> & values, const std::vector<Index> & nodes)
{
  Vector3 sum = Vector3::Zero();
  for (Index n : nodes)
  {
    sum += values[n];
  }
  return sum;
}

inline double
MaxNorm(const std::vector<Vector3> & values, const std::vector<Index> & nodes = {})
{
  double m = 0.0;
  if (nodes.empty())
  {
    for (const auto & v : values)
      m = std::max(m, v.norm());
  }
  else
  {
    for (Index n : nodes)
      m = std::max(m, values[n].norm());
  }
  return m;
}

/** Largest |a_n - b_n - shift| over the nodes: how far one solution is from
 *  another (translated by `shift`). */
inline double
MaxDifference(const std::vector<Vector3> & a, const std::vector<Vector3> & b, const Vector3 & shift = Vector3::Zero())
{
  double m = 0.0;
  for (std::size_t n = 0; n < a.size(); ++n)
  {
    m = std::max(m, (a[n] - b[n] - shift).norm());
  }
  return m;
}

/** Scientific notation for RecordProperty (shows in --gtest_output=xml). */
inline std::string
Sci(double value)
{
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.3e", value);
  return buffer;
}

inline bool
AllFinite(const std::vector<Vector3> & values)
{
  return std::all_of(values.begin(), values.end(), [](const Vector3 & v) { return v.allFinite(); });
}

/** Signed volume of a tetrahedron. */
inline double
TetrahedronVolume(const Vector3 & a, const Vector3 & b, const Vector3 & c, const Vector3 & d)
{
  return (b - a).cross(c - a).dot(d - a) / 6.0;
}

/** Smallest, over cells, of the smallest corner Jacobian determinant (hexahedra)
 *  or 6 x volume (tetrahedra), in the deformed configuration X + u. Positive
 *  iff no cell is inverted at its corners. */
inline double
MinDeformedJacobian(const Model & model, const std::vector<Vector3> & u)
{
  static const int neighbours[8][3] = { { 1, 3, 4 }, { 2, 0, 5 }, { 3, 1, 6 }, { 0, 2, 7 },
                                        { 7, 5, 0 }, { 4, 6, 1 }, { 5, 7, 2 }, { 6, 4, 3 } };
  auto             x = [&](Index n) -> Vector3 { return model.nodes[n] + u[n]; };
  double           minimum = std::numeric_limits<double>::max();
  for (const auto & cell : model.cells)
  {
    if (cell.type == CellType::Hexahedron)
    {
      for (int c = 0; c < 8; ++c)
      {
        const Vector3 p = x(cell.nodes[c]);
        const Vector3 a = x(cell.nodes[neighbours[c][0]]) - p;
        const Vector3 b = x(cell.nodes[neighbours[c][1]]) - p;
        const Vector3 d = x(cell.nodes[neighbours[c][2]]) - p;
        minimum = std::min(minimum, a.cross(b).dot(d));
      }
    }
    else
    {
      minimum = std::min(minimum,
                         6.0 * TetrahedronVolume(x(cell.nodes[0]), x(cell.nodes[1]), x(cell.nodes[2]), x(cell.nodes[3])));
    }
  }
  return minimum;
}

/** Bitwise equality of two displacement arrays. */
inline bool
BitwiseEqual(const std::vector<Vector3> & a, const std::vector<Vector3> & b)
{
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(Vector3)) == 0);
}

// ---------------------------------------------------------------------------
// Geometry of rigid surfaces.
// ---------------------------------------------------------------------------

/** Open square of side 2*halfSize centred at `centre` in the plane with normal
 *  `normal` (two triangles, right-hand rule normal = `normal`). */
inline ContactSurface
MakePlane(const Vector3 & centre, const Vector3 & normal, double halfSize, const std::string & name = "plane")
{
  const Vector3 n = normal.normalized();
  Vector3       t1 = (std::abs(n.x()) < 0.9 ? Vector3::UnitX() : Vector3::UnitY()).cross(n).normalized();
  Vector3       t2 = n.cross(t1); // t1 x t2 = n
  ContactSurface s;
  s.name = name;
  s.vertices = { centre - halfSize * t1 - halfSize * t2, centre + halfSize * t1 - halfSize * t2,
                 centre + halfSize * t1 + halfSize * t2, centre - halfSize * t1 + halfSize * t2 };
  s.triangles = { { 0, 1, 2 }, { 0, 2, 3 } };
  return s;
}

/** Outward unit normal of a triangle of a surface (right-hand rule). */
inline Vector3
TriangleNormal(const ContactSurface & s, const std::array<Index, 3> & t)
{
  return (s.vertices[t[1]] - s.vertices[t[0]]).cross(s.vertices[t[2]] - s.vertices[t[0]]).normalized();
}

/** For a closed convex surface with outward normals: the depth of p inside it
 *  (>0 inside, = distance to the nearest face plane), or a negative number
 *  (minus the largest distance to a face plane) outside. */
inline double
DepthInsideConvex(const ContactSurface & s, const Vector3 & p)
{
  double depth = std::numeric_limits<double>::max();
  for (const auto & t : s.triangles)
  {
    depth = std::min(depth, -TriangleNormal(s, t).dot(p - s.vertices[t[0]]));
  }
  return depth;
}

} // namespace test
} // namespace bmr

#endif
