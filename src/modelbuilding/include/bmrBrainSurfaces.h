// Surfaces and boundary regions of a patient-specific brain model: the brain
// surface and a rigid skull (contact master) surface as level sets of a signed
// distance volume, and node regions on a model's boundary (craniotomy,
// skull base). Plain C++ and VTK, no ITK: the signed distance of a mask comes
// from the ITK layer (itkBrainSurfaceMeshSource.h).
//
// Units: mm, ITK physical space (LPS; +z superior).
#ifndef bmrBrainSurfaces_h
#define bmrBrainSurfaces_h

#include "bmrImageVolume.h"
#include "bmrModel.h"

#include <string>
#include <vector>

namespace bmr
{

struct IsosurfaceSettings
{
  /** Windowed-sinc smoothing iterations (Taubin's low-pass filter, VTK); 0 = none.
   *  20 removes the voxel staircase and keeps the enclosed volume within
   *  about 0.3% of the unsmoothed surface's on brain-sized shapes. */
  int smoothingIterations = 20;
  /** Pass band of the windowed-sinc filter (0 < band <= 2; smaller smooths more). */
  double smoothingPassBand = 0.1;
  /** Target mean edge length (mm) of an edge-collapse decimation (CGAL,
   *  topology preserving, Lindstrom-Turk placement); 0 = no decimation. A value
   *  at or below the current mean edge length leaves the surface as it is. */
  double targetEdgeLength = 0.0;
  /** Keep only the connected component with the most triangles. */
  bool keepLargestComponent = true;
  /** Name given to the resulting ContactSurface. */
  std::string name = "isosurface";
};

/** Closed, manifold, outward-oriented (right-hand rule normals point to where
 *  field > level) triangulated surface of {field = level}, in physical space
 *  (spacing, origin and direction cosines of field.geometry respected).
 *
 *  The volume is padded by one voxel of "outside" value, so the surface is
 *  closed even where the level set reaches the image border (it is then clipped
 *  at the border). Marching cubes (VTK flying edges), largest component,
 *  windowed-sinc smoothing, optional edge-collapse decimation (CGAL).
 *
 *  Errors (bmr::Error): a volume with no voxels, more than one component, a NaN,
 *  no voxel below the level (nothing inside), or a result that is not closed and
 *  manifold. Warnings (decimation that had to be skipped to keep the surface
 *  manifold, dropped components) go to `warnings` when given. */
ContactSurface
ExtractIsosurface(const ScalarVolume &       field,
                  double                     level,
                  const IsosurfaceSettings & settings = IsosurfaceSettings{},
                  std::vector<std::string> * warnings = nullptr);

/** Edge-collapse decimation (CGAL, topology preserving, Lindstrom-Turk
 *  placement) of a closed, outward-oriented surface to about `targetEdgeLength`
 *  (mm) mean edge length. The surface comes back as it is when the target is
 *  at or below its mean edge length, or (with a warning) when the decimation
 *  would break its topology. */
ContactSurface
DecimateSurface(const ContactSurface & surface, double targetEdgeLength, std::vector<std::string> * warnings = nullptr);

struct BrainSurfaceSettings
{
  /** Gap (mm) between the brain surface and the rigid skull surface: the skull
   *  is the level +skullGap of the signed distance, i.e. the boundary of the
   *  brain mask dilated by skullGap. The brain can move this far outward before
   *  it touches bone; the CSF layer between brain and skull is about 1-3 mm
   *  thick, so 1.5 mm is the default. */
  double skullGap = 1.5;
  /** Radius (mm) of a morphological closing of the brain before the skull is
   *  made from it: the skull does not follow the brain into fissures and
   *  notches narrower than twice the radius, where it would be a thin rigid
   *  blade inside the fold (the interhemispheric fissure, the tentorial
   *  notch), which a mesh coarser than the fold cannot resolve and which
   *  penalty contact (CalculiX) finds on both sides of a node. 0: the skull
   *  follows every fold wider than twice the gap. The volume must then extend
   *  skullGap + skullClosing + 1 voxel beyond the brain. 1 mm by default: the
   *  dura does not follow sulci either, and the closing rounds the creases of
   *  the offset skull, on which contact slaves otherwise cycle in and out of
   *  contact (the meshless frontal 15 mm registration of the validation
   *  study: 6,981 steps without, 1,228 with; docs/model-building.md). */
  double skullClosing = 1.0;
  IsosurfaceSettings isosurface;
  /** False: only the brain surface (the skull is left empty), e.g. for the
   *  anatomical surface that a surface scan is matched to. */
  bool skull = true;
};

struct BrainSurfaces
{
  ContactSurface brain; // name "brain"
  ContactSurface skull; // name "skull", bodySide Inside: a ready contact master surface
};

/** Brain (level 0) and skull (level skullGap) surfaces of a signed distance
 *  volume (mm, negative inside the brain). The volume must extend at least
 *  skullGap + 1 voxel beyond the brain, or the skull is clipped at the border
 *  (the ITK layer pads by skullGap + 2 voxels). Errors as ExtractIsosurface,
 *  and a negative or non-finite skullGap. */
BrainSurfaces
ExtractBrainSurfaces(const ScalarVolume &         signedDistance,
                     const BrainSurfaceSettings & settings = BrainSurfaceSettings{},
                     std::vector<std::string> *   warnings = nullptr);

/** Closedness check used by the functions above and by tests: every edge is
 *  shared by exactly two triangles, each of the two orientations once
 *  (consistently oriented, manifold edges). */
bool
IsClosedOrientedSurface(const ContactSurface & surface);

/** Signed volume (mm^3) enclosed by a closed triangulated surface; positive
 *  when the normals point outward. */
double
EnclosedVolume(const ContactSurface & surface);

// ---------------------------------------------------------------------------
// Regions on a model's boundary. `surfaceNodes` are node ids (for example
// model.BoundaryNodes() or model.NodeSet("surface")); results are sorted ids,
// a subset of surfaceNodes. An id out of range is a bmr::Error.
// ---------------------------------------------------------------------------

/** Surface nodes within `radius` (mm, inclusive) of `centre` (mm): a craniotomy
 *  or any spherical region. Selecting no node is a bmr::Error that names the
 *  region (centre, radius), gives the distance from the centre to the nearest
 *  surface node and suggests a radius that reaches it. */
std::vector<Index>
SurfaceNodesInSphere(const Model &              model,
                     const std::vector<Index> & surfaceNodes,
                     const Vector3 &            centre,
                     double                     radius);

/** Surface nodes that have a non-zero voxel of `regionMask` whose centre lies
 *  within `tolerance` mm of the node. tolerance < 0 (default) means one voxel
 *  diagonal (|spacing|), so a mask drawn on the image's boundary voxels catches
 *  the surface nodes between them. An empty mask, or a mask that selects no
 *  node, is a bmr::Error (the latter gives the distance from the mask to the
 *  nearest surface node). */
std::vector<Index>
SurfaceNodesInMask(const Model &              model,
                   const std::vector<Index> & surfaceNodes,
                   const LabelVolume &        regionMask,
                   double                     tolerance = -1.0);

/** The craniotomy, the opening of the skull whose surface nodes are exposed:
 *  a sphere (radius > 0 mm) or a mask (non-zero voxels, on any grid), not both. */
struct CraniotomyRegion
{
  Vector3 centre = Vector3::Zero();
  double  radius = 0.0;
  /** Not owned; must outlive the call. */
  const LabelVolume * mask = nullptr;

  bool
  Given() const
  {
    return radius > 0.0 || mask != nullptr;
  }
};

/** The one check of a craniotomy region, shared by the filters, the command
 *  line and Python: a sphere or a mask, not both, and one of them given.
 *  Throws bmr::Error saying what to give. */
void
CheckCraniotomyRegion(const CraniotomyRegion & region);

/** The same check before the mask is read: a sphere of `radius` (> 0: given)
 *  and whether a mask is given. */
void
CheckCraniotomyChoice(double radius, bool maskGiven);

/** The exposed surface nodes: those of the craniotomy region
 *  (SurfaceNodesInSphere or SurfaceNodesInMask), after CheckCraniotomyRegion. */
std::vector<Index>
ExposedSurfaceNodes(const Model & model, const std::vector<Index> & surfaceNodes, const CraniotomyRegion & region);

struct SkullBaseSettings
{
  /** Height (mm) of the fixed band above the lowest surface node, measured
   *  along `superior`. The brain rests on the skull base and is tethered by the
   *  brain stem at the foramen magnum; 10 mm above the most inferior point
   *  covers the cut end of the brain stem (medulla) of an adult brain mask
   *  without reaching far up the cerebellum. */
  double height = 10.0;
  /** Superior direction in physical space (normalised here): LPS +z. */
  Vector3 superior = Vector3::UnitZ();
  /** When sphereRadius > 0, the region is the sphere (sphereCentre, sphereRadius) instead of the band. */
  Vector3 sphereCentre = Vector3::Zero();
  double  sphereRadius = 0.0;
  /** When not null (and no sphere is given), the region is this mask (see
   *  SurfaceNodesInMask, with maskTolerance). Not owned; must outlive the call. */
  const LabelVolume * mask = nullptr;
  double              maskTolerance = -1.0;
};

/** The fixed skull-base / brain-stem region: by default the surface nodes whose
 *  height along `superior` is at most the lowest surface node's + height.
 *  Errors: no surface nodes, height < 0, direction of zero length, and the
 *  errors of the sphere and mask variants. */
std::vector<Index>
SkullBaseNodes(const Model & model, const std::vector<Index> & surfaceNodes, const SkullBaseSettings & settings = {});

/** The boundary regions of a brain model's surface, set by SetBrainRegions. */
struct BrainRegionSettings
{
  SkullBaseSettings skullBase;
  /** Not given (radius 0, no mask): no exposed set. */
  CraniotomyRegion craniotomy;
  bool             contact = true;
};

/** Sets the node sets of the surface regions (replacing earlier ones):
 *  "skull_base" (SkullBaseNodes; model.fixedConstraints becomes its one
 *  fixed constraint, all three directions), "exposed" (ExposedSurfaceNodes,
 *  when the craniotomy is given) and, with `contact`, "contact": every other
 *  surface node, the slaves of the skull. The craniotomy takes precedence
 *  over the skull base: a node in both is exposed, not fixed (an opening low
 *  on the head reaches into the default band). Exposed nodes are never
 *  contact slaves, even where a measurement is rejected: the craniotomy has
 *  no bone. Returns how many skull-base nodes the craniotomy took. Errors
 *  are those of the region functions. */
std::size_t
SetBrainRegions(Model & model, const std::vector<Index> & surfaceNodes, const BrainRegionSettings & settings);

/** The checks of the regions that need only the brain mask, made before the
 *  grid is built so that a conflict is named in the user's terms without
 *  waiting for the model: a craniotomy sphere must reach the mask's surface
 *  and must not cover the whole default skull-base band (nothing would then
 *  hold the brain stem). Surface voxels stand for the model's surface nodes.
 *  `craniotomyOption` and `heightOption` name the settings in the message
 *  (e.g. "--craniotomy-radius", "--skull-base-height"). Throws bmr::Error. */
void
CheckBrainRegionsOnMask(const LabelVolume &       brainMask,
                        const CraniotomyRegion &  craniotomy,
                        const SkullBaseSettings & skullBase,
                        const std::string &       craniotomyOption = "the craniotomy's radius",
                        const std::string &       heightOption = "the skull base's height");

} // namespace bmr

#endif
