#ifndef itkFuzzyCMeansClassifierImageFilter_hxx
#define itkFuzzyCMeansClassifierImageFilter_hxx

#include "itkFuzzyCMeansClassifierImageFilter.h"

#include <algorithm>

namespace itk
{

template <typename TInputImage, typename TMaskImage>
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::FuzzyCMeansClassifierImageFilter()
{
  // #0 "Primary" required, #1 "MaskImage" optional.
  Self::AddOptionalInputName("MaskImage", 1);
  this->SetNumberOfRequiredOutputs(2);
  this->SetNthOutput(1, this->MakeOutput(1));
}

template <typename TInputImage, typename TMaskImage>
DataObject::Pointer
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::MakeOutput(DataObjectPointerArraySizeType index)
{
  if (index == 1)
  {
    return LabelImageType::New().GetPointer();
  }
  return Superclass::MakeOutput(index);
}

template <typename TInputImage, typename TMaskImage>
auto
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::GetLabelOutput() -> LabelImageType *
{
  return dynamic_cast<LabelImageType *>(this->ProcessObject::GetOutput(1));
}

template <typename TInputImage, typename TMaskImage>
void
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::GenerateOutputInformation()
{
  Superclass::GenerateOutputInformation(); // both outputs take the input's geometry
  this->GetOutput()->SetNumberOfComponentsPerPixel(m_NumberOfClasses);
}

template <typename TInputImage, typename TMaskImage>
void
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::GenerateInputRequestedRegion()
{
  Superclass::GenerateInputRequestedRegion();
  // Clustering is global: the whole input and mask are needed.
  if (auto * input = const_cast<InputImageType *>(this->GetInput()))
  {
    input->SetRequestedRegionToLargestPossibleRegion();
  }
  if (auto * mask = const_cast<MaskImageType *>(this->GetMaskImage()))
  {
    mask->SetRequestedRegionToLargestPossibleRegion();
  }
}

template <typename TInputImage, typename TMaskImage>
void
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::EnlargeOutputRequestedRegion(DataObject * output)
{
  Superclass::EnlargeOutputRequestedRegion(output);
  for (unsigned int n = 0; n < this->GetNumberOfIndexedOutputs(); ++n)
  {
    if (auto * image = dynamic_cast<ImageBase<ImageDimension> *>(this->ProcessObject::GetOutput(n)))
    {
      image->SetRequestedRegionToLargestPossibleRegion();
    }
  }
}

template <typename TInputImage, typename TMaskImage>
void
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::GenerateData()
{
  const InputImageType * input = this->GetInput();
  const MaskImageType *  mask = this->GetMaskImage();

  bmr::FuzzyCMeansSettings settings;
  settings.classes = static_cast<int>(m_NumberOfClasses);
  settings.fuzziness = m_Fuzziness;
  settings.tolerance = m_Tolerance;
  settings.maxIterations = static_cast<int>(std::min<unsigned int>(m_MaximumNumberOfIterations, 1u << 30));

  bmr::TissueClassification classification;
  m_Warnings.clear();
  try
  {
    const bmr::ScalarVolume intensities = MakeBiomechanicalVolume<float>(input);
    bmr::LabelVolume        maskVolume;
    if (mask)
    {
      maskVolume = FuzzyCMeansDetail::MakeMaskVolume(mask);
    }
    classification = bmr::ClassifyTissue(
      intensities,
      mask ? &maskVolume : nullptr,
      settings,
      [this](double fraction) { this->UpdateProgress(static_cast<float>(fraction)); },
      &m_Warnings);
  }
  catch (const bmr::Error & error)
  {
    itkExceptionMacro(<< error.what());
  }
  for (const std::string & warning : m_Warnings)
  {
    itkWarningMacro(<< warning);
  }
  m_Centroids = classification.fit.centroids;
  m_NumberOfIterations = static_cast<unsigned int>(classification.fit.iterations);
  m_Converged = classification.fit.converged;

  // The outputs' requested regions are the largest possible ones, which are
  // the input's buffered region: the core's voxel order is the buffer order.
  OutputImageType * memberships = this->GetOutput();
  if (memberships->GetRequestedRegion().GetNumberOfPixels() != classification.labels.values.size())
  {
    itkExceptionMacro(<< "the output's requested region " << memberships->GetRequestedRegion()
                      << " is not the input's buffered region; update the whole image");
  }
  memberships->SetBufferedRegion(memberships->GetRequestedRegion());
  memberships->SetNumberOfComponentsPerPixel(m_NumberOfClasses);
  memberships->Allocate();
  std::copy(classification.memberships.values.begin(),
            classification.memberships.values.end(),
            memberships->GetBufferPointer());

  LabelImageType * labels = this->GetLabelOutput();
  labels->SetBufferedRegion(labels->GetRequestedRegion());
  labels->Allocate();
  std::copy(classification.labels.values.begin(), classification.labels.values.end(), labels->GetBufferPointer());
}

template <typename TInputImage, typename TMaskImage>
void
FuzzyCMeansClassifierImageFilter<TInputImage, TMaskImage>::PrintSelf(std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "NumberOfClasses: " << m_NumberOfClasses << std::endl;
  os << indent << "Fuzziness: " << m_Fuzziness << std::endl;
  os << indent << "Tolerance: " << m_Tolerance << std::endl;
  os << indent << "MaximumNumberOfIterations: " << m_MaximumNumberOfIterations << std::endl;
  os << indent << "Centroids:";
  for (double centroid : m_Centroids)
  {
    os << ' ' << centroid;
  }
  os << std::endl;
  os << indent << "NumberOfIterations: " << m_NumberOfIterations << std::endl;
  os << indent << "Converged: " << (m_Converged ? "true" : "false") << std::endl;
}

} // namespace itk

#endif
