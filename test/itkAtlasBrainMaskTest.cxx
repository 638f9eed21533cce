// Atlas-based skull stripping (itk::AtlasBrainMaskImageFilter): Colin27 with a
// known affine transform, the identity, repeatability, and clear errors.
#include "itkAtlasBrainMaskImageFilter.h"

#include "itkAffineTransform.h"
#include "itkImageFileReader.h"
#include "itkImageRegionConstIterator.h"
#include "itkImageRegionIterator.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkLinearInterpolateImageFunction.h"
#include "itkMultiThreaderBase.h"
#include "itkNearestNeighborInterpolateImageFunction.h"
#include "itkResampleImageFilter.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

namespace
{

using AtlasImage = itk::Image<float, 3>;
using MaskImage = itk::Image<unsigned char, 3>;
using AtlasFilter = itk::AtlasBrainMaskImageFilter<AtlasImage, MaskImage>;

const std::string colinT1 = "/usr/share/mricron/templates/ch2.nii.gz";
const std::string colinBrain = "/usr/share/mricron/templates/ch2bet.nii.gz";

bool
ColinAvailable()
{
  return std::filesystem::exists(colinT1) && std::filesystem::exists(colinBrain);
}

AtlasImage::Pointer
ReadImage(const std::string & fileName)
{
  auto reader = itk::ImageFileReader<AtlasImage>::New();
  reader->SetFileName(fileName);
  reader->Update();
  return reader->GetOutput();
}

// Colin27 T1 and brain, read once for all tests.
struct Colin
{
  AtlasImage::Pointer t1;
  AtlasImage::Pointer brain;
};

const Colin &
GetColin()
{
  static const Colin colin{ ReadImage(colinT1), ReadImage(colinBrain) };
  return colin;
}

// Dice coefficient of two 0/non-0 images on the same grid.
template <typename TImageA, typename TImageB>
double
Dice(const TImageA * a, const TImageB * b)
{
  EXPECT_EQ(a->GetLargestPossibleRegion(), b->GetLargestPossibleRegion());
  itk::ImageRegionConstIterator<TImageA> itA(a, a->GetLargestPossibleRegion());
  itk::ImageRegionConstIterator<TImageB> itB(b, b->GetLargestPossibleRegion());
  double both = 0.0, countA = 0.0, countB = 0.0;
  for (; !itA.IsAtEnd(); ++itA, ++itB)
  {
    const bool inA = itA.Get() > 0;
    const bool inB = itB.Get() > 0;
    both += (inA && inB) ? 1.0 : 0.0;
    countA += inA ? 1.0 : 0.0;
    countB += inB ? 1.0 : 0.0;
  }
  return 2.0 * both / (countA + countB);
}

// Resamples an atlas-space image through `subjectToAtlas` onto `grid`.
AtlasImage::Pointer
Resample(const AtlasImage * image, const itk::Transform<double, 3, 3> * subjectToAtlas, const AtlasImage * grid,
         bool nearestNeighbour)
{
  auto resample = itk::ResampleImageFilter<AtlasImage, AtlasImage>::New();
  resample->SetInput(image);
  resample->SetTransform(subjectToAtlas);
  resample->SetOutputParametersFromImage(grid);
  resample->SetDefaultPixelValue(0.0f);
  if (nearestNeighbour)
  {
    resample->SetInterpolator(itk::NearestNeighborInterpolateImageFunction<AtlasImage, double>::New());
  }
  else
  {
    resample->SetInterpolator(itk::LinearInterpolateImageFunction<AtlasImage, double>::New());
  }
  resample->Update();
  return resample->GetOutput();
}

// Known subject-to-atlas affine map: rotation of 10 degrees about an oblique
// axis, anisotropic scaling 0.95 / 1.05 / 1.08, translation ~10 mm, about the
// atlas centre.
itk::AffineTransform<double, 3>::Pointer
KnownSubjectToAtlasTransform(const AtlasImage * atlas, double angleDegrees = 10.0, double translationScale = 1.0)
{
  auto transform = itk::AffineTransform<double, 3>::New();
  const auto                        size = atlas->GetLargestPossibleRegion().GetSize();
  itk::ContinuousIndex<double, 3>   centreIndex;
  for (unsigned int d = 0; d < 3; ++d)
  {
    centreIndex[d] = 0.5 * static_cast<double>(size[d] - 1);
  }
  itk::Point<double, 3> centre;
  atlas->TransformContinuousIndexToPhysicalPoint(centreIndex, centre);
  transform->SetCenter(centre);
  itk::Vector<double, 3> axis;
  axis[0] = 1.0;
  axis[1] = 2.0;
  axis[2] = 2.0;
  axis.Normalize();
  transform->Rotate3D(axis, angleDegrees * itk::Math::pi / 180.0);
  itk::Vector<double, 3> scale;
  scale[0] = 0.95;
  scale[1] = 1.05;
  scale[2] = 1.08;
  transform->Scale(scale, true);
  itk::Vector<double, 3> translation;
  translation[0] = 7.0;
  translation[1] = -6.0;
  translation[2] = 4.0; // |t| = 10.0 mm
  transform->SetTranslation(translation * translationScale);
  return transform;
}

// Identity-direction grid of `spacing` mm that holds the whole atlas head
// mapped into subject space (corners of the atlas through the inverse map).
AtlasImage::Pointer
SubjectGrid(const AtlasImage * atlas, const itk::AffineTransform<double, 3> * subjectToAtlas, double spacing)
{
  auto inverse = itk::AffineTransform<double, 3>::New();
  subjectToAtlas->GetInverse(inverse);
  const auto size = atlas->GetLargestPossibleRegion().GetSize();
  double     lower[3], upper[3];
  for (unsigned int d = 0; d < 3; ++d)
  {
    lower[d] = std::numeric_limits<double>::max();
    upper[d] = -std::numeric_limits<double>::max();
  }
  for (unsigned int corner = 0; corner < 8; ++corner)
  {
    itk::Index<3> index;
    for (unsigned int d = 0; d < 3; ++d)
    {
      index[d] = (corner >> d) & 1u ? static_cast<itk::IndexValueType>(size[d] - 1) : 0;
    }
    itk::Point<double, 3> atlasPoint;
    atlas->TransformIndexToPhysicalPoint(index, atlasPoint);
    const auto subjectPoint = inverse->TransformPoint(atlasPoint);
    for (unsigned int d = 0; d < 3; ++d)
    {
      lower[d] = std::min(lower[d], subjectPoint[d]);
      upper[d] = std::max(upper[d], subjectPoint[d]);
    }
  }
  auto                  grid = AtlasImage::New();
  AtlasImage::SizeType  gridSize;
  AtlasImage::PointType origin;
  AtlasImage::SpacingType gridSpacing;
  for (unsigned int d = 0; d < 3; ++d)
  {
    origin[d] = lower[d];
    gridSpacing[d] = spacing;
    gridSize[d] = static_cast<itk::SizeValueType>(std::ceil((upper[d] - lower[d]) / spacing)) + 1;
  }
  grid->SetRegions(gridSize);
  grid->SetOrigin(origin);
  grid->SetSpacing(gridSpacing);
  grid->Allocate(true);
  return grid;
}

// Colin27 moved by the known affine onto a 2 mm grid, and its true brain mask.
struct MovedColin
{
  AtlasImage::Pointer subject;
  AtlasImage::Pointer trueBrain;
};

const MovedColin &
GetMovedColin()
{
  static const MovedColin moved = [] {
    const Colin & colin = GetColin();
    const auto    subjectToAtlas = KnownSubjectToAtlasTransform(colin.t1);
    const auto    grid = SubjectGrid(colin.t1, subjectToAtlas, 2.0);
    return MovedColin{ Resample(colin.t1, subjectToAtlas, grid, false),
                       Resample(colin.brain, subjectToAtlas, grid, true) };
  }();
  return moved;
}

AtlasFilter::Pointer
MakeColinFilter(const AtlasImage * subject)
{
  const Colin & colin = GetColin();
  auto          filter = AtlasFilter::New();
  filter->SetInput(subject);
  filter->SetAtlasImage(colin.t1);
  filter->SetAtlasMaskImage(colin.brain);
  return filter;
}

double
Seconds(std::chrono::steady_clock::time_point start)
{
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Small synthetic head for the error cases: a bright ellipsoid in a dark box.
AtlasImage::Pointer
SyntheticHead(double spacing = 2.0)
{
  auto                    image = AtlasImage::New();
  AtlasImage::SizeType    size;
  AtlasImage::SpacingType spacings;
  size.Fill(24);
  spacings.Fill(spacing);
  image->SetRegions(size);
  image->SetSpacing(spacings);
  image->Allocate(true);
  for (itk::ImageRegionIteratorWithIndex<AtlasImage> it(image, image->GetLargestPossibleRegion()); !it.IsAtEnd(); ++it)
  {
    const auto   index = it.GetIndex();
    const double x = (index[0] - 11.5) / 9.0, y = (index[1] - 11.5) / 10.0, z = (index[2] - 11.5) / 8.0;
    it.Set(x * x + y * y + z * z < 1.0 ? 100.0f + static_cast<float>(index[2]) : 0.0f);
  }
  return image;
}

std::string
ErrorOf(AtlasFilter * filter)
{
  try
  {
    filter->Update();
  }
  catch (const itk::ExceptionObject & error)
  {
    return error.GetDescription();
  }
  return "no error";
}

} // namespace

TEST(AtlasBrainMaskColin, KnownAffineTransformDiceAbove095)
{
  if (!ColinAvailable())
  {
    GTEST_SKIP() << "Colin27 (mricron-data) not installed";
  }
  const MovedColin & moved = GetMovedColin();
  auto               filter = MakeColinFilter(moved.subject);
  std::vector<float> progress;
  filter->AddObserver(itk::ProgressEvent(), [&](const itk::EventObject &) { progress.push_back(filter->GetProgress()); });
  const auto start = std::chrono::steady_clock::now();
  filter->Update();
  const double seconds = Seconds(start);
  const double dice = Dice(filter->GetOutput(), moved.trueBrain.GetPointer());
  std::cout << "[ AtlasBrainMask ] known affine, subject "
            << moved.subject->GetLargestPossibleRegion().GetSize() << " at 2 mm: Dice " << dice << ", "
            << seconds << " s, affine MI " << filter->GetAffineFinalMetricValue() << " ("
            << filter->GetAffineIterationsRun() << " it.), B-spline MI " << filter->GetBSplineFinalMetricValue()
            << " (" << filter->GetBSplineIterationsRun() << " it.)" << std::endl;
  EXPECT_GT(dice, 0.95);
  ASSERT_GT(progress.size(), 10u);
  EXPECT_TRUE(std::is_sorted(progress.begin(), progress.end()));
  EXPECT_FLOAT_EQ(progress.back(), 1.0f);
  ASSERT_NE(filter->GetBSplineTransform(), nullptr);
  EXPECT_EQ(filter->GetCompositeTransform()->GetNumberOfTransforms(), 2u);
  // The affine stage alone recovers the known map: a subject point maps to its atlas point within 2 mm
  // (one voxel of the subject) across the brain.
  const auto truth = KnownSubjectToAtlasTransform(GetColin().t1);
  double     largestError = 0.0;
  for (double dx : { -50.0, 50.0 })
  {
    for (double dy : { -60.0, 60.0 })
    {
      for (double dz : { -40.0, 40.0 })
      {
        itk::Point<double, 3> point = truth->GetCenter();
        point[0] += dx;
        point[1] += dy;
        point[2] += dz;
        const auto expected = truth->TransformPoint(point);
        const auto found = filter->GetAffineTransform()->TransformPoint(point);
        largestError = std::max(largestError, expected.EuclideanDistanceTo(found));
      }
    }
  }
  std::cout << "[ AtlasBrainMask ] affine error at brain-box corners " << largestError << " mm" << std::endl;
  EXPECT_LT(largestError, 2.0);
}

TEST(AtlasBrainMaskColin, LargeShiftAndRotationRecoveredByAffineStage)
{
  if (!ColinAvailable())
  {
    GTEST_SKIP() << "Colin27 (mricron-data) not installed";
  }
  // 15 degrees about an oblique axis and a 35 mm shift, 3 mm subject grid, affine stage only.
  const Colin & colin = GetColin();
  const auto    subjectToAtlas = KnownSubjectToAtlasTransform(colin.t1, 15.0, 3.5);
  const auto    grid = SubjectGrid(colin.t1, subjectToAtlas, 3.0);
  const auto    subject = Resample(colin.t1, subjectToAtlas, grid, false);
  const auto    trueBrain = Resample(colin.brain, subjectToAtlas, grid, true);
  auto          filter = MakeColinFilter(subject);
  filter->SetUseBSplineStage(false);
  const auto start = std::chrono::steady_clock::now();
  filter->Update();
  const double dice = Dice(filter->GetOutput(), trueBrain.GetPointer());
  std::cout << "[ AtlasBrainMask ] 15 deg, 35 mm, 3 mm grid, affine only: Dice " << dice << ", " << Seconds(start)
            << " s" << std::endl;
  EXPECT_GT(dice, 0.95);
  EXPECT_EQ(filter->GetBSplineTransform(), nullptr);
  EXPECT_EQ(filter->GetCompositeTransform()->GetNumberOfTransforms(), 1u);
}

TEST(AtlasBrainMaskColin, IdentityDiceAbove098)
{
  if (!ColinAvailable())
  {
    GTEST_SKIP() << "Colin27 (mricron-data) not installed";
  }
  const Colin & colin = GetColin();
  auto          filter = MakeColinFilter(colin.t1);
  const auto    start = std::chrono::steady_clock::now();
  filter->Update();
  const double seconds = Seconds(start);
  const double dice = Dice(filter->GetOutput(), colin.brain.GetPointer());
  std::cout << "[ AtlasBrainMask ] identity at 1 mm (181x217x181): Dice " << dice << ", " << seconds << " s"
            << std::endl;
  EXPECT_GT(dice, 0.98);
  const double ratio = filter->GetPropagatedBrainVolume() / filter->GetAtlasBrainVolume();
  EXPECT_NEAR(ratio, 1.0, 0.03);
}

TEST(AtlasBrainMaskColin, RepeatsExactlyAcrossRunsAndThreadCounts)
{
  if (!ColinAvailable())
  {
    GTEST_SKIP() << "Colin27 (mricron-data) not installed";
  }
  // Few iterations keep the test short; repeatability does not depend on convergence.
  const MovedColin & moved = GetMovedColin();
  const auto         shortRun = [&moved] {
    auto filter = MakeColinFilter(moved.subject);
    filter->SetAffineNumberOfIterations(8);
    filter->SetBSplineNumberOfIterations(3);
    filter->SetMinimumVolumeRatio(0.0); // a half-converged mask is fine here
    return filter;
  };
  auto first = shortRun();
  first->Update();
  const auto threads = itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads();
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(1);
  auto second = shortRun();
  second->Update();
  itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(threads);

  EXPECT_EQ(first->GetAffineTransform()->GetParameters(), second->GetAffineTransform()->GetParameters());
  EXPECT_EQ(first->GetBSplineTransform()->GetParameters(), second->GetBSplineTransform()->GetParameters());
  itk::ImageRegionConstIterator<MaskImage> a(first->GetOutput(), first->GetOutput()->GetLargestPossibleRegion());
  itk::ImageRegionConstIterator<MaskImage> b(second->GetOutput(), second->GetOutput()->GetLargestPossibleRegion());
  itk::SizeValueType                       differing = 0;
  for (; !a.IsAtEnd(); ++a, ++b)
  {
    differing += a.Get() != b.Get() ? 1 : 0;
  }
  EXPECT_EQ(differing, 0u);
}

TEST(AtlasBrainMaskErrors, MissingAtlasImageOrMask)
{
  const auto head = SyntheticHead();
  auto       filter = AtlasFilter::New();
  filter->SetInput(head);
  filter->SetAtlasMaskImage(head);
  EXPECT_NE(ErrorOf(filter).find("atlas image is not set"), std::string::npos) << ErrorOf(filter);

  filter = AtlasFilter::New();
  filter->SetInput(head);
  filter->SetAtlasImage(head);
  EXPECT_NE(ErrorOf(filter).find("atlas mask image is not set"), std::string::npos) << ErrorOf(filter);
}

TEST(AtlasBrainMaskErrors, AtlasMaskWithoutForeground)
{
  const auto head = SyntheticHead();
  auto       empty = SyntheticHead();
  empty->FillBuffer(0.0f);
  auto filter = AtlasFilter::New();
  filter->SetInput(head);
  filter->SetAtlasImage(head);
  filter->SetAtlasMaskImage(empty);
  EXPECT_NE(ErrorOf(filter).find("no foreground"), std::string::npos) << ErrorOf(filter);
}

TEST(AtlasBrainMaskErrors, AtlasMaskNotOnAtlasGrid)
{
  const auto head = SyntheticHead();
  auto       filter = AtlasFilter::New();
  filter->SetInput(head);
  filter->SetAtlasImage(head);
  filter->SetAtlasMaskImage(SyntheticHead(2.5)); // other spacing
  std::string error = ErrorOf(filter);
  EXPECT_NE(error.find("not on the atlas grid"), std::string::npos) << error;
  EXPECT_NE(error.find("spacing"), std::string::npos) << error;

  auto shifted = SyntheticHead();
  auto origin = shifted->GetOrigin();
  origin[1] += 1.0;
  shifted->SetOrigin(origin);
  filter->SetAtlasMaskImage(shifted);
  error = ErrorOf(filter);
  EXPECT_NE(error.find("not on the atlas grid"), std::string::npos) << error;
  EXPECT_NE(error.find("origin"), std::string::npos) << error;

  auto rotated = SyntheticHead();
  auto direction = rotated->GetDirection();
  direction[0][0] = -1.0;
  rotated->SetDirection(direction);
  filter->SetAtlasMaskImage(rotated);
  error = ErrorOf(filter);
  EXPECT_NE(error.find("direction"), std::string::npos) << error;
}

TEST(AtlasBrainMaskErrors, NaNInSubject)
{
  auto subject = SyntheticHead();
  subject->SetPixel({ { 3, 4, 5 } }, std::numeric_limits<float>::quiet_NaN());
  const auto head = SyntheticHead();
  auto       filter = AtlasFilter::New();
  filter->SetInput(subject);
  filter->SetAtlasImage(head);
  filter->SetAtlasMaskImage(head);
  const std::string error = ErrorOf(filter);
  EXPECT_NE(error.find("subject image contains 1 NaN"), std::string::npos) << error;
  EXPECT_NE(error.find("[3, 4, 5]"), std::string::npos) << error;
}

TEST(AtlasBrainMaskErrors, ImplausibleVolumeReportsFailedRegistration)
{
  if (!ColinAvailable())
  {
    GTEST_SKIP() << "Colin27 (mricron-data) not installed";
  }
  // The subject's spacing given in cm instead of mm: the whole "head" is 2 cm wide, far smaller than any
  // brain, so the propagated mask cannot have a plausible volume.
  const MovedColin & moved = GetMovedColin();
  auto               subject = AtlasImage::New();
  subject->Graft(moved.subject);
  auto spacing = subject->GetSpacing();
  for (unsigned int d = 0; d < 3; ++d)
  {
    spacing[d] *= 0.1;
  }
  subject->SetSpacing(spacing);
  auto filter = MakeColinFilter(subject);
  filter->SetUseBSplineStage(false);
  const std::string error = ErrorOf(filter);
  EXPECT_NE(error.find("registration failed"), std::string::npos) << error;
  EXPECT_NE(error.find("supply a brain mask"), std::string::npos) << error;
}
