// B-spline intensity registration baseline (itk::BSplineIntensityRegistrationFilter
// and `biomech bspline-register`): ITK's example brain slices registered
// clearly better than unregistered (edge-based Hausdorff distance), a known
// smooth deformation recovered, bitwise repeatability, its building blocks
// (the fixed-work-unit metrics, the quiet L-BFGS-B optimizer) each on its
// own, and bad input named with nothing written.
//
// ITK headers first: ITK's bundled Eigen must come before the system Eigen.
// Over 800 lines: the tests of one filter and its command, which share their
// images.
#include "itkBSplineIntensityRegistrationFilter.h"
#include "itkBiomechanicalTransformIO.h"
#include "itkDisplacementFieldTransform.h"
#include "itkEdgeHausdorffDistanceImageFilter.h"
#include "itkFixedWorkUnitsCorrelationMetric.h"
#include "itkFixedWorkUnitsMattesMetric.h"
#include "itkIdentityTransform.h"
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"
#include "itkImageRegionConstIterator.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkMultiThreaderBase.h"
#include "itkQuietLBFGSBOptimizerv4.h"
#include "itkResampleImageFilter.h"
#include "itkTranslationTransform.h"

#include "bmrTemporaryFolderTest.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iostream>
#include <limits>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace
{

using SliceImage = itk::Image<float, 2>;
using RegistrationFilter = itk::BSplineIntensityRegistrationFilter<SliceImage>;
using PointType = SliceImage::PointType;
using bmr::test::CommandResult;

const fs::path    ExampleData("/usr/share/doc/insighttoolkit5-examples/examples/Data");
const std::string FixedSlice = "BrainProtonDensitySlice.png";
const std::string DeformedSlice = "BrainProtonDensitySliceBSplined10.png";
const std::string ShiftedSlice = "BrainProtonDensitySliceShifted13x17y.png";

bool
ExamplesAvailable()
{
  return fs::exists(ExampleData / FixedSlice) && fs::exists(ExampleData / DeformedSlice) &&
         fs::exists(ExampleData / ShiftedSlice);
}

SliceImage::Pointer
ReadSlice(const fs::path & path)
{
  auto reader = itk::ImageFileReader<SliceImage>::New();
  reader->SetFileName(path.string());
  reader->Update();
  return reader->GetOutput();
}

/** The message of the itk::ExceptionObject that `action` throws. */
std::string
ItkErrorMessage(const std::function<void()> & action)
{
  try
  {
    action();
  }
  catch (const itk::ExceptionObject & exception)
  {
    return exception.GetDescription();
  }
  return "(no itk::ExceptionObject thrown)";
}

/** `image` on the grid of `reference` without moving it (physical space as the files give it). */
SliceImage::Pointer
OnGridOf(const SliceImage * image, const SliceImage * reference)
{
  auto resample = itk::ResampleImageFilter<SliceImage, SliceImage>::New();
  resample->SetInput(image);
  resample->SetTransform(itk::IdentityTransform<double, 2>::New());
  resample->SetOutputParametersFromImage(reference);
  resample->Update();
  return resample->GetOutput();
}

double
MeanAbsoluteDifference(const SliceImage * a, const SliceImage * b)
{
  itk::ImageRegionConstIterator<SliceImage> itA(a, a->GetLargestPossibleRegion());
  itk::ImageRegionConstIterator<SliceImage> itB(b, b->GetLargestPossibleRegion());
  double                                    sum = 0.0;
  double                                    count = 0.0;
  for (; !itA.IsAtEnd(); ++itA, ++itB)
  {
    sum += std::abs(static_cast<double>(itA.Get()) - static_cast<double>(itB.Get()));
    count += 1.0;
  }
  return sum / count;
}

/** Edge-based Hausdorff evaluation of `image` against `fixed` (evaluator defaults: Canny variance 2 mm^2,
 *  automatic thresholds, 1.7 mm threshold). */
itk::EdgeHausdorffResult
EdgeDistances(const SliceImage * fixed, const SliceImage * image)
{
  auto evaluator = itk::EdgeHausdorffDistanceImageFilter<SliceImage>::New();
  evaluator->SetFixedImage(fixed);
  evaluator->SetMovingImage(image);
  evaluator->Update();
  return evaluator->GetResult();
}

/** The defaults, with the moments start the example slices need (their files share no physical space). */
RegistrationFilter::Pointer
MakeFilter(const SliceImage * fixed, const SliceImage * moving)
{
  auto filter = RegistrationFilter::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  filter->SetTranslationInitialization(RegistrationFilter::TranslationInitializationType::Moments);
  return filter;
}

std::vector<double>
Parameters(const RegistrationFilter * filter)
{
  const auto & parameters = filter->GetTransform()->GetParameters();
  return std::vector<double>(parameters.begin(), parameters.end());
}

struct SliceVerification
{
  double unregisteredP95 = 0.0;
  double registeredP95 = 0.0;
  double unregisteredWithin = 0.0;
  double registeredWithin = 0.0;
  double unregisteredDifference = 0.0;
  double registeredDifference = 0.0;
};

/** Registers `movingName` to the fixed slice and evaluates both the registered image and the
 *  unregistered one (the moving slice on the fixed grid as the files place it). */
SliceVerification
VerifySlicePair(const std::string & movingName, RegistrationFilter::Pointer * filterOut = nullptr)
{
  const auto fixed = ReadSlice(ExampleData / FixedSlice);
  const auto moving = ReadSlice(ExampleData / movingName);
  auto       filter = MakeFilter(fixed, moving);
  filter->Update();
  const auto unregistered = OnGridOf(moving, fixed);

  const itk::EdgeHausdorffResult before = EdgeDistances(fixed, unregistered);
  const itk::EdgeHausdorffResult after = EdgeDistances(fixed, filter->GetOutput());
  EXPECT_TRUE(before.valid) << before.message;
  EXPECT_TRUE(after.valid) << after.message;
  SliceVerification result;
  if (before.valid && after.valid)
  {
    result.unregisteredP95 = before.symmetric[94];
    result.registeredP95 = after.symmetric[94];
    result.unregisteredWithin = before.fractionWithinThreshold;
    result.registeredWithin = after.fractionWithinThreshold;
  }
  result.unregisteredDifference = MeanAbsoluteDifference(fixed, unregistered);
  result.registeredDifference = MeanAbsoluteDifference(fixed, filter->GetOutput());
  std::cout << movingName << ": symmetric 95th percentile " << result.unregisteredP95 << " -> " << result.registeredP95
            << " mm, fraction within 1.7 mm " << result.unregisteredWithin << " -> " << result.registeredWithin
            << ", mean |difference| " << result.unregisteredDifference << " -> " << result.registeredDifference << ", "
            << filter->GetElapsedSeconds() << " s\n";
  if (filterOut != nullptr)
  {
    *filterOut = filter;
  }
  return result;
}

/** A textured synthetic slice: 120 Gaussian blobs (radius 3-8 mm, amplitude
 *  -100 to 100 on a level of 128) from a fixed sequence, evaluated analytically
 *  at any point. Overlapping blobs spread the intensities over the range, which
 *  mutual information needs (a few bright blobs on a flat background leave
 *  most histogram bins empty). */
class BlobPattern
{
public:
  BlobPattern()
  {
    std::uint32_t state = 12345u;
    const auto    next = [&state] {
      state = state * 1664525u + 1013904223u;
      return static_cast<double>(state >> 8) / static_cast<double>(1u << 24);
    };
    for (int blob = 0; blob < 120; ++blob)
    {
      m_Blobs.push_back({ -4.0 + 136.0 * next(), -4.0 + 136.0 * next(), 3.0 + 5.0 * next(), -100.0 + 200.0 * next() });
    }
  }

  double
  operator()(double x, double y) const
  {
    double value = 128.0;
    for (const Blob & blob : m_Blobs)
    {
      const double r2 = (x - blob.x) * (x - blob.x) + (y - blob.y) * (y - blob.y);
      value += blob.amplitude * std::exp(-r2 / (2.0 * blob.radius * blob.radius));
    }
    return value;
  }

private:
  struct Blob
  {
    double x, y, radius, amplitude;
  };
  std::vector<Blob> m_Blobs;
};

/** The known smooth displacement (mm): up to 3 mm, one period over the 128 mm slice. */
itk::Vector<double, 2>
KnownDisplacement(const PointType & point)
{
  const double           pi = 3.14159265358979323846;
  itk::Vector<double, 2> u;
  u[0] = 3.0 * std::sin(pi * point[0] / 128.0) * std::sin(pi * point[1] / 128.0);
  u[1] = 2.0 * std::sin(2.0 * pi * point[0] / 128.0) * std::sin(pi * point[1] / 128.0);
  return u;
}

/** A 128 x 128 slice of 1 mm pixels sampled from the pattern at x + displacement(x). */
SliceImage::Pointer
SampledPattern(const BlobPattern & pattern, bool displaced)
{
  auto                   image = SliceImage::New();
  SliceImage::RegionType region;
  region.SetSize({ { 128, 128 } });
  image->SetRegions(region);
  image->Allocate();
  for (itk::ImageRegionIteratorWithIndex<SliceImage> it(image, region); !it.IsAtEnd(); ++it)
  {
    PointType point;
    image->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    const itk::Vector<double, 2> u = displaced ? KnownDisplacement(point) : itk::Vector<double, 2>(0.0);
    it.Set(static_cast<float>(pattern(point[0] + u[0], point[1] + u[1])));
  }
  return image;
}

SliceImage::Pointer
ConstantSlice(float value)
{
  auto                   image = SliceImage::New();
  SliceImage::RegionType region;
  region.SetSize({ { 64, 64 } });
  image->SetRegions(region);
  image->Allocate();
  image->FillBuffer(value);
  return image;
}

template <typename TImage>
void
WriteTestImage(const TImage * image, const fs::path & path)
{
  auto writer = itk::ImageFileWriter<TImage>::New();
  writer->SetInput(image);
  writer->SetFileName(path.string());
  writer->Update();
}

std::string
Quoted(const fs::path & path)
{
  return "'" + path.string() + "'";
}

} // namespace

// ---------------------------------------------------------------------------
// The verification on ITK's example slices.
// ---------------------------------------------------------------------------

TEST(BSplineIntensityRegistrationSlices, BSplined10RegisteredClearlyBetterThanUnregistered)
{
  if (!ExamplesAvailable())
  {
    GTEST_SKIP() << "insighttoolkit5-examples not installed";
  }
  const SliceVerification result = VerifySlicePair(DeformedSlice);
  // The moving file's 20-pixel border plus the deformation: about 20 mm apart unregistered.
  EXPECT_GT(result.unregisteredP95, 10.0);
  EXPECT_LT(result.registeredP95, 0.25 * result.unregisteredP95);
  EXPECT_GT(result.registeredWithin, result.unregisteredWithin + 0.4);
  EXPECT_GT(result.registeredWithin, 0.8);
  EXPECT_LT(result.registeredDifference, 0.2 * result.unregisteredDifference);
}

TEST(BSplineIntensityRegistrationSlices, Shifted13x17yRegisteredClearlyBetterAndShiftRecovered)
{
  if (!ExamplesAvailable())
  {
    GTEST_SKIP() << "insighttoolkit5-examples not installed";
  }
  RegistrationFilter::Pointer filter;
  const SliceVerification     result = VerifySlicePair(ShiftedSlice, &filter);
  EXPECT_GT(result.unregisteredP95, 10.0);
  EXPECT_LT(result.registeredP95, 0.25 * result.unregisteredP95);
  EXPECT_LT(result.registeredP95, 2.0);
  EXPECT_GT(result.registeredWithin, result.unregisteredWithin + 0.5);
  EXPECT_GT(result.registeredWithin, 0.9);
  EXPECT_LT(result.registeredDifference, 0.1 * result.unregisteredDifference);

  // The truth is a translation: the file's 20-pixel border plus 13 x 17 pixels (1 mm spacing).
  const SliceImage * fixed = filter->GetFixedImage();
  double             largestError = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<SliceImage> it(fixed, fixed->GetLargestPossibleRegion()); !it.IsAtEnd();
       ++it)
  {
    if (it.GetIndex()[0] % 10 != 0 || it.GetIndex()[1] % 10 != 0 || it.Get() < 30.0f)
    {
      continue; // every 10th pixel, inside the head
    }
    PointType point;
    fixed->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    const PointType mapped = filter->GetTransform()->TransformPoint(point);
    largestError =
      std::max({ largestError, std::abs(mapped[0] - point[0] - 33.0), std::abs(mapped[1] - point[1] - 37.0) });
  }
  EXPECT_LT(largestError, 0.5) << "largest error of the recovered 33 x 37 mm translation inside the head";
}

// ---------------------------------------------------------------------------
// A known smooth deformation, recovered.
// ---------------------------------------------------------------------------

namespace
{

/** Error of the registration's transform against the known displacement (or
 *  the identity) at interior points 12-116 mm, 4 mm apart: {RMS, largest}. */
std::pair<double, double>
DisplacementError(const RegistrationFilter * filter, bool displaced)
{
  double largestError = 0.0;
  double squaredErrorSum = 0.0;
  int    count = 0;
  for (double x = 12.0; x <= 116.0; x += 4.0)
  {
    for (double y = 12.0; y <= 116.0; y += 4.0)
    {
      PointType point;
      point[0] = x;
      point[1] = y;
      const itk::Vector<double, 2> truth = displaced ? KnownDisplacement(point) : itk::Vector<double, 2>(0.0);
      const double                 error = ((filter->GetTransform()->TransformPoint(point) - point) - truth).GetNorm();
      largestError = std::max(largestError, error);
      squaredErrorSum += error * error;
      ++count;
    }
  }
  return { std::sqrt(squaredErrorSum / count), largestError };
}

RegistrationFilter::Pointer
RegisterPattern(bool displaced, RegistrationFilter::MetricType metric)
{
  const BlobPattern pattern;
  // fixed(x) = moving(x + u(x)): the resampling transform to find is x -> x + u(x).
  auto filter = RegistrationFilter::New();
  filter->SetFixedImage(SampledPattern(pattern, displaced));
  filter->SetMovingImage(SampledPattern(pattern, false));
  filter->SetMetric(metric);
  filter->Update();
  return filter;
}

} // namespace

TEST(BSplineIntensityRegistrationSynthetic, KnownSmoothDisplacementRecoveredWithMutualInformation)
{
  const auto filter = RegisterPattern(true, RegistrationFilter::MetricType::MattesMutualInformation);
  const auto [rms, largest] = DisplacementError(filter, true);
  std::cout << "Mattes, known displacement (up to 3.1 mm): error RMS " << rms << " mm, largest " << largest << " mm, "
            << filter->GetElapsedSeconds() << " s\n";
  EXPECT_LT(rms, 0.2);
  EXPECT_LT(largest, 0.5);
}

TEST(BSplineIntensityRegistrationSynthetic, KnownSmoothDisplacementRecoveredWithCorrelation)
{
  const auto filter = RegisterPattern(true, RegistrationFilter::MetricType::Correlation);
  const auto [rms, largest] = DisplacementError(filter, true);
  std::cout << "Correlation, known displacement (up to 3.1 mm): error RMS " << rms << " mm, largest " << largest
            << " mm, " << filter->GetElapsedSeconds() << " s\n";
  EXPECT_LT(rms, 0.1);
  EXPECT_LT(largest, 0.3);
  EXPECT_LT(filter->GetFinalMetricValue(), -0.99); // -r^2 of a nearly perfect match
}

TEST(BSplineIntensityRegistrationSynthetic, IdenticalImagesStayNearTheIdentity)
{
  // Correlation's derivative vanishes exactly at the identity; mutual information's
  // Parzen-window estimate drifts a little (sub-voxel) on a sampled histogram.
  const auto correlation = RegisterPattern(false, RegistrationFilter::MetricType::Correlation);
  EXPECT_LT(DisplacementError(correlation, false).second, 1e-3);
  const auto mattes = RegisterPattern(false, RegistrationFilter::MetricType::MattesMutualInformation);
  EXPECT_LT(DisplacementError(mattes, false).second, 0.5);
  EXPECT_LT(MeanAbsoluteDifference(mattes->GetFixedImage(), mattes->GetOutput()), 1.0);
}

// ---------------------------------------------------------------------------
// Results, progress and repeatability.
// ---------------------------------------------------------------------------

TEST(BSplineIntensityRegistrationResults, MeshIterationsTimesAndProgressAreReported)
{
  const BlobPattern pattern;
  const auto        fixed = SampledPattern(pattern, true);
  const auto        moving = SampledPattern(pattern, false);
  auto              filter = RegistrationFilter::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  filter->SetNumberOfIterations({ 12, 8, 4 });
  std::vector<float> progress;
  filter->AddObserver(itk::ProgressEvent(),
                      [&](const itk::EventObject &) { progress.push_back(filter->GetProgress()); });
  filter->Update();

  // Default budget: 100 halved per level, at least 10.
  auto defaults = RegistrationFilter::New();
  EXPECT_EQ(defaults->IterationsAtLevel(0), 100u);
  EXPECT_EQ(defaults->IterationsAtLevel(1), 50u);
  EXPECT_EQ(defaults->IterationsAtLevel(2), 25u);
  EXPECT_EQ(defaults->IterationsAtLevel(3), 13u);
  EXPECT_EQ(defaults->IterationsAtLevel(5), 10u);

  // 127 mm extent / 20 mm -> 6 cells, halved per coarser level.
  ASSERT_EQ(filter->GetMeshSizesPerLevel().size(), 3u);
  EXPECT_EQ(filter->GetMeshSizesPerLevel()[0][0], 2u);
  EXPECT_EQ(filter->GetMeshSizesPerLevel()[1][0], 3u);
  EXPECT_EQ(filter->GetMeshSizesPerLevel()[2][0], 6u);
  EXPECT_EQ(filter->GetTransform()->GetNumberOfParameters(), 2u * 9u * 9u);
  ASSERT_EQ(filter->GetIterationsPerLevel().size(), 3u);
  const unsigned int budget[3] = { 12, 8, 4 };
  for (unsigned int level = 0; level < 3; ++level)
  {
    EXPECT_GE(filter->GetIterationsPerLevel()[level], 1u);
    EXPECT_LE(filter->GetIterationsPerLevel()[level], budget[level]);
  }
  EXPECT_EQ(filter->GetIterationsRun(),
            filter->GetIterationsPerLevel()[0] + filter->GetIterationsPerLevel()[1] +
              filter->GetIterationsPerLevel()[2]);
  EXPECT_GT(filter->GetTranslationIterationsRun(), 0u);
  EXPECT_GT(filter->GetElapsedSeconds(), 0.0);
  EXPECT_GT(filter->GetWarpElapsedSeconds(), 0.0);
  EXPECT_LT(filter->GetFinalMetricValue(), 0.0); // negative mutual information
  // Progress per optimizer iteration: more reports than levels, never decreasing, ending at 1.
  ASSERT_GT(progress.size(), filter->GetIterationsRun());
  for (std::size_t k = 1; k < progress.size(); ++k)
  {
    EXPECT_GE(progress[k], progress[k - 1]);
  }
  EXPECT_FLOAT_EQ(progress.back(), 1.0f);
  // The output lies on the fixed grid.
  EXPECT_EQ(filter->GetOutput()->GetLargestPossibleRegion(), fixed->GetLargestPossibleRegion());
}

TEST(BSplineIntensityRegistrationResults, RepeatsBitwiseAcrossRunsAndThreadCounts)
{
  if (!ExamplesAvailable())
  {
    GTEST_SKIP() << "insighttoolkit5-examples not installed";
  }
  const auto fixed = ReadSlice(ExampleData / FixedSlice);
  const auto moving = ReadSlice(ExampleData / DeformedSlice);
  const auto run = [&](itk::ThreadIdType threads, RegistrationFilter::MetricType metric) {
    const itk::ThreadIdType saved = itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads();
    itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(threads);
    auto filter = MakeFilter(fixed, moving);
    filter->SetMetric(metric);
    filter->SetNumberOfIterations({ 20, 10, 5 });
    filter->Update();
    itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(saved);
    return Parameters(filter);
  };
  for (const auto metric :
       { RegistrationFilter::MetricType::MattesMutualInformation, RegistrationFilter::MetricType::Correlation })
  {
    const std::vector<double> first = run(2, metric);
    const std::vector<double> second = run(2, metric);
    const std::vector<double> oneThread = run(1, metric);
    ASSERT_EQ(first.size(), second.size());
    EXPECT_TRUE(first == second) << "two runs differ";
    EXPECT_TRUE(first == oneThread) << "1 and 2 threads differ";
    // Not trivially equal: the registration moved the coefficients.
    EXPECT_GT(std::abs(first[0]), 1.0);
  }
}

// ---------------------------------------------------------------------------
// The filter's building blocks (include/itkFixedWorkUnits*Metric.h,
// include/itkQuietLBFGSBOptimizerv4.h), each on its own.
// ---------------------------------------------------------------------------

namespace
{

using Translation = itk::TranslationTransform<double, 2>;

/** The metric's value and derivative at a translation of the blob pattern,
 *  made and evaluated with `threads` as ITK's global thread count. */
template <typename TMetric>
std::pair<double, std::vector<double>>
ValueAndDerivative(itk::ThreadIdType threads)
{
  const itk::ThreadIdType saved = itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads();
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(threads);
  const BlobPattern pattern;
  auto              transform = Translation::New();
  Translation::ParametersType offset(2);
  offset[0] = 0.7;
  offset[1] = -0.4;
  transform->SetParameters(offset);
  auto metric = TMetric::New();
  metric->SetFixedImage(SampledPattern(pattern, true));
  metric->SetMovingImage(SampledPattern(pattern, false));
  metric->SetMovingTransform(transform);
  metric->SetFixedNumberOfWorkUnits(1);
  metric->Initialize();
  typename TMetric::MeasureType    value = 0.0;
  typename TMetric::DerivativeType derivative;
  metric->GetValueAndDerivative(value, derivative);
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(saved);
  return { value, std::vector<double>(derivative.begin(), derivative.end()) };
}

template <typename TMetric>
void
ExpectThreadCountIndependent()
{
  const auto one = ValueAndDerivative<TMetric>(1);
  const auto four = ValueAndDerivative<TMetric>(4);
  EXPECT_TRUE(std::isfinite(one.first));
  ASSERT_EQ(one.second.size(), 2u);
  EXPECT_GT(std::abs(one.second[0]) + std::abs(one.second[1]), 0.0) << "a translated pattern has a gradient";
  EXPECT_EQ(one.first, four.first) << "the value depends on the thread count";
  EXPECT_TRUE(one.second == four.second) << "the derivative depends on the thread count";
}

} // namespace

TEST(FixedWorkUnitsMattesMetric, ValueAndDerivativeDoNotDependOnTheThreadCount)
{
  ExpectThreadCountIndependent<itk::FixedWorkUnitsMattesMetric<SliceImage>>();
}

TEST(FixedWorkUnitsCorrelationMetric, ValueAndDerivativeDoNotDependOnTheThreadCount)
{
  ExpectThreadCountIndependent<itk::FixedWorkUnitsCorrelationMetric<SliceImage>>();
}

TEST(QuietLBFGSBOptimizerv4, StartsFromTheCurrentParametersUnboundedAndImproves)
{
  // Each start takes the metric's current parameters (LBFGSBOptimizerv4 keeps
  // its first start while the parameter count does not grow), with an
  // unbounded problem sized to them, and lowers the metric.
  const BlobPattern pattern;
  auto              transform = Translation::New();
  auto              metric = itk::FixedWorkUnitsCorrelationMetric<SliceImage>::New();
  metric->SetFixedImage(SampledPattern(pattern, false));
  metric->SetMovingImage(SampledPattern(pattern, false));
  metric->SetMovingTransform(transform);
  metric->SetFixedNumberOfWorkUnits(1);
  metric->Initialize();
  auto optimizer = itk::QuietLBFGSBOptimizerv4::New();
  optimizer->SetMetric(metric);
  optimizer->SetNumberOfIterations(20);
  for (const double start : { 1.5, -2.0 })
  {
    Translation::ParametersType offset(2);
    offset[0] = start;
    offset[1] = 0.5 * start;
    transform->SetParameters(offset);
    const double before = metric->GetValue();
    optimizer->StartOptimization();
    EXPECT_EQ(optimizer->GetInitialPosition()[0], start);
    EXPECT_EQ(optimizer->GetInitialPosition()[1], 0.5 * start);
    EXPECT_EQ(optimizer->GetBoundSelection().size(), 2u);
    EXPECT_LT(metric->GetValue(), before) << "start " << start;
    EXPECT_LT(std::abs(transform->GetParameters()[0]), std::abs(start)) << "towards the identity from " << start;
  }
}

// ---------------------------------------------------------------------------
// Bad input: clear exceptions.
// ---------------------------------------------------------------------------

TEST(BSplineIntensityRegistrationErrors, MissingImages)
{
  const BlobPattern pattern;
  const auto        image = SampledPattern(pattern, false);
  auto              noMoving = RegistrationFilter::New();
  noMoving->SetFixedImage(image);
  EXPECT_CONTAINS(ItkErrorMessage([&] { noMoving->Update(); }), "the moving image is not set");
  auto noFixed = RegistrationFilter::New();
  noFixed->SetMovingImage(image);
  EXPECT_CONTAINS(ItkErrorMessage([&] { noFixed->Update(); }), "the fixed image is not set");
}

TEST(BSplineIntensityRegistrationErrors, ConstantOrNaNImages)
{
  const BlobPattern pattern;
  const auto        image = SampledPattern(pattern, false);
  const auto        constant = ConstantSlice(7.0f);
  auto              constantMoving = RegistrationFilter::New();
  constantMoving->SetFixedImage(image);
  constantMoving->SetMovingImage(constant);
  EXPECT_CONTAINS(ItkErrorMessage([&] { constantMoving->Update(); }), "the moving image is constant");

  auto withNaN = SampledPattern(pattern, false);
  withNaN->SetPixel({ { 5, 9 } }, std::numeric_limits<float>::quiet_NaN());
  auto nanFixed = RegistrationFilter::New();
  nanFixed->SetFixedImage(withNaN);
  nanFixed->SetMovingImage(image);
  const std::string message = ItkErrorMessage([&] { nanFixed->Update(); });
  EXPECT_CONTAINS(message, "the fixed image contains 1 NaN or infinite voxel(s)");
  EXPECT_CONTAINS(message, "[5, 9]");
}

TEST(BSplineIntensityRegistrationErrors, EmptyOrMisplacedMask)
{
  const BlobPattern pattern;
  const auto        image = SampledPattern(pattern, false);
  using MaskImage = RegistrationFilter::MaskImageType;
  auto mask = MaskImage::New();
  mask->CopyInformation(image);
  mask->SetRegions(image->GetLargestPossibleRegion());
  mask->Allocate();
  mask->FillBuffer(0);
  auto filter = RegistrationFilter::New();
  filter->SetFixedImage(image);
  filter->SetMovingImage(image);
  filter->SetFixedMask(mask);
  EXPECT_CONTAINS(ItkErrorMessage([&] { filter->Update(); }), "the fixed mask is empty");

  mask->FillBuffer(1);
  const double farAway[2] = { 1000.0, 1000.0 };
  mask->SetOrigin(farAway);
  filter->Modified();
  EXPECT_CONTAINS(ItkErrorMessage([&] { filter->Update(); }), "lies inside the fixed image");
}

TEST(BSplineIntensityRegistrationErrors, InvalidParameters)
{
  const BlobPattern pattern;
  const auto        image = SampledPattern(pattern, false);
  const auto        failure = [&](const std::function<void(RegistrationFilter *)> & configure) {
    auto filter = RegistrationFilter::New();
    filter->SetFixedImage(image);
    filter->SetMovingImage(image);
    configure(filter);
    return ItkErrorMessage([&] { filter->Update(); });
  };
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) { f->SetControlPointSpacing(0.0); }),
                  "ControlPointSpacing must be a positive number of mm, got 0");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) { f->SetControlPointSpacing(-5.0); }), "got -5");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) {
                    f->SetSmoothingSigmas({ 2.0, 1.0 });
                  }),
                  "ShrinkFactors has 3 levels but SmoothingSigmas has 2");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) { f->SetShrinkFactors({}); }), "ShrinkFactors is empty");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) { f->SetShrinkFactors({ 4, 0, 1 }); }), "at least 1");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) { f->SetSmoothingSigmas({ 2.0, -1.0, 0.0 }); }), ">= 0 mm");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) {
                    f->SetNumberOfIterations({ 10, 10 });
                  }),
                  "NumberOfIterations has 2 values for 3 levels");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) { f->SetMetricSamplingPercentage(1.5); }), "(0, 1]");
  EXPECT_CONTAINS(failure([](RegistrationFilter * f) { f->SetNumberOfHistogramBins(2); }), "at least 5");
}

TEST(BSplineIntensityRegistrationErrors, ImagesThatDoNotOverlapFailWithTheLevel)
{
  const BlobPattern pattern;
  const auto        fixed = SampledPattern(pattern, false);
  auto              moving = SampledPattern(pattern, false);
  const double      farAway[2] = { 5000.0, -5000.0 };
  moving->SetOrigin(farAway);
  auto filter = RegistrationFilter::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  filter->SetUseTranslationStage(false);
  const std::string message = ItkErrorMessage([&] { filter->Update(); });
  EXPECT_CONTAINS(message, "the registration failed at level 1 of 3");
  EXPECT_CONTAINS(message, "overlap in physical space");
}

// ---------------------------------------------------------------------------
// biomech bspline-register
// ---------------------------------------------------------------------------

class BSplineRegisterCommand : public bmr::test::TemporaryFolderTest
{};

TEST_F(BSplineRegisterCommand, SlicePairWritesWarpedImageTransformAndReport)
{
  if (!ExamplesAvailable())
  {
    GTEST_SKIP() << "insighttoolkit5-examples not installed";
  }
  const fs::path      warped = m_Folder / "out" / "warped.png";
  const fs::path      transformPath = m_Folder / "out" / "transform.h5";
  const fs::path      reportPath = m_Folder / "out" / "report.json";
  const CommandResult result = bmr::test::RunBiomech(
    m_Folder,
    "bspline-register " + Quoted(ExampleData / FixedSlice) + " " + Quoted(ExampleData / ShiftedSlice) + " -o " +
      Quoted(warped) + " --transform " + Quoted(transformPath) + " --report " + Quoted(reportPath) +
      " --initialize moments --iterations 20 10 5 --threads 2");
  ASSERT_EQ(result.exitCode, 0) << result.err;
  ASSERT_TRUE(fs::exists(warped));
  ASSERT_TRUE(fs::exists(transformPath));
  ASSERT_TRUE(fs::exists(reportPath));
  EXPECT_CONTAINS(result.out, "translation");

  // The same registration in this process.
  const auto fixed = ReadSlice(ExampleData / FixedSlice);
  auto       filter = MakeFilter(fixed, ReadSlice(ExampleData / ShiftedSlice));
  filter->SetNumberOfIterations({ 20, 10, 5 });
  filter->Update();

  // The transform read back maps points exactly as the filter's does.
  const auto read = itk::ReadBiomechanicalTransform(transformPath.string());
  ASSERT_STREQ(read->GetNameOfClass(), "BSplineTransform");
  const auto * readBack = dynamic_cast<const itk::Transform<double, 2, 2> *>(read.GetPointer());
  ASSERT_NE(readBack, nullptr);
  double largestDifference = 0.0;
  for (double x = -10.0; x <= 190.0; x += 7.0)
  {
    for (double y = -10.0; y <= 225.0; y += 7.0)
    {
      PointType point;
      point[0] = x;
      point[1] = y;
      largestDifference = std::max(
        largestDifference, (readBack->TransformPoint(point) - filter->GetTransform()->TransformPoint(point)).GetNorm());
    }
  }
  EXPECT_EQ(largestDifference, 0.0);

  // The warped PNG is the filter's output rounded to the moving image's 8 bits.
  auto reader = itk::ImageFileReader<itk::Image<unsigned char, 2>>::New();
  reader->SetFileName(warped.string());
  reader->Update();
  const auto * written = reader->GetOutput();
  EXPECT_EQ(written->GetLargestPossibleRegion(), fixed->GetLargestPossibleRegion());
  itk::ImageRegionConstIterator<itk::Image<unsigned char, 2>> itWritten(written, written->GetLargestPossibleRegion());
  itk::ImageRegionConstIterator<SliceImage>                   itFilter(filter->GetOutput(),
                                                     filter->GetOutput()->GetLargestPossibleRegion());
  double                                                      largestPixelDifference = 0.0;
  for (; !itWritten.IsAtEnd(); ++itWritten, ++itFilter)
  {
    const double expected = std::clamp(std::round(static_cast<double>(itFilter.Get())), 0.0, 255.0);
    largestPixelDifference = std::max(largestPixelDifference, std::abs(itWritten.Get() - expected));
  }
  EXPECT_EQ(largestPixelDifference, 0.0);

  const json report = json::parse(bmr::test::ReadText(reportPath));
  EXPECT_EQ(report["dimension"], 2);
  EXPECT_EQ(report["warped_pixel_type"], "uint8");
  EXPECT_EQ(report["parameters"]["metric"], "mattes");
  EXPECT_EQ(report["parameters"]["control_point_spacing_mm"], 20.0);
  EXPECT_EQ(report["parameters"]["max_iterations_per_level"], json({ 20, 10, 5 }));
  EXPECT_EQ(report["parameters"]["threads"], 2);
  EXPECT_EQ(report["mesh_sizes"], json({ { 2, 3 }, { 5, 6 }, { 9, 11 } }));
  EXPECT_DOUBLE_EQ(report["final_metric"].get<double>(), filter->GetFinalMetricValue());
  EXPECT_EQ(report["iterations"]["total"], filter->GetIterationsRun());
  EXPECT_NEAR(report["initial_translation_mm"][0].get<double>(), 33.0, 0.5);
  EXPECT_NEAR(report["initial_translation_mm"][1].get<double>(), 37.0, 0.5);
  EXPECT_GT(report["registration_seconds"].get<double>(), 0.0);
  EXPECT_GT(report["warp_seconds"].get<double>(), 0.0);
  EXPECT_TRUE(report["seconds"].contains("total"));
}

TEST_F(BSplineRegisterCommand, DifferentDimensionsFailWithNothingWritten)
{
  if (!ExamplesAvailable())
  {
    GTEST_SKIP() << "insighttoolkit5-examples not installed";
  }
  auto                             volume = itk::Image<float, 3>::New();
  itk::Image<float, 3>::RegionType region;
  region.SetSize({ { 8, 8, 8 } });
  volume->SetRegions(region);
  volume->Allocate();
  volume->FillBuffer(1.0f);
  WriteTestImage(volume.GetPointer(), m_Folder / "volume.nii.gz");
  const fs::path      warped = m_Folder / "warped.nii.gz";
  const CommandResult result = bmr::test::RunBiomech(m_Folder,
                                                     "bspline-register " + Quoted(ExampleData / FixedSlice) + " " +
                                                       Quoted(m_Folder / "volume.nii.gz") + " -o " + Quoted(warped) +
                                                       " --report " + Quoted(m_Folder / "report.json"));
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_CONTAINS(result.err, "biomech: error: the fixed image");
  EXPECT_CONTAINS(result.err, "is 2D but the moving image");
  EXPECT_CONTAINS(result.err, "is 3D");
  EXPECT_FALSE(fs::exists(warped));
  EXPECT_FALSE(fs::exists(m_Folder / "report.json"));
}

TEST_F(BSplineRegisterCommand, ConstantImageFailsWithNothingWritten)
{
  const BlobPattern pattern;
  WriteTestImage(SampledPattern(pattern, false).GetPointer(), m_Folder / "fixed.mha");
  WriteTestImage(ConstantSlice(3.0f).GetPointer(), m_Folder / "moving.mha");
  const fs::path      warped = m_Folder / "warped.mha";
  const fs::path      transformPath = m_Folder / "transform.tfm";
  const CommandResult result = bmr::test::RunBiomech(
    m_Folder,
    "bspline-register " + Quoted(m_Folder / "fixed.mha") + " " + Quoted(m_Folder / "moving.mha") + " -o " +
      Quoted(warped) + " --transform " + Quoted(transformPath) + " --report " + Quoted(m_Folder / "r.json"));
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_CONTAINS(result.err, "biomech: error: bspline-register failed");
  EXPECT_CONTAINS(result.err, "the moving image is constant");
  EXPECT_FALSE(fs::exists(warped));
  EXPECT_FALSE(fs::exists(transformPath));
  EXPECT_FALSE(fs::exists(m_Folder / "r.json"));
}

TEST_F(BSplineRegisterCommand, BadArgumentsFailBeforeRegistering)
{
  const BlobPattern pattern;
  WriteTestImage(SampledPattern(pattern, false).GetPointer(), m_Folder / "image.mha");
  const std::string images = Quoted(m_Folder / "image.mha") + " " + Quoted(m_Folder / "image.mha");

  CommandResult result = bmr::test::RunBiomech(m_Folder,
                                               "bspline-register " + images + " -o " + Quoted(m_Folder / "w.mha") +
                                                 " --transform " + Quoted(m_Folder / "t.json"));
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_CONTAINS(result.err, "the extension must be .h5 or .hdf5 (HDF5) or .tfm or .txt");

  result = bmr::test::RunBiomech(m_Folder, "bspline-register " + images + " -o " + Quoted(m_Folder / "w.png"));
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_CONTAINS(result.err, "PNG holds 8- or 16-bit unsigned pixels but the warped image is float32");

  result = bmr::test::RunBiomech(m_Folder,
                                 "bspline-register " + Quoted(m_Folder / "missing.mha") + " " +
                                   Quoted(m_Folder / "image.mha") + " -o " + Quoted(m_Folder / "w.mha"));
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_CONTAINS(result.err, "cannot read fixed image");
  EXPECT_CONTAINS(result.err, "no such file");

  result = bmr::test::RunBiomech(
    m_Folder, "bspline-register " + images + " -o " + Quoted(m_Folder / "w.mha") + " --smoothing-sigmas 2 1");
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_CONTAINS(result.err, "ShrinkFactors has 3 levels but SmoothingSigmas has 2");

  result = bmr::test::RunBiomech(
    m_Folder, "bspline-register " + images + " -o " + Quoted(m_Folder / "w.mha") + " --control-point-spacing 0");
  EXPECT_EQ(result.exitCode, 1);
  EXPECT_CONTAINS(result.err, "--control-point-spacing");
  EXPECT_FALSE(fs::exists(m_Folder / "w.mha"));
  EXPECT_FALSE(fs::exists(m_Folder / "w.png"));
}

// ---------------------------------------------------------------------------
// Measurement, not a test (disabled; docs/bspline-registration.md quotes it):
//   build/test/bmrTests --gtest_also_run_disabled_tests --gtest_filter='*BSplineIntensityRegistrationTiming*'
// ---------------------------------------------------------------------------

namespace
{

std::string
LoadAverage()
{
  return bmr::test::ReadText("/proc/loadavg").substr(0, 14);
}

} // namespace

TEST(BSplineIntensityRegistrationTiming, DISABLED_SlicesAndColin27WithDefaults)
{
  std::cout << "load average before: " << LoadAverage() << ", ITK threads "
            << itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads() << "\n";
  if (ExamplesAvailable())
  {
    const auto fixed = ReadSlice(ExampleData / FixedSlice);
    for (const std::string & name : { DeformedSlice, ShiftedSlice })
    {
      const auto moving = ReadSlice(ExampleData / name);
      for (const unsigned int workUnits : { 1u, 2u })
      {
        std::vector<double> seconds;
        for (int run = 0; run < 3; ++run)
        {
          auto filter = MakeFilter(fixed, moving);
          filter->SetMetricNumberOfWorkUnits(workUnits);
          filter->Update();
          seconds.push_back(filter->GetElapsedSeconds());
        }
        std::sort(seconds.begin(), seconds.end());
        std::cout << name << ", " << workUnits << " metric work unit(s): registration " << seconds[1]
                  << " s (median of 3; range " << seconds[0] << "-" << seconds[2] << ")\n";
      }
    }
  }

  const fs::path colin("/usr/share/mricron/templates/ch2.nii.gz");
  const fs::path colinBrain("/usr/share/mricron/templates/ch2bet.nii.gz");
  if (!fs::exists(colin) || !fs::exists(colinBrain))
  {
    GTEST_SKIP() << "mricron-data (Colin27) not installed";
  }
  using VolumeImage = itk::Image<float, 3>;
  const auto readVolume = [](const fs::path & path) {
    auto reader = itk::ImageFileReader<VolumeImage>::New();
    reader->SetFileName(path.string());
    reader->Update();
    return VolumeImage::Pointer(reader->GetOutput());
  };
  const VolumeImage::Pointer t1 = readVolume(colin);
  const VolumeImage::Pointer brain = readVolume(colinBrain);

  // A brain-shift-like displacement: a Gaussian bump (sigma 30 mm) of (3, -2, 2) mm
  // at the brain's centre, sampled on a 2 mm field.
  VolumeImage::PointType centre;
  centre.Fill(0.0);
  double brainVoxels = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<VolumeImage> it(brain, brain->GetLargestPossibleRegion()); !it.IsAtEnd();
       ++it)
  {
    if (it.Get() > 0.0f)
    {
      VolumeImage::PointType point;
      brain->TransformIndexToPhysicalPoint(it.GetIndex(), point);
      for (unsigned int d = 0; d < 3; ++d)
      {
        centre[d] += point[d];
      }
      brainVoxels += 1.0;
    }
  }
  for (unsigned int d = 0; d < 3; ++d)
  {
    centre[d] /= brainVoxels;
  }
  const auto displacement = [&centre](const VolumeImage::PointType & point) {
    const double           weight = std::exp(-point.SquaredEuclideanDistanceTo(centre) / (2.0 * 30.0 * 30.0));
    itk::Vector<double, 3> u;
    u[0] = 3.0 * weight;
    u[1] = -2.0 * weight;
    u[2] = 2.0 * weight;
    return u;
  };
  using FieldTransformType = itk::DisplacementFieldTransform<double, 3>;
  using FieldType = FieldTransformType::DisplacementFieldType;
  auto                   field = FieldType::New();
  FieldType::SizeType    fieldSize;
  FieldType::SpacingType fieldSpacing;
  for (unsigned int d = 0; d < 3; ++d)
  {
    fieldSize[d] = t1->GetLargestPossibleRegion().GetSize()[d] / 2 + 2;
    fieldSpacing[d] = 2.0 * t1->GetSpacing()[d];
  }
  field->SetRegions(fieldSize);
  field->SetSpacing(fieldSpacing);
  field->SetOrigin(t1->GetOrigin());
  field->SetDirection(t1->GetDirection());
  field->Allocate();
  for (itk::ImageRegionIteratorWithIndex<FieldType> it(field, field->GetLargestPossibleRegion()); !it.IsAtEnd(); ++it)
  {
    VolumeImage::PointType point;
    field->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    it.Set(displacement(point));
  }
  auto fieldTransform = FieldTransformType::New();
  fieldTransform->SetDisplacementField(field);
  auto warp = itk::ResampleImageFilter<VolumeImage, VolumeImage>::New();
  warp->SetInput(t1);
  warp->SetTransform(fieldTransform);
  warp->SetOutputParametersFromImage(t1);
  warp->Update();
  // "Intraoperative" = the displaced copy: fixed(x) = t1(x + u(x)).
  const VolumeImage::Pointer intraoperative = warp->GetOutput();

  for (const bool masked : { false, true })
  {
    for (const unsigned int workUnits : { 1u, 2u })
    {
      auto filter = itk::BSplineIntensityRegistrationFilter<VolumeImage, VolumeImage, VolumeImage>::New();
      filter->SetFixedImage(intraoperative);
      filter->SetMovingImage(t1);
      if (masked)
      {
        filter->SetFixedMask(brain);
      }
      filter->SetMetricNumberOfWorkUnits(workUnits);
      filter->Update();
      double errorSum = 0.0, largestError = 0.0, truthSum = 0.0, count = 0.0;
      for (itk::ImageRegionConstIteratorWithIndex<VolumeImage> it(brain, brain->GetLargestPossibleRegion());
           !it.IsAtEnd();
           ++it)
      {
        const auto index = it.GetIndex();
        if (it.Get() <= 0.0f || index[0] % 3 != 0 || index[1] % 3 != 0 || index[2] % 3 != 0)
        {
          continue;
        }
        VolumeImage::PointType point;
        brain->TransformIndexToPhysicalPoint(index, point);
        const itk::Vector<double, 3> truth = displacement(point);
        const double error = ((filter->GetTransform()->TransformPoint(point) - point) - truth).GetNorm();
        errorSum += error;
        largestError = std::max(largestError, error);
        truthSum += truth.GetNorm();
        count += 1.0;
      }
      std::cout << "Colin27 " << (masked ? "with brain mask" : "no mask") << ", " << workUnits
                << " metric work unit(s): registration " << filter->GetElapsedSeconds() << " s, warp "
                << filter->GetWarpElapsedSeconds() << " s, iterations " << filter->GetIterationsPerLevel()[0] << " + "
                << filter->GetIterationsPerLevel()[1] << " + " << filter->GetIterationsPerLevel()[2]
                << "; in the brain: true displacement mean " << truthSum / count << " mm, error mean "
                << errorSum / count << " mm, largest " << largestError << " mm; load " << LoadAverage() << "\n";
    }
  }
}
