// From displacements at scattered points to a transform and a warped image:
// the multilevel B-spline fitter (itk::DisplacementPointSetToBSplineTransformFilter),
// the warp (itk::TransformWarpImageFilter), transform IO, and the
// `biomech fit-transform` and `biomech warp` subcommands.
//
// The reference field is analytic and smooth, so the fitted transform can be
// checked between the data points, and its inverse (for the backward map) is
// found independently by fixed-point iteration.
//
// ITK headers first: ITK's bundled Eigen must come before the system Eigen.
#include "itkBiomechanicalTransformIO.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkImage.h"
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkBSplineLatticeConversion.h"
#include "itkMultiThreaderBase.h"
#include "itkResampleImageFilter.h"
#include "itkTransformWarpImageFilter.h"

#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"

#include "bmrTemporaryFolderTest.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace
{

using PointSetType = itk::DisplacementPointSetType<3>;
using FitterType = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>;
using ImageType = itk::Image<float, 3>;
using LabelImageType = itk::Image<unsigned char, 3>;
using PointType = itk::Point<double, 3>;
using VectorType = itk::Vector<double, 3>;

/** A smooth brain-shift-like field (mm): a sag of up to 4 mm along -z,
 *  largest near the top centre, with a lateral swirl of about 1 mm. Its
 *  gradient stays below 0.15, so x -> x + u(x) is invertible. */
VectorType
AnalyticDisplacement(const PointType & x)
{
  const double a = x[0] / 60.0;
  const double b = x[1] / 60.0;
  const double c = (x[2] + 40.0) / 80.0;
  VectorType   u;
  u[0] = 1.0 * std::sin(1.2 * b) * c;
  u[1] = -1.0 * std::sin(1.2 * a) * c;
  u[2] = -4.0 * std::exp(-(a * a + b * b)) * c * c;
  return u;
}

/** x with x + u(x) = y, by fixed-point iteration (|grad u| < 1). */
PointType
InverseOfAnalytic(const PointType & y)
{
  PointType x = y;
  for (int iteration = 0; iteration < 100; ++iteration)
  {
    x = y - AnalyticDisplacement(x);
  }
  return x;
}

/** A 64 x 64 x 48 image of 2 mm voxels centred on the origin, oblique (rotated
 *  10 degrees about z) so that the direction cosines matter. */
template <typename TImage>
typename TImage::Pointer
MakeReferenceImage(double spacing = 2.0)
{
  auto                         image = TImage::New();
  typename TImage::RegionType  region;
  region.SetSize({ { 64, 64, 48 } });
  image->SetRegions(region);
  typename TImage::SpacingType spacings;
  spacings.Fill(spacing);
  image->SetSpacing(spacings);
  typename TImage::DirectionType direction;
  direction.SetIdentity();
  const double angle = 10.0 * M_PI / 180.0;
  direction[0][0] = std::cos(angle);
  direction[0][1] = -std::sin(angle);
  direction[1][0] = std::sin(angle);
  direction[1][1] = std::cos(angle);
  image->SetDirection(direction);
  // Centre of the grid at the origin.
  typename TImage::PointType origin;
  itk::Vector<double, 3>     halfExtent;
  for (unsigned int d = 0; d < 3; ++d)
  {
    halfExtent[d] = 0.5 * spacing * (region.GetSize()[d] - 1);
  }
  const auto rotated = direction * halfExtent;
  for (unsigned int d = 0; d < 3; ++d)
  {
    origin[d] = -rotated[d];
  }
  image->SetOrigin(origin);
  return image;
}

/** `count` points, uniformly random (fixed seed) in a 100 x 100 x 70 mm box
 *  about the origin (inside the reference image), with the analytic field. */
PointSetType::Pointer
ScatteredAnalyticPoints(std::size_t count, unsigned int seed)
{
  std::mt19937                           random(seed);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  auto                                   points = PointSetType::New();
  for (std::size_t n = 0; n < count; ++n)
  {
    PointType x;
    x[0] = 50.0 * uniform(random);
    x[1] = 50.0 * uniform(random);
    x[2] = 35.0 * uniform(random);
    points->SetPoint(n, x);
    points->SetPointData(n, AnalyticDisplacement(x));
  }
  return points;
}

FitterType::Pointer
FitAnalytic(std::size_t count = 6000)
{
  auto fitter = FitterType::New();
  fitter->SetInput(ScatteredAnalyticPoints(count, 7));
  fitter->SetReferenceImage(MakeReferenceImage<ImageType>());
  fitter->SetGenerateForwardTransform(true);
  fitter->Update();
  return fitter;
}

/** A smooth test image: sum of two Gaussian blobs and a slow ramp, values 0..~200. */
double
AnalyticIntensity(const PointType & x)
{
  auto blob = [&](double cx, double cy, double cz, double width) {
    const double r2 = (x[0] - cx) * (x[0] - cx) + (x[1] - cy) * (x[1] - cy) + (x[2] - cz) * (x[2] - cz);
    return std::exp(-r2 / (2.0 * width * width));
  };
  return 100.0 * blob(10.0, -5.0, 10.0, 12.0) + 80.0 * blob(-15.0, 12.0, -5.0, 9.0) + 0.3 * (x[0] + 60.0);
}

template <typename TImage, typename TFunction>
void
FillImage(TImage * image, TFunction && value)
{
  image->Allocate();
  for (itk::ImageRegionIteratorWithIndex<TImage> it(image, image->GetLargestPossibleRegion()); !it.IsAtEnd(); ++it)
  {
    PointType point;
    image->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    it.Set(static_cast<typename TImage::PixelType>(value(point)));
  }
}

// ---------------------------------------------------------------------------
// The fitter
// ---------------------------------------------------------------------------

TEST(DisplacementPointSetToBSplineTransform, RecoversAnalyticFieldBetweenThePoints)
{
  const auto fitter = FitAnalytic();
  const auto & report = fitter->GetReport();
  const auto & forwardReport = fitter->GetForwardReport();
  EXPECT_TRUE(report.toleranceReached);
  EXPECT_TRUE(forwardReport.toleranceReached);
  EXPECT_LE(report.maximumResidual, 0.1);
  EXPECT_LE(forwardReport.maximumResidual, 0.1);
  EXPECT_LE(report.rmsResidual, report.maximumResidual);
  EXPECT_GE(report.levels, 2u); // one level cannot reach 0.1 mm on this field
  EXPECT_FALSE(fitter->GetDomainExtended());

  // Between the data points (other random points, 30 mm inside the sampled
  // box's edges are not needed: the data cover the whole box).
  const auto * forward = fitter->GetForwardTransform();
  const auto * backward = fitter->GetTransform();
  auto         probes = ScatteredAnalyticPoints(2000, 99);
  double       worstForward = 0.0;
  double       worstBackward = 0.0;
  double       largestDisplacement = 0.0;
  for (std::size_t n = 0; n < probes->GetNumberOfPoints(); ++n)
  {
    const PointType  x = probes->GetPoint(n);
    const VectorType u = AnalyticDisplacement(x);
    largestDisplacement = std::max(largestDisplacement, u.GetNorm());
    worstForward = std::max(worstForward, (forward->TransformPoint(x) - (x + u)).GetNorm());
    worstBackward = std::max(worstBackward, (backward->TransformPoint(x + u) - x).GetNorm());
  }
  EXPECT_GT(largestDisplacement, 3.0); // the field is not trivially small
  // 0.1 mm at the points; between them (about 5 mm apart) 0.12 mm measured.
  EXPECT_LE(worstForward, 0.15);
  EXPECT_LE(worstBackward, 0.15);
}

TEST(DisplacementPointSetToBSplineTransform, ResidualReportMatchesAnIndependentEvaluation)
{
  const auto   fitter = FitAnalytic();
  const auto * backward = fitter->GetTransform();
  auto         data = ScatteredAnalyticPoints(6000, 7);
  double       largest = 0.0;
  double       sumOfSquares = 0.0;
  for (std::size_t n = 0; n < data->GetNumberOfPoints(); ++n)
  {
    const PointType  x = data->GetPoint(n);
    const VectorType u = AnalyticDisplacement(x);
    const double     residual = (backward->TransformPoint(x + u) - x).GetNorm();
    largest = std::max(largest, residual);
    sumOfSquares += residual * residual;
  }
  EXPECT_NEAR(fitter->GetReport().maximumResidual, largest, 1e-9);
  EXPECT_NEAR(fitter->GetReport().rmsResidual, std::sqrt(sumOfSquares / 6000.0), 1e-9);
}

TEST(DisplacementPointSetToBSplineTransform, StopsAtTheMinimumSpacingAndSaysSo)
{
  auto fitter = FitterType::New();
  fitter->SetInput(ScatteredAnalyticPoints(6000, 7));
  fitter->SetReferenceImage(MakeReferenceImage<ImageType>());
  fitter->SetTolerance(1e-4);
  fitter->SetMinimumControlPointSpacing(20.0);
  fitter->Update();
  const auto & report = fitter->GetReport();
  EXPECT_FALSE(report.toleranceReached);
  EXPECT_GT(report.maximumResidual, 1e-4);
  for (double spacing : report.controlPointSpacing)
  {
    EXPECT_GE(spacing, 20.0);
    EXPECT_LT(spacing, 40.0); // the last level allowed was fitted
  }
}

TEST(DisplacementPointSetToBSplineTransform, BackwardMapWarpsToTheAnalyticallyDeformedImage)
{
  // Preoperative image f(x); the intraoperative image is f(X(y)) with
  // y = x + u(x). Warping f with the fitted backward map must give it.
  auto preoperative = MakeReferenceImage<ImageType>();
  FillImage(preoperative.GetPointer(), AnalyticIntensity);
  auto expected = MakeReferenceImage<ImageType>();
  FillImage(expected.GetPointer(), [](const PointType & y) { return AnalyticIntensity(InverseOfAnalytic(y)); });

  const auto fitter = FitAnalytic();
  using WarpType = itk::TransformWarpImageFilter<ImageType>;
  auto warp = WarpType::New();
  warp->SetInput(preoperative);
  warp->SetTransform(fitter->GetTransform());
  warp->Update();

  // Inside the region the data cover (|x|, |y| < 45, |z| < 30 mm).
  double worstWarped = 0.0;
  double worstUnwarped = 0.0;
  for (itk::ImageRegionIteratorWithIndex<ImageType> it(expected, expected->GetLargestPossibleRegion()); !it.IsAtEnd();
       ++it)
  {
    PointType y;
    expected->TransformIndexToPhysicalPoint(it.GetIndex(), y);
    if (std::abs(y[0]) > 45.0 || std::abs(y[1]) > 45.0 || std::abs(y[2]) > 30.0)
    {
      continue;
    }
    worstWarped = std::max(worstWarped, std::abs(double(warp->GetOutput()->GetPixel(it.GetIndex())) - it.Get()));
    worstUnwarped = std::max(worstUnwarped, std::abs(double(preoperative->GetPixel(it.GetIndex())) - it.Get()));
  }
  // Intensity slopes are below ~5 per mm: 0.15 mm of transform error and the
  // linear interpolation of a 2 mm grid stay below 1 unit (0.66 measured); no warp is off by 12.
  EXPECT_LT(worstWarped, 1.0);
  EXPECT_GT(worstUnwarped, 10.0);
}

TEST(DisplacementPointSetToBSplineTransform, DenseFieldMatchesTheSplineOnTheReferenceGrid)
{
  auto reference = MakeReferenceImage<ImageType>();
  auto fitter = FitterType::New();
  fitter->SetInput(ScatteredAnalyticPoints(6000, 7));
  fitter->SetReferenceImage(reference);
  fitter->SetGenerateDisplacementField(true);
  fitter->Update();
  const auto * field = fitter->GetDisplacementFieldTransform();
  ASSERT_NE(field, nullptr);
  const auto * fieldImage = field->GetDisplacementField();
  EXPECT_EQ(fieldImage->GetLargestPossibleRegion(), reference->GetLargestPossibleRegion());
  double worst = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<ImageType> it(reference, reference->GetLargestPossibleRegion());
       !it.IsAtEnd();
       ++it)
  {
    PointType y;
    reference->TransformIndexToPhysicalPoint(it.GetIndex(), y);
    worst = std::max(worst, (field->TransformPoint(y) - fitter->GetTransform()->TransformPoint(y)).GetNorm());
  }
  EXPECT_LT(worst, 1e-5); // the sampler works partly in single precision
}

TEST(DisplacementPointSetToBSplineTransform, SameResultForOneAndTwoThreads)
{
  const int threads = itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads();
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(1);
  const auto one = FitAnalytic(3000);
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(2);
  const auto two = FitAnalytic(3000);
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(threads);
  const auto & a = one->GetTransform()->GetParameters();
  const auto & b = two->GetTransform()->GetParameters();
  ASSERT_EQ(a.Size(), b.Size());
  for (unsigned int n = 0; n < a.Size(); ++n)
  {
    ASSERT_EQ(a[n], b[n]) << "parameter " << n;
  }
}

TEST(DisplacementPointSetToBSplineTransform, PointsOutsideTheImageExtendTheDomainOrAreRejected)
{
  // A reference grid that covers only the middle of the data.
  auto small = ImageType::New();
  ImageType::SizeType smallSize = { { 10, 10, 10 } };
  small->SetRegions(smallSize);
  small->SetSpacing(4.0);
  small->SetOrigin(PointType(std::array<double, 3>{ { -18.0, -18.0, -18.0 } }.data()));

  auto fitter = FitterType::New();
  fitter->SetInput(ScatteredAnalyticPoints(3000, 7));
  fitter->SetReferenceImage(small);
  fitter->Update();
  EXPECT_TRUE(fitter->GetDomainExtended());
  EXPECT_TRUE(fitter->GetReport().toleranceReached);

  fitter->SetExtendDomainToPoints(false);
  try
  {
    fitter->Update();
    ADD_FAILURE() << "points outside the reference image were accepted";
  }
  catch (const itk::ExceptionObject & exception)
  {
    EXPECT_CONTAINS(exception.GetDescription(), "outside the reference image");
    EXPECT_CONTAINS(exception.GetDescription(), "ExtendDomainToPoints");
  }
}

std::string
FitError(const PointSetType::Pointer & points, const ImageType * reference)
{
  auto fitter = FitterType::New();
  fitter->SetInput(points);
  if (reference != nullptr)
  {
    fitter->SetReferenceImage(reference);
  }
  try
  {
    fitter->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    return exception.GetDescription();
  }
  return "(no exception)";
}

TEST(DisplacementPointSetToBSplineTransform, BadInputIsNamed)
{
  auto reference = MakeReferenceImage<ImageType>();
  EXPECT_CONTAINS(FitError(ScatteredAnalyticPoints(63, 1), reference), "at least 64 points");
  EXPECT_CONTAINS(FitError(ScatteredAnalyticPoints(100, 1), nullptr), "no reference image");

  auto withNaN = ScatteredAnalyticPoints(100, 1);
  VectorType bad;
  bad.Fill(std::nan(""));
  withNaN->SetPointData(42, bad);
  const std::string message = FitError(withNaN, reference);
  EXPECT_CONTAINS(message, "point 42");
  EXPECT_CONTAINS(message, "NaN");
}

TEST(CubicBSplineLattice, EvaluationAndSamplingMatchITKBSplineTransform)
{
  // A random lattice on an oblique grid, as ITK's transform and as the core's lattice.
  bmr::CubicBSplineLattice lattice;
  lattice.geometry.size = { 9, 8, 7 };
  lattice.geometry.spacing = bmr::Vector3(12.0, 10.0, 9.0);
  lattice.geometry.origin = bmr::Vector3(-40.0, -35.0, -30.0);
  lattice.geometry.direction = Eigen::AngleAxisd(0.3, bmr::Vector3(1.0, 2.0, 3.0).normalized()).toRotationMatrix();
  std::mt19937                           random(5);
  std::uniform_real_distribution<double> uniform(-3.0, 3.0);
  lattice.coefficients.resize(lattice.geometry.VoxelCount());
  for (auto & coefficient : lattice.coefficients)
  {
    coefficient = bmr::Vector3(uniform(random), uniform(random), uniform(random));
  }
  const auto transform = itk::MakeBSplineTransform(lattice);
  EXPECT_EQ(itk::MakeCubicBSplineLattice(transform).coefficients, lattice.coefficients);

  // Points all over the lattice's box, valid region and outside it.
  double worst = 0.0;
  int    inside = 0;
  for (int n = 0; n < 5000; ++n)
  {
    const bmr::Vector3 index(uniform(random) * 1.6 + 4.0, uniform(random) * 1.4 + 3.5, uniform(random) * 1.2 + 3.0);
    const bmr::Vector3 point = lattice.geometry.IndexToPoint(index);
    PointType          itkPoint;
    for (int d = 0; d < 3; ++d)
    {
      itkPoint[d] = point[d];
    }
    const auto         moved = transform->TransformPoint(itkPoint);
    const bmr::Vector3 itkDisplacement(moved[0] - point[0], moved[1] - point[1], moved[2] - point[2]);
    worst = std::max(worst, (lattice.Evaluate(point) - itkDisplacement).norm());
    inside += itkDisplacement.norm() > 0.0;
  }
  EXPECT_LT(worst, 1e-12);
  EXPECT_GT(inside, 500); // both the valid region and outside it are probed
  EXPECT_LT(inside, 5000);

  // Sampling on a grid of the lattice's direction (another spacing and origin).
  auto grid = ImageType::New();
  ImageType::SizeType gridSize = { { 40, 35, 30 } };
  grid->SetRegions(gridSize);
  grid->SetSpacing(std::array<double, 3>{ { 2.5, 2.0, 1.5 } }.data());
  ImageType::DirectionType direction;
  for (int d = 0; d < 3; ++d)
  {
    for (int e = 0; e < 3; ++e)
    {
      direction[d][e] = lattice.geometry.direction(d, e);
    }
  }
  grid->SetDirection(direction);
  grid->SetOrigin(PointType(lattice.geometry.IndexToPoint(bmr::Vector3(0.5, 0.7, 0.4)).data()));
  const auto field = itk::SampleBSplineTransform(transform, grid);
  ASSERT_NE(field, nullptr);
  double worstSample = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<ImageType> it(grid, grid->GetLargestPossibleRegion()); !it.IsAtEnd(); ++it)
  {
    PointType y;
    grid->TransformIndexToPhysicalPoint(it.GetIndex(), y);
    worstSample = std::max(worstSample, ((transform->TransformPoint(y) - y) - field->GetPixel(it.GetIndex())).GetNorm());
  }
  EXPECT_LT(worstSample, 1e-12);

  // Another direction: no sampling (the caller resamples through the transform).
  grid->SetDirection(ImageType::DirectionType::GetIdentity());
  EXPECT_EQ(itk::SampleBSplineTransform(transform, grid), nullptr);
}

// ---------------------------------------------------------------------------
// Transform IO and the warp
// ---------------------------------------------------------------------------

class TransformFiles : public bmr::test::TemporaryFolderTest
{};

TEST_F(TransformFiles, WrittenTransformReadsBackIdentically)
{
  const auto   fitter = FitAnalytic(2000);
  const auto * written = fitter->GetTransform();
  for (const std::string name : { "backward.h5", "backward.tfm" })
  {
    const std::string path = (m_Folder / name).string();
    itk::WriteBiomechanicalTransform(written, path);
    const auto read = itk::ReadBiomechanicalTransform(path);
    ASSERT_STREQ(read->GetNameOfClass(), "BSplineTransform") << name;
    ASSERT_EQ(read->GetFixedParameters(), written->GetFixedParameters()) << name;
    const auto & a = read->GetParameters();
    const auto & b = written->GetParameters();
    ASSERT_EQ(a.Size(), b.Size());
    for (unsigned int n = 0; n < a.Size(); ++n)
    {
      ASSERT_EQ(a[n], b[n]) << name << " parameter " << n;
    }
  }
  try
  {
    itk::WriteBiomechanicalTransform(written, (m_Folder / "backward.xyz").string());
    ADD_FAILURE() << "an unknown extension was accepted";
  }
  catch (const itk::ExceptionObject & exception)
  {
    EXPECT_CONTAINS(exception.GetDescription(), ".h5");
  }
  EXPECT_FALSE(fs::exists(m_Folder / "backward.xyz"));
}

TEST(TransformWarp, SampledSplineGivesTheImageOfResampleImageFilter)
{
  auto image = MakeReferenceImage<ImageType>();
  FillImage(image.GetPointer(), AnalyticIntensity);
  auto fitter = FitterType::New();
  fitter->SetInput(ScatteredAnalyticPoints(4000, 7));
  fitter->SetReferenceImage(image);
  fitter->Update();

  auto warp = itk::TransformWarpImageFilter<ImageType>::New();
  warp->SetInput(image);
  warp->SetTransform(fitter->GetTransform());
  warp->Update();
  auto resampler = itk::ResampleImageFilter<ImageType, ImageType>::New();
  resampler->SetInput(image);
  resampler->SetTransform(fitter->GetTransform());
  resampler->SetOutputParametersFromImage(image);
  resampler->Update();
  double worst = 0.0;
  double range = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<ImageType> it(resampler->GetOutput(), image->GetLargestPossibleRegion());
       !it.IsAtEnd();
       ++it)
  {
    worst = std::max(worst, std::abs(double(it.Get()) - warp->GetOutput()->GetPixel(it.GetIndex())));
    range = std::max(range, double(it.Get()));
  }
  EXPECT_GT(range, 50.0);
  EXPECT_LT(worst, 1e-3);
}

TEST(TransformWarp, NearestNeighbourKeepsLabelsAndFieldPathMatchesSplinePath)
{
  auto labels = MakeReferenceImage<LabelImageType>();
  FillImage(labels.GetPointer(), [](const PointType & x) {
    const double r = x.GetVectorFromOrigin().GetNorm();
    return r < 15.0 ? 3 : (r < 30.0 ? 2 : (r < 45.0 ? 1 : 0));
  });
  auto fitter = FitterType::New();
  fitter->SetInput(ScatteredAnalyticPoints(4000, 7));
  fitter->SetReferenceImage(labels);
  fitter->SetGenerateDisplacementField(true);
  fitter->Update();

  using WarpType = itk::TransformWarpImageFilter<LabelImageType>;
  auto throughSpline = WarpType::New();
  throughSpline->SetInput(labels);
  throughSpline->SetTransform(fitter->GetTransform());
  throughSpline->SetInterpolation(itk::WarpInterpolation::NearestNeighbor);
  throughSpline->Update();
  auto throughField = WarpType::New();
  throughField->SetInput(labels);
  throughField->SetTransform(fitter->GetDisplacementFieldTransform());
  throughField->SetInterpolation(itk::WarpInterpolation::NearestNeighbor);
  throughField->Update();

  std::set<int> values;
  std::size_t   differences = 0;
  std::size_t   changed = 0;
  for (itk::ImageRegionConstIteratorWithIndex<LabelImageType> it(throughSpline->GetOutput(),
                                                                  labels->GetLargestPossibleRegion());
       !it.IsAtEnd();
       ++it)
  {
    values.insert(it.Get());
    differences += it.Get() != throughField->GetOutput()->GetPixel(it.GetIndex());
    changed += it.Get() != labels->GetPixel(it.GetIndex());
  }
  EXPECT_EQ(values, (std::set<int>{ 0, 1, 2, 3 }));
  EXPECT_GT(changed, 1000u);     // the labels moved
  EXPECT_LT(differences, 20u);   // a voxel centre may sit within 1e-4 mm of a label boundary
}

// ---------------------------------------------------------------------------
// The subcommands
// ---------------------------------------------------------------------------

class TransformCommands : public bmr::test::TemporaryFolderTest
{
protected:
  /** A solved-like result: a block mesh with the analytic displacement at its nodes. */
  void WriteResult()
  {
    bmr::Model model = bmr::MakeBlockMesh(bmr::Vector3(100, 100, 70), { 20, 20, 14 }, bmr::GridCells::Hexahedra,
                                          bmr::Material{}, bmr::Vector3(-50, -50, -35));
    bmr::SolveResult result;
    for (const auto & node : model.nodes)
    {
      PointType x;
      for (int d = 0; d < 3; ++d)
      {
        x[d] = node[d];
      }
      const VectorType u = AnalyticDisplacement(x);
      result.displacements.emplace_back(u[0], u[1], u[2]);
      result.reactionForces.emplace_back(bmr::Vector3::Zero());
    }
    bmr::WriteResultVtu((m_Folder / "result.vtu").string(), model, result);

    auto image = MakeReferenceImage<ImageType>();
    FillImage(image.GetPointer(), AnalyticIntensity);
    auto writer = itk::ImageFileWriter<ImageType>::New();
    writer->SetInput(image);
    writer->SetFileName((m_Folder / "preoperative.nii.gz").string());
    writer->Update();
  }

  std::string Path(const std::string & name) const { return "'" + (m_Folder / name).string() + "'"; }
};

TEST_F(TransformCommands, FitTransformThenWarpGiveTheDeformedImage)
{
  WriteResult();
  const auto fit = bmr::test::RunBiomech(m_Folder, "fit-transform " + Path("result.vtu") + " " +
                                                     Path("preoperative.nii.gz") + " -o " + Path("backward.h5") +
                                                     " --forward-output " + Path("forward.tfm") + " --report " +
                                                     Path("fit.json"));
  ASSERT_EQ(fit.exitCode, 0) << fit.err;
  const json report = json::parse(bmr::test::ReadText(m_Folder / "fit.json"));
  EXPECT_EQ(report["points"], 21 * 21 * 15);
  EXPECT_LE(report["backward"]["maximum_residual_mm"].get<double>(), 0.1);
  EXPECT_TRUE(report["backward"]["tolerance_reached"].get<bool>());
  EXPECT_LE(report["forward"]["maximum_residual_mm"].get<double>(), 0.1);
  EXPECT_CONTAINS(fit.out, "maximum residual");

  // The written forward transform moves a node as the analytic field does.
  const auto forward = itk::ReadBiomechanicalTransform((m_Folder / "forward.tfm").string());
  using TransformType = itk::Transform<double, 3, 3>;
  const auto * forwardTransform = dynamic_cast<const TransformType *>(forward.GetPointer());
  ASSERT_NE(forwardTransform, nullptr);
  PointType node;
  node[0] = 10.0;
  node[1] = -5.0;
  node[2] = 15.0;
  EXPECT_LT((forwardTransform->TransformPoint(node) - (node + AnalyticDisplacement(node))).GetNorm(), 0.1);

  const auto warp = bmr::test::RunBiomech(m_Folder, "warp " + Path("preoperative.nii.gz") + " " + Path("backward.h5") +
                                                      " -o " + Path("warped.nii.gz"));
  ASSERT_EQ(warp.exitCode, 0) << warp.err;
  auto reader = itk::ImageFileReader<ImageType>::New();
  reader->SetFileName((m_Folder / "warped.nii.gz").string());
  reader->Update();
  const ImageType * warped = reader->GetOutput();
  double            worst = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<ImageType> it(warped, warped->GetLargestPossibleRegion()); !it.IsAtEnd();
       ++it)
  {
    PointType y;
    warped->TransformIndexToPhysicalPoint(it.GetIndex(), y);
    if (std::abs(y[0]) > 45.0 || std::abs(y[1]) > 45.0 || std::abs(y[2]) > 30.0)
    {
      continue;
    }
    worst = std::max(worst, std::abs(double(it.Get()) - AnalyticIntensity(InverseOfAnalytic(y))));
  }
  EXPECT_LT(worst, 1.0);
}

TEST_F(TransformCommands, BadInputExitsWithAMessageAndWritesNothing)
{
  WriteResult();
  auto run = [&](const std::string & arguments) { return bmr::test::RunBiomech(m_Folder, arguments); };

  auto missing = run("fit-transform " + Path("nothing.vtu") + " " + Path("preoperative.nii.gz") + " -o " +
                     Path("t.h5"));
  EXPECT_EQ(missing.exitCode, 1);
  EXPECT_CONTAINS(missing.err, "nothing.vtu");

  auto badExtension = run("fit-transform " + Path("result.vtu") + " " + Path("preoperative.nii.gz") + " -o " +
                          Path("t.png"));
  EXPECT_EQ(badExtension.exitCode, 1);
  EXPECT_CONTAINS(badExtension.err, ".h5");

  auto noTransform = run("warp " + Path("preoperative.nii.gz") + " " + Path("none.h5") + " -o " + Path("w.nii.gz"));
  EXPECT_EQ(noTransform.exitCode, 1);
  EXPECT_CONTAINS(noTransform.err, "none.h5");

  // A mesh without displacements.
  bmr::WriteMesh((m_Folder / "mesh.vtu").string(), bmr::MakeBlockMesh(bmr::Vector3(10, 10, 10), { 4, 4, 4 },
                                                                      bmr::GridCells::Hexahedra, bmr::Material{}));
  auto noDisplacement = run("fit-transform " + Path("mesh.vtu") + " " + Path("preoperative.nii.gz") + " -o " +
                            Path("t.h5"));
  EXPECT_EQ(noDisplacement.exitCode, 1);
  EXPECT_CONTAINS(noDisplacement.err, "displacement");

  for (const char * name : { "t.h5", "t.png", "w.nii.gz" })
  {
    EXPECT_FALSE(fs::exists(m_Folder / name)) << name;
  }
}

} // namespace
