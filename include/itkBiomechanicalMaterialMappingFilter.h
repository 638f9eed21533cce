#ifndef itkBiomechanicalMaterialMappingFilter_h
#define itkBiomechanicalMaterialMappingFilter_h

// ITK headers first: ITK's bundled Eigen must be seen before the system Eigen of the core.
#include "itkBiomechanicalImageConversion.h"
#include "itkImage.h"
#include "itkProcessObject.h"
#include "itkVectorImage.h"

#include "itkBiomechanicalModelObject.h"

#include "bmrMaterialMapping.h"

#include <string>
#include <vector>

namespace itk
{

/** \class BiomechanicalMaterialMappingFilter
 * \brief Gives a biomechanical model's cells (or meshless integration points)
 * their materials from tissue-class memberships: the membership-weighted
 * mixture of the classes' properties (Zhang, Joldes, Wittek and Miller 2013).
 *
 * Inputs:
 *  - "ModelInput" (required): a BiomechanicalModelObject, e.g.
 *    BiomechanicalGridImageFilter::GetModelOutput();
 *  - "Memberships" (required): a VectorImage with one component per class
 *    (ascending centroid), 0 outside the brain, e.g. the output of
 *    FuzzyCMeansClassifierImageFilter;
 *  - "TumourMask" (optional): a mask on the memberships' grid (non-zero =
 *    tumour), an extra class of full membership there;
 *  - "ResectionMask" (optional): a mask on the memberships' grid (non-zero =
 *    tissue removed by the surgery), full membership in the CSF's class
 *    (CsfClass, default 0: the darkest) there, over the tumour's.
 *
 * Settings: ClassMaterials (one per class; empty, the default:
 * bmr::DefaultClassMaterials, the darkest class CSF and the others
 * parenchyma), CsfClass (the class whose fluid fills a resection: 0 on a
 * T1 image, the brightest on a T2 one; bmr::ChooseCsfClass), TumourMaterial,
 * Sampling (bmr::MaterialSampling), and
 * NumberOfWorkUnits (the sampling's threads; results do not depend on it).
 *
 * Output: the model (a BiomechanicalModelObject) with model.materials and
 * each cell's (and integration point's) material set, as
 * bmr::MapMaterialsFromMemberships does (bmrMaterialMapping.h, where the
 * sampling and the mixture rule are described). Its warnings (cells outside
 * the mask) go through itkWarningMacro and GetWarnings(); its errors (memberships
 * on another space than the model, class materials of the wrong count, ...)
 * are thrown as itk::ExceptionObject with the core's message.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TMembershipImage = VectorImage<float, 3>, typename TMaskImage = Image<unsigned char, 3>>
class ITK_TEMPLATE_EXPORT BiomechanicalMaterialMappingFilter : public ProcessObject
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BiomechanicalMaterialMappingFilter);

  using Self = BiomechanicalMaterialMappingFilter;
  using Superclass = ProcessObject;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BiomechanicalMaterialMappingFilter, ProcessObject);

  using ModelObjectType = BiomechanicalModelObject;
  using MembershipImageType = TMembershipImage;
  using MaskImageType = TMaskImage;

  static_assert(TMembershipImage::ImageDimension == 3 && TMaskImage::ImageDimension == 3, "the core is 3D");

  itkSetInputMacro(ModelInput, ModelObjectType);
  itkGetInputMacro(ModelInput, ModelObjectType);
  itkSetInputMacro(Memberships, MembershipImageType);
  itkGetInputMacro(Memberships, MembershipImageType);
  itkSetInputMacro(TumourMask, MaskImageType);
  itkGetInputMacro(TumourMask, MaskImageType);
  itkSetInputMacro(ResectionMask, MaskImageType);
  itkGetInputMacro(ResectionMask, MaskImageType);

  /** One material per class (ascending centroid); empty: bmr::DefaultClassMaterials. */
  void
  SetClassMaterials(const std::vector<bmr::Material> & materials)
  {
    m_Settings.classMaterials = materials;
    this->Modified();
  }
  const std::vector<bmr::Material> &
  GetClassMaterials() const
  {
    return m_Settings.classMaterials;
  }
  void
  SetCsfClass(int csfClass)
  {
    if (m_Settings.csfClass != csfClass)
    {
      m_Settings.csfClass = csfClass;
      this->Modified();
    }
  }
  int
  GetCsfClass() const
  {
    return m_Settings.csfClass;
  }
  void
  SetTumourMaterial(const bmr::Material & material)
  {
    m_Settings.tumour = material;
    this->Modified();
  }
  void
  SetSampling(const bmr::MaterialSampling & sampling)
  {
    m_Settings.sampling = sampling;
    this->Modified();
  }
  const bmr::MaterialMappingSettings &
  GetSettings() const
  {
    return m_Settings;
  }

  ModelObjectType *
  GetOutput()
  {
    return itkDynamicCastInDebugMode<ModelObjectType *>(this->GetPrimaryOutput());
  }

  /** Warnings of the last update (cells with no sample inside the mask). */
  const std::vector<std::string> &
  GetWarnings() const
  {
    return m_Warnings;
  }

protected:
  BiomechanicalMaterialMappingFilter()
  {
    this->SetPrimaryInputName("ModelInput");
    this->AddRequiredInputName("Memberships");
    this->AddOptionalInputName("TumourMask");
    this->AddOptionalInputName("ResectionMask");
    this->SetNumberOfRequiredOutputs(1);
    this->SetNthOutput(0, this->MakeOutput(0));
  }
  ~BiomechanicalMaterialMappingFilter() override = default;

  using Superclass::MakeOutput;
  DataObject::Pointer
  MakeOutput(DataObjectPointerArraySizeType) override
  {
    return ModelObjectType::New().GetPointer();
  }

  /** The output's information does not come from the model input's. */
  void
  GenerateOutputInformation() override
  {}

  void
  GenerateData() override
  {
    m_Warnings.clear();
    const ModelObjectType *     input = this->GetModelInput();
    const MembershipImageType * memberships = this->GetMemberships();
    if (input == nullptr || memberships == nullptr)
    {
      itkExceptionMacro(<< "give the model (SetModelInput) and the memberships (SetMemberships).");
    }
    bmr::Model                   model = input->GetModel();
    bmr::MaterialMappingSettings settings = m_Settings;
    settings.sampling.threads = static_cast<int>(this->GetNumberOfWorkUnits());
    try
    {
      const bmr::ScalarVolume volume = MakeBiomechanicalVolume<float>(memberships);
      if (settings.classMaterials.empty())
      {
        settings.classMaterials = bmr::DefaultClassMaterials(volume.components);
      }
      bmr::LabelVolume tumour, resection;
      if (const MaskImageType * mask = this->GetTumourMask())
      {
        tumour = MakeBiomechanicalVolume<std::uint8_t>(mask);
      }
      if (const MaskImageType * mask = this->GetResectionMask())
      {
        resection = MakeBiomechanicalVolume<std::uint8_t>(mask);
      }
      bmr::MapMaterialsFromMemberships(model, volume, settings, tumour.values.empty() ? nullptr : &tumour,
                                       &m_Warnings, resection.values.empty() ? nullptr : &resection);
    }
    catch (const bmr::Error & error)
    {
      itkExceptionMacro(<< error.what());
    }
    for (const std::string & warning : m_Warnings)
    {
      itkWarningMacro(<< warning);
    }
    this->GetOutput()->SetModel(std::move(model));
  }

  void
  PrintSelf(std::ostream & os, Indent indent) const override
  {
    Superclass::PrintSelf(os, indent);
    os << indent << "ClassMaterials: " << m_Settings.classMaterials.size() << ", CsfClass: " << m_Settings.csfClass
       << std::endl;
    os << indent << "Tumour: E = " << m_Settings.tumour.youngsModulus << " Pa" << std::endl;
    os << indent << "SamplesPerVoxel: " << m_Settings.sampling.samplesPerVoxel << std::endl;
  }

private:
  bmr::MaterialMappingSettings m_Settings;
  std::vector<std::string>     m_Warnings;
};

} // namespace itk

#endif
