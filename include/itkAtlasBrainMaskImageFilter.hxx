#ifndef itkAtlasBrainMaskImageFilter_hxx
#define itkAtlasBrainMaskImageFilter_hxx

#include "itkAtlasBrainMaskImageFilter.h"
#include "itkFloatImageScan.h"

#include "itkBSplineTransformInitializer.h"
#include "itkCastImageFilter.h"
#include "itkCenteredTransformInitializer.h"
#include "itkConjugateGradientLineSearchOptimizerv4.h"
#include "itkDisplacementFieldTransform.h"
#include "itkImageRegionConstIterator.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIterator.h"
#include "itkLinearInterpolateImageFunction.h"
#include "itkNearestNeighborInterpolateImageFunction.h"
#include "itkFixedWorkUnitsMattesMetric.h"
#include "itkQuietLBFGSBOptimizerv4.h"
#include "itkRegistrationParameterScalesFromPhysicalShift.h"
#include "itkResampleImageFilter.h"
#include "itkTransformToDisplacementFieldFilter.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace itk
{
template <typename TInputImage, typename TOutputImage>
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::AtlasBrainMaskImageFilter()
{
  this->SetNumberOfRequiredInputs(1);
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::VerifyPreconditions() ITKv5_CONST
{
  if (this->GetInput() == nullptr)
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the subject image (primary input) is not set; call SetInput() "
                      "with the T1 image to skull-strip.");
  }
  if (this->GetAtlasImage() == nullptr)
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the atlas image is not set; call SetAtlasImage() with a T1 "
                      "template, e.g. /usr/share/mricron/templates/ch2.nii.gz (Colin27).");
  }
  if (this->GetAtlasMaskImage() == nullptr)
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the atlas mask image is not set; call SetAtlasMaskImage() with the "
                      "template's brain (voxels > 0), e.g. /usr/share/mricron/templates/ch2bet.nii.gz.");
  }
  Superclass::VerifyPreconditions();
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::VerifyInputInformation() ITKv5_CONST
{
  // The subject and the atlas live on unrelated grids (that is the point of
  // registering them); only the atlas mask must lie on the atlas grid.
  const AtlasImageType *     atlas = this->GetAtlasImage();
  const AtlasMaskImageType * mask = this->GetAtlasMaskImage();
  if (atlas == nullptr || mask == nullptr)
  {
    return;
  }
  const double coordinateTolerance = this->GetCoordinateTolerance();
  const double directionTolerance = this->GetDirectionTolerance();
  const double spacingTolerance = coordinateTolerance * atlas->GetSpacing()[0];
  std::ostringstream mismatch;
  if (atlas->GetLargestPossibleRegion() != mask->GetLargestPossibleRegion())
  {
    mismatch << " region " << mask->GetLargestPossibleRegion().GetIndex() << " size "
             << mask->GetLargestPossibleRegion().GetSize() << " vs atlas " << atlas->GetLargestPossibleRegion().GetIndex()
             << " size " << atlas->GetLargestPossibleRegion().GetSize() << ';';
  }
  if (!atlas->GetOrigin().GetVnlVector().is_equal(mask->GetOrigin().GetVnlVector(), spacingTolerance))
  {
    mismatch << " origin " << mask->GetOrigin() << " vs atlas " << atlas->GetOrigin() << ';';
  }
  if (!atlas->GetSpacing().GetVnlVector().is_equal(mask->GetSpacing().GetVnlVector(), spacingTolerance))
  {
    mismatch << " spacing " << mask->GetSpacing() << " vs atlas " << atlas->GetSpacing() << ';';
  }
  if (!atlas->GetDirection().GetVnlMatrix().as_ref().is_equal(mask->GetDirection().GetVnlMatrix().as_ref(),
                                                               directionTolerance))
  {
    mismatch << " direction differs from the atlas direction;";
  }
  if (!mismatch.str().empty())
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the atlas mask is not on the atlas grid:"
                      << mismatch.str()
                      << " resample the atlas mask onto the atlas image grid (nearest neighbour) or supply the "
                         "matching pair, e.g. ch2.nii.gz with ch2bet.nii.gz.");
  }
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::GenerateInputRequestedRegion()
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

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::EnlargeOutputRequestedRegion(DataObject * output)
{
  Superclass::EnlargeOutputRequestedRegion(output);
  output->SetRequestedRegionToLargestPossibleRegion();
}

template <typename TInputImage, typename TOutputImage>
auto
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::MakeRealImage(const InputImageType * image,
                                                                    const char *           role) const ->
  typename RealImageType::Pointer
{
  // NaN or infinity would poison the joint histogram silently.
  const auto scan = CastAndScanToFloat<RealImageType>(image);
  if (scan.notFinite > 0)
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the " << role << " image contains " << scan.notFinite
                                                        << " NaN or infinite voxel(s), the first at index "
                                                        << scan.firstNotFinite
                                                        << "; replace them (e.g. by 0) before skull stripping.");
  }
  if (scan.Constant())
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the " << role
                                                        << " image is constant; a T1-weighted head image is needed "
                                                           "for registration.");
  }
  return scan.image;
}

template <typename TInputImage, typename TOutputImage>
auto
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::ShrinkFactorsFor(const RealImageType * image,
                                                                       double targetSpacing) const ->
  typename ImageRegistrationMethodv4<RealImageType, RealImageType>::ShrinkFactorsPerDimensionContainerType
{
  typename ImageRegistrationMethodv4<RealImageType, RealImageType>::ShrinkFactorsPerDimensionContainerType factors;
  const auto size = image->GetLargestPossibleRegion().GetSize();
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    const double factor = std::round(targetSpacing / image->GetSpacing()[d]);
    // Keep at least 4 voxels per axis so that the coarse grid still has a B-spline-smoothable extent.
    const double largest = std::max(1.0, std::floor(static_cast<double>(size[d]) / 4.0));
    factors[d] = static_cast<unsigned int>(std::clamp(factor, 1.0, largest));
  }
  return factors;
}

template <typename TInputImage, typename TOutputImage>
double
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::SamplingPercentageFor(
  const RealImageType *                                                                                   image,
  const typename ImageRegistrationMethodv4<RealImageType, RealImageType>::ShrinkFactorsPerDimensionContainerType &
    factors,
  SizeValueType maximumNumberOfSamples) const
{
  // Voxels of the shrunk registration grid (ShrinkImageFilter rounds sizes down).
  double voxels = 1.0;
  const auto size = image->GetLargestPossibleRegion().GetSize();
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    voxels *= std::max(1.0, std::floor(static_cast<double>(size[d]) / static_cast<double>(factors[d])));
  }
  double percentage = m_MetricSamplingPercentage;
  if (maximumNumberOfSamples > 0)
  {
    percentage = std::min(percentage, static_cast<double>(maximumNumberOfSamples) / voxels);
  }
  return percentage;
}

template <typename TInputImage, typename TOutputImage>
auto
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::MakeResamplingTransform(const RealImageType * subject) const
  -> typename CompositeTransformType::Pointer
{
  if (m_BSplineTransform.IsNull())
  {
    return m_CompositeTransform;
  }
  // Evaluating ITK's BSplineTransform costs about a microsecond per point, which
  // dominates resampling a 1 mm head. The B-spline is sampled once into a
  // displacement field of BSplineControlPointSpacing / 10 spacing covering the
  // subject (plus a cell), and the field is interpolated linearly: for a cubic
  // spline with knots 10 cells apart the interpolation error is below 1/500 of
  // the largest coefficient, i.e. far below a voxel.
  using FieldTransformType = DisplacementFieldTransform<double, ImageDimension>;
  using FieldType = typename FieldTransformType::DisplacementFieldType;
  using FieldFilterType = TransformToDisplacementFieldFilter<FieldType, double>;

  const double fieldSpacing = m_BSplineControlPointSpacing / 10.0;
  typename FieldFilterType::SizeType    size;
  typename FieldFilterType::SpacingType spacing;
  ContinuousIndex<double, ImageDimension> start;
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    const double extent = subject->GetSpacing()[d] *
                          static_cast<double>(subject->GetLargestPossibleRegion().GetSize()[d] - 1);
    spacing[d] = fieldSpacing;
    size[d] = static_cast<SizeValueType>(std::ceil(extent / fieldSpacing)) + 3;
    // One field cell before the first subject voxel, along the subject axes.
    start[d] = static_cast<double>(subject->GetLargestPossibleRegion().GetIndex()[d]) -
               fieldSpacing / subject->GetSpacing()[d];
  }
  typename FieldFilterType::OriginType origin;
  subject->TransformContinuousIndexToPhysicalPoint(start, origin);

  auto fieldFilter = FieldFilterType::New();
  fieldFilter->SetTransform(m_BSplineTransform);
  fieldFilter->SetOutputOrigin(origin);
  fieldFilter->SetOutputSpacing(spacing);
  fieldFilter->SetOutputDirection(subject->GetDirection());
  fieldFilter->SetSize(size);
  fieldFilter->Update();

  auto field = FieldTransformType::New();
  field->SetDisplacementField(fieldFilter->GetOutput());
  auto transform = CompositeTransformType::New();
  transform->AddTransform(m_AffineTransform);
  transform->AddTransform(field);
  return transform;
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::GenerateData()
{
  this->CheckSettings();
  m_AffineTransform = nullptr;
  m_BSplineTransform = nullptr;
  m_CompositeTransform = nullptr;
  m_AffineFinalMetricValue = 0.0;
  m_BSplineFinalMetricValue = 0.0;
  m_AffineIterationsRun = 0;
  m_BSplineIterationsRun = 0;
  m_PropagatedBrainVolume = 0.0;

  const typename RealImageType::Pointer atlasBrain = this->MakeAtlasBrain();
  const typename RealImageType::Pointer subject = this->MakeRealImage(this->GetInput(), "subject");
  const typename RealImageType::Pointer atlas = this->MakeRealImage(this->GetAtlasImage(), "atlas");
  this->RegisterAffine(subject, atlas);
  this->UpdateProgress(0.5f);
  m_CompositeTransform = CompositeTransformType::New();
  m_CompositeTransform->AddTransform(m_AffineTransform);
  if (m_UseBSplineStage)
  {
    this->RegisterBSpline(subject, atlas);
    m_CompositeTransform->AddTransform(m_BSplineTransform);
  }
  this->UpdateProgress(0.95f);
  this->PropagateAtlasBrain(atlasBrain, subject);
  this->UpdateProgress(1.0f);
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::CheckSettings() const
{
  if (m_AffineLevelSpacings.empty() || m_AffineLevelSpacings.size() != m_AffineSmoothingSigmas.size())
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: AffineLevelSpacings (" << m_AffineLevelSpacings.size()
                                                                         << " levels) and AffineSmoothingSigmas ("
                                                                         << m_AffineSmoothingSigmas.size()
                                                                         << ") must be non-empty and of equal length.");
  }
  if (!(m_MetricSamplingPercentage > 0.0 && m_MetricSamplingPercentage <= 1.0))
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: MetricSamplingPercentage must lie in (0, 1], got "
                      << m_MetricSamplingPercentage << '.');
  }
  if (!(m_BSplineControlPointSpacing > 0.0))
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: BSplineControlPointSpacing must be positive (mm), got "
                      << m_BSplineControlPointSpacing << '.');
  }
}

template <typename TInputImage, typename TOutputImage>
typename AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::RealImageType::Pointer
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::MakeAtlasBrain()
{
  const AtlasMaskImageType * atlasMask = this->GetAtlasMaskImage();
  // Atlas brain: voxels > 0, as a 0/1 float image for resampling.
  auto atlasBrain = RealImageType::New();
  atlasBrain->CopyInformation(atlasMask);
  atlasBrain->SetRegions(atlasMask->GetLargestPossibleRegion());
  atlasBrain->Allocate();
  SizeValueType atlasBrainVoxels = 0;
  {
    ImageRegionConstIterator<AtlasMaskImageType> in(atlasMask, atlasMask->GetLargestPossibleRegion());
    ImageRegionIterator<RealImageType>           out(atlasBrain, atlasBrain->GetLargestPossibleRegion());
    for (; !in.IsAtEnd(); ++in, ++out)
    {
      const bool brain = in.Get() > NumericTraits<typename AtlasMaskImageType::PixelType>::ZeroValue();
      out.Set(brain ? 1.0f : 0.0f);
      atlasBrainVoxels += brain ? 1 : 0;
    }
  }
  if (atlasBrainVoxels == 0)
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the atlas mask has no foreground (no voxel > 0); supply the "
                      "template's brain mask, e.g. ch2bet.nii.gz.");
  }
  double atlasVoxelVolume = 1.0;
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    atlasVoxelVolume *= atlasMask->GetSpacing()[d];
  }
  m_AtlasBrainVolume = static_cast<double>(atlasBrainVoxels) * atlasVoxelVolume;
  return atlasBrain;
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::ReportIterationProgress(const Object * optimizer, float start, float span, unsigned int levels,
                                                                              unsigned int iterationsPerLevel, unsigned int level)
{
  // The stage's fraction spread over levels x iterations.
  const auto * base = dynamic_cast<const ObjectToObjectOptimizerBaseTemplate<double> *>(optimizer);
  const double perLevel = 1.0 / static_cast<double>(std::max(1u, levels));
  const double within = base == nullptr ? 0.0
                                        : std::min(1.0, static_cast<double>(base->GetCurrentIteration() + 1) /
                                                          static_cast<double>(std::max(1u, iterationsPerLevel)));
  this->UpdateProgress(start + span * static_cast<float>(perLevel * (level + within)));
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::RegisterAffine(const RealImageType * subject,
                                                                     const RealImageType * atlas)
{
  using RegistrationType = ImageRegistrationMethodv4<RealImageType, RealImageType, AffineTransformType>;
  using MetricType = FixedWorkUnitsMattesMetric<RealImageType>;

  // Initialisation: centres of mass (image moments) aligned.
  m_AffineTransform = AffineTransformType::New();
  {
    using InitializerType = CenteredTransformInitializer<AffineTransformType, RealImageType, RealImageType>;
    auto initializer = InitializerType::New();
    initializer->SetTransform(m_AffineTransform);
    initializer->SetFixedImage(subject);
    initializer->SetMovingImage(atlas);
    initializer->MomentsOn();
    initializer->InitializeTransform();
  }
  this->UpdateProgress(0.02f);

  auto metric = MetricType::New();
  metric->SetNumberOfHistogramBins(m_NumberOfHistogramBins);
  metric->SetUseMovingImageGradientFilter(false);
  metric->SetUseFixedImageGradientFilter(false);
  metric->SetFixedNumberOfWorkUnits(m_MetricNumberOfWorkUnits);

  using ScalesEstimatorType = RegistrationParameterScalesFromPhysicalShift<MetricType>;
  auto scalesEstimator = ScalesEstimatorType::New();
  scalesEstimator->SetMetric(metric);
  scalesEstimator->SetTransformForward(true);

  using OptimizerType = ConjugateGradientLineSearchOptimizerv4Template<double>;
  auto optimizer = OptimizerType::New();
  optimizer->SetScalesEstimator(scalesEstimator);
  optimizer->SetDoEstimateLearningRateOnce(true);
  optimizer->SetDoEstimateLearningRateAtEachIteration(false);
  optimizer->SetLowerLimit(0.0);
  optimizer->SetUpperLimit(2.0);
  optimizer->SetEpsilon(0.2);
  optimizer->SetMaximumLineSearchIterations(20);
  optimizer->SetNumberOfIterations(m_AffineNumberOfIterations);
  optimizer->SetMinimumConvergenceValue(1e-6);
  optimizer->SetConvergenceWindowSize(10);

  auto registration = RegistrationType::New();
  registration->SetFixedImage(subject);
  registration->SetMovingImage(atlas);
  registration->SetMetric(metric);
  registration->SetOptimizer(optimizer);
  registration->SetInitialTransform(m_AffineTransform);
  registration->InPlaceOn();

  const auto levels = static_cast<unsigned int>(m_AffineLevelSpacings.size());
  registration->SetNumberOfLevels(levels);
  typename RegistrationType::SmoothingSigmasArrayType sigmas(levels);
  for (unsigned int level = 0; level < levels; ++level)
  {
    registration->SetShrinkFactorsPerDimension(level, this->ShrinkFactorsFor(subject, m_AffineLevelSpacings[level]));
    sigmas[level] = m_AffineSmoothingSigmas[level];
  }
  registration->SetSmoothingSigmasPerLevel(sigmas);
  registration->SetSmoothingSigmasAreSpecifiedInPhysicalUnits(true);
  if (m_MetricSamplingStrategy != MetricSamplingStrategyEnum::NONE)
  {
    typename RegistrationType::MetricSamplingPercentageArrayType percentages(levels);
    for (unsigned int level = 0; level < levels; ++level)
    {
      percentages[level] = this->SamplingPercentageFor(
        subject, registration->GetShrinkFactorsPerDimension(level), m_MaximumNumberOfMetricSamples);
    }
    registration->SetMetricSamplingStrategy(m_MetricSamplingStrategy);
    registration->SetMetricSamplingPercentagePerLevel(percentages);
  }
  registration->MetricSamplingReinitializeSeed(m_RandomSeed);

  unsigned int currentLevel = 0;
  registration->AddObserver(MultiResolutionIterationEvent(), [&](const EventObject &) {
    currentLevel = static_cast<unsigned int>(registration->GetCurrentLevel());
  });
  const OptimizerType * optimizerPointer = optimizer.GetPointer();
  optimizer->AddObserver(IterationEvent(), [&](const EventObject &) {
    this->ReportIterationProgress(optimizerPointer, 0.02f, 0.48f, levels, m_AffineNumberOfIterations, currentLevel);
  });

  registration->Update();
  m_AffineFinalMetricValue = optimizer->GetCurrentMetricValue();
  m_AffineIterationsRun = static_cast<unsigned int>(optimizer->GetCurrentIteration());
}

// Composed after the affine (the affine is its moving initial transform).
template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::RegisterBSpline(const RealImageType * subject,
                                                                      const RealImageType * atlas)
{
  using BSplineRegistrationType = ImageRegistrationMethodv4<RealImageType, RealImageType, BSplineTransformType>;
  using MetricType = FixedWorkUnitsMattesMetric<RealImageType>;

  m_BSplineTransform = BSplineTransformType::New();
  {
    typename BSplineTransformType::MeshSizeType meshSize;
    for (unsigned int d = 0; d < ImageDimension; ++d)
    {
      const double extent = subject->GetSpacing()[d] *
                            static_cast<double>(subject->GetLargestPossibleRegion().GetSize()[d] - 1);
      meshSize[d] = static_cast<unsigned int>(std::max(1.0, std::round(extent / m_BSplineControlPointSpacing)));
    }
    using InitializerType = BSplineTransformInitializer<BSplineTransformType, RealImageType>;
    auto initializer = InitializerType::New();
    initializer->SetTransform(m_BSplineTransform);
    initializer->SetImage(subject);
    initializer->SetTransformDomainMeshSize(meshSize);
    initializer->InitializeTransform();
    m_BSplineTransform->SetIdentity();
  }

  auto metric = MetricType::New();
  metric->SetNumberOfHistogramBins(m_NumberOfHistogramBins);
  metric->SetUseMovingImageGradientFilter(false);
  metric->SetUseFixedImageGradientFilter(false);
  metric->SetFixedNumberOfWorkUnits(m_MetricNumberOfWorkUnits);

  auto optimizer = QuietLBFGSBOptimizerv4::New();
  const unsigned int numberOfParameters = m_BSplineTransform->GetNumberOfParameters();
  LBFGSBOptimizerv4::BoundSelectionType unbounded(numberOfParameters);
  LBFGSBOptimizerv4::BoundValueType     bounds(numberOfParameters);
  unbounded.Fill(0);
  bounds.Fill(0.0);
  optimizer->SetBoundSelection(unbounded);
  optimizer->SetLowerBound(bounds);
  optimizer->SetUpperBound(bounds);
  optimizer->SetCostFunctionConvergenceFactor(1e7);
  optimizer->SetGradientConvergenceTolerance(1e-6);
  optimizer->SetNumberOfIterations(m_BSplineNumberOfIterations);
  optimizer->SetMaximumNumberOfFunctionEvaluations(2 * m_BSplineNumberOfIterations + 10);
  optimizer->SetMaximumNumberOfCorrections(7);

  auto registration = BSplineRegistrationType::New();
  registration->SetFixedImage(subject);
  registration->SetMovingImage(atlas);
  registration->SetMetric(metric);
  registration->SetOptimizer(optimizer);
  registration->SetMovingInitialTransform(m_AffineTransform);
  registration->SetInitialTransform(m_BSplineTransform);
  registration->InPlaceOn();
  registration->SetNumberOfLevels(1);
  registration->SetShrinkFactorsPerDimension(0, this->ShrinkFactorsFor(subject, m_BSplineLevelSpacing));
  typename BSplineRegistrationType::SmoothingSigmasArrayType sigmas(1);
  sigmas[0] = m_BSplineSmoothingSigma;
  registration->SetSmoothingSigmasPerLevel(sigmas);
  registration->SetSmoothingSigmasAreSpecifiedInPhysicalUnits(true);
  if (m_MetricSamplingStrategy != MetricSamplingStrategyEnum::NONE)
  {
    typename BSplineRegistrationType::MetricSamplingPercentageArrayType percentages(1);
    percentages[0] = this->SamplingPercentageFor(
      subject, registration->GetShrinkFactorsPerDimension(0), m_BSplineMaximumNumberOfMetricSamples);
    registration->SetMetricSamplingStrategy(m_MetricSamplingStrategy);
    registration->SetMetricSamplingPercentagePerLevel(percentages);
  }
  registration->MetricSamplingReinitializeSeed(m_RandomSeed + 1);

  const LBFGSBOptimizerv4 * optimizerPointer = optimizer.GetPointer();
  optimizer->AddObserver(IterationEvent(), [&](const EventObject &) {
    this->ReportIterationProgress(optimizerPointer, 0.5f, 0.45f, 1, m_BSplineNumberOfIterations, 0);
  });

  registration->Update();
  m_BSplineFinalMetricValue = optimizer->GetCurrentMetricValue();
  m_BSplineIterationsRun = static_cast<unsigned int>(optimizer->GetCurrentIteration());
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::PropagateAtlasBrain(const RealImageType * atlasBrain, const RealImageType * subject)
{
  // Propagate the atlas brain onto the subject grid.
  using ResampleType = ResampleImageFilter<RealImageType, RealImageType, double>;
  auto resample = ResampleType::New();
  resample->SetInput(atlasBrain);
  resample->SetTransform(this->MakeResamplingTransform(subject));
  resample->SetOutputParametersFromImage(subject);
  resample->SetDefaultPixelValue(0.0f);
  if (m_UseLinearMaskInterpolation)
  {
    resample->SetInterpolator(LinearInterpolateImageFunction<RealImageType, double>::New());
  }
  else
  {
    resample->SetInterpolator(NearestNeighborInterpolateImageFunction<RealImageType, double>::New());
  }
  resample->Update();

  TOutputImage * output = this->GetOutput();
  output->SetBufferedRegion(output->GetRequestedRegion());
  output->Allocate();
  SizeValueType brainVoxels = 0;
  {
    ImageRegionConstIterator<RealImageType> in(resample->GetOutput(), output->GetBufferedRegion());
    ImageRegionIterator<TOutputImage>       out(output, output->GetBufferedRegion());
    for (; !in.IsAtEnd(); ++in, ++out)
    {
      const bool brain = in.Get() >= 0.5f;
      out.Set(brain ? NumericTraits<OutputPixelType>::OneValue() : NumericTraits<OutputPixelType>::ZeroValue());
      brainVoxels += brain ? 1 : 0;
    }
  }
  double subjectVoxelVolume = 1.0;
  for (unsigned int d = 0; d < ImageDimension; ++d)
  {
    subjectVoxelVolume *= subject->GetSpacing()[d];
  }
  m_PropagatedBrainVolume = static_cast<double>(brainVoxels) * subjectVoxelVolume;
  const double ratio = m_PropagatedBrainVolume / m_AtlasBrainVolume;
  if (brainVoxels == 0 || ratio < m_MinimumVolumeRatio || ratio > m_MaximumVolumeRatio)
  {
    itkExceptionMacro("AtlasBrainMaskImageFilter: the registration failed: the propagated brain mask has "
                      << m_PropagatedBrainVolume << " mm^3, " << ratio << " times the atlas brain volume ("
                      << m_AtlasBrainVolume << " mm^3; plausible range " << m_MinimumVolumeRatio << " to "
                      << m_MaximumVolumeRatio
                      << "). Check that the subject is a T1-weighted head image with its spacing in mm, or supply "
                         "a brain mask instead of computing one.");
  }
}

template <typename TInputImage, typename TOutputImage>
void
AtlasBrainMaskImageFilter<TInputImage, TOutputImage>::PrintSelf(std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "AffineLevelSpacings (mm):";
  for (const double spacing : m_AffineLevelSpacings)
  {
    os << ' ' << spacing;
  }
  os << '\n' << indent << "AffineSmoothingSigmas (mm):";
  for (const double sigma : m_AffineSmoothingSigmas)
  {
    os << ' ' << sigma;
  }
  os << '\n';
  os << indent << "AffineNumberOfIterations: " << m_AffineNumberOfIterations << '\n';
  os << indent << "UseBSplineStage: " << m_UseBSplineStage << '\n';
  os << indent << "BSplineControlPointSpacing (mm): " << m_BSplineControlPointSpacing << '\n';
  os << indent << "BSplineLevelSpacing (mm): " << m_BSplineLevelSpacing << '\n';
  os << indent << "BSplineSmoothingSigma (mm): " << m_BSplineSmoothingSigma << '\n';
  os << indent << "BSplineNumberOfIterations: " << m_BSplineNumberOfIterations << '\n';
  os << indent << "NumberOfHistogramBins: " << m_NumberOfHistogramBins << '\n';
  os << indent << "MetricSamplingPercentage: " << m_MetricSamplingPercentage << '\n';
  os << indent << "MetricSamplingStrategy: " << m_MetricSamplingStrategy << '\n';
  os << indent << "MaximumNumberOfMetricSamples: " << m_MaximumNumberOfMetricSamples << '\n';
  os << indent << "BSplineMaximumNumberOfMetricSamples: " << m_BSplineMaximumNumberOfMetricSamples << '\n';
  os << indent << "RandomSeed: " << m_RandomSeed << '\n';
  os << indent << "MetricNumberOfWorkUnits: " << m_MetricNumberOfWorkUnits << '\n';
  os << indent << "UseLinearMaskInterpolation: " << m_UseLinearMaskInterpolation << '\n';
  os << indent << "MinimumVolumeRatio: " << m_MinimumVolumeRatio << '\n';
  os << indent << "MaximumVolumeRatio: " << m_MaximumVolumeRatio << '\n';
  os << indent << "AffineFinalMetricValue: " << m_AffineFinalMetricValue << '\n';
  os << indent << "BSplineFinalMetricValue: " << m_BSplineFinalMetricValue << '\n';
  os << indent << "AtlasBrainVolume (mm^3): " << m_AtlasBrainVolume << '\n';
  os << indent << "PropagatedBrainVolume (mm^3): " << m_PropagatedBrainVolume << '\n';
}

} // namespace itk

#endif

