#include "bmrSolverSettingsTable.h"


namespace bmr
{

namespace
{

using Field = SolverSettingField;
using Kind = SolverSettingField::Kind;

template <typename Member>
Field
NumberField(std::string name, std::string unit, Member member, double lowest, bool lowestOpen, double highest,
            bool highestOpen, std::string meaning)
{
  return MakeSettingField<SolverSettings>(
    Kind::Number, "", std::move(name), std::move(unit), lowest, lowestOpen, highest, highestOpen, std::move(meaning),
    [member](const SolverSettings & settings) { return static_cast<double>(settings.*member); },
    [member](SolverSettings & settings, double value) { settings.*member = value; });
}

Field
IntegerField(std::string name, int SolverSettings::*member, double lowest, double highest, std::string meaning)
{
  return MakeSettingField<SolverSettings>(
    Kind::Integer, "", std::move(name), "", lowest, false, highest, false, std::move(meaning),
    [member](const SolverSettings & settings) { return static_cast<double>(settings.*member); },
    [member](SolverSettings & settings, double value) { settings.*member = static_cast<int>(value); });
}

/** A setting of two choices: `first` (value 0, named choices[0]) or `second` (1). */
template <typename Enum>
Field
ChoiceField(std::string name, Enum SolverSettings::*member, Enum first, Enum second, std::vector<std::string> choices,
            std::string meaning)
{
  Field field = MakeSettingField<SolverSettings>(
    Kind::Choice, "", std::move(name), "", 0, false, 0, false, std::move(meaning),
    [member, second](const SolverSettings & s) { return s.*member == second ? 1.0 : 0.0; },
    [member, first, second](SolverSettings & s, double v) { s.*member = v == 1.0 ? second : first; });
  field.choices = std::move(choices);
  return field;
}

constexpr double kInfinity = std::numeric_limits<double>::infinity();

std::vector<Field>
MakeFields()
{
  std::vector<Field> fields;
  fields.push_back(ChoiceField("integrator", &SolverSettings::integrator, Integrator::DynamicRelaxation,
                               Integrator::ExplicitDynamics, { "dynamic_relaxation", "explicit_dynamics" },
                               "dynamic relaxation (steady state) or explicit dynamics (time-accurate central "
                               "difference)"));
  fields.push_back(ChoiceField("tetrahedron", &SolverSettings::tetrahedron, TetrahedronFormulation::AverageNodalPressure,
                               TetrahedronFormulation::Linear, { "anp", "linear" },
                               "average nodal pressure (non-locking) or the plain constant-strain tetrahedron, for "
                               "comparison"));
  fields.push_back(NumberField("tolerance", "mm", &SolverSettings::tolerance, 0.0, true, kInfinity, false,
                               "dynamic relaxation stops when the estimated distance to the solution is below it"));
  fields.push_back(IntegerField("max_steps", &SolverSettings::maxSteps, 1, std::numeric_limits<int>::max(),
                                "dynamic relaxation step limit; reaching it gives `converged: false`"));
  fields.push_back(IntegerField("load_steps", &SolverSettings::loadSteps, 1, std::numeric_limits<int>::max(),
                                "dynamic relaxation steps over which loads are ramped"));
  fields.push_back(IntegerField("adapt_interval", &SolverSettings::adaptInterval, 2, std::numeric_limits<int>::max(),
                                "dynamic relaxation steps between updates of the convergence-rate estimate"));
  fields.push_back(NumberField("time_step", "s", &SolverSettings::timeStep, 0.0, false, kInfinity, false,
                               "explicit dynamics step; 0 = the critical step × `safety_factor`"));
  fields.push_back(NumberField("safety_factor", "", &SolverSettings::timeStepSafetyFactor, 0.0, true, 1.0, false,
                               "fraction of the critical time step used (1 is the stability limit)"));
  fields.push_back(NumberField("end_time", "s", &SolverSettings::endTime, 0.0, true, kInfinity, false,
                               "explicit dynamics end time"));
  fields.push_back(NumberField("damping", "1/s", &SolverSettings::dampingCoefficient, 0.0, false, kInfinity, false,
                               "explicit dynamics mass-proportional damping"));
  fields.push_back(NumberField("hourglass_coefficient", "", &SolverSettings::hourglassCoefficient, 0.0, false, 1.0,
                               false, "hexahedron hourglass stiffness k: k 2 mu V (B:B) / 8 per cell (docs/solver.md)"));
  fields.push_back(NumberField("collapse_bulk_modulus", "Pa", &SolverSettings::collapseBulkModulus, 0.0, false,
                               kInfinity, false,
                               "bulk modulus with which a cell or integration point resists collapse below half its "
                               "reference volume (docs/solver.md); 0 = the model's volume-weighted median bulk "
                               "modulus; a stiffer cell keeps its own"));
  fields.push_back(IntegerField("threads", &SolverSettings::threads, 0, 4096,
                                "worker threads, 0 = all (OpenMP default); results do not depend on it"));
  fields.push_back(MakeSettingField<SolverSettings>(
    Kind::Flag, "", "compute_stress", "", 0, false, 1, false,
    "compute the Cauchy stress per cell at the end (written as `cauchy_stress`)",
    [](const SolverSettings & s) { return s.computeStress ? 1.0 : 0.0; },
    [](SolverSettings & s, double v) { s.computeStress = v != 0.0; }));
  Field output = NumberField("output_interval", "s", &SolverSettings::outputInterval, 0.0, false, kInfinity, false,
                             "explicit dynamics: seconds between the frames `biomech simulate` writes (the first "
                             "step at or after each multiple, plus t = 0 and the end); 0 = none; required by "
                             "`simulate`");
  fields.push_back(output);
  return fields;
}

} // namespace

const std::vector<SolverSettingField> &
SolverSettingFields()
{
  static const std::vector<SolverSettingField> fields = MakeFields();
  return fields;
}

const SolverSettingField *
FindSolverSetting(const std::string & name)
{
  return FindSettingField(SolverSettingFields(), name);
}

void
SetSolverSetting(SolverSettings & settings, const std::string & name, const std::string & text)
{
  const SolverSettingField * field = FindSolverSetting(name);
  if (field == nullptr)
  {
    throw Error("unknown solver setting '" + name + "'; the settings are: " + SettingNames(SolverSettingFields()));
  }
  field->SetText(settings, text);
}

std::string
SolverSettingsMarkdown()
{
  return SettingsMarkdown(SolverSettingFields(), SolverSettings{});
}

} // namespace bmr
