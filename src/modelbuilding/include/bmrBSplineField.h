// Cubic B-spline vector fields on a uniform control lattice, in ITK's
// BSplineTransform convention, fitted to scattered data by multilevel
// B-spline approximation (Lee, Wolberg and Shin 1997) and sampled on image
// grids. The ITK layer turns a lattice into an itk::BSplineTransform
// (itkDisplacementPointSetToBSplineTransformFilter.h) and back.
//
// Written in the core rather than taken from ITK's
// BSplineScatteredDataPointSetToImageFilter: that filter evaluates the spline
// at every data point after each level by collapsing the whole lattice per
// point, which took 5.7 s for one 4 mm level on 29,000 points on this
// project's 2-core machine, and it allocates its output image on every call;
// here a level costs O(points x 64). ITK's BSplineControlPointImageFilter
// samples only its own domain grid and evaluates kernels per voxel; the
// sampler here takes any grid of the lattice's direction and costs about 12
// multiply-adds per voxel (docs/transform-fitting.md has the numbers).
#ifndef bmrBSplineField_h
#define bmrBSplineField_h

#include "bmrImageVolume.h"

#include <array>
#include <vector>

namespace bmr
{

/** A cubic B-spline vector field (mm): control points on the grid
 *  `geometry` (size, spacing, origin = first control point, direction) with
 *  one vector each, x fastest. As in ITK's BSplineTransform, the field is
 *  defined where the continuous control index lies in [1, size - 2) along
 *  every axis and is zero elsewhere. */
struct CubicBSplineLattice
{
  ImageGeometry        geometry;
  std::vector<Vector3> coefficients;

  /** The field at a physical point (mm); zero outside the valid region. */
  Vector3 Evaluate(const Vector3 & point) const;
};

struct BSplineFitSettings
{
  double tolerance = 0.1;      // mm: levels stop once the largest residual is at most this
  double minimumSpacing = 1.0; // mm (a preoperative MRI voxel): no level with a finer control-point spacing along any axis
};

struct BSplineFitResult
{
  CubicBSplineLattice lattice;
  double              maximumResidual = 0.0; // mm, at the data points
  double              rmsResidual = 0.0;     // mm
  int                 levels = 0;
  std::array<int, 3>  meshSize{ 0, 0, 0 };   // spans per axis (control points - 3)
  Vector3             controlPointSpacing = Vector3::Zero(); // mm
  bool                toleranceReached = false;
};

/** Multilevel B-spline approximation of `values` given at `points` (mm) over
 *  the box spanned by the voxel centres of `domain` (its direction is the
 *  lattice's). The first mesh has one span along the domain's longest axis
 *  and about square spans along the others; each level doubles the mesh,
 *  approximates the residual of the levels before it and is added to them
 *  (the coarse lattice refined exactly onto the fine one). Levels are added
 *  until the largest residual is at most settings.tolerance or the next level
 *  would have a spacing below settings.minimumSpacing. Deterministic and
 *  sequential (a level costs O(points x 64)).
 *  Throws bmr::Error for a point outside the domain, a non-finite value, a
 *  domain with fewer than 2 voxels along an axis, or settings <= 0. */
BSplineFitResult
FitMultilevelBSpline(const std::vector<Vector3> & points,
                     const std::vector<Vector3> & values,
                     const ImageGeometry &        domain,
                     const BSplineFitSettings &   settings);

/** Samples the field at every voxel centre of `grid`, 3 values per voxel
 *  (buffer order, x fastest) into `out` (3 x grid.VoxelCount() doubles).
 *  The grid must have the lattice's direction (to 1e-6); throws bmr::Error
 *  otherwise. Voxels outside the valid region get zero. Deterministic for
 *  any thread count (0: OpenMP's default). */
void
SampleBSplineField(const CubicBSplineLattice & lattice, const ImageGeometry & grid, double * out, int threads = 0);

} // namespace bmr

#endif
