// Edge-based Hausdorff distance between an intraoperative image and a
// registered preoperative image: how far the edges of one lie from the edges
// of the other, as a percentile curve (Mostayed et al. 2013; Garlapati et al.
// 2015; Huttenlocher's generalised Hausdorff distance).
#ifndef itkEdgeHausdorffDistanceImageFilter_h
#define itkEdgeHausdorffDistanceImageFilter_h

#include "itkImage.h"
#include "itkImageToImageFilter.h"
#include "itkRGBPixel.h"

#include <cstddef>
#include <string>
#include <vector>

namespace itk
{

/** Result of an edge-based Hausdorff evaluation (distances in mm). */
struct EdgeHausdorffResult
{
  // distance at percentile K = 1..100 is element K-1; nearest-rank percentile of the directed distances
  std::vector<double> fixedToMoving; // for each fixed-image edge pixel, distance to the nearest moving edge
  std::vector<double> movingToFixed;
  std::vector<double> symmetric;                          // max of the two directed values at each K (Huttenlocher)
  double              distanceThreshold = 1.7;            // mm
  double              fractionFixedWithinThreshold = 0.0; // fraction of fixed edge pixels with distance <= threshold
  double              fractionMovingWithinThreshold = 0.0;
  double              fractionWithinThreshold = 0.0; // both edge sets pooled
  // Edge pixels whose distances make the curves (slice mode: those of the evaluated slices;
  // when valid is false: all edge pixels found within the mask).
  std::size_t fixedEdgePixels = 0;
  std::size_t movingEdgePixels = 0;
  std::size_t slicesEvaluated = 0; // slice mode; 1 in whole-image mode (0 when valid is false)
  std::size_t slicesSkipped = 0;   // slice mode: slices with edges in only one image (see below)
  bool        valid = false;       // false when an edge set is empty: curves then empty, message says why
  std::string message;
};

/** \class EdgeHausdorffDistanceImageFilter
 * \brief Edge-based (generalised) Hausdorff distance between an intraoperative
 * ("fixed") image and a registered preoperative ("moving") image on the same grid.
 *
 * Method (Mostayed et al., Ann. Biomed. Eng. 2013; Garlapati et al., Comput.
 * Biol. Med. 2015; Huttenlocher et al. 1993):
 *  1. Canny edges (itk::CannyEdgeDetectionImageFilter) of both images,
 *     detected on the whole image (or slice), then restricted to the mask;
 *  2. for every edge pixel of one image the distance (mm) to the nearest edge
 *     pixel of the other, from an itk::SignedMaurerDistanceMapImageFilter of
 *     the other edge set (UseImageSpacing on, SquaredDistance off, values
 *     inside clamped to 0, as itk::DirectedHausdorffDistanceImageFilter does);
 *     both directions. Both the source and the target edge sets are the
 *     masked ones, so the 100th percentile equals
 *     itk::HausdorffDistanceImageFilter on GetFixedEdges() and GetMovingEdges();
 *  3. the nearest-rank K-th percentile (K = 1..100) of each direction's
 *     distances, and their maximum at each K (symmetric curve); the fraction of
 *     edge pixels whose distance is at most DistanceThreshold.
 *
 * Inputs:
 *  - SetFixedImage() (input 0): the intraoperative image, any scalar pixel
 *    type (computed in float). Required. It is passed through as the output.
 *  - SetMovingImage(): the registered preoperative image, resampled onto the
 *    fixed grid. Required.
 *  - SetMaskImage(): optional region of interest on the fixed grid (voxels > 0
 *    inside, e.g. a brain mask). Only edge pixels inside count, in both sets.
 *    Edges are detected on the whole image first, so the mask border is no edge.
 *
 * Parameters (defaults in brackets):
 *  - Variance [2 mm^2]: variance of Canny's Gaussian smoothing in physical
 *    units (sigma = 1.41 mm: MATLAB's default sigma of sqrt(2) pixels at the
 *    ~1 mm voxels of brain MRI). Must be > 0.
 *  - AutomaticThresholds [true]: hysteresis thresholds per image from its own
 *    gradient magnitude (the Gaussian-smoothed image's central differences
 *    per pixel, exactly the magnitude Canny thresholds), pooled over the
 *    pixels inside the mask (all pixels without a mask; all slices in slice
 *    mode): upper = the UpperThresholdQuantile [0.8] quantile (nearest
 *    rank), but at least 1/64 of the largest magnitude (MATLAB's histogram
 *    bin; keeps noise-free flat regions from giving edges); lower =
 *    LowerThresholdRatio [0.4] x upper. Each image gets its own thresholds, so
 *    images of different intensity scales are compared fairly.
 *  - UpperThreshold, LowerThreshold [0]: absolute gradient magnitudes
 *    (intensity units per pixel, as ITK's Canny uses them). A value > 0 is
 *    used for both images instead of the automatic one; with automatic
 *    thresholds on and only UpperThreshold given, lower = LowerThresholdRatio
 *    x upper. With AutomaticThresholds off, a threshold left at 0 is 0.
 *  - SliceAxis [2]: -1 evaluates the whole image (2D or 3D edges and
 *    distances); 0, 1 or 2 evaluates slice by slice across that axis (2D edges
 *    and in-slice distances, as the published evaluation on axial slices) and
 *    pools all slices' distances into one curve. Slices where neither image
 *    has edges are ignored; slices where only one has edges cannot give
 *    distances and are skipped and counted (slicesSkipped, and the message).
 *    Ignored for 2D images.
 *  - DistanceThreshold [1.7 mm]: an edge pixel within it counts as registered
 *    (about twice the in-plane voxel size of intraoperative MRI).
 *
 * Results of the last Update(): GetResult() (EdgeHausdorffResult), the edge
 * images GetFixedEdges() / GetMovingEdges() (1 on edges inside the mask, on
 * the fixed grid; in slice mode the slices' 2D edges stacked) and the
 * thresholds used, GetFixedUpperThresholdUsed() etc.
 *
 * No edges (an empty edge set inside the mask) is a result, not an error:
 * valid = false, empty curves, the counts, and a message naming the image and
 * what to change (lower thresholds, smaller variance, bigger mask).
 *
 * Errors (itk::ExceptionObject, message names what is wrong and what to do):
 *  - fixed or moving image not set;
 *  - moving image or mask not on the fixed grid (size/index, spacing, origin
 *    or direction differ beyond ITK's coordinate/direction tolerances): the
 *    message names the differences; resample onto the intraoperative grid
 *    first (`biomech warp --reference`);
 *  - NaN or infinite pixel values; invalid parameters (Variance <= 0,
 *    quantile outside (0, 1), ratio outside (0, 1], lower > upper threshold,
 *    SliceAxis of a 3D image outside -1..2, negative DistanceThreshold);
 *  - a mask without any voxel > 0.
 *
 * Threads: slice mode processes NumberOfWorkUnits slices at a time (each
 * slice's filters single-threaded) and joins the results in slice order;
 * whole-image mode uses ITK's multithreaded filters. Deterministic: the same
 * inputs give the same result for any number of threads. The distance maps
 * are computed on the bounding box of both edge sets (same distances, less work).
 * Units: mm (physical space). Only 2D and 3D images have been tested; slice
 * mode needs a 3D image (other dimensions use the whole image).
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TImage, typename TMaskImage = Image<unsigned char, TImage::ImageDimension>>
class ITK_TEMPLATE_EXPORT EdgeHausdorffDistanceImageFilter : public ImageToImageFilter<TImage, TImage>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(EdgeHausdorffDistanceImageFilter);

  using Self = EdgeHausdorffDistanceImageFilter;
  using Superclass = ImageToImageFilter<TImage, TImage>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(EdgeHausdorffDistanceImageFilter, ImageToImageFilter);

  static constexpr unsigned int ImageDimension = TImage::ImageDimension;

  using ImageType = TImage;
  using MaskImageType = TMaskImage;
  using EdgeImageType = Image<unsigned char, ImageDimension>;
  /** Edges are detected on float copies of the images. */
  using RealImageType = Image<float, ImageDimension>;

  /** Intraoperative image (input 0). Required. */
  void
  SetFixedImage(const ImageType * image)
  {
    this->SetInput(image);
  }
  const ImageType *
  GetFixedImage() const
  {
    return this->GetInput();
  }
  /** Registered preoperative image on the fixed grid. Required. */
  itkSetInputMacro(MovingImage, ImageType);
  itkGetInputMacro(MovingImage, ImageType);
  /** Optional region of interest on the fixed grid (> 0 inside). */
  itkSetInputMacro(MaskImage, MaskImageType);
  itkGetInputMacro(MaskImage, MaskImageType);

  /** Canny Gaussian variance (mm^2, default 2). */
  itkSetMacro(Variance, double);
  itkGetConstMacro(Variance, double);
  /** Absolute hysteresis thresholds (gradient magnitude per pixel); used when > 0 (default 0). */
  itkSetMacro(UpperThreshold, double);
  itkGetConstMacro(UpperThreshold, double);
  itkSetMacro(LowerThreshold, double);
  itkGetConstMacro(LowerThreshold, double);
  /** Thresholds from each image's gradient magnitude when not given (default true). */
  itkSetMacro(AutomaticThresholds, bool);
  itkGetConstMacro(AutomaticThresholds, bool);
  itkBooleanMacro(AutomaticThresholds);
  /** Automatic upper threshold: this quantile of the gradient magnitude (default 0.8). */
  itkSetMacro(UpperThresholdQuantile, double);
  itkGetConstMacro(UpperThresholdQuantile, double);
  /** Automatic lower threshold: this fraction of the upper one (default 0.4). */
  itkSetMacro(LowerThresholdRatio, double);
  itkGetConstMacro(LowerThresholdRatio, double);
  /** -1: whole image; 0/1/2: slice by slice across that axis (default 2; ignored for 2D). */
  itkSetMacro(SliceAxis, int);
  itkGetConstMacro(SliceAxis, int);
  /** Distance (mm) within which an edge pixel counts as registered (default 1.7). */
  itkSetMacro(DistanceThreshold, double);
  itkGetConstMacro(DistanceThreshold, double);

  /** Result of the last Update(). */
  const EdgeHausdorffResult &
  GetResult() const
  {
    return m_Result;
  }
  /** Edge images of the last Update() (1 on edges inside the mask, fixed grid). */
  const EdgeImageType *
  GetFixedEdges() const
  {
    return m_FixedEdges.GetPointer();
  }
  const EdgeImageType *
  GetMovingEdges() const
  {
    return m_MovingEdges.GetPointer();
  }
  /** Hysteresis thresholds used in the last Update(), per image. */
  itkGetConstMacro(FixedUpperThresholdUsed, double);
  itkGetConstMacro(FixedLowerThresholdUsed, double);
  itkGetConstMacro(MovingUpperThresholdUsed, double);
  itkGetConstMacro(MovingLowerThresholdUsed, double);
  /** Whether the last Update() went slice by slice (false: whole image). */
  itkGetConstMacro(SliceModeUsed, bool);

protected:
  EdgeHausdorffDistanceImageFilter();
  ~EdgeHausdorffDistanceImageFilter() override = default;

  void
  PrintSelf(std::ostream & os, Indent indent) const override;

  void
  VerifyPreconditions() ITKv5_CONST override;

  /** The moving image and the mask must lie on the fixed grid; the message names the difference. */
  void
  VerifyInputInformation() ITKv5_CONST override;

  void
  GenerateInputRequestedRegion() override;

  void
  EnlargeOutputRequestedRegion(DataObject * output) override;

  void
  GenerateData() override;

private:
  typename RealImageType::Pointer
  MakeRealImage(const ImageType * image, const char * role) const;

  /** Upper and lower thresholds of one image from its pooled gradient magnitudes. */
  void
  ChooseThresholds(std::vector<float> & magnitudes, double & upper, double & lower, const char * role) const;

  void
  EvaluateWholeImage(const RealImageType * fixed, const RealImageType * moving, const std::vector<unsigned char> & mask,
                     std::vector<double> & fixedToMoving, std::vector<double> & movingToFixed);

  void
  EvaluateSlices(const RealImageType * fixed, const RealImageType * moving, const std::vector<unsigned char> & mask,
                 std::vector<double> & fixedToMoving, std::vector<double> & movingToFixed);

  void
  MakeResult(std::vector<double> & fixedToMoving, std::vector<double> & movingToFixed, std::size_t skippedFixedPixels,
             std::size_t skippedMovingPixels);

  double m_Variance{ 2.0 };
  double m_UpperThreshold{ 0.0 };
  double m_LowerThreshold{ 0.0 };
  bool   m_AutomaticThresholds{ true };
  double m_UpperThresholdQuantile{ 0.8 };
  double m_LowerThresholdRatio{ 0.4 };
  int    m_SliceAxis{ 2 };
  double m_DistanceThreshold{ 1.7 };

  EdgeHausdorffResult             m_Result;
  typename EdgeImageType::Pointer m_FixedEdges;
  typename EdgeImageType::Pointer m_MovingEdges;
  double                          m_FixedUpperThresholdUsed{ 0.0 };
  double                          m_FixedLowerThresholdUsed{ 0.0 };
  double                          m_MovingUpperThresholdUsed{ 0.0 };
  double                          m_MovingLowerThresholdUsed{ 0.0 };
  bool                            m_SliceModeUsed{ false };
  std::size_t                     m_FixedEdgesFound{ 0 };
  std::size_t                     m_MovingEdgesFound{ 0 };
};

/** Grey background with coloured edges: fixed-image edges red, moving-image
 * edges blue, pixels on both green. */
using EdgeOverlayImageType = Image<RGBPixel<unsigned char>, 2>;

/** The indices (along sliceAxis) of the slices where either edge image has an
 * edge pixel, in increasing order. For a 2D image: {0} when it has edges. */
template <typename TEdgeImage>
std::vector<IndexValueType>
EdgeOverlaySlices(const TEdgeImage * fixedEdges, const TEdgeImage * movingEdges, unsigned int sliceAxis);

/** One slice (index `slice` along sliceAxis of a 3D image; the image itself
 * for 2D) as an RGB overlay: background grey scaled linearly from
 * [greyMinimum, greyMaximum] to [0, 255] (clamped), fixed edges red
 * (255, 0, 0), moving edges blue (0, 0, 255), overlap green (0, 255, 0). The
 * in-plane axes keep their order (the lower image axis runs along the PNG
 * rows); across axis 0 or 1 the rows are flipped so that axis 2 (superior
 * in LPS/RAS-aligned volumes) points up. All images must share one grid. */
template <typename TEdgeImage, typename TBackgroundImage>
typename EdgeOverlayImageType::Pointer
MakeEdgeOverlaySlice(const TEdgeImage * fixedEdges, const TEdgeImage * movingEdges, const TBackgroundImage * background,
                     unsigned int sliceAxis, IndexValueType slice, double greyMinimum, double greyMaximum);

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkEdgeHausdorffDistanceImageFilter.hxx"
#endif

#endif
