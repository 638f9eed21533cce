#ifndef itkBiomechanicalUncertaintyFilter_hxx
#define itkBiomechanicalUncertaintyFilter_hxx

#include "itkBiomechanicalUncertaintyFilter.h"

#include "itkBiomechanicalImageConversion.h"
#include "itkBiomechanicalImageIO.h"

#include "bmrBSplineField.h"
#include "bmrMaterialMapping.h"

#include <algorithm>
#include <exception>
#include <memory>

namespace itk
{

namespace BiomechanicalUncertaintyDetail
{
/** A point set sharing `shared`'s points and displacements: each member's
 *  filter gets its own pipeline object, so that the members' updates, in
 *  parallel, never touch one object's pipeline state. */
template <typename TPointSet>
typename TPointSet::Pointer
ShallowCopy(const TPointSet * shared)
{
  auto copy = TPointSet::New();
  copy->SetPoints(const_cast<typename TPointSet::PointsContainer *>(shared->GetPoints()));
  copy->SetPointData(const_cast<typename TPointSet::PointDataContainer *>(shared->GetPointData()));
  return copy;
}

/** The same for a mesh: its points and cells shared (a mesh releases shared
 *  cells only as their last owner, by the original's allocation method). */
template <typename TMesh>
typename TMesh::Pointer
ShallowMeshCopy(const TMesh * shared)
{
  auto copy = TMesh::New();
  copy->SetPoints(const_cast<typename TMesh::PointsContainer *>(shared->GetPoints()));
  copy->SetCellsAllocationMethod(shared->GetCellsAllocationMethod());
  copy->SetCells(const_cast<typename TMesh::CellsContainer *>(shared->GetCells()));
  return copy;
}
} // namespace BiomechanicalUncertaintyDetail

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage,
                               TUncertaintyImage>::BiomechanicalUncertaintyFilter()
{
  this->SetPrimaryInputName("ModelInput");
  this->AddOptionalInputName("PrescribedDisplacements");
  this->AddOptionalInputName("ContactSurface");
  this->AddOptionalInputName("MaskImage");
  this->SetNumberOfRequiredOutputs(3);
  for (unsigned int output = 0; output < 3; ++output)
  {
    this->SetNthOutput(output, this->MakeOutput(output));
  }
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
DataObject::Pointer
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::MakeOutput(
  DataObjectPointerArraySizeType index)
{
  if (index == 1)
  {
    return UncertaintyPointSetType::New().GetPointer();
  }
  if (index == 2)
  {
    return UncertaintyImageType::New().GetPointer();
  }
  return DisplacementPointSetType::New().GetPointer();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
auto
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::GetOutput()
  -> DisplacementPointSetType *
{
  return itkDynamicCastInDebugMode<DisplacementPointSetType *>(this->GetPrimaryOutput());
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
auto
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage,
                               TUncertaintyImage>::GetUncertaintyOutput() -> UncertaintyPointSetType *
{
  return itkDynamicCastInDebugMode<UncertaintyPointSetType *>(this->ProcessObject::GetOutput(1));
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
auto
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::GetUncertaintyImage()
  -> UncertaintyImageType *
{
  return itkDynamicCastInDebugMode<UncertaintyImageType *>(this->ProcessObject::GetOutput(2));
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SetModel(
  const bmr::Model & model)
{
  auto object = ModelObjectType::New();
  object->SetModel(model);
  this->SetModelInput(object);
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
std::string
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::MemberInputName(
  const char * what, unsigned int member)
{
  return std::string(what) + std::to_string(member);
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SetMemberModelInput(
  unsigned int member, const ModelObjectType * model)
{
  const std::string name = MemberInputName("MemberModel", member);
  this->AddOptionalInputName(name);
  this->SetInput(name, const_cast<ModelObjectType *>(model));
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::
  SetMemberPrescribedDisplacements(unsigned int member, const DisplacementPointSetType * displacements)
{
  const std::string name = MemberInputName("MemberPrescribedDisplacements", member);
  this->AddOptionalInputName(name);
  this->SetInput(name, const_cast<DisplacementPointSetType *>(displacements));
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SetGravity(
  const VectorType & gravity)
{
  if (!m_GravityGiven || m_Gravity != gravity)
  {
    m_Gravity = gravity;
    m_GravityGiven = true;
    this->Modified();
  }
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SetEnsembleSettings(
  const bmr::EnsembleSettings & settings)
{
  m_EnsembleSettings = settings;
  this->Modified();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SetMemberDraws(
  const std::vector<bmr::EnsembleDraw> & draws)
{
  m_MemberDraws = draws;
  this->Modified();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SetSolverSettings(
  const bmr::SolverSettings & settings)
{
  m_SolverSettings = settings;
  this->Modified();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SetWarmStart(
  const bmr::WarmStart & start)
{
  m_WarmStart = start;
  this->Modified();
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
unsigned int
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage,
                               TUncertaintyImage>::GetNumberOfUsedMembers() const
{
  return static_cast<unsigned int>(std::count_if(m_Members.begin(), m_Members.end(),
                                                 [](const bmr::EnsembleMember & member) { return member.converged; }));
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage,
                               TUncertaintyImage>::GenerateOutputInformation()
{
  if (const MaskImageType * mask = this->GetMaskImage())
  {
    UncertaintyImageType * map = this->GetUncertaintyImage();
    map->CopyInformation(mask);
    map->SetLargestPossibleRegion(mask->GetLargestPossibleRegion());
  }
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage,
                               TUncertaintyImage>::EnlargeOutputRequestedRegion(DataObject * output)
{
  output->SetRequestedRegionToLargestPossibleRegion(); // the map is made whole
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
std::vector<bmr::EnsembleDraw>
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::Draws() const
{
  if (!m_MemberDraws.empty())
  {
    if (m_MemberDraws.size() < 2)
    {
      itkExceptionMacro(<< "uncertainty: " << m_MemberDraws.size()
                        << " member draws; an ensemble needs at least 2 (16 is a good start)");
    }
    return m_MemberDraws;
  }
  std::vector<bmr::EnsembleDraw> draws;
  try
  {
    bmr::EnsembleDrawer drawer(m_EnsembleSettings, this->GetModelInput()->GetModel(), m_ContactGap);
    for (int m = 0; m < m_EnsembleSettings.members; ++m)
    {
      draws.push_back(drawer.Next());
    }
  }
  catch (const bmr::Error & error)
  {
    itkExceptionMacro(<< error.what());
  }
  return draws;
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
std::vector<bmr::Vector3>
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::SolveMember(
  unsigned int member, const bmr::ContactSurface * contact, int threads)
{
  namespace detail = BiomechanicalUncertaintyDetail;
  bmr::EnsembleMember & outcome = m_Members[member];
  const auto *          memberModel =
    dynamic_cast<const ModelObjectType *>(this->ProcessObject::GetInput(MemberInputName("MemberModel", member)));
  const ModelObjectType * object = memberModel != nullptr ? memberModel : this->GetModelInput();
  const bmr::Model &      model = object->GetModel();
  const bmr::Vector3      gravity =
    m_GravityGiven ? bmr::Vector3(m_Gravity[0], m_Gravity[1], m_Gravity[2]) : model.bodyAcceleration;
  auto drawn = ModelObjectType::New();
  if (outcome.tissueFactors.empty())
  {
    drawn->SetModel(bmr::DrawnModel(model, outcome, gravity));
  }
  else
  {
    bmr::Model remixed = model;
    bmr::RemixTissueModuli(remixed, outcome.tissueFactors, threads);
    drawn->SetModel(bmr::DrawnModel(remixed, outcome, gravity));
  }
  if (bmr::KeepsMaterials(outcome))
  {
    drawn->SetPrecomputation(object->GetPrecomputation()); // the same reference configuration
  }
  auto deformation = DeformationFilterType::New();
  deformation->SetModelInput(drawn);
  const auto * memberPrescribed = dynamic_cast<const DisplacementPointSetType *>(
    this->ProcessObject::GetInput(MemberInputName("MemberPrescribedDisplacements", member)));
  const DisplacementPointSetType * prescribed =
    memberPrescribed != nullptr ? memberPrescribed : this->GetPrescribedDisplacements();
  if (prescribed != nullptr)
  {
    deformation->SetPrescribedDisplacements(detail::ShallowCopy(prescribed));
  }
  if (contact != nullptr)
  {
    // The contact surface at the drawn gap. Wider: the contact's offset, the
    // level set of the surface's distance behind it (moved along its normals,
    // a skull kept its ridges where they were and crossed itself in its
    // folds, and every such member folded a cell or started beyond it).
    // Narrower: the surface moved towards the body (the offset's level set on
    // the body's side has creases in the surface's valleys, where pressed
    // slaves did not settle: docs/solver.md, contact offset).
    if (outcome.skullOffset < 0.0)
    {
      deformation->SetContactSurface(
        MakeMeshFromContactSurface<SurfaceMeshType>(bmr::NarrowedContactSurface(*contact, -outcome.skullOffset)));
    }
    else
    {
      deformation->SetContactSurface(detail::ShallowMeshCopy(this->GetContactSurface()));
      deformation->SetContactOffset(-outcome.skullOffset);
    }
    deformation->SetContactBodySideInside(m_ContactBodySideInside);
  }
  bmr::SolverSettings solver = m_SolverSettings;
  solver.threads = threads;
  deformation->SetSolverSettings(solver);
  deformation->SetWarmStart(m_WarmStart);
  deformation->SetNumberOfWorkUnits(static_cast<ThreadIdType>(threads));
  deformation->Update();
  const bmr::SolveResult & solve = deformation->GetSolveResult();
  outcome.converged = solve.converged;
  outcome.steps = solve.steps;
  outcome.message = solve.message;
  if (solve.displacements.size() != this->GetModelInput()->GetModel().nodes.size())
  {
    outcome.converged = false;
    outcome.failed = true;
    outcome.message = "its model has " + std::to_string(solve.displacements.size()) + " nodes, the ensemble's " +
                      std::to_string(this->GetModelInput()->GetModel().nodes.size());
  }
  return solve.displacements;
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::GenerateData()
{
  DisplacementPointSetType * mean = this->GetOutput();
  UncertaintyPointSetType *  nodal = this->GetUncertaintyOutput();
  mean->Initialize();
  nodal->Initialize();
  m_Members.clear();
  if (this->GetModelInput() == nullptr || this->GetModelInput()->GetModel().nodes.empty())
  {
    itkExceptionMacro(<< "no model (or one without nodes): call SetModelInput with the model of the nominal solve.");
  }
  const std::vector<bmr::EnsembleDraw> draws = this->Draws();
  for (const bmr::EnsembleDraw & draw : draws)
  {
    bmr::EnsembleMember member;
    static_cast<bmr::EnsembleDraw &>(member) = draw;
    m_Members.push_back(member);
  }
  // The contact surface as the core's, once, for the members whose gap is narrower.
  std::unique_ptr<bmr::ContactSurface> contact;
  if (const SurfaceMeshType * surface = this->GetContactSurface())
  {
    contact = std::make_unique<bmr::ContactSurface>(MakeContactSurfaceFromMesh(surface, "contact surface"));
    contact->bodySide = m_ContactBodySideInside ? bmr::ContactSurface::Side::Inside : bmr::ContactSurface::Side::Outside;
  }

  const int                              count = static_cast<int>(m_Members.size());
  std::vector<std::vector<bmr::Vector3>> displacements(m_Members.size());
  bmr::ForEachMember(count, static_cast<int>(this->GetNumberOfWorkUnits()), [&](int m, int threads) {
    bmr::EnsembleMember & member = m_Members[static_cast<std::size_t>(m)];
    try
    {
      displacements[static_cast<std::size_t>(m)] = this->SolveMember(static_cast<unsigned int>(m), contact.get(), threads);
    }
    catch (const ExceptionObject & error)
    {
      member.failed = true;
      member.message = PlainDescription(error.GetDescription());
    }
    catch (const std::exception & error)
    {
      member.failed = true;
      member.message = error.what();
    }
  });

  std::vector<std::size_t> used;
  std::string              firstReason;
  for (std::size_t m = 0; m < m_Members.size(); ++m)
  {
    if (m_Members[m].converged)
    {
      used.push_back(m);
    }
    else if (firstReason.empty())
    {
      firstReason = "member " + std::to_string(m + 1) + (m_Members[m].failed ? " failed" : " did not converge") +
                    ": " + m_Members[m].message;
    }
  }
  if (used.size() < 2)
  {
    itkExceptionMacro(<< "uncertainty: " << used.size() << " of " << count
                      << " members converged, too few for a spread (" << firstReason
                      << "); narrow the distributions or raise max_steps");
  }
  const bmr::EnsembleSpread         spread = bmr::SpreadOfMembers(displacements, used);
  const std::vector<bmr::Vector3> & nodes = this->GetModelInput()->GetModel().nodes;
  FillDisplacementPointSet(mean, nodes, spread.mean);
  nodal->SetPoints(MakePointsContainer<typename UncertaintyPointSetType::PointsContainer>(nodes));
  auto values = UncertaintyPointSetType::PointDataContainer::New();
  values->Reserve(static_cast<typename UncertaintyPointSetType::PointDataContainer::ElementIdentifier>(nodes.size()));
  for (std::size_t n = 0; n < nodes.size(); ++n)
  {
    values->SetElement(n, spread.p95[n]);
  }
  nodal->SetPointData(values);
  MarkPointSetProduced(nodal);
  if (this->GetMaskImage() != nullptr)
  {
    this->MapUncertainty(nodes, spread.p95);
  }
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::MapUncertainty(
  const std::vector<bmr::Vector3> & nodes, const std::vector<double> & uncertainty)
{
  const MaskImageType *     maskImage = this->GetMaskImage();
  const bmr::LabelVolume    mask = MakeBiomechanicalVolume<std::uint8_t>(maskImage);
  std::vector<bmr::Vector3> values(nodes.size(), bmr::Vector3::Zero());
  for (std::size_t n = 0; n < nodes.size(); ++n)
  {
    values[n].x() = uncertainty[n];
  }
  bmr::BSplineFitSettings fit;
  fit.tolerance = m_FitTolerance;
  fit.minimumSpacing = m_MinimumControlPointSpacing;
  std::vector<double> sampled(3 * mask.geometry.VoxelCount());
  try
  {
    const bmr::BSplineFitResult field = bmr::FitMultilevelBSpline(nodes, values, mask.geometry, fit);
    bmr::SampleBSplineField(field.lattice, mask.geometry, sampled.data(), static_cast<int>(this->GetNumberOfWorkUnits()));
  }
  catch (const bmr::Error & error)
  {
    itkExceptionMacro(<< "uncertainty map: " << error.what());
  }
  UncertaintyImageType * map = this->GetUncertaintyImage();
  map->SetBufferedRegion(maskImage->GetBufferedRegion());
  map->Allocate();
  auto *            out = map->GetBufferPointer();
  const std::size_t voxels = mask.values.size();
  for (std::size_t v = 0; v < voxels; ++v)
  {
    // 0 outside the body; the spline's undershoot is no spread.
    out[v] = mask.values[v] != 0 ? static_cast<typename UncertaintyImageType::PixelType>(std::max(0.0, sampled[3 * v]))
                                 : 0;
  }
}

template <typename TDisplacementPointSet, typename TSurfaceMesh, typename TMaskImage, typename TUncertaintyImage>
void
BiomechanicalUncertaintyFilter<TDisplacementPointSet, TSurfaceMesh, TMaskImage, TUncertaintyImage>::PrintSelf(
  std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "Members: "
     << (m_MemberDraws.empty() ? m_EnsembleSettings.members : static_cast<int>(m_MemberDraws.size()))
     << (m_MemberDraws.empty() ? " drawn" : " given") << std::endl;
  os << indent << "Seed: " << m_EnsembleSettings.seed << std::endl;
  os << indent << "GravityRange: [" << m_EnsembleSettings.gravityLow << ", " << m_EnsembleSettings.gravityHigh << "]"
     << std::endl;
  os << indent << "YoungsModulusSpread: " << m_EnsembleSettings.youngsModulusSpread << std::endl;
  os << indent << "PoissonRatioRange: [" << m_EnsembleSettings.poissonLow << ", " << m_EnsembleSettings.poissonHigh
     << "]" << std::endl;
  os << indent << "GapSpread: " << m_EnsembleSettings.skullGapSpread << " mm, ContactGap: " << m_ContactGap << " mm"
     << std::endl;
  os << indent << "ContactBodySideInside: " << m_ContactBodySideInside << std::endl;
  os << indent << "Gravity: ";
  if (m_GravityGiven)
  {
    os << m_Gravity << std::endl;
  }
  else
  {
    os << "the model's" << std::endl;
  }
  os << indent << "Tolerance: " << m_SolverSettings.tolerance << " mm" << std::endl;
  os << indent << "UsedMembers: " << this->GetNumberOfUsedMembers() << " of " << m_Members.size() << std::endl;
}

} // namespace itk

#endif
