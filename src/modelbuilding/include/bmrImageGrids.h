// Computational grids from a brain mask or a label image: a regular
// hexahedral grid conforming to the mask, a tetrahedral mesh from CGAL's 3D
// mesh generator (Mesh_3) on the labelled image, a mixed mesh (hexahedra
// inside, tetrahedra in the boundary layer snapped to the mask surface), or a
// meshless point cloud with the background integration points of MTLED.
// Plain C++17 + Eigen (+ CGAL in the .cxx); images only through bmr::Volume.
#ifndef bmrImageGrids_h
#define bmrImageGrids_h

#include "bmrImageVolume.h"
#include "bmrMeshless.h"
#include "bmrModel.h"

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace bmr
{

enum class ImageGridKind
{
  Hexahedra,  // regular grid of cubes aligned with the image axes
  Tetrahedra, // CGAL Mesh_3 on the labelled image
  Mixed,      // hexahedra inside, a boundary layer of tetrahedra snapped to the surface
  Meshless    // point cloud + background integration points (MTLED)
};

/** "hexahedra", "tetrahedra", "mixed", "meshless". */
const char *
ImageGridKindName(ImageGridKind kind);

/** Parses the names above (also "hex", "tet"); throws bmr::Error naming the
 *  accepted names for anything else. */
ImageGridKind
ParseImageGridKind(const std::string & name);

struct ImageGridSettings
{
  ImageGridKind kind = ImageGridKind::Hexahedra;
  /** mm. Hexahedra and mixed: the grid's cell edge. Tetrahedra: the target
   *  edge length (CGAL cell_size = elementSize * sqrt(6)/4, the circumradius of
   *  a regular tetrahedron of that edge; facet_size = elementSize / sqrt(3),
   *  the circumradius of an equilateral triangle of that edge). Meshless: the
   *  nodal spacing of the interior nodes and the size of the surface mesh
   *  that gives the boundary nodes. Must be at least the smallest voxel
   *  spacing, and the body must be at least 2 elements across along every
   *  image axis. */
  double elementSize = 5.0;

  // Tetrahedra (and the surface of a meshless cloud): CGAL Mesh_3 criteria.
  /** Lower bound of the surface facets' angles, degrees (CGAL facet_angle; at most 30). */
  double facetAngle = 25.0;
  /** Upper bound of the distance between a surface facet and the mask
   *  surface, mm (CGAL facet_distance); 0: elementSize / 8, i.e. about half a
   *  voxel at the 4-6 mm sizes a brain model uses, small enough to follow the
   *  surface's curvature, large enough not to chase the voxel staircase. */
  double facetDistance = 0.0;
  /** Upper bound of a cell's circumradius / shortest edge (CGAL cell_radius_edge_ratio, >= 2). */
  double cellRadiusEdgeRatio = 3.0;
  /** Sliver removal after refinement: CGAL perturb (sliver bound 10 degrees)
   *  followed by exude (sliver bound 15 degrees), both without time limit so
   *  that the result is reproducible. */
  bool optimise = true;
  /** CGAL is randomised: its default random generator is re-seeded with this
   *  value, so the same seed gives the same mesh. */
  std::uint32_t seed = 1;

  // Meshless.
  /** MLS shape functions; the default dilatation here is 1.7 (the core's is
   *  1.6, where a cloud of grid nodes plus surface-mesh nodes leaves
   *  integration points in thin parts of a brain with 4 nearly coplanar
   *  neighbours: Colin27 at 7 mm fails). About 20 neighbours a point
   *  instead of the 32 of the 2.0 used before halve a step's cost; the
   *  solves measured took 0.7 to 1.2 times the steps and 0.4 to 0.9 times
   *  the time, equally accurate (docs/model-building.md). */
  MlsSettings meshlessShapeFunctions = [] {
    MlsSettings shapeFunctions;
    shapeFunctions.dilatation = 1.7;
    return shapeFunctions;
  }();
  /** Where the cloud does not cover the body at that dilatation (a point
   *  with fewer than 4 neighbours, or nearly coplanar ones, in a thin part),
   *  it is made again at this one, with a warning; at most the dilatation
   *  itself (e.g. 0): an error instead. */
  double meshlessFallbackDilatation = 2.0;
  /** Background integration grid: cells of the median nodal spacing, 2x2x2
   *  Gauss points, and here no coarse interior blocks: the tissue classes
   *  reach the points from the image after the points are made, so the
   *  blocks' one-material test cannot keep them off tissue interfaces
   *  (Colin27 at 4.25 mm with them: 2,008 -> 5,886 dynamic-relaxation steps). */
  IntegrationSettings meshlessIntegration = [] {
    IntegrationSettings integration;
    integration.interiorPointsPerDirection = 0;
    return integration;
  }();

  /** Threads for the meshless shape-function evaluation (0: OpenMP default).
   *  The result does not depend on it. */
  int threads = 0;
};

/** Size and quality of a grid. Scaled Jacobian: the smallest corner Jacobian
 *  determinant of the cell with unit edge vectors (1 for a cube and for an
 *  equilateral tetrahedron scaled by sqrt(2); <= 0 for an inverted cell).
 *  Aspect ratio: longest edge / shortest edge of a cell. */
struct GridQuality
{
  std::size_t cells = 0, hexahedra = 0, tetrahedra = 0, nodes = 0;
  double      meshVolume = 0.0; // mm^3: sum of cell volumes (meshless: sum of integration weights)
  double      maskVolume = 0.0; // mm^3: tissue voxels x voxel volume
  double      volumeError = 0.0; // (meshVolume - maskVolume) / maskVolume
  double      minScaledJacobian = 0.0, meanScaledJacobian = 0.0;
  double      minDihedralAngleDeg = 0.0, maxDihedralAngleDeg = 0.0; // tetrahedra only (0 when there are none)
  double      maxAspectRatio = 0.0;
  double      meanEdgeLength = 0.0; // mm, over the cells' edges (meshless: mean nodal spacing)
  std::size_t integrationPoints = 0;                               // meshless
  double      minNeighboursPerPoint = 0.0, meanNeighboursPerPoint = 0.0; // meshless
  double      seconds = 0.0; // wall time of MakeGridFromLabels
};

struct ImageGrid
{
  /** Nodes (mm, the image's physical space), cells (hexahedra in VTK order,
   *  positively oriented tetrahedra), one material "parenchyma" (E = 3000 Pa,
   *  nu = 0.49, rho = 1000 kg/m^3) at index 0 for every cell or integration
   *  point, node sets "all" and "surface" (the boundary nodes). A meshless
   *  model has no cells: discretization = Meshless, model.meshless filled. */
  Model            model;
  /** The image label of each cell: the label covering most of the cell's
   *  volume (hexahedra, mixed) or CGAL's subdomain index, which is the label
   *  (tetrahedra). Empty for a meshless grid. */
  std::vector<int> cellLabels;
  GridQuality      quality;
  /** Meshless only: the tetrahedral mesh whose region the integration points
   *  cover (its boundary vertices are the cloud's surface nodes). Surfaces
   *  that must enclose the body, such as the skull, are made from it. */
  Model            meshlessBody;
};

/** Builds the grid of the body given by `labels` (0 = outside, > 0 = tissue
 *  label; a mask is labels {0, 1}). Only the largest face-connected part of
 *  the tissue voxels is meshed (specks of a skull-stripped mask would be loose
 *  pieces of the model); a warning says what was dropped, and maskVolume is
 *  that part's volume.
 *  Hexahedra: a regular grid of cubes of edge elementSize aligned with the
 *  image axes and centred on the body's bounding box; a cube is kept when at
 *  least half of its volume lies inside the body (computed exactly from the
 *  voxel overlaps, i.e. the limit of supersampling with nearest-voxel lookup),
 *  which makes the mesh volume match the mask volume. Edge- and vertex-only
 *  contacts (non-manifold edges and vertices) are removed by adding the
 *  missing cube with the largest inside fraction until none remains, and only
 *  the largest face-connected component is kept (a warning names what was
 *  dropped).
 *  Mixed: the same cubes; those touching the boundary are split into the 6
 *  conforming Kuhn tetrahedra of MakeBlockMesh, and the surface nodes are
 *  moved along the surface normal to the 0.5 level of the mask (trilinear),
 *  at most 0.4 elementSize, a move being halved until every attached
 *  tetrahedron keeps at least 15% of its unsnapped volume.
 *  Tetrahedra: CGAL Mesh_3 (sequential, seeded) on the labelled image.
 *  Meshless: nodes on the elementSize grid inside the body (nearest voxel
 *  inside, at least 0.5 elementSize from a surface node) plus the boundary
 *  vertices of the tetrahedral mesh of the same size; integration points from
 *  MakeIntegrationPoints over the region of that mesh's tetrahedra.
 *  Throws bmr::Error (nothing half-built) for: labels with components != 1 or
 *  a size that does not match the values, an empty / all-background volume,
 *  elementSize not finite or below the smallest voxel spacing, a body less
 *  than 2 elements across along an image axis, CGAL failing to mesh, or
 *  integration points with too few MLS neighbours. */
ImageGrid
MakeGridFromLabels(const LabelVolume &         labels,
                   const ImageGridSettings &   settings,
                   std::vector<std::string> * warnings = nullptr);

/** Quality figures of a grid as a few human-readable lines (for the CLI). */
std::string
FormatGridQuality(const GridQuality & quality);

/** Computes the quality of a finite-element model's cells (volumes, scaled
 *  Jacobians, dihedral angles, aspect ratios); maskVolume is left 0. */
GridQuality
MeasureGridQuality(const Model & model);

/** The body as the model discretises it, on an image grid: 1 for the voxels
 *  whose centre lies in a cell (hexahedra as their 6 Kuhn tetrahedra), 0
 *  elsewhere. Surfaces that must enclose the model rather than the mask (the
 *  skull around a staircase hexahedral grid) are made from it. Throws
 *  bmr::Error for a model without cells. */
LabelVolume
RasterizeCells(const Model & model, const ImageGeometry & grid);

} // namespace bmr

#endif
