// Helpers of the electrode localisation (bmrElectrodes.cxx) that its
// synthetic CT (the evaluation library's bmrSyntheticElectrodeCt.cxx) shares:
// private to the module, not installed.
#ifndef bmrElectrodeImages_h
#define bmrElectrodeImages_h

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkImageRegionConstIteratorWithIndex.h"

#include "bmrBrainShiftRegistration.h"

#include <algorithm>
#include <string>
#include <vector>

namespace bmr
{
namespace electrodes
{

constexpr double kAirHU = -1000.0;

inline Vector3
ToVector(const itk::Point<double, 3> & point)
{
  return Vector3(point[0], point[1], point[2]);
}

inline itk::Point<double, 3>
ToPoint(const Vector3 & vector)
{
  itk::Point<double, 3> point;
  for (unsigned int d = 0; d < 3; ++d)
  {
    point[d] = vector[d];
  }
  return point;
}

/** The value below which `fraction` of `values` lie (values is reordered). */
inline double
Quantile(std::vector<float> & values, double fraction)
{
  if (values.empty())
  {
    return 0.0;
  }
  const auto at = values.begin() + static_cast<std::ptrdiff_t>(fraction * static_cast<double>(values.size() - 1));
  std::nth_element(values.begin(), at, values.end());
  return *at;
}

/** Centroid (mm) of the voxels above `threshold`; throws when there are none. */
template <typename TImage>
Vector3
CentroidAbove(const TImage * image, double threshold, const std::string & what)
{
  Vector3     sum = Vector3::Zero();
  std::size_t count = 0;
  for (itk::ImageRegionConstIteratorWithIndex<TImage> it(image, image->GetBufferedRegion()); !it.IsAtEnd(); ++it)
  {
    if (it.Get() > threshold)
    {
      itk::Point<double, 3> point;
      image->TransformIndexToPhysicalPoint(it.GetIndex(), point);
      sum += ToVector(point);
      ++count;
    }
  }
  if (count == 0)
  {
    throw Error("the " + what + " has no voxel above " + std::to_string(threshold) + ": is it the right image?");
  }
  return sum / static_cast<double>(count);
}

} // namespace electrodes
} // namespace bmr

#endif
