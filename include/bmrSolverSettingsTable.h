// The solver's settings as one table: each setting's name, type, unit,
// range, default and meaning, and how it reads and writes a SolverSettings.
// Every face reads it: the scene file's "solver" object (formats), Python's
// SolverSettings attributes and solve() keywords, `biomech solve --set
// NAME=VALUE`, and the table in docs/scene-format.md (`biomech settings
// --markdown` prints it; a test checks that the docs hold it).
#ifndef bmrSolverSettingsTable_h
#define bmrSolverSettingsTable_h

#include "bmrSolver.h"

#include <functional>
#include <limits>
#include <string>
#include <vector>

namespace bmr
{

struct SolverSettingField
{
  enum class Kind
  {
    Number,
    Integer,
    Flag,
    Choice
  };

  std::string name; // scene key, Python attribute and keyword, --set NAME
  Kind        kind = Kind::Number;
  std::string unit; // empty: dimensionless
  std::string meaning;
  /** Kind::Choice: the names; the value is the index. */
  std::vector<std::string> choices;
  /** Number and Integer: the allowed range, each end open or closed. */
  double lowest = -std::numeric_limits<double>::infinity();
  double highest = std::numeric_limits<double>::infinity();
  bool   lowestOpen = false;
  bool   highestOpen = false;
  /** The value in a SolverSettings: a number, an integer, 0/1 for a flag, the
   *  index of a choice. */
  std::function<double(const SolverSettings &)> get;
  std::function<void(SolverSettings &, double)> set;

  /** "(0, 1]", ">= 1", "> 0", ... or "" when any value is allowed. */
  std::string Range() const;
  /** Empty when `value` is allowed (a finite number in the range, an
   *  integer for Integer, 0/1 for Flag, an index for Choice); otherwise what
   *  is wrong, e.g. "must lie in (0, 1], got 1.5". */
  std::string Check(double value) const;
  /** The value of `settings` as a scene file writes it: 0.001, 20, true, "anp". */
  std::string Text(const SolverSettings & settings) const;
};

/** Every setting, in the docs' order. */
const std::vector<SolverSettingField> &
SolverSettingFields();

/** The field of `name`, or nullptr. */
const SolverSettingField *
FindSolverSetting(const std::string & name);

/** Sets one setting from text ("0.01", "20", "true", "explicit_dynamics"), as
 *  `biomech solve --set` and Python give it. Throws bmr::Error naming the
 *  setting and what is allowed (an unknown name lists the names). */
void
SetSolverSetting(SolverSettings & settings, const std::string & name, const std::string & text);

/** The docs' table (Markdown): key, type, unit, default, allowed, meaning. */
std::string
SolverSettingsMarkdown();

} // namespace bmr

#endif
