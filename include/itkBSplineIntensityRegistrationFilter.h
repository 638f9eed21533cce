// Intensity-based B-spline registration: the baseline that validation
// pipelines run on the same image pair as the biomechanical registration.
#ifndef itkBSplineIntensityRegistrationFilter_h
#define itkBSplineIntensityRegistrationFilter_h

#include "itkBSplineTransform.h"
#include "itkImage.h"
#include "itkImageRegistrationMethodv4.h"
#include "itkImageToImageFilter.h"
#include "itkImageToImageMetricv4.h"
#include "itkSpatialObject.h"

#include <string>
#include <vector>

namespace itk
{

/** \class BSplineIntensityRegistrationFilter
 * \brief Deformable registration of a moving (preoperative) image to a fixed
 * (intraoperative) image with a cubic B-spline transform, ITK's v4
 * registration framework, a multi-resolution pyramid and L-BFGS-B; the output
 * is the moving image warped onto the fixed image's grid.
 *
 * Inputs:
 *  - SetMovingImage() (the primary input, same as SetInput()): the image to
 *    warp, e.g. the preoperative MRI. Required.
 *  - SetFixedImage(): the reference, e.g. the intraoperative MRI. Required.
 *    Any grid: the images only need to overlap in physical space.
 *  - SetFixedMask(): optional; voxels > 0 are inside. Only metric samples
 *    inside the mask count (e.g. the brain). Any grid (physical space).
 * Scalar pixel types; the registration works on float copies.
 *
 * Output: the moving image resampled onto the fixed image's grid through
 * the transform (linear interpolation; DefaultPixelValue, default 0, outside
 * the moving image; integer pixel types are rounded, not truncated).
 *
 * Method:
 *  - Transform: BSplineTransform of order 3 over the fixed image's domain
 *    (its physical extent, direction cosines respected) that maps fixed
 *    points to moving points (the resampling transform). Points outside the
 *    domain are not moved (they lie outside the output grid).
 *  - Start: TranslationInitialization Identity (default: the images are
 *    aligned in physical space, as navigated clinical pairs are) or Moments
 *    (centres of mass of the whole images aligned, masks ignored; for images
 *    whose files share no physical space, e.g. ITK's example slices, whose
 *    moving files carry a 20-pixel border). Moments is not the default
 *    because an intraoperative field of view that covers part of the head
 *    moves the centre of mass by centimetres.
 *  - Translation stage (UseTranslationStage, default true): a
 *    TranslationTransform registered with the same metric and pyramid by
 *    regular-step gradient descent (steps in mm: the level's voxel size,
 *    halved at each reversal down to 0.01 mm; TranslationNumberOfIterations,
 *    default 100 per level). A B-spline from the identity does not recover a
 *    rigid shift of 1-2 cm (its control points are pulled apart into a
 *    local optimum); a translation does, and is folded into the B-spline
 *    exactly (every coefficient equal to it), so the result is one
 *    BSplineTransform. Costs about 5% of the time.
 *  - Metric: MetricType MattesMutualInformation (default; any modality pair)
 *    with NumberOfHistogramBins (default 50), or Correlation
 *    (CorrelationImageToImageMetricv4, value -r^2; same modality).
 *  - Pyramid: ShrinkFactors (default {4, 2, 1}) and SmoothingSigmas (mm,
 *    default {2, 1, 0}), one entry per level, coarse to fine. A factor applies
 *    to the finest axis; coarser axes shrink proportionally less (an axis
 *    with spacing s shrinks by round(f * smallest spacing / s), at least 1)
 *    and every axis keeps at least 4 voxels.
 *  - Mesh: ControlPointSpacing (mm, default 20) is the spacing of the final
 *    mesh: round(extent / spacing) cells per axis, at least 1. With
 *    RefineMeshPerLevel (default true) the mesh is coarser by 2 per level
 *    below the last (e.g. 80, 40, 20 mm for three levels) and refined between
 *    levels with BSplineTransformParametersAdaptor: the coarse levels fit
 *    the large, smooth part of the deformation with few parameters, and the
 *    fine mesh starts near the answer (slightly better and no slower than
 *    the final mesh at every level on the example slices).
 *  - Optimizer: L-BFGS-B (itk::QuietLBFGSBOptimizerv4, unbounded), at most
 *    NumberOfIterations per level (default 100 at the coarsest level, halved
 *    at each finer one: {100, 50, 25}; one value applies to every level) and
 *    2 x iterations + 10 metric evaluations;
 *    stops earlier when the relative metric change is below
 *    CostFunctionConvergenceFactor (default 1e7) times machine precision.
 *    L-BFGS-B needs no learning rate or parameter scales, which for a
 *    B-spline (thousands of parameters of equal kind, mm) is what makes it
 *    the standard choice in ITK's B-spline examples.
 *  - Metric samples: MetricSamplingStrategy (RANDOM by default, REGULAR, or
 *    NONE: every voxel) with MetricSamplingPercentage (default 0.2) of the
 *    fixed voxels (of the level's shrunk grid; inside the mask when one is
 *    set), at most MaximumNumberOfMetricSamples (default 20000; 0: no limit)
 *    inside the mask: the v4 metric costs O(samples x B-spline parameters)
 *    per evaluation, which the limit bounds for 3D images. The samples are
 *    drawn from RandomSeed (default 121212), fixed so runs repeat.
 *  - The metric runs in MetricNumberOfWorkUnits work units (default 1): ITK's
 *    metrics add per-unit partial sums in an order that depends on the
 *    number of units (and for Mattes, on which unit finishes first), so 1
 *    gives the same transform bit for bit on every run and for every thread
 *    count; more units are faster on several cores (2 units on 2 cores:
 *    1.5x on the 2D slices, 1.8x on Colin27; docs/bspline-registration.md)
 *    but results then vary in the last bits between runs and thread counts.
 *    Smoothing and warping stay multithreaded (repeatable).
 *
 * Results after Update(): GetTransform() (fixed -> moving points),
 * GetFinalMetricValue() (the metric at the last level's samples and
 * smoothing: negative mutual information, or -r^2), GetInitialTranslation()
 * and GetTranslationIterationsRun(), GetIterationsPerLevel()
 * and GetIterationsRun() (total), GetMeshSizesPerLevel(),
 * GetStopConditionDescription() (last level), GetElapsedSeconds() (wall time
 * of the registration, input checks included, warp excluded) and
 * GetWarpElapsedSeconds().
 *
 * Progress: per optimizer iteration: translation stage up to 10% (when on),
 * B-spline levels up to 95%; the warp ends at 100%.
 *
 * Errors (itk::ExceptionObject naming the input or parameter and what to do):
 * missing fixed or moving image; NaN or infinite voxels; a constant image;
 * fewer than 4 voxels along an axis; a fixed mask without voxels > 0 or
 * outside the fixed image; ControlPointSpacing
 * <= 0; ShrinkFactors empty or holding 0; SmoothingSigmas negative or of
 * another length than ShrinkFactors; NumberOfIterations of another length
 * (other than 0 or 1) or holding 0; MetricSamplingPercentage outside (0, 1]; fewer than 5
 * histogram bins; and registration failures (e.g. images that do not
 * overlap), with ITK's message and the level.
 *
 * Units: mm (physical space, LPS as ITK reads images).
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TFixedImage, typename TMovingImage = TFixedImage,
          typename TMaskImage = Image<unsigned char, TFixedImage::ImageDimension>>
class ITK_TEMPLATE_EXPORT BSplineIntensityRegistrationFilter : public ImageToImageFilter<TMovingImage, TMovingImage>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BSplineIntensityRegistrationFilter);

  using Self = BSplineIntensityRegistrationFilter;
  using Superclass = ImageToImageFilter<TMovingImage, TMovingImage>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BSplineIntensityRegistrationFilter, ImageToImageFilter);

  static constexpr unsigned int ImageDimension = TFixedImage::ImageDimension;
  static_assert(TMovingImage::ImageDimension == ImageDimension && TMaskImage::ImageDimension == ImageDimension,
                "fixed image, moving image and mask must have the same dimension");

  using FixedImageType = TFixedImage;
  using MovingImageType = TMovingImage;
  using MaskImageType = TMaskImage;
  using OutputImageType = TMovingImage;
  using OutputPixelType = typename TMovingImage::PixelType;
  /** Registration works on float copies of the images. */
  using RealImageType = Image<float, ImageDimension>;

  static constexpr unsigned int SplineOrder = 3;
  using BSplineTransformType = BSplineTransform<double, ImageDimension, SplineOrder>;
  using MeshSizeType = typename BSplineTransformType::MeshSizeType;
  using MetricSamplingStrategyEnum = ImageRegistrationMethodv4Enums::MetricSamplingStrategy;
  using TranslationType = Vector<double, ImageDimension>;

  enum class MetricType
  {
    MattesMutualInformation,
    Correlation
  };
  enum class TranslationInitializationType
  {
    Identity,
    Moments
  };

  /** The image to warp (primary input). Required. */
  void
  SetMovingImage(const MovingImageType * image)
  {
    this->SetInput(image);
  }
  const MovingImageType *
  GetMovingImage() const
  {
    return this->GetInput();
  }
  /** The reference image; the output lies on its grid. Required. */
  itkSetInputMacro(FixedImage, FixedImageType);
  itkGetInputMacro(FixedImage, FixedImageType);
  /** Optional mask of the fixed image (> 0 inside) restricting the metric samples. */
  itkSetInputMacro(FixedMask, MaskImageType);
  itkGetInputMacro(FixedMask, MaskImageType);

  /** MattesMutualInformation (default) or Correlation. */
  itkSetEnumMacro(Metric, MetricType);
  itkGetEnumMacro(Metric, MetricType);

  /** Control point spacing of the final B-spline mesh (mm, default 20). */
  itkSetMacro(ControlPointSpacing, double);
  itkGetConstMacro(ControlPointSpacing, double);

  /** Shrink factor per level, coarse to fine (default {4, 2, 1}). */
  void
  SetShrinkFactors(const std::vector<unsigned int> & factors)
  {
    m_ShrinkFactors = factors;
    this->Modified();
  }
  const std::vector<unsigned int> &
  GetShrinkFactors() const
  {
    return m_ShrinkFactors;
  }
  /** Gaussian smoothing sigma per level (mm, default {2, 1, 0}); same length as ShrinkFactors. */
  void
  SetSmoothingSigmas(const std::vector<double> & sigmas)
  {
    m_SmoothingSigmas = sigmas;
    this->Modified();
  }
  const std::vector<double> &
  GetSmoothingSigmas() const
  {
    return m_SmoothingSigmas;
  }
  /** Maximum L-BFGS-B iterations per level: one value for every level, one
   * per level, or none (default): 100 at the coarsest level, halved at each
   * finer one, at least 10 ({100, 50, 25} for three levels). */
  void
  SetNumberOfIterations(const std::vector<unsigned int> & iterations)
  {
    m_NumberOfIterations = iterations;
    this->Modified();
  }
  void
  SetNumberOfIterations(unsigned int iterations)
  {
    this->SetNumberOfIterations(std::vector<unsigned int>{ iterations });
  }
  const std::vector<unsigned int> &
  GetNumberOfIterations() const
  {
    return m_NumberOfIterations;
  }

  /** Start of the translation: Identity (default; images already aligned in
   * physical space, as navigated clinical pairs are) or Moments (centres of
   * mass aligned; for images whose files share no physical space). */
  itkSetEnumMacro(TranslationInitialization, TranslationInitializationType);
  itkGetEnumMacro(TranslationInitialization, TranslationInitializationType);
  /** Register a translation first and start the B-spline from it (default true). */
  itkSetMacro(UseTranslationStage, bool);
  itkGetConstMacro(UseTranslationStage, bool);
  itkBooleanMacro(UseTranslationStage);
  /** Maximum gradient-descent iterations per level of the translation stage (default 100). */
  itkSetMacro(TranslationNumberOfIterations, unsigned int);
  itkGetConstMacro(TranslationNumberOfIterations, unsigned int);

  /** Refine the B-spline mesh by 2 per level up to ControlPointSpacing (default true). */
  itkSetMacro(RefineMeshPerLevel, bool);
  itkGetConstMacro(RefineMeshPerLevel, bool);
  itkBooleanMacro(RefineMeshPerLevel);

  /** L-BFGS-B stops when the relative metric change is below this factor
   * times machine precision (default 1e7, i.e. about 2e-9). */
  itkSetMacro(CostFunctionConvergenceFactor, double);
  itkGetConstMacro(CostFunctionConvergenceFactor, double);

  /** Mattes histogram bins (default 50). */
  itkSetMacro(NumberOfHistogramBins, unsigned int);
  itkGetConstMacro(NumberOfHistogramBins, unsigned int);
  /** Fraction of the fixed voxels of each level used as metric samples, (0, 1] (default 0.2). */
  itkSetMacro(MetricSamplingPercentage, double);
  itkGetConstMacro(MetricSamplingPercentage, double);
  /** Upper bound on the metric samples per level (default 20000; 0: none). */
  itkSetMacro(MaximumNumberOfMetricSamples, SizeValueType);
  itkGetConstMacro(MaximumNumberOfMetricSamples, SizeValueType);
  /** RANDOM (default), REGULAR or NONE (every voxel). */
  itkSetEnumMacro(MetricSamplingStrategy, MetricSamplingStrategyEnum);
  itkGetEnumMacro(MetricSamplingStrategy, MetricSamplingStrategyEnum);
  /** Seed of the metric sampling (default 121212); fixed so runs repeat. */
  itkSetMacro(RandomSeed, int);
  itkGetConstMacro(RandomSeed, int);
  /** Work units of the metric (default 1: bitwise repeatable; see the class doc). */
  itkSetClampMacro(MetricNumberOfWorkUnits, unsigned int, 1, ITK_MAX_THREADS);
  itkGetConstMacro(MetricNumberOfWorkUnits, unsigned int);

  /** Output value where the transform maps outside the moving image (default 0). */
  itkSetMacro(DefaultPixelValue, OutputPixelType);
  itkGetConstMacro(DefaultPixelValue, OutputPixelType);

  /** Results of the last Update(). The transform maps fixed points to moving points. */
  const BSplineTransformType *
  GetTransform() const
  {
    return m_Transform.GetPointer();
  }
  itkGetConstMacro(FinalMetricValue, double);
  /** Translation the B-spline started from: the moments' offset refined by
   * the translation stage (mm, fixed -> moving; zero when both are off). */
  itkGetConstReferenceMacro(InitialTranslation, TranslationType);
  /** Iterations of the translation stage over all levels. */
  itkGetConstMacro(TranslationIterationsRun, unsigned int);
  /** L-BFGS-B iterations run at each level. */
  const std::vector<unsigned int> &
  GetIterationsPerLevel() const
  {
    return m_IterationsPerLevel;
  }
  /** The iteration budget of a level (see SetNumberOfIterations). */
  unsigned int
  IterationsAtLevel(unsigned int level) const;
  /** Total iterations over the levels. */
  unsigned int
  GetIterationsRun() const;
  /** B-spline mesh (cells per axis) of each level. */
  const std::vector<MeshSizeType> &
  GetMeshSizesPerLevel() const
  {
    return m_MeshSizesPerLevel;
  }
  /** Why the optimizer stopped at the last level. */
  const std::string &
  GetStopConditionDescription() const
  {
    return m_StopConditionDescription;
  }
  /** Wall time of the registration (s), input checks included, final warp excluded. */
  itkGetConstMacro(ElapsedSeconds, double);
  /** Wall time of the final warp (s). */
  itkGetConstMacro(WarpElapsedSeconds, double);

protected:
  BSplineIntensityRegistrationFilter();
  ~BSplineIntensityRegistrationFilter() override = default;

  void
  PrintSelf(std::ostream & os, Indent indent) const override;

  /** Clear messages when the fixed or moving image is missing. */
  void
  VerifyPreconditions() ITKv5_CONST override;

  /** The inputs live on different grids; nothing to compare. */
  void
  VerifyInputInformation() ITKv5_CONST override
  {}

  /** The output lies on the fixed image's grid. */
  void
  GenerateOutputInformation() override;

  /** Registration needs every input whole. */
  void
  GenerateInputRequestedRegion() override;

  void
  EnlargeOutputRequestedRegion(DataObject * output) override;

  void
  GenerateData() override;

private:
  using RegistrationType = ImageRegistrationMethodv4<RealImageType, RealImageType, BSplineTransformType>;
  using ShrinkFactorsType = typename RegistrationType::ShrinkFactorsPerDimensionContainerType;
  using ImageMetricType = ImageToImageMetricv4<RealImageType, RealImageType>;

  /** Share of the progress taken by the translation stage. */
  static constexpr float TranslationProgress = 0.1f;

  /** Checks the parameters; throws naming the first that is wrong. */
  void
  VerifyParameters() const;

  template <typename TImage>
  typename RealImageType::Pointer
  MakeRealImage(const TImage * image, const char * role) const;

  /** Throws unless both images have at least 4 voxels per axis. */
  void
  CheckImageSizes(const RealImageType * fixed, const RealImageType * moving) const;

  /** The fixed mask as a spatial object (voxels > 0 inside; null without a
   *  mask) and the share of the fixed domain it covers; throws when it holds
   *  no voxel inside the fixed image (no metric sample could be drawn). */
  typename SpatialObject<ImageDimension>::Pointer
  MakeMaskObject(const RealImageType * fixed, double & maskFraction) const;

  /** m_Transform over the fixed domain at the coarsest mesh, moved by the
   *  initial translation (moments, translation stage). */
  void
  InitializeTransform(const RealImageType * fixed, const RealImageType * moving,
                      const SpatialObject<ImageDimension> * mask, double maskFraction);

  ShrinkFactorsType
  ShrinkFactorsFor(const RealImageType * image, unsigned int factor) const;

  double
  SamplingPercentageFor(const RealImageType * image, const ShrinkFactorsType & factors, double maskFraction) const;

  /** A new metric of the chosen type, its work units and the mask set. */
  typename ImageMetricType::Pointer
  MakeMetric(const SpatialObject<ImageDimension> * mask) const;

  /** Levels, shrink factors, smoothing and metric sampling of a registration. */
  template <typename TRegistration>
  void
  SetUpPyramid(TRegistration * registration, const RealImageType * fixed, double maskFraction) const;

  /** The translation stage; returns the translation (mm, fixed -> moving). */
  TranslationType
  RegisterTranslation(const RealImageType * fixed, const RealImageType * moving,
                      const SpatialObject<ImageDimension> * mask, double maskFraction, const TranslationType & initial);

  /** B-spline mesh (cells per axis) of every level over `fixed`. */
  std::vector<MeshSizeType>
  MeshSizesFor(const RealImageType * fixed) const;

  /** The warp of the moving image onto the fixed grid into the output. */
  void
  Warp(const RealImageType * movingReal);

  MetricType                    m_Metric{ MetricType::MattesMutualInformation };
  double                        m_ControlPointSpacing{ 20.0 };
  std::vector<unsigned int>     m_ShrinkFactors{ 4, 2, 1 };
  std::vector<double>           m_SmoothingSigmas{ 2.0, 1.0, 0.0 };
  std::vector<unsigned int>     m_NumberOfIterations;
  TranslationInitializationType m_TranslationInitialization{ TranslationInitializationType::Identity };
  bool                          m_UseTranslationStage{ true };
  unsigned int                  m_TranslationNumberOfIterations{ 100 };
  bool                          m_RefineMeshPerLevel{ true };
  double                        m_CostFunctionConvergenceFactor{ 1e7 };
  unsigned int                  m_NumberOfHistogramBins{ 50 };
  double                        m_MetricSamplingPercentage{ 0.2 };
  SizeValueType                 m_MaximumNumberOfMetricSamples{ 20000 };
  MetricSamplingStrategyEnum    m_MetricSamplingStrategy{ MetricSamplingStrategyEnum::RANDOM };
  int                           m_RandomSeed{ 121212 };
  unsigned int                  m_MetricNumberOfWorkUnits{ 1 };
  OutputPixelType               m_DefaultPixelValue{};

  typename BSplineTransformType::Pointer m_Transform;
  double                                 m_FinalMetricValue{ 0.0 };
  TranslationType                        m_InitialTranslation{};
  unsigned int                           m_TranslationIterationsRun{ 0 };
  std::vector<unsigned int>              m_IterationsPerLevel;
  std::vector<MeshSizeType>              m_MeshSizesPerLevel;
  std::string                            m_StopConditionDescription;
  double                                 m_ElapsedSeconds{ 0.0 };
  double                                 m_WarpElapsedSeconds{ 0.0 };
};

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkBSplineIntensityRegistrationFilter.hxx"
#endif

#endif
