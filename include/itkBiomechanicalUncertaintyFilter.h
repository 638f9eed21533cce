#ifndef itkBiomechanicalUncertaintyFilter_h
#define itkBiomechanicalUncertaintyFilter_h

// ITK headers first: ITK's bundled Eigen (the deformation filter's) must be
// seen before the system Eigen of the core.
#include "itkBiomechanicalDeformationFilter.h"
#include "itkImage.h"

#include "bmrEnsemble.h"

#include <string>
#include <vector>

namespace itk
{

/** \class BiomechanicalUncertaintyFilter
 * \brief Where to trust a biomechanical solve: an ensemble of solves of one
 * model with its uncertain mechanical inputs drawn, the mean displacements
 * and, per node and per voxel, the 95th percentile of the members' distance
 * from the mean.
 *
 * Inputs, as BiomechanicalDeformationFilter takes them (the nominal solve):
 *  - "Model" (SetModelInput, required), "PrescribedDisplacements" and
 *    "ContactSurface" (optional), ContactBodySideInside, Gravity (mm/s^2): the
 *    nominal gravity the members' factors scale, replacing the model's body
 *    acceleration even when zero (a registration's fitted gravity may be
 *    none); not set: the model's own.
 *  - Per member, optionally: SetMemberModelInput(m, model) and
 *    SetMemberPrescribedDisplacements(m, points) replace the shared ones for
 *    member m (0-based): e.g. the loads filter run on the member's noisy
 *    measurements, or the regions made again for another exposed radius.
 *  - "MaskImage" (optional): the map's grid and the body's voxels (non-zero);
 *    without it the image output stays empty.
 *
 * Settings: SetEnsembleSettings (bmr::EnsembleSettings: members, seed, and
 * the distributions of gravity's size, Young's moduli (all together, and per
 * tissue class of a model whose materials were mapped from memberships),
 * Poisson's ratio and the gap to the contact surface; ContactGap is the nominal gap a narrower
 * draw keeps a tenth of), or the draws themselves (SetMemberDraws, one per
 * member, instead of drawing them); SetSolverSettings (the members' solves:
 * tolerance, steps) and SetWarmStart (each member starts from it, e.g. the
 * nominal solve's steady state: members then take fewer steps); FitTolerance
 * and MinimumControlPointSpacing of the map's multilevel B-spline fit (as
 * DisplacementPointSetToBSplineTransformFilter's). NumberOfWorkUnits threads
 * run the members, one each when there are at least as many members as
 * threads; the results do not depend on it.
 *
 * Outputs:
 *  0. the mean of the converged members' displacements, a point set of the
 *     nodes as BiomechanicalDeformationFilter's output (the input
 *     DisplacementPointSetToBSplineTransformFilter expects);
 *  1. GetUncertaintyOutput(): the nodes carrying the 95th percentile over the
 *     converged members of |u_i - u_mean| (mm);
 *  2. GetUncertaintyImage(): the same on the mask's grid between the nodes by
 *     the B-spline fit, 0 outside the body (empty without a mask).
 *
 * GetMembers() tells what each member drew and how its solve ended: one that
 * fails (it throws) or does not converge is left out of the statistics, and
 * fewer than two converged members throw ExceptionObject naming the first
 * one's reason. Bad settings throw ExceptionObject naming the setting.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TDisplacementPointSet = DisplacementPointSetType<3>,
          typename TSurfaceMesh = BiomechanicalSurfaceMeshType,
          typename TMaskImage = Image<unsigned char, 3>,
          typename TUncertaintyImage = Image<float, 3>>
class ITK_TEMPLATE_EXPORT BiomechanicalUncertaintyFilter : public ProcessObject
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BiomechanicalUncertaintyFilter);

  using Self = BiomechanicalUncertaintyFilter;
  using Superclass = ProcessObject;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BiomechanicalUncertaintyFilter, ProcessObject);

  using DeformationFilterType = BiomechanicalDeformationFilter<TDisplacementPointSet, TSurfaceMesh>;
  using ModelObjectType = BiomechanicalModelObject;
  using DisplacementPointSetType = TDisplacementPointSet;
  using SurfaceMeshType = TSurfaceMesh;
  using VectorType = typename DeformationFilterType::VectorType;
  using MaskImageType = TMaskImage;
  using UncertaintyImageType = TUncertaintyImage;
  /** The nodes carrying a scalar: the nodal uncertainty (mm). */
  using UncertaintyPointSetType =
    PointSet<double, 3, DefaultStaticMeshTraits<double, 3, 3, double, double>>;

  itkSetInputMacro(ModelInput, ModelObjectType);
  itkGetInputMacro(ModelInput, ModelObjectType);
  /** The model as a new model object. */
  void
  SetModel(const bmr::Model & model);
  itkSetInputMacro(PrescribedDisplacements, DisplacementPointSetType);
  itkGetInputMacro(PrescribedDisplacements, DisplacementPointSetType);
  itkSetInputMacro(ContactSurface, SurfaceMeshType);
  itkGetInputMacro(ContactSurface, SurfaceMeshType);
  itkSetInputMacro(MaskImage, MaskImageType);
  itkGetInputMacro(MaskImage, MaskImageType);

  /** Member m's model instead of the shared one. */
  void
  SetMemberModelInput(unsigned int member, const ModelObjectType * model);
  /** Member m's prescribed displacements instead of the shared ones. */
  void
  SetMemberPrescribedDisplacements(unsigned int member, const DisplacementPointSetType * displacements);

  itkSetMacro(ContactBodySideInside, bool);
  itkGetConstMacro(ContactBodySideInside, bool);
  /** The nominal gap (mm) between the body and the contact surface. */
  itkSetMacro(ContactGap, double);
  itkGetConstMacro(ContactGap, double);
  void
  SetGravity(const VectorType & gravity);
  itkGetConstMacro(Gravity, VectorType);
  itkSetMacro(FitTolerance, double);
  itkGetConstMacro(FitTolerance, double);
  itkSetMacro(MinimumControlPointSpacing, double);
  itkGetConstMacro(MinimumControlPointSpacing, double);

  void
  SetEnsembleSettings(const bmr::EnsembleSettings & settings);
  const bmr::EnsembleSettings &
  GetEnsembleSettings() const
  {
    return m_EnsembleSettings;
  }
  /** The members' draws instead of drawing them (one per member); empty: draw. */
  void
  SetMemberDraws(const std::vector<bmr::EnsembleDraw> & draws);
  void
  SetSolverSettings(const bmr::SolverSettings & settings);
  const bmr::SolverSettings &
  GetSolverSettings() const
  {
    return m_SolverSettings;
  }
  void
  SetWarmStart(const bmr::WarmStart & start);

  DisplacementPointSetType *
  GetOutput();
  UncertaintyPointSetType *
  GetUncertaintyOutput();
  UncertaintyImageType *
  GetUncertaintyImage();

  /** Per member: its draws and how its solve ended (after an update). */
  const std::vector<bmr::EnsembleMember> &
  GetMembers() const
  {
    return m_Members;
  }
  /** The converged members, those in the statistics. */
  unsigned int
  GetNumberOfUsedMembers() const;

protected:
  BiomechanicalUncertaintyFilter();
  ~BiomechanicalUncertaintyFilter() override = default;

  using DataObjectPointerArraySizeType = ProcessObject::DataObjectPointerArraySizeType;
  using Superclass::MakeOutput;
  DataObject::Pointer
  MakeOutput(DataObjectPointerArraySizeType index) override;

  /** The map's information is the mask's; the point sets have none to pass on. */
  void
  GenerateOutputInformation() override;
  void
  EnlargeOutputRequestedRegion(DataObject * output) override;
  void
  GenerateData() override;
  void
  PrintSelf(std::ostream & os, Indent indent) const override;

private:
  static std::string
  MemberInputName(const char * what, unsigned int member);
  /** The draws of every member: the given ones or drawn from the settings. */
  std::vector<bmr::EnsembleDraw>
  Draws() const;
  /** Member m's solve (its displacements at the nodes), its outcome into m_Members[m]. */
  std::vector<bmr::Vector3>
  SolveMember(unsigned int member, const bmr::ContactSurface * contact, int threads);
  void
  MapUncertainty(const std::vector<bmr::Vector3> & nodes, const std::vector<double> & uncertainty);

  bool                             m_ContactBodySideInside{ true };
  double                           m_ContactGap{ 0.0 };
  VectorType                       m_Gravity{ 0.0 };
  bool                             m_GravityGiven{ false };
  double                           m_FitTolerance{ 0.1 };
  double                           m_MinimumControlPointSpacing{ 1.0 };
  bmr::EnsembleSettings            m_EnsembleSettings;
  std::vector<bmr::EnsembleDraw>   m_MemberDraws;
  bmr::SolverSettings              m_SolverSettings;
  bmr::WarmStart                   m_WarmStart;
  std::vector<bmr::EnsembleMember> m_Members;
};

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkBiomechanicalUncertaintyFilter.hxx"
#endif

#endif
