#ifndef itkBiomechanicalDeformationFilter_hxx
#define itkBiomechanicalDeformationFilter_hxx

#include "itkBiomechanicalDeformationFilter.h"

#include "bmrMeshless.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>

namespace itk
{

template <typename TDisplacementPointSet, typename TSurfaceMesh>
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::BiomechanicalDeformationFilter()
{
  // Named inputs; the model is the primary one.
  this->SetPrimaryInputName("ModelInput");
  this->AddOptionalInputName("PrescribedDisplacements");
  this->AddOptionalInputName("ContactSurface");
  this->SetNumberOfRequiredOutputs(1);
  this->SetNthOutput(0, this->MakeOutput(0));
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
DataObject::Pointer
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::MakeOutput(DataObjectPointerArraySizeType)
{
  return DisplacementPointSetType::New().GetPointer();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
auto
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::GetOutput() -> DisplacementPointSetType *
{
  return itkDynamicCastInDebugMode<DisplacementPointSetType *>(this->GetPrimaryOutput());
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
auto
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::GetOutput() const
  -> const DisplacementPointSetType *
{
  return itkDynamicCastInDebugMode<const DisplacementPointSetType *>(this->GetPrimaryOutput());
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
void
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::SetModel(const bmr::Model & model)
{
  auto object = ModelObjectType::New();
  object->SetModel(model);
  this->SetModelInput(object);
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
void
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::SetSolverSettings(
  const bmr::SolverSettings & settings)
{
  m_SolverSettings = settings;
  this->Modified();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
void
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::SetWarmStart(const bmr::WarmStart & start)
{
  m_WarmStart = start;
  this->Modified();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
void
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::SetTolerance(double tolerance)
{
  if (m_SolverSettings.tolerance != tolerance)
  {
    m_SolverSettings.tolerance = tolerance;
    this->Modified();
  }
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
void
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::SetMaximumNumberOfSteps(int steps)
{
  if (m_SolverSettings.maxSteps != steps)
  {
    m_SolverSettings.maxSteps = steps;
    this->Modified();
  }
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
bmr::Model
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::AssembleModel() const
{
  const ModelObjectType * input = this->GetModelInput();
  if (input == nullptr)
  {
    itkExceptionMacro(<< "no model: call SetModelInput (e.g. with BiomechanicalGridImageFilter::GetModelOutput()) "
                         "or SetModel.");
  }
  bmr::Model model = input->GetModel();
  if (model.nodes.empty())
  {
    itkExceptionMacro(<< "the model has no nodes; update the filter that makes it first.");
  }

  if (const DisplacementPointSetType * prescribed = this->GetPrescribedDisplacements())
  {
    // Each point must be a node: the nearest node within 1e-6 of the model's
    // size, searched among the nodes sorted by x (ITK's PointsLocator would
    // bring ITK's bundled Eigen into every includer, before the core's).
    bmr::Vector3 lowest = model.nodes.front(), highest = model.nodes.front();
    for (const bmr::Vector3 & node : model.nodes)
    {
      lowest = lowest.cwiseMin(node);
      highest = highest.cwiseMax(node);
    }
    const double             matchDistance = 1e-6 * std::max((highest - lowest).norm(), 1.0);
    std::vector<bmr::Index> byX(model.nodes.size());
    for (std::size_t n = 0; n < byX.size(); ++n)
    {
      byX[n] = static_cast<bmr::Index>(n);
    }
    std::sort(byX.begin(), byX.end(), [&](bmr::Index a, bmr::Index b) { return model.nodes[a].x() < model.nodes[b].x(); });
    const auto nearestNode = [&](const bmr::Vector3 & x) {
      double distance = std::numeric_limits<double>::infinity();
      auto first = std::lower_bound(byX.begin(), byX.end(), x.x() - matchDistance,
                                    [&](bmr::Index n, double value) { return model.nodes[n].x() < value; });
      bmr::Index nearest = -1;
      for (auto it = first; it != byX.end() && model.nodes[*it].x() <= x.x() + matchDistance; ++it)
      {
        const double d = (model.nodes[*it] - x).norm();
        if (d <= matchDistance && d < distance)
        {
          distance = d;
          nearest = *it;
        }
      }
      return nearest;
    };

    const auto * points = prescribed->GetPoints();
    const auto * data = prescribed->GetPointData();
    if (points == nullptr || data == nullptr || data->Size() != points->Size())
    {
      itkExceptionMacro(<< "the prescribed displacements need one displacement (point data) per point; they have "
                        << (points ? points->Size() : 0) << " points and " << (data ? data->Size() : 0)
                        << " displacements.");
    }
    bmr::PrescribedDisplacement load;
    for (auto it = points->Begin(); it != points->End(); ++it)
    {
      const bmr::Vector3 x(it.Value()[0], it.Value()[1], it.Value()[2]);
      const bmr::Index   node = nearestNode(x);
      if (node < 0)
      {
        double closest = std::numeric_limits<double>::infinity();
        for (const bmr::Vector3 & other : model.nodes)
        {
          closest = std::min(closest, (other - x).norm());
        }
        itkExceptionMacro(<< "prescribed displacement point " << it.Index() << " at " << it.Value()
                          << " is not a model node (the nearest node is " << closest
                          << " mm away); prescribe displacements at the model's nodes, e.g. from the loads of its "
                             "exposed surface.");
      }
      const auto &  displacement = data->ElementAt(it.Index());
      bmr::Vector3 u;
      for (unsigned int d = 0; d < 3; ++d)
      {
        u[d] = displacement[d];
      }
      load.nodes.push_back(node);
      load.displacements.push_back(u);
    }
    if (!load.nodes.empty())
    {
      model.prescribedDisplacements.push_back(std::move(load));
    }
  }

  if (const SurfaceMeshType * surface = this->GetContactSurface())
  {
    bmr::ContactSurface contact = MakeContactSurfaceFromMesh(surface, "contact surface");
    contact.name = "contact-surface-input";
    contact.bodySide = m_ContactBodySideInside ? bmr::ContactSurface::Side::Inside : bmr::ContactSurface::Side::Outside;
    contact.slaveNodeSet = model.nodeSets.count("contact") > 0 ? "contact" : "";
    contact.offset = m_ContactOffset;
    model.contactSurfaces.push_back(std::move(contact));
  }

  if (m_Gravity.GetNorm() > 0.0)
  {
    model.bodyAcceleration = bmr::Vector3(m_Gravity[0], m_Gravity[1], m_Gravity[2]);
  }
  return model;
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
void
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::GenerateData()
{
  DisplacementPointSetType * output = this->GetOutput();
  output->Initialize();
  m_Result = bmr::SolveResult{};
  m_SolvedModel = bmr::Model{};

  const bmr::Model    model = this->AssembleModel();
  bmr::SolverSettings settings = m_SolverSettings;
  settings.threads = static_cast<int>(this->GetNumberOfWorkUnits());

  // Dynamic relaxation reports no fraction: progress is how far the estimated
  // error has fallen, on a log scale, from the first report to the tolerance.
  double firstError = std::numeric_limits<double>::quiet_NaN();
  float  progress = 0.0f;
  const auto report = [&](int step, double fraction, double estimatedError) {
    m_CurrentStep = step;
    m_CurrentEstimatedError = estimatedError;
    double done = fraction;
    if (fraction < 0.0 && std::isfinite(estimatedError) && estimatedError > 0.0)
    {
      if (!std::isfinite(firstError))
      {
        firstError = estimatedError;
      }
      done = firstError > settings.tolerance
               ? std::log(firstError / estimatedError) / std::log(firstError / settings.tolerance)
               : 1.0;
    }
    progress = std::max(progress, static_cast<float>(std::clamp(done, 0.0, 0.99)));
    this->UpdateProgress(progress);
    if (this->GetAbortGenerateData())
    {
      ProcessAborted aborted(__FILE__, __LINE__);
      aborted.SetDescription("BiomechanicalDeformationFilter: the solve was aborted (AbortGenerateData).");
      throw aborted;
    }
  };
  try
  {
    // The model object's precomputation, made before surgery, when it has one.
    bmr::Solver solver(model, settings, this->GetModelInput()->GetPrecomputation().get());
    solver.SetWarmStart(m_WarmStart);
    m_Result = solver.Solve(report);
  }
  catch (const bmr::Error & error)
  {
    // The solver's message as it is (it names the cell, step and cause):
    // callers pass it on to their users.
    throw ExceptionObject(__FILE__, __LINE__, error.what(), ITK_LOCATION);
  }
  if (!m_Result.converged)
  {
    itkWarningMacro(<< "the solve did not converge: " << m_Result.message);
  }

  FillDisplacementPointSet(output, model.nodes, m_Result.displacements);
  if (model.discretization == bmr::Discretization::Meshless)
  {
    m_SolvedModel = model;
  }
  this->UpdateProgress(1.0f);
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
auto
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::EvaluateDisplacements(
  const std::vector<PointType> & points) const -> std::vector<VectorType>
{
  if (m_SolvedModel.discretization != bmr::Discretization::Meshless || m_Result.nodalParameters.empty())
  {
    itkExceptionMacro(<< "EvaluateDisplacements needs a solved meshless model; update the filter with one first "
                         "(a finite-element solution is given at its nodes: fit a transform to them for other points).");
  }
  std::vector<bmr::Vector3> at(points.size());
  for (std::size_t p = 0; p < points.size(); ++p)
  {
    at[p] = bmr::Vector3(points[p][0], points[p][1], points[p][2]);
  }
  std::vector<bmr::Vector3> values;
  try
  {
    const auto shapeFunctions = bmr::MovingLeastSquares::ForModel(m_SolvedModel);
    values = bmr::InterpolateDisplacements(*shapeFunctions, m_Result.nodalParameters, at,
                                           static_cast<int>(this->GetNumberOfWorkUnits()));
  }
  catch (const bmr::Error & error)
  {
    itkExceptionMacro(<< error.what());
  }
  std::vector<VectorType> displacements(values.size());
  for (std::size_t p = 0; p < values.size(); ++p)
  {
    for (unsigned int d = 0; d < 3; ++d)
    {
      displacements[p][d] = values[p][d];
    }
  }
  return displacements;
}

template <typename TDisplacementPointSet, typename TSurfaceMesh>
void
BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>::PrintSelf(std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "ContactBodySideInside: " << m_ContactBodySideInside << std::endl;
  os << indent << "ContactOffset: " << m_ContactOffset << std::endl;
  os << indent << "Gravity: " << m_Gravity << std::endl;
  os << indent << "Tolerance: " << m_SolverSettings.tolerance << " mm" << std::endl;
  os << indent << "MaximumNumberOfSteps: " << m_SolverSettings.maxSteps << std::endl;
  os << indent << "WarmStart: " << (m_WarmStart.Empty() ? "none" : std::to_string(m_WarmStart.state.size()) + " nodes")
     << std::endl;
  os << indent << "Converged: " << m_Result.converged << ", steps: " << m_Result.steps << std::endl;
}

} // namespace itk

#endif
