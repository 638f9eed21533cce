// Registration error against a known answer (bmrRegistrationMetrics.h).
#include "bmrRegistrationMetrics.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalImageConversion.h"
#include "itkConnectedComponentImageFilter.h"
#include "itkFuzzyCMeansClassifierImageFilter.h"
#include "itkIdentityTransform.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkRelabelComponentImageFilter.h"
#include "itkSignedMaurerDistanceMapImageFilter.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace bmr
{
namespace
{

/** Signed Euclidean distance (mm) of every voxel centre to the boundary
 *  voxels of `mask` (> 0), negative inside: ITK's Maurer map. */
itk::Image<float, 3>::Pointer
SignedDistanceToMask(const RegistrationLabelImage * mask)
{
  auto map = itk::SignedMaurerDistanceMapImageFilter<RegistrationLabelImage, itk::Image<float, 3>>::New();
  map->SetInput(mask);
  map->SetBackgroundValue(0);
  map->SetUseImageSpacing(true);
  map->SetSquaredDistance(false);
  map->SetInsideIsPositive(false);
  map->Update();
  return map->GetOutput();
}

/** A mask on `grid`'s grid (size, spacing, origin, direction), its values not yet set. */
RegistrationLabelImage::Pointer
MaskOnGridOf(const RegistrationLabelImage * grid)
{
  auto mask = RegistrationLabelImage::New();
  mask->CopyInformation(grid);
  mask->SetRegions(grid->GetBufferedRegion());
  mask->Allocate();
  return mask;
}

/** The voxels of `mask` (> 0) with a 6-neighbour outside it or outside its grid. */
std::vector<itk::Index<3>>
BoundaryVoxels(const RegistrationLabelImage * mask)
{
  std::vector<itk::Index<3>> boundary;
  const auto                 region = mask->GetBufferedRegion();
  for (itk::ImageRegionConstIteratorWithIndex<RegistrationLabelImage> it(mask, region); !it.IsAtEnd(); ++it)
  {
    if (it.Get() == 0)
    {
      continue;
    }
    bool outside = false;
    for (unsigned int axis = 0; axis < 3 && !outside; ++axis)
    {
      for (const int step : { -1, 1 })
      {
        auto neighbour = it.GetIndex();
        neighbour[axis] += step;
        if (!region.IsInside(neighbour) || mask->GetPixel(neighbour) == 0)
        {
          outside = true;
          break;
        }
      }
    }
    if (outside)
    {
      boundary.push_back(it.GetIndex());
    }
  }
  return boundary;
}

/** The 95th percentile of `values` (not empty; the nearest rank, ceil(0.95 n)), which it reorders. */
double
NearestRankPercentile95(std::vector<double> & values)
{
  const auto rank = values.begin() + static_cast<std::ptrdiff_t>(std::ceil(0.95 * static_cast<double>(values.size()))) - 1;
  std::nth_element(values.begin(), rank, values.end());
  return *rank;
}

/** Whether `mask` has a voxel on the outermost layer of its grid (a structure cut off by it). */
bool
TouchesGridEdge(const RegistrationLabelImage * mask, const std::vector<itk::Index<3>> & boundary)
{
  const auto region = mask->GetBufferedRegion();
  for (const auto & index : boundary)
  {
    for (unsigned int axis = 0; axis < 3; ++axis)
    {
      if (index[axis] == region.GetIndex()[axis] ||
          index[axis] == region.GetIndex()[axis] + static_cast<itk::IndexValueType>(region.GetSize()[axis]) - 1)
      {
        return true;
      }
    }
  }
  return false;
}

// A margin this wide means the map moved the structure farther than any brain shift: a broken transform.
constexpr double kLargestSurfaceDistanceMargin = 200.0; // mm

} // namespace

RegistrationLabelImage::Pointer
RegionNear(const RegistrationLabelImage * structure, const RegistrationLabelImage * region, double distance)
{
  if (structure == nullptr || region == nullptr || !(distance >= 0.0))
  {
    throw Error("RegionNear: give the structure's mask, the region and a distance >= 0 mm");
  }
  const ImageGeometry grid = itk::MakeBiomechanicalGeometry(region);
  if (!itk::MakeBiomechanicalGeometry(structure).SameGridAs(grid))
  {
    throw Error("RegionNear: the structure's mask is not on the region's grid; resample it onto that grid");
  }
  const auto distanceMap = SignedDistanceToMask(structure);
  auto       near = MaskOnGridOf(region);
  const std::size_t voxels = region->GetBufferedRegion().GetNumberOfPixels();
  const float *     distances = distanceMap->GetBufferPointer();
  std::size_t       inside = 0, count = 0;
  for (std::size_t n = 0; n < voxels; ++n)
  {
    inside += structure->GetBufferPointer()[n] > 0;
    const bool take = region->GetBufferPointer()[n] > 0 && distances[n] <= distance;
    near->GetBufferPointer()[n] = take ? 1 : 0;
    count += take;
  }
  if (inside == 0 || count == 0)
  {
    throw Error(inside == 0 ? "RegionNear: the structure's mask has no voxel"
                            : "RegionNear: no voxel of the region lies within " + std::to_string(distance) +
                                " mm of the structure");
  }
  return near;
}

namespace
{

/** |T(x) - T_truth(x)| (mm) on every `stride`-th voxel of `region` (> 0) along each axis, with each voxel's index. */
std::vector<std::pair<double, RegistrationLabelImage::IndexType>>
SampledErrors(const itk::Transform<double, 3, 3> * transform, const itk::Transform<double, 3, 3> * truth,
              const RegistrationLabelImage * region, int stride, const char * who)
{
  if (truth == nullptr || region == nullptr || stride < 1)
  {
    throw Error(std::string(who) + ": give the ground-truth transform, the region and a stride >= 1");
  }
  const auto size = region->GetBufferedRegion().GetSize();
  const auto start = region->GetBufferedRegion().GetIndex();
  std::vector<std::pair<double, RegistrationLabelImage::IndexType>> errors;
  RegistrationLabelImage::IndexType index;
  for (index[2] = start[2]; index[2] < start[2] + static_cast<itk::IndexValueType>(size[2]); index[2] += stride)
  {
    for (index[1] = start[1]; index[1] < start[1] + static_cast<itk::IndexValueType>(size[1]); index[1] += stride)
    {
      for (index[0] = start[0]; index[0] < start[0] + static_cast<itk::IndexValueType>(size[0]); index[0] += stride)
      {
        if (region->GetPixel(index) == 0)
        {
          continue;
        }
        RegistrationLabelImage::PointType x;
        region->TransformIndexToPhysicalPoint(index, x);
        const auto expected = truth->TransformPoint(x);
        const auto estimate = transform != nullptr ? transform->TransformPoint(x) : x;
        errors.emplace_back(expected.EuclideanDistanceTo(estimate), index);
      }
    }
  }
  if (errors.empty())
  {
    throw Error(std::string(who) + ": the region has no voxel; give the brain mask of the intraoperative image");
  }
  return errors;
}

double
Median(std::vector<double> values)
{
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

} // namespace

DisplacementError
MeasureDisplacementError(const itk::Transform<double, 3, 3> * transform,
                         const itk::Transform<double, 3, 3> * truth,
                         const RegistrationLabelImage *       region,
                         int                                  stride)
{
  std::vector<double> errors;
  for (const auto & sample : SampledErrors(transform, truth, region, stride, "MeasureDisplacementError"))
  {
    errors.push_back(sample.first);
  }
  DisplacementError result;
  result.samples = errors.size();
  double sum = 0.0;
  for (const double error : errors)
  {
    sum += error;
  }
  result.mean = sum / static_cast<double>(errors.size());
  result.p95 = NearestRankPercentile95(errors);
  result.max = *std::max_element(errors.begin(), errors.end());
  return result;
}

UncertaintyCalibration
MeasureUncertaintyCalibration(const itk::Transform<double, 3, 3> * transform,
                              const itk::Transform<double, 3, 3> * truth,
                              const RegistrationLabelImage *       region,
                              const RegistrationImage *            bound,
                              int                                  stride)
{
  const char * who = "MeasureUncertaintyCalibration";
  if (bound == nullptr || region == nullptr ||
      !itk::MakeBiomechanicalGeometry(bound).SameGridAs(itk::MakeBiomechanicalGeometry(region)))
  {
    throw Error(std::string(who) + ": give the uncertainty map on the region's grid (the preoperative grid)");
  }
  std::vector<double> errors, bounds;
  std::size_t         within = 0;
  for (const auto & [error, index] : SampledErrors(transform, truth, region, stride, who))
  {
    const double limit = bound->GetPixel(index);
    errors.push_back(error);
    bounds.push_back(limit);
    within += error <= limit;
  }
  UncertaintyCalibration result;
  result.samples = errors.size();
  result.fractionWithinBound = static_cast<double>(within) / static_cast<double>(errors.size());
  result.medianError = Median(errors);
  result.medianBound = Median(bounds);
  return result;
}

RegistrationLabelImage::Pointer
VentricleMask(const RegistrationImage * t1Image, const RegistrationLabelImage * brainMask, double depth)
{
  if (t1Image == nullptr || brainMask == nullptr || !(depth >= 0.0))
  {
    throw Error("VentricleMask: give a T1 image, its brain mask and a depth >= 0 mm");
  }
  if (!itk::MakeBiomechanicalGeometry(t1Image).SameGridAs(itk::MakeBiomechanicalGeometry(brainMask)))
  {
    throw Error("VentricleMask: the brain mask is not on the image's grid; resample it onto that grid");
  }
  // The material mapping's classification: three classes on a T1 image, the darkest CSF.
  using Classifier = itk::FuzzyCMeansClassifierImageFilter<RegistrationImage, RegistrationLabelImage>;
  auto classifier = Classifier::New();
  classifier->SetInput(t1Image);
  classifier->SetMaskImage(brainMask);
  const FuzzyCMeansSettings modelClasses = BrainModelSettings{}.classifier;
  classifier->SetNumberOfClasses(static_cast<unsigned int>(modelClasses.classes));
  classifier->SetFuzziness(modelClasses.fuzziness);
  classifier->SetTolerance(modelClasses.tolerance);
  classifier->Update();
  const RegistrationLabelImage * classes = classifier->GetLabelOutput();
  const auto                     fromSurface = SignedDistanceToMask(brainMask); // negative inside

  auto deepFluid = MaskOnGridOf(brainMask);
  const std::size_t voxels = brainMask->GetBufferedRegion().GetNumberOfPixels();
  std::size_t       count = 0;
  for (std::size_t n = 0; n < voxels; ++n)
  {
    const bool take = classes->GetBufferPointer()[n] == 1 && fromSurface->GetBufferPointer()[n] < -depth;
    deepFluid->GetBufferPointer()[n] = take ? 1 : 0;
    count += take;
  }
  if (count == 0)
  {
    throw Error("VentricleMask: no voxel of the CSF class lies deeper than " + std::to_string(depth) +
                " mm in the brain; is the image a T1 (CSF dark) and the mask the whole brain?");
  }
  // An opening by kOpening (erosion, the largest component, dilation): the fissures and cisterns that touch
  // the ventricles are thinner than twice it and fall away; the ventricles' bodies are wider.
  constexpr double kOpening = 2.0; // mm
  auto             outside = MaskOnGridOf(deepFluid);
  for (std::size_t n = 0; n < voxels; ++n)
  {
    outside->GetBufferPointer()[n] = deepFluid->GetBufferPointer()[n] > 0 ? 0 : 1;
  }
  const auto fromOutside = SignedDistanceToMask(outside); // distance to the nearest voxel outside the fluid
  auto       core = MaskOnGridOf(deepFluid);
  std::size_t inCore = 0;
  for (std::size_t n = 0; n < voxels; ++n)
  {
    const bool take = fromOutside->GetBufferPointer()[n] > kOpening;
    core->GetBufferPointer()[n] = take ? 1 : 0;
    inCore += take;
  }
  if (inCore == 0)
  {
    throw Error("VentricleMask: the deep CSF is nowhere wider than " + std::to_string(2.0 * kOpening) +
                " mm; no ventricles to measure (is the image a T1 of a whole brain?)");
  }
  using ComponentImage = itk::Image<unsigned int, 3>;
  auto components = itk::ConnectedComponentImageFilter<RegistrationLabelImage, ComponentImage>::New();
  components->SetInput(core);
  components->FullyConnectedOn();
  auto bySize = itk::RelabelComponentImageFilter<ComponentImage, ComponentImage>::New(); // 1: the largest
  bySize->SetInput(components->GetOutput());
  bySize->Update();
  const ComponentImage * labels = bySize->GetOutput();
  for (std::size_t n = 0; n < voxels; ++n)
  {
    core->GetBufferPointer()[n] = labels->GetBufferPointer()[n] == 1 ? 1 : 0;
  }
  // Grown back within the fluid: the opened fluid, in place of the deep fluid.
  const auto fromCore = SignedDistanceToMask(core);
  for (std::size_t n = 0; n < voxels; ++n)
  {
    const bool take = deepFluid->GetBufferPointer()[n] > 0 && fromCore->GetBufferPointer()[n] <= kOpening;
    deepFluid->GetBufferPointer()[n] = take ? 1 : 0;
  }
  return deepFluid;
}

StructureSurfaceDistance::StructureSurfaceDistance(const itk::Transform<double, 3, 3> * truth,
                                                   const RegistrationLabelImage *       structure,
                                                   double                               spacing)
  : StructureSurfaceDistance(truth, structure, spacing, -1.0)
{}

StructureSurfaceDistance::StructureSurfaceDistance(const itk::Transform<double, 3, 3> * truth,
                                                   const RegistrationLabelImage *       structure,
                                                   double                               spacing,
                                                   double                               margin)
  : m_Truth(truth)
  , m_Structure(structure)
  , m_Spacing(spacing)
  , m_Margin(margin)
{
  if (truth == nullptr || structure == nullptr || !(spacing > 0.0))
  {
    throw Error("StructureSurfaceDistance: give the ground-truth transform, the structure's mask and a spacing > 0 mm");
  }
  Build();
}

void
StructureSurfaceDistance::Build()
{
  // The structure's box, and (first time) the truth's largest displacement of it for the margin.
  Vector3 low = Vector3::Constant(std::numeric_limits<double>::max());
  Vector3 high = Vector3::Constant(std::numeric_limits<double>::lowest());
  double  largestDisplacement = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<RegistrationLabelImage> it(m_Structure, m_Structure->GetBufferedRegion());
       !it.IsAtEnd(); ++it)
  {
    if (it.Get() == 0)
    {
      continue;
    }
    RegistrationLabelImage::PointType point;
    m_Structure->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    const Vector3 x(point[0], point[1], point[2]);
    low = low.cwiseMin(x);
    high = high.cwiseMax(x);
    if (m_Margin < 0.0)
    {
      largestDisplacement = std::max(largestDisplacement, point.EuclideanDistanceTo(m_Truth->TransformPoint(point)));
    }
  }
  if (!(low.x() <= high.x()))
  {
    throw Error("StructureSurfaceDistance: the structure's mask has no voxel");
  }
  if (m_Margin < 0.0)
  {
    // Where the truth takes the structure, and 10 mm more for a method that misses it.
    m_Margin = largestDisplacement + 10.0;
  }
  for (;;)
  {
    if (m_Margin > kLargestSurfaceDistanceMargin)
    {
      throw Error("StructureSurfaceDistance: the ground truth moves the structure more than " +
                  std::to_string(kLargestSurfaceDistanceMargin) + " mm; check the transform");
    }
    m_Grid = RegistrationLabelImage::New();
    RegistrationLabelImage::SizeType    size;
    RegistrationLabelImage::PointType   origin;
    RegistrationLabelImage::SpacingType voxel;
    for (unsigned int axis = 0; axis < 3; ++axis)
    {
      size[axis] = static_cast<itk::SizeValueType>(std::ceil((high[axis] - low[axis] + 2.0 * m_Margin) / m_Spacing)) + 1;
      origin[axis] = low[axis] - m_Margin;
      voxel[axis] = m_Spacing;
    }
    m_Grid->SetRegions(size);
    m_Grid->SetOrigin(origin);
    m_Grid->SetSpacing(voxel);
    m_Grid = WarpLabelImage(m_Structure, m_Truth, m_Grid);
    m_TruthBoundary = BoundaryVoxels(m_Grid);
    if (m_TruthBoundary.empty())
    {
      throw Error("StructureSurfaceDistance: the ground truth moves the structure off its grid; check the transform");
    }
    if (!TouchesGridEdge(m_Grid, m_TruthBoundary))
    {
      break;
    }
    m_Margin += 30.0;
  }
  m_TruthDistance = SignedDistanceToMask(m_Grid);
}

double
StructureSurfaceDistance::Percentile95(const itk::Transform<double, 3, 3> * transform) const
{
  const auto identity = itk::IdentityTransform<double, 3>::New();
  const auto mask = WarpLabelImage(m_Structure, transform != nullptr ? transform : identity.GetPointer(), m_Grid);
  const auto boundary = BoundaryVoxels(mask);
  if (boundary.empty() || TouchesGridEdge(mask, boundary))
  {
    // The map takes the structure off the grid: measure again on a wider one.
    if (m_Margin + 30.0 > kLargestSurfaceDistanceMargin)
    {
      throw Error("StructureSurfaceDistance: the map moves the structure more than " +
                  std::to_string(kLargestSurfaceDistanceMargin) + " mm from where the ground truth puts it");
    }
    return StructureSurfaceDistance(m_Truth, m_Structure, m_Spacing, m_Margin + 30.0).Percentile95(transform);
  }
  // Maurer's map measures to the other mask's boundary voxel centres: zero on them.
  const auto          toMethod = SignedDistanceToMask(mask);
  std::vector<double> distances;
  distances.reserve(boundary.size() + m_TruthBoundary.size());
  for (const auto & index : boundary)
  {
    distances.push_back(std::abs(m_TruthDistance->GetPixel(index)));
  }
  for (const auto & index : m_TruthBoundary)
  {
    distances.push_back(std::abs(toMethod->GetPixel(index)));
  }
  return NearestRankPercentile95(distances);
}

} // namespace bmr
