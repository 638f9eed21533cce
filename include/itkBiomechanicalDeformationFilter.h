#ifndef itkBiomechanicalDeformationFilter_h
#define itkBiomechanicalDeformationFilter_h

// ITK headers first: ITK's bundled Eigen (the fitter's header) must be seen
// before the system Eigen of the core.
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkMesh.h"
#include "itkProcessObject.h"

#include "itkBiomechanicalModelObject.h"

#include "bmrSolver.h"

#include <string>
#include <vector>

namespace itk
{

/** \class BiomechanicalDeformationFilter
 * \brief Solves a biomechanical model (TLED / MTLED: hexahedra, ANP or linear
 * tetrahedra, mixed, meshless) and outputs the nodal displacements.
 *
 * Inputs:
 *  - "Model" (SetModelInput, required): a BiomechanicalModelObject, e.g.
 *    BiomechanicalGridImageFilter::GetModelOutput() after material mapping,
 *    or SetModel() with a bmr::Model. Its fixed and prescribed displacements,
 *    contact surfaces and gravity are used as they are, and its
 *    precomputation (BiomechanicalModelObject::SetPrecomputation, e.g. from a
 *    model bundle) instead of computing the shape functions again.
 *  - "PrescribedDisplacements" (optional): a point set whose points are
 *    model nodes (the nearest node, within 1e-6 of the model's size) and
 *    whose point data are their displacements (mm), e.g. from a loads filter.
 *    They are added to the model's prescribed displacements (all three
 *    components). A point that is not a node is an error naming it.
 *  - "ContactSurface" (optional): a closed triangle mesh (mm) that the body
 *    stays inside (SetContactBodySideInside(false): outside), e.g.
 *    BrainSurfaceMeshSource::GetSkullOutput(). Its slave nodes are the
 *    model's node set "contact" if it has one, otherwise every boundary node.
 *
 * Settings: the solver's (SetSolverSettings: integrator, tolerance, steps,
 * time step, ...; Tolerance and MaximumNumberOfSteps also one by one),
 * Gravity (mm/s^2; when not zero it replaces the model's body acceleration)
 * and NumberOfWorkUnits (the solver's threads; results do not depend on it).
 *
 * Output: a point set of the nodes' reference positions (mm) carrying their
 * displacements (mm): for a meshless model the interpolated, physical ones.
 * It is the input DisplacementPointSetToBSplineTransformFilter expects.
 * EvaluateDisplacements() gives a meshless solution at any points of the
 * body (e.g. the voxels a fitter needs).
 *
 * The solve's report: GetSolveResult() (steps, estimated error, restarts,
 * contact, active components, reactions), GetConverged() and
 * GetStopConditionDescription(). A solve that stops without converging is
 * not an exception: it is reported there and with itkWarningMacro. A solve
 * that fails (an inverted element, which it names; an unstable solution; a
 * model that does not validate) throws itk::ExceptionObject whose
 * description is the solver's message, and leaves the output empty.
 *
 * Progress: ProgressEvent every 200 steps (dynamic relaxation: how far the
 * estimated error has fallen towards the tolerance, on a log scale; explicit
 * dynamics: the fraction of the end time); GetCurrentStep() and
 * GetCurrentEstimatedError() give the solver's state in an observer. AbortGenerateData stops the solve
 * at the next report with itk::ProcessAborted. A second Update() without a
 * change of an input or a setting does not solve again.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TDisplacementPointSet = DisplacementPointSetType<3>,
          typename TSurfaceMesh = BiomechanicalSurfaceMeshType>
class ITK_TEMPLATE_EXPORT BiomechanicalDeformationFilter : public ProcessObject
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BiomechanicalDeformationFilter);

  using Self = BiomechanicalDeformationFilter;
  using Superclass = ProcessObject;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BiomechanicalDeformationFilter, ProcessObject);

  using ModelObjectType = BiomechanicalModelObject;
  using DisplacementPointSetType = TDisplacementPointSet;
  using SurfaceMeshType = TSurfaceMesh;
  using PointType = typename DisplacementPointSetType::PointType;
  using VectorType = Vector<double, 3>;

  static_assert(TDisplacementPointSet::PointDimension == 3 && TSurfaceMesh::PointDimension == 3,
                "the mechanics core is 3D");

  itkSetInputMacro(ModelInput, ModelObjectType);
  itkGetInputMacro(ModelInput, ModelObjectType);
  /** Wraps `model` in a BiomechanicalModelObject and makes it the model input. */
  void
  SetModel(const bmr::Model & model);

  itkSetInputMacro(PrescribedDisplacements, DisplacementPointSetType);
  itkGetInputMacro(PrescribedDisplacements, DisplacementPointSetType);

  itkSetInputMacro(ContactSurface, SurfaceMeshType);
  itkGetInputMacro(ContactSurface, SurfaceMeshType);
  /** The body stays inside the contact surface (default) or outside it. */
  itkSetMacro(ContactBodySideInside, bool);
  itkGetConstMacro(ContactBodySideInside, bool);
  itkBooleanMacro(ContactBodySideInside);

  /** Contact offset (mm, bmr::ContactSurface::offset): the body keeps this far
   *  from the contact surface; negative, it may pass it by that much (a skull
   *  at another gap without remaking it). 0 by default. */
  itkSetMacro(ContactOffset, double);
  itkGetConstMacro(ContactOffset, double);

  /** Body acceleration (mm/s^2), e.g. (0, 0, -9810); zero (default): the model's own. */
  itkSetMacro(Gravity, VectorType);
  itkGetConstMacro(Gravity, VectorType);

  /** Dynamic relaxation from an earlier solve's steady state (bmr::WarmStart,
   *  e.g. the previous intraoperative update's); empty (default): from rest. */
  void
  SetWarmStart(const bmr::WarmStart & start);
  const bmr::WarmStart &
  GetWarmStart() const
  {
    return m_WarmStart;
  }

  /** All solver settings at once (bmrSolver.h); `threads` is taken from NumberOfWorkUnits. */
  void
  SetSolverSettings(const bmr::SolverSettings & settings);
  const bmr::SolverSettings &
  GetSolverSettings() const
  {
    return m_SolverSettings;
  }
  /** Dynamic relaxation stops at this estimated distance to the solution (mm). */
  void
  SetTolerance(double tolerance);
  double
  GetTolerance() const
  {
    return m_SolverSettings.tolerance;
  }
  void
  SetMaximumNumberOfSteps(int steps);
  int
  GetMaximumNumberOfSteps() const
  {
    return m_SolverSettings.maxSteps;
  }

  /** The output: nodes carrying their displacements. */
  DisplacementPointSetType *
  GetOutput();
  const DisplacementPointSetType *
  GetOutput() const;

  /** During a ProgressEvent: the solver's step and its estimated error (mm, dynamic relaxation). */
  itkGetConstMacro(CurrentStep, int);
  itkGetConstMacro(CurrentEstimatedError, double);

  /** The last solve's report. */
  const bmr::SolveResult &
  GetSolveResult() const
  {
    return m_Result;
  }
  bool
  GetConverged() const
  {
    return m_Result.converged;
  }
  const std::string &
  GetStopConditionDescription() const
  {
    return m_Result.message;
  }

  /** Displacements (mm) of the last meshless solve at `points` (mm, inside the
   *  body). Throws ExceptionObject for a finite-element model (its nodal
   *  output is exact at the nodes; fit a transform for other points) or
   *  before an update. */
  std::vector<VectorType>
  EvaluateDisplacements(const std::vector<PointType> & points) const;

protected:
  BiomechanicalDeformationFilter();
  ~BiomechanicalDeformationFilter() override = default;

  using DataObjectPointerArraySizeType = ProcessObject::DataObjectPointerArraySizeType;
  using Superclass::MakeOutput;
  DataObject::Pointer
  MakeOutput(DataObjectPointerArraySizeType index) override;

  /** The output's information does not come from the model input (another data type). */
  void
  GenerateOutputInformation() override
  {}
  void
  GenerateData() override;
  void
  PrintSelf(std::ostream & os, Indent indent) const override;

private:
  /** The input model with the prescribed displacements, contact surface and gravity of the other inputs. */
  bmr::Model
  AssembleModel() const;

  bool                m_ContactBodySideInside{ true };
  double              m_ContactOffset{ 0.0 };
  int                 m_CurrentStep{ 0 };
  double              m_CurrentEstimatedError{ 0.0 };
  VectorType          m_Gravity{ 0.0 };
  bmr::SolverSettings m_SolverSettings;
  bmr::WarmStart      m_WarmStart;
  bmr::SolveResult    m_Result;
  bmr::Model          m_SolvedModel; // meshless: for EvaluateDisplacements
};

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkBiomechanicalDeformationFilter.hxx"
#endif

#endif
