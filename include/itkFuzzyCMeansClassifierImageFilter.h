#ifndef itkFuzzyCMeansClassifierImageFilter_h
#define itkFuzzyCMeansClassifierImageFilter_h

// ITK headers first: ITK's bundled Eigen must be seen before the system
// Eigen that the core headers include.
#include "itkImage.h"
#include "itkImageToImageFilter.h"
#include "itkVectorImage.h"

#include "bmrFuzzyCMeans.h"
#include "bmrMaterialMapping.h"
#include "itkBiomechanicalImageConversion.h"

#include <map>
#include <string>
#include <vector>

namespace itk
{

/** \class FuzzyCMeansClassifierImageFilter
 * \brief Fuzzy c-means tissue classification of an MRI, inside an optional mask.
 *
 * Fits NumberOfClasses intensity centroids with fuzzy c-means (fuzziness m,
 * deterministic initialisation from intensity quantiles, classes ordered by
 * ascending centroid) to the voxels where the mask is non-zero (every voxel
 * without a mask), as in Zhang, Joldes, Wittek and Miller, IJNMBE 2013.
 *
 * Outputs, on the input's grid (size, spacing, origin, direction):
 *  - output 0: a VectorImage<float, 3> with the membership of each class per
 *    voxel (component k = class k, ascending centroid; all 0 outside the mask);
 *  - GetLabelOutput(): an Image<unsigned char, 3> with the class of largest
 *    membership, 1..NumberOfClasses, 0 outside the mask;
 *  - GetCentroids(), GetNumberOfIterations(), GetConverged() after Update().
 *
 * For a T1 image with 3 classes, class 1 is CSF, 2 grey and 3 white matter.
 * Defaults: 2 classes, fuzziness 2, tolerance 1e-5 (largest centroid change
 * relative to the intensity range), 300 iterations. Not converging is a
 * warning, not an error. Bad input (mask on another grid, all-background
 * mask, NaN inside the mask, more classes than distinct intensities,
 * NumberOfClasses < 2, Fuzziness <= 1) throws an itk::ExceptionObject whose
 * message says what is wrong and what to do. The computation is multithreaded
 * (OpenMP; the result does not depend on the thread count) and reports progress.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TInputImage, typename TMaskImage = Image<unsigned char, TInputImage::ImageDimension>>
class FuzzyCMeansClassifierImageFilter
  : public ImageToImageFilter<TInputImage, VectorImage<float, TInputImage::ImageDimension>>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(FuzzyCMeansClassifierImageFilter);

  static constexpr unsigned int ImageDimension = TInputImage::ImageDimension;
  static_assert(ImageDimension == 3, "FuzzyCMeansClassifierImageFilter works on 3D images");

  using InputImageType = TInputImage;
  using MaskImageType = TMaskImage;
  using OutputImageType = VectorImage<float, ImageDimension>;
  using LabelImageType = Image<unsigned char, ImageDimension>;

  using Self = FuzzyCMeansClassifierImageFilter;
  using Superclass = ImageToImageFilter<InputImageType, OutputImageType>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;
  using DataObjectPointerArraySizeType = typename Superclass::DataObjectPointerArraySizeType;

  itkNewMacro(Self);
  itkTypeMacro(FuzzyCMeansClassifierImageFilter, ImageToImageFilter);

  /** Optional brain mask on the input's grid: non-zero voxels are classified. */
  itkSetInputMacro(MaskImage, MaskImageType);
  itkGetInputMacro(MaskImage, MaskImageType);

  /** Number of classes K (>= 2, <= 255); default 2. */
  itkSetMacro(NumberOfClasses, unsigned int);
  itkGetConstMacro(NumberOfClasses, unsigned int);
  /** Fuzziness exponent m (> 1); default 2. */
  itkSetMacro(Fuzziness, double);
  itkGetConstMacro(Fuzziness, double);
  /** Largest centroid change relative to the intensity range that ends the iteration; default 1e-5. */
  itkSetMacro(Tolerance, double);
  itkGetConstMacro(Tolerance, double);
  /** Iteration limit; default 300. */
  itkSetMacro(MaximumNumberOfIterations, unsigned int);
  itkGetConstMacro(MaximumNumberOfIterations, unsigned int);

  /** Results of the last Update(). */
  const std::vector<double> &
  GetCentroids() const
  {
    return m_Centroids;
  }
  itkGetConstMacro(NumberOfIterations, unsigned int);
  itkGetConstMacro(Converged, bool);
  /** Warnings of the last update (e.g. no convergence; also sent through itkWarningMacro). */
  const std::vector<std::string> &
  GetWarnings() const
  {
    return m_Warnings;
  }

  /** The hard label map (second output). */
  LabelImageType *
  GetLabelOutput();

  using Superclass::MakeOutput;
  DataObject::Pointer
  MakeOutput(DataObjectPointerArraySizeType index) override;

protected:
  FuzzyCMeansClassifierImageFilter();
  ~FuzzyCMeansClassifierImageFilter() override = default;

  void
  PrintSelf(std::ostream & os, Indent indent) const override;

  void
  GenerateOutputInformation() override;
  void
  GenerateInputRequestedRegion() override;
  void
  EnlargeOutputRequestedRegion(DataObject * output) override;
  /** The core checks that the mask is on the input's grid and names both grids. */
  void
  VerifyInputInformation() ITKv5_CONST override
  {}
  void
  GenerateData() override;

private:
  unsigned int        m_NumberOfClasses{ 2 };
  double              m_Fuzziness{ 2.0 };
  double              m_Tolerance{ 1e-5 };
  unsigned int        m_MaximumNumberOfIterations{ 300 };
  std::vector<double> m_Centroids;
  unsigned int        m_NumberOfIterations{ 0 };
  bool                m_Converged{ false };
  std::vector<std::string> m_Warnings;
};

namespace FuzzyCMeansDetail
{
/** A mask image as a core label volume: non-zero voxels become 1. */
template <typename TMaskImage>
bmr::LabelVolume
MakeMaskVolume(const TMaskImage * mask)
{
  bmr::LabelVolume volume = MakeBiomechanicalVolume<std::uint8_t>(mask);
  ImageRegionConstIterator<TMaskImage> it(mask, mask->GetBufferedRegion());
  std::size_t                          n = 0;
  for (it.GoToBegin(); !it.IsAtEnd(); ++it)
  {
    volume.values[n++] = it.Get() != typename TMaskImage::PixelType{} ? 1 : 0;
  }
  return volume;
}
} // namespace FuzzyCMeansDetail

/** Material mapping from a membership image (the first output of
 *  FuzzyCMeansClassifierImageFilter) to a model's cells or meshless
 *  integration points: bmr::MapMaterialsFromMemberships (see
 *  bmrMaterialMapping.h for sampling, mixture rule and defaults). The optional
 *  tumour mask must be on the membership image's grid (non-zero = tumour).
 *  Core errors come back as itk::ExceptionObject; core warnings are appended
 *  to `warnings` when given. */
template <typename TMembershipImage, typename TMaskImage = Image<unsigned char, 3>>
void
MapBiomechanicalMaterials(bmr::Model &                         model,
                          const TMembershipImage *             memberships,
                          const bmr::MaterialMappingSettings & settings = {},
                          const TMaskImage *                   tumourMask = nullptr,
                          std::vector<std::string> *           warnings = nullptr)
{
  if (memberships == nullptr)
  {
    itkGenericExceptionMacro("MapBiomechanicalMaterials: no membership image; run the fuzzy c-means classifier first");
  }
  try
  {
    const bmr::ScalarVolume membershipVolume = MakeBiomechanicalVolume<float>(memberships);
    bmr::LabelVolume        tumourVolume;
    if (tumourMask)
    {
      tumourVolume = FuzzyCMeansDetail::MakeMaskVolume(tumourMask);
    }
    bmr::MapMaterialsFromMemberships(model, membershipVolume, settings, tumourMask ? &tumourVolume : nullptr, warnings);
  }
  catch (const bmr::Error & error)
  {
    itkGenericExceptionMacro("MapBiomechanicalMaterials: " << error.what());
  }
}

/** Material mapping from a hard label image: bmr::MapMaterialsFromLabels. */
template <typename TLabelImage>
void
MapBiomechanicalMaterialsFromLabels(bmr::Model &                         model,
                                    const TLabelImage *                  labels,
                                    const std::map<int, bmr::Material> & materialOfLabel,
                                    const bmr::MaterialSampling &        sampling = {},
                                    std::vector<std::string> *           warnings = nullptr)
{
  if (labels == nullptr)
  {
    itkGenericExceptionMacro("MapBiomechanicalMaterialsFromLabels: no label image given");
  }
  try
  {
    const bmr::LabelVolume labelVolume = MakeBiomechanicalVolume<std::uint8_t>(labels);
    bmr::MapMaterialsFromLabels(model, labelVolume, materialOfLabel, sampling, warnings);
  }
  catch (const bmr::Error & error)
  {
    itkGenericExceptionMacro("MapBiomechanicalMaterialsFromLabels: " << error.what());
  }
}

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkFuzzyCMeansClassifierImageFilter.hxx"
#endif

#endif
