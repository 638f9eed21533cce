// The solver's settings as one table (bmrSettingsTable.h): each setting's
// name, type, unit, range, default and meaning, and how it reads and writes a
// SolverSettings. Every face reads it: the scene file's "solver" object
// (formats), Python's SolverSettings attributes and solve() keywords,
// `biomech solve --set NAME=VALUE`, and the table in docs/scene-format.md
// (`biomech settings --markdown` prints it; a test checks that the docs hold it).
#ifndef bmrSolverSettingsTable_h
#define bmrSolverSettingsTable_h

#include "bmrSettingsTable.h"
#include "bmrSolver.h"

#include <string>
#include <vector>

namespace bmr
{

using SolverSettingField = SettingField<SolverSettings>;

/** Every setting, in the docs' order. */
const std::vector<SolverSettingField> &
SolverSettingFields();

/** The field of `name`, or nullptr. */
const SolverSettingField *
FindSolverSetting(const std::string & name);

/** Sets one setting from text ("0.01", "20", "true", "explicit_dynamics"), as
 *  `biomech solve --set` gives it. Throws bmr::Error naming the setting and
 *  what is allowed (an unknown name lists the names). */
void
SetSolverSetting(SolverSettings & settings, const std::string & name, const std::string & text);

/** The docs' table (Markdown): key, default, unit, allowed, meaning. */
std::string
SolverSettingsMarkdown();

} // namespace bmr

#endif
