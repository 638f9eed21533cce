// The model bundle: a brain model prepared before surgery (`biomech
// prepare`, bmr::PrepareBrainModel) written to a folder, and read back for
// each intraoperative update (`biomech update`, bmr::UpdateBrainShift).
//
// A bundle is a folder (docs/registration.md, "The model bundle"):
//   manifest.json          format name and version, the module's version, the
//                          preoperative image's exact geometry, the settings,
//                          the preparation's report, and every file with its
//                          size and CRC-32
//   model.bin              the model, lossless: nodes, cells, materials, node
//                          sets, constraints, meshless integration points, and
//                          the brain, skull and cortex surfaces
//   precomputation.bin     the solver's Total Lagrangian precomputation
//                          (bmr::SolverPrecomputation: shape-function
//                          derivatives, hourglass vectors, ANP averaging, the
//                          kernels' schedules, the meshless MLS tables)
//   preoperative.nii.gz    the preoperative image (float32), brain-mask.nii.gz,
//   tissue-classes.nii.gz  the classes (1..K), labels-K.nii.gz the label maps
//   model.vtu, brain.vtp, skull.vtp, cortex.vtp (+ integration-points.vtu):
//                          the same model and surfaces for a viewer (ParaView,
//                          3D Slicer); not read back
// A bundle of another version, a missing, truncated or edited file, or a
// manifest that does not parse is a bmr::Error that names the file and says
// to prepare the bundle again: never a wrong solve. A bundle is written into
// a temporary folder beside its target and renamed, so a failed `prepare`
// leaves no half-written bundle.
//
// What is not in the bundle: the masses (they follow each solve's time step)
// and the contact search trees (CGAL's AABB trees point into the surfaces),
// which each update's solver builds (docs/registration.md says what it costs).
#ifndef bmrModelBundle_h
#define bmrModelBundle_h

#include "bmrBrainShiftRegistration.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace bmr
{

/** The bundle format's version: a bundle of another version is not read. */
constexpr int kModelBundleVersion = 4; // 2: precomputation.bin; 3: the materials' laws; 4: the tissue mixture (2 and 3 are still read)
constexpr int kOldestModelBundleVersion = 2;

struct ModelBundle
{
  /** As PrepareBrainModel made it (no loads, no contact yet; the cortex made). */
  BrainModel                                   model;
  RegistrationImage::Pointer                   preoperativeImage;
  std::vector<RegistrationLabelImage::Pointer> labelMaps;
  /** Their file names as given to prepare (the warped maps are named after them). */
  std::vector<std::string>                     labelMapNames;
  /** Every setting of the table as prepared (the model's, and the solve's,
   *  fit's and evaluation's defaults for the updates). */
  BrainShiftRegistrationSettings               settings;
  /** The manifest as written or read (the preparation's report under "prepare"). */
  nlohmann::json                               manifest;
};

/** Writes `bundle` (manifest from its parts; bundle.manifest["prepare"], when
 *  set, is kept as the preparation's report) into `folder`, replacing a bundle
 *  there; returns the manifest written. Throws bmr::Error naming the file
 *  that could not be written. */
nlohmann::json
WriteModelBundle(const std::filesystem::path & folder, const ModelBundle & bundle);

/** Reads a bundle WriteModelBundle wrote; every file's size and CRC-32 are
 *  checked against the manifest first. Throws bmr::Error naming the folder,
 *  the file and what to do. */
ModelBundle
ReadModelBundle(const std::filesystem::path & folder);

/** An update's steady state, written beside its report (solution.bin) so
 *  that the next update of the same surgery can start from it (`biomech
 *  update --previous OUT`, UpdateBrainShift's `previous`). */
struct UpdateSolution
{
  WarmStart start;
  /** The steps of this update's solve, and those of the cold (not
   *  warm-started) solve at the head of its chain of updates: a warm start's
   *  saving is said against that one. */
  int       steps = 0;
  int       coldSteps = 0;
  /** The bundle's model.bin CRC-32 and node count: a solution is read back
   *  only with the bundle whose model it solved. */
  std::uint32_t modelChecksum = 0;
  Index         nodes = 0;
};

/** The solution of `solve` on the model of the bundle described by
 *  `bundleManifest`; `coldSteps` from the chain's head (solve.steps for a cold solve). */
UpdateSolution
MakeUpdateSolution(const SolveResult & solve, const nlohmann::json & bundleManifest, int coldSteps);

/** Writes solution.bin atomically. Throws bmr::Error naming the file. */
void
WriteUpdateSolution(const std::filesystem::path & file, const UpdateSolution & solution);

/** Reads `folder`/solution.bin (or the file itself) and checks that it
 *  solved the model of the bundle described by `bundleManifest`. Throws
 *  bmr::Error naming the file and what to do (a missing file, another
 *  bundle's solution, a damaged file). */
UpdateSolution
ReadUpdateSolution(const std::filesystem::path & previous, const nlohmann::json & bundleManifest);

} // namespace bmr

#endif
