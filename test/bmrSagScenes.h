// Sagging craniotomies on a real brain's mask for the tests that run the
// pipeline: where the opening lies, sparse measurements of its sag, and the
// coarse registration settings that keep such tests quick.
#ifndef bmrSagScenes_h
#define bmrSagScenes_h

#include "bmrBrainShiftRegistration.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace bmr_test
{

inline bmr::Vector3
MaskCentroid(const bmr::LabelVolume & mask)
{
  bmr::Vector3 sum = bmr::Vector3::Zero();
  double       count = 0.0;
  const auto & g = mask.geometry;
  for (int k = 0; k < g.size[2]; ++k)
  {
    for (int j = 0; j < g.size[1]; ++j)
    {
      for (int i = 0; i < g.size[0]; ++i)
      {
        if (mask.At(i, j, k) != 0)
        {
          sum += g.IndexToPoint(bmr::Vector3(i, j, k));
          count += 1.0;
        }
      }
    }
  }
  return sum / count;
}

inline bool
InsideMask(const bmr::LabelVolume & mask, const bmr::Vector3 & point)
{
  const bmr::Vector3 index = mask.geometry.PointToIndex(point);
  const int          i = static_cast<int>(std::lround(index.x()));
  const int          j = static_cast<int>(std::lround(index.y()));
  const int          k = static_cast<int>(std::lround(index.z()));
  const auto &       size = mask.geometry.size;
  return i >= 0 && j >= 0 && k >= 0 && i < size[0] && j < size[1] && k < size[2] && mask.At(i, j, k) != 0;
}

/** The outermost point of the mask on the ray from its centroid along `direction` (patient LPS). */
inline bmr::Vector3
SurfacePointAlong(const bmr::LabelVolume & mask, const bmr::Vector3 & direction)
{
  const bmr::Vector3 centroid = MaskCentroid(mask);
  const bmr::Vector3 unit = direction.normalized();
  bmr::Vector3       last = centroid;
  for (double t = 0.0; t < 250.0; t += 0.25)
  {
    if (InsideMask(mask, centroid + t * unit))
    {
      last = centroid + t * unit;
    }
  }
  return last;
}

/** Sparse measurements of a sag of the exposed surface: the mask's surface
 *  voxels within 0.8 of the craniotomy's radius (every `stride`-th), moved
 *  towards the brain's centroid by depth * (1 - (d / 0.8 R)^2). */
inline bmr::SparseDisplacements
SagOfTheOpening(const bmr::LabelVolume & mask, const bmr::Vector3 & centre, double radius, double depth)
{
  const bmr::Vector3       inward = (MaskCentroid(mask) - centre).normalized();
  const auto &             g = mask.geometry;
  bmr::SparseDisplacements sag;
  std::vector<bmr::Vector3> points;
  const double              reach = 0.8 * radius;
  for (int k = 1; k + 1 < g.size[2]; ++k)
  {
    for (int j = 1; j + 1 < g.size[1]; ++j)
    {
      for (int i = 1; i + 1 < g.size[0]; ++i)
      {
        if (mask.At(i, j, k) == 0)
        {
          continue;
        }
        const bool surface = mask.At(i - 1, j, k) == 0 || mask.At(i + 1, j, k) == 0 || mask.At(i, j - 1, k) == 0 ||
                             mask.At(i, j + 1, k) == 0 || mask.At(i, j, k - 1) == 0 || mask.At(i, j, k + 1) == 0;
        const bmr::Vector3 x = g.IndexToPoint(bmr::Vector3(i, j, k));
        if (surface && (x - centre).norm() <= reach)
        {
          points.push_back(x);
        }
      }
    }
  }
  const std::size_t stride = std::max<std::size_t>(1, points.size() / 60);
  for (std::size_t n = 0; n < points.size(); n += stride)
  {
    const double d = (points[n] - centre).norm() / reach;
    sag.points.push_back(points[n]);
    sag.displacements.push_back(depth * (1.0 - d * d) * inward);
  }
  return sag;
}

inline bmr::BrainShiftRegistrationSettings
CoarseRegistration(bmr::ImageGridKind kind, double elementSize, const bmr::Vector3 & centre, double radius)
{
  bmr::BrainShiftRegistrationSettings settings;
  settings.model.grid.kind = kind;
  settings.model.grid.elementSize = elementSize;
  settings.model.craniotomyCentre = centre;
  settings.model.craniotomyRadius = radius;
  return settings;
}

} // namespace bmr_test

#endif
