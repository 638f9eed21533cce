#include "bmrImageVolume.h"

#include <cmath>
#include <sstream>

namespace bmr
{

bool
ImageGeometry::SameGridAs(const ImageGeometry & other) const
{
  if (size != other.size)
  {
    return false;
  }
  // ITK's own tolerances (ImageToImageFilter): 1e-6 of the spacing for
  // coordinates, 1e-6 for direction cosines.
  const double tolerance = 1e-6 * spacing.cwiseAbs().maxCoeff();
  return (spacing - other.spacing).cwiseAbs().maxCoeff() <= tolerance &&
         (origin - other.origin).cwiseAbs().maxCoeff() <= tolerance &&
         (direction - other.direction).cwiseAbs().maxCoeff() <= 1e-6;
}

std::string
ImageGeometry::Describe() const
{
  std::ostringstream text;
  text << size[0] << " x " << size[1] << " x " << size[2] << " voxels of " << spacing.x() << " x " << spacing.y() << " x "
       << spacing.z() << " mm, origin (" << origin.x() << ", " << origin.y() << ", " << origin.z() << ") mm";
  return text.str();
}

} // namespace bmr
