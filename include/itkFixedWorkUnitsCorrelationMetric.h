// Normalised correlation whose result does not depend on the thread count,
// for the B-spline intensity registration.
#ifndef itkFixedWorkUnitsCorrelationMetric_h
#define itkFixedWorkUnitsCorrelationMetric_h

#include "itkCorrelationImageToImageMetricv4.h"

namespace itk
{

/** \class FixedWorkUnitsCorrelationMetric
 * \brief Normalised correlation (CorrelationImageToImageMetricv4, value
 * -r^2) with a fixed number of work units.
 *
 * The metric sums per-unit partial sums (image means, cross products,
 * derivatives) in unit order, so a run repeats bitwise for a given number of
 * work units; but ITK sets that number from the global thread count when the
 * metric is made, which makes the result depend on the thread count. Fixing
 * it (here for the mean helpers as well) removes that dependence.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TImage>
class ITK_TEMPLATE_EXPORT FixedWorkUnitsCorrelationMetric : public CorrelationImageToImageMetricv4<TImage, TImage>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(FixedWorkUnitsCorrelationMetric);
  using Self = FixedWorkUnitsCorrelationMetric;
  using Superclass = CorrelationImageToImageMetricv4<TImage, TImage>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;
  itkNewMacro(Self);
  itkTypeMacro(FixedWorkUnitsCorrelationMetric, CorrelationImageToImageMetricv4);

  /** Work units of the value-and-derivative and of the mean computations. */
  void
  SetFixedNumberOfWorkUnits(ThreadIdType workUnits)
  {
    this->m_DenseGetValueAndDerivativeThreader->SetNumberOfWorkUnits(workUnits);
    this->m_SparseGetValueAndDerivativeThreader->SetNumberOfWorkUnits(workUnits);
    this->m_HelperDenseThreader->SetNumberOfWorkUnits(workUnits);
    this->m_HelperSparseThreader->SetNumberOfWorkUnits(workUnits);
    this->Modified();
  }

protected:
  FixedWorkUnitsCorrelationMetric() = default;
  ~FixedWorkUnitsCorrelationMetric() override = default;
};

} // namespace itk

#endif
