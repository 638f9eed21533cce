// Meshless discretization (MTLED, Horton et al. 2010): moving-least-squares
// shape functions on a point cloud, and integration points on a background
// grid of the body. Plain C++17 + Eigen, no ITK.
#ifndef bmrMeshless_h
#define bmrMeshless_h

#include "bmrModel.h"

#include <Eigen/Geometry>

#include <memory>
#include <string>
#include <vector>

namespace bmr
{

/** Shape functions at a set of evaluation points in compressed rows: the
 *  neighbours of point p are nodes[offsets[p] .. offsets[p + 1]). */
struct ShapeFunctionTable
{
  std::vector<Index>  offsets{ 0 }; // point count + 1
  std::vector<Index>  nodes;        // neighbour node ids, ascending within a row
  std::vector<double> values;       // phi_I(x_p), one per entry
  std::vector<double> gradients;    // d phi_I / dX (1/mm), 3 per entry; empty when not requested

  Index PointCount() const { return static_cast<Index>(offsets.size()) - 1; }

  /** sum_I phi_I(x_p) v_I for a field of 3 values per node. */
  Vector3 Interpolate(Index point, const double * nodalValues) const;
};

/** Moving least squares (Element-Free Galerkin) with linear basis, or the
 *  modified MLS of Joldes et al. (2015) with a quadratic basis; quartic-spline
 *  weights with compact support. Neighbours are found with a k-d tree (nanoflann). */
class MovingLeastSquares
{
public:
  /** Computes each node's local spacing and support radius. Throws bmr::Error
   *  for fewer than 4 nodes, duplicate nodes, or settings out of range.
   *  With `integrationPoints`, a node's support radius is the dilatation times
   *  the larger of its nodal spacing and its distance to the 4th nearest
   *  integration point, so that every support holds several points (without
   *  them a node can have mass but hardly any stiffness: see docs/solver.md).
   *  The solver passes the model's integration points; so must anyone who
   *  evaluates the solution's shape functions (or use ForModel). */
  MovingLeastSquares(std::vector<Vector3>         nodes,
                     const MlsSettings &          settings,
                     const std::vector<Vector3> & integrationPoints = {});

  /** The shape functions the solver uses for a meshless model: its nodes, its
   *  MLS settings and its integration points. */
  static std::unique_ptr<MovingLeastSquares> ForModel(const Model & model);
  ~MovingLeastSquares();
  MovingLeastSquares(const MovingLeastSquares &) = delete;
  MovingLeastSquares & operator=(const MovingLeastSquares &) = delete;

  const MlsSettings &          Settings() const;
  const std::vector<Vector3> & Nodes() const;
  Index                        NodeCount() const;
  /** Mean distance (mm) from the node to its nearest neighbours. */
  double NodalSpacing(Index node) const;
  /** dilatation x NodalSpacing(node). */
  double SupportRadius(Index node) const;

  /** Shape functions (and their exact derivatives) at the points. A point whose
   *  moment matrix is singular or ill-conditioned (too few or coplanar
   *  neighbours) throws bmr::Error naming `pointLabel`, its index and position
   *  and suggesting a larger dilatation or denser nodes. Deterministic for any
   *  thread count (0 = OpenMP default). */
  ShapeFunctionTable Evaluate(const std::vector<Vector3> & points,
                              bool                         withGradients,
                              int                          threads = 0,
                              const std::string &          pointLabel = "point") const;

private:
  struct Impl;
  std::unique_ptr<Impl> m_Impl;
};

/** The region the body occupies in the reference configuration, with the
 *  material at each point. */
class BodyRegion
{
public:
  /** The union of the model's cells (hexahedra as 6 tetrahedra); the material
   *  of a point is that of the cell containing it. */
  static BodyRegion FromCells(const Model & model);
  /** The inside of a closed, consistently oriented triangulated surface, one material. */
  static BodyRegion FromSurface(const std::vector<Vector3> &              vertices,
                                const std::vector<std::array<Index, 3>> & triangles,
                                Index                                     material);

  BodyRegion(BodyRegion &&) noexcept;
  BodyRegion & operator=(BodyRegion &&) noexcept;
  ~BodyRegion();

  bool                 Contains(const Vector3 & x) const;
  /** Material index at x, -1 outside the body. */
  Index                MaterialAt(const Vector3 & x) const;
  Eigen::AlignedBox3d  Bounds() const;

private:
  struct Impl;
  explicit BodyRegion(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> m_Impl;
};

struct IntegrationSettings
{
  /** Edge of the background grid's cells (mm); 0: the median nodal spacing.
   *  The grid spans the body's bounding box with whole cells, so each edge is
   *  adjusted per axis to the nearest size that fits (a box-shaped body, or one
   *  made of a grid's cells, is then never cut by a background cell). */
  double cellSize = 0.0;
  /** Gauss points per direction in each cell: 1, 2 or 3. The default 2 gives
   *  about 8 points per node: one point per cell leaves zero-energy
   *  (checkerboard) modes on regular node grids (see docs/solver.md). */
  int pointsPerDirection = 2;
  /** Adaptive integration (Joldes, Wittek, Miller 2015): a cell is divided in 8
   *  until the integrals of the shape functions over it change by less than
   *  `adaptiveTolerance` (relative to the cell volume) between two levels; an
   *  accepted cell keeps its children's (finer) points. A cell whose corners
   *  lie on both sides of the body's boundary is divided too, as the shape
   *  functions alone cannot see the boundary. Costs at least 8 times the points. */
  bool   adaptive = false;
  double adaptiveTolerance = 1e-2;
  int    maxSubdivisionLevels = 3;
  /** Coarse interior blocks: each block of 2 x 2 x 2 background cells that
   *  lies, with the ring of cells around it, inside the body and in one
   *  material, and whose coarse
   *  rule integrates the gradients of the shape functions within
   *  `interiorTolerance` of its cells' rule (max over nodes of |difference| x
   *  cell edge / block volume) is integrated as one cell of twice the edge
   *  with `interiorPointsPerDirection` points per direction. Cells near the
   *  boundary or a material interface, and blocks of irregular clouds, keep
   *  `pointsPerDirection`. 0: no coarse blocks. Ignored with adaptive
   *  integration. On regular clouds the default 2 halves the points (about
   *  one per node inside) at the same accuracy against CalculiX C3D10 (see
   *  docs/solver.md); a regular cloud's blocks measure 0.023, a cloud jittered
   *  by 25 % of its spacing 0.04 to 0.07. */
  int    interiorPointsPerDirection = 2;
  double interiorTolerance = 0.03;
};

struct IntegrationPoints
{
  std::vector<Vector3> positions; // mm
  std::vector<double>  weights;   // mm^3
  std::vector<Index>   materials; // per point, from BodyRegion::MaterialAt
};

/** Gauss points of the background cells that intersect the body, kept where
 *  they lie inside it. Deterministic order and values for any thread count. */
IntegrationPoints
MakeIntegrationPoints(const BodyRegion &          body,
                      const MovingLeastSquares &  shapeFunctions,
                      const IntegrationSettings & settings,
                      int                         threads = 0);

/** Fills model.meshless (integration points, weights, materials) for the
 *  model's nodes, the body given by its cells, and sets the discretization to
 *  Meshless. Throws bmr::Error for a model without cells. */
void
MakeMeshlessFromCells(Model & model, const MlsSettings & shapeFunctions, const IntegrationSettings & integration,
                      int threads = 0);

/** Displacements (mm) at arbitrary points of a meshless model, from the nodal
 *  parameters of its solution (SolveResult::nodalParameters). */
std::vector<Vector3>
InterpolateDisplacements(const MovingLeastSquares &   shapeFunctions,
                         const std::vector<Vector3> & nodalParameters,
                         const std::vector<Vector3> & points,
                         int                          threads = 0);

} // namespace bmr

#endif
