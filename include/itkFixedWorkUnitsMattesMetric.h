// Mattes mutual information whose result does not depend on the thread
// count, for the module's registration filters (atlas skull stripping,
// B-spline intensity registration) and the gravity fit.
#ifndef itkFixedWorkUnitsMattesMetric_h
#define itkFixedWorkUnitsMattesMetric_h

#include "itkMattesMutualInformationImageToImageMetricv4.h"

namespace itk
{

/** \class FixedWorkUnitsMattesMetric
 * \brief Mattes mutual information with a fixed number of work units.
 *
 * ITK's metric splits its samples into as many work units as the global
 * default thread count, and with several work units it adds the per-unit
 * joint-histogram derivatives in the order in which the units finish; a fixed
 * count of one makes the metric bitwise repeatable for any thread count (the
 * base class only lets one limit the threads, not the work units).
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TImage>
class ITK_TEMPLATE_EXPORT FixedWorkUnitsMattesMetric
  : public MattesMutualInformationImageToImageMetricv4<TImage, TImage>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(FixedWorkUnitsMattesMetric);
  using Self = FixedWorkUnitsMattesMetric;
  using Superclass = MattesMutualInformationImageToImageMetricv4<TImage, TImage>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;
  itkNewMacro(Self);
  itkTypeMacro(FixedWorkUnitsMattesMetric, MattesMutualInformationImageToImageMetricv4);

  /** Work units of the value-and-derivative computation (1: bitwise repeatable). */
  void
  SetFixedNumberOfWorkUnits(ThreadIdType workUnits)
  {
    this->m_DenseGetValueAndDerivativeThreader->SetNumberOfWorkUnits(workUnits);
    this->m_SparseGetValueAndDerivativeThreader->SetNumberOfWorkUnits(workUnits);
    this->Modified();
  }

protected:
  FixedWorkUnitsMattesMetric() = default;
  ~FixedWorkUnitsMattesMetric() override = default;
};

} // namespace itk

#endif
