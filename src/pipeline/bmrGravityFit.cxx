// The gravity fit of an update (bmrRegistrationUpdate.h): the size of
// gravity after CSF loss chosen by the registered image's match with the
// intraoperative one (docs/registration.md, "Fitted gravity").
#include "bmrRegistrationUpdate.h"

#include "itkFixedWorkUnitsMattesMetric.h"

#include "bmrPipelineDetail.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <utility>
#include <vector>

namespace bmr
{
namespace
{

using SamplePointSet = itk::FixedWorkUnitsMattesMetric<RegistrationImage>::FixedSampledPointSetType;

/** The centres of the voxels of `image` inside `brain` (a mask on any grid):
 *  every second voxel along each axis, then evenly thinned to at most
 *  `largest`; the same samples score every candidate of a fit. */
SamplePointSet::Pointer
BrainSamplePoints(const RegistrationImage * image, const RegistrationLabelImage * brain, std::size_t largest = 50000)
{
  std::vector<RegistrationImage::PointType> inside;
  const auto                                size = image->GetLargestPossibleRegion().GetSize();
  const auto                                start = image->GetLargestPossibleRegion().GetIndex();
  RegistrationImage::IndexType              index;
  for (index[2] = start[2]; index[2] < start[2] + static_cast<long>(size[2]); index[2] += 2)
  {
    for (index[1] = start[1]; index[1] < start[1] + static_cast<long>(size[1]); index[1] += 2)
    {
      for (index[0] = start[0]; index[0] < start[0] + static_cast<long>(size[0]); index[0] += 2)
      {
        RegistrationImage::PointType point;
        image->TransformIndexToPhysicalPoint(index, point);
        RegistrationLabelImage::IndexType maskIndex;
        if (brain->TransformPhysicalPointToIndex(point, maskIndex) && brain->GetPixel(maskIndex) > 0)
        {
          inside.push_back(point);
        }
      }
    }
  }
  if (inside.empty())
  {
    throw Error("the gravity fit found no voxel of the intraoperative image inside the brain: give an "
                "intraoperative brain mask that overlaps the image");
  }
  auto         samples = SamplePointSet::New();
  const double step = std::max(1.0, static_cast<double>(inside.size()) / static_cast<double>(largest));
  std::size_t  count = 0;
  for (double position = 0.0; position < static_cast<double>(inside.size()); position += step)
  {
    samples->SetPoint(count++, inside[static_cast<std::size_t>(position)]);
  }
  return samples;
}

/** Mattes mutual information (32 bins, one work unit: the same for any
 *  thread count) between `fixed` at `samples` and `moving` at their images
 *  under `transform`; higher: a better match. */
double
MutualInformation(const RegistrationImage *      fixed,
                  const RegistrationImage *      moving,
                  const RegistrationTransform *  transform,
                  const SamplePointSet *         samples)
{
  auto metric = itk::FixedWorkUnitsMattesMetric<RegistrationImage>::New();
  metric->SetNumberOfHistogramBins(32);
  metric->SetFixedNumberOfWorkUnits(1);
  metric->SetUseMovingImageGradientFilter(false);
  metric->SetUseFixedImageGradientFilter(false);
  metric->SetFixedImage(fixed);
  metric->SetMovingImage(moving);
  metric->SetMovingTransform(const_cast<RegistrationTransform *>(transform));
  metric->SetFixedSampledPointSet(samples);
  metric->SetUseSampledPointSet(true);
  try
  {
    metric->Initialize();
    return -metric->GetValue();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error("the gravity fit could not compare the images: " + itk::PlainDescription(exception.GetDescription()));
  }
}

/** The next size towards the best of those tried (size, information): the
 *  vertex of the parabola through the best and its nearest neighbours each
 *  side (successive parabolic interpolation), or, when the best is at an end
 *  of the range, the midpoint between it and its neighbour (a coarse grid's
 *  best at 0 g may hide a better size below the next one). None when the
 *  neighbours leave no vertex between them (flat, or a failed neighbour) or
 *  the size is within `resolution` of one tried. */
std::optional<double>
NextGravitySize(std::vector<std::pair<double, double>> tried, double resolution)
{
  std::sort(tried.begin(), tried.end());
  const auto best = static_cast<std::size_t>(
    std::max_element(tried.begin(), tried.end(), [](const auto & a, const auto & b) { return a.second < b.second; }) -
    tried.begin());
  double next = 0.5 * (tried[best].first + tried[best == 0 ? 1 : best - 1].first);
  if (best > 0 && best + 1 < tried.size())
  {
    const auto [x0, y0] = tried[best - 1];
    const auto [x1, y1] = tried[best];
    const auto [x2, y2] = tried[best + 1];
    const double denominator = (x1 - x0) * (y1 - y2) - (x1 - x2) * (y1 - y0);
    next = x1 - 0.5 * ((x1 - x0) * (x1 - x0) * (y1 - y2) - (x1 - x2) * (x1 - x2) * (y1 - y0)) / denominator;
    if (!(next > x0 && next < x2))
    {
      return std::nullopt;
    }
  }
  const bool known =
    std::any_of(tried.begin(), tried.end(), [&](const auto & size) { return std::abs(size.first - next) < resolution; });
  return known ? std::nullopt : std::optional<double>(next);
}

} // namespace

GravityFitChoice
FitGravity(BrainShiftRegistrationResult &         result,
           const BrainShiftUpdateInputs &         inputs,
           const BrainShiftRegistrationSettings & settings,
           const UpdateFilters &                  filters)
{
  GravityFitChoice choice;
  const Vector3    largest = result.model.model.bodyAcceleration;
  // Every candidate's weight comes from the filter's gravity; zero: the model's own, here none.
  Model weightless = result.model.pipelineModel->GetModel();
  weightless.bodyAcceleration.setZero();
  auto weightlessModel = itk::BiomechanicalModelObject::New();
  weightlessModel->SetModel(std::move(weightless));
  weightlessModel->SetPrecomputation(result.model.pipelineModel->GetPrecomputation());
  const auto samples = BrainSamplePoints(inputs.intraoperative.image,
                                         inputs.intraoperative.imageBrainMask.IsNotNull()
                                           ? inputs.intraoperative.imageBrainMask.GetPointer()
                                           : itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(
                                               result.model.brainMask)
                                               .GetPointer());
  double     bestInformation = -std::numeric_limits<double>::infinity();
  double     bestSize = 0.0;
  // A size's solve starts from the steady state of the nearest size solved
  // so far when that weight is nearer its own than no weight is (else from
  // the update's own start). Measured on Colin27 10 mm (2026-12-06), the
  // 5-size fit and its refinements: from the nearest size always, 11 %
  // (5 mm hexahedra) and 10 % (7 mm tetrahedra) fewer steps than every
  // size from rest, but the first weighted size took 37-39 % more steps
  // from the weightless state than from rest; so that one starts from rest.
  std::vector<std::pair<double, WarmStart>> solvedStates;
  const auto evaluate = [&](double size) {
    auto candidate = filters.MakeDeformation(weightlessModel);
    const Vector3 gravity = size * largest.normalized();
    candidate->SetGravity(UpdateDeformation::VectorType(gravity.data()));
    const auto nearest = std::min_element(solvedStates.begin(), solvedStates.end(), [&](const auto & a, const auto & b) {
      return std::abs(a.first - size) < std::abs(b.first - size);
    });
    BrainShiftRegistrationResult::GravityFitSolve solve;
    if (nearest != solvedStates.end() && std::abs(nearest->first - size) < size)
    {
      candidate->SetWarmStart(nearest->second);
      solve.startSize = nearest->first;
    }
    try
    {
      UpdateStage(candidate.GetPointer(), "the solve failed");
    }
    catch (const Error & error)
    {
      // A weight under which the model folds is not the brain's: left out, and said.
      result.warnings.push_back("gravity fit: the solve at " + InG(size) + " failed and was left out (" +
                                error.what() + ")");
      result.gravityFit.emplace_back(size, -std::numeric_limits<double>::infinity());
      result.gravityFitSolves.push_back(solve);
      return;
    }
    if (!candidate->GetConverged())
    {
      result.warnings.push_back("gravity fit: the solve at " + InG(size) + " did not converge (" +
                                candidate->GetSolveResult().message + ")");
    }
    else
    {
      solvedStates.emplace_back(size, WarmStartFrom(candidate->GetSolveResult()));
    }
    const auto fitter = filters.FitTransform(candidate);
    const double information =
      MutualInformation(inputs.intraoperative.image, inputs.preoperativeImage, fitter->GetTransform(), samples);
    result.gravityFit.emplace_back(size, information);
    solve.steps = candidate->GetSolveResult().steps;
    result.gravityFitSolves.push_back(solve);
    if (information > bestInformation)
    {
      bestInformation = information;
      bestSize = size;
      choice.deformation = candidate;
      choice.fitter = fitter;
    }
  };
  const int count = settings.gravityFitCandidates;
  for (int k = 0; k < count; ++k)
  {
    evaluate(k * largest.norm() / (count - 1));
  }
  const double resolution = 0.01 * largest.norm(); // sizes nearer than this to a solved one teach nothing
  for (int refinement = 0; refinement < 3; ++refinement)
  {
    const std::optional<double> next = NextGravitySize(result.gravityFit, resolution);
    if (!next)
    {
      break;
    }
    evaluate(*next);
  }
  if (!std::isfinite(bestInformation))
  {
    throw Error("gravity fit: every size's solve failed (" + result.warnings.back() +
                "); give a smaller gravity or a finer mesh");
  }
  if (bestSize == largest.norm())
  {
    result.warnings.push_back("gravity fit: the best size is the largest tried (" + InG(largest.norm()) +
                              "); give a larger gravity to try larger sizes");
  }
  result.gravity = bestSize * largest.normalized();
  // The model the result reports is the one solved: with the fitted gravity.
  result.model.model.bodyAcceleration = result.gravity;
  Model solved = weightlessModel->GetModel();
  solved.bodyAcceleration = result.gravity;
  result.model.pipelineModel = itk::BiomechanicalModelObject::New();
  result.model.pipelineModel->SetModel(std::move(solved));
  result.model.pipelineModel->SetPrecomputation(weightlessModel->GetPrecomputation());
  return choice;
}

} // namespace bmr
