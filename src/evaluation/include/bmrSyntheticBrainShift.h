// A brain shift with a known answer, for the README demo, the validation
// study and the tests: a craniotomy, the brain sinking under gravity after
// CSF loss with contact against the skull, solved with an independent, finer
// model (by default hexahedra of 4 mm on a grid not nested in the
// registration's 5 mm one, loaded by gravity and skull contact instead of
// surface displacements; see docs/validation.md for why not tetrahedra); from it an "intraoperative" image (the
// preoperative image warped, resampled to a typical intraoperative
// resolution, with noise) and the displaced exposed brain surface, the only
// thing the registration is given. Also: the intensity-based B-spline
// registration baseline on the same pair. The error of any transform against
// the ground truth: bmrRegistrationMetrics.h.
//
// Units: mm, Pa, kg/m^3, s.
#ifndef bmrSyntheticBrainShift_h
#define bmrSyntheticBrainShift_h

#include "bmrBrainShiftRegistration.h"
#include "bmrRegistrationMetrics.h"

#include <optional>

namespace bmr
{

/** The intraoperative image's contrast: the preoperative T1's, a T2-like one
 *  (CSF bright, white matter dark) or a low-field T1-like one (less contrast
 *  between the tissue classes). */
enum class IntraoperativeContrast
{
  Preoperative,
  T2Like,
  LowFieldT1
};

const char *
IntraoperativeContrastName(IntraoperativeContrast contrast);

/** "preoperative", "t2", "low-field-t1"; throws bmr::Error naming the choices. */
IntraoperativeContrast
ParseIntraoperativeContrast(const std::string & name);

/** Gaussian noise, or Rician: the magnitude of complex Gaussian noise, as in
 *  magnitude MR images at low signal-to-noise ratio (low field). */
enum class NoiseModel
{
  Gaussian,
  Rician
};

/** The building blocks of the synthetic intraoperative image. */

/** The image in another contrast: three tissue classes (CSF, grey, white
 *  matter) from fuzzy c-means on the brain's voxels; intensity is mapped
 *  piecewise linearly through the class centres (0 -> 0, centre k -> its
 *  level in the new contrast, the last segment's ratio beyond). T2-like:
 *  CSF at white matter's T1 level, grey matter at 0.65 and white matter at
 *  0.5 of it (CSF twice, grey matter 1.3 times white matter); low-field T1: each class at half its T1 contrast to white matter. A
 *  function of the T1 intensity, so still mutual information's ideal case (a
 *  real T2 is not): it tests that a method copes with another contrast. */
RegistrationImage::Pointer
MakeImageInContrast(const RegistrationImage * image, const RegistrationLabelImage * brainMask,
                    IntraoperativeContrast contrast);

/** Multiplies the image by 1 + amplitude p(x), p a random quadratic
 *  polynomial of the grid's normalised coordinates whose largest magnitude
 *  over the grid is 1: a smooth receive-coil bias field. */
void
ApplyBiasField(RegistrationImage * image, double amplitude, std::uint32_t seed);

/** Adds noise of standard deviation `deviation` (Gaussian), or takes the
 *  magnitude of the value plus complex Gaussian noise (Rician). */
void
AddImageNoise(RegistrationImage * image, double deviation, NoiseModel model, std::uint32_t seed);

struct SyntheticBrainShiftSettings
{
  /** Craniotomy: the exposed surface (sphere). "Down" points from the
   *  craniotomy towards the brain's centroid (the head lies with the opening up). */
  Vector3 craniotomyCentre = Vector3(-11.0, 43.0, 84.0);
  double  craniotomyRadius = 30.0;
  /** The shift: the exposed surface sinks by targetShift (1 - (r/R)^2) mm
   *  along "down" (r: distance from the craniotomy centre, R its radius),
   *  the CSF-loss sag; the rest of the brain carries gravity (in g, along
   *  "down") and rests on the skull. Gravity alone cannot make the sag: it
   *  folds the soft CSF cells first (4 mm hexahedra folded at 0.84 g before
   *  the exposed surface had sunk 10 mm). */
  double targetShift = 10.0;
  /** Width of the opening's rim, as a fraction of its radius, whose exposed
   *  nodes are left to the model (neither moved nor touching the skull): the
   *  sag is prescribed only for r < (1 - freeRim) R. 0 pins the sag's zero at
   *  the rim; shifts of 15 mm and more need about 0.2, because a ring held
   *  fixed around a deep sag folds the cells at the ring (25 mm on Colin27:
   *  docs/model-building.md). */
  double freeRim = 0.0;
  double gravity = 0.3; // g
  /** The displaced surface reaches this far beyond the craniotomy (mm). */
  double scanMargin = 10.0;
  /** Spacing of the tracked surface points (mm). */
  double trackedPointSpacing = 5.0;

  /** The ground-truth model: a finer grid than the registration's default. */
  ImageGridSettings grid = [] {
    ImageGridSettings settings;
    settings.kind = ImageGridKind::Hexahedra;
    settings.elementSize = 4.0;
    return settings;
  }();
  double solverTolerance = 0.01; // mm
  int    solverMaxSteps = 0;      // dynamic-relaxation steps before the truth's solve gives up; 0: the solver's default
  /** Closing radius of the ground truth's body before its skull is made (mm;
   *  BrainModelSettings::skullClosing; 1 mm by default, as the registration's:
   *  the dura does not follow sulci; 0: the skull follows every fold, e.g. the
   *  Sylvian fissure as a thin sheet). `biomech demo --truth-skull-closing`. */
  double skullClosing = BrainSurfaceSettings{}.skullClosing;

  /** Materials: Poisson's ratio of parenchyma (and tumour), Young's modulus
   *  of the CSF class (ventricles; 10 Pa by default, "very soft" below). */
  double poissonRatio = ParenchymaMaterial().poissonRatio;
  double csfYoungsModulus = CsfMaterial().youngsModulus;
  /** Poisson's ratio of the CSF class, in the ground truth and (biomech demo)
   *  the registration. The default 0.1 lets CSF cells be crushed: shifts of
   *  20 mm invert CSF tetrahedra. A nearly incompressible, fluid-like CSF
   *  (0.49) keeps them: see docs/model-building.md, "Limits". */
  double csfPoissonRatio = CsfMaterial().poissonRatio;
  /** The CSF has drained (that is why the brain sinks): its class carries
   *  almost no weight. With its full weight, 10 Pa CSF cells cannot carry
   *  themselves under gravity and fold (3 mm hexahedra diverge at 0.3 g). */
  double csfDensity = 1.0; // kg/m^3
  /** Physics the registration does not model (docs/validation.md, "Truths of
   *  another kind"), so that a study judging it is not an inverse crime.
   *  CSF drained only partly: the CSF's surface lies this far (mm) below the
   *  brain's highest node along gravity; the tissue below it stays buoyed and
   *  carries no weight (Model::fluidSurface, Miga et al. 1999). Negative:
   *  drained completely, as the registration assumes. */
  double csfDrainedDepth = -1.0;
  /** A bonded brain-skull interface over part of the surface: the skull-contact
   *  nodes deeper than this (mm along "down" from the craniotomy's centre) are
   *  held to the skull (zero displacement) instead of sliding on it, as
   *  tethering by the dura's attachments, vessels and nerves at the skull base
   *  would. Negative: none (frictionless sliding everywhere). */
  double bondedDepth = -1.0;
  /** Heterogeneous parenchyma: Young's moduli of grey and white matter (Pa)
   *  on a three-class classification (CSF, grey, white), e.g. 1390 and 1895 Pa
   *  from indentation (Budday et al. 2015); both 0: one parenchyma of
   *  ParenchymaMaterial()'s modulus on two classes, as the registration. */
  double greyMatterYoungsModulus = 0.0;
  double whiteMatterYoungsModulus = 0.0;
  /** Another law: parenchyma and tumour Mooney-Rivlin (docs/materials.md)
   *  with this share C01 / (C10 + C01) in (0, 1] and the same small-strain
   *  moduli, where the registration is neo-Hookean; 0: neo-Hookean. */
  double mooneyRivlinShare = 0.0;

  /** A synthetic spherical tumour (radius 0: none), stiffness x parenchyma. */
  Vector3 tumourCentre = Vector3::Zero();
  double  tumourRadius = 0.0;
  double  tumourStiffness = 2.0;

  /** The intraoperative image: voxel spacing (mm) and noise (standard
   *  deviation as a fraction of the 99.5th intensity percentile). */
  Vector3       intraoperativeSpacing = Vector3(0.86, 0.86, 2.5);
  double        noise = 0.02;
  NoiseModel    noiseModel = NoiseModel::Gaussian;
  std::uint32_t seed = 1;
  /** Realistic intraoperative images (docs/validation.md): another contrast
   *  (a function of the preoperative intensity through its tissue classes),
   *  a smooth multiplicative bias field (largest deviation from 1, e.g. 0.2),
   *  and a partial field of view (edge of a cube in mm around the craniotomy
   *  and what lies beneath it; 0: the whole head). */
  IntraoperativeContrast contrast = IntraoperativeContrast::Preoperative;
  double                 biasField = 0.0;
  double                 fieldOfView = 0.0;
  /** A resection cavity: the tumour and this margin (mm) removed before the
   *  intraoperative image; negative: no resection (needs a tumour). The
   *  cavity's cells carry the drained CSF's material, so its walls sag; in the
   *  image it is fluid, and it is left out of the intraoperative brain. */
  double resectionMargin = -1.0;

  int threads = 0;
};

struct SyntheticBrainShift
{
  BrainModel  model;          // the ground-truth model (gravity, contact, no prescribed motion)
  SolveResult solve;          // its converged solution
  Vector3     gravity = Vector3::Zero(); // mm/s^2
  Vector3     down = Vector3::Zero();    // unit vector from the craniotomy towards the brain's centroid
  double      shift = 0.0;    // mm, largest displacement of the exposed nodes
  /** Backward map of the ground truth (intraoperative point -> preoperative point),
   *  fitted to its nodes with a tolerance of 0.05 mm. Not always reached:
   *  truthFitMaxResidual says how close it came (Colin27, 2026-11-26: 4 mm
   *  hexahedra 0.07 mm, 5-6 mm ANP tetrahedra 1.5-2.4 mm). */
  RegistrationTransform::Pointer truthTransform;
  double                         truthFitMaxResidual = 0.0;
  /** Forward map of the ground truth (preoperative point -> intraoperative
   *  point), fitted to the same nodes: moves surface points and electrodes. */
  RegistrationTransform::ConstPointer forwardTransform;
  RegistrationImage::Pointer      intraoperativeImage;     // intraoperative grid (field of view), contrast, bias, noise
  RegistrationLabelImage::Pointer intraoperativeBrainMask; // intraoperative grid; without the resection cavity
  /** The intraoperative brain on the preoperative grid (the whole brain, also
   *  outside a partial field of view; without the resection cavity): where
   *  displacement errors are measured. */
  RegistrationLabelImage::Pointer intraoperativeBrainOnPreoperativeGrid;
  /** The displaced exposed brain surface: the preoperative brain surface
   *  within craniotomyRadius + scanMargin, moved by the ground truth. */
  ContactSurface                  exposedSurface;
  /** Tracked points of the exposed surface (one per trackedPointSpacing cube,
   *  within the craniotomy) with their ground-truth displacements. */
  SparseDisplacements             trackedPoints;
  RegistrationLabelImage::Pointer tumourMask; // preoperative grid; null without a tumour
  double                          resectionCavityRadius = 0.0; // mm around the tumour's centre; 0: no resection
  /** The planned resection on the preoperative grid (the brain within
   *  resectionCavityRadius of the tumour's centre), what a registration may be
   *  given (BrainModelSettings::resectionMask); null without a resection. */
  RegistrationLabelImage::Pointer resectionMask;
  StageTimer                      timer;
};

/** The ground truth's first half: its model with the sag prescribed, gravity
 *  and skull contact (model, gravity, down, tumourMask,
 *  resectionCavityRadius, timer), not solved: the same scene for another
 *  solver, e.g. an implicit reference. Throws bmr::Error for bad settings. */
SyntheticBrainShift
MakeSyntheticBrainShiftModel(const RegistrationImage *           preoperativeImage,
                             const RegistrationLabelImage *      brainMask,
                             const SyntheticBrainShiftSettings & settings,
                             const StageCallback &               stageCallback = {});

/** Makes the ground truth. The preoperative image and brain mask must share a
 *  grid. Throws bmr::Error when the solve fails or does not converge. */
SyntheticBrainShift
MakeSyntheticBrainShift(const RegistrationImage *           preoperativeImage,
                        const RegistrationLabelImage *      brainMask,
                        const SyntheticBrainShiftSettings & settings,
                        const StageCallback &               stageCallback = {});

/** The intensity-based baseline (itk::BSplineIntensityRegistrationFilter with
 *  its defaults: translation, then B-spline 80 -> 40 -> 20 mm, Mattes mutual
 *  information, L-BFGS-B): `fixed` is the intraoperative image, `moving` the
 *  preoperative one; `fixedMask` may be null. */
struct BaselineRegistration
{
  RegistrationTransform::Pointer transform;       // fixed point -> moving point (a backward map)
  RegistrationImage::Pointer     warpedOnFixedGrid;
  double                         seconds = 0.0;
};

struct BaselineSettings
{
  std::vector<unsigned int> shrinkFactors{ 4, 2, 1 };
  std::vector<double>       smoothingSigmas{ 2.0, 1.0, 0.0 };
  unsigned int              iterations = 0; // per level; 0: the filter's default
  // Empty: the filter's default (itkBSplineIntensityRegistrationFilter.h).
  std::optional<double>       controlPointSpacing; // mm, finest level
  std::optional<bool>         useTranslationStage;
  std::optional<unsigned int> translationIterations;
  std::optional<bool>         refineMeshPerLevel;
  std::optional<unsigned int> histogramBins;
  std::optional<double>       metricSamplingPercentage;
  std::optional<double>       costFunctionConvergenceFactor;
  std::optional<int>          randomSeed;
};

BaselineRegistration
RegisterWithBSplineBaseline(const RegistrationImage *      fixed,
                            const RegistrationImage *      moving,
                            const RegistrationLabelImage * fixedMask,
                            const BaselineSettings &       settings = {});

} // namespace bmr

#endif
