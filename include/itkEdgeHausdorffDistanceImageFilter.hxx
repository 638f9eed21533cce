#ifndef itkEdgeHausdorffDistanceImageFilter_hxx
#define itkEdgeHausdorffDistanceImageFilter_hxx

#include "itkEdgeHausdorffDistanceImageFilter.h"
#include "itkEdgeHausdorffDistanceImageFilterDetail.h"
#include "itkFloatImageScan.h"

#include "itkCannyEdgeDetectionImageFilter.h"
#include "itkDiscreteGaussianImageFilter.h"
#include "itkImageRegionConstIterator.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIterator.h"
#include "itkSignedMaurerDistanceMapImageFilter.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <exception>
#include <functional>
#include <mutex>
#include <sstream>
#include <thread>

namespace itk
{

template <typename TImage, typename TMaskImage>
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::EdgeHausdorffDistanceImageFilter()
{
  this->SetNumberOfRequiredInputs(1);
  this->AddRequiredInputName("MovingImage");
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::VerifyPreconditions() ITKv5_CONST
{
  if (this->GetFixedImage() == nullptr)
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the fixed (intraoperative) image is not set; call "
                      "SetFixedImage().");
  }
  if (this->GetMovingImage() == nullptr)
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the moving (registered preoperative) image is not set; "
                      "call SetMovingImage() with the preoperative image resampled onto the intraoperative grid.");
  }
  Superclass::VerifyPreconditions();
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::VerifyInputInformation() ITKv5_CONST
{
  const ImageType * fixed = this->GetFixedImage();
  const ImageType * moving = this->GetMovingImage();
  if (fixed == nullptr || moving == nullptr)
  {
    return;
  }
  using EdgeHausdorffDistanceImageFilterDetail::GridDifference;
  const double      coordinateTolerance = this->GetCoordinateTolerance();
  const double      directionTolerance = this->GetDirectionTolerance();
  const std::string movingDifference =
    GridDifference<ImageDimension>(moving, fixed, coordinateTolerance, directionTolerance);
  if (!movingDifference.empty())
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the moving (registered preoperative) image is not on the "
                      "fixed (intraoperative) image grid:"
                      << movingDifference
                      << " (moving vs fixed). Resample the registered image onto the intraoperative grid first "
                         "(`biomech warp --reference FIXED`).");
  }
  if (const MaskImageType * mask = this->GetMaskImage())
  {
    const std::string maskDifference =
      GridDifference<ImageDimension>(mask, fixed, coordinateTolerance, directionTolerance);
    if (!maskDifference.empty())
    {
      itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the mask is not on the fixed (intraoperative) image grid:"
                        << maskDifference
                        << " (mask vs fixed). Resample the mask onto the intraoperative grid with nearest-neighbour "
                           "interpolation (`biomech warp --reference FIXED`).");
    }
  }
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::GenerateInputRequestedRegion()
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

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::EnlargeOutputRequestedRegion(DataObject * output)
{
  Superclass::EnlargeOutputRequestedRegion(output);
  output->SetRequestedRegionToLargestPossibleRegion();
}

template <typename TImage, typename TMaskImage>
auto
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::MakeRealImage(const ImageType * image, const char * role) const ->
  typename RealImageType::Pointer
{
  const auto scan = CastAndScanToFloat<RealImageType>(image);
  if (scan.notFinite > 0)
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the "
                      << role << " image contains " << scan.notFinite << " NaN or infinite pixel(s), the first at index "
                      << scan.firstNotFinite << "; replace them (e.g. by 0) before evaluating.");
  }
  return scan.image;
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::ChooseThresholds(std::vector<float> & magnitudes, double & upper,
                                                                       double & lower, const char * role) const
{
  upper = m_UpperThreshold > 0.0 ? m_UpperThreshold : 0.0;
  lower = m_LowerThreshold > 0.0 ? m_LowerThreshold : 0.0;
  if (m_AutomaticThresholds)
  {
    if (!(m_UpperThreshold > 0.0) && !magnitudes.empty())
    {
      const std::size_t rank = std::max<std::size_t>(
        1, static_cast<std::size_t>(std::ceil(m_UpperThresholdQuantile * static_cast<double>(magnitudes.size()))));
      const auto quantile = magnitudes.begin() + static_cast<std::ptrdiff_t>(std::min(rank, magnitudes.size()) - 1);
      std::nth_element(magnitudes.begin(), quantile, magnitudes.end());
      const double largest = *std::max_element(quantile, magnitudes.end());
      upper = std::max(static_cast<double>(*quantile), largest / 64.0);
    }
    if (!(m_LowerThreshold > 0.0))
    {
      lower = m_LowerThresholdRatio * upper;
    }
  }
  if (lower > upper)
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the lower threshold "
                      << lower << " exceeds the upper threshold " << upper << " of the " << role
                      << " image; give a lower threshold below the upper one (gradient magnitude per pixel).");
  }
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::EvaluateWholeImage(const RealImageType *              fixed,
                                                                         const RealImageType *              moving,
                                                                         const std::vector<unsigned char> & mask,
                                                                         std::vector<double> & fixedToMoving,
                                                                         std::vector<double> & movingToFixed)
{
  namespace Detail = EdgeHausdorffDistanceImageFilterDetail;
  const bool needMagnitudes = m_AutomaticThresholds && !(m_UpperThreshold > 0.0);
  for (const bool isFixed : { true, false })
  {
    const RealImageType * image = isFixed ? fixed : moving;
    std::vector<float>    magnitudes;
    if (needMagnitudes)
    {
      const typename RealImageType::Pointer smoothed = Detail::Smooth<ImageDimension>(image, m_Variance, 0);
      Detail::AppendGradientMagnitudes<ImageDimension>(smoothed, mask, magnitudes);
    }
    double & upper = isFixed ? m_FixedUpperThresholdUsed : m_MovingUpperThresholdUsed;
    double & lower = isFixed ? m_FixedLowerThresholdUsed : m_MovingLowerThresholdUsed;
    this->ChooseThresholds(magnitudes, upper, lower, isFixed ? "fixed" : "moving");
    magnitudes = std::vector<float>();
    std::size_t & count = isFixed ? m_FixedEdgesFound : m_MovingEdgesFound;
    (isFixed ? m_FixedEdges : m_MovingEdges) =
      Detail::DetectEdges<ImageDimension>(image, m_Variance, upper, lower, mask, count, 0);
    this->UpdateProgress(isFixed ? 0.4f : 0.8f);
  }
  if (m_FixedEdgesFound > 0 && m_MovingEdgesFound > 0)
  {
    Detail::AppendDirectedDistances<ImageDimension>(m_FixedEdges, m_MovingEdges, fixedToMoving, 0);
    Detail::AppendDirectedDistances<ImageDimension>(m_MovingEdges, m_FixedEdges, movingToFixed, 0);
  }
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::EvaluateSlices(const RealImageType *              fixed,
                                                                     const RealImageType *              moving,
                                                                     const std::vector<unsigned char> & mask,
                                                                     std::vector<double> &              fixedToMoving,
                                                                     std::vector<double> &              movingToFixed)
{
  if constexpr (ImageDimension == 3)
  {
    namespace Detail = EdgeHausdorffDistanceImageFilterDetail;
    using SliceImageType = Image<float, 2>;
    const unsigned int  axis = static_cast<unsigned int>(m_SliceAxis);
    const Size<3>       size = fixed->GetBufferedRegion().GetSize();
    const auto          spacing = fixed->GetSpacing();
    const SizeValueType slices = size[axis];

    // Slices run in parallel, each with single-threaded filters (ITK's threads
    // gain nothing on a slice); results are kept per slice and joined in slice
    // order, so they do not depend on the number of threads.
    const auto workers = static_cast<unsigned int>(
      std::max<SizeValueType>(1, std::min<SizeValueType>(this->GetNumberOfWorkUnits(), slices)));
    const ThreadIdType innerWorkUnits = workers > 1 ? 1 : 0;

    // Pass 1: each image's gradient magnitudes pooled over all its slices, for its thresholds.
    std::vector<float> fixedMagnitudes;
    std::vector<float> movingMagnitudes;
    if (m_AutomaticThresholds && !(m_UpperThreshold > 0.0))
    {
      std::vector<std::vector<float>> fixedPerSlice(slices);
      std::vector<std::vector<float>> movingPerSlice(slices);
      Detail::ForEachSlice(slices, workers, [&](SizeValueType slice) {
        const std::vector<unsigned char> sliceMask = Detail::ExtractMaskSlice(mask, size, axis, slice);
        for (const bool isFixed : { true, false })
        {
          const typename SliceImageType::Pointer image =
            Detail::ExtractSlice((isFixed ? fixed : moving)->GetBufferPointer(), size, spacing, axis, slice);
          Detail::AppendGradientMagnitudes<2>(Detail::Smooth<2>(image, m_Variance, innerWorkUnits),
                                              sliceMask,
                                              isFixed ? fixedPerSlice[slice] : movingPerSlice[slice]);
        }
      });
      for (SizeValueType slice = 0; slice < slices; ++slice)
      {
        fixedMagnitudes.insert(fixedMagnitudes.end(), fixedPerSlice[slice].begin(), fixedPerSlice[slice].end());
        movingMagnitudes.insert(movingMagnitudes.end(), movingPerSlice[slice].begin(), movingPerSlice[slice].end());
        fixedPerSlice[slice] = std::vector<float>();
        movingPerSlice[slice] = std::vector<float>();
      }
    }
    this->ChooseThresholds(fixedMagnitudes, m_FixedUpperThresholdUsed, m_FixedLowerThresholdUsed, "fixed");
    this->ChooseThresholds(movingMagnitudes, m_MovingUpperThresholdUsed, m_MovingLowerThresholdUsed, "moving");
    fixedMagnitudes = std::vector<float>();
    movingMagnitudes = std::vector<float>();
    this->UpdateProgress(0.3f);

    // Pass 2: 2D edges and in-slice distances.
    std::vector<std::size_t>         fixedCounts(slices, 0);
    std::vector<std::size_t>         movingCounts(slices, 0);
    std::vector<std::vector<double>> fixedDistances(slices);
    std::vector<std::vector<double>> movingDistances(slices);
    Detail::ForEachSlice(slices, workers, [&](SizeValueType slice) {
      const std::vector<unsigned char> sliceMask = Detail::ExtractMaskSlice(mask, size, axis, slice);
      const auto                       fixedEdges =
        Detail::DetectEdges<2>(Detail::ExtractSlice(fixed->GetBufferPointer(), size, spacing, axis, slice),
                               m_Variance,
                               m_FixedUpperThresholdUsed,
                               m_FixedLowerThresholdUsed,
                               sliceMask,
                               fixedCounts[slice],
                               innerWorkUnits);
      const auto movingEdges =
        Detail::DetectEdges<2>(Detail::ExtractSlice(moving->GetBufferPointer(), size, spacing, axis, slice),
                               m_Variance,
                               m_MovingUpperThresholdUsed,
                               m_MovingLowerThresholdUsed,
                               sliceMask,
                               movingCounts[slice],
                               innerWorkUnits);
      // Slices are disjoint, so the workers write to different pixels.
      if (fixedCounts[slice] > 0)
      {
        Detail::InsertSlice(fixedEdges, m_FixedEdges->GetBufferPointer(), size, axis, slice);
      }
      if (movingCounts[slice] > 0)
      {
        Detail::InsertSlice(movingEdges, m_MovingEdges->GetBufferPointer(), size, axis, slice);
      }
      if (fixedCounts[slice] > 0 && movingCounts[slice] > 0)
      {
        Detail::AppendDirectedDistances<2>(fixedEdges, movingEdges, fixedDistances[slice], innerWorkUnits);
        Detail::AppendDirectedDistances<2>(movingEdges, fixedEdges, movingDistances[slice], innerWorkUnits);
      }
    });
    for (SizeValueType slice = 0; slice < slices; ++slice)
    {
      m_FixedEdgesFound += fixedCounts[slice];
      m_MovingEdgesFound += movingCounts[slice];
      if (fixedCounts[slice] > 0 && movingCounts[slice] > 0)
      {
        fixedToMoving.insert(fixedToMoving.end(), fixedDistances[slice].begin(), fixedDistances[slice].end());
        movingToFixed.insert(movingToFixed.end(), movingDistances[slice].begin(), movingDistances[slice].end());
        ++m_Result.slicesEvaluated;
      }
      else if (fixedCounts[slice] > 0 || movingCounts[slice] > 0)
      {
        ++m_Result.slicesSkipped;
      }
    }
    this->UpdateProgress(1.0f);
  }
  else
  {
    (void)fixed;
    (void)moving;
    (void)mask;
    (void)fixedToMoving;
    (void)movingToFixed;
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: slice mode needs a 3D image.");
  }
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::MakeResult(std::vector<double> & fixedToMoving,
                                                                 std::vector<double> & movingToFixed,
                                                                 std::size_t           skippedFixedPixels,
                                                                 std::size_t           skippedMovingPixels)
{
  namespace Detail = EdgeHausdorffDistanceImageFilterDetail;
  EdgeHausdorffResult & result = m_Result;
  std::ostringstream    thresholds;
  thresholds << "(variance " << m_Variance << " mm^2; thresholds upper/lower: fixed " << m_FixedUpperThresholdUsed
             << '/' << m_FixedLowerThresholdUsed << ", moving " << m_MovingUpperThresholdUsed << '/'
             << m_MovingLowerThresholdUsed << ')';
  const std::string remedy = "; lower the Canny thresholds, use a smaller variance or a bigger mask";
  if (m_FixedEdgesFound == 0 || m_MovingEdgesFound == 0)
  {
    result.valid = false;
    result.fixedEdgePixels = m_FixedEdgesFound;
    result.movingEdgePixels = m_MovingEdgesFound;
    result.slicesEvaluated = 0;
    const char * which = m_FixedEdgesFound == 0 && m_MovingEdgesFound == 0
                           ? "neither the fixed (intraoperative) nor the moving (registered preoperative) image has"
                         : m_FixedEdgesFound == 0 ? "the fixed (intraoperative) image has"
                                                  : "the moving (registered preoperative) image has";
    result.message = std::string("no distances: ") + which + " no edges" +
                     (this->GetMaskImage() != nullptr ? " inside the mask " : " ") + thresholds.str() + remedy;
    return;
  }
  const std::string axis = std::to_string(m_SliceAxis);
  if (fixedToMoving.empty())
  {
    // Slice mode only: both images have edges, never in the same slice.
    result.valid = false;
    result.fixedEdgePixels = m_FixedEdgesFound;
    result.movingEdgePixels = m_MovingEdgesFound;
    result.message = "no distances: no slice across axis " + axis + " has edges in both images (" +
                     std::to_string(result.slicesSkipped) +
                     " slices with edges in only one were skipped); the images do not overlap: check the "
                     "registration, or evaluate the whole image (slice axis none)";
    return;
  }

  std::sort(fixedToMoving.begin(), fixedToMoving.end());
  std::sort(movingToFixed.begin(), movingToFixed.end());
  result.fixedToMoving = Detail::PercentileCurve(fixedToMoving);
  result.movingToFixed = Detail::PercentileCurve(movingToFixed);
  result.symmetric.resize(100);
  for (std::size_t k = 0; k < 100; ++k)
  {
    result.symmetric[k] = std::max(result.fixedToMoving[k], result.movingToFixed[k]);
  }
  const auto within = [this](const std::vector<double> & sorted) {
    return static_cast<std::size_t>(std::upper_bound(sorted.begin(), sorted.end(), m_DistanceThreshold) -
                                    sorted.begin());
  };
  const std::size_t fixedWithin = within(fixedToMoving);
  const std::size_t movingWithin = within(movingToFixed);
  result.fixedEdgePixels = fixedToMoving.size();
  result.movingEdgePixels = movingToFixed.size();
  result.fractionFixedWithinThreshold = static_cast<double>(fixedWithin) / static_cast<double>(fixedToMoving.size());
  result.fractionMovingWithinThreshold = static_cast<double>(movingWithin) / static_cast<double>(movingToFixed.size());
  result.fractionWithinThreshold =
    static_cast<double>(fixedWithin + movingWithin) / static_cast<double>(fixedToMoving.size() + movingToFixed.size());
  result.valid = true;
  if (result.slicesSkipped > 0)
  {
    result.message = std::to_string(result.slicesSkipped) + " slices across axis " + axis +
                     " had edges in only one image and were skipped (" + std::to_string(skippedFixedPixels) +
                     " fixed and " + std::to_string(skippedMovingPixels) + " moving edge pixels not evaluated)";
  }
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::GenerateData()
{
  if (!(m_Variance > 0.0) || !std::isfinite(m_Variance))
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: Variance must be a positive number (mm^2), got " << m_Variance
                                                                                                          << '.');
  }
  if (!(m_UpperThresholdQuantile > 0.0 && m_UpperThresholdQuantile < 1.0))
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: UpperThresholdQuantile must lie in (0, 1), got "
                      << m_UpperThresholdQuantile << '.');
  }
  if (!(m_LowerThresholdRatio > 0.0 && m_LowerThresholdRatio <= 1.0))
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: LowerThresholdRatio must lie in (0, 1], got "
                      << m_LowerThresholdRatio << '.');
  }
  if (!std::isfinite(m_UpperThreshold) || !std::isfinite(m_LowerThreshold) || m_UpperThreshold < 0.0 ||
      m_LowerThreshold < 0.0)
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the Canny thresholds must be >= 0 (0: automatic), got upper "
                      << m_UpperThreshold << ", lower " << m_LowerThreshold << '.');
  }
  if (ImageDimension == 3 && (m_SliceAxis < -1 || m_SliceAxis > 2))
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: SliceAxis must be -1 (whole image) or an axis 0..2, got "
                      << m_SliceAxis << '.');
  }
  if (!(m_DistanceThreshold >= 0.0) || !std::isfinite(m_DistanceThreshold))
  {
    itkExceptionMacro("EdgeHausdorffDistanceImageFilter: DistanceThreshold must be >= 0 (mm), got "
                      << m_DistanceThreshold << '.');
  }

  m_Result = EdgeHausdorffResult();
  m_Result.distanceThreshold = m_DistanceThreshold;
  m_FixedEdgesFound = 0;
  m_MovingEdgesFound = 0;
  m_FixedUpperThresholdUsed = m_FixedLowerThresholdUsed = 0.0;
  m_MovingUpperThresholdUsed = m_MovingLowerThresholdUsed = 0.0;

  const typename RealImageType::Pointer fixed = this->MakeRealImage(this->GetFixedImage(), "fixed (intraoperative)");
  const typename RealImageType::Pointer moving =
    this->MakeRealImage(this->GetMovingImage(), "moving (registered preoperative)");

  std::vector<unsigned char> mask;
  if (const MaskImageType * maskImage = this->GetMaskImage())
  {
    mask.reserve(fixed->GetBufferedRegion().GetNumberOfPixels());
    SizeValueType inside = 0;
    for (ImageRegionConstIterator<MaskImageType> it(maskImage, maskImage->GetLargestPossibleRegion()); !it.IsAtEnd();
         ++it)
    {
      const bool in = it.Get() > NumericTraits<typename MaskImageType::PixelType>::ZeroValue();
      mask.push_back(in ? 1 : 0);
      inside += in ? 1 : 0;
    }
    if (inside == 0)
    {
      itkExceptionMacro("EdgeHausdorffDistanceImageFilter: the mask has no voxel > 0; give a region of interest "
                        "(e.g. the brain mask) or no mask.");
    }
  }

  const auto makeEdgeImage = [&fixed]() {
    auto edges = EdgeImageType::New();
    edges->CopyInformation(fixed);
    edges->SetRegions(fixed->GetBufferedRegion());
    edges->Allocate(true);
    return edges;
  };
  m_FixedEdges = makeEdgeImage();
  m_MovingEdges = makeEdgeImage();

  std::vector<double> fixedToMoving;
  std::vector<double> movingToFixed;
  m_SliceModeUsed = ImageDimension == 3 && m_SliceAxis >= 0;
  if (m_SliceModeUsed)
  {
    this->EvaluateSlices(fixed, moving, mask, fixedToMoving, movingToFixed);
  }
  else
  {
    this->EvaluateWholeImage(fixed, moving, mask, fixedToMoving, movingToFixed);
  }
  // Edge pixels of skipped slices (slice mode): found, but without distances.
  const std::size_t skippedFixed = m_FixedEdgesFound - fixedToMoving.size();
  const std::size_t skippedMoving = m_MovingEdgesFound - movingToFixed.size();
  if (!m_SliceModeUsed && !fixedToMoving.empty())
  {
    m_Result.slicesEvaluated = 1;
  }
  this->MakeResult(fixedToMoving, movingToFixed, skippedFixed, skippedMoving);

  // The fixed image passes through, as in itk::HausdorffDistanceImageFilter.
  this->GraftOutput(const_cast<ImageType *>(this->GetFixedImage()));
}

template <typename TImage, typename TMaskImage>
void
EdgeHausdorffDistanceImageFilter<TImage, TMaskImage>::PrintSelf(std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "Variance: " << m_Variance << " mm^2" << std::endl;
  os << indent << "UpperThreshold: " << m_UpperThreshold << std::endl;
  os << indent << "LowerThreshold: " << m_LowerThreshold << std::endl;
  os << indent << "AutomaticThresholds: " << m_AutomaticThresholds << std::endl;
  os << indent << "UpperThresholdQuantile: " << m_UpperThresholdQuantile << std::endl;
  os << indent << "LowerThresholdRatio: " << m_LowerThresholdRatio << std::endl;
  os << indent << "SliceAxis: " << m_SliceAxis << std::endl;
  os << indent << "DistanceThreshold: " << m_DistanceThreshold << " mm" << std::endl;
  os << indent << "Thresholds used (upper/lower): fixed " << m_FixedUpperThresholdUsed << '/'
     << m_FixedLowerThresholdUsed << ", moving " << m_MovingUpperThresholdUsed << '/' << m_MovingLowerThresholdUsed
     << std::endl;
  os << indent << "Result: valid " << m_Result.valid << ", edge pixels fixed " << m_Result.fixedEdgePixels << " moving "
     << m_Result.movingEdgePixels << ", slices evaluated " << m_Result.slicesEvaluated << " skipped "
     << m_Result.slicesSkipped;
  if (!m_Result.symmetric.empty())
  {
    os << ", symmetric Hausdorff (100th percentile) " << m_Result.symmetric.back() << " mm";
  }
  os << std::endl;
  if (!m_Result.message.empty())
  {
    os << indent << "Message: " << m_Result.message << std::endl;
  }
}

// ---------------------------------------------------------------------------
// Overlays.
// ---------------------------------------------------------------------------

template <typename TEdgeImage>
std::vector<IndexValueType>
EdgeOverlaySlices(const TEdgeImage * fixedEdges, const TEdgeImage * movingEdges, unsigned int sliceAxis)
{
  constexpr unsigned int Dimension = TEdgeImage::ImageDimension;
  static_assert(Dimension == 2 || Dimension == 3, "EdgeOverlaySlices: 2D or 3D edge images");
  const auto                                    region = fixedEdges->GetLargestPossibleRegion();
  const unsigned int                            axis = Dimension == 3 ? sliceAxis : 0;
  const SizeValueType                           slices = Dimension == 3 ? region.GetSize()[axis] : 1;
  std::vector<unsigned char>                    hasEdges(slices, 0);
  ImageRegionConstIteratorWithIndex<TEdgeImage> fixedIt(fixedEdges, region);
  ImageRegionConstIterator<TEdgeImage>          movingIt(movingEdges, region);
  for (; !fixedIt.IsAtEnd(); ++fixedIt, ++movingIt)
  {
    if (fixedIt.Get() != 0 || movingIt.Get() != 0)
    {
      const SizeValueType slice = Dimension == 3 ? fixedIt.GetIndex()[axis] - region.GetIndex()[axis] : 0;
      hasEdges[slice] = 1;
    }
  }
  std::vector<IndexValueType> result;
  for (SizeValueType slice = 0; slice < slices; ++slice)
  {
    if (hasEdges[slice] != 0)
    {
      result.push_back(static_cast<IndexValueType>(slice) + (Dimension == 3 ? region.GetIndex()[axis] : 0));
    }
  }
  return result;
}

template <typename TEdgeImage, typename TBackgroundImage>
typename EdgeOverlayImageType::Pointer
MakeEdgeOverlaySlice(const TEdgeImage * fixedEdges, const TEdgeImage * movingEdges, const TBackgroundImage * background,
                     unsigned int sliceAxis, IndexValueType slice, double greyMinimum, double greyMaximum)
{
  constexpr unsigned int Dimension = TEdgeImage::ImageDimension;
  static_assert(Dimension == 2 || Dimension == 3, "MakeEdgeOverlaySlice: 2D or 3D images");
  const auto region = fixedEdges->GetLargestPossibleRegion();
  if (movingEdges->GetLargestPossibleRegion() != region || background->GetLargestPossibleRegion() != region)
  {
    itkGenericExceptionMacro("MakeEdgeOverlaySlice: the edge images and the background must share one grid.");
  }
  std::array<unsigned int, 2> axes{ 0, 1 };
  bool                        flipRows = false;
  if constexpr (Dimension == 3)
  {
    if (sliceAxis > 2 || slice < region.GetIndex()[sliceAxis] ||
        slice >= region.GetIndex()[sliceAxis] + static_cast<IndexValueType>(region.GetSize()[sliceAxis]))
    {
      itkGenericExceptionMacro("MakeEdgeOverlaySlice: slice " << slice << " across axis " << sliceAxis
                                                              << " is outside the image " << region);
    }
    axes = EdgeHausdorffDistanceImageFilterDetail::InPlaneAxes(sliceAxis);
    flipRows = sliceAxis != 2;
  }
  auto                           overlay = EdgeOverlayImageType::New();
  EdgeOverlayImageType::SizeType size{ { region.GetSize()[axes[0]], region.GetSize()[axes[1]] } };
  overlay->SetRegions(EdgeOverlayImageType::RegionType(size));
  EdgeOverlayImageType::SpacingType spacing;
  spacing[0] = fixedEdges->GetSpacing()[axes[0]];
  spacing[1] = fixedEdges->GetSpacing()[axes[1]];
  overlay->SetSpacing(spacing);
  overlay->Allocate();
  const double                   scale = greyMaximum > greyMinimum ? 255.0 / (greyMaximum - greyMinimum) : 0.0;
  typename TEdgeImage::IndexType index = region.GetIndex();
  if constexpr (Dimension == 3)
  {
    index[sliceAxis] = slice;
  }
  for (SizeValueType j = 0; j < size[1]; ++j)
  {
    index[axes[1]] = region.GetIndex()[axes[1]] + static_cast<IndexValueType>(j);
    const SizeValueType row = flipRows ? size[1] - 1 - j : j;
    for (SizeValueType i = 0; i < size[0]; ++i)
    {
      index[axes[0]] = region.GetIndex()[axes[0]] + static_cast<IndexValueType>(i);
      const bool              fixedEdge = fixedEdges->GetPixel(index) != 0;
      const bool              movingEdge = movingEdges->GetPixel(index) != 0;
      RGBPixel<unsigned char> pixel;
      if (fixedEdge && movingEdge)
      {
        pixel.Set(0, 255, 0);
      }
      else if (fixedEdge)
      {
        pixel.Set(255, 0, 0);
      }
      else if (movingEdge)
      {
        pixel.Set(0, 0, 255);
      }
      else
      {
        const double grey = (static_cast<double>(background->GetPixel(index)) - greyMinimum) * scale;
        const auto   value = static_cast<unsigned char>(std::clamp(std::round(grey), 0.0, 255.0));
        pixel.Set(value, value, value);
      }
      overlay->SetPixel({ { static_cast<IndexValueType>(i), static_cast<IndexValueType>(row) } }, pixel);
    }
  }
  return overlay;
}

} // namespace itk

#endif
