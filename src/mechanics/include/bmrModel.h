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

#include "bmrError.h"
#include "bmrMaterialLaw.h"
#include "bmrOgden.h"

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace bmr
{

using Index = std::int32_t;
using Vector3 = Eigen::Vector3d;

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

/** A hyperelastic solid (bmrMaterialLaw.h): the law, its small-strain
 *  moduli from E and nu, W_iso + kappa/2 (J - 1)^2. */
struct Material
{
  std::string name;
  double      youngsModulus = 3000.0; // Pa
  double      poissonRatio = 0.49;
  double      density = 1000.0; // kg/m^3
  MaterialLaw law = MaterialLaw::NeoHookean;
  /** Mooney-Rivlin only: C01 / (C10 + C01), the share of the small-strain
   *  shear modulus carried by the second invariant, in [0, 1]. A law's
   *  parameter: listed in MaterialParameters() (bmrMaterialLaw.cxx). */
  double secondInvariantShare = 0.0;

  /** The small-strain shear modulus mu = 2 (C10 + C01) (Pa). */
  double ShearModulus() const { return youngsModulus / (2.0 * (1.0 + poissonRatio)); }
  double BulkModulus() const { return youngsModulus / (3.0 * (1.0 - 2.0 * poissonRatio)); }
  /** 2 C01 (Pa): the second invariant's part of mu; 0 for a law without
   *  the second invariant's term (MaterialLawDescription::secondInvariant). */
  double SecondInvariantModulus() const;
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
  /** Contact offset (mm): the body keeps this far from the surface on its
   *  side; negative, it may pass the surface by that much. A projected node
   *  goes to its closest point moved by the offset along the smooth normal
   *  there: the surface moved without remaking it (a skull at another gap). */
  double                      offset = 0.0;

  /** The triangles with their normals (right-hand rule) pointing to the
   *  surface's outside: a closed surface oriented outward, an open one as
   *  given (flipNormals reverses it). `closed` (when given): whether every
   *  edge is shared by exactly two triangles. Throws bmr::Error for a closed
   *  surface whose triangles are not consistently oriented. */
  std::vector<std::array<Index, 3>> OutwardTriangles(bool * closed = nullptr) const;
  /** Mean length of the triangles' edges (mm; each shared edge counted once per triangle); 0 without triangles. */
  double MeanEdgeLength() const;
};

/** Where a rigid tool is at a time: the origin of the tool's frame (mm) and
 *  its orientation as a rotation vector (axis times angle, radians), both in
 *  the model's frame. */
struct ToolPose
{
  double  time = 0.0; // s
  Vector3 position = Vector3::Zero();
  Vector3 rotation = Vector3::Zero();
};

/** A rigid surgical tool moved along a prescribed trajectory: frictionless
 *  contact with separation, the body staying outside the tool. Explicit
 *  dynamics moves it in time; dynamic relaxation ramps it from the first to
 *  the last pose over the load steps and reports the steady state.
 *  Shapes, in the tool's frame (the tip at the origin, the tool along +z):
 *   - Probe: a sphere-ended cylinder of `radius`, the tip sphere centred at the
 *     origin, the shaft `length` mm along +z;
 *   - Spatula: a flat blade of thickness 2 radius with rounded edges around
 *     the rectangle x in [-width/2, width/2], y = 0, z in [0, length];
 *   - Surface: `surface` (a closed triangulated surface, any shape). */
struct RigidTool
{
  enum class Shape
  {
    Probe,
    Spatula,
    Surface
  };
  std::string           name = "tool";
  Shape                 shape = Shape::Probe;
  double                radius = 2.0;  // mm
  double                length = 50.0; // mm
  double                width = 10.0;  // mm, spatula
  ContactSurface        surface;       // Shape::Surface, tool frame
  std::vector<ToolPose> trajectory;    // times increasing; linear in position, spherical-linear in rotation
  std::string           slaveNodeSet;  // empty: the boundary nodes
  /** Stresses near the tool (explicit dynamics): the cells whose reference
   *  centroid comes within this distance (mm) of the tool anywhere along its
   *  trajectory are re-evaluated every step with `stressMaterial`, Miller and
   *  Chinzei's Ogden-type hyperviscoelastic law, from their deformation
   *  gradients and time history; the tool force is corrected by the
   *  difference of those cells' nodal forces. 0: no re-evaluation. The
   *  re-evaluation does not feed back into the motion. */
  double                    stressRegionRadius = 0.0;
  OgdenViscoelasticMaterial stressMaterial;
};

const char *
ToolShapeName(RigidTool::Shape shape);

/** The tool's pose at `time`: interpolated between the trajectory's poses,
 *  held at the first before it starts and at the last after it ends. */
ToolPose
ToolPoseAt(const RigidTool & tool, double time);

/** Basis of the moving-least-squares shape functions of the meshless discretization. */
enum class MlsBasis : std::uint8_t
{
  Linear,           // Element-Free Galerkin, basis [1, x, y, z]
  ModifiedQuadratic // modified MLS (Joldes et al. 2015): quadratic basis at the nodal density of a linear one
};

struct MlsSettings
{
  MlsBasis basis = MlsBasis::Linear;
  /** Support radius of node I = dilatation x its local nodal spacing (mean
   *  distance to its nearest neighbours). Smaller supports make dynamic
   *  relaxation converge faster (less smoothing, better conditioning); 1.6
   *  keeps enough neighbours for jittered clouds (see docs/solver.md). */
  double dilatation = 1.6;
  /** Modified MLS only: regularisation mu of the quadratic coefficients, in
   *  coordinates scaled by the support radius (see docs/solver.md). */
  double quadraticRegularization = 1e-3;
};

/** How essential boundary conditions act on a meshless model. */
enum class EssentialBoundaryImposition : std::uint8_t
{
  Ebciem, // the MLS-interpolated displacement meets the prescribed value (Joldes et al. 2017)
  Nodal   // the nodal parameter is set (inexact: MLS is not interpolating); for comparison
};

/** Meshless (MTLED) discretization: the model's nodes carry MLS shape
 *  functions, integrals are sums over integration points. Cells, if the model
 *  has any, only describe the body (output, boundary) and are not integrated. */
struct MeshlessDiscretization
{
  MlsSettings                 shapeFunctions;
  EssentialBoundaryImposition essentialBoundary = EssentialBoundaryImposition::Ebciem;
  std::vector<Vector3>        integrationPoints;    // mm, reference configuration
  std::vector<double>         integrationWeights;   // mm^3
  std::vector<Index>          integrationMaterials; // index into Model::materials, one per point
};

enum class Discretization : std::uint8_t
{
  FiniteElement,
  Meshless
};

/** What a model's materials were mixed from (MapMaterialsFromMemberships):
 *  the tissue classes' materials (the tumour last) and, per cell and then per
 *  meshless integration point, each class's share (rows of classes.size()
 *  values summing to 1). Empty: the materials are not a mixture of classes
 *  (a scene, a label map). The uncertainty ensemble draws a stiffness per
 *  class from it (bmrEnsemble.h, RemixTissueModuli in bmrMaterialMapping.h). */
struct TissueMixture
{
  std::vector<Material> classes;
  std::vector<double>   shares;

  bool Empty() const { return classes.empty(); }
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
  /** CSF drainage (Miga et al. 1999): where set, the CSF still fills the skull
   *  up to the plane through this point normal to bodyAcceleration. Nodes
   *  below it stay buoyed (neutrally, as before drainage) and carry no body
   *  force; nodes above it have lost that buoyancy and carry their weight.
   *  Unset: every node carries its weight (the CSF fully drained). */
  std::optional<Vector3>              fluidSurface; // mm
  std::vector<ContactSurface>         contactSurfaces;
  std::vector<RigidTool>              tools;

  Discretization         discretization = Discretization::FiniteElement;
  MeshlessDiscretization meshless; // used when discretization == Meshless
  TissueMixture          tissueMixture;

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

/** "(x, y, z)" with 6 significant digits, for messages that name a position. */
std::string
FormatPoint(const Vector3 & point);

/** Signed volume of a cell in the reference configuration (mm^3). Negative for
 *  an inverted cell. Hexahedra: exact trilinear volume. */
double
CellVolume(const Model & model, Index cell);

/** The cells c with keep[c] != 0 and the nodes they use, renumbered in order
 *  of first use; materials kept; node sets, constraints and loads are not
 *  carried (the caller maps them). `newIndexOfNode`, when given, receives the
 *  old -> new node indices (-1 for a dropped node). */
Model
KeepCells(const Model & model, const std::vector<char> & keep, std::vector<Index> * newIndexOfNode = nullptr);

} // namespace bmr

#endif
