#ifndef itkBiomechanicalRegionsFilter_h
#define itkBiomechanicalRegionsFilter_h

// ITK headers first: ITK's bundled Eigen must be seen before the system Eigen of the core.
#include "itkBiomechanicalImageConversion.h"
#include "itkImage.h"
#include "itkProcessObject.h"

#include "itkBiomechanicalModelObject.h"

#include "bmrBrainSurfaces.h"

#include <string>
#include <vector>

namespace itk
{

/** \class BiomechanicalRegionsFilter
 * \brief The boundary regions of a brain model's surface: the fixed skull
 * base, the exposed craniotomy and the nodes that may touch the skull.
 *
 * Inputs:
 *  - "ModelInput" (required): a BiomechanicalModelObject with a node set of
 *    its surface nodes (SurfaceNodeSet, default "surface", as the grid filter
 *    makes), e.g. BiomechanicalMaterialMappingFilter::GetOutput();
 *  - "CraniotomyMask" (optional): a mask (non-zero voxels, any grid) of the
 *    craniotomy, instead of the sphere CraniotomyCentre, CraniotomyRadius.
 *
 * Settings: SkullBase (bmr::SkullBaseSettings: the band of Height mm above
 * the lowest surface node along Superior, default 10 mm along LPS +z),
 * CraniotomyCentre (mm) and CraniotomyRadius (mm; 0, the default: no
 * sphere), Contact (default true).
 *
 * Output: the model with the node sets (bmr::SetBrainRegions)
 *  - "skull_base": fixed in all three directions (a fixed constraint);
 *  - "exposed": the craniotomy's surface nodes (bmr::ExposedSurfaceNodes),
 *    when a craniotomy is given: the nodes BiomechanicalLoadsFilter loads;
 *  - "contact", with Contact on: every other surface node, the slaves of the
 *    skull in BiomechanicalDeformationFilter. Exposed nodes are not among
 *    them even where a measurement is rejected: the craniotomy has no bone.
 * Errors (no surface node set, a craniotomy given both as a sphere and as a
 * mask, a region that selects no surface node) are thrown as
 * itk::ExceptionObject with the core's message.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TMaskImage = Image<unsigned char, 3>>
class ITK_TEMPLATE_EXPORT BiomechanicalRegionsFilter : public ProcessObject
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BiomechanicalRegionsFilter);

  using Self = BiomechanicalRegionsFilter;
  using Superclass = ProcessObject;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BiomechanicalRegionsFilter, ProcessObject);

  using ModelObjectType = BiomechanicalModelObject;
  using MaskImageType = TMaskImage;

  static_assert(TMaskImage::ImageDimension == 3, "the core is 3D");

  itkSetInputMacro(ModelInput, ModelObjectType);
  itkGetInputMacro(ModelInput, ModelObjectType);
  itkSetInputMacro(CraniotomyMask, MaskImageType);
  itkGetInputMacro(CraniotomyMask, MaskImageType);

  /** The skull base region (a mask it points to must outlive the filter's updates). */
  void
  SetSkullBase(const bmr::SkullBaseSettings & settings)
  {
    m_SkullBase = settings;
    this->Modified();
  }
  const bmr::SkullBaseSettings &
  GetSkullBase() const
  {
    return m_SkullBase;
  }
  void
  SetCraniotomyCentre(const bmr::Vector3 & centre)
  {
    if (centre != m_CraniotomyCentre)
    {
      m_CraniotomyCentre = centre;
      this->Modified();
    }
  }
  const bmr::Vector3 &
  GetCraniotomyCentre() const
  {
    return m_CraniotomyCentre;
  }
  itkSetMacro(CraniotomyRadius, double);
  itkGetConstMacro(CraniotomyRadius, double);
  itkSetMacro(Contact, bool);
  itkGetConstMacro(Contact, bool);
  itkBooleanMacro(Contact);
  itkSetStringMacro(SurfaceNodeSet);
  itkGetStringMacro(SurfaceNodeSet);
  /** After Update: the skull-base nodes that lie in the craniotomy and are
   *  exposed instead of fixed (the opening takes precedence). */
  itkGetConstMacro(FixedNodesExposed, SizeValueType);

  ModelObjectType *
  GetOutput()
  {
    return itkDynamicCastInDebugMode<ModelObjectType *>(this->GetPrimaryOutput());
  }

protected:
  BiomechanicalRegionsFilter()
  {
    this->SetPrimaryInputName("ModelInput");
    this->AddOptionalInputName("CraniotomyMask");
    this->SetNumberOfRequiredOutputs(1);
    this->SetNthOutput(0, this->MakeOutput(0));
  }
  ~BiomechanicalRegionsFilter() override = default;

  using Superclass::MakeOutput;
  DataObject::Pointer
  MakeOutput(DataObjectPointerArraySizeType) override
  {
    return ModelObjectType::New().GetPointer();
  }

  /** The output's information does not come from the inputs'. */
  void
  GenerateOutputInformation() override
  {}

  void
  GenerateData() override
  {
    const ModelObjectType * input = this->GetModelInput();
    if (input == nullptr)
    {
      itkExceptionMacro(<< "no model: call SetModelInput (e.g. with the material mapping's output).");
    }
    bmr::Model model = input->GetModel();
    if (model.nodeSets.count(m_SurfaceNodeSet) == 0)
    {
      itkExceptionMacro(<< "the model has no node set '" << m_SurfaceNodeSet
                        << "' of surface nodes; give a model from BiomechanicalGridImageFilter or SetSurfaceNodeSet.");
    }
    const std::vector<bmr::Index> surfaceNodes = model.nodeSets.at(m_SurfaceNodeSet);
    try
    {
      bmr::LabelVolume         mask;
      bmr::BrainRegionSettings settings;
      settings.skullBase = m_SkullBase;
      settings.craniotomy.centre = m_CraniotomyCentre;
      settings.craniotomy.radius = m_CraniotomyRadius;
      if (const MaskImageType * image = this->GetCraniotomyMask())
      {
        mask = MakeBiomechanicalVolume<std::uint8_t>(image);
        settings.craniotomy.mask = &mask;
      }
      settings.contact = m_Contact;
      m_FixedNodesExposed = bmr::SetBrainRegions(model, surfaceNodes, settings);
    }
    catch (const bmr::Error & error)
    {
      itkExceptionMacro(<< error.what());
    }
    this->GetOutput()->SetModel(std::move(model));
  }

  void
  PrintSelf(std::ostream & os, Indent indent) const override
  {
    Superclass::PrintSelf(os, indent);
    os << indent << "SkullBase: height " << m_SkullBase.height << " mm" << std::endl;
    os << indent << "Craniotomy: centre " << m_CraniotomyCentre.transpose() << " mm, radius " << m_CraniotomyRadius
       << " mm" << std::endl;
    os << indent << "Contact: " << m_Contact << ", SurfaceNodeSet: " << m_SurfaceNodeSet << std::endl;
  }

private:
  bmr::SkullBaseSettings m_SkullBase;
  bmr::Vector3           m_CraniotomyCentre{ bmr::Vector3::Zero() };
  double                 m_CraniotomyRadius{ 0.0 };
  bool                   m_Contact{ true };
  std::string            m_SurfaceNodeSet{ "surface" };
  SizeValueType          m_FixedNodesExposed{ 0 };
};

} // namespace itk

#endif
