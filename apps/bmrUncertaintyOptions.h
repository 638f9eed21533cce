// The uncertainty ensemble's options and steps shared by `register`,
// `update` (bmrModelCommands.cxx) and `demo` (bmrDemoCommand.cxx):
// --uncertainty N and its distributions (docs/registration.md, Uncertainty).
#ifndef bmrUncertaintyOptions_h
#define bmrUncertaintyOptions_h

#include "bmrBrainShiftUncertainty.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace bmr
{
namespace app
{

/** The ensemble of `register` and `update` (--uncertainty N and its distributions). */
struct UncertaintyOptions
{
  UncertaintySettings settings; // members 0: no ensemble
  std::vector<double> gravity;  // low, high
  std::vector<double> poisson;  // low, high

  void
  Add(CLI::App * command)
  {
    command
      ->add_option("--uncertainty", settings.members,
                   "An ensemble of this many solves with the uncertain inputs drawn (measurement noise, gravity's "
                   "size, Young's moduli, Poisson's ratio: docs/registration.md, Uncertainty); writes "
                   "displacement-uncertainty.nii.gz (per voxel the 95th percentile of |u_i - u_mean|, mm), "
                   "mean-transform.h5 and uncertainty-overlay.png")
      ->check(CLI::Range(2, 1000));
    command
      ->add_option("--uncertainty-noise", settings.noiseSigma,
                   "Measurement noise (mm, standard deviation per component); negative: the loads' RMS "
                   "correspondence distance; 0: none")
      ->capture_default_str();
    command
      ->add_option("--uncertainty-gravity", gravity,
                   "Gravity's size drawn uniformly between these fractions of the registration's, e.g. 0.5 1.5")
      ->expected(2);
    command
      ->add_option("--uncertainty-modulus-spread", settings.youngsModulusSpread,
                   "Standard deviation of the logarithm of one factor on every Young's modulus; 0: none")
      ->capture_default_str();
    command
      ->add_option("--uncertainty-tissue-modulus-spread", settings.tissueModulusSpread,
                   "Standard deviation of the logarithm of a factor per tissue class (CSF, grey, white matter, the "
                   "tumour) on top of the common one, the materials mixed again; 0: none")
      ->capture_default_str();
    command
      ->add_option("--uncertainty-poisson", poisson,
                   "The parenchyma's Poisson's ratio drawn uniformly in this range (default 0.45 0.499; 0 0: none)")
      ->expected(2);
    command
      ->add_option("--uncertainty-skull-gap", settings.skullGapSpread,
                   "Standard deviation (mm) of the skull's offset along its normals: the brain-skull gap; 0: none")
      ->capture_default_str();
    command
      ->add_option("--uncertainty-exposed-radius", settings.exposedRadiusSpread,
                   "Standard deviation (mm) of the craniotomy's radius, the exposed region made again per member "
                   "(a spherical craniotomy); 0: none")
      ->capture_default_str();
    command
      ->add_option("--uncertainty-tolerance", settings.memberTolerance,
                   "The members' dynamic-relaxation tolerance (mm; 0: the registration's solver tolerance)")
      ->capture_default_str();
    command->add_option("--uncertainty-seed", settings.seed, "Seed of the draws")->capture_default_str();
  }

  /** The settings with the ranges, checked (before any work). */
  UncertaintySettings
  Checked() const
  {
    UncertaintySettings checked = settings;
    if (!gravity.empty())
    {
      checked.gravityLow = gravity.at(0);
      checked.gravityHigh = gravity.at(1);
    }
    if (!poisson.empty())
    {
      checked.poissonLow = poisson.at(0);
      checked.poissonHigh = poisson.at(1);
    }
    if (checked.members != 0)
    {
      CheckUncertaintySettings(checked);
    }
    return checked;
  }
};

/** The ensemble after a registration (`prepared`: its model before the
 *  loads; bmr::EstimateUncertaintyAfter), its label-map regions named after
 *  `labelNames`. */
BrainShiftUncertaintyResult
RunEnsemble(const BrainModel & prepared, BrainShiftRegistrationResult & result, const BrainShiftUpdateInputs & inputs,
            const BrainShiftRegistrationSettings & settings, const UncertaintySettings & uncertainty,
            const std::vector<std::string> & labelNames);

/** The ensemble's files into `folder` (listed in `files`). */
void
WriteEnsemble(const BrainShiftUncertaintyResult & ensemble, const RegistrationImage * preoperative,
              const std::filesystem::path & folder, nlohmann::json & files);

} // namespace app
} // namespace bmr

#endif
