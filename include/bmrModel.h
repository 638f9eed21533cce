// Model data of the mechanics core: nodes, cells, node sets, materials, loads,
// constraints and contact surfaces. Plain data, no images, no ITK.
//
// Units at this boundary are the user's: lengths in mm, moduli in Pa, density
// in kg/m^3, time in s, accelerations in mm/s^2, forces reported in N.
// Conversion to the solver's internal system happens in bmrUnits.h only.
#ifndef bmrModel_h
#define bmrModel_h

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace bmr
{

using Index = std::int32_t;
using Vector3 = Eigen::Vector3d;

/** Every error of the core: the message names the object and what to do. */
class Error : public std::runtime_error
{
public:
  using std::runtime_error::runtime_error;
};

enum class CellType : std::uint8_t
{
  Hexahedron, // 8 nodes, VTK_HEXAHEDRON ordering
  Tetrahedron // 4 nodes, VTK_TETRA ordering
};

inline int
NodesPerCell(CellType type)
{
  return type == CellType::Hexahedron ? 8 : 4;
}

const char *
CellTypeName(CellType type);

struct Cell
{
  CellType              type = CellType::Tetrahedron;
  std::array<Index, 8>  nodes{}; // first NodesPerCell(type) entries used
  Index                 material = 0; // index into Model::materials
};

/** Compressible neo-Hookean: W = mu/2 (I1bar - 3) + kappa/2 (J - 1)^2. */
struct Material
{
  std::string name;
  double      youngsModulus = 3000.0; // Pa
  double      poissonRatio = 0.49;
  double      density = 1000.0; // kg/m^3

  double ShearModulus() const { return youngsModulus / (2.0 * (1.0 + poissonRatio)); }
  double BulkModulus() const { return youngsModulus / (3.0 * (1.0 - 2.0 * poissonRatio)); }
};

/** Smooth (zero velocity and acceleration at both ends) or linear ramp from 0 to 1. */
struct LoadCurve
{
  enum class Shape
  {
    Smooth,
    Linear,
    Step
  };
  Shape  shape = Shape::Smooth;
  double rampTime = 1.0; // s; explicit dynamics only (dynamic relaxation ramps over steps)

  /** Load factor at fraction s = t / rampTime of the ramp (clamped to [0, 1]). */
  double Factor(double fraction) const;
};

/** Nodes of a set held at zero displacement in the chosen components. */
struct FixedConstraint
{
  std::string         nodeSet;
  std::array<bool, 3> components{ true, true, true };
};

/** Enforced displacement per node (mm), ramped by the load curve. */
struct PrescribedDisplacement
{
  std::vector<Index>   nodes;
  std::vector<Vector3> displacements;
  std::array<bool, 3>  components{ true, true, true };
  LoadCurve            curve;
};

/** Rigid triangulated master surface for frictionless contact with separation.
 *  Triangle normals (right-hand rule) point to the surface's outside. A closed
 *  surface is re-oriented outward automatically; an open one keeps the user's
 *  orientation (flipNormals reverses it). The body stays on `bodySide`. */
struct ContactSurface
{
  enum class Side
  {
    Inside,
    Outside
  };
  std::string                 name = "contact";
  std::vector<Vector3>        vertices;
  std::vector<std::array<Index, 3>> triangles;
  Side                        bodySide = Side::Inside;
  bool                        flipNormals = false;
  std::string                 slaveNodeSet; // empty: all boundary nodes of the mesh
};

struct Model
{
  std::vector<Vector3>                        nodes; // mm
  std::vector<Cell>                           cells;
  std::vector<Material>                       materials;
  std::map<std::string, std::vector<Index>>   nodeSets;

  std::vector<FixedConstraint>        fixedConstraints;
  std::vector<PrescribedDisplacement> prescribedDisplacements;
  Vector3                             bodyAcceleration = Vector3::Zero(); // mm/s^2 (gravity: 0,0,-9810)
  LoadCurve                           bodyForceCurve;
  std::vector<ContactSurface>         contactSurfaces;

  /** Checks indices, cell shapes (no degenerate or inverted cell), materials and
   *  node-set references; throws bmr::Error naming the first offending object. */
  void Validate() const;

  /** Node ids of the named set; throws bmr::Error if the set does not exist. */
  const std::vector<Index> & NodeSet(const std::string & name) const;

  /** Nodes on the boundary (faces that belong to exactly one cell), sorted. */
  std::vector<Index> BoundaryNodes() const;

  /** Boundary faces as triangles (hexahedron quads split in two), outward normals. */
  std::vector<std::array<Index, 3>> BoundaryTriangles() const;
};

/** Signed volume of a cell in the reference configuration (mm^3). Negative for
 *  an inverted cell. Hexahedra: exact trilinear volume. */
double
CellVolume(const Model & model, Index cell);

} // namespace bmr

#endif
