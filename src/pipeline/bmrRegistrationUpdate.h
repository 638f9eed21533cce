// The intraoperative update's filters as the registration sets them up, for
// the update itself (bmrBrainShiftRegistration.cxx) and its gravity fit
// (bmrGravityFit.cxx). Private to the pipeline, not installed.
#ifndef bmrRegistrationUpdate_h
#define bmrRegistrationUpdate_h

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalDeformationFilter.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"

#include "bmrPipelineDetail.h"

#include <string>

namespace bmr
{

using UpdatePointSet = itk::DisplacementPointSetType<3>;
using UpdateDeformation = itk::BiomechanicalDeformationFilter<UpdatePointSet>;
using UpdateFitter = itk::DisplacementPointSetToBSplineTransformFilter<UpdatePointSet>;

/** The deformation filter of a model with the update's loads, contact,
 *  solver settings and warm start, and the transform fitted to a solve. */
class UpdateFilters
{
public:
  UpdateFilters(const BrainModel &                     model,
                const BrainShiftUpdateInputs &         inputs,
                const BrainShiftRegistrationSettings & settings);

  UpdateDeformation::Pointer MakeDeformation(const itk::BiomechanicalModelObject * model) const;
  /** Fits the transform to the deformation's solved nodes (its output). */
  UpdateFitter::Pointer FitTransform(const UpdateDeformation * deformation) const;

private:
  const BrainModel &                     m_Model;
  const BrainShiftUpdateInputs &         m_Inputs;
  const BrainShiftRegistrationSettings & m_Settings;
};

/** The gravity fit's choice: the best size's solve and its fitted transform. */
struct GravityFitChoice
{
  UpdateDeformation::Pointer deformation;
  UpdateFitter::Pointer      fitter;
};

/** Tries settings.gravityFitCandidates sizes of the model's gravity from 0 to
 *  its size, then up to three sizes towards the best, scoring each by the
 *  Mattes mutual information of the registered and the intraoperative image;
 *  fills result.gravityFit, gravityFitSolves, warnings and gravity, and sets
 *  the result's model to the one solved with the best size (docs/registration.md). */
GravityFitChoice
FitGravity(BrainShiftRegistrationResult &         result,
           const BrainShiftUpdateInputs &         inputs,
           const BrainShiftRegistrationSettings & settings,
           const UpdateFilters &                  filters);

} // namespace bmr

#endif
