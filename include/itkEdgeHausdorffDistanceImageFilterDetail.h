// Helpers of itkEdgeHausdorffDistanceImageFilter.hxx: smoothing and edge
// detection as Canny does them, automatic thresholds, distance maps, grid
// checks and percentile curves. Not part of the public interface.
#ifndef itkEdgeHausdorffDistanceImageFilterDetail_h
#define itkEdgeHausdorffDistanceImageFilterDetail_h

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
namespace EdgeHausdorffDistanceImageFilterDetail
{

template <unsigned int VDimension>
using RealImage = Image<float, VDimension>;
template <unsigned int VDimension>
using EdgeImage = Image<unsigned char, VDimension>;
// double, as itk::DirectedHausdorffDistanceImageFilter uses for unsigned char edges,
// so that the 100th percentile agrees with ITK's filter to rounding.
template <unsigned int VDimension>
using DistanceImage = Image<double, VDimension>;

/** Canny's own Gaussian smoothing (same filter and settings), for the automatic thresholds. */
template <unsigned int VDimension>
typename RealImage<VDimension>::Pointer
Smooth(const RealImage<VDimension> * image, double variance, ThreadIdType workUnits)
{
  auto gaussian = DiscreteGaussianImageFilter<RealImage<VDimension>, RealImage<VDimension>>::New();
  gaussian->SetInput(image);
  gaussian->SetVariance(variance);
  gaussian->SetMaximumError(0.01); // Canny's default
  if (workUnits > 0)
  {
    gaussian->SetNumberOfWorkUnits(workUnits);
  }
  gaussian->Update();
  return gaussian->GetOutput();
}

/** Appends the gradient magnitude that ITK's Canny thresholds (central
 * differences per pixel, zero-flux boundary, sqrt(1e-4 + sum dx^2)) at every
 * pixel inside `mask` (buffer order; empty: every pixel). */
template <unsigned int VDimension>
void
AppendGradientMagnitudes(const RealImage<VDimension> * smoothed, const std::vector<unsigned char> & mask,
                         std::vector<float> & magnitudes)
{
  const auto                            size = smoothed->GetBufferedRegion().GetSize();
  const float *                         values = smoothed->GetBufferPointer();
  std::array<SizeValueType, VDimension> stride;
  SizeValueType                         count = 1;
  for (unsigned int d = 0; d < VDimension; ++d)
  {
    stride[d] = count;
    count *= size[d];
  }
  std::array<SizeValueType, VDimension> index{};
  for (SizeValueType n = 0; n < count; ++n)
  {
    if (mask.empty() || mask[n] != 0)
    {
      float sum = 0.0001f; // Canny's regularisation of the magnitude
      for (unsigned int d = 0; d < VDimension; ++d)
      {
        const SizeValueType low = index[d] > 0 ? n - stride[d] : n;
        const SizeValueType high = index[d] + 1 < size[d] ? n + stride[d] : n;
        const float         dx = 0.5f * (values[high] - values[low]);
        sum += dx * dx;
      }
      magnitudes.push_back(static_cast<float>(std::sqrt(static_cast<double>(sum))));
    }
    for (unsigned int d = 0; d < VDimension; ++d)
    {
      if (++index[d] < size[d])
      {
        break;
      }
      index[d] = 0;
    }
  }
}

/** Canny edges of `image` (1 on edges) restricted to `mask` (empty: none); `count` = edge pixels kept. */
template <unsigned int VDimension>
typename EdgeImage<VDimension>::Pointer
DetectEdges(const RealImage<VDimension> * image, double variance, double upper, double lower,
            const std::vector<unsigned char> & mask, std::size_t & count, ThreadIdType workUnits)
{
  auto canny = CannyEdgeDetectionImageFilter<RealImage<VDimension>, RealImage<VDimension>>::New();
  canny->SetInput(image);
  canny->SetVariance(variance);
  canny->SetMaximumError(0.01);
  canny->SetUpperThreshold(static_cast<float>(upper));
  canny->SetLowerThreshold(static_cast<float>(lower));
  if (workUnits > 0)
  {
    canny->SetNumberOfWorkUnits(workUnits);
  }
  canny->Update();
  const RealImage<VDimension> * cannyEdges = canny->GetOutput();

  auto edges = EdgeImage<VDimension>::New();
  edges->CopyInformation(image);
  edges->SetRegions(image->GetBufferedRegion());
  edges->Allocate();
  const float *       in = cannyEdges->GetBufferPointer();
  unsigned char *     out = edges->GetBufferPointer();
  const SizeValueType pixels = edges->GetBufferedRegion().GetNumberOfPixels();
  count = 0;
  for (SizeValueType n = 0; n < pixels; ++n)
  {
    const bool edge = in[n] > 0.5f && (mask.empty() || mask[n] != 0);
    out[n] = edge ? 1 : 0;
    count += edge ? 1 : 0;
  }
  return edges;
}

/** The smallest region holding every edge pixel of both images (both have some). */
template <unsigned int VDimension>
ImageRegion<VDimension>
EdgeBoundingBox(const EdgeImage<VDimension> * first, const EdgeImage<VDimension> * second)
{
  const ImageRegion<VDimension>         region = first->GetBufferedRegion();
  const unsigned char *                 a = first->GetBufferPointer();
  const unsigned char *                 b = second->GetBufferPointer();
  std::array<SizeValueType, VDimension> low;
  std::array<SizeValueType, VDimension> high{};
  std::array<SizeValueType, VDimension> index{};
  for (unsigned int d = 0; d < VDimension; ++d)
  {
    low[d] = region.GetSize()[d];
  }
  const SizeValueType pixels = region.GetNumberOfPixels();
  for (SizeValueType n = 0; n < pixels; ++n)
  {
    if (a[n] != 0 || b[n] != 0)
    {
      for (unsigned int d = 0; d < VDimension; ++d)
      {
        low[d] = std::min(low[d], index[d]);
        high[d] = std::max(high[d], index[d]);
      }
    }
    for (unsigned int d = 0; d < VDimension; ++d)
    {
      if (++index[d] < region.GetSize()[d])
      {
        break;
      }
      index[d] = 0;
    }
  }
  ImageRegion<VDimension> box;
  for (unsigned int d = 0; d < VDimension; ++d)
  {
    box.SetIndex(d, region.GetIndex()[d] + static_cast<IndexValueType>(low[d]));
    box.SetSize(d, high[d] - low[d] + 1);
  }
  return box;
}

/** `box` of an edge image as an image of its own (same spacing). */
template <unsigned int VDimension>
typename EdgeImage<VDimension>::Pointer
CropEdges(const EdgeImage<VDimension> * edges, const ImageRegion<VDimension> & box)
{
  auto crop = EdgeImage<VDimension>::New();
  crop->SetRegions(box.GetSize());
  crop->SetSpacing(edges->GetSpacing());
  crop->Allocate();
  ImageRegionConstIterator<EdgeImage<VDimension>> in(edges, box);
  ImageRegionIterator<EdgeImage<VDimension>>      out(crop, crop->GetBufferedRegion());
  for (; !in.IsAtEnd(); ++in, ++out)
  {
    out.Set(in.Get());
  }
  return crop;
}

/** For every pixel of `from` that is an edge, the distance (mm) to the nearest edge pixel of `to`. */
template <unsigned int VDimension>
void
AppendDirectedDistances(const EdgeImage<VDimension> * fromImage, const EdgeImage<VDimension> * toImage,
                        std::vector<double> & distances, ThreadIdType workUnits)
{
  // The distance map is computed on the bounding box of both edge sets only:
  // every source and every target lies inside, so the distances are the same
  // (the exact Euclidean transform), at a fraction of the cost for a brain in
  // a head-sized image. Raster order within the box is that of the image.
  const ImageRegion<VDimension>                box = EdgeBoundingBox<VDimension>(fromImage, toImage);
  typename EdgeImage<VDimension>::ConstPointer from = fromImage;
  typename EdgeImage<VDimension>::ConstPointer to = toImage;
  if (box != fromImage->GetBufferedRegion())
  {
    from = CropEdges<VDimension>(fromImage, box);
    to = CropEdges<VDimension>(toImage, box);
  }
  auto maurer = SignedMaurerDistanceMapImageFilter<EdgeImage<VDimension>, DistanceImage<VDimension>>::New();
  maurer->SetInput(to);
  maurer->SetUseImageSpacing(true);
  maurer->SetSquaredDistance(false);
  if (workUnits > 0)
  {
    maurer->SetNumberOfWorkUnits(workUnits);
  }
  maurer->Update();
  const double *        map = maurer->GetOutput()->GetBufferPointer();
  const unsigned char * edges = from->GetBufferPointer();
  const SizeValueType   pixels = from->GetBufferedRegion().GetNumberOfPixels();
  for (SizeValueType n = 0; n < pixels; ++n)
  {
    if (edges[n] != 0)
    {
      // Edge pixels of `to` lie on the inside (<= 0): clamped to 0 as ITK's Hausdorff filter does.
      distances.push_back(std::max(map[n], 0.0));
    }
  }
}

/** Runs work(slice) for slices 0 .. slices - 1 on `workers` threads (this
 * one included), each taking the next slice not yet taken; the first
 * exception stops the rest and is rethrown. */
inline void
ForEachSlice(SizeValueType slices, unsigned int workers, const std::function<void(SizeValueType)> & work)
{
  std::atomic<SizeValueType> next{ 0 };
  std::exception_ptr         failure;
  std::mutex                 failureMutex;
  const auto                 run = [&]() {
    try
    {
      for (SizeValueType slice = next++; slice < slices; slice = next++)
      {
        work(slice);
      }
    }
    catch (...)
    {
      const std::lock_guard<std::mutex> lock(failureMutex);
      if (!failure)
      {
        failure = std::current_exception();
      }
      next = slices;
    }
  };
  std::vector<std::thread> threads;
  for (unsigned int worker = 1; worker < workers; ++worker)
  {
    threads.emplace_back(run);
  }
  run();
  for (std::thread & thread : threads)
  {
    thread.join();
  }
  if (failure)
  {
    std::rethrow_exception(failure);
  }
}

/** The two axes in a slice across `axis` of a 3D image, in increasing order. */
inline std::array<unsigned int, 2>
InPlaneAxes(unsigned int axis)
{
  return { axis == 0 ? 1u : 0u, axis == 2 ? 1u : 2u };
}

/** Linear offsets of a 3D buffer along each axis. */
inline std::array<SizeValueType, 3>
Strides(const Size<3> & size)
{
  return { 1, size[0], size[0] * size[1] };
}

/** Slice `slice` across `axis` of a 3D buffer as a 2D image with the in-plane
 * spacing (origin 0, identity direction: distances only need the spacing). */
template <typename TPixel>
typename Image<TPixel, 2>::Pointer
ExtractSlice(const TPixel * buffer, const Size<3> & size, const Vector<double, 3> & spacing, unsigned int axis,
             SizeValueType slice)
{
  const auto axes = InPlaneAxes(axis);
  const auto stride = Strides(size);
  auto       image = Image<TPixel, 2>::New();
  Size<2>    sliceSize{ { size[axes[0]], size[axes[1]] } };
  image->SetRegions(ImageRegion<2>(sliceSize));
  typename Image<TPixel, 2>::SpacingType sliceSpacing;
  sliceSpacing[0] = spacing[axes[0]];
  sliceSpacing[1] = spacing[axes[1]];
  image->SetSpacing(sliceSpacing);
  image->Allocate();
  TPixel * out = image->GetBufferPointer();
  for (SizeValueType j = 0; j < sliceSize[1]; ++j)
  {
    const TPixel * row = buffer + slice * stride[axis] + j * stride[axes[1]];
    for (SizeValueType i = 0; i < sliceSize[0]; ++i)
    {
      *out++ = row[i * stride[axes[0]]];
    }
  }
  return image;
}

/** The mask pixels of slice `slice` (empty when there is no mask). */
inline std::vector<unsigned char>
ExtractMaskSlice(const std::vector<unsigned char> & mask, const Size<3> & size, unsigned int axis, SizeValueType slice)
{
  std::vector<unsigned char> sliceMask;
  if (mask.empty())
  {
    return sliceMask;
  }
  const auto axes = InPlaneAxes(axis);
  const auto stride = Strides(size);
  sliceMask.reserve(size[axes[0]] * size[axes[1]]);
  for (SizeValueType j = 0; j < size[axes[1]]; ++j)
  {
    for (SizeValueType i = 0; i < size[axes[0]]; ++i)
    {
      sliceMask.push_back(mask[slice * stride[axis] + j * stride[axes[1]] + i * stride[axes[0]]]);
    }
  }
  return sliceMask;
}

/** Copies a 2D slice of edges into slice `slice` across `axis` of a 3D edge buffer. */
inline void
InsertSlice(const EdgeImage<2> * sliceEdges, unsigned char * buffer, const Size<3> & size, unsigned int axis,
            SizeValueType slice)
{
  const auto            axes = InPlaneAxes(axis);
  const auto            stride = Strides(size);
  const unsigned char * in = sliceEdges->GetBufferPointer();
  for (SizeValueType j = 0; j < size[axes[1]]; ++j)
  {
    unsigned char * row = buffer + slice * stride[axis] + j * stride[axes[1]];
    for (SizeValueType i = 0; i < size[axes[0]]; ++i)
    {
      row[i * stride[axes[0]]] = *in++;
    }
  }
}

/** What differs between the grid of `image` and `reference` ("" when nothing). */
template <unsigned int VDimension>
std::string
GridDifference(const ImageBase<VDimension> * image, const ImageBase<VDimension> * reference, double coordinateTolerance,
               double directionTolerance)
{
  std::ostringstream difference;
  const double       tolerance = coordinateTolerance * reference->GetSpacing()[0];
  if (image->GetLargestPossibleRegion() != reference->GetLargestPossibleRegion())
  {
    difference << " size " << image->GetLargestPossibleRegion().GetSize() << " index "
               << image->GetLargestPossibleRegion().GetIndex() << " vs "
               << reference->GetLargestPossibleRegion().GetSize() << " index "
               << reference->GetLargestPossibleRegion().GetIndex() << ';';
  }
  if (!image->GetSpacing().GetVnlVector().is_equal(reference->GetSpacing().GetVnlVector(), tolerance))
  {
    difference << " spacing " << image->GetSpacing() << " vs " << reference->GetSpacing() << " mm;";
  }
  if (!image->GetOrigin().GetVnlVector().is_equal(reference->GetOrigin().GetVnlVector(), tolerance))
  {
    difference << " origin " << image->GetOrigin() << " vs " << reference->GetOrigin() << " mm;";
  }
  if (!image->GetDirection().GetVnlMatrix().as_ref().is_equal(reference->GetDirection().GetVnlMatrix().as_ref(),
                                                              directionTolerance))
  {
    difference << " direction differs;";
  }
  return difference.str();
}

/** Nearest-rank percentiles K = 1..100 of sorted values. */
inline std::vector<double>
PercentileCurve(const std::vector<double> & sorted)
{
  std::vector<double> curve(100);
  const std::size_t   count = sorted.size();
  for (std::size_t k = 1; k <= 100; ++k)
  {
    const std::size_t rank = std::max<std::size_t>(1, (k * count + 99) / 100);
    curve[k - 1] = sorted[rank - 1];
  }
  return curve;
}

} // namespace EdgeHausdorffDistanceImageFilterDetail

} // namespace itk

#endif
