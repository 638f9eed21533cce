// An image cast to float with the facts the module's filters check before
// using it (non-finite voxels, the range of the finite ones): one scan,
// shared by the atlas skull stripping, the B-spline registration and the
// edge-based evaluator, each of which words its own error.
#ifndef itkFloatImageScan_h
#define itkFloatImageScan_h

#include "itkImage.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIterator.h"
#include "itkNumericTraits.h"

#include <algorithm>
#include <cmath>

namespace itk
{

template <typename TRealImage>
struct FloatImageScan
{
  typename TRealImage::Pointer   image;         // the buffered region, cast to float
  SizeValueType                  notFinite = 0; // NaN or infinite voxels
  typename TRealImage::IndexType firstNotFinite{};
  float                          minimum = NumericTraits<float>::max();            // of the finite voxels
  float                          maximum = NumericTraits<float>::NonpositiveMin(); // of the finite voxels

  bool Constant() const { return !(maximum > minimum); }
};

/** Casts the buffered region of `image` to TRealImage (float pixels, same geometry) and scans it. */
template <typename TRealImage, typename TImage>
FloatImageScan<TRealImage>
CastAndScanToFloat(const TImage * image)
{
  static_assert(TImage::ImageDimension == TRealImage::ImageDimension, "the float image has the input's dimension");
  FloatImageScan<TRealImage> scan;
  scan.image = TRealImage::New();
  scan.image->CopyInformation(image);
  scan.image->SetRegions(image->GetBufferedRegion());
  scan.image->Allocate();
  ImageRegionIterator<TRealImage> out(scan.image, scan.image->GetBufferedRegion());
  for (ImageRegionConstIteratorWithIndex<TImage> in(image, image->GetBufferedRegion()); !in.IsAtEnd(); ++in, ++out)
  {
    const auto value = static_cast<float>(in.Get());
    out.Set(value);
    if (!std::isfinite(value))
    {
      if (scan.notFinite++ == 0)
      {
        scan.firstNotFinite = in.GetIndex();
      }
      continue;
    }
    scan.minimum = std::min(scan.minimum, value);
    scan.maximum = std::max(scan.maximum, value);
  }
  return scan;
}

} // namespace itk

#endif
