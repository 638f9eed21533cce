// What the pipeline's sources share and nothing else needs: running a filter
// of the chain with ITK's exception as the module's error, the patient's
// superior axis and skull base, the model's regions as the registration makes
// them (PrepareBrainModel, and the uncertainty ensemble's drawn openings), and
// text for messages (private to the pipeline, not installed).
#ifndef bmrPipelineDetail_h
#define bmrPipelineDetail_h

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalImageIO.h"
#include "itkBiomechanicalRegionsFilter.h"

#include "bmrBrainShiftRegistration.h"
#include "bmrUnits.h"

#include <cmath>
#include <iomanip>
#include <sstream>
#include <string>

namespace bmr
{

/** Runs one filter of the chain; its itk::ExceptionObject becomes the bmr::Error every caller translates. */
template <typename TFilter>
void
UpdateStage(TFilter * filter, const std::string & what)
{
  try
  {
    filter->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(what + ": " + itk::PlainDescription(exception.GetDescription()));
  }
}

/** An acceleration (mm/s^2) in g, for messages. */
inline std::string
InG(double acceleration)
{
  std::ostringstream text;
  text << std::setprecision(3) << acceleration / units::StandardGravity << " g";
  return text.str();
}

/** The image axis (a direction-cosine column) nearest LPS +z, pointing up. */
inline Vector3
SuperiorImageAxis(const RegistrationImage * image)
{
  const auto & direction = image->GetDirection();
  Vector3      best = Vector3::UnitZ();
  double       bestCosine = 0.0;
  for (unsigned int axis = 0; axis < 3; ++axis)
  {
    const Vector3 column(direction[0][axis], direction[1][axis], direction[2][axis]);
    if (std::abs(column.z()) > std::abs(bestCosine))
    {
      bestCosine = column.z();
      best = column.normalized();
    }
  }
  return bestCosine < 0.0 ? Vector3(-best) : best;
}

/** The skull base along the patient's superior axis: the image axis nearest
 *  LPS +z unless the settings name another direction. On an oblique
 *  acquisition (scanners tilt the slices 20-30 degrees) world +z would tilt
 *  the fixed band across the brain stem. */
inline SkullBaseSettings
PatientSkullBase(SkullBaseSettings skullBase, const RegistrationImage * image)
{
  if (skullBase.superior == Vector3::UnitZ())
  {
    skullBase.superior = SuperiorImageAxis(image);
  }
  return skullBase;
}

using RegionsFilter = itk::BiomechanicalRegionsFilter<RegistrationLabelImage>;

/** The regions filter on `model` as the registration sets it up from `settings` (skull base along the patient's
 *  superior axis of `image`, the craniotomy, contact), with the craniotomy's radius `craniotomyRadius`; not updated. */
inline RegionsFilter::Pointer
BrainRegionsFilter(const itk::BiomechanicalModelObject * model, const BrainModelSettings & settings,
                   const RegistrationImage * image, double craniotomyRadius)
{
  auto regions = RegionsFilter::New();
  regions->SetModelInput(model);
  regions->SetSkullBase(PatientSkullBase(settings.skullBase, image));
  regions->SetCraniotomyCentre(settings.craniotomyCentre);
  regions->SetCraniotomyRadius(craniotomyRadius);
  if (settings.craniotomyMask.IsNotNull())
  {
    regions->SetCraniotomyMask(settings.craniotomyMask);
  }
  regions->SetContact(settings.contact);
  return regions;
}

/** The regions filter's output as the brain model's (its pipeline model, model and exposed nodes). */
inline void
TakeRegions(BrainModel & result, itk::BiomechanicalModelObject * regions)
{
  result.pipelineModel = regions;
  result.model = result.pipelineModel->GetModel();
  const auto exposed = result.model.nodeSets.find("exposed");
  result.exposedNodes = exposed != result.model.nodeSets.end() ? exposed->second : std::vector<Index>{};
}

} // namespace bmr

#endif
