// Fuzzy c-means tissue classification and material mapping (issue 4, items 1
// and 2): synthetic images with known classes, analytic memberships, the real
// T1 of ITK's examples, bad input, and material mapping against analytic
// cell averages.
// ITK headers first: ITK's bundled Eigen must come before the system Eigen.
// Over 800 lines: the tests of one stage (classification and mapping), which
// share their synthetic images.
#include "itkCommand.h"
#include "itkImageFileReader.h"
#include "itkImageRegionIteratorWithIndex.h"

#include "bmrFuzzyCMeans.h"
#include "bmrMaterialMapping.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshless.h"
#include "itkBiomechanicalImageConversion.h"
#include "itkFuzzyCMeansClassifierImageFilter.h"

#include "bmrTemporaryFolderTest.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <map>
#include <limits>
#include <random>
#include <set>
#include <string>
#include <vector>

namespace
{

using bmr::Vector3;

bmr::ImageGeometry
CubeGeometry(int size, double spacing = 1.0)
{
  bmr::ImageGeometry geometry;
  geometry.size = { size, size, size };
  geometry.spacing = Vector3::Constant(spacing);
  return geometry;
}

// Three slabs along x with true means 50 / 120 / 200 (class of voxel = slab),
// Gaussian noise of standard deviation 10, fixed seed.
struct ThreeClassImage
{
  bmr::ScalarVolume intensities;
  std::vector<int>  trueClass; // 0, 1, 2 per voxel
  double            means[3] = { 50.0, 120.0, 200.0 };
};

ThreeClassImage
MakeThreeClassImage(int size, bool brightFirst = false)
{
  ThreeClassImage image;
  image.intensities.geometry = CubeGeometry(size);
  image.intensities.values.resize(image.intensities.geometry.VoxelCount());
  image.trueClass.resize(image.intensities.values.size());
  std::mt19937                     random(20240417u);
  std::normal_distribution<double> noise(0.0, 10.0);
  for (int k = 0; k < size; ++k)
    for (int j = 0; j < size; ++j)
      for (int i = 0; i < size; ++i)
      {
        int slab = std::min(2, 3 * i / size);
        if (brightFirst)
        {
          slab = 2 - slab;
        }
        const std::size_t n = image.intensities.geometry.Offset(i, j, k);
        image.trueClass[n] = slab;
        image.intensities.values[n] = static_cast<float>(image.means[slab] + noise(random));
      }
  return image;
}

bmr::LabelVolume
FullMask(const bmr::ImageGeometry & geometry)
{
  bmr::LabelVolume mask;
  mask.geometry = geometry;
  mask.values.assign(geometry.VoxelCount(), 1);
  return mask;
}

using bmr::test::ErrorMessage;

const std::string kItkData = "/usr/share/doc/insighttoolkit5-examples/examples/Data/";

// ---------------------------------------------------------------------------
// Fuzzy c-means
// ---------------------------------------------------------------------------

TEST(FuzzyCMeansSynthetic, ThreeNoisyClassesRecovered)
{
  const ThreeClassImage image = MakeThreeClassImage(40);
  bmr::FuzzyCMeansSettings settings;
  settings.classes = 3;
  const bmr::TissueClassification result = bmr::ClassifyTissue(image.intensities, nullptr, settings);

  ASSERT_TRUE(result.fit.converged);
  ASSERT_EQ(result.fit.centroids.size(), 3u);
  // Centroids within 2% of the true means (fuzzy c-means pulls them slightly
  // toward each other; with sigma 10 and gaps of 70 the pull is < 1%).
  for (int k = 0; k < 3; ++k)
  {
    EXPECT_NEAR(result.fit.centroids[k], image.means[k], 0.02 * image.means[k]) << "class " << k;
  }
  const std::size_t voxels = image.trueClass.size();
  std::size_t       correct = 0;
  double            ownMembership[3] = { 0, 0, 0 };
  std::size_t       regionVoxels[3] = { 0, 0, 0 };
  double            worstSumError = 0.0;
  for (std::size_t n = 0; n < voxels; ++n)
  {
    const int truth = image.trueClass[n];
    correct += result.labels.values[n] == truth + 1 ? 1 : 0;
    double sum = 0.0;
    for (int k = 0; k < 3; ++k)
    {
      sum += result.memberships.values[n * 3 + k];
    }
    worstSumError = std::max(worstSumError, std::abs(sum - 1.0));
    ownMembership[truth] += result.memberships.values[n * 3 + truth];
    ++regionVoxels[truth];
  }
  // Hard labels correct on >= 99% of voxels (the Bayes error here is ~2e-4).
  EXPECT_GE(static_cast<double>(correct) / voxels, 0.99);
  EXPECT_LE(worstSumError, 1e-5); // memberships sum to 1
  for (int k = 0; k < 3; ++k)
  {
    EXPECT_GT(ownMembership[k] / regionVoxels[k], 0.9) << "region " << k; // mean own-class membership
  }
}

TEST(FuzzyCMeansMemberships, TwoCentroidsMatchAnalyticFormula)
{
  const std::vector<double> centroids = { 10.0, 30.0 };
  for (double m : { 1.5, 2.0, 3.0 })
  {
    for (double value : { -5.0, 0.0, 12.0, 17.5, 20.0, 29.0, 45.0 })
    {
      float u[2];
      bmr::FuzzyMemberships(value, centroids, m, u);
      const double d1 = std::abs(value - centroids[0]);
      const double d2 = std::abs(value - centroids[1]);
      const double expected = 1.0 / (1.0 + std::pow(d1 / d2, 2.0 / (m - 1.0)));
      EXPECT_NEAR(u[0], expected, 1e-6) << "m " << m << " value " << value;
      EXPECT_NEAR(u[1], 1.0 - expected, 1e-6) << "m " << m << " value " << value;
    }
    // A value on a centroid belongs to it entirely.
    float u[2];
    bmr::FuzzyMemberships(30.0, centroids, m, u);
    EXPECT_EQ(u[0], 0.0f);
    EXPECT_EQ(u[1], 1.0f);
  }
  // Extreme fuzziness near 1 must not overflow (ratios to the nearest centre).
  float u[2];
  bmr::FuzzyMemberships(10.0 + 1e-12, centroids, 1.01, u);
  EXPECT_EQ(u[0], 1.0f);
  EXPECT_EQ(u[1], 0.0f);
}

TEST(FuzzyCMeansDeterminism, OrderedByCentroidAndThreadIndependent)
{
  // Float intensities: ~27,000 distinct values, several reduction blocks.
  const ThreeClassImage image = MakeThreeClassImage(30, /*brightFirst=*/true);
  const bmr::LabelVolume mask = FullMask(image.intensities.geometry);
  bmr::FuzzyCMeansSettings settings;
  settings.classes = 3;
  settings.threads = 1;
  const bmr::TissueClassification one = bmr::ClassifyTissue(image.intensities, &mask, settings);
  settings.threads = 2;
  const bmr::TissueClassification two = bmr::ClassifyTissue(image.intensities, &mask, settings);

  // Ascending centroids although the brightest slab comes first in x.
  ASSERT_EQ(one.fit.centroids.size(), 3u);
  EXPECT_LT(one.fit.centroids[0], one.fit.centroids[1]);
  EXPECT_LT(one.fit.centroids[1], one.fit.centroids[2]);
  EXPECT_EQ(one.labels.At(0, 0, 0), 3);   // brightest slab -> last class
  EXPECT_EQ(one.labels.At(29, 0, 0), 1);  // darkest slab -> first class
  // Bitwise identical for 1 and 2 threads.
  EXPECT_EQ(one.fit.iterations, two.fit.iterations);
  EXPECT_EQ(0, std::memcmp(one.fit.centroids.data(), two.fit.centroids.data(), 3 * sizeof(double)));
  ASSERT_EQ(one.memberships.values.size(), two.memberships.values.size());
  EXPECT_EQ(0, std::memcmp(one.memberships.values.data(), two.memberships.values.data(),
                           one.memberships.values.size() * sizeof(float)));
  EXPECT_EQ(one.labels.values, two.labels.values);
  // The histogram fit of FitFuzzyCMeans gives the same centroids.
  const bmr::FuzzyCMeansResult fit = bmr::FitFuzzyCMeans(image.intensities.values, settings);
  EXPECT_EQ(0, std::memcmp(one.fit.centroids.data(), fit.centroids.data(), 3 * sizeof(double)));
}

// The T1 of ITK's examples (128 x 128 x 62 voxels of 2 x 2 x 3 mm, 8-bit
// intensities) with its skull-strip labels: 0 outside the brain, 4, 5 and 6
// inside (126 / 15,667 / 112,679 voxels), so the brain mask is label > 0.
TEST(FuzzyCMeansRealT1, ClassesOrderCsfGreyWhiteAndCsfCoversVentricles)
{
  using FloatImage = itk::Image<float, 3>;
  using MaskImage = itk::Image<unsigned char, 3>;
  const auto t1 = itk::ReadImage<FloatImage>(kItkData + "KmeansTest_T1UCharRaw.nii.gz");
  const auto strip = itk::ReadImage<MaskImage>(kItkData + "KmeansTest_T1RawSkullStrip.nii.gz");
  const bmr::ScalarVolume intensities = itk::MakeBiomechanicalVolume<float>(t1.GetPointer());
  bmr::LabelVolume        mask = itk::MakeBiomechanicalVolume<std::uint8_t>(strip.GetPointer());
  std::size_t             brainVoxels = 0;
  for (auto & value : mask.values)
  {
    value = value > 0 ? 1 : 0;
    brainVoxels += value;
  }
  ASSERT_EQ(brainVoxels, 128472u);

  bmr::FuzzyCMeansSettings settings;
  settings.classes = 3;
  const bmr::TissueClassification result = bmr::ClassifyTissue(intensities, &mask, settings);
  ASSERT_TRUE(result.fit.converged);
  const auto & c = result.fit.centroids;
  // CSF < grey < white, each gap larger than 10 intensity units (measured:
  // about 47.7, 76.4, 102.8).
  EXPECT_GT(c[1] - c[0], 10.0);
  EXPECT_GT(c[2] - c[1], 10.0);

  // Plausible CSF share of the brain mask: 5-25% (sulcal CSF and ventricles on
  // this low-contrast 2 x 2 x 3 mm scan; measured about 20%).
  std::size_t csf = 0;
  for (auto label : result.labels.values)
  {
    csf += label == 1 ? 1 : 0;
  }
  const double csfFraction = static_cast<double>(csf) / brainVoxels;
  EXPECT_GT(csfFraction, 0.05);
  EXPECT_LT(csfFraction, 0.25);

  // Ventricles, located by inspecting axial slices: the dark butterfly of the
  // lateral ventricles near the brain's centre (mask centroid at voxel
  // (61, 62, 29)), deep inside the brain (> 15 mm from the mask surface).
  // These voxels (x, y, z) lie inside the ventricles on slices 27, 32 and 37;
  // the CSF class must own them.
  const int ventricleVoxels[][3] = { { 59, 69, 32 }, { 64, 68, 32 }, { 61, 68, 37 }, { 56, 67, 27 } };
  for (const auto & v : ventricleVoxels)
  {
    EXPECT_EQ(result.labels.At(v[0], v[1], v[2]), 1) << "voxel " << v[0] << ", " << v[1] << ", " << v[2];
    EXPECT_GT(result.memberships.At(v[0], v[1], v[2], 0), 0.6f) << "voxel " << v[0] << ", " << v[1] << ", " << v[2];
  }
  // A small box around the lateral ventricles on slices 31-33 (x 56-67, y
  // 67-70; it also holds the white matter between the horns): CSF is the
  // most frequent class there (measured 63%), while it is 20% of the brain.
  std::size_t boxCsf = 0, boxVoxels = 0;
  for (int z = 31; z <= 33; ++z)
    for (int y = 67; y <= 70; ++y)
      for (int x = 56; x <= 67; ++x)
      {
        boxCsf += result.labels.At(x, y, z) == 1 ? 1 : 0;
        ++boxVoxels;
      }
  EXPECT_GT(static_cast<double>(boxCsf) / boxVoxels, 0.5);
}

TEST(FuzzyCMeansBadInput, ClearErrors)
{
  const ThreeClassImage image = MakeThreeClassImage(12);
  bmr::FuzzyCMeansSettings settings;
  settings.classes = 3;

  // NaN inside the mask: the message names the voxel index.
  bmr::ScalarVolume withNaN = image.intensities;
  withNaN.At(3, 4, 5) = std::numeric_limits<float>::quiet_NaN();
  std::string message = ErrorMessage([&] { bmr::ClassifyTissue(withNaN, nullptr, settings); });
  EXPECT_NE(message.find("NaN"), std::string::npos) << message;
  EXPECT_NE(message.find("(3, 4, 5)"), std::string::npos) << message;
  // ... infinity too; but a NaN outside the mask is fine.
  bmr::ScalarVolume withInf = image.intensities;
  withInf.At(1, 1, 1) = std::numeric_limits<float>::infinity();
  message = ErrorMessage([&] { bmr::ClassifyTissue(withInf, nullptr, settings); });
  EXPECT_NE(message.find("(1, 1, 1)"), std::string::npos) << message;
  bmr::LabelVolume mask = FullMask(image.intensities.geometry);
  mask.At(3, 4, 5) = 0;
  EXPECT_NO_THROW(bmr::ClassifyTissue(withNaN, &mask, settings));

  // Empty and all-background masks.
  bmr::LabelVolume empty;
  message = ErrorMessage([&] { bmr::ClassifyTissue(image.intensities, &empty, settings); });
  EXPECT_NE(message.find("empty"), std::string::npos) << message;
  bmr::LabelVolume background = FullMask(image.intensities.geometry);
  std::fill(background.values.begin(), background.values.end(), 0);
  message = ErrorMessage([&] { bmr::ClassifyTissue(image.intensities, &background, settings); });
  EXPECT_NE(message.find("all background"), std::string::npos) << message;

  // Mask on another grid: both grids are described.
  bmr::LabelVolume shifted = FullMask(image.intensities.geometry);
  shifted.geometry.spacing = Vector3(1.0, 1.0, 1.5);
  message = ErrorMessage([&] { bmr::ClassifyTissue(image.intensities, &shifted, settings); });
  EXPECT_NE(message.find("not on the image grid"), std::string::npos) << message;
  EXPECT_NE(message.find("1 x 1 x 1.5 mm"), std::string::npos) << message;

  // Settings out of range.
  bmr::FuzzyCMeansSettings oneClass = settings;
  oneClass.classes = 1;
  message = ErrorMessage([&] { bmr::ClassifyTissue(image.intensities, nullptr, oneClass); });
  EXPECT_NE(message.find("at least 2 classes"), std::string::npos) << message;
  bmr::FuzzyCMeansSettings crisp = settings;
  crisp.fuzziness = 1.0;
  message = ErrorMessage([&] { bmr::ClassifyTissue(image.intensities, nullptr, crisp); });
  EXPECT_NE(message.find("fuzziness"), std::string::npos) << message;

  // More classes than distinct intensities inside the mask.
  bmr::ScalarVolume twoValues = image.intensities;
  for (std::size_t n = 0; n < twoValues.values.size(); ++n)
  {
    twoValues.values[n] = image.trueClass[n] == 0 ? 10.0f : 20.0f;
  }
  message = ErrorMessage([&] { bmr::ClassifyTissue(twoValues, nullptr, settings); });
  EXPECT_NE(message.find("only 2 distinct intensities"), std::string::npos) << message;

  // Not converging is a result, not an exception: converged false, a warning.
  bmr::FuzzyCMeansSettings hurried = settings;
  hurried.maxIterations = 1;
  std::vector<std::string>        warnings;
  const bmr::TissueClassification partial = bmr::ClassifyTissue(image.intensities, nullptr, hurried, {}, &warnings);
  EXPECT_FALSE(partial.fit.converged);
  EXPECT_EQ(partial.fit.iterations, 1);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("did not converge"), std::string::npos) << warnings[0];
}

// ---------------------------------------------------------------------------
// ITK filter
// ---------------------------------------------------------------------------

class ProgressRecorder : public itk::Command
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(ProgressRecorder);
  using Self = ProgressRecorder;
  using Pointer = itk::SmartPointer<Self>;
  itkNewMacro(Self);
  void Execute(itk::Object * caller, const itk::EventObject & event) override
  {
    Execute(static_cast<const itk::Object *>(caller), event);
  }
  void Execute(const itk::Object * caller, const itk::EventObject & event) override
  {
    if (itk::ProgressEvent().CheckEvent(&event))
    {
      values.push_back(static_cast<const itk::ProcessObject *>(caller)->GetProgress());
    }
  }
  std::vector<float> values;

protected:
  ProgressRecorder() = default;
};

TEST(FuzzyCMeansClassifierImageFilter, OutputsOnInputGridMatchCore)
{
  using FloatImage = itk::Image<float, 3>;
  using MaskImage = itk::Image<unsigned char, 3>;
  using Filter = itk::FuzzyCMeansClassifierImageFilter<FloatImage>;

  // 14 x 12 x 10 voxels, anisotropic, shifted, rotated 90 degrees about z.
  auto image = FloatImage::New();
  FloatImage::RegionType region;
  region.SetSize({ { 14, 12, 10 } });
  image->SetRegions(region);
  const double spacing[3] = { 1.5, 1.0, 2.0 };
  const double origin[3] = { -3.0, 4.0, 7.0 };
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  FloatImage::DirectionType direction;
  direction.Fill(0.0);
  direction[0][1] = -1.0;
  direction[1][0] = 1.0;
  direction[2][2] = 1.0;
  image->SetDirection(direction);
  image->Allocate();
  auto mask = MaskImage::New();
  mask->CopyInformation(image);
  mask->SetRegions(region);
  mask->Allocate();
  std::mt19937                     random(7u);
  std::normal_distribution<double> noise(0.0, 8.0);
  for (itk::ImageRegionIteratorWithIndex<FloatImage> it(image, region); !it.IsAtEnd(); ++it)
  {
    const auto index = it.GetIndex();
    it.Set(static_cast<float>((index[0] < 7 ? 100.0 : 300.0) + noise(random)));
    const bool border = index[0] == 0 || index[1] == 0 || index[2] == 0 || index[0] == 13;
    mask->SetPixel(index, border ? 0 : 1);
  }

  auto filter = Filter::New();
  filter->SetInput(image);
  filter->SetMaskImage(mask);
  filter->SetNumberOfClasses(2);
  auto recorder = ProgressRecorder::New();
  filter->AddObserver(itk::ProgressEvent(), recorder);
  filter->Update();

  const auto * memberships = filter->GetOutput();
  const auto * labels = filter->GetLabelOutput();
  for (const itk::ImageBase<3> * output : { static_cast<const itk::ImageBase<3> *>(memberships),
                                            static_cast<const itk::ImageBase<3> *>(labels) })
  {
    EXPECT_EQ(output->GetLargestPossibleRegion(), region);
    EXPECT_EQ(output->GetBufferedRegion(), region);
    EXPECT_EQ(output->GetSpacing(), image->GetSpacing());
    EXPECT_EQ(output->GetOrigin(), image->GetOrigin());
    EXPECT_EQ(output->GetDirection(), image->GetDirection());
  }
  EXPECT_EQ(memberships->GetNumberOfComponentsPerPixel(), 2u);

  // Same result as the core.
  const bmr::ScalarVolume intensities = itk::MakeBiomechanicalVolume<float>(image.GetPointer());
  const bmr::LabelVolume  maskVolume = itk::MakeBiomechanicalVolume<std::uint8_t>(mask.GetPointer());
  bmr::FuzzyCMeansSettings settings;
  const bmr::TissueClassification core = bmr::ClassifyTissue(intensities, &maskVolume, settings);
  EXPECT_EQ(filter->GetCentroids(), core.fit.centroids);
  EXPECT_EQ(static_cast<int>(filter->GetNumberOfIterations()), core.fit.iterations);
  EXPECT_TRUE(filter->GetConverged());
  EXPECT_NEAR(filter->GetCentroids()[0], 100.0, 2.0);
  EXPECT_NEAR(filter->GetCentroids()[1], 300.0, 2.0);
  const bmr::LabelVolume filterLabels = itk::MakeBiomechanicalVolume<std::uint8_t>(labels);
  EXPECT_EQ(filterLabels.values, core.labels.values);
  const bmr::ScalarVolume filterMemberships = itk::MakeBiomechanicalVolume<float>(memberships);
  EXPECT_EQ(filterMemberships.values, core.memberships.values);
  EXPECT_EQ(labels->GetPixel({ { 0, 5, 5 } }), 0);  // outside the mask
  EXPECT_EQ(labels->GetPixel({ { 3, 5, 5 } }), 1);  // dark half
  EXPECT_EQ(labels->GetPixel({ { 10, 5, 5 } }), 2); // bright half

  // Progress: several intermediate values, never decreasing, ending at 1.
  ASSERT_GE(recorder->values.size(), 5u);
  EXPECT_TRUE(std::is_sorted(recorder->values.begin(), recorder->values.end()));
  EXPECT_FLOAT_EQ(recorder->values.back(), 1.0f);
  EXPECT_GE(std::set<float>(recorder->values.begin(), recorder->values.end()).size(), 4u);

  // A mask on another grid is an ITK exception naming the problem.
  auto otherMask = MaskImage::New();
  otherMask->CopyInformation(mask);
  otherMask->SetRegions(region);
  const double unitSpacing[3] = { 1.0, 1.0, 1.0 };
  otherMask->SetSpacing(unitSpacing);
  otherMask->Allocate(true);
  filter->SetMaskImage(otherMask);
  try
  {
    filter->Update();
    ADD_FAILURE() << "no exception for a mask on another grid";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("not on the image grid"), std::string::npos)
      << error.GetDescription();
  }

  // An iteration limit reached: a result (warning), not an exception.
  filter->SetMaskImage(mask);
  filter->SetMaximumNumberOfIterations(1);
  const bool warnings = itk::Object::GetGlobalWarningDisplay();
  itk::Object::SetGlobalWarningDisplay(false); // keep the test log clean
  filter->Update();
  itk::Object::SetGlobalWarningDisplay(warnings);
  EXPECT_FALSE(filter->GetConverged());
  EXPECT_EQ(filter->GetNumberOfIterations(), 1u);
  filter->SetMaximumNumberOfIterations(300);

  // Material mapping through the ITK layer equals the core's on the same memberships.
  // The image spans x in [-14.5, -2.5] mm (index y, flipped), y in [3.25, 24.25], z in [6, 26].
  bmr::Model model = bmr::MakeBlockMesh(Vector3(9, 15, 15), { 3, 3, 3 }, bmr::GridCells::Hexahedra, bmr::Material{},
                                        Vector3(-13, 6, 9));
  bmr::Model coreModel = model;
  filter->Update();
  itk::MapBiomechanicalMaterials(model, filter->GetOutput());
  bmr::MapMaterialsFromMemberships(coreModel, itk::MakeBiomechanicalVolume<float>(filter->GetOutput()));
  ASSERT_EQ(model.materials.size(), coreModel.materials.size());
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    EXPECT_EQ(model.materials[model.cells[c].material].youngsModulus,
              coreModel.materials[coreModel.cells[c].material].youngsModulus);
  }
  // Memberships span both classes over this block: both pure values or mixtures in between.
  double stiffest = 0.0, softest = 1e9;
  for (const auto & material : model.materials)
  {
    stiffest = std::max(stiffest, material.youngsModulus);
    softest = std::min(softest, material.youngsModulus);
  }
  EXPECT_LT(softest, 1500.0);
  EXPECT_GT(stiffest, 1500.0);
}

// ---------------------------------------------------------------------------
// Material mapping
// ---------------------------------------------------------------------------

// 32^3 voxels of 1 mm from the origin; two classes with u_csf = i / 31 (linear
// in x, so trilinear interpolation reproduces it exactly and a cell's average
// is the value at its centroid).
bmr::ScalarVolume
LinearMemberships()
{
  bmr::ScalarVolume memberships;
  memberships.geometry = CubeGeometry(32);
  memberships.components = 2;
  memberships.values.resize(memberships.geometry.VoxelCount() * 2);
  for (int k = 0; k < 32; ++k)
    for (int j = 0; j < 32; ++j)
      for (int i = 0; i < 32; ++i)
      {
        memberships.At(i, j, k, 0) = static_cast<float>(i / 31.0);
        memberships.At(i, j, k, 1) = static_cast<float>(1.0 - i / 31.0);
      }
  return memberships;
}

double
LinearYoungsModulus(double x)
{
  const double csf = x / 31.0;
  return csf * 10.0 + (1.0 - csf) * 3000.0;
}

double
LinearPoissonRatio(double x)
{
  const double csf = x / 31.0;
  return csf * 0.1 + (1.0 - csf) * 0.49;
}

Vector3
Centroid(const bmr::Model & model, const bmr::Cell & cell)
{
  Vector3 sum = Vector3::Zero();
  for (int a = 0; a < bmr::NodesPerCell(cell.type); ++a)
  {
    sum += model.nodes[cell.nodes[a]];
  }
  return sum / bmr::NodesPerCell(cell.type);
}

TEST(MaterialMappingMemberships, CellAveragesOfLinearFieldAreExact)
{
  const bmr::ScalarVolume memberships = LinearMemberships();
  for (auto cells : { bmr::GridCells::Hexahedra, bmr::GridCells::Tetrahedra, bmr::GridCells::Mixed })
  {
    bmr::Model model = bmr::MakeBlockMesh(Vector3(20, 20, 20), { 4, 4, 4 }, cells, bmr::Material{}, Vector3(5, 5, 5));
    bmr::MapMaterialsFromMemberships(model, memberships);
    model.Validate();
    for (std::size_t c = 0; c < model.cells.size(); ++c)
    {
      const bmr::Material & material = model.materials[model.cells[c].material];
      const double          x = Centroid(model, model.cells[c]).x();
      // Tolerance: the membership image is stored in float (relative 1e-7).
      EXPECT_NEAR(material.youngsModulus, LinearYoungsModulus(x), 1e-3) << "cell " << c;
      EXPECT_NEAR(material.poissonRatio, LinearPoissonRatio(x), 1e-6) << "cell " << c;
      EXPECT_DOUBLE_EQ(material.density, 1000.0);
      EXPECT_EQ(material.name.rfind("mix(E=", 0), 0u) << material.name;
    }
    // Equal mixtures share one entry: at most one material per distinct
    // centroid x (4 for the hexahedra's columns).
    std::set<long> columns;
    for (const auto & cell : model.cells)
    {
      columns.insert(std::lround(Centroid(model, cell).x() * 1e6));
    }
    EXPECT_LE(model.materials.size(), columns.size());
    if (cells == bmr::GridCells::Hexahedra)
    {
      EXPECT_EQ(model.materials.size(), 4u);
    }
  }
}

// Three classes: x < 16 parenchyma (split grey 0.3 / white 0.7), x >= 16 CSF.
bmr::ScalarVolume
PiecewiseMemberships()
{
  bmr::ScalarVolume memberships;
  memberships.geometry = CubeGeometry(32);
  memberships.components = 3;
  memberships.values.resize(memberships.geometry.VoxelCount() * 3);
  for (int k = 0; k < 32; ++k)
    for (int j = 0; j < 32; ++j)
      for (int i = 0; i < 32; ++i)
      {
        const bool csf = i >= 16;
        memberships.At(i, j, k, 0) = csf ? 1.0f : 0.0f;
        memberships.At(i, j, k, 1) = csf ? 0.0f : 0.3f;
        memberships.At(i, j, k, 2) = csf ? 0.0f : 0.7f;
      }
  return memberships;
}

TEST(MaterialMappingMemberships, PureCellsGetClassValuesExactly)
{
  const bmr::ScalarVolume memberships = PiecewiseMemberships();
  // Cells of 4 mm along x from 3: [3,7] [7,11] [11,15] pure parenchyma,
  // [15,19] straddles the jump (voxel 15 -> 16), [19,23] [23,27] pure CSF.
  bmr::Model model =
    bmr::MakeBlockMesh(Vector3(24, 8, 8), { 6, 2, 2 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(3, 4, 4));
  bmr::MapMaterialsFromMemberships(model, memberships);
  std::set<bmr::Index> parenchymaEntries;
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const bmr::Material & material = model.materials[model.cells[c].material];
    const double          x = Centroid(model, model.cells[c]).x();
    if (x < 15.0)
    {
      EXPECT_EQ(material.youngsModulus, 3000.0);
      EXPECT_EQ(material.poissonRatio, 0.49);
      EXPECT_EQ(material.name, "parenchyma");
      parenchymaEntries.insert(model.cells[c].material);
    }
    else if (x > 19.0)
    {
      EXPECT_EQ(material.youngsModulus, 10.0);
      EXPECT_EQ(material.poissonRatio, 0.1);
      EXPECT_EQ(material.name, "csf");
    }
    else
    {
      // Analytic average of the interpolated field over x in [15, 19]: u_csf
      // rises linearly from 0 at 15 to 1 at 16, then stays 1: (0.5 + 3) / 4.
      // n = 5 midpoint samples per direction miss the kink's integral by at
      // most 0.02 in u (stated tolerance).
      const double csf = 3.5 / 4.0;
      EXPECT_NEAR(material.youngsModulus, csf * 10.0 + (1 - csf) * 3000.0, 0.02 * 2990.0);
      EXPECT_EQ(material.name.rfind("mix(", 0), 0u);
    }
  }
  // All-parenchyma cells (grey + white, equal values) share one entry.
  EXPECT_EQ(parenchymaEntries.size(), 1u);
  // parenchyma, mixture, csf.
  EXPECT_EQ(model.materials.size(), 3u);

  // Configurable class materials: three different ones give a grey/white mixture.
  bmr::MaterialMappingSettings settings;
  settings.classMaterials = { bmr::CsfMaterial(), { "grey", 2000.0, 0.45, 1100.0 }, { "white", 4000.0, 0.49, 1000.0 } };
  bmr::MapMaterialsFromMemberships(model, memberships, settings);
  const bmr::Material & first = model.materials[model.cells[0].material];
  EXPECT_NEAR(first.youngsModulus, 0.3 * 2000.0 + 0.7 * 4000.0, 1e-3);
  EXPECT_NEAR(first.poissonRatio, 0.3 * 0.45 + 0.7 * 0.49, 1e-7);
  EXPECT_NEAR(first.density, 0.3 * 1100.0 + 0.7 * 1000.0, 1e-4);
}

// The mapping records each site's class shares (Model::tissueMixture), and
// mixing them again with every class's modulus scaled gives what mapping the
// memberships with those classes gives, site by site and bit for bit
// (hexahedra and meshless integration points; grey and white matter with
// equal values mix apart once their factors differ); unit factors give the
// mapping's own materials.
TEST(MaterialMappingMemberships, RemixedClassModuliEqualTheMappingOfScaledClasses)
{
  const bmr::ScalarVolume memberships = PiecewiseMemberships();
  for (const bool meshless : { false, true })
  {
    bmr::Model model =
      bmr::MakeBlockMesh(Vector3(24, 8, 8), { 6, 2, 2 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(3, 4, 4));
    if (meshless)
    {
      bmr::MakeMeshlessFromCells(model, bmr::MlsSettings{}, bmr::IntegrationSettings{});
    }
    bmr::MaterialMappingSettings settings;
    settings.classMaterials = bmr::DefaultClassMaterials(3);
    bmr::MapMaterialsFromMemberships(model, memberships, settings);
    const bmr::TissueMixture & mixture = model.tissueMixture;
    ASSERT_EQ(mixture.classes.size(), 4u) << "three classes and the tumour";
    const std::size_t sites = model.cells.size() + (meshless ? model.meshless.integrationPoints.size() : 0);
    ASSERT_EQ(mixture.shares.size(), 4 * sites);
    for (std::size_t site = 0; site < sites; ++site)
    {
      EXPECT_NEAR(mixture.shares[4 * site] + mixture.shares[4 * site + 1] + mixture.shares[4 * site + 2] +
                    mixture.shares[4 * site + 3],
                  1.0, 1e-12);
    }
    const auto materialOf = [&](const bmr::Model & m, std::size_t site) {
      return site < m.cells.size() ? m.materials[m.cells[site].material]
                                   : m.materials[m.meshless.integrationMaterials[site - m.cells.size()]];
    };
    const auto expectSameMaterials = [&](const bmr::Model & a, const bmr::Model & b, const char * what) {
      for (std::size_t site = 0; site < sites; ++site)
      {
        const bmr::Material first = materialOf(a, site), second = materialOf(b, site);
        EXPECT_EQ(first.youngsModulus, second.youngsModulus) << what << ", site " << site;
        EXPECT_EQ(first.poissonRatio, second.poissonRatio) << what << ", site " << site;
        EXPECT_EQ(first.density, second.density) << what << ", site " << site;
        EXPECT_EQ(first.name, second.name) << what << ", site " << site;
      }
      EXPECT_EQ(a.materials.size(), b.materials.size()) << what;
    };

    bmr::Model unit = model;
    bmr::RemixTissueModuli(unit, { 1.0, 1.0, 1.0, 1.0 });
    expectSameMaterials(unit, model, "unit factors");

    const std::vector<double> factors = { 0.5, 0.8, 1.6, 2.0 };
    bmr::Model                remixed = model;
    bmr::RemixTissueModuli(remixed, factors, 2);
    bmr::MaterialMappingSettings scaled = settings;
    for (std::size_t k = 0; k < 3; ++k)
    {
      scaled.classMaterials[k].youngsModulus *= factors[k];
    }
    scaled.tumour.youngsModulus *= factors[3];
    bmr::Model mapped = model;
    bmr::MapMaterialsFromMemberships(mapped, memberships, scaled);
    expectSameMaterials(remixed, mapped, "scaled classes");
    // Grey (0.3) and white (0.7) matter at 0.8 and 1.6 times 3 kPa.
    EXPECT_NEAR(materialOf(remixed, 0).youngsModulus, 0.3 * 2400.0 + 0.7 * 4800.0, 1e-3); // float memberships
    EXPECT_EQ(remixed.tissueMixture.shares, model.tissueMixture.shares) << "the mixture stays the nominal one";
  }

  bmr::Model model =
    bmr::MakeBlockMesh(Vector3(24, 8, 8), { 6, 2, 2 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(3, 4, 4));
  bmr::MapMaterialsFromMemberships(model, memberships);
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::RemixTissueModuli(model, { 1.0, 2.0 }); }), "one factor per class");
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::RemixTissueModuli(model, { 1.0, 0.0, 1.0, 1.0 }); }), "positive");
  bmr::Model plain =
    bmr::MakeBlockMesh(Vector3(24, 8, 8), { 6, 2, 2 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(3, 4, 4));
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::RemixTissueModuli(plain, { 1.0 }); }), "not mixed from tissue classes");
}

TEST(MaterialMappingMemberships, TumourMaskOverridesMemberships)
{
  const bmr::ScalarVolume memberships = LinearMemberships();
  bmr::LabelVolume        tumour = FullMask(memberships.geometry);
  for (int k = 0; k < 32; ++k)
    for (int j = 0; j < 32; ++j)
      for (int i = 0; i < 32; ++i)
      {
        tumour.At(i, j, k) = i >= 20 ? 1 : 0;
      }
  // Cells of 5 mm from x = 5: [5,10] [10,15] [15,20] [20,25].
  bmr::Model model =
    bmr::MakeBlockMesh(Vector3(20, 10, 10), { 4, 2, 2 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(5, 5, 5));
  bmr::MapMaterialsFromMemberships(model, memberships, {}, &tumour);
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const bmr::Material & material = model.materials[model.cells[c].material];
    const double          x = Centroid(model, model.cells[c]).x();
    if (x > 20.0) // entirely in the tumour: exactly its values
    {
      EXPECT_EQ(material.name, "tumour");
      EXPECT_EQ(material.youngsModulus, 6000.0);
      EXPECT_EQ(material.poissonRatio, 0.49);
    }
    else if (x < 15.0) // untouched by the tumour: the linear mixture
    {
      EXPECT_NEAR(material.youngsModulus, LinearYoungsModulus(x), 1e-3);
    }
    else // [15, 20]: interpolation reaches tumour voxel 20 between x = 19 and 20
    {
      EXPECT_GT(material.youngsModulus, LinearYoungsModulus(x));
      EXPECT_LT(material.youngsModulus, 6000.0);
    }
  }
  // A tumour mask on another grid is refused.
  bmr::LabelVolume shifted = tumour;
  shifted.geometry.origin = Vector3(0.5, 0, 0);
  const std::string message =
    ErrorMessage([&] { bmr::MapMaterialsFromMemberships(model, memberships, {}, &shifted); });
  EXPECT_NE(message.find("tumour mask is not on"), std::string::npos) << message;
}

TEST(MaterialMappingMemberships, ResectedTissueIsTheFirstClassFluidOverTheTumour)
{
  const bmr::ScalarVolume memberships = LinearMemberships();
  bmr::LabelVolume        tumour = FullMask(memberships.geometry);
  bmr::LabelVolume        resection = FullMask(memberships.geometry);
  for (int k = 0; k < 32; ++k)
    for (int j = 0; j < 32; ++j)
      for (int i = 0; i < 32; ++i)
      {
        tumour.At(i, j, k) = i >= 20 ? 1 : 0;
        resection.At(i, j, k) = i >= 10 && i <= 25 ? 1 : 0;
      }
  // Cells of 5 mm from x = 5: [5,10] [10,15] [15,20] [20,25] [25,30].
  bmr::Model model =
    bmr::MakeBlockMesh(Vector3(25, 10, 10), { 5, 2, 2 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(5, 5, 5));
  bmr::MaterialMappingSettings settings;
  settings.classMaterials = { { "fluid", 1.0, 0.2, 1.0 }, bmr::ParenchymaMaterial() };
  bmr::MapMaterialsFromMemberships(model, memberships, settings, &tumour, nullptr, &resection);
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const bmr::Material & material = model.materials[model.cells[c].material];
    const double          x = Centroid(model, model.cells[c]).x();
    if (x > 10.0 && x < 25.0) // resected, also where the tumour was: exactly the first class's values
    {
      EXPECT_EQ(material.name, "fluid") << "x " << x;
      EXPECT_EQ(material.youngsModulus, 1.0);
      EXPECT_EQ(material.poissonRatio, 0.2);
      EXPECT_EQ(material.density, 1.0);
    }
    else if (x < 10.0)
    {
      // [5,10]: six midpoint samples along x; the last (9.58) gives 0.58 of its weight to resected voxel 10,
      // 0.097 of the cell's, which takes the fluid's 1 Pa instead of voxel 10's mixture (2033 Pa): 197 Pa
      // softer than the linear mixture's average (stated tolerance 20 Pa for the sampling's rounding).
      const double mixture = 7.5 / 31.0 * 1.0 + (1.0 - 7.5 / 31.0) * 3000.0;
      EXPECT_NEAR(material.youngsModulus, mixture - 197.0, 20.0) << material.name;
    }
    else // [25,30]: the tumour the resection left, but for the first sample's 0.58 of resected voxel 25
    {
      EXPECT_NEAR(material.youngsModulus, 6000.0 - 0.0972 * 5999.0, 20.0) << material.name;
    }
  }
  // A resection mask on another grid is refused, by name.
  bmr::LabelVolume shifted = resection;
  shifted.geometry.origin = Vector3(0.5, 0, 0);
  const std::string message =
    ErrorMessage([&] { bmr::MapMaterialsFromMemberships(model, memberships, settings, &tumour, nullptr, &shifted); });
  EXPECT_NE(message.find("resection mask is not on"), std::string::npos) << message;
}

TEST(MaterialMappingMemberships, OutsideMaskTakesNearestVoxelAndOutsideImageFails)
{
  // Memberships only for x < 16 (mask), zero beyond.
  bmr::ScalarVolume memberships = LinearMemberships();
  for (int k = 0; k < 32; ++k)
    for (int j = 0; j < 32; ++j)
      for (int i = 16; i < 32; ++i)
      {
        memberships.At(i, j, k, 0) = memberships.At(i, j, k, 1) = 0.0f;
      }
  // Cells [5,12] (inside the mask), [12,19] (partly) and [20,27] (no sample in the mask) along x.
  bmr::Model model = bmr::MakeBlockMesh(Vector3(14, 6, 6), { 2, 1, 1 }, bmr::GridCells::Hexahedra, bmr::Material{},
                                        Vector3(5, 5, 5));
  bmr::Model far = bmr::MakeBlockMesh(Vector3(7, 6, 6), { 1, 1, 1 }, bmr::GridCells::Hexahedra, bmr::Material{},
                                      Vector3(20, 5, 5));
  const auto offset = static_cast<bmr::Index>(model.nodes.size());
  model.nodes.insert(model.nodes.end(), far.nodes.begin(), far.nodes.end());
  bmr::Cell cell = far.cells[0];
  for (auto & node : cell.nodes)
  {
    node += offset;
  }
  model.cells.push_back(cell);
  std::vector<std::string> warnings;
  bmr::MapMaterialsFromMemberships(model, memberships, {}, nullptr, &warnings);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("nearest mask voxel"), std::string::npos) << warnings[0];
  // Nearest mask voxel to the centroid (23.5, 8, 8): x index 15.
  EXPECT_NEAR(model.materials[model.cells[2].material].youngsModulus, LinearYoungsModulus(15.0), 1e-3);
  // Inside the mask: the value at the centroid.
  EXPECT_NEAR(model.materials[model.cells[0].material].youngsModulus, LinearYoungsModulus(8.5), 1e-3);
  // Partly outside: only the inside samples count. Interpolated, both
  // memberships fade as (16 - x) over x in [15, 16], so the average is
  // u_csf = [int_12^15 x/31 dx + int_15^16 (16 - x) 15/31 dx] / [3 + 1/2] = 0.44240;
  // 8 midpoint samples per direction resolve the fade to 0.01 in u (stated).
  const double partial = ((15.0 * 15.0 - 12.0 * 12.0) / 62.0 + 7.5 / 31.0) / 3.5;
  EXPECT_NEAR(model.materials[model.cells[1].material].youngsModulus, partial * 10.0 + (1.0 - partial) * 3000.0,
              0.01 * 2990.0);

  // A model away from the image is an error, not a silent fallback.
  bmr::Model outside = bmr::MakeBlockMesh(Vector3(10, 10, 10), { 2, 2, 2 }, bmr::GridCells::Tetrahedra,
                                          bmr::Material{}, Vector3(100, 100, 100));
  const std::string message = ErrorMessage([&] { bmr::MapMaterialsFromMemberships(outside, memberships); });
  EXPECT_NE(message.find("outside the image"), std::string::npos) << message;
  // A membership image with a NaN.
  bmr::ScalarVolume broken = memberships;
  broken.At(2, 3, 4, 1) = std::numeric_limits<float>::quiet_NaN();
  const std::string nanMessage = ErrorMessage([&] { bmr::MapMaterialsFromMemberships(model, broken); });
  EXPECT_NE(nanMessage.find("not a finite"), std::string::npos) << nanMessage;
  // Class materials that do not match the classes.
  bmr::MaterialMappingSettings settings;
  settings.classMaterials = bmr::DefaultClassMaterials(3);
  const std::string countMessage = ErrorMessage([&] { bmr::MapMaterialsFromMemberships(model, memberships, settings); });
  EXPECT_NE(countMessage.find("one material per class"), std::string::npos) << countMessage;
}

TEST(MaterialMappingMeshless, IntegrationPointsGetPointValues)
{
  const bmr::ScalarVolume memberships = LinearMemberships();
  bmr::Model model =
    bmr::MakeBlockMesh(Vector3(20, 20, 20), { 4, 4, 4 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(5, 5, 5));
  bmr::MakeMeshlessFromCells(model, bmr::MlsSettings{}, bmr::IntegrationSettings{});
  const auto & points = model.meshless.integrationPoints;
  ASSERT_EQ(points.size(), 512u); // 64 cells x 8 Gauss points
  bmr::MaterialMappingSettings settings;
  settings.sampling.threads = 2;
  bmr::MapMaterialsFromMemberships(model, memberships, settings);
  model.Validate();
  ASSERT_EQ(model.meshless.integrationMaterials.size(), points.size());
  // Cube of edge cbrt(w) = 2.5 mm centred at the point: the average of a
  // linear field is its value at the point.
  for (std::size_t p = 0; p < points.size(); ++p)
  {
    const bmr::Material & material = model.materials[model.meshless.integrationMaterials[p]];
    EXPECT_NEAR(material.youngsModulus, LinearYoungsModulus(points[p].x()), 1e-3) << "point " << p;
    EXPECT_NEAR(material.poissonRatio, LinearPoissonRatio(points[p].x()), 1e-6) << "point " << p;
  }
  // Same result on 1 thread.
  bmr::Model single = model;
  settings.sampling.threads = 1;
  bmr::MapMaterialsFromMemberships(single, memberships, settings);
  EXPECT_EQ(single.meshless.integrationMaterials, model.meshless.integrationMaterials);
  ASSERT_EQ(single.materials.size(), model.materials.size());
  for (std::size_t m = 0; m < model.materials.size(); ++m)
  {
    EXPECT_EQ(single.materials[m].youngsModulus, model.materials[m].youngsModulus);
  }
}

TEST(MaterialMappingLabels, MajorityLabelAndMissingMaterial)
{
  bmr::LabelVolume labels;
  labels.geometry = CubeGeometry(32);
  labels.values.resize(labels.geometry.VoxelCount());
  for (int k = 0; k < 32; ++k)
    for (int j = 0; j < 32; ++j)
      for (int i = 0; i < 32; ++i)
      {
        labels.At(i, j, k) = i < 16 ? 1 : 2; // boundary at x = 15.5
      }
  // Cells of 8 mm from x = 4: [4,12] all label 1; [12,20] 3.5 mm of label 1,
  // 4.5 mm of label 2 -> 2; [20,28] label 2.
  bmr::Model model =
    bmr::MakeBlockMesh(Vector3(24, 8, 8), { 3, 1, 1 }, bmr::GridCells::Hexahedra, bmr::Material{}, Vector3(4, 4, 4));
  const std::map<int, bmr::Material> materials = { { 1, bmr::ParenchymaMaterial() },
                                                   { 2, { "", 6000.0, 0.45, 1050.0 } } };
  bmr::MapMaterialsFromLabels(model, labels, materials);
  ASSERT_EQ(model.materials.size(), 2u);
  EXPECT_EQ(model.materials[model.cells[0].material].name, "parenchyma");
  EXPECT_EQ(model.materials[model.cells[1].material].name, "label 2");
  EXPECT_EQ(model.materials[model.cells[1].material].youngsModulus, 6000.0);
  EXPECT_EQ(model.materials[model.cells[2].material].density, 1050.0);

  // Meshless: each integration point takes the label at its neighbourhood.
  bmr::Model meshless = model;
  bmr::MakeMeshlessFromCells(meshless, bmr::MlsSettings{}, bmr::IntegrationSettings{});
  bmr::MaterialSampling pointwise;
  pointwise.neighbourhoodSize = 0.5; // below the voxel size: one sample, the point's voxel
  bmr::MapMaterialsFromLabels(meshless, labels, materials, pointwise);
  for (std::size_t p = 0; p < meshless.meshless.integrationPoints.size(); ++p)
  {
    const double x = meshless.meshless.integrationPoints[p].x();
    if (std::abs(x - 15.5) > 0.01)
    {
      EXPECT_EQ(meshless.materials[meshless.meshless.integrationMaterials[p]].youngsModulus, x < 15.5 ? 3000.0 : 6000.0)
        << "point " << p << " at x " << x;
    }
  }

  // A label the model meets without a material is named.
  const std::map<int, bmr::Material> incomplete = { { 1, bmr::ParenchymaMaterial() } };
  const std::string message = ErrorMessage([&] { bmr::MapMaterialsFromLabels(model, labels, incomplete); });
  EXPECT_NE(message.find("label 2"), std::string::npos) << message;
  EXPECT_NE(message.find("no material"), std::string::npos) << message;
}

TEST(MaterialMappingDefaults, ClassMaterialsForK)
{
  const auto two = bmr::DefaultClassMaterials(2);
  ASSERT_EQ(two.size(), 2u);
  EXPECT_EQ(two[0].youngsModulus, 10.0);
  EXPECT_EQ(two[0].poissonRatio, 0.1);
  EXPECT_EQ(two[1].youngsModulus, 3000.0);
  EXPECT_EQ(two[1].poissonRatio, 0.49);
  const auto three = bmr::DefaultClassMaterials(3);
  ASSERT_EQ(three.size(), 3u);
  EXPECT_EQ(three[0].name, "csf");
  EXPECT_EQ(three[2].youngsModulus, 3000.0);
  EXPECT_EQ(bmr::TumourMaterial().youngsModulus, 6000.0);
  for (const auto & material : three)
  {
    EXPECT_EQ(material.density, 1000.0);
  }
}

} // namespace
