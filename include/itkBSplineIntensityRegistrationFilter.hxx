#ifndef itkBSplineIntensityRegistrationFilter_hxx
#define itkBSplineIntensityRegistrationFilter_hxx

#include "itkBSplineIntensityRegistrationFilter.h"
#include "itkFloatImageScan.h"

#include "itkBSplineTransformInitializer.h"
#include "itkBSplineTransformParametersAdaptor.h"
#include "itkCastImageFilter.h"
#include "itkImageMaskSpatialObject.h"
#include "itkImageMomentsCalculator.h"
#include "itkImageRegionConstIterator.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIterator.h"
#include "itkLinearInterpolateImageFunction.h"
#include "itkFixedWorkUnitsCorrelationMetric.h"
#include "itkFixedWorkUnitsMattesMetric.h"
#include "itkQuietLBFGSBOptimizerv4.h"
#include "itkRegularStepGradientDescentOptimizerv4.h"
#include "itkResampleImageFilter.h"
#include "itkTranslationTransform.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <sstream>
#include <typeinfo>

namespace itk
{

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::BSplineIntensityRegistrationFilter()
{
  this->SetNumberOfRequiredInputs(1);
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
unsigned int
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::IterationsAtLevel(unsigned int level) const
{
  if (m_NumberOfIterations.empty())
  {
    // Coarse levels are cheap (few samples, few coefficients); the last ones dominate the time.
    return std::max(10u, static_cast<unsigned int>(std::lround(100.0 * std::ldexp(1.0, -static_cast<int>(level)))));
  }
  return m_NumberOfIterations.size() == 1 ? m_NumberOfIterations[0] : m_NumberOfIterations[level];
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
unsigned int
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::GetIterationsRun() const
{
  return std::accumulate(m_IterationsPerLevel.begin(), m_IterationsPerLevel.end(), 0u);
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::VerifyPreconditions() ITKv5_CONST
{
  if (this->GetMovingImage() == nullptr)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: the moving image is not set; call SetMovingImage() with "
                      "the image to warp (e.g. the preoperative MRI).");
  }
  if (this->GetFixedImage() == nullptr)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: the fixed image is not set; call SetFixedImage() with the "
                      "reference image (e.g. the intraoperative MRI).");
  }
  Superclass::VerifyPreconditions();
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::GenerateOutputInformation()
{
  const FixedImageType * fixed = this->GetFixedImage();
  OutputImageType *      output = this->GetOutput();
  if (fixed == nullptr || output == nullptr)
  {
    return;
  }
  output->CopyInformation(fixed);
  output->SetLargestPossibleRegion(fixed->GetLargestPossibleRegion());
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::GenerateInputRequestedRegion()
{
  Superclass::GenerateInputRequestedRegion();
  for (const auto & name : this->GetInputNames())
  {
    if (auto * image = dynamic_cast<ImageBase<ImageDimension> *>(this->ProcessObject::GetInput(name)))
    {
      image->SetRequestedRegionToLargestPossibleRegion();
    }
  }
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::EnlargeOutputRequestedRegion(
  DataObject * output)
{
  Superclass::EnlargeOutputRequestedRegion(output);
  output->SetRequestedRegionToLargestPossibleRegion();
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::VerifyParameters() const
{
  if (!(m_ControlPointSpacing > 0.0) || !std::isfinite(m_ControlPointSpacing))
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: ControlPointSpacing must be a positive number of mm, got "
                      << m_ControlPointSpacing << " (20 mm suits brain shift).");
  }
  if (m_ShrinkFactors.empty())
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: ShrinkFactors is empty; give one factor per pyramid level, "
                      "e.g. {4, 2, 1}.");
  }
  if (std::find(m_ShrinkFactors.begin(), m_ShrinkFactors.end(), 0u) != m_ShrinkFactors.end())
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: ShrinkFactors must be at least 1 (1: full resolution).");
  }
  if (m_SmoothingSigmas.size() != m_ShrinkFactors.size())
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: ShrinkFactors has "
                      << m_ShrinkFactors.size() << " levels but SmoothingSigmas has " << m_SmoothingSigmas.size()
                      << "; give one smoothing sigma (mm) per shrink factor.");
  }
  for (const double sigma : m_SmoothingSigmas)
  {
    if (!(sigma >= 0.0) || !std::isfinite(sigma))
    {
      itkExceptionMacro("BSplineIntensityRegistrationFilter: SmoothingSigmas must be >= 0 mm, got " << sigma << '.');
    }
  }
  if (m_NumberOfIterations.size() > 1 && m_NumberOfIterations.size() != m_ShrinkFactors.size())
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: NumberOfIterations has "
                      << m_NumberOfIterations.size() << " values for " << m_ShrinkFactors.size()
                      << " levels; give one value for every level or one per level (or none: 100 halved per level).");
  }
  if (std::find(m_NumberOfIterations.begin(), m_NumberOfIterations.end(), 0u) != m_NumberOfIterations.end())
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: NumberOfIterations must be at least 1.");
  }
  if (!(m_MetricSamplingPercentage > 0.0 && m_MetricSamplingPercentage <= 1.0))
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: MetricSamplingPercentage must lie in (0, 1], got "
                      << m_MetricSamplingPercentage << '.');
  }
  if (m_Metric == MetricType::MattesMutualInformation && m_NumberOfHistogramBins < 5)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: NumberOfHistogramBins must be at least 5, got "
                      << m_NumberOfHistogramBins << " (50 is usual).");
  }
  if (!(m_CostFunctionConvergenceFactor >= 0.0))
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: CostFunctionConvergenceFactor must be >= 0, got "
                      << m_CostFunctionConvergenceFactor << '.');
  }
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
template <typename TImage>
auto
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::MakeRealImage(const TImage * image,
                                                                                         const char *   role) const ->
  typename RealImageType::Pointer
{
  // NaN or infinity would poison the joint histogram silently.
  const auto scan = CastAndScanToFloat<RealImageType>(image);
  if (scan.notFinite > 0)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: the "
                      << role << " image contains " << scan.notFinite << " NaN or infinite voxel(s), the first at index "
                      << scan.firstNotFinite << "; replace them (e.g. by 0) before registration.");
  }
  if (scan.Constant())
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: the "
                      << role << " image is constant (every voxel " << scan.minimum
                      << "); intensity registration needs image structure. Check that the right file was given.");
  }
  return scan.image;
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
auto
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::ShrinkFactorsFor(const RealImageType * image,
                                                                                            unsigned int factor) const
  -> ShrinkFactorsType
{
  const auto &      spacing = image->GetSpacing();
  const double      finest = *std::min_element(spacing.Begin(), spacing.End());
  const auto        size = image->GetLargestPossibleRegion().GetSize();
  ShrinkFactorsType factors;
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    // Near-isotropic registration grids for anisotropic voxels; at least 4
    // voxels per axis so that the coarse grid still has an extent.
    const double axisFactor = std::round(static_cast<double>(factor) * finest / spacing[d]);
    const double largest = std::max(1.0, std::floor(static_cast<double>(size[d]) / 4.0));
    factors[d] = static_cast<unsigned int>(std::clamp(axisFactor, 1.0, largest));
  }
  return factors;
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
double
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::SamplingPercentageFor(
  const RealImageType * image, const ShrinkFactorsType & factors, double maskFraction) const
{
  // Voxels of the shrunk registration grid (ShrinkImageFilter rounds sizes down).
  double     voxels = 1.0;
  const auto size = image->GetLargestPossibleRegion().GetSize();
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    voxels *= std::max(1.0, std::floor(static_cast<double>(size[d]) / static_cast<double>(factors[d])));
  }
  double percentage = m_MetricSamplingPercentage;
  if (m_MaximumNumberOfMetricSamples > 0)
  {
    // ITK drops the samples outside the mask: the bound is on those inside.
    percentage = std::min(
      percentage, static_cast<double>(m_MaximumNumberOfMetricSamples) / (voxels * std::max(maskFraction, 1e-6)));
  }
  return percentage;
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
auto
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::MeshSizesFor(
  const RealImageType * fixed) const -> std::vector<MeshSizeType>
{
  const auto                levels = static_cast<unsigned int>(m_ShrinkFactors.size());
  std::vector<MeshSizeType> meshSizes(levels);
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    const double extent =
      fixed->GetSpacing()[d] * static_cast<double>(fixed->GetLargestPossibleRegion().GetSize()[d] - 1);
    const double cells = std::max(1.0, std::round(extent / m_ControlPointSpacing));
    for (unsigned int level = 0; level < levels; ++level)
    {
      const double coarsening = m_RefineMeshPerLevel ? std::ldexp(1.0, static_cast<int>(levels - 1 - level)) : 1.0;
      meshSizes[level][d] = static_cast<SizeValueType>(std::max(1.0, std::round(cells / coarsening)));
    }
  }
  return meshSizes;
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::Warp(const RealImageType * movingReal)
{
  OutputImageType * output = this->GetOutput();
  const auto        start = std::chrono::steady_clock::now();
  if constexpr (NumericTraits<OutputPixelType>::is_integer)
  {
    // ResampleImageFilter truncates to integers; interpolate in float and round.
    using ResampleType = ResampleImageFilter<RealImageType, RealImageType, double>;
    auto resample = ResampleType::New();
    resample->SetInput(movingReal);
    resample->SetTransform(m_Transform);
    resample->SetInterpolator(LinearInterpolateImageFunction<RealImageType, double>::New());
    resample->SetOutputParametersFromImage(this->GetFixedImage());
    resample->SetDefaultPixelValue(static_cast<float>(m_DefaultPixelValue));
    resample->Update();

    output->SetBufferedRegion(output->GetRequestedRegion());
    output->Allocate();
    const double lowest = static_cast<double>(NumericTraits<OutputPixelType>::NonpositiveMin());
    const double highest = static_cast<double>(NumericTraits<OutputPixelType>::max());
    ImageRegionConstIterator<RealImageType> in(resample->GetOutput(), output->GetBufferedRegion());
    ImageRegionIterator<OutputImageType>    out(output, output->GetBufferedRegion());
    for (; !in.IsAtEnd(); ++in, ++out)
    {
      out.Set(static_cast<OutputPixelType>(std::clamp(std::round(static_cast<double>(in.Get())), lowest, highest)));
    }
  }
  else
  {
    (void)movingReal;
    using ResampleType = ResampleImageFilter<MovingImageType, OutputImageType, double>;
    auto resample = ResampleType::New();
    resample->SetInput(this->GetMovingImage());
    resample->SetTransform(m_Transform);
    resample->SetInterpolator(LinearInterpolateImageFunction<MovingImageType, double>::New());
    resample->SetOutputParametersFromImage(this->GetFixedImage());
    resample->SetDefaultPixelValue(m_DefaultPixelValue);
    resample->GraftOutput(output);
    resample->Update();
    this->GraftOutput(resample->GetOutput());
  }
  m_WarpElapsedSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
auto
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::MakeMetric(
  const SpatialObject<ImageDimension> * mask) const -> typename ImageMetricType::Pointer
{
  typename ImageMetricType::Pointer metric;
  if (m_Metric == MetricType::Correlation)
  {
    auto correlation = FixedWorkUnitsCorrelationMetric<RealImageType>::New();
    correlation->SetFixedNumberOfWorkUnits(m_MetricNumberOfWorkUnits);
    metric = correlation;
  }
  else
  {
    auto mattes = FixedWorkUnitsMattesMetric<RealImageType>::New();
    mattes->SetNumberOfHistogramBins(m_NumberOfHistogramBins);
    mattes->SetFixedNumberOfWorkUnits(m_MetricNumberOfWorkUnits);
    metric = mattes;
  }
  // Central differences on the fly: cheaper than gradient images for sparse samples.
  metric->SetUseMovingImageGradientFilter(false);
  metric->SetUseFixedImageGradientFilter(false);
  if (mask != nullptr)
  {
    metric->SetFixedImageMask(mask);
  }
  return metric;
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
template <typename TRegistration>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::SetUpPyramid(TRegistration * registration,
                                                                                        const RealImageType * fixed,
                                                                                        double maskFraction) const
{
  const auto levels = static_cast<unsigned int>(m_ShrinkFactors.size());
  registration->SetNumberOfLevels(levels);
  typename TRegistration::SmoothingSigmasArrayType          sigmas(levels);
  typename TRegistration::MetricSamplingPercentageArrayType percentages(levels);
  for (unsigned int level = 0; level < levels; ++level)
  {
    const ShrinkFactorsType factors = this->ShrinkFactorsFor(fixed, m_ShrinkFactors[level]);
    registration->SetShrinkFactorsPerDimension(level, factors);
    sigmas[level] = m_SmoothingSigmas[level];
    percentages[level] = this->SamplingPercentageFor(fixed, factors, maskFraction);
  }
  registration->SetSmoothingSigmasPerLevel(sigmas);
  registration->SetSmoothingSigmasAreSpecifiedInPhysicalUnits(true);
  if (m_MetricSamplingStrategy != MetricSamplingStrategyEnum::NONE)
  {
    registration->SetMetricSamplingStrategy(m_MetricSamplingStrategy);
    registration->SetMetricSamplingPercentagePerLevel(percentages);
  }
  registration->MetricSamplingReinitializeSeed(m_RandomSeed);
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
auto
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::RegisterTranslation(
  const RealImageType * fixed, const RealImageType * moving, const SpatialObject<ImageDimension> * mask,
  double maskFraction, const TranslationType & initial) -> TranslationType
{
  using TranslationTransformType = TranslationTransform<double, ImageDimension>;
  using TranslationRegistrationType = ImageRegistrationMethodv4<RealImageType, RealImageType, TranslationTransformType>;
  auto translation = TranslationTransformType::New();
  translation->SetOffset(initial);

  // Regular steps: the step is a length in mm (the parameters are mm), so
  // each level starts with a step of its own voxel size and halves it at
  // every reversal down to 0.01 mm.
  using OptimizerType = RegularStepGradientDescentOptimizerv4<double>;
  auto optimizer = OptimizerType::New();
  optimizer->SetNumberOfIterations(m_TranslationNumberOfIterations);
  optimizer->SetMinimumStepLength(0.01);
  optimizer->SetRelaxationFactor(0.5);
  optimizer->SetDoEstimateLearningRateAtEachIteration(false);
  optimizer->SetDoEstimateLearningRateOnce(false);

  auto registration = TranslationRegistrationType::New();
  registration->SetFixedImage(fixed);
  registration->SetMovingImage(moving);
  registration->SetMetric(this->MakeMetric(mask));
  registration->SetOptimizer(optimizer);
  registration->SetInitialTransform(translation);
  registration->InPlaceOn();
  this->SetUpPyramid(registration.GetPointer(), fixed, maskFraction);

  const auto   levels = static_cast<unsigned int>(m_ShrinkFactors.size());
  const double finest = *std::min_element(fixed->GetSpacing().Begin(), fixed->GetSpacing().End());
  unsigned int currentLevel = 0;
  registration->AddObserver(MultiResolutionIterationEvent(), [&](const EventObject &) {
    currentLevel = static_cast<unsigned int>(registration->GetCurrentLevel());
    optimizer->SetLearningRate(static_cast<double>(m_ShrinkFactors[currentLevel]) * finest);
  });
  optimizer->AddObserver(IterationEvent(), [&](const EventObject &) {
    ++m_TranslationIterationsRun;
    const double within = std::min(1.0,
                                   static_cast<double>(optimizer->GetCurrentIteration() + 1) /
                                     static_cast<double>(m_TranslationNumberOfIterations));
    this->UpdateProgress(TranslationProgress *
                         static_cast<float>((currentLevel + within) / static_cast<double>(levels)));
  });
  try
  {
    registration->Update();
  }
  catch (const ProcessAborted &)
  {
    throw;
  }
  catch (const ExceptionObject & exception)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: the translation stage failed at level "
                      << currentLevel + 1 << " of " << levels << ": " << exception.GetDescription()
                      << " Check that the fixed and moving images overlap in physical space (origin, spacing, "
                         "direction) and that the mask covers image structure.");
  }
  return translation->GetOffset();
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::GenerateData()
{
  const auto startTime = std::chrono::steady_clock::now();
  m_Transform = nullptr;
  m_InitialTranslation.Fill(0.0);
  m_TranslationIterationsRun = 0;
  m_FinalMetricValue = 0.0;
  m_IterationsPerLevel.clear();
  m_MeshSizesPerLevel.clear();
  m_StopConditionDescription.clear();
  m_ElapsedSeconds = 0.0;
  m_WarpElapsedSeconds = 0.0;

  this->VerifyParameters();
  const typename RealImageType::Pointer fixed = this->MakeRealImage(this->GetFixedImage(), "fixed");
  const typename RealImageType::Pointer moving = this->MakeRealImage(this->GetMovingImage(), "moving");
  this->CheckImageSizes(fixed, moving);

  double     maskFraction = 1.0;
  const auto maskObject = this->MakeMaskObject(fixed, maskFraction);

  this->InitializeTransform(fixed, moving, maskObject, maskFraction);
  const auto levels = static_cast<unsigned int>(m_ShrinkFactors.size());
  const float start = m_UseTranslationStage ? TranslationProgress : 0.0f;

  const typename ImageMetricType::Pointer metric = this->MakeMetric(maskObject);
  auto                                    optimizer = QuietLBFGSBOptimizerv4::New();
  optimizer->SetCostFunctionConvergenceFactor(m_CostFunctionConvergenceFactor);
  optimizer->SetGradientConvergenceTolerance(1e-6);
  optimizer->SetMaximumNumberOfCorrections(7);

  auto registration = RegistrationType::New();
  registration->SetFixedImage(fixed);
  registration->SetMovingImage(moving);
  registration->SetMetric(metric);
  registration->SetOptimizer(optimizer);
  registration->SetInitialTransform(m_Transform);
  registration->InPlaceOn();
  this->SetUpPyramid(registration.GetPointer(), fixed, maskFraction);
  // The mesh of each level; the coefficients are refined between levels.
  typename RegistrationType::TransformParametersAdaptorsContainerType adaptors;
  for (unsigned int level = 0; level < levels; ++level)
  {
    using AdaptorType = BSplineTransformParametersAdaptor<BSplineTransformType>;
    auto adaptor = AdaptorType::New();
    adaptor->SetRequiredTransformDomainOrigin(m_Transform->GetTransformDomainOrigin());
    adaptor->SetRequiredTransformDomainPhysicalDimensions(m_Transform->GetTransformDomainPhysicalDimensions());
    adaptor->SetRequiredTransformDomainDirection(m_Transform->GetTransformDomainDirection());
    adaptor->SetRequiredTransformDomainMeshSize(m_MeshSizesPerLevel[level]);
    adaptors.push_back(adaptor.GetPointer());
  }
  registration->SetTransformParametersAdaptorsPerLevel(adaptors);

  // Per level: the iteration budget, and progress per optimizer iteration.
  const auto   iterationsAt = [this](unsigned int level) { return this->IterationsAtLevel(level); };
  unsigned int currentLevel = 0;
  m_IterationsPerLevel.assign(levels, 0);
  registration->AddObserver(MultiResolutionIterationEvent(), [&](const EventObject &) {
    currentLevel = static_cast<unsigned int>(registration->GetCurrentLevel());
    optimizer->SetNumberOfIterations(iterationsAt(currentLevel));
    optimizer->SetMaximumNumberOfFunctionEvaluations(2 * iterationsAt(currentLevel) + 10);
  });
  optimizer->AddObserver(IterationEvent(), [&](const EventObject & event) {
    // The vnl adaptor also sends IterationEvent subclasses per metric evaluation.
    if (typeid(event) != typeid(IterationEvent))
    {
      return;
    }
    const unsigned int done = ++m_IterationsPerLevel[currentLevel];
    const double within = std::min(1.0, static_cast<double>(done) / static_cast<double>(iterationsAt(currentLevel)));
    this->UpdateProgress(start +
                         (0.95f - start) * static_cast<float>((currentLevel + within) / static_cast<double>(levels)));
  });

  try
  {
    registration->Update();
  }
  catch (const ProcessAborted &)
  {
    throw;
  }
  catch (const ExceptionObject & exception)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: the registration failed at level "
                      << currentLevel + 1 << " of " << levels << ": " << exception.GetDescription()
                      << " Check that the fixed and moving images overlap in physical space (origin, spacing, "
                         "direction) and that the mask covers image structure.");
  }
  m_StopConditionDescription = optimizer->GetStopConditionDescription();
  // The metric at the final parameters (the optimizer's last value may belong to a rejected line-search trial).
  m_FinalMetricValue = metric->GetValue();
  m_ElapsedSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - startTime).count();
  this->UpdateProgress(0.95f);

  this->Warp(moving);
  this->UpdateProgress(1.0f);
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::CheckImageSizes(const RealImageType * fixed, const RealImageType * moving) const
{
  for (const RealImageType * image : { fixed, moving })
  {
    const auto size = image->GetLargestPossibleRegion().GetSize();
    for (unsigned int d = 0; d < ImageDimension; ++d)
    {
      if (size[d] < 4)
      {
        itkExceptionMacro("BSplineIntensityRegistrationFilter: the "
                          << (image == fixed ? "fixed" : "moving") << " image has " << size[d]
                          << " voxel(s) along axis " << d
                          << "; registration needs at least 4 per axis (a 2D image stored as 3D? register it as 2D).");
      }
    }
  }
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
auto
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::MakeMaskObject(const RealImageType * fixed,
                                                                                      double & maskFraction) const
  -> typename SpatialObject<ImageDimension>::Pointer
{
  // The fixed mask as a spatial object (voxels > 0 inside); it must hold
  // voxels inside the fixed image, or no metric sample could be drawn.
  using MaskSpatialObjectType = ImageMaskSpatialObject<ImageDimension>;
  maskFraction = 1.0;
  const MaskImageType * mask = this->GetFixedMask();
  if (mask == nullptr)
  {
    return nullptr;
  }
  using BinaryImageType = typename MaskSpatialObjectType::ImageType;
  auto binary = BinaryImageType::New();
  binary->CopyInformation(mask);
  binary->SetRegions(mask->GetLargestPossibleRegion());
  binary->Allocate();
  SizeValueType inside = 0;
  SizeValueType insideFixed = 0;
  using MaskIteratorType = ImageRegionConstIteratorWithIndex<MaskImageType>;
  ImageRegionIterator<BinaryImageType> out(binary, binary->GetLargestPossibleRegion());
  for (MaskIteratorType in(mask, mask->GetLargestPossibleRegion()); !in.IsAtEnd(); ++in, ++out)
  {
    const bool isInside = in.Get() > NumericTraits<typename MaskImageType::PixelType>::ZeroValue();
    out.Set(isInside ? 1 : 0);
    if (isInside)
    {
      ++inside;
      typename RealImageType::PointType point;
      mask->TransformIndexToPhysicalPoint(in.GetIndex(), point);
      typename RealImageType::IndexType index;
      insideFixed += fixed->TransformPhysicalPointToIndex(point, index) ? 1 : 0;
    }
  }
  if (inside == 0)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: the fixed mask is empty (no voxel > 0); give a mask of "
                      "the region to register (e.g. the brain) or no mask.");
  }
  if (insideFixed == 0)
  {
    itkExceptionMacro("BSplineIntensityRegistrationFilter: none of the fixed mask's "
                      << inside
                      << " voxels lies inside the fixed image; the mask must be in the fixed image's physical "
                         "space (check its origin, spacing and direction).");
  }
  // Share of the fixed domain's volume inside the mask (for the sample bound).
  double maskVoxelVolume = 1.0;
  double fixedVolume = 1.0;
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    maskVoxelVolume *= mask->GetSpacing()[d];
    fixedVolume *= fixed->GetSpacing()[d] * static_cast<double>(fixed->GetLargestPossibleRegion().GetSize()[d]);
  }
  maskFraction = std::min(1.0, static_cast<double>(insideFixed) * maskVoxelVolume / fixedVolume);
  auto maskObject = MaskSpatialObjectType::New();
  maskObject->SetImage(binary);
  maskObject->Update();
  return maskObject;
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::InitializeTransform(const RealImageType * fixed, const RealImageType * moving,
                                                                                const SpatialObject<ImageDimension> * mask,
                                                                                double maskFraction)
{
  // The B-spline over the fixed domain, starting at the coarsest mesh.
  m_MeshSizesPerLevel = this->MeshSizesFor(fixed);
  m_Transform = BSplineTransformType::New();
  {
    using InitializerType = BSplineTransformInitializer<BSplineTransformType, RealImageType>;
    auto initializer = InitializerType::New();
    initializer->SetTransform(m_Transform);
    initializer->SetImage(fixed);
    initializer->SetTransformDomainMeshSize(m_MeshSizesPerLevel[0]);
    initializer->InitializeTransform();
    m_Transform->SetIdentity();
  }

  // Optional translation stage, folded into the B-spline: a cubic B-spline
  // whose coefficients all equal t moves every point of its domain by t.
  if (m_TranslationInitialization == TranslationInitializationType::Moments)
  {
    // Centres of mass of the whole images (not the mask: the moving image has none).
    using MomentsType = ImageMomentsCalculator<RealImageType>;
    auto fixedMoments = MomentsType::New();
    fixedMoments->SetImage(fixed);
    fixedMoments->Compute();
    auto movingMoments = MomentsType::New();
    movingMoments->SetImage(moving);
    movingMoments->Compute();
    m_InitialTranslation = movingMoments->GetCenterOfGravity() - fixedMoments->GetCenterOfGravity();
  }
  if (m_UseTranslationStage)
  {
    m_InitialTranslation = this->RegisterTranslation(fixed, moving, mask, maskFraction, m_InitialTranslation);
  }
  if (m_InitialTranslation.GetSquaredNorm() > 0.0)
  {
    typename BSplineTransformType::ParametersType parameters(m_Transform->GetNumberOfParameters());
    const SizeValueType                           controlPoints = parameters.Size() / ImageDimension;
    for (unsigned int d = 0; d < ImageDimension; ++d)
    {
      std::fill_n(parameters.data_block() + d * controlPoints, controlPoints, m_InitialTranslation[d]);
    }
    m_Transform->SetParameters(parameters);
  }
}

template <typename TFixedImage, typename TMovingImage, typename TMaskImage>
void
BSplineIntensityRegistrationFilter<TFixedImage, TMovingImage, TMaskImage>::PrintSelf(std::ostream & os,
                                                                                     Indent         indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "Metric: " << (m_Metric == MetricType::Correlation ? "Correlation" : "MattesMutualInformation")
     << '\n';
  os << indent << "ControlPointSpacing (mm): " << m_ControlPointSpacing << '\n';
  os << indent << "ShrinkFactors:";
  for (const unsigned int factor : m_ShrinkFactors)
  {
    os << ' ' << factor;
  }
  os << '\n' << indent << "SmoothingSigmas (mm):";
  for (const double sigma : m_SmoothingSigmas)
  {
    os << ' ' << sigma;
  }
  os << '\n' << indent << "NumberOfIterations:";
  for (unsigned int level = 0; level < m_ShrinkFactors.size(); ++level)
  {
    os << ' ' << this->IterationsAtLevel(level);
  }
  os << '\n';
  os << indent << "RefineMeshPerLevel: " << m_RefineMeshPerLevel << '\n';
  os << indent << "CostFunctionConvergenceFactor: " << m_CostFunctionConvergenceFactor << '\n';
  os << indent << "NumberOfHistogramBins: " << m_NumberOfHistogramBins << '\n';
  os << indent << "MetricSamplingPercentage: " << m_MetricSamplingPercentage << '\n';
  os << indent << "MaximumNumberOfMetricSamples: " << m_MaximumNumberOfMetricSamples << '\n';
  os << indent << "MetricSamplingStrategy: " << m_MetricSamplingStrategy << '\n';
  os << indent << "RandomSeed: " << m_RandomSeed << '\n';
  os << indent << "MetricNumberOfWorkUnits: " << m_MetricNumberOfWorkUnits << '\n';
  os << indent
     << "DefaultPixelValue: " << static_cast<typename NumericTraits<OutputPixelType>::PrintType>(m_DefaultPixelValue)
     << '\n';
  os << indent << "FinalMetricValue: " << m_FinalMetricValue << '\n';
  os << indent << "IterationsRun: " << this->GetIterationsRun() << '\n';
  os << indent << "ElapsedSeconds: " << m_ElapsedSeconds << '\n';
  os << indent << "WarpElapsedSeconds: " << m_WarpElapsedSeconds << '\n';
}

} // namespace itk

#endif
