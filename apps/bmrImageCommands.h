// The image subcommands of `biomech`: from computed displacements to a warped
// image and a measured accuracy. Each lives in its own translation unit so
// that the ITK templates it needs compile in parallel with the rest.
//
//   fit-transform, warp   (bmrTransformCommands.cxx)
//   evaluate              (bmrEvaluateCommand.cxx)
//   bspline-register      (bmrBSplineRegisterCommand.cxx)
//   demo                  (bmrDemoCommand.cxx: registration against a known answer)
//   electrodes            (bmrElectrodesCommand.cxx: contacts from an intraoperative CT)
#ifndef bmrImageCommands_h
#define bmrImageCommands_h

#include <CLI/CLI.hpp>

#include <functional>

namespace bmr
{
namespace app
{

/** Each adds its subcommands to `app`; the returned function runs the one
 *  that was parsed and returns its exit status, or -1 when none of them was. */
std::function<int()>
AddTransformCommands(CLI::App & app);
std::function<int()>
AddEvaluateCommand(CLI::App & app);
std::function<int()>
AddBSplineRegisterCommand(CLI::App & app);
std::function<int()>
AddDemoCommand(CLI::App & app);
std::function<int()>
AddElectrodesCommand(CLI::App & app);

} // namespace app
} // namespace bmr

#endif
