// Conversion between ITK images and the mechanics core's voxel volumes
// (bmrImageVolume.h). The core never includes ITK; every filter of the ITK
// layer passes its images through these functions.
#ifndef itkBiomechanicalImageConversion_h
#define itkBiomechanicalImageConversion_h

// ITK first: its bundled Eigen (used by ITK's own headers) must come before
// the system Eigen that the core's headers include.
#include "itkImage.h"
#include "itkImageRegionConstIterator.h"
#include "itkVectorImage.h"

#include "bmrImageVolume.h"

#include <type_traits>

namespace itk
{

/** Geometry of the image's buffered region as the core sees it. */
template <typename TImage>
bmr::ImageGeometry
MakeBiomechanicalGeometry(const TImage * image)
{
  static_assert(TImage::ImageDimension == 3, "the mechanics core works on 3D images");
  bmr::ImageGeometry geometry;
  const auto         region = image->GetBufferedRegion();
  // The buffered region may start at a non-zero index: its first voxel is the core's origin.
  typename TImage::PointType first;
  image->TransformIndexToPhysicalPoint(region.GetIndex(), first);
  for (unsigned int d = 0; d < 3; ++d)
  {
    geometry.size[d] = static_cast<int>(region.GetSize()[d]);
    geometry.spacing[d] = image->GetSpacing()[d];
    geometry.origin[d] = first[d];
    for (unsigned int e = 0; e < 3; ++e)
    {
      geometry.direction(d, e) = image->GetDirection()[d][e];
    }
  }
  return geometry;
}

/** Copies a scalar image's buffered region into a core volume of value type T. */
template <typename T, typename TImage>
bmr::Volume<T>
MakeBiomechanicalVolume(const TImage * image)
{
  bmr::Volume<T> volume;
  volume.geometry = MakeBiomechanicalGeometry(image);
  volume.components = 1;
  volume.values.resize(volume.geometry.VoxelCount());
  ImageRegionConstIterator<TImage> it(image, image->GetBufferedRegion());
  std::size_t                      n = 0;
  for (it.GoToBegin(); !it.IsAtEnd(); ++it)
  {
    volume.values[n++] = static_cast<T>(it.Get());
  }
  return volume;
}

/** Copies a VectorImage (one value per component per voxel) into a core volume. */
template <typename T, typename TPixel>
bmr::Volume<T>
MakeBiomechanicalVolume(const VectorImage<TPixel, 3> * image)
{
  bmr::Volume<T> volume;
  volume.geometry = MakeBiomechanicalGeometry(image);
  volume.components = static_cast<int>(image->GetNumberOfComponentsPerPixel());
  volume.values.resize(volume.geometry.VoxelCount() * volume.components);
  ImageRegionConstIterator<VectorImage<TPixel, 3>> it(image, image->GetBufferedRegion());
  std::size_t                                      n = 0;
  for (it.GoToBegin(); !it.IsAtEnd(); ++it)
  {
    const auto pixel = it.Get();
    for (int c = 0; c < volume.components; ++c)
    {
      volume.values[n++] = static_cast<T>(pixel[c]);
    }
  }
  return volume;
}

/** Sets an image's geometry (largest region from index 0) from the core's. */
template <typename TImage>
void
ApplyBiomechanicalGeometry(const bmr::ImageGeometry & geometry, TImage * image)
{
  typename TImage::RegionType region;
  typename TImage::SpacingType spacing;
  typename TImage::PointType origin;
  typename TImage::DirectionType direction;
  for (unsigned int d = 0; d < 3; ++d)
  {
    region.SetSize(d, static_cast<SizeValueType>(geometry.size[d]));
    region.SetIndex(d, 0);
    spacing[d] = geometry.spacing[d];
    origin[d] = geometry.origin[d];
    for (unsigned int e = 0; e < 3; ++e)
    {
      direction[d][e] = geometry.direction(d, e);
    }
  }
  image->SetRegions(region);
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->SetDirection(direction);
}

/** A new scalar image holding a core volume (components must be 1). */
template <typename TImage, typename T>
typename TImage::Pointer
MakeImageFromBiomechanicalVolume(const bmr::Volume<T> & volume)
{
  if (volume.components != 1)
  {
    itkGenericExceptionMacro("MakeImageFromBiomechanicalVolume: the volume has " << volume.components
                                                                                 << " components; a scalar image takes 1");
  }
  auto image = TImage::New();
  ApplyBiomechanicalGeometry(volume.geometry, image.GetPointer());
  image->Allocate();
  auto * buffer = image->GetBufferPointer();
  for (std::size_t n = 0; n < volume.values.size(); ++n)
  {
    buffer[n] = static_cast<typename TImage::PixelType>(volume.values[n]);
  }
  return image;
}

} // namespace itk

#endif
