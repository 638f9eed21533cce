// A voxel volume as the mechanics core sees it: ITK's image geometry (size,
// spacing, origin, direction cosines; physical space in mm) and the voxel
// values in ITK's buffer order (x fastest, then y, then z). The core reads
// images only through this struct; the ITK layer converts
// (itkBiomechanicalImageConversion.h), so no core file includes ITK.
#ifndef bmrImageVolume_h
#define bmrImageVolume_h

#include "bmrModel.h"

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace bmr
{

struct ImageGeometry
{
  std::array<int, 3> size{ 0, 0, 0 };
  Vector3            spacing = Vector3::Ones();                // mm
  Vector3            origin = Vector3::Zero();                 // mm, centre of voxel (0, 0, 0)
  Eigen::Matrix3d    direction = Eigen::Matrix3d::Identity();  // columns: physical directions of the index axes

  std::size_t VoxelCount() const
  {
    return static_cast<std::size_t>(size[0]) * static_cast<std::size_t>(size[1]) * static_cast<std::size_t>(size[2]);
  }
  std::size_t Offset(int i, int j, int k) const
  {
    return static_cast<std::size_t>(i) +
           static_cast<std::size_t>(size[0]) * (static_cast<std::size_t>(j) + static_cast<std::size_t>(size[1]) * k);
  }
  /** Physical point (mm) of a continuous index. */
  Vector3 IndexToPoint(const Vector3 & continuousIndex) const
  {
    return origin + direction * spacing.cwiseProduct(continuousIndex);
  }
  /** Continuous index of a physical point (voxel centres at integers). */
  Vector3 PointToIndex(const Vector3 & point) const
  {
    return (direction.transpose() * (point - origin)).cwiseQuotient(spacing);
  }
  /** Volume of one voxel, mm^3. */
  double VoxelVolume() const { return spacing.prod(); }
  /** True when both describe the same voxel grid (to 1e-6 relative tolerance). */
  bool SameGridAs(const ImageGeometry & other) const;
  /** "181 x 217 x 181 voxels of 1 x 1 x 1 mm", for messages. */
  std::string Describe() const;
};

/** Voxel values on an image grid; `components` values per voxel, voxel after voxel. */
template <typename T>
struct Volume
{
  ImageGeometry  geometry;
  int            components = 1;
  std::vector<T> values;

  T &       At(int i, int j, int k, int component = 0) { return values[geometry.Offset(i, j, k) * components + component]; }
  const T & At(int i, int j, int k, int component = 0) const
  {
    return values[geometry.Offset(i, j, k) * components + component];
  }
};

using LabelVolume = Volume<std::uint8_t>; // masks (0 = outside) and label maps
using ScalarVolume = Volume<float>;       // intensities, memberships (components = classes)

} // namespace bmr

#endif
