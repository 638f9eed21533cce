// The intensity-registration peers users pick: elastix run as Debian's
// `elastix` and `transformix` programs on an image pair (`biomech demo
// --elastix`), or any peer run elsewhere (ANTs or itk-elastix from Python,
// `biomech demo --peer-field`) and read back: its backward map over the
// preoperative grid, where the study measures errors, and its warped image on
// the intraoperative grid.
#ifndef bmrElastixPeer_h
#define bmrElastixPeer_h

#include "itkDisplacementFieldTransform.h"

#include "bmrBrainShiftRegistration.h"

#include <filesystem>
#include <string>
#include <vector>

namespace bmr
{
namespace app
{

/** Whether `program` is an executable file in a folder of PATH. */
bool
OnPath(const std::string & program);

/** The elastix parameter files shipped with the module: installed beside the
 *  executable (share/BiomechanicalRegistration/elastix), else the source tree's. */
std::vector<std::string>
DefaultElastixParameters();

/** A peer's registration of the pair and what the study measures of it. */
struct IntensityPeer
{
  itk::DisplacementFieldTransform<double, 3>::Pointer transform; // backward map over the preoperative grid
  RegistrationImage::Pointer                          warpedOnFixedGrid; // on the intraoperative grid, exactly
  double                                              seconds = 0.0;       // the registration alone
  double                                              outputSeconds = 0.0; // transformix: field and warped image
};

/** elastix (the parameter files in turn) with the intraoperative image fixed,
 *  the preoperative one moving and the intraoperative brain mask; then
 *  transformix for the warped image on the fixed grid and for the
 *  deformation field on the preoperative grid, where errors are measured
 *  (outside a partial field of view too, as elastix's B-spline extends it).
 *  Throws Error naming the program and the end of its log when it fails. */
IntensityPeer
RegisterWithElastix(const std::filesystem::path & fixed, const std::filesystem::path & moving,
                    const std::filesystem::path & fixedMask, const std::vector<std::string> & parameterFiles,
                    const RegistrationImage * preoperativeGrid, const std::filesystem::path & folder, int threads);

/** A peer registration run elsewhere: its displacement field (a 3-vector
 *  image over the preoperative grid, intraoperative point -> preoperative
 *  point minus the point, LPS mm) and the preoperative image it warped onto
 *  `intraoperativeGrid`. Throws Error naming the file that is missing,
 *  unreadable or on another grid. */
IntensityPeer
ReadIntensityPeer(const std::string & fieldPath, const std::string & warpedPath, const RegistrationImage * preoperativeGrid,
                  const RegistrationImage * intraoperativeGrid);

} // namespace app
} // namespace bmr

#endif
