// The synthetic electrode CT (bmrSyntheticElectrodeCt.h): a fixture of the evaluation library.
#include "bmrSyntheticElectrodeCt.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkCompositeTransform.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkSignedMaurerDistanceMapImageFilter.h"

#include "bmrElectrodeImages.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <random>

namespace bmr
{

using namespace electrodes;

namespace
{

constexpr double kBoneHU = 1100.0;
constexpr double kSoftTissueHU = 40.0;
constexpr double kMetalHU = 3000.0;
constexpr double kFluidHU = 5.0;   // CSF, and saline where the brain sank away
constexpr double kCsfLayer = 2.5;  // mm of dark voxels around the brain taken as CSF, not bone

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
