// The model-building subcommands of `biomech` (classify, mask, grid,
// surfaces, loads, model): from a preoperative MRI to a scene that `biomech
// solve` runs; and `register`, the whole registration in one call. They share
// their options; the ITK filters they run are compiled once in the pipeline
// library (bmrBrainShiftRegistration.h).
#ifndef bmrModelCommands_h
#define bmrModelCommands_h

#include <CLI/CLI.hpp>

#include <functional>

namespace bmr
{
namespace app
{

/** Adds the subcommands to `app`. The returned function runs the one that
 *  was parsed and returns its exit status, or -1 when none of them was. */
std::function<int()>
AddModelCommands(CLI::App & app);

/** `simulate` (bmrSimulateCommand.cxx): explicit dynamics with moving tools, written as a time series. */
std::function<int()>
AddSimulateCommand(CLI::App & app);

} // namespace app
} // namespace bmr

#endif
