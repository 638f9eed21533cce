// Text the pipeline's sources share for messages and reports (private to the
// pipeline, not installed).
#ifndef bmrPipelineText_h
#define bmrPipelineText_h

#include "bmrUnits.h"

#include <iomanip>
#include <sstream>
#include <string>

namespace bmr
{

/** An acceleration (mm/s^2) in g, for messages. */
inline std::string
InG(double acceleration)
{
  std::ostringstream text;
  text << std::setprecision(3) << acceleration / units::StandardGravity << " g";
  return text.str();
}

} // namespace bmr

#endif
