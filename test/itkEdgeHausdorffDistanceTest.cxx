// Edge-based Hausdorff evaluator (itk::EdgeHausdorffDistanceImageFilter) and
// `biomech evaluate`: identical images, known shifts in mm (isotropic and
// anisotropic voxels), agreement with ITK's Hausdorff filter and with a
// brute-force nearest-edge search, slice mode, mask, bad input, Colin27.
//
// ITK headers first: ITK's bundled Eigen must come before the system Eigen.
// Over 800 lines: the tests of one filter and its command, which share their
// images and the brute-force reference.
#include "itkDirectedHausdorffDistanceImageFilter.h"
#include "itkEdgeHausdorffDistanceImageFilter.h"
#include "itkExtractImageFilter.h"
#include "itkHausdorffDistanceImageFilter.h"
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkMultiThreaderBase.h"

#include "bmrTemporaryFolderTest.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <string>
#include <type_traits>
#include <vector>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace
{

using Image2 = itk::Image<float, 2>;
using Image3 = itk::Image<float, 3>;
// The mask has the image's pixel type (> 0 inside), as the command reads it.
using Filter2 = itk::EdgeHausdorffDistanceImageFilter<Image2, Image2>;
using Filter3 = itk::EdgeHausdorffDistanceImageFilter<Image3, Image3>;
using Edges2 = Filter2::EdgeImageType;
using Edges3 = Filter3::EdgeImageType;

const fs::path   ItkExamplesData("/usr/share/doc/insighttoolkit5-examples/examples/Data");
const fs::path   Colin27("/usr/share/mricron/templates/ch2.nii.gz");
constexpr double Pi = 3.14159265358979323846;

template <unsigned int D>
using Point = itk::Point<double, D>;

/** An image of `size` voxels of `spacing` mm (origin -5 mm on every axis) whose value at each voxel centre is
 * `value(point)`. */
template <unsigned int D>
typename itk::Image<float, D>::Pointer
MakeImage(const std::array<itk::SizeValueType, D> & size, const std::array<double, D> & spacing,
          const std::function<double(const Point<D> & p)> & value)
{
  using ImageType = itk::Image<float, D>;
  auto                            image = ImageType::New();
  typename ImageType::SizeType    imageSize;
  typename ImageType::SpacingType imageSpacing;
  typename ImageType::PointType   origin;
  for (unsigned int d = 0; d < D; ++d)
  {
    imageSize[d] = size[d];
    imageSpacing[d] = spacing[d];
    origin[d] = -5.0;
  }
  image->SetRegions(imageSize);
  image->SetSpacing(imageSpacing);
  image->SetOrigin(origin);
  image->Allocate();
  for (itk::ImageRegionIteratorWithIndex<ImageType> it(image, image->GetBufferedRegion()); !it.IsAtEnd(); ++it)
  {
    Point<D> point;
    image->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    it.Set(static_cast<float>(value(point)));
  }
  return image;
}

/** Texture of 0.5 % of the object's contrast (100), moved with the object.
 *  The automatic thresholds (0.8 quantile of the gradient magnitude, at least
 *  1/64 of the largest) ignore it; at 1-2 % they start to pick texture edges in
 *  these images, where the object's edge is a small part of the field (in a
 *  brain mask, edges are everywhere). */
template <unsigned int D>
double
Texture(const Point<D> & p)
{
  double texture = 0.5 * std::sin(2.0 * Pi * p[0] / 7.0) * std::cos(2.0 * Pi * p[1] / 5.0);
  if constexpr (D == 3)
  {
    texture *= std::cos(2.0 * Pi * p[2] / 9.0);
  }
  return texture;
}

/** A bright disk (radius 12 mm, centre (25, 24) mm) on a dark textured background, moved by `shift` mm. */
double
Disk(const Point<2> & p, double shiftX, double shiftY)
{
  Point<2> q;
  q[0] = p[0] - shiftX;
  q[1] = p[1] - shiftY;
  const double r = std::hypot(q[0] - 25.0, q[1] - 24.0);
  return (r < 12.0 ? 110.0 : 10.0) + Texture<2>(q);
}

/** 0.5 mm pixels, 60 x 60 mm. */
Image2::Pointer
DiskImage(double shiftX, double shiftY = 0.0)
{
  return MakeImage<2>({ 120, 120 }, { 0.5, 0.5 }, [=](const Point<2> & p) { return Disk(p, shiftX, shiftY); });
}

/** A cylinder along z (radius 10 mm, z in [5, 20) mm) in 0.5 x 0.5 x 1 mm voxels, moved by `shift` mm. */
Image3::Pointer
CylinderImage(double shiftX, double shiftZ)
{
  return MakeImage<3>({ 80, 80, 30 }, { 0.5, 0.5, 1.0 }, [=](const Point<3> & p) {
    Point<3> q = p;
    q[0] -= shiftX;
    q[2] -= shiftZ;
    const bool inside = std::hypot(q[0] - 15.0, q[1] - 14.0) < 10.0 && q[2] >= 5.0 && q[2] < 20.0;
    return (inside ? 110.0 : 10.0) + Texture<3>(q);
  });
}

template <typename TImage>
itk::EdgeHausdorffResult
Evaluate(const TImage * fixed, const TImage * moving, int sliceAxis = 2, const TImage * mask = nullptr,
         typename itk::EdgeHausdorffDistanceImageFilter<TImage, TImage>::Pointer * keep = nullptr)
{
  auto filter = itk::EdgeHausdorffDistanceImageFilter<TImage, TImage>::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  filter->SetMaskImage(mask);
  filter->SetSliceAxis(sliceAxis);
  filter->Update();
  if (keep != nullptr)
  {
    *keep = filter;
  }
  return filter->GetResult();
}

/** For every edge pixel of `from`, the distance (mm, physical points) to the
 *  nearest edge pixel of `to`, by brute force; sorted. */
template <typename TEdgeImage>
std::vector<double>
BruteForceDistances(const TEdgeImage * from, const TEdgeImage * to)
{
  using PointType = typename TEdgeImage::PointType;
  const auto edgePoints = [](const TEdgeImage * edges) {
    std::vector<PointType> points;
    for (itk::ImageRegionConstIteratorWithIndex<TEdgeImage> it(edges, edges->GetBufferedRegion()); !it.IsAtEnd(); ++it)
    {
      if (it.Get() != 0)
      {
        PointType point;
        edges->TransformIndexToPhysicalPoint(it.GetIndex(), point);
        points.push_back(point);
      }
    }
    return points;
  };
  const std::vector<PointType> sources = edgePoints(from);
  const std::vector<PointType> targets = edgePoints(to);
  std::vector<double>          distances;
  for (const PointType & source : sources)
  {
    double nearest = std::numeric_limits<double>::infinity();
    for (const PointType & target : targets)
    {
      nearest = std::min(nearest, source.EuclideanDistanceTo(target));
    }
    distances.push_back(nearest);
  }
  std::sort(distances.begin(), distances.end());
  return distances;
}

/** Nearest-rank percentile K of sorted values: the value of rank ceil(K N / 100). */
double
NearestRank(const std::vector<double> & sorted, int k)
{
  const auto rank = static_cast<std::size_t>(std::ceil(k * static_cast<double>(sorted.size()) / 100.0));
  return sorted[std::max<std::size_t>(rank, 1) - 1];
}

double
FractionWithin(const std::vector<double> & sorted, double threshold)
{
  return static_cast<double>(std::upper_bound(sorted.begin(), sorted.end(), threshold) - sorted.begin()) /
         static_cast<double>(sorted.size());
}

/** The whole curve and fractions against the brute-force nearest-edge search on the filter's own edge sets. */
template <typename TFilter>
void
ExpectMatchesBruteForce(const TFilter * filter)
{
  const itk::EdgeHausdorffResult & result = filter->GetResult();
  const std::vector<double> fixedToMoving = BruteForceDistances(filter->GetFixedEdges(), filter->GetMovingEdges());
  const std::vector<double> movingToFixed = BruteForceDistances(filter->GetMovingEdges(), filter->GetFixedEdges());
  ASSERT_EQ(result.fixedEdgePixels, fixedToMoving.size());
  ASSERT_EQ(result.movingEdgePixels, movingToFixed.size());
  for (int k = 1; k <= 100; ++k)
  {
    EXPECT_NEAR(result.fixedToMoving[k - 1], NearestRank(fixedToMoving, k), 1e-9) << "K = " << k;
    EXPECT_NEAR(result.movingToFixed[k - 1], NearestRank(movingToFixed, k), 1e-9) << "K = " << k;
    EXPECT_EQ(result.symmetric[k - 1], std::max(result.fixedToMoving[k - 1], result.movingToFixed[k - 1]));
  }
  const double threshold = result.distanceThreshold;
  EXPECT_DOUBLE_EQ(result.fractionFixedWithinThreshold, FractionWithin(fixedToMoving, threshold));
  EXPECT_DOUBLE_EQ(result.fractionMovingWithinThreshold, FractionWithin(movingToFixed, threshold));
  EXPECT_DOUBLE_EQ(result.fractionWithinThreshold,
                   (FractionWithin(fixedToMoving, threshold) * static_cast<double>(fixedToMoving.size()) +
                    FractionWithin(movingToFixed, threshold) * static_cast<double>(movingToFixed.size())) /
                     static_cast<double>(fixedToMoving.size() + movingToFixed.size()));
}

template <typename TEdgeImage>
std::size_t
CountEdges(const TEdgeImage * edges)
{
  const unsigned char * begin = edges->GetBufferPointer();
  return static_cast<std::size_t>(std::count_if(
    begin, begin + edges->GetBufferedRegion().GetNumberOfPixels(), [](unsigned char v) { return v != 0; }));
}

std::string
ExceptionMessage(const std::function<void()> & action)
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

template <typename TImage>
typename TImage::Pointer
ReadImage(const fs::path & path)
{
  auto reader = itk::ImageFileReader<TImage>::New();
  reader->SetFileName(path.string());
  reader->Update();
  return reader->GetOutput();
}

template <typename TImage>
void
WriteImage(const TImage * image, const fs::path & path)
{
  auto writer = itk::ImageFileWriter<TImage>::New();
  writer->SetInput(image);
  writer->SetFileName(path.string());
  writer->Update();
}

/** A region of Colin27 (1 mm, 181 x 217 x 181) starting at `start`, as its own image. */
Image3::Pointer
Colin27Region(const Image3 * colin, const itk::Index<3> & start, const itk::Size<3> & size)
{
  auto extract = itk::ExtractImageFilter<Image3, Image3>::New();
  extract->SetInput(colin);
  extract->SetExtractionRegion(Image3::RegionType(start, size));
  extract->SetDirectionCollapseToIdentity();
  extract->Update();
  Image3::Pointer region = extract->GetOutput();
  region->DisconnectPipeline();
  // Same grid for every region (only the content moves), as a resampled image would be.
  Image3::RegionType whole(size);
  region->SetRegions(whole);
  Image3::PointType origin;
  origin.Fill(0.0);
  region->SetOrigin(origin);
  return region;
}

} // namespace

TEST(EdgeHausdorffDistance, IdenticalImagesGiveZeroAtEveryPercentile)
{
  // A real MRI slice (ITK's example data) and a synthetic 3D image in slice and whole-image mode.
  const fs::path slicePath = ItkExamplesData / "BrainProtonDensitySlice.png";
  if (fs::exists(slicePath))
  {
    const Image2::Pointer          slice = ReadImage<Image2>(slicePath);
    const itk::EdgeHausdorffResult result = Evaluate<Image2>(slice, slice);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_GT(result.fixedEdgePixels, 1000u);
    EXPECT_EQ(result.fixedEdgePixels, result.movingEdgePixels);
    EXPECT_EQ(result.slicesEvaluated, 1u);
    ASSERT_EQ(result.symmetric.size(), 100u);
    for (std::size_t k = 0; k < 100; ++k)
    {
      EXPECT_EQ(result.fixedToMoving[k], 0.0);
      EXPECT_EQ(result.movingToFixed[k], 0.0);
      EXPECT_EQ(result.symmetric[k], 0.0);
    }
    EXPECT_EQ(result.fractionWithinThreshold, 1.0);
    EXPECT_EQ(result.fractionFixedWithinThreshold, 1.0);
    EXPECT_EQ(result.fractionMovingWithinThreshold, 1.0);
  }
  const Image3::Pointer cylinder = CylinderImage(0.0, 0.0);
  for (const int axis : { 2, 0, -1 })
  {
    const itk::EdgeHausdorffResult result = Evaluate<Image3>(cylinder, cylinder, axis);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_GT(result.fixedEdgePixels, 500u) << "axis " << axis;
    EXPECT_EQ(result.symmetric.back(), 0.0) << "axis " << axis;
    EXPECT_EQ(result.fractionWithinThreshold, 1.0);
    EXPECT_EQ(result.slicesSkipped, 0u);
  }
}

TEST(EdgeHausdorffDistance, TwoMillimetreShiftGivesACurveUpToTwoMillimetres)
{
  // Disk of radius R = 12 mm moved by d = 2 mm along x (4 pixels of 0.5 mm).
  // An edge point at angle theta lies ||p - c'| - R| ~ d |cos theta| from the
  // moved circle: the directed distances run from ~0 (theta = 90 deg) to
  // exactly d (theta = 0; the moved edge set is the exact translate, so no
  // distance exceeds d); the continuous median is d sin(45 deg) = 1.41 mm and
  // the fraction within 1.7 mm (2/pi) asin(0.85) = 0.65. Pixel edges move
  // each value by up to half a diagonal pixel (0.35 mm): bands below.
  Filter2::Pointer               filter;
  const itk::EdgeHausdorffResult result = Evaluate<Image2>(DiskImage(0.0), DiskImage(2.0), 2, nullptr, &filter);
  ASSERT_TRUE(result.valid) << result.message;
  // Only the circle is an edge: its length 2 pi 12 mm is ~151 pixels along a
  // diagonal-free path and up to sqrt(2) times more in pixel steps.
  EXPECT_GT(result.fixedEdgePixels, 130u);
  EXPECT_LT(result.fixedEdgePixels, 260u);
  for (const auto * curve : { &result.fixedToMoving, &result.movingToFixed, &result.symmetric })
  {
    EXPECT_GE(curve->back(), 1.8);
    EXPECT_LE(curve->back(), 2.0 + 1e-9);
    EXPECT_GE((*curve)[49], 1.1);
    EXPECT_LE((*curve)[49], 1.7);
    EXPECT_LE((*curve)[0], 0.5);
  }
  EXPECT_GT(result.fractionWithinThreshold, 0.5);
  EXPECT_LT(result.fractionWithinThreshold, 0.8);
  ExpectMatchesBruteForce(filter.GetPointer());
}

TEST(EdgeHausdorffDistance, UsesPhysicalSpacingOfAnisotropicPixels)
{
  // A bright box in 0.5 x 2 mm pixels, moved by whole pixels: 4 pixels along x
  // (2 mm) or 2 pixels along y (4 mm). The edges perpendicular to the shift
  // lie exactly the shift away from their translates and nothing lies farther,
  // so the 100th percentile is the shift in mm (in pixels it would be 4 and 2).
  const auto box = [](double shiftX, double shiftY) {
    return MakeImage<2>({ 100, 40 }, { 0.5, 2.0 }, [=](const Point<2> & p) {
      Point<2> q;
      q[0] = p[0] - shiftX;
      q[1] = p[1] - shiftY;
      const bool inside = q[0] >= 10.0 && q[0] < 30.0 && q[1] >= 20.0 && q[1] < 50.0;
      return (inside ? 110.0 : 10.0) + Texture<2>(q);
    });
  };
  const Image2::Pointer fixed = box(0.0, 0.0);
  {
    Filter2::Pointer               filter;
    const itk::EdgeHausdorffResult result = Evaluate<Image2>(fixed, box(2.0, 0.0), 2, nullptr, &filter);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_NEAR(result.symmetric.back(), 2.0, 1e-9);
    EXPECT_NEAR(result.fixedToMoving.back(), 2.0, 1e-9);
    ExpectMatchesBruteForce(filter.GetPointer());
  }
  {
    Filter2::Pointer               filter;
    const itk::EdgeHausdorffResult result = Evaluate<Image2>(fixed, box(0.0, 4.0), 2, nullptr, &filter);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_NEAR(result.symmetric.back(), 4.0, 1e-9);
    EXPECT_NEAR(result.movingToFixed.back(), 4.0, 1e-9);
    ExpectMatchesBruteForce(filter.GetPointer());
  }
}

TEST(EdgeHausdorffDistance, AgreesWithItkHausdorffDistanceOnTheSameEdgeSets)
{
  // Non-integer shifts, so that the edge sets differ in shape, in 2D and in 3D
  // with anisotropic voxels and a mask (whole-image mode).
  const auto check = [](auto filter) {
    using EdgeImageType = typename std::remove_pointer_t<decltype(filter)>::EdgeImageType;
    const itk::EdgeHausdorffResult & result = filter->GetResult();
    ASSERT_TRUE(result.valid) << result.message;
    auto hausdorff = itk::HausdorffDistanceImageFilter<EdgeImageType, EdgeImageType>::New();
    hausdorff->SetInput1(filter->GetFixedEdges());
    hausdorff->SetInput2(filter->GetMovingEdges());
    hausdorff->SetUseImageSpacing(true);
    hausdorff->Update();
    EXPECT_NEAR(result.symmetric.back(), hausdorff->GetHausdorffDistance(), 1e-9);
    auto directed = itk::DirectedHausdorffDistanceImageFilter<EdgeImageType, EdgeImageType>::New();
    directed->SetInput1(filter->GetFixedEdges());
    directed->SetInput2(filter->GetMovingEdges());
    directed->SetUseImageSpacing(true);
    directed->Update();
    EXPECT_NEAR(result.fixedToMoving.back(), directed->GetDirectedHausdorffDistance(), 1e-9);
    EXPECT_GT(result.symmetric.back(), 0.5);
  };
  {
    Filter2::Pointer filter;
    Evaluate<Image2>(DiskImage(0.0), DiskImage(1.3, -0.7), 2, nullptr, &filter);
    check(filter.GetPointer());
  }
  {
    const auto sphere = [](double shiftX, double shiftY, double shiftZ) {
      return MakeImage<3>({ 50, 50, 24 }, { 0.8, 0.8, 1.5 }, [=](const Point<3> & p) {
        const double r = std::sqrt(std::pow(p[0] - shiftX - 15.0, 2) + std::pow(p[1] - shiftY - 14.0, 2) +
                                   std::pow((p[2] - shiftZ - 12.0) * 1.2, 2));
        return r < 11.0 ? 100.0 : 20.0;
      });
    };
    const Image3::Pointer mask =
      MakeImage<3>({ 50, 50, 24 }, { 0.8, 0.8, 1.5 }, [](const Point<3> & p) { return p[0] < 18.0 ? 1.0 : 0.0; });
    Filter3::Pointer filter;
    Evaluate<Image3>(sphere(0.0, 0.0, 0.0), sphere(1.3, 0.4, 2.1), -1, mask.GetPointer(), &filter);
    check(filter.GetPointer());
    EXPECT_FALSE(filter->GetSliceModeUsed());
  }
}

TEST(EdgeHausdorffDistance, SliceModeMeasuresInSliceDistances)
{
  // A cylinder along z (15 slices of 1 mm) moved 2 mm along z: every axial
  // slice through both cylinders shows the same disk (distance 0); the two
  // slices at each end show the disk in one image only and are skipped. In
  // 3D the caps move by 2 mm.
  const Image3::Pointer fixed = CylinderImage(0.0, 0.0);
  {
    const itk::EdgeHausdorffResult result = Evaluate<Image3>(fixed, CylinderImage(0.0, 2.0), 2);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_EQ(result.slicesEvaluated, 13u);
    EXPECT_EQ(result.slicesSkipped, 4u);
    EXPECT_CONTAINS(result.message, "4 slices across axis 2 had edges in only one image and were skipped");
    EXPECT_EQ(result.symmetric.back(), 0.0);
    EXPECT_EQ(result.fractionWithinThreshold, 1.0);
  }
  {
    const itk::EdgeHausdorffResult result = Evaluate<Image3>(fixed, CylinderImage(0.0, 2.0), -1);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_GE(result.symmetric.back(), 1.8);
    EXPECT_LE(result.symmetric.back(), 2.0 + 1e-9);
  }
  // Moved 2 mm along x: each axial slice is the 2D disk case (radius 10 mm).
  {
    Filter3::Pointer               filter;
    const itk::EdgeHausdorffResult result = Evaluate<Image3>(fixed, CylinderImage(2.0, 0.0), 2, nullptr, &filter);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_TRUE(filter->GetSliceModeUsed());
    EXPECT_EQ(result.slicesEvaluated, 15u);
    EXPECT_EQ(result.slicesSkipped, 0u);
    EXPECT_GE(result.symmetric.back(), 1.8);
    EXPECT_LE(result.symmetric.back(), 2.0 + 1e-9);
    EXPECT_GE(result.symmetric[49], 1.1);
    EXPECT_LE(result.symmetric[49], 1.7);
    // The stacked 2D edges: every evaluated slice has its own circle.
    const std::vector<itk::IndexValueType> slices =
      itk::EdgeOverlaySlices(filter->GetFixedEdges(), filter->GetMovingEdges(), 2);
    ASSERT_EQ(slices.size(), 15u);
    EXPECT_EQ(slices.front(), 10);
    EXPECT_EQ(slices.back(), 24);
    EXPECT_EQ(CountEdges(filter->GetFixedEdges()), result.fixedEdgePixels);
  }
}

TEST(EdgeHausdorffDistance, MaskRestrictsTheEdgePixelsOfBothImages)
{
  // The left half of the field: the masked edges are exactly the unmasked
  // edges inside the mask (edges are detected on the whole image, so the mask
  // border is no edge), and the curve is that of those edge sets.
  const Image2::Pointer fixed = DiskImage(0.0);
  const Image2::Pointer moving = DiskImage(2.0);
  const Image2::Pointer mask =
    MakeImage<2>({ 120, 120 }, { 0.5, 0.5 }, [](const Point<2> & p) { return p[0] < 22.0 ? 1.0 : 0.0; });
  // The same thresholds in both runs (automatic ones come from the pixels inside the mask).
  const auto run = [&](const Image2 * roi, Filter2::Pointer & filter) {
    filter = Filter2::New();
    filter->SetFixedImage(fixed);
    filter->SetMovingImage(moving);
    filter->SetMaskImage(roi);
    filter->SetUpperThreshold(4.0);
    filter->SetLowerThreshold(1.5);
    filter->Update();
    EXPECT_EQ(filter->GetMovingUpperThresholdUsed(), 4.0);
    EXPECT_EQ(filter->GetMovingLowerThresholdUsed(), 1.5);
    return filter->GetResult();
  };
  Filter2::Pointer               unmasked;
  Filter2::Pointer               masked;
  const itk::EdgeHausdorffResult whole = run(nullptr, unmasked);
  const itk::EdgeHausdorffResult half = run(mask, masked);
  ASSERT_TRUE(half.valid) << half.message;
  for (const bool isFixed : { true, false })
  {
    const Edges2 * all = isFixed ? unmasked->GetFixedEdges() : unmasked->GetMovingEdges();
    const Edges2 * inside = isFixed ? masked->GetFixedEdges() : masked->GetMovingEdges();
    std::size_t    expected = 0;
    std::size_t    mismatches = 0;
    for (itk::ImageRegionConstIteratorWithIndex<Edges2> it(all, all->GetBufferedRegion()); !it.IsAtEnd(); ++it)
    {
      const bool in = mask->GetPixel(it.GetIndex()) > 0.0f;
      const bool edge = it.Get() != 0 && in;
      expected += edge ? 1 : 0;
      mismatches += (inside->GetPixel(it.GetIndex()) != 0) != edge ? 1 : 0;
    }
    EXPECT_EQ(mismatches, 0u);
    EXPECT_EQ(isFixed ? half.fixedEdgePixels : half.movingEdgePixels, expected);
  }
  EXPECT_LT(static_cast<double>(half.fixedEdgePixels), 0.8 * static_cast<double>(whole.fixedEdgePixels));
  EXPECT_GT(static_cast<double>(half.fixedEdgePixels), 0.3 * static_cast<double>(whole.fixedEdgePixels));
  ExpectMatchesBruteForce(masked.GetPointer());
}

TEST(EdgeHausdorffDistance, AutomaticThresholdsFollowTheIntensityScale)
{
  // MRI comes in arbitrary intensity units: the automatic thresholds scale with
  // the image, so the edges do not change when the intensities are multiplied,
  // and each image gets its own thresholds (fixed x 10, moving x 1000).
  const auto scaled = [](double factor, double shiftX) {
    return MakeImage<2>({ 120, 120 }, { 0.5, 0.5 }, [=](const Point<2> & p) { return factor * Disk(p, shiftX, 0.0); });
  };
  Filter2::Pointer               reference;
  Filter2::Pointer               rescaled;
  const itk::EdgeHausdorffResult one = Evaluate<Image2>(scaled(1.0, 0.0), scaled(1.0, 1.5), 2, nullptr, &reference);
  const itk::EdgeHausdorffResult other =
    Evaluate<Image2>(scaled(10.0, 0.0), scaled(1000.0, 1.5), 2, nullptr, &rescaled);
  ASSERT_TRUE(one.valid && other.valid);
  EXPECT_NEAR(rescaled->GetFixedUpperThresholdUsed(),
              10.0 * reference->GetFixedUpperThresholdUsed(),
              1e-4 * rescaled->GetFixedUpperThresholdUsed());
  EXPECT_NEAR(rescaled->GetMovingUpperThresholdUsed(),
              1000.0 * reference->GetMovingUpperThresholdUsed(),
              1e-4 * rescaled->GetMovingUpperThresholdUsed());
  EXPECT_NEAR(rescaled->GetMovingLowerThresholdUsed(), 0.4 * rescaled->GetMovingUpperThresholdUsed(), 1e-9);
  EXPECT_EQ(one.fixedToMoving, other.fixedToMoving);
  EXPECT_EQ(one.movingToFixed, other.movingToFixed);
  EXPECT_EQ(one.fixedEdgePixels, other.fixedEdgePixels);
  // Fixed thresholds far above the edge strength find nothing.
  auto filter = Filter2::New();
  filter->SetFixedImage(scaled(1.0, 0.0));
  filter->SetMovingImage(scaled(1.0, 1.5));
  filter->SetUpperThreshold(1000.0);
  filter->Update();
  EXPECT_FALSE(filter->GetResult().valid);
  EXPECT_EQ(filter->GetFixedLowerThresholdUsed(), 400.0);
}

TEST(EdgeHausdorffDistance, BadInputThrowsNamingTheProblem)
{
  const Image2::Pointer fixed = DiskImage(0.0);
  const auto            run = [&](const Image2 * moving, const Image2 * mask) {
    return ExceptionMessage([&] { Evaluate<Image2>(fixed, moving, 2, mask); });
  };
  // Another size.
  const Image2::Pointer smaller =
    MakeImage<2>({ 100, 120 }, { 0.5, 0.5 }, [](const Point<2> & p) { return Disk(p, 0.0, 0.0); });
  std::string message = run(smaller, nullptr);
  EXPECT_CONTAINS(message, "moving (registered preoperative) image is not on the fixed (intraoperative) image grid");
  EXPECT_CONTAINS(message, "size [100, 120]");
  EXPECT_CONTAINS(message, "biomech warp");
  // Another spacing, another origin.
  const Image2::Pointer coarser = DiskImage(0.0);
  Image2::SpacingType   spacing;
  spacing.Fill(0.6);
  coarser->SetSpacing(spacing);
  EXPECT_CONTAINS(run(coarser, nullptr), "spacing [0.6, 0.6]");
  const Image2::Pointer moved = DiskImage(0.0);
  Image2::PointType     origin;
  origin.Fill(-4.0);
  moved->SetOrigin(origin);
  message = run(moved, nullptr);
  EXPECT_CONTAINS(message, "origin [-4, -4]");
  EXPECT_EQ(message.find("size"), std::string::npos) << message;
  // A mask on another grid.
  EXPECT_CONTAINS(run(fixed, smaller), "the mask is not on the fixed (intraoperative) image grid");
  // An empty mask, a missing moving image, NaN, bad parameters.
  const Image2::Pointer empty = MakeImage<2>({ 120, 120 }, { 0.5, 0.5 }, [](const Point<2> &) { return 0.0; });
  EXPECT_CONTAINS(run(fixed, empty), "the mask has no voxel > 0");
  EXPECT_CONTAINS(ExceptionMessage([&] {
                    auto filter = Filter2::New();
                    filter->SetFixedImage(fixed);
                    filter->Update();
                  }),
                  "the moving (registered preoperative) image is not set");
  const Image2::Pointer withNaN = DiskImage(0.0);
  withNaN->SetPixel({ { 3, 4 } }, std::numeric_limits<float>::quiet_NaN());
  EXPECT_CONTAINS(run(withNaN, nullptr), "contains 1 NaN or infinite pixel(s), the first at index [3, 4]");
  const auto withParameter = [&](const std::function<void(Filter2 *)> & set) {
    return ExceptionMessage([&] {
      auto filter = Filter2::New();
      filter->SetFixedImage(fixed);
      filter->SetMovingImage(fixed);
      set(filter);
      filter->Update();
    });
  };
  EXPECT_CONTAINS(withParameter([](Filter2 * f) { f->SetVariance(0.0); }), "Variance must be a positive number");
  EXPECT_CONTAINS(withParameter([](Filter2 * f) {
                    f->SetUpperThreshold(2.0);
                    f->SetLowerThreshold(3.0);
                  }),
                  "the lower threshold 3 exceeds the upper threshold 2");
  EXPECT_CONTAINS(ExceptionMessage([] {
                    const Image3::Pointer cylinder = CylinderImage(0.0, 0.0);
                    Evaluate<Image3>(cylinder, cylinder, 3);
                  }),
                  "SliceAxis must be -1 (whole image) or an axis 0..2, got 3");
}

TEST(EdgeHausdorffDistance, EmptyEdgeSetIsAnInvalidResultNotAnError)
{
  const Image2::Pointer    fixed = DiskImage(0.0);
  const Image2::Pointer    flat = MakeImage<2>({ 120, 120 }, { 0.5, 0.5 }, [](const Point<2> &) { return 37.0; });
  itk::EdgeHausdorffResult result;
  ASSERT_NO_THROW(result = Evaluate<Image2>(fixed, flat));
  EXPECT_FALSE(result.valid);
  EXPECT_TRUE(result.fixedToMoving.empty());
  EXPECT_TRUE(result.symmetric.empty());
  EXPECT_GT(result.fixedEdgePixels, 100u);
  EXPECT_EQ(result.movingEdgePixels, 0u);
  EXPECT_EQ(result.fractionWithinThreshold, 0.0);
  EXPECT_CONTAINS(result.message, "the moving (registered preoperative) image has no edges");
  EXPECT_CONTAINS(result.message, "lower the Canny thresholds, use a smaller variance or a bigger mask");

  ASSERT_NO_THROW(result = Evaluate<Image2>(flat, flat));
  EXPECT_FALSE(result.valid);
  EXPECT_CONTAINS(result.message, "neither the fixed (intraoperative) nor the moving");

  // Slice mode: edges in both images but never in the same slice.
  const Image3::Pointer low = CylinderImage(0.0, -9.0);
  const Image3::Pointer high = CylinderImage(0.0, 9.0);
  ASSERT_NO_THROW(result = Evaluate<Image3>(low, high, 2));
  EXPECT_FALSE(result.valid);
  EXPECT_EQ(result.slicesSkipped, 26u); // fixed in slices 1..15, moving in 19..29
  EXPECT_CONTAINS(result.message,
                  "no slice across axis 2 has edges in both images (26 slices with edges in only one were skipped)");
}

TEST(EdgeHausdorffDistance, SameResultForAnyNumberOfThreads)
{
  const Image3::Pointer                 fixed = CylinderImage(0.0, 0.0);
  const Image3::Pointer                 moving = CylinderImage(1.3, 0.6);
  const int                             defaultThreads = itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads();
  std::vector<itk::EdgeHausdorffResult> results;
  std::vector<Filter3::Pointer>         filters;
  for (const int threads : { 1, 3 })
  {
    itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(threads);
    for (const int axis : { 2, -1 })
    {
      Filter3::Pointer filter;
      results.push_back(Evaluate<Image3>(fixed, moving, axis, nullptr, &filter));
      filters.push_back(filter);
    }
  }
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(defaultThreads);
  for (std::size_t mode = 0; mode < 2; ++mode)
  {
    const auto & one = results[mode];
    const auto & three = results[mode + 2];
    ASSERT_TRUE(one.valid);
    EXPECT_EQ(one.fixedToMoving, three.fixedToMoving);
    EXPECT_EQ(one.movingToFixed, three.movingToFixed);
    EXPECT_EQ(one.fractionWithinThreshold, three.fractionWithinThreshold);
    const unsigned char * a = filters[mode]->GetFixedEdges()->GetBufferPointer();
    const unsigned char * b = filters[mode + 2]->GetFixedEdges()->GetBufferPointer();
    EXPECT_TRUE(std::equal(a, a + fixed->GetBufferedRegion().GetNumberOfPixels(), b));
  }
}

TEST(EdgeHausdorffDistance, Colin27IdenticalGivesZeroAndShiftedGivesAtMostTheShift)
{
  if (!fs::exists(Colin27))
  {
    GTEST_SKIP() << "mricron-data is not installed (scripts/install-dependencies.sh installs it)";
  }
  // A 100 x 110 x 24 mm block through the ventricles (kept small for speed).
  const Image3::Pointer colin = ReadImage<Image3>(Colin27);
  const itk::Size<3>    size{ { 100, 110, 24 } };
  const Image3::Pointer fixed = Colin27Region(colin, { { 40, 50, 80 } }, size);
  for (const int axis : { 2, -1 })
  {
    const itk::EdgeHausdorffResult result = Evaluate<Image3>(fixed, fixed, axis);
    ASSERT_TRUE(result.valid) << result.message;
    EXPECT_GT(result.fixedEdgePixels, 5000u);
    EXPECT_EQ(result.symmetric.back(), 0.0);
    EXPECT_EQ(result.fractionWithinThreshold, 1.0);
  }
  // The content moved by 2 voxels (2 mm) along x: away from the block's faces
  // every edge has its translate 2 mm away, so almost all distances are <= 2 mm.
  const Image3::Pointer          moving = Colin27Region(colin, { { 38, 50, 80 } }, size);
  const itk::EdgeHausdorffResult result = Evaluate<Image3>(fixed, moving, 2);
  ASSERT_TRUE(result.valid) << result.message;
  EXPECT_LE(result.symmetric[94], 2.0 + 1e-9);
  EXPECT_GE(result.symmetric[94], 1.0);
  EXPECT_GT(result.fractionWithinThreshold, 0.5);
}

TEST(EdgeHausdorffDistance, OverlaySlicesColourTheEdges)
{
  auto fixedEdges = Edges3::New();
  fixedEdges->SetRegions(itk::Size<3>{ { 4, 3, 5 } });
  fixedEdges->Allocate(true);
  auto movingEdges = Edges3::New();
  movingEdges->SetRegions(fixedEdges->GetBufferedRegion());
  movingEdges->Allocate(true);
  const Image3::Pointer background =
    MakeImage<3>({ 4, 3, 5 }, { 1.0, 1.0, 1.0 }, [](const Point<3> & p) { return 10.0 * (p[0] + 5.0); });
  background->SetOrigin(fixedEdges->GetOrigin());
  fixedEdges->SetPixel({ { 1, 1, 2 } }, 1);
  movingEdges->SetPixel({ { 2, 1, 2 } }, 1);
  fixedEdges->SetPixel({ { 3, 2, 2 } }, 1);
  movingEdges->SetPixel({ { 3, 2, 2 } }, 1);
  movingEdges->SetPixel({ { 0, 0, 4 } }, 1);
  EXPECT_EQ(itk::EdgeOverlaySlices(fixedEdges.GetPointer(), movingEdges.GetPointer(), 2),
            (std::vector<itk::IndexValueType>{ 2, 4 }));
  EXPECT_EQ(itk::EdgeOverlaySlices(fixedEdges.GetPointer(), movingEdges.GetPointer(), 0),
            (std::vector<itk::IndexValueType>{ 0, 1, 2, 3 }));
  const auto overlay = itk::MakeEdgeOverlaySlice(
    fixedEdges.GetPointer(), movingEdges.GetPointer(), background.GetPointer(), 2, 2, 0.0, 30.0);
  ASSERT_EQ(overlay->GetLargestPossibleRegion().GetSize(), (itk::Size<2>{ { 4, 3 } }));
  using RGB = itk::RGBPixel<unsigned char>;
  const auto rgb = [](unsigned char r, unsigned char g, unsigned char b) {
    RGB pixel;
    pixel.Set(r, g, b);
    return pixel;
  };
  EXPECT_EQ(overlay->GetPixel({ { 1, 1 } }), rgb(255, 0, 0));
  EXPECT_EQ(overlay->GetPixel({ { 2, 1 } }), rgb(0, 0, 255));
  EXPECT_EQ(overlay->GetPixel({ { 3, 2 } }), rgb(0, 255, 0));
  EXPECT_EQ(overlay->GetPixel({ { 0, 0 } }), rgb(0, 0, 0));       // grey 0 at the minimum
  EXPECT_EQ(overlay->GetPixel({ { 1, 0 } }), rgb(85, 85, 85));    // 10 of [0, 30]
  EXPECT_EQ(overlay->GetPixel({ { 3, 0 } }), rgb(255, 255, 255)); // 30, clamped above
  // Across axis 0 the rows are flipped so that axis 2 points up.
  const auto sagittal = itk::MakeEdgeOverlaySlice(
    fixedEdges.GetPointer(), movingEdges.GetPointer(), background.GetPointer(), 0, 1, 0.0, 30.0);
  ASSERT_EQ(sagittal->GetLargestPossibleRegion().GetSize(), (itk::Size<2>{ { 3, 5 } }));
  EXPECT_EQ(sagittal->GetPixel({ { 1, 4 - 2 } }), rgb(255, 0, 0));
}

// ---------------------------------------------------------------------------
// biomech evaluate
// ---------------------------------------------------------------------------

class EdgeHausdorffCommandTest : public bmr::test::TemporaryFolderTest
{
protected:
  bmr::test::CommandResult
  Biomech(const std::string & arguments) const
  {
    return bmr::test::RunBiomech(m_Folder, arguments);
  }
  std::string
  Path(const std::string & name) const
  {
    return "'" + (m_Folder / name).string() + "'";
  }
};

TEST_F(EdgeHausdorffCommandTest, ReportMatchesTheFilter)
{
  // 2D images (read by the command as one-slice volumes).
  WriteImage<Image2>(DiskImage(0.0), m_Folder / "fixed.mha");
  WriteImage<Image2>(DiskImage(1.5, 0.5), m_Folder / "moving.mha");
  const auto run = Biomech("evaluate " + Path("fixed.mha") + " " + Path("moving.mha") + " -o " +
                           Path("out/report.json") + " --overlays " + Path("out/png") + " --threshold 1.2");
  ASSERT_EQ(run.exitCode, 0) << run.err;
  EXPECT_CONTAINS(run.out, "symmetric");
  EXPECT_CONTAINS(run.out, "within 1.2 mm");
  const json report = json::parse(bmr::test::ReadText(m_Folder / "out/report.json"));

  auto filter = itk::EdgeHausdorffDistanceImageFilter<Image3, Image3>::New();
  filter->SetFixedImage(ReadImage<Image3>(m_Folder / "fixed.mha"));
  filter->SetMovingImage(ReadImage<Image3>(m_Folder / "moving.mha"));
  filter->SetDistanceThreshold(1.2);
  filter->Update();
  const itk::EdgeHausdorffResult & result = filter->GetResult();
  ASSERT_TRUE(result.valid);
  EXPECT_EQ(report["valid"], true);
  EXPECT_EQ(report["mode"], "2d");
  EXPECT_EQ(report["image"]["dimension"], 2);
  EXPECT_EQ(report["parameters"]["variance_mm2"].get<double>(), filter->GetVariance());
  EXPECT_EQ(report["parameters"]["distance_threshold_mm"].get<double>(), 1.2);
  EXPECT_EQ(report["percentiles"].size(), 100u);
  EXPECT_EQ(report["fixed_to_moving_mm"].get<std::vector<double>>(), result.fixedToMoving);
  EXPECT_EQ(report["moving_to_fixed_mm"].get<std::vector<double>>(), result.movingToFixed);
  EXPECT_EQ(report["symmetric_mm"].get<std::vector<double>>(), result.symmetric);
  EXPECT_EQ(report["hausdorff_mm"].get<double>(), result.symmetric.back());
  EXPECT_EQ(report["fraction_within_threshold"]["pooled"].get<double>(), result.fractionWithinThreshold);
  EXPECT_EQ(report["fraction_within_threshold"]["fixed_to_moving"].get<double>(), result.fractionFixedWithinThreshold);
  EXPECT_EQ(report["counts"]["fixed_edge_pixels"].get<std::size_t>(), result.fixedEdgePixels);
  EXPECT_EQ(report["counts"]["moving_edge_pixels"].get<std::size_t>(), result.movingEdgePixels);
  EXPECT_EQ(report["thresholds_used"]["fixed"]["upper"].get<double>(), filter->GetFixedUpperThresholdUsed());
  EXPECT_GT(report["seconds"]["total"].get<double>(), 0.0);
  EXPECT_TRUE(fs::is_regular_file(m_Folder / "out/png/edges.png"));
  EXPECT_EQ(report["overlays"]["files"], 1);

  // 3D, slice mode across axis 2 with a mask, and whole-image mode; --quiet prints nothing.
  WriteImage<Image3>(CylinderImage(0.0, 0.0), m_Folder / "fixed3.nii.gz");
  WriteImage<Image3>(CylinderImage(1.0, 1.0), m_Folder / "moving3.nii.gz");
  WriteImage<Image3>(
    MakeImage<3>({ 80, 80, 30 }, { 0.5, 0.5, 1.0 }, [](const Point<3> & p) { return p[1] < 16.0 ? 1.0 : 0.0; }),
    m_Folder / "mask3.nii.gz");
  for (const std::string axis : { "2", "none" })
  {
    const auto run3 =
      Biomech("evaluate " + Path("fixed3.nii.gz") + " " + Path("moving3.nii.gz") + " --mask " + Path("mask3.nii.gz") +
              " --slice-axis " + axis + " --quiet -o " + Path("report3.json") + " --overlays " + Path("png3-" + axis));
    ASSERT_EQ(run3.exitCode, 0) << run3.err;
    EXPECT_EQ(run3.out, "");
    const json report3 = json::parse(bmr::test::ReadText(m_Folder / "report3.json"));
    auto       filter3 = Filter3::New();
    filter3->SetFixedImage(ReadImage<Image3>(m_Folder / "fixed3.nii.gz"));
    filter3->SetMovingImage(ReadImage<Image3>(m_Folder / "moving3.nii.gz"));
    filter3->SetMaskImage(ReadImage<Image3>(m_Folder / "mask3.nii.gz"));
    filter3->SetSliceAxis(axis == "none" ? -1 : 2);
    filter3->Update();
    EXPECT_EQ(report3["symmetric_mm"].get<std::vector<double>>(), filter3->GetResult().symmetric);
    EXPECT_EQ(report3["counts"]["slices_evaluated"].get<std::size_t>(), filter3->GetResult().slicesEvaluated);
    EXPECT_EQ(report3["counts"]["slices_skipped"].get<std::size_t>(), filter3->GetResult().slicesSkipped);
    EXPECT_EQ(report3["mode"], axis == "none" ? "3d" : "slices");
    const std::size_t slicesWithEdges =
      itk::EdgeOverlaySlices(filter3->GetFixedEdges(), filter3->GetMovingEdges(), 2).size();
    EXPECT_GT(slicesWithEdges, 10u);
    EXPECT_EQ(report3["overlays"]["files"].get<std::size_t>(), slicesWithEdges);
    std::size_t pngs = 0;
    for (const auto & entry : fs::directory_iterator(m_Folder / ("png3-" + axis)))
    {
      pngs += entry.path().extension() == ".png" ? 1 : 0;
    }
    EXPECT_EQ(pngs, slicesWithEdges);
  }
}

TEST_F(EdgeHausdorffCommandTest, BadInputExitsOneAndWritesNothing)
{
  WriteImage<Image2>(DiskImage(0.0), m_Folder / "fixed.mha");
  WriteImage<Image2>(MakeImage<2>({ 100, 120 }, { 0.5, 0.5 }, [](const Point<2> & p) { return Disk(p, 0.0, 0.0); }),
                     m_Folder / "other-grid.mha");
  WriteImage<Image2>(MakeImage<2>({ 120, 120 }, { 0.5, 0.5 }, [](const Point<2> &) { return 5.0; }),
                     m_Folder / "flat.mha");
  const std::string outputs = " -o " + Path("report.json") + " --overlays " + Path("png");
  const auto        expectFailure = [&](const std::string & arguments, const std::string & message) {
    const auto run = Biomech("evaluate " + arguments + outputs);
    EXPECT_EQ(run.exitCode, 1) << arguments;
    EXPECT_CONTAINS(run.err, "biomech: error: ");
    EXPECT_CONTAINS(run.err, message);
    EXPECT_FALSE(fs::exists(m_Folder / "report.json")) << arguments;
    EXPECT_FALSE(fs::exists(m_Folder / "png")) << arguments;
  };
  expectFailure(Path("fixed.mha") + " " + Path("other-grid.mha"),
                "the moving (registered preoperative) image is not on the fixed (intraoperative) image grid: size");
  expectFailure(Path("fixed.mha") + " " + Path("fixed.mha") + " --mask " + Path("other-grid.mha"),
                "the mask is not on the fixed (intraoperative) image grid");
  expectFailure(Path("fixed.mha") + " " + Path("flat.mha"),
                "no distances: the moving (registered preoperative) image has no edges");
  expectFailure(Path("fixed.mha") + " " + Path("missing.mha"), "cannot read moving (registered preoperative) image");
  expectFailure(Path("fixed.mha") + " " + Path("fixed.mha") + " --slice-axis 3", "--slice-axis");
  expectFailure(Path("fixed.mha") + " " + Path("fixed.mha") + " --variance -1", "--variance");
  expectFailure(Path("fixed.mha") + " " + Path("fixed.mha") + " --upper-threshold 2 --lower-threshold 3",
                "the lower threshold 3 exceeds the upper threshold 2");
}
