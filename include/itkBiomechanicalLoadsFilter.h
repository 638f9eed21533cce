#ifndef itkBiomechanicalLoadsFilter_h
#define itkBiomechanicalLoadsFilter_h

// ITK headers first: ITK's bundled Eigen (the fitter's header) must be seen
// before the system Eigen of the core.
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkMesh.h"
#include "itkProcessObject.h"

#include "itkBiomechanicalModelObject.h"

#include "bmrSurfaceLoads.h"

#include <optional>
#include <string>
#include <vector>

namespace itk
{

/** \class BiomechanicalLoadsFilter
 * \brief Prescribed displacements of a model's exposed surface from
 * intraoperative measurements: the point set that
 * BiomechanicalDeformationFilter takes as "PrescribedDisplacements".
 *
 * Inputs:
 *  - "ModelInput" (required): a BiomechanicalModelObject whose node set
 *    ExposedNodeSet (default "exposed") holds the exposed surface nodes;
 *  - one measurement:
 *    - "SparseDisplacements": a point set of measured points (reference,
 *      i.e. preoperative, positions, mm) carrying their displacements
 *      (tracked surface points, electrodes): interpolated to the exposed
 *      nodes with a thin-plate (phi = r) spline plus an affine part
 *      (bmr::DisplacementsFromSparsePoints);
 *    - "IntraoperativeSurface": a triangle mesh of the displaced surface:
 *      each exposed node moves to its closest point on it
 *      (bmr::DisplacementsFromSurface), or, with "PreoperativeSurface" (the
 *      cortex the scan images: BrainSurfaceMeshSource of the brain mask with
 *      ComputeSkull off) also given, the surface
 *      is matched to the preoperative one as a scanner sees it and the
 *      matches are interpolated (bmr::DisplacementsBetweenSurfaces, with
 *      ScanReach and ScanSpacing).
 *  - "ModelSurface" (optional): the body's boundary surface, needed for a
 *    meshless point cloud, which has no cells to take it from (sparse
 *    points and surface-to-surface matching measure distances to it).
 *
 * Settings: MaxDistance (mm, default 10: farther measurements are rejected
 * with a warning naming them), Smoothing (mm, default 0: an interpolating
 * spline), ExposedNodeSet, ScanReach and ScanSpacing (mm, defaults 10 and 5),
 * MatchDirection (surface to surface: the direction a scanner looks along;
 * unset, the default: the preoperative surface's normals).
 *
 * Output: the loaded exposed nodes (reference positions, mm) carrying their
 * displacements (mm); GetPrescribedDisplacement() gives the same load with
 * the nodes' indices (bmr::PrescribedDisplacement). GetLoadReport() gives the points used and rejected and
 * the correspondence distances; warnings also go through itkWarningMacro.
 * Errors of the core (no exposed nodes, every measurement rejected, a NaN
 * coordinate, ...) are thrown as itk::ExceptionObject with its message.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TDisplacementPointSet = DisplacementPointSetType<3>,
          typename TSurfaceMesh = BiomechanicalSurfaceMeshType>
class ITK_TEMPLATE_EXPORT BiomechanicalLoadsFilter : public ProcessObject
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BiomechanicalLoadsFilter);

  using Self = BiomechanicalLoadsFilter;
  using Superclass = ProcessObject;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BiomechanicalLoadsFilter, ProcessObject);

  using ModelObjectType = BiomechanicalModelObject;
  using DisplacementPointSetType = TDisplacementPointSet;
  using SurfaceMeshType = TSurfaceMesh;

  itkSetInputMacro(ModelInput, ModelObjectType);
  itkGetInputMacro(ModelInput, ModelObjectType);
  itkSetInputMacro(SparseDisplacements, DisplacementPointSetType);
  itkGetInputMacro(SparseDisplacements, DisplacementPointSetType);
  itkSetInputMacro(IntraoperativeSurface, SurfaceMeshType);
  itkGetInputMacro(IntraoperativeSurface, SurfaceMeshType);
  itkSetInputMacro(PreoperativeSurface, SurfaceMeshType);
  itkGetInputMacro(PreoperativeSurface, SurfaceMeshType);
  /** The body's boundary, for a meshless point cloud (which has no cells to take it from). */
  itkSetInputMacro(ModelSurface, SurfaceMeshType);
  itkGetInputMacro(ModelSurface, SurfaceMeshType);

  itkSetStringMacro(ExposedNodeSet);
  itkGetStringMacro(ExposedNodeSet);
  itkSetMacro(MaxDistance, double);
  itkGetConstMacro(MaxDistance, double);
  itkSetMacro(Smoothing, double);
  itkGetConstMacro(Smoothing, double);
  itkSetMacro(ScanReach, double);
  itkGetConstMacro(ScanReach, double);
  itkSetMacro(ScanSpacing, double);
  itkGetConstMacro(ScanSpacing, double);
  void
  SetMatchDirection(const std::optional<bmr::Vector3> & direction)
  {
    if (direction != m_MatchDirection)
    {
      m_MatchDirection = direction;
      this->Modified();
    }
  }
  const std::optional<bmr::Vector3> &
  GetMatchDirection() const
  {
    return m_MatchDirection;
  }

  DisplacementPointSetType *
  GetOutput()
  {
    return itkDynamicCastInDebugMode<DisplacementPointSetType *>(this->GetPrimaryOutput());
  }

  const bmr::LoadReport &
  GetLoadReport() const
  {
    return m_Report;
  }
  /** The output's load with the indices of its nodes (the model's node numbering). */
  const bmr::PrescribedDisplacement &
  GetPrescribedDisplacement() const
  {
    return m_Load;
  }

protected:
  BiomechanicalLoadsFilter()
  {
    this->SetPrimaryInputName("ModelInput");
    this->AddOptionalInputName("SparseDisplacements");
    this->AddOptionalInputName("IntraoperativeSurface");
    this->AddOptionalInputName("PreoperativeSurface");
    this->AddOptionalInputName("ModelSurface");
    this->SetNumberOfRequiredOutputs(1);
    this->SetNthOutput(0, this->MakeOutput(0));
  }
  ~BiomechanicalLoadsFilter() override = default;

  using Superclass::MakeOutput;
  DataObject::Pointer
  MakeOutput(DataObjectPointerArraySizeType) override
  {
    return DisplacementPointSetType::New().GetPointer();
  }

  /** The output's information does not come from the model input's. */
  void
  GenerateOutputInformation() override
  {}

  void
  GenerateData() override
  {
    DisplacementPointSetType * output = this->GetOutput();
    output->Initialize();
    m_Report = bmr::LoadReport{};
    m_Load = bmr::PrescribedDisplacement{};
    const ModelObjectType *          input = this->GetModelInput();
    const DisplacementPointSetType * sparse = this->GetSparseDisplacements();
    const SurfaceMeshType *          surface = this->GetIntraoperativeSurface();
    if (input == nullptr)
    {
      itkExceptionMacro(<< "no model: call SetModelInput.");
    }
    if ((sparse == nullptr) == (surface == nullptr))
    {
      itkExceptionMacro(<< "give one measurement: SetSparseDisplacements or SetIntraoperativeSurface"
                        << (sparse ? ", not both." : "."));
    }
    const bmr::Model & model = input->GetModel();
    if (model.nodeSets.count(m_ExposedNodeSet) == 0)
    {
      itkExceptionMacro(<< "the model has no node set '" << m_ExposedNodeSet
                        << "' of exposed nodes; add it (e.g. the craniotomy's surface nodes) or SetExposedNodeSet.");
    }
    const std::vector<bmr::Index> & exposed = model.nodeSets.at(m_ExposedNodeSet);
    bmr::SurfaceLoadSettings        settings;
    settings.maxDistance = m_MaxDistance;
    settings.smoothing = m_Smoothing;
    settings.matchDirection = m_MatchDirection;
    bmr::PrescribedDisplacement load;
    try
    {
      bmr::ContactSurface body;
      if (const SurfaceMeshType * modelSurface = this->GetModelSurface())
      {
        body = MakeContactSurfaceFromMesh(modelSurface, "model surface");
      }
      const bmr::ContactSurface * bodySurface = body.triangles.empty() ? nullptr : &body;
      if (sparse != nullptr)
      {
        const auto * points = sparse->GetPoints();
        const auto * data = sparse->GetPointData();
        if (points == nullptr || data == nullptr || points->Size() != data->Size())
        {
          itkExceptionMacro(<< "the sparse displacements need one displacement (point data) per point.");
        }
        std::vector<bmr::Vector3> at, displacements;
        for (auto it = points->Begin(); it != points->End(); ++it)
        {
          const auto & u = data->ElementAt(it.Index());
          at.emplace_back(it.Value()[0], it.Value()[1], it.Value()[2]);
          displacements.emplace_back(u[0], u[1], u[2]);
        }
        load = bmr::DisplacementsFromSparsePoints(model, exposed, at, displacements, settings, &m_Report, bodySurface);
      }
      else if (const SurfaceMeshType * preoperative = this->GetPreoperativeSurface())
      {
        load = bmr::DisplacementsBetweenSurfaces(model, exposed, MakeContactSurfaceFromMesh(preoperative, "preoperative surface"),
                                                 MakeContactSurfaceFromMesh(surface, "intraoperative surface"), m_ScanReach,
                                                 m_ScanSpacing, settings, &m_Report, bodySurface);
      }
      else
      {
        load = bmr::DisplacementsFromSurface(model, exposed, MakeContactSurfaceFromMesh(surface, "intraoperative surface"),
                                             settings, &m_Report);
      }
    }
    catch (const bmr::Error & error)
    {
      itkExceptionMacro(<< error.what());
    }
    for (const std::string & warning : m_Report.warnings)
    {
      itkWarningMacro(<< warning);
    }
    std::vector<bmr::Vector3> positions;
    for (const bmr::Index node : load.nodes)
    {
      positions.push_back(model.nodes[node]);
    }
    FillDisplacementPointSet(output, positions, load.displacements);
    m_Load = std::move(load);
  }

  void
  PrintSelf(std::ostream & os, Indent indent) const override
  {
    Superclass::PrintSelf(os, indent);
    os << indent << "ExposedNodeSet: " << m_ExposedNodeSet << std::endl;
    os << indent << "MaxDistance: " << m_MaxDistance << " mm, Smoothing: " << m_Smoothing << " mm" << std::endl;
    os << indent << "ScanReach: " << m_ScanReach << " mm, ScanSpacing: " << m_ScanSpacing << " mm" << std::endl;
    os << indent << "MatchDirection: " << (m_MatchDirection ? "given" : "surface normals") << std::endl;
  }

private:
  std::string     m_ExposedNodeSet{ "exposed" };
  double          m_MaxDistance{ bmr::SurfaceLoadSettings{}.maxDistance };
  double          m_Smoothing{ 0.0 };
  double          m_ScanReach{ 10.0 };
  double          m_ScanSpacing{ bmr::kDefaultScanSpacing };
  std::optional<bmr::Vector3>  m_MatchDirection;
  bmr::LoadReport             m_Report;
  bmr::PrescribedDisplacement m_Load;
};

} // namespace itk

#endif
