#include "bmrElectrodes.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkCompositeTransform.h"
#include "itkConnectedComponentImageFilter.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkImageRegistrationMethodv4.h"
#include "itkRegistrationComponents.h"
#include "itkSignedMaurerDistanceMapImageFilter.h"
#include "itkRegistrationParameterScalesFromPhysicalShift.h"
#include "itkRegularStepGradientDescentOptimizerv4.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>

namespace bmr
{

namespace
{

constexpr double kAirHU = -1000.0;
constexpr double kBoneHU = 1100.0;
constexpr double kSoftTissueHU = 40.0;
constexpr double kMetalHU = 3000.0;
constexpr double kFluidHU = 5.0;   // CSF, and saline where the brain sank away
constexpr double kCsfLayer = 2.5;  // mm of dark voxels around the brain taken as CSF, not bone

Vector3
ToVector(const itk::Point<double, 3> & point)
{
  return Vector3(point[0], point[1], point[2]);
}

itk::Point<double, 3>
ToPoint(const Vector3 & vector)
{
  itk::Point<double, 3> point;
  for (unsigned int d = 0; d < 3; ++d)
  {
    point[d] = vector[d];
  }
  return point;
}

/** The value below which `fraction` of `values` lie (values is reordered). */
double
Quantile(std::vector<float> & values, double fraction)
{
  if (values.empty())
  {
    return 0.0;
  }
  const auto at = values.begin() + static_cast<std::ptrdiff_t>(fraction * static_cast<double>(values.size() - 1));
  std::nth_element(values.begin(), at, values.end());
  return *at;
}

/** Centroid (mm) of the voxels above `threshold`; throws when there are none. */
template <typename TImage>
Vector3
CentroidAbove(const TImage * image, double threshold, const std::string & what)
{
  Vector3     sum = Vector3::Zero();
  std::size_t count = 0;
  for (itk::ImageRegionConstIteratorWithIndex<TImage> it(image, image->GetBufferedRegion()); !it.IsAtEnd(); ++it)
  {
    if (it.Get() > threshold)
    {
      itk::Point<double, 3> point;
      image->TransformIndexToPhysicalPoint(it.GetIndex(), point);
      sum += ToVector(point);
      ++count;
    }
  }
  if (count == 0)
  {
    throw Error("the " + what + " has no voxel above " + std::to_string(threshold) + ": is it the right image?");
  }
  return sum / static_cast<double>(count);
}

/** Inside the head: between the first and last bright voxel along each of
 *  the three grid lines through a voxel (fills the dark skull between scalp
 *  and brain, leaves the air around the head). */
std::vector<char>
HeadEnvelope(const RegistrationImage * image, double bright)
{
  const auto          size = image->GetBufferedRegion().GetSize();
  const float *       values = image->GetBufferPointer();
  const std::size_t   count = image->GetBufferedRegion().GetNumberOfPixels();
  std::vector<char>   inside(count, 1);
  const std::size_t   stride[3] = { 1, size[0], size[0] * size[1] };
  for (unsigned int axis = 0; axis < 3; ++axis)
  {
    const unsigned int a = (axis + 1) % 3, b = (axis + 2) % 3;
    for (std::size_t i = 0; i < size[a]; ++i)
    {
      for (std::size_t j = 0; j < size[b]; ++j)
      {
        const std::size_t start = i * stride[a] + j * stride[b];
        long              first = -1, last = -1;
        for (std::size_t k = 0; k < size[axis]; ++k)
        {
          if (values[start + k * stride[axis]] > bright)
          {
            last = static_cast<long>(k);
            first = first < 0 ? last : first;
          }
        }
        for (std::size_t k = 0; k < size[axis]; ++k)
        {
          const long position = static_cast<long>(k);
          if (position < first || position > last || first < 0)
          {
            inside[start + k * stride[axis]] = 0;
          }
        }
      }
    }
  }
  return inside;
}

/** Hounsfield units of the head on the T1's grid (see MakeSyntheticElectrodeCt), plus 1000 (air 0: the warp's padding). */
RegistrationImage::Pointer
HeadInHounsfieldUnits(const RegistrationImage * image, const RegistrationLabelImage * brainMask)
{
  const std::size_t     count = image->GetBufferedRegion().GetNumberOfPixels();
  const float *         values = image->GetBufferPointer();
  const unsigned char * brain = brainMask->GetBufferPointer();
  std::vector<float>    brainValues;
  for (std::size_t n = 0; n < count; ++n)
  {
    if (brain[n] > 0)
    {
      brainValues.push_back(values[n]);
    }
  }
  if (brainValues.empty())
  {
    throw Error("the brain mask of the synthetic CT is empty");
  }
  const double white = Quantile(brainValues, 0.95); // white matter's level in the T1
  if (!(white > 0.0))
  {
    throw Error("the synthetic CT needs a T1 image with a positive brain intensity");
  }
  const std::vector<char> head = HeadEnvelope(image, 0.25 * white);
  // Dark voxels next to the brain are the CSF around it, farther out the skull.
  auto distance = itk::SignedMaurerDistanceMapImageFilter<RegistrationLabelImage, RegistrationImage>::New();
  distance->SetInput(brainMask);
  distance->SetUseImageSpacing(true);
  distance->SetSquaredDistance(false);
  distance->SetInsideIsPositive(false);
  distance->Update();
  const float * fromBrain = distance->GetOutput()->GetBufferPointer();
  auto          hounsfield = RegistrationImage::New();
  hounsfield->CopyInformation(image);
  hounsfield->SetRegions(image->GetBufferedRegion());
  hounsfield->Allocate();
  float * out = hounsfield->GetBufferPointer();
  for (std::size_t n = 0; n < count; ++n)
  {
    const double relative = values[n] / white;
    double       hu = kAirHU;
    if (brain[n] > 0)
    {
      hu = kFluidHU + 30.0 * std::clamp(relative, 0.0, 1.2);
    }
    else if (head[n])
    {
      hu = relative >= 0.35 ? kSoftTissueHU : fromBrain[n] <= kCsfLayer ? kFluidHU : kBoneHU;
    }
    out[n] = static_cast<float>(hu - kAirHU);
  }
  return hounsfield;
}

/** Adds metal spheres (centres in the image's physical space) with their partial volume. */
void
PaintContacts(RegistrationImage * ct, const std::vector<Vector3> & centres, double radius)
{
  constexpr int kSubsamples = 5;
  const auto    region = ct->GetBufferedRegion();
  for (const Vector3 & centre : centres)
  {
    itk::ContinuousIndex<double, 3> low, high;
    RegistrationImage::IndexType    first, last;
    ct->TransformPhysicalPointToContinuousIndex(ToPoint(centre), low);
    high = low;
    // The sphere's reach in index units along each axis (spacing may differ).
    for (unsigned int d = 0; d < 3; ++d)
    {
      const double reach = radius / ct->GetSpacing()[d] + 1.0;
      first[d] = static_cast<itk::IndexValueType>(std::floor(low[d] - reach));
      last[d] = static_cast<itk::IndexValueType>(std::ceil(high[d] + reach));
    }
    RegistrationImage::RegionType box;
    box.SetIndex(first);
    for (unsigned int d = 0; d < 3; ++d)
    {
      box.SetSize(d, static_cast<itk::SizeValueType>(last[d] - first[d] + 1));
    }
    if (!box.Crop(region))
    {
      throw Error("a synthetic electrode contact at " + FormatPoint(centre) + " lies outside the CT");
    }
    for (itk::ImageRegionIteratorWithIndex<RegistrationImage> it(ct, box); !it.IsAtEnd(); ++it)
    {
      int inside = 0;
      for (int i = 0; i < kSubsamples; ++i)
      {
        for (int j = 0; j < kSubsamples; ++j)
        {
          for (int k = 0; k < kSubsamples; ++k)
          {
            itk::ContinuousIndex<double, 3> sample;
            const int                       offsets[3] = { i, j, k };
            for (unsigned int d = 0; d < 3; ++d)
            {
              sample[d] = static_cast<double>(it.GetIndex()[d]) + (offsets[d] + 0.5) / kSubsamples - 0.5;
            }
            itk::Point<double, 3> point;
            ct->TransformContinuousIndexToPhysicalPoint(sample, point);
            inside += (ToVector(point) - centre).norm() <= radius ? 1 : 0;
          }
        }
      }
      const double fraction = inside / double(kSubsamples * kSubsamples * kSubsamples);
      it.Set(static_cast<float>((1.0 - fraction) * it.Get() + fraction * kMetalHU));
    }
  }
}

} // namespace

// ---------------------------------------------------------------------------
// Finding the contacts.
// ---------------------------------------------------------------------------

std::vector<ElectrodeContact>
DetectElectrodeContacts(const RegistrationImage *          ct,
                        const ElectrodeDetectionSettings & settings,
                        std::vector<std::string> *         warnings)
{
  if (ct == nullptr)
  {
    throw Error("no CT image: give the intraoperative CT with the electrodes");
  }
  if (!(settings.threshold > settings.tissueLevel) || !(settings.minimumVolume >= 0.0) ||
      !(settings.maximumVolume > settings.minimumVolume) || settings.expectedContacts < 0)
  {
    throw Error("electrode detection: the threshold must exceed the tissue level and the volume range must be "
                "0 <= minimum < maximum");
  }
  using LabelImage = itk::Image<unsigned int, 3>;
  auto binary = RegistrationLabelImage::New();
  binary->CopyInformation(ct);
  binary->SetRegions(ct->GetBufferedRegion());
  binary->Allocate();
  const std::size_t count = ct->GetBufferedRegion().GetNumberOfPixels();
  std::size_t       metal = 0;
  for (std::size_t n = 0; n < count; ++n)
  {
    const bool above = ct->GetBufferPointer()[n] > settings.threshold;
    binary->GetBufferPointer()[n] = above ? 1 : 0;
    metal += above ? 1 : 0;
  }
  if (metal == 0)
  {
    throw Error("no electrode contact in the CT: no voxel is above " + std::to_string(settings.threshold) +
                " HU (is it a CT in Hounsfield units? lower the threshold for a CT scaled otherwise)");
  }
  auto components = itk::ConnectedComponentImageFilter<RegistrationLabelImage, LabelImage>::New();
  components->SetInput(binary);
  components->FullyConnectedOn();
  components->Update();
  const LabelImage * labels = components->GetOutput();

  // Each blob's box (indices) and peak value, then its metal fraction over the box grown by one voxel.
  struct Blob
  {
    RegistrationImage::IndexType low, high;
    double                       peak = -1e300;
  };
  std::map<unsigned int, Blob> blobs;
  for (itk::ImageRegionConstIteratorWithIndex<LabelImage> it(labels, labels->GetBufferedRegion()); !it.IsAtEnd(); ++it)
  {
    if (it.Get() == 0)
    {
      continue;
    }
    auto [entry, added] = blobs.try_emplace(it.Get());
    Blob & blob = entry->second;
    for (unsigned int d = 0; d < 3; ++d)
    {
      blob.low[d] = added ? it.GetIndex()[d] : std::min(blob.low[d], it.GetIndex()[d]);
      blob.high[d] = added ? it.GetIndex()[d] : std::max(blob.high[d], it.GetIndex()[d]);
    }
    blob.peak = std::max(blob.peak, static_cast<double>(ct->GetPixel(it.GetIndex())));
  }
  const double voxelVolume = ct->GetSpacing()[0] * ct->GetSpacing()[1] * ct->GetSpacing()[2];
  std::vector<ElectrodeContact> contacts;
  std::vector<std::string>      rejected;
  for (const auto & [label, blob] : blobs)
  {
    RegistrationImage::RegionType box;
    for (unsigned int d = 0; d < 3; ++d)
    {
      box.SetIndex(d, blob.low[d] - 1);
      box.SetSize(d, static_cast<itk::SizeValueType>(blob.high[d] - blob.low[d] + 3));
    }
    box.Crop(ct->GetBufferedRegion());
    double  weight = 0.0;
    Vector3 moment = Vector3::Zero();
    for (itk::ImageRegionConstIteratorWithIndex<RegistrationImage> it(ct, box); !it.IsAtEnd(); ++it)
    {
      const double fraction = std::clamp((it.Get() - settings.tissueLevel) / (blob.peak - settings.tissueLevel), 0.0, 1.0);
      if (fraction < 0.02) // noise in the tissue around the contact
      {
        continue;
      }
      itk::Point<double, 3> point;
      ct->TransformIndexToPhysicalPoint(it.GetIndex(), point);
      weight += fraction;
      moment += fraction * ToVector(point);
    }
    const ElectrodeContact contact{ moment / weight, weight * voxelVolume };
    if (contact.volume < settings.minimumVolume || contact.volume > settings.maximumVolume)
    {
      std::ostringstream text;
      text << "a metal blob of " << contact.volume << " mm^3 at " << FormatPoint(contact.position)
           << " is not a contact (volume outside " << settings.minimumVolume << ".." << settings.maximumVolume
           << " mm^3); left out";
      rejected.push_back(text.str());
      continue;
    }
    contacts.push_back(contact);
  }
  if (warnings != nullptr)
  {
    warnings->insert(warnings->end(), rejected.begin(), rejected.end());
  }
  if (contacts.empty())
  {
    throw Error("no electrode contact in the CT: " + std::to_string(blobs.size()) +
                " metal blob(s), none of a contact's volume (" + (rejected.empty() ? std::string() : rejected.front()) +
                "); adjust the volume range");
  }
  if (settings.expectedContacts > 0 && static_cast<int>(contacts.size()) != settings.expectedContacts)
  {
    throw Error("found " + std::to_string(contacts.size()) + " electrode contacts in the CT, expected " +
                std::to_string(settings.expectedContacts) +
                ": touching contacts, contacts outside the CT or a wrong threshold (" + std::to_string(settings.threshold) +
                " HU)");
  }
  return contacts;
}

// ---------------------------------------------------------------------------
// CT to MRI.
// ---------------------------------------------------------------------------

RigidAlignment
AlignCtToMri(const RegistrationImage * ct, const RegistrationImage * mri, const RigidAlignmentSettings & settings)
{
  if (ct == nullptr || mri == nullptr)
  {
    throw Error("the rigid alignment needs the CT and the MRI");
  }
  const std::size_t levels = settings.shrinkFactors.size();
  if (levels == 0 || settings.smoothingSigmas.size() != levels || settings.histogramBins < 8 ||
      settings.iterations == 0 || settings.maximumSamples == 0)
  {
    throw Error("rigid alignment settings: give as many smoothing sigmas as shrink factors (at least one level), "
                "at least 8 histogram bins, iterations and samples");
  }
  const auto start = std::chrono::steady_clock::now();

  // The metric sees the CT clipped: bone's range, no metal.
  auto clipped = RegistrationImage::New();
  clipped->CopyInformation(ct);
  clipped->SetRegions(ct->GetBufferedRegion());
  clipped->Allocate();
  const std::size_t ctCount = ct->GetBufferedRegion().GetNumberOfPixels();
  for (std::size_t n = 0; n < ctCount; ++n)
  {
    clipped->GetBufferPointer()[n] =
      static_cast<float>(std::clamp(static_cast<double>(ct->GetBufferPointer()[n]), kAirHU, settings.metalClip));
  }
  const float * mriValues = mri->GetBufferPointer();
  std::vector<float> values(mriValues, mriValues + mri->GetBufferedRegion().GetNumberOfPixels());
  const double       mriBright = Quantile(values, 0.99);

  // Start: the heads' centroids aligned, no rotation.
  RigidAlignment result;
  result.ctToMri = RigidTransform::New();
  const Vector3 ctCentre = CentroidAbove(ct, -500.0, "CT (Hounsfield units)");
  const Vector3 mriCentre = CentroidAbove(mri, 0.2 * mriBright, "MRI");
  result.ctToMri->SetCenter(ToPoint(ctCentre));
  RigidTransform::OutputVectorType translation;
  for (unsigned int d = 0; d < 3; ++d)
  {
    translation[d] = mriCentre[d] - ctCentre[d];
  }
  result.ctToMri->SetTranslation(translation);

  using MetricType = itk::FixedWorkUnitsMattesMetric<RegistrationImage>;
  auto metric = MetricType::New();
  metric->SetNumberOfHistogramBins(settings.histogramBins);
  metric->SetUseMovingImageGradientFilter(false);
  metric->SetUseFixedImageGradientFilter(false);
  metric->SetFixedNumberOfWorkUnits(1);

  auto scales = itk::RegistrationParameterScalesFromPhysicalShift<MetricType>::New();
  scales->SetMetric(metric);
  auto optimizer = itk::RegularStepGradientDescentOptimizerv4<double>::New();
  optimizer->SetScalesEstimator(scales);
  optimizer->SetLearningRate(2.0); // mm: the largest first step
  optimizer->SetMinimumStepLength(0.005);
  optimizer->SetRelaxationFactor(0.6);
  optimizer->SetNumberOfIterations(settings.iterations);
  optimizer->SetDoEstimateLearningRateOnce(false);
  optimizer->SetDoEstimateLearningRateAtEachIteration(false);

  using RegistrationType = itk::ImageRegistrationMethodv4<RegistrationImage, RegistrationImage, RigidTransform>;
  auto registration = RegistrationType::New();
  registration->SetFixedImage(clipped);
  registration->SetMovingImage(mri);
  registration->SetMetric(metric);
  registration->SetOptimizer(optimizer);
  registration->SetInitialTransform(result.ctToMri);
  registration->InPlaceOn();
  registration->SetNumberOfLevels(static_cast<unsigned int>(levels));
  typename RegistrationType::ShrinkFactorsArrayType    shrink(levels);
  typename RegistrationType::SmoothingSigmasArrayType  sigmas(levels);
  typename RegistrationType::MetricSamplingPercentageArrayType percentages(levels);
  for (std::size_t level = 0; level < levels; ++level)
  {
    shrink[level] = std::max(1u, settings.shrinkFactors[level]);
    sigmas[level] = settings.smoothingSigmas[level];
    const double voxels = static_cast<double>(ctCount) / std::pow(static_cast<double>(shrink[level]), 3.0);
    percentages[level] = std::min(1.0, settings.maximumSamples / voxels);
  }
  registration->SetShrinkFactorsPerLevel(shrink);
  registration->SetSmoothingSigmasPerLevel(sigmas);
  registration->SetSmoothingSigmasAreSpecifiedInPhysicalUnits(true);
  registration->SetMetricSamplingStrategy(RegistrationType::MetricSamplingStrategyEnum::RANDOM);
  registration->SetMetricSamplingPercentagePerLevel(percentages);
  registration->MetricSamplingReinitializeSeed(settings.randomSeed);
  try
  {
    registration->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(std::string("the rigid registration of the CT to the MRI failed: ") + exception.GetDescription());
  }
  result.metricValue = optimizer->GetCurrentMetricValue();
  result.iterations = static_cast<unsigned int>(optimizer->GetCurrentIteration());
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

// ---------------------------------------------------------------------------
// The whole localisation.
// ---------------------------------------------------------------------------

ContactSurface
ElectrodeReferenceSurface(const RegistrationLabelImage * brainMask, std::vector<std::string> * warnings)
{
  std::vector<std::string> surfaceWarnings;
  const BrainSurfaces      surfaces =
    BrainSurfacesOfMask(MaskVolume(brainMask, "brain mask"), BrainModelSettings{}.skullGap, surfaceWarnings);
  if (warnings != nullptr)
  {
    warnings->insert(warnings->end(), surfaceWarnings.begin(), surfaceWarnings.end());
  }
  return surfaces.brain;
}

ElectrodeLocalisation
LocateElectrodes(const RegistrationImage *             ct,
                 const RegistrationImage *             mri,
                 const ContactSurface &                preoperativeBrainSurface,
                 const ElectrodeLocalisationSettings & settings)
{
  ElectrodeLocalisation result;
  result.contactsInCt = DetectElectrodeContacts(ct, settings.detection, &result.warnings);
  result.alignment = AlignCtToMri(ct, mri, settings.alignment);
  for (const ElectrodeContact & contact : result.contactsInCt)
  {
    result.contacts.push_back(ToVector(result.alignment.ctToMri->TransformPoint(ToPoint(contact.position))));
  }
  result.loads = ProjectOntoSurface(result.contacts, preoperativeBrainSurface,
                                    settings.projectionDirection ? &*settings.projectionDirection : nullptr);
  return result;
}

// ---------------------------------------------------------------------------
// A synthetic CT with a known answer.
// ---------------------------------------------------------------------------

SyntheticElectrodeCt
MakeSyntheticElectrodeCt(const RegistrationImage *            preoperativeImage,
                         const RegistrationLabelImage *       brainMask,
                         const SyntheticBrainShift &          truth,
                         const Vector3 &                      craniotomyCentre,
                         const SyntheticElectrodeCtSettings & settings)
{
  if (preoperativeImage == nullptr || brainMask == nullptr ||
      preoperativeImage->GetBufferedRegion().GetSize() != brainMask->GetBufferedRegion().GetSize())
  {
    throw Error("the synthetic CT needs the preoperative image and its brain mask on the same grid");
  }
  if (truth.forwardTransform.IsNull() || truth.truthTransform.IsNull() || truth.down.norm() == 0.0)
  {
    throw Error("the synthetic CT needs a ground truth made by MakeSyntheticBrainShift");
  }
  if (settings.rows < 1 || settings.columns < 1 || !(settings.contactSpacing > 2.0 * settings.contactRadius) ||
      !(settings.contactRadius > 0.0) || !(settings.spacing.minCoeff() > 0.0) || !(settings.noise >= 0.0))
  {
    throw Error("synthetic CT settings: rows and columns >= 1, a contact radius > 0 below half the contact spacing, "
                "positive voxel spacing and noise >= 0");
  }
  SyntheticElectrodeCt ct;

  // The grid in the plane across "down" through the craniotomy's centre, dropped along "down" onto the brain surface.
  const Vector3        down = truth.down.normalized();
  const Vector3        across = down.unitOrthogonal();
  const Vector3        along = down.cross(across);
  std::vector<Vector3> planar;
  for (int r = 0; r < settings.rows; ++r)
  {
    for (int c = 0; c < settings.columns; ++c)
    {
      planar.push_back(craniotomyCentre + settings.contactSpacing * ((r - 0.5 * (settings.rows - 1)) * across +
                                                                     (c - 0.5 * (settings.columns - 1)) * along));
    }
  }
  ct.preoperativeContacts = ProjectOntoSurface(planar, ElectrodeReferenceSurface(brainMask), &down).points;
  for (const Vector3 & contact : ct.preoperativeContacts)
  {
    ct.contacts.push_back(ToVector(truth.forwardTransform->TransformPoint(ToPoint(contact))));
  }

  // The head's position in the scanner: a rotation about the brain's centroid and a translation.
  ct.mriToCt = RigidTransform::New();
  ct.mriToCt->SetCenter(ToPoint(CentroidAbove(brainMask, 0.0, "brain mask of the synthetic CT")));
  const double degrees = std::acos(-1.0) / 180.0;
  ct.mriToCt->SetRotation(settings.rotation.x() * degrees, settings.rotation.y() * degrees,
                          settings.rotation.z() * degrees);
  RigidTransform::OutputVectorType translation;
  for (unsigned int d = 0; d < 3; ++d)
  {
    translation[d] = settings.translation[d];
  }
  ct.mriToCt->SetTranslation(translation);

  // The CT's grid: the MRI's box carried by the rigid motion, at the CT's spacing.
  auto grid = RegistrationImage::New();
  grid->SetOrigin(ct.mriToCt->TransformPoint(preoperativeImage->GetOrigin()));
  grid->SetDirection(ct.mriToCt->GetMatrix() * preoperativeImage->GetDirection());
  RegistrationImage::SpacingType spacing;
  RegistrationImage::SizeType    size;
  for (unsigned int d = 0; d < 3; ++d)
  {
    spacing[d] = settings.spacing[d];
    const double extent = static_cast<double>(preoperativeImage->GetLargestPossibleRegion().GetSize()[d] - 1) *
                          preoperativeImage->GetSpacing()[d];
    size[d] = static_cast<itk::SizeValueType>(std::floor(extent / spacing[d])) + 1;
  }
  grid->SetSpacing(spacing);
  grid->SetRegions(size);

  // The brain moved by the ground truth, the skull and scalp by the rigid
  // motion only: CT point -> MRI point (inverse rigid motion), and for the
  // brain on to its preoperative point (the ground truth's backward map).
  // Where the brain sank away from the skull there is fluid.
  const auto mriFromCt = ct.mriToCt->GetInverseTransform();
  auto       ctToPreoperative = itk::CompositeTransform<double, 3>::New();
  ctToPreoperative->AddTransform(truth.truthTransform);
  ctToPreoperative->AddTransform(mriFromCt);
  const RegistrationImage::Pointer hounsfield = HeadInHounsfieldUnits(preoperativeImage, brainMask);
  ct.image = WarpImage(hounsfield, ctToPreoperative, grid);
  const RegistrationImage::Pointer      head = WarpImage(hounsfield, mriFromCt, grid);
  const RegistrationLabelImage::Pointer shiftedBrain = WarpLabelImage(brainMask, ctToPreoperative, grid);
  const RegistrationLabelImage::Pointer formerBrain = WarpLabelImage(brainMask, mriFromCt, grid);
  float *           values = ct.image->GetBufferPointer();
  const std::size_t count = ct.image->GetBufferedRegion().GetNumberOfPixels();
  for (std::size_t n = 0; n < count; ++n)
  {
    if (shiftedBrain->GetBufferPointer()[n] == 0)
    {
      values[n] = formerBrain->GetBufferPointer()[n] > 0 ? static_cast<float>(kFluidHU - kAirHU) : head->GetBufferPointer()[n];
    }
    values[n] += static_cast<float>(kAirHU);
  }
  std::vector<Vector3> inScanner;
  for (const Vector3 & contact : ct.contacts)
  {
    inScanner.push_back(ToVector(ct.mriToCt->TransformPoint(ToPoint(contact))));
  }
  PaintContacts(ct.image, inScanner, settings.contactRadius);
  if (settings.noise > 0.0)
  {
    AddImageNoise(ct.image, settings.noise, NoiseModel::Gaussian, settings.seed);
  }
  return ct;
}

ElectrodeLocalisationErrors
MeasureElectrodeLocalisation(const ElectrodeLocalisation & located, const SyntheticElectrodeCt & truth)
{
  ElectrodeLocalisationErrors errors;
  std::vector<int>            matched(truth.contacts.size(), 0);
  const double                count = static_cast<double>(std::max<std::size_t>(1, located.contacts.size()));
  for (std::size_t k = 0; k < located.contacts.size(); ++k)
  {
    std::size_t nearest = 0;
    double      distance = std::numeric_limits<double>::infinity();
    for (std::size_t t = 0; t < truth.contacts.size(); ++t)
    {
      const double d = (located.contacts[k] - truth.contacts[t]).norm();
      if (d < distance)
      {
        distance = d;
        nearest = t;
      }
    }
    if (truth.contacts.empty())
    {
      break;
    }
    ++matched[nearest];
    const Vector3 inCt = ToVector(truth.mriToCt->TransformPoint(ToPoint(truth.contacts[nearest])));
    errors.detectionMax = std::max(errors.detectionMax, (located.contactsInCt[k].position - inCt).norm());
    errors.locationMax = std::max(errors.locationMax, distance);
    errors.locationMean += distance / count;
    const Vector3 displacement = truth.contacts[nearest] - truth.preoperativeContacts[nearest];
    const double  error = (located.loads.displacements[k] - displacement).norm();
    errors.displacementMax = std::max(errors.displacementMax, error);
    errors.displacementMean += error / count;
  }
  errors.eachContactFoundOnce = std::all_of(matched.begin(), matched.end(), [](int m) { return m == 1; });
  return errors;
}

} // namespace bmr
