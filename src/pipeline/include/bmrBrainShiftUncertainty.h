// Where to trust an update: an ensemble of intraoperative solves with the
// uncertain inputs drawn from stated distributions, and the spread of their
// displacements as a map on the preoperative grid.
#ifndef bmrBrainShiftUncertainty_h
#define bmrBrainShiftUncertainty_h

#include "bmrBrainShiftRegistration.h"
#include "bmrEnsemble.h"

#include <cstdint>
#include <string>
#include <vector>

namespace bmr
{

/** The uncertain inputs and how each is drawn: the mechanical ones
 *  (bmr::EnsembleSettings: members, seed, gravity's size, Young's moduli,
 *  Poisson's ratio, the skull gap, drawn by itk::BiomechanicalUncertaintyFilter)
 *  and the registration's own: the measurements' noise and the exposed
 *  region. Gravity's fractions are of the registration's gravity (given or
 *  fitted); when the gravity fit chose none, they are of the smallest nonzero
 *  size it tried (which it could not tell from none), with a warning. The
 *  skull gap is not drawn by default: the gap the model was made with is the
 *  skull's segmentation plus a margin, and how far that margin is from the
 *  real one is not measured here; the validation study draws it with 0.5 mm. */
struct UncertaintySettings : EnsembleSettings
{
  /** Measurement noise: a normal deviate of this standard deviation (mm) added
   *  to each component of each measured displacement (sparse points) or
   *  vertex (a displaced surface); 0.5 mm a component is about the 1 mm RMS
   *  of a tracked stylus or a laser range scan. Negative: the loads' RMS
   *  correspondence distance (the measured points' distance to the model's
   *  surface), which also holds the model surface's discretisation: on
   *  Colin27's 5 mm hexahedra 1.2 mm, under which 3 of 8 members folded a
   *  cell, the interpolating spline through independently perturbed close
   *  points being rough. */
  double noiseSigma = 0.5;
  /** The exposed region: the craniotomy's radius drawn as a normal deviate
   *  of this standard deviation (mm) around the registration's, at least half
   *  of it, and the model's regions (exposed, contact, fixed) made again for
   *  it (itk::BiomechanicalRegionsFilter), so that where the measured surface
   *  ends and the skull begins is uncertain. A spherical craniotomy only. 0:
   *  not perturbed (the default). */
  double exposedRadiusSpread = 0.0;
  /** The members' dynamic-relaxation tolerance (mm; 0: the registration's
   *  solver tolerance). A member starts from the update's steady state and
   *  stops within this of its own equilibrium, on the update's side, so the
   *  map can understate a spread by up to about this much. On the cost
   *  benchmark's 16 members (docs/benchmarks.md) 0.05 mm instead of 0.01 mm
   *  took the median member from 778 to 201 steps and the map's 95th
   *  percentile in the brain from 0.127 to 0.119 mm. */
  double memberTolerance = 0.05;
  /** Worker threads over the members (0: OpenMP's default); with at least
   *  as many members as threads each member's solve is single-threaded. */
  int threads = 0;
};

/** Throws bmr::Error naming the setting that is out of range. */
void
CheckUncertaintySettings(const UncertaintySettings & settings);

/** What one member drew and how its solve ended. */
struct UncertaintyMember : EnsembleMember
{
  double noiseSigma = 0.0;    // mm
  double exposedRadius = 0.0; // mm, the craniotomy's drawn radius; 0: the registration's
};

/** How deep inside the brain (mm) CSF counts as the ventricles' rather than the sulci's. */
constexpr double kVentricleDepth = 10.0;

struct BrainShiftUncertaintyResult
{
  std::vector<UncertaintyMember> members;
  int                            usedMembers = 0; // converged, in the statistics
  /** The mean of the converged members' nodal displacements, fitted as the
   *  registration's transform is (backward map). */
  RegistrationTransform::Pointer meanTransform;
  /** Per node: the 95th percentile over the converged members of
   *  |u_i - u_mean| (mm). */
  std::vector<double> nodalUncertainty;
  /** The same on the preoperative grid (mm; 0 outside the brain), between the
   *  nodes by the B-spline fit the transforms use. */
  RegistrationImage::Pointer uncertaintyImage;
  /** Nodal uncertainty's median and largest at the exposed nodes and at the
   *  others (mm). */
  double exposedMedian = 0.0, exposedMax = 0.0, interiorMedian = 0.0, interiorMax = 0.0;
  /** Map percentiles inside the brain (mm). */
  double brainMedian = 0.0, brainP95 = 0.0, brainMax = 0.0;
  /** The map inside regions (mm): the ventricles (voxels of the CSF class at
   *  least kVentricleDepth mm inside the brain) and each of the update's
   *  label maps (voxels > 0; "label map 1", ... in their order: the tumour or
   *  a resection margin, when given). */
  struct Region
  {
    std::string name;
    int         labelMap = -1; // its index in the update's label maps, or -1
    std::size_t voxels = 0;
    double      median = 0.0, p95 = 0.0, max = 0.0;
  };
  std::vector<Region> regions;
  double seconds = 0.0;
  std::vector<std::string> warnings;
};

/** The ensemble around an update: `prepared` is the model before its loads
 *  (as UpdateBrainShift takes it), `nominal` the update's result with the
 *  same inputs and settings. Each member loads the prepared model from its
 *  own noisy measurements (and its own exposed region), and
 *  itk::BiomechanicalUncertaintyFilter solves the members with their drawn
 *  gravity, materials and skull gap from the nominal steady state (members
 *  differ from it by small perturbations, so they take fewer steps than a
 *  cold solve), in parallel. A member that fails or does not converge is reported and left
 *  out of the statistics; fewer than two converged members throw bmr::Error,
 *  as do bad settings. */
BrainShiftUncertaintyResult
EstimateBrainShiftUncertainty(const BrainModel &                     prepared,
                              const BrainShiftRegistrationResult &   nominal,
                              const BrainShiftUpdateInputs &         inputs,
                              const BrainShiftRegistrationSettings & settings,
                              const UncertaintySettings &            uncertainty);

/** The ensemble after a registration or an update (`result`, with the
 *  `prepared` model it started from): EstimateBrainShiftUncertainty timed as
 *  the result's stage "uncertainty", its warnings added to the result's. */
BrainShiftUncertaintyResult
EstimateUncertaintyAfter(BrainShiftRegistrationResult &         result,
                         const BrainModel &                     prepared,
                         const BrainShiftUpdateInputs &         inputs,
                         const BrainShiftRegistrationSettings & settings,
                         const UncertaintySettings &            uncertainty);

/** The report's "uncertainty" entry: settings, members, statistics. */
nlohmann::json
UncertaintyReportJson(const BrainShiftUncertaintyResult & result, const UncertaintySettings & settings);

/** An axial slice through the largest uncertainty: the preoperative image in
 *  grey with the map over it (transparent at 0, yellow to red up to its
 *  maximum) as a PNG at `path`. */
void
WriteUncertaintyOverlay(const BrainShiftUncertaintyResult & result, const RegistrationImage * preoperative,
                        const std::string & path);

} // namespace bmr

#endif
