// How far a registration is from a known answer, in the field's terms: the
// displacement error against a ground-truth transform (over the brain or a
// region near a structure), and how far it puts a structure's surface (the
// tumour, the ventricles) from where the truth puts it. The demo, the
// validation study, the Python module and the tests measure with these.
//
// Units: mm.
#ifndef bmrRegistrationMetrics_h
#define bmrRegistrationMetrics_h

#include "bmrBrainShiftRegistration.h"

#include <vector>

namespace bmr
{

/** Displacement error |T(x) - T_truth(x)| (mm) of a backward map T (null: no
 *  registration, the identity) over the voxels of `region` (> 0), sampled
 *  on every `stride`-th voxel along each axis. */
struct DisplacementError
{
  double      mean = 0.0, p95 = 0.0, max = 0.0;
  std::size_t samples = 0;
};

DisplacementError
MeasureDisplacementError(const itk::Transform<double, 3, 3> * transform,
                         const itk::Transform<double, 3, 3> * truth,
                         const RegistrationLabelImage *       region,
                         int                                  stride = 2);

/** How well an uncertainty map bounds the true error: the fraction of the
 *  sampled voxels of `region` (as MeasureDisplacementError samples them)
 *  whose error |T(x) - T_truth(x)| lies within the map's value there (`bound`,
 *  mm, on the region's grid, e.g. bmr::BrainShiftUncertaintyResult's 95th
 *  percentile map): 0.95 for a calibrated 95 % bound; with the medians of
 *  the errors and of the bounds over the same voxels. */
struct UncertaintyCalibration
{
  double      fractionWithinBound = 0.0;
  double      medianError = 0.0, medianBound = 0.0; // mm
  std::size_t samples = 0;
};

UncertaintyCalibration
MeasureUncertaintyCalibration(const itk::Transform<double, 3, 3> * transform,
                              const itk::Transform<double, 3, 3> * truth,
                              const RegistrationLabelImage *       region,
                              const RegistrationImage *            bound,
                              int                                  stride = 2);

/** The voxels of `region` (e.g. the intraoperative brain on the preoperative
 *  grid) within `distance` mm of `structure` (a tumour or a resection cavity,
 *  voxels > 0, on the same grid): where the error near a tumour or a cavity
 *  is measured. Throws bmr::Error for masks on different grids, an empty
 *  structure, or no voxel of the region that near. */
RegistrationLabelImage::Pointer
RegionNear(const RegistrationLabelImage * structure, const RegistrationLabelImage * region, double distance);

/** The lateral ventricles of a T1 preoperative image, for their surface
 *  distance: the voxels of the CSF class (the darkest of three fuzzy c-means
 *  classes inside the brain mask, as the model's material mapping
 *  classifies) deeper than `depth` mm below the brain mask's surface, opened
 *  by 2 mm (the voxels more than 2 mm inside that fluid, their largest
 *  26-connected component, grown back by 2 mm within the fluid): the
 *  fissures and cisterns that touch the ventricles are thinner than 4 mm and
 *  fall away (on Colin27 the deep CSF is 64 mL, the ventricles 21 mL). On
 *  the image's grid. Throws bmr::Error for images on different grids, or no
 *  CSF that deep and wide. */
RegistrationLabelImage::Pointer
VentricleMask(const RegistrationImage * t1Image, const RegistrationLabelImage * brainMask, double depth = 10.0);

/** How far a registration puts a structure's surface from where the truth
 *  puts it (a symmetric 95th-percentile Hausdorff distance, mm).
 *
 *  The structure (voxels > 0, on the preoperative grid, e.g. the tumour or
 *  the ventricles) is warped by the truth's backward map once, at
 *  construction, and by each method's in Percentile95(), onto one
 *  axis-aligned grid of `spacing` mm (the image's own voxels, often
 *  anisotropic, would quantize the distances) over the structure's box and
 *  a margin of the truth's largest displacement there + 10 mm (grown by
 *  30 mm, and the measure repeated, for a map that reaches the grid's edge).
 *  The result is the 95th percentile of the distances from each warped
 *  mask's boundary voxels (a 6-neighbour outside) to the other's, both ways;
 *  distances between voxel centres, from ITK's Maurer map. Distances are
 *  therefore steps of the grid: 0, spacing, sqrt 2 spacing, ...
 *  Throws bmr::Error for an empty structure or a map that moves it more
 *  than 200 mm. */
class StructureSurfaceDistance
{
public:
  StructureSurfaceDistance(const itk::Transform<double, 3, 3> * truth,
                           const RegistrationLabelImage *       structure,
                           double                               spacing = 0.5);

  /** The 95th percentile for the backward map `transform` (null: no
   *  registration, the identity). */
  double
  Percentile95(const itk::Transform<double, 3, 3> * transform) const;

private:
  StructureSurfaceDistance(const itk::Transform<double, 3, 3> * truth,
                           const RegistrationLabelImage *       structure,
                           double                               spacing,
                           double                               margin);

  void
  Build();

  itk::Transform<double, 3, 3>::ConstPointer m_Truth;
  RegistrationLabelImage::ConstPointer       m_Structure;
  double                                     m_Spacing;
  double                                     m_Margin; // mm around the structure's box
  RegistrationLabelImage::Pointer            m_Grid;   // the truth's warped mask
  itk::Image<float, 3>::Pointer              m_TruthDistance;
  std::vector<itk::Index<3>>                 m_TruthBoundary;
};

} // namespace bmr

#endif
