// The ground truth of `biomech demo` as files. `demo --truth-only` solves a
// scene's truth and writes it; `demo --truth-from FOLDER` reads it back and
// registers it, so that a study solves each truth once and runs every method
// as its own job (the Snakemake workflow in examples/validation).
#ifndef bmrDemoTruth_h
#define bmrDemoTruth_h

#include "bmrSyntheticBrainShift.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>

namespace bmr
{
namespace app
{

/** Writes what every demo writes of `truth` into `folder`: the intraoperative
 *  image and its brain mask, the displaced exposed surface, the tracked
 *  points and the ground-truth (backward) transform. With `reusable`, also
 *  what ReadTruthFiles needs beyond them: the forward transform, the
 *  intraoperative brain on the preoperative grid and the tumour mask (the
 *  second truth's transform, when there is one, the demo writes itself). */
void
WriteTruthFiles(const SyntheticBrainShift & truth, const std::filesystem::path & folder, bool reusable);

/** What `demo --truth-only` wrote: the truth (only what a registration and
 *  its scoring use: not the model, the solve or the timer, whose numbers the
 *  report holds), the scene settings the registration shares with it
 *  (craniotomy, tumour stiffness, CSF Poisson's ratio), the images it was
 *  made from, its report (demo-report.json), and the second truth of
 *  --truth-check when there was one (else null). */
struct TruthFiles
{
  SyntheticBrainShift            truth;
  SyntheticBrainShiftSettings    scene;
  std::string                    preoperativeImage;
  std::string                    brainMask;
  nlohmann::json                 report;
  RegistrationTransform::Pointer secondTruth;
};

/** Reads the truth that `demo --truth-only` wrote into `folder`. Throws Error
 *  naming a missing or unreadable file and saying to rerun `demo --truth-only`. */
TruthFiles
ReadTruthFiles(const std::filesystem::path & folder);

} // namespace app
} // namespace bmr

#endif
