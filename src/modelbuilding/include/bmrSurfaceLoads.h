// Loading from intraoperative measurements: enforced displacements of the
// exposed brain surface (a Dirichlet problem, Miller, Wittek, Joldes et al.),
// computed from
//  (a) an intraoperative surface (stereo camera, ultrasound, iMRI/CT
//      segmentation): each exposed node moves to the closest point of it, or
//  (b) sparse displacement vectors at points (tracked surface points,
//      electrodes seen on CT): interpolated to the exposed nodes with a
//      polyharmonic (thin-plate, phi(r) = r in 3D) spline plus an affine part.
// Plain C++ with Eigen and CGAL; units mm.
#ifndef bmrSurfaceLoads_h
#define bmrSurfaceLoads_h

#include "bmrModel.h"

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

namespace bmr
{

struct SurfaceLoadSettings
{
  /** mm: a measurement farther than this from the model surface is rejected
   *  with a warning (an exposed node whose closest intraoperative point is
   *  farther, in (a); a sparse point farther from the model's boundary
   *  surface, in (b)). Brain shift reaches 10-20 mm; 10 mm keeps outliers out. */
  double maxDistance = 10.0;
  /** (b) only: regularisation lambda (mm) added to the kernel diagonal; 0 =
   *  interpolating spline. Positive values trade fidelity at the points for a
   *  smoother field (noisy measurements). */
  double smoothing = 0.0;
  /** (c) only: each scanned vertex is matched along this direction (e.g.
   *  gravity's, along which the brain sinks after CSF loss) to the first
   *  point of the intraoperative surface a ray along it meets, instead of to
   *  its closest point; a vertex whose ray misses the surface is left out.
   *  Unset: closest points. */
  std::optional<Vector3> matchDirection;
};

struct LoadReport
{
  std::size_t              usedPoints = 0;      // (a) exposed nodes loaded; (b) measurement points kept
  std::size_t              rejectedPoints = 0;  // (a) exposed nodes left out; (b) points rejected
  double                   maxCorrespondenceDistance = 0.0; // mm, over used points: (a) node to surface, (b) point to model surface
  double                   rmsCorrespondenceDistance = 0.0; // mm
  std::vector<std::string> warnings;
};

/** (a) Each exposed node moves to the closest point of the intraoperative
 *  surface (CGAL AABB tree): displacement = closest point - node position.
 *  Nodes whose closest point is farther than settings.maxDistance are left
 *  out of the load; a warning names them and their distances.
 *
 *  Accuracy: the correspondence is exact for a motion along the surface
 *  normal; a tangential component of the true motion is not observable from a
 *  surface and is lost (the error is the tangential part, plus the chord error
 *  of the triangulation).
 *
 *  Errors (bmr::Error): no exposed nodes, a node id out of range, an empty
 *  surface or a non-finite vertex, and every node rejected. */
PrescribedDisplacement
DisplacementsFromSurface(const Model &              model,
                         const std::vector<Index> & exposedNodes,
                         const ContactSurface &     intraoperativeSurface,
                         const SurfaceLoadSettings & settings = SurfaceLoadSettings{},
                         LoadReport *               report = nullptr);

/** (b) Interpolates displacement vectors measured at `points` (reference,
 *  i.e. preoperative, positions, mm) to every exposed node:
 *      u(x) = sum_i w_i |x - p_i| + a0 + A x,  sum_i w_i = 0, sum_i w_i p_i = 0
 *  (polyharmonic spline phi(r) = r, the thin-plate spline of 3D, which
 *  reproduces affine fields exactly). Solved with Eigen's complete orthogonal
 *  decomposition, so coplanar points (a flat patch) give the minimum-norm
 *  affine part instead of failing.
 *
 *  Points farther than settings.maxDistance from the model's boundary surface
 *  (model.BoundaryTriangles(), or `modelSurface` when given: a meshless point
 *  cloud has no cells, and its body's surface is given instead) are rejected with a warning naming the point's
 *  index, position and distance. With 1 to 3 kept points, the spline is not
 *  determined: the mean of their displacements is applied to every exposed
 *  node (a rigid translation) with a warning.
 *
 *  Errors (bmr::Error): a NaN or infinite coordinate or displacement (naming
 *  the point), sizes that differ, no exposed nodes, a node id out of range, a
 *  model without boundary, and no point kept. */
PrescribedDisplacement
DisplacementsFromSparsePoints(const Model &                model,
                              const std::vector<Index> &   exposedNodes,
                              const std::vector<Vector3> & points,
                              const std::vector<Vector3> & displacements,
                              const SurfaceLoadSettings &  settings = SurfaceLoadSettings{},
                              LoadReport *                 report = nullptr,
                              const ContactSurface *       modelSurface = nullptr);

/** Default spacing (mm) of the scanned surface's points that load the model:
 *  the tracked-point density of a surface scan. */
constexpr double kDefaultScanSpacing = 5.0;

/** (c) Surface to surface, for a displaced surface that covers the exposed
 *  region (a scan): the vertices of the smooth `preoperativeSurface` (the
 *  cortex, the surface the scan images: the pipeline gives the smooth
 *  surface of the brain mask, CortexSurfaceOfMask) that lie within `reach` mm of an
 *  exposed node are viewed along the exposed region's mean normal, as a
 *  scanner looking into the craniotomy sees them: per lateral cell of
 *  `spacing` mm, the highest vertex whose normal is within 60 degrees of
 *  the view. Each is matched to its closest point on the
 *  `intraoperativeSurface` (or along settings.matchDirection); each match is
 *  then refined twice from a robust local linear fit of its neighbours'
 *  matches (the closest point of the surface to the fit's prediction), a
 *  match still more than max(1 mm, 20 %) from that fit is left out with a
 *  warning, and the displacements are interpolated to the exposed nodes as in (b).
 *
 *  Why not (a): the nodes of a staircase hexahedral surface lie up to half a
 *  cell off the brain surface, and nodes on the walls of a sulcus or of the
 *  interhemispheric fissure inside the opening have their closest
 *  intraoperative point sideways or on the displaced crowns above them; both
 *  turn into spurious displacements of several mm (a 5 mm hexahedral
 *  Colin27 model folded under them). Hidden vertices are left out for the
 *  same reason. Matches
 *  farther than settings.maxDistance are rejected with a warning.
 *
 *  Errors (bmr::Error): those of (b), an empty surface, and no vertex of the
 *  preoperative surface near the exposed nodes. */
PrescribedDisplacement
DisplacementsBetweenSurfaces(const Model &               model,
                             const std::vector<Index> &  exposedNodes,
                             const ContactSurface &      preoperativeSurface,
                             const ContactSurface &      intraoperativeSurface,
                             double                      reach,
                             double                      spacing,
                             const SurfaceLoadSettings & settings = SurfaceLoadSettings{},
                             LoadReport *                report = nullptr,
                             const ContactSurface *      modelSurface = nullptr);

struct SparseDisplacements
{
  std::vector<Vector3> points;        // mm, reference positions
  std::vector<Vector3> displacements; // mm
};

/** Writes `sparse` as the CSV ReadSparseDisplacements reads (header
 *  x,y,z,ux,uy,uz), through a temporary file. Throws bmr::Error naming the
 *  path when it cannot be written or the sizes differ. */
void
WriteSparseDisplacements(const std::string & csvPath, const SparseDisplacements & sparse);

/** Points measured on the displaced brain (e.g. electrode contacts on the
 *  shifted cortex) as sparse displacements: each point's reference position
 *  lies on the undeformed `referenceSurface`, its displacement is the point
 *  minus that position. Without `direction` the reference is the closest
 *  point of the surface (normal projection: motion along the surface is
 *  lost, as in the literature's electrode workflow; and a point that sank
 *  below the surface may find a sulcus' wall); with a direction (e.g.
 *  gravity's, along which the brain sinks) it is the first point of the
 *  surface that a ray along the direction meets, started 50 mm before the
 *  point (outside the brain): where the point was before it sank.
 *  Errors (bmr::Error): no points, a point that is not finite or whose ray
 *  misses the surface (naming it), a zero direction, and the surface's own
 *  errors (TriangleSurfaceTree). */
SparseDisplacements
ProjectOntoSurface(const std::vector<Vector3> & displacedPoints, const ContactSurface & referenceSurface,
                   const Vector3 * direction = nullptr);

/** Reads a CSV file with the header `x,y,z,ux,uy,uz` (mm; spaces around
 *  fields allowed), one point per line. Blank lines and lines starting with
 *  '#' are skipped. Errors (bmr::Error naming the path and the line number): a
 *  missing file, a wrong header, a row without exactly 6 fields, a field that
 *  is not a finite number, and a file with no rows. */
SparseDisplacements
ReadSparseDisplacements(const std::string & csvPath);

} // namespace bmr

#endif
