#include "bmrElectrodes.h"
#include "bmrElectrodeImages.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkConnectedComponentImageFilter.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegistrationMethodv4.h"
#include "itkFixedWorkUnitsMattesMetric.h"
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

using namespace electrodes;

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

} // namespace bmr
