// Atlas-based skull stripping: a brain mask for a T1 image that comes without
// one, by registering a T1 template (Colin27) to the image and propagating the
// template's brain mask.
#ifndef itkAtlasBrainMaskImageFilter_h
#define itkAtlasBrainMaskImageFilter_h

#include "itkAffineTransform.h"
#include "itkBSplineTransform.h"
#include "itkCompositeTransform.h"
#include "itkImage.h"
#include "itkImageRegistrationMethodv4.h"
#include "itkImageToImageFilter.h"

#include <vector>

namespace itk
{

/** \class AtlasBrainMaskImageFilter
 * \brief Brain mask of a T1-weighted MRI by registration of an atlas (template
 * T1 image with a brain mask), for subjects that come without a mask.
 *
 * Inputs:
 *  - primary input: the subject T1 image (any scalar pixel type, any grid);
 *  - SetAtlasImage(): the template T1 image, e.g. Colin27 `ch2.nii.gz`
 *    (Debian `mricron-data`, /usr/share/mricron/templates);
 *  - SetAtlasMaskImage(): the template's brain on the template grid; voxels
 *    > 0 are brain, so the brain-extracted `ch2bet.nii.gz` works as it is.
 *
 * Output: the brain mask (0 background, 1 brain) on the subject's grid.
 *
 * Method (ITK's v4 registration framework; the subject is the fixed image,
 * the atlas the moving image, so every transform maps subject points to
 * atlas points):
 *  1. initialisation: CenteredTransformInitializer on image moments (centres
 *     of mass aligned; recovers shifts of several cm);
 *  2. affine stage: Mattes mutual information, conjugate-gradient line search
 *     with parameter scales from physical shifts, on a pyramid of registration
 *     grids of AffineLevelSpacings mm (default 4, 2) smoothed with
 *     AffineSmoothingSigmas mm (default 2, 1);
 *  3. B-spline stage (SetUseBSplineStage(false) skips it): cubic
 *     BSplineTransform on a coarse control mesh (BSplineControlPointSpacing,
 *     default 50 mm, over the subject domain), L-BFGS-B, few iterations, on a
 *     BSplineLevelSpacing (default 4 mm) grid, composed after the affine;
 *  4. the atlas mask (as 0/1) is resampled through the composite transform
 *     onto the subject grid. Default: linear interpolation thresholded at 0.5,
 *     which gives a smoother boundary than nearest neighbour on a subject
 *     grid finer or oblique with respect to the atlas grid;
 *     SetUseLinearMaskInterpolation(false) uses nearest neighbour. For this
 *     resampling only, the B-spline is sampled into a displacement field of
 *     BSplineControlPointSpacing / 10 spacing (interpolation error far below
 *     a voxel, ~7x faster than evaluating the B-spline per voxel).
 *
 * Metric samples: MetricSamplingPercentage (default 0.2) of the voxels of the
 * registration grid, at most MaximumNumberOfMetricSamples (default 20000;
 * B-spline stage BSplineMaximumNumberOfMetricSamples, default 10000), chosen
 * with MetricSamplingStrategy (default RANDOM) from a FIXED seed (RandomSeed,
 * default 121212), so results repeat exactly.
 * The metric runs in MetricNumberOfWorkUnits (default 1) work units: ITK's
 * Mattes metric reduces per-thread joint-histogram derivatives in the order in
 * which threads finish, so more work units trade bitwise repeatability (run to
 * run and across thread counts) for speed. Smoothing and resampling stay
 * multithreaded (they are repeatable).
 *
 * Errors (itk::ExceptionObject, message names the input and what to do):
 *  - atlas image or atlas mask not set;
 *  - atlas mask without foreground (no voxel > 0);
 *  - atlas mask not on the atlas grid (size, spacing, origin or direction
 *    differ beyond ITK's global coordinate/direction tolerances);
 *  - NaN or infinite values in the subject or the atlas; a constant subject;
 *  - registration failure: a propagated mask whose volume is below
 *    MinimumVolumeRatio (default 0.3) or above MaximumVolumeRatio (default 3)
 *    times the atlas brain volume (mm^3), or empty.
 *
 * Units: mm (physical space of the images, LPS as ITK reads them).
 * Progress: initialisation 2%, affine stage up to 50%, B-spline stage up to
 * 95%, mask propagation 100% (per optimizer iteration inside the stages).
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TInputImage, typename TOutputImage = Image<unsigned char, TInputImage::ImageDimension>>
class ITK_TEMPLATE_EXPORT AtlasBrainMaskImageFilter : public ImageToImageFilter<TInputImage, TOutputImage>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(AtlasBrainMaskImageFilter);

  using Self = AtlasBrainMaskImageFilter;
  using Superclass = ImageToImageFilter<TInputImage, TOutputImage>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(AtlasBrainMaskImageFilter, ImageToImageFilter);

  static constexpr unsigned int ImageDimension = TInputImage::ImageDimension;

  using InputImageType = TInputImage;
  using OutputImageType = TOutputImage;
  using OutputPixelType = typename TOutputImage::PixelType;
  /** The atlas T1 and its mask are read with the same pixel type as the subject. */
  using AtlasImageType = TInputImage;
  using AtlasMaskImageType = TInputImage;
  /** Registration works on float copies of the images. */
  using RealImageType = Image<float, ImageDimension>;

  static constexpr unsigned int SplineOrder = 3;
  using AffineTransformType = AffineTransform<double, ImageDimension>;
  using BSplineTransformType = BSplineTransform<double, ImageDimension, SplineOrder>;
  using CompositeTransformType = CompositeTransform<double, ImageDimension>;
  using MetricSamplingStrategyEnum = ImageRegistrationMethodv4Enums::MetricSamplingStrategy;

  /** Template T1 image (moving image of the registration). Required. */
  itkSetInputMacro(AtlasImage, AtlasImageType);
  itkGetInputMacro(AtlasImage, AtlasImageType);
  /** Template brain mask (> 0 is brain) on the template grid. Required. */
  itkSetInputMacro(AtlasMaskImage, AtlasMaskImageType);
  itkGetInputMacro(AtlasMaskImage, AtlasMaskImageType);

  /** Registration grid spacing per affine level (mm, coarse to fine; default
   * {4, 2}). The shrink factor per axis is round(level spacing / voxel
   * spacing), at least 1, so anisotropic images shrink sensibly. */
  void
  SetAffineLevelSpacings(const std::vector<double> & spacings)
  {
    m_AffineLevelSpacings = spacings;
    this->Modified();
  }
  const std::vector<double> &
  GetAffineLevelSpacings() const
  {
    return m_AffineLevelSpacings;
  }
  /** Gaussian smoothing sigma per affine level (mm; default {2, 1}); same length
   * as AffineLevelSpacings. */
  void
  SetAffineSmoothingSigmas(const std::vector<double> & sigmas)
  {
    m_AffineSmoothingSigmas = sigmas;
    this->Modified();
  }
  const std::vector<double> &
  GetAffineSmoothingSigmas() const
  {
    return m_AffineSmoothingSigmas;
  }
  /** Maximum optimizer iterations per affine level (default 100). */
  itkSetMacro(AffineNumberOfIterations, unsigned int);
  itkGetConstMacro(AffineNumberOfIterations, unsigned int);

  /** Run the B-spline stage after the affine one (default true). */
  itkSetMacro(UseBSplineStage, bool);
  itkGetConstMacro(UseBSplineStage, bool);
  itkBooleanMacro(UseBSplineStage);
  /** B-spline control point spacing over the subject domain (mm, default 50). */
  itkSetMacro(BSplineControlPointSpacing, double);
  itkGetConstMacro(BSplineControlPointSpacing, double);
  /** Registration grid spacing of the B-spline stage (mm, default 4). */
  itkSetMacro(BSplineLevelSpacing, double);
  itkGetConstMacro(BSplineLevelSpacing, double);
  /** Smoothing sigma of the B-spline stage (mm, default 2). */
  itkSetMacro(BSplineSmoothingSigma, double);
  itkGetConstMacro(BSplineSmoothingSigma, double);
  /** Maximum L-BFGS-B iterations of the B-spline stage (default 20). */
  itkSetMacro(BSplineNumberOfIterations, unsigned int);
  itkGetConstMacro(BSplineNumberOfIterations, unsigned int);

  /** Mattes mutual information histogram bins (default 50). */
  itkSetMacro(NumberOfHistogramBins, unsigned int);
  itkGetConstMacro(NumberOfHistogramBins, unsigned int);
  /** Fraction of registration-grid voxels used as metric samples (0, 1]
   * (default 0.2); ignored when the strategy is NONE (all voxels). */
  itkSetMacro(MetricSamplingPercentage, double);
  itkGetConstMacro(MetricSamplingPercentage, double);
  /** Upper bound on the metric samples per level (default 20000; 0: no
   * bound): caps the cost of the fine levels of large images, where the
   * sampling percentage alone would give hundreds of thousands of samples. */
  itkSetMacro(MaximumNumberOfMetricSamples, SizeValueType);
  itkGetConstMacro(MaximumNumberOfMetricSamples, SizeValueType);
  /** The same bound for the B-spline stage (default 10000): its v4 metric
   * costs O(samples x B-spline parameters) per evaluation. */
  itkSetMacro(BSplineMaximumNumberOfMetricSamples, SizeValueType);
  itkGetConstMacro(BSplineMaximumNumberOfMetricSamples, SizeValueType);
  /** RANDOM (default), REGULAR or NONE. */
  itkSetEnumMacro(MetricSamplingStrategy, MetricSamplingStrategyEnum);
  itkGetEnumMacro(MetricSamplingStrategy, MetricSamplingStrategyEnum);
  /** Seed of the metric sampling (default 121212); fixed so runs repeat. */
  itkSetMacro(RandomSeed, int);
  itkGetConstMacro(RandomSeed, int);
  /** Work units of the metric (default 1, bitwise repeatable; see class doc). */
  itkSetClampMacro(MetricNumberOfWorkUnits, unsigned int, 1, ITK_MAX_THREADS);
  itkGetConstMacro(MetricNumberOfWorkUnits, unsigned int);

  /** Resample the atlas mask linearly and threshold at 0.5 (default true) or
   * with nearest neighbour (false). */
  itkSetMacro(UseLinearMaskInterpolation, bool);
  itkGetConstMacro(UseLinearMaskInterpolation, bool);
  itkBooleanMacro(UseLinearMaskInterpolation);

  /** Plausible propagated brain volume relative to the atlas brain volume
   * (defaults 0.3 and 3); outside, the registration is reported as failed. */
  itkSetMacro(MinimumVolumeRatio, double);
  itkGetConstMacro(MinimumVolumeRatio, double);
  itkSetMacro(MaximumVolumeRatio, double);
  itkGetConstMacro(MaximumVolumeRatio, double);

  /** Results of the last Update(). The transforms map subject (fixed) points
   * to atlas (moving) points. The B-spline transform is null when the stage
   * was skipped; the composite holds the affine, then (applied first) the
   * B-spline transform. */
  const AffineTransformType *
  GetAffineTransform() const
  {
    return m_AffineTransform.GetPointer();
  }
  const BSplineTransformType *
  GetBSplineTransform() const
  {
    return m_BSplineTransform.GetPointer();
  }
  const CompositeTransformType *
  GetCompositeTransform() const
  {
    return m_CompositeTransform.GetPointer();
  }
  /** Final Mattes metric value (negative mutual information) per stage. */
  itkGetConstMacro(AffineFinalMetricValue, double);
  itkGetConstMacro(BSplineFinalMetricValue, double);
  /** Optimizer iterations run in the last level of each stage. */
  itkGetConstMacro(AffineIterationsRun, unsigned int);
  itkGetConstMacro(BSplineIterationsRun, unsigned int);
  /** Brain volume of the atlas mask and of the propagated mask (mm^3). */
  itkGetConstMacro(AtlasBrainVolume, double);
  itkGetConstMacro(PropagatedBrainVolume, double);

protected:
  AtlasBrainMaskImageFilter();
  ~AtlasBrainMaskImageFilter() override = default;

  void
  PrintSelf(std::ostream & os, Indent indent) const override;

  /** Checks that the atlas inputs are set, in addition to the primary input. */
  void
  VerifyPreconditions() ITKv5_CONST override;

  /** The inputs live on different grids: only the atlas mask must share the
   * atlas grid. */
  void
  VerifyInputInformation() ITKv5_CONST override;

  /** Registration needs every input whole. */
  void
  GenerateInputRequestedRegion() override;

  void
  EnlargeOutputRequestedRegion(DataObject * output) override;

  void
  GenerateData() override;

private:
  /** Throws naming a setting out of range. */
  void
  CheckSettings() const;

  /** The atlas brain (mask > 0) as a 0/1 float image; sets m_AtlasBrainVolume. */
  typename RealImageType::Pointer
  MakeAtlasBrain();

  /** Progress of a stage that spans [start, start + span], `levels` levels
   * of `iterationsPerLevel` iterations, after an iteration of `optimizer`. */
  void
  ReportIterationProgress(const Object * optimizer, float start, float span, unsigned int levels,
                          unsigned int iterationsPerLevel, unsigned int level);

  /** Moments initialisation, then the affine stage (m_AffineTransform). */
  void
  RegisterAffine(const RealImageType * subject, const RealImageType * atlas);

  /** The B-spline stage after the affine one (m_BSplineTransform). */
  void
  RegisterBSpline(const RealImageType * subject, const RealImageType * atlas);

  /** The atlas brain resampled onto the subject's grid: the output; checks its volume. */
  void
  PropagateAtlasBrain(const RealImageType * atlasBrain, const RealImageType * subject);

  typename RealImageType::Pointer
  MakeRealImage(const InputImageType * image, const char * role) const;

  /** Shrink factors per axis that bring the image's spacing near targetSpacing (mm). */
  typename ImageRegistrationMethodv4<RealImageType, RealImageType>::ShrinkFactorsPerDimensionContainerType
  ShrinkFactorsFor(const RealImageType * image, double targetSpacing) const;

  /** Metric sampling fraction of a registration grid shrunk by `factors`,
   * MetricSamplingPercentage bounded by maximumNumberOfSamples (0: none). */
  double
  SamplingPercentageFor(
    const RealImageType * image,
    const typename ImageRegistrationMethodv4<RealImageType, RealImageType>::ShrinkFactorsPerDimensionContainerType &
      factors,
    SizeValueType maximumNumberOfSamples) const;

  /** The composite transform for resampling the mask, with the B-spline
   * replaced by a dense displacement field (see the .hxx). */
  typename CompositeTransformType::Pointer
  MakeResamplingTransform(const RealImageType * subject) const;

  std::vector<double>        m_AffineLevelSpacings{ 4.0, 2.0 };
  std::vector<double>        m_AffineSmoothingSigmas{ 2.0, 1.0 };
  unsigned int               m_AffineNumberOfIterations{ 100 };
  bool                       m_UseBSplineStage{ true };
  double                     m_BSplineControlPointSpacing{ 50.0 };
  double                     m_BSplineLevelSpacing{ 4.0 };
  double                     m_BSplineSmoothingSigma{ 2.0 };
  unsigned int               m_BSplineNumberOfIterations{ 20 };
  unsigned int               m_NumberOfHistogramBins{ 50 };
  double                     m_MetricSamplingPercentage{ 0.2 };
  SizeValueType              m_MaximumNumberOfMetricSamples{ 20000 };
  SizeValueType              m_BSplineMaximumNumberOfMetricSamples{ 10000 };
  MetricSamplingStrategyEnum m_MetricSamplingStrategy{ MetricSamplingStrategyEnum::RANDOM };
  int                        m_RandomSeed{ 121212 };
  unsigned int               m_MetricNumberOfWorkUnits{ 1 };
  bool                       m_UseLinearMaskInterpolation{ true };
  double                     m_MinimumVolumeRatio{ 0.3 };
  double                     m_MaximumVolumeRatio{ 3.0 };

  typename AffineTransformType::Pointer    m_AffineTransform;
  typename BSplineTransformType::Pointer   m_BSplineTransform;
  typename CompositeTransformType::Pointer m_CompositeTransform;
  double                                   m_AffineFinalMetricValue{ 0.0 };
  double                                   m_BSplineFinalMetricValue{ 0.0 };
  unsigned int                             m_AffineIterationsRun{ 0 };
  unsigned int                             m_BSplineIterationsRun{ 0 };
  double                                   m_AtlasBrainVolume{ 0.0 };
  double                                   m_PropagatedBrainVolume{ 0.0 };
};

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkAtlasBrainMaskImageFilter.hxx"
#endif

#endif
