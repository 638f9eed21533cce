// Building blocks shared by the module's registration filters (atlas skull
// stripping, B-spline intensity registration): ITK v4 metrics whose results
// do not depend on the thread count, and an L-BFGS-B optimizer that works
// across the levels of a registration pyramid.
#ifndef itkRegistrationComponents_h
#define itkRegistrationComponents_h

#include "itkCorrelationImageToImageMetricv4.h"
#include "itkLBFGSBOptimizerv4.h"
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

/** \class QuietLBFGSBOptimizerv4
 * \brief LBFGSBOptimizerv4 that is quiet about scales and restarts from the
 * current transform on every StartOptimization().
 *
 *  - No warning that LBFGSBOptimizerv4::SetScales prints on every run:
 *    ImageRegistrationMethodv4 always hands it unit scales, which is exactly
 *    what L-BFGS-B uses anyway.
 *  - Each StartOptimization() starts from the metric's current parameters.
 *    LBFGSBOptimizerv4 keeps its first initial position while the number of
 *    parameters does not grow, so the second level of a pyramid would
 *    restart from the first level's start, discarding its result.
 *  - An unbounded problem (no bounds set, or every bound selection
 *    UNBOUNDED) is resized to the current number of parameters, so one
 *    optimizer serves levels whose B-spline mesh is refined.
 *
 * \ingroup BiomechanicalRegistration
 */
class QuietLBFGSBOptimizerv4 : public LBFGSBOptimizerv4
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(QuietLBFGSBOptimizerv4);
  using Self = QuietLBFGSBOptimizerv4;
  using Superclass = LBFGSBOptimizerv4;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;
  itkNewMacro(Self);
  itkTypeMacro(QuietLBFGSBOptimizerv4, LBFGSBOptimizerv4);

  void
  SetScales(const ScalesType &) override
  {
    this->m_Scales.SetSize(this->m_Metric->GetNumberOfLocalParameters());
    this->m_Scales.Fill(1.0);
    this->m_ScalesAreIdentity = true;
  }

  void
  StartOptimization(bool doOnlyInitialization = false) override
  {
    if (this->m_Metric.IsNotNull())
    {
      this->SetInitialPosition(this->m_Metric->GetParameters());
      const SizeValueType numberOfParameters = this->m_Metric->GetNumberOfParameters();
      if (this->GetBoundSelection().size() != numberOfParameters && this->GetBoundSelection().is_zero())
      {
        BoundSelectionType unbounded(numberOfParameters);
        BoundValueType     bounds(numberOfParameters);
        unbounded.Fill(UNBOUNDED);
        bounds.Fill(0.0);
        this->SetBoundSelection(unbounded);
        this->SetLowerBound(bounds);
        this->SetUpperBound(bounds);
      }
    }
    Superclass::StartOptimization(doOnlyInitialization);
  }

protected:
  QuietLBFGSBOptimizerv4() = default;
  ~QuietLBFGSBOptimizerv4() override = default;
};

} // namespace itk

#endif
