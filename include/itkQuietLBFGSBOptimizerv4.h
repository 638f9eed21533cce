// An L-BFGS-B optimizer that works across the levels of a registration
// pyramid, for the atlas skull stripping and the B-spline intensity registration.
#ifndef itkQuietLBFGSBOptimizerv4_h
#define itkQuietLBFGSBOptimizerv4_h

#include "itkLBFGSBOptimizerv4.h"

namespace itk
{

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
