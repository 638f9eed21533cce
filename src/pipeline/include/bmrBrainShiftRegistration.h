// The whole brain-shift registration in one call: preoperative MRI (+ brain
// mask, tumour mask, skull surface) and intraoperative data (a displaced
// surface, sparse displacements, or an intraoperative image) -> patient
// model -> TLED solve -> B-spline transform -> warped preoperative image and
// label maps -> edge-based evaluation and a report.
//
// It composes the module's ITK filters and core on fixed image types (float
// intensities, unsigned char masks and labels) and is compiled once into the
// BiomechanicalRegistrationPipeline library, so that the command-line tool,
// the tests and the Python binding do not each instantiate every filter's
// templates. examples/BrainShiftRegistrationExample.cxx builds the same
// pipeline from the filters step by step.
//
// Units: mm (ITK physical space, LPS), Pa, kg/m^3, s.
#ifndef bmrBrainShiftRegistration_h
#define bmrBrainShiftRegistration_h

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBSplineTransform.h"
#include "itkImage.h"
#include "itkVectorImage.h"
#include "itkBiomechanicalModelObject.h"

#include "bmrBrainSurfaces.h"
#include "bmrFuzzyCMeans.h"
#include "bmrImageGrids.h"
#include "bmrMaterialMapping.h"
#include "bmrSettingsTable.h"
#include "bmrSolver.h"
#include "bmrSurfaceLoads.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace bmr
{

using RegistrationImage = itk::Image<float, 3>;
using RegistrationLabelImage = itk::Image<unsigned char, 3>;
/** Backward (resampling) map: intraoperative point -> preoperative point. */
using RegistrationTransform = itk::BSplineTransform<double, 3, 3>;

/** Stage events for progress displays: `seconds` < 0 when a stage starts,
 *  its wall time when it ends. */
using StageCallback = std::function<void(const std::string & stage, double seconds)>;

/** Wall time of named stages, in order; tells a StageCallback about each. */
class StageTimer
{
public:
  explicit StageTimer(StageCallback callback = {})
    : m_Callback(std::move(callback))
  {}

  template <typename Stage>
  auto Run(const std::string & name, Stage && stage)
  {
    Start(name);
    const auto start = Clock::now();
    struct Finish
    {
      StageTimer *             timer;
      const std::string &      name;
      Clock::time_point        start;
      ~Finish() { timer->Finish(name, start); }
    } finish{ this, name, start };
    return stage();
  }

  /** Seconds per stage in order, and "total". */
  nlohmann::json Json() const;
  const std::vector<std::pair<std::string, double>> & Stages() const { return m_Seconds; }
  /** Seconds of the named stage (0 when it did not run). */
  double Seconds(const std::string & name) const;

private:
  using Clock = std::chrono::steady_clock;
  void Start(const std::string & name);
  void Finish(const std::string & name, Clock::time_point start);

  StageCallback                               m_Callback;
  std::vector<std::pair<std::string, double>> m_Seconds;
};

// ---------------------------------------------------------------------------
// The patient model (shared with `biomech model`).
// ---------------------------------------------------------------------------

/** Atlas skull stripping (itk::AtlasBrainMaskImageFilter): Colin27 from Debian's mricron-data by default. */
struct AtlasSettings
{
  std::string image = "/usr/share/mricron/templates/ch2.nii.gz";
  std::string mask = "/usr/share/mricron/templates/ch2bet.nii.gz"; // voxels > 0 are brain
  bool        bsplineStage = true;                                  // false: affine only
};

/** Brain mask (1 inside) of a T1 image by atlas registration. Throws bmr::Error. */
RegistrationLabelImage::Pointer
AtlasBrainMask(const RegistrationImage * image, const AtlasSettings & settings = {});

/** Brain surface (level 0) and rigid skull (level skullGap of the mask
 *  closed by skullClosing mm; left empty without `skull`) of a mask
 *  (itk::BrainSurfaceMeshSource); its warnings are appended to `warnings`. */
BrainSurfaces
BrainSurfacesOfMask(const RegistrationLabelImage * mask, double skullGap, std::vector<std::string> & warnings,
                    bool skull = true, double skullClosing = BrainSurfaceSettings{}.skullClosing);
BrainSurfaces
BrainSurfacesOfMask(const LabelVolume & mask, double skullGap, std::vector<std::string> & warnings, bool skull = true,
                    double skullClosing = BrainSurfaceSettings{}.skullClosing);

/** The smooth surface (level 0) of a brain mask alone, without a skull: the
 *  cortex that a surface scan images (BrainSurfacesOfMask without the skull).
 *  Throws bmr::Error. */
ContactSurface
CortexSurfaceOfMask(const RegistrationLabelImage * brainMask, std::vector<std::string> & warnings);

/** 1 where `image` > 0, 0 elsewhere, same grid: a brain-extracted image
 *  such as Colin27's ch2bet.nii.gz as a mask. */
RegistrationLabelImage::Pointer
ThresholdMask(const RegistrationImage * image);

/** `image` resampled through the backward map `transform` onto `grid` (null:
 *  the image's own grid) with itk::TransformWarpImageFilter: linear for
 *  intensities, nearest neighbour for labels. Throws bmr::Error. */
RegistrationImage::Pointer
WarpImage(const RegistrationImage * image, const itk::Transform<double, 3, 3> * transform,
          const itk::ImageBase<3> * grid = nullptr);
RegistrationLabelImage::Pointer
WarpLabelImage(const RegistrationLabelImage * labels, const itk::Transform<double, 3, 3> * transform,
               const itk::ImageBase<3> * grid = nullptr);

/** A mask image as a core volume (voxels > 0 are 1). When `grid` is given the
 *  mask must lie on it; otherwise an Error names `what` and both grids. */
LabelVolume
MaskVolume(const RegistrationLabelImage * image, const std::string & what, const ImageGeometry * grid = nullptr);

struct BrainModelSettings
{
  /** Fuzzy c-means; 3 classes on a T1 image (CSF, grey, white: with 2, the
   *  darker class would be grey matter and get the CSF material). */
  FuzzyCMeansSettings classifier = [] {
    FuzzyCMeansSettings settings;
    settings.classes = 3;
    return settings;
  }();
  /** Which class is the CSF: the darkest (t1), the brightest (t2), or
   *  decided from the classes (auto; bmr::ChooseCsfClass). */
  TissueContrast contrast = TissueContrast::Auto;
  /** Materials per tissue class in T1 order (ascending centroid on a T1
   *  image: the CSF first; BuildBrainModel reverses them on a T2 image) and
   *  of the tumour. */
  MaterialMappingSettings materials;
  /** Hexahedra of 5 mm by default. */
  ImageGridSettings grid;
  /** Skull stripping when no brain mask is given. */
  AtlasSettings atlas;
  /** Gap between brain and the rigid skull made from the model (mm). */
  double skullGap = BrainSurfaceSettings{}.skullGap;
  /** Closing radius of the body before the skull is made (mm; 0: the skull
   *  follows every fold; bmr::BrainSurfaceSettings::skullClosing). */
  double skullClosing = BrainSurfaceSettings{}.skullClosing;
  /** Fixed skull base / brain stem band. */
  SkullBaseSettings skullBase;
  /** The craniotomy: a sphere (radius > 0) or a mask on any grid (voxels > 0). */
  Vector3                             craniotomyCentre = Vector3::Zero();
  double                              craniotomyRadius = 0.0;
  RegistrationLabelImage::ConstPointer craniotomyMask;
  /** Tissue removed by the surgery (voxels > 0, on the image grid; null:
   *  none), e.g. the planned resection: the fluid that fills the cavity takes
   *  its place (the CSF class's material, bmr::MapMaterialsFromMemberships),
   *  so that the cavity's walls can sag into it. */
  RegistrationLabelImage::ConstPointer resectionMask;
  /** Brain-skull contact of every surface node that is neither fixed nor exposed (itk::BiomechanicalRegionsFilter). */
  bool contact = true;
  /** Body acceleration (mm/s^2); zero: none (registration loads by displacements only). */
  Vector3 gravity = Vector3::Zero();
  /** CSF drainage under gravity: the CSF's surface lies this far (mm) below
   *  the brain's highest node along gravity; only the tissue above it carries
   *  its weight (Model::fluidSurface). Unset: the whole brain does. */
  std::optional<double> csfDrainedDepth;
  /** Threads of the grid and material mapping; 0: OpenMP's default. */
  int threads = 0;
};

/** Intraoperative data. The exposed surface's motion comes from `surface`
 *  or `sparse` (not both); when neither is given, from `image`: the boundary
 *  of `imageBrainMask`, or of a mask from atlas skull stripping of `image`.
 *  `image`, when given, is also the fixed image of the evaluation. */
struct IntraoperativeData
{
  ContactSurface                       surface; // displaced exposed (or whole) brain surface, mm
  SparseDisplacements                  sparse;  // preoperative points and their displacements, mm
  RegistrationImage::ConstPointer      image;
  RegistrationLabelImage::ConstPointer imageBrainMask;
  /** Measurements farther than this from the model surface are left out (mm). */
  double maxDistance = SurfaceLoadSettings{}.maxDistance;
  /** A displaced surface (or the image's) is matched along this direction,
   *  e.g. gravity's, instead of by closest points (SurfaceLoadSettings::matchDirection). */
  std::optional<Vector3> surfaceMatchDirection;
};

struct BrainModel
{
  /** The model as one scene: fixed skull base, prescribed exposed-surface
   *  displacements, contact (what `biomech model` writes). */
  Model                    model;
  BrainSurfaces            surfaces; // preoperative brain surface and the skull (contact master)
  /** The classifier's fit (centroids, iterations, convergence). */
  FuzzyCMeansResult        classificationFit;
  /** The class that became the CSF (ascending centroid order) and why,
   *  and its volume (mm^3, voxels whose largest membership is the CSF's). */
  CsfClassChoice           csfClass;
  double                   csfVolume = 0.0;
  LabelVolume              brainMask;
  /** Brain removed by settings.resectionMask (mm^3; 0 without one). */
  double                   resectedVolume = 0.0;
  GridQuality              gridQuality;
  std::vector<Index>       exposedNodes;
  PrescribedDisplacement   load;
  LoadReport               loadReport;
  std::vector<std::string> warnings;
  /** The cortex: the smooth surface of the brain mask (CortexSurfaceOfMask)
   *  that a displaced surface is matched to; made when the loads may need it
   *  (always by PrepareBrainModel with `cortex`), else empty. */
  ContactSurface           cortex;
  /** The same model as the pipeline hands it to itk::BiomechanicalDeformationFilter:
   *  the regions filter's output (materials, node sets "skull_base" (fixed),
   *  "exposed", "contact", gravity; no loads, no contact surface), the loads
   *  filter's point set (null without measurements) and the skull mesh (null
   *  without contact). */
  itk::BiomechanicalModelObject::Pointer           pipelineModel;
  itk::DisplacementPointSetType<3>::Pointer        prescribedDisplacements;
  itk::BiomechanicalSurfaceMeshType::Pointer       contactSurface;
  /** The classifier's outputs, shared with the material mapping rather than
   *  copied (about 85 MB on Colin27): memberships per class (component k:
   *  class k, ascending centroid) and the class of largest membership (1..K). */
  itk::VectorImage<float, 3>::ConstPointer membershipImage;
  RegistrationLabelImage::ConstPointer     tissueLabelImage;
};

/** Builds the model of `image` inside `brainMask` (null: atlas skull stripping
 *  with Colin27 from mricron-data), with `tumourMask` (may be null) as a stiff
 *  region, the skull from the model dilated by settings.skullGap (or
 *  `skullSurface` when it has triangles), and, when `intraoperative` is not
 *  null, the exposed nodes loaded from it. Masks must lie on the image grid.
 *  Throws bmr::Error naming the bad input. */
BrainModel
BuildBrainModel(const RegistrationImage *      image,
                const RegistrationLabelImage * brainMask,
                const RegistrationLabelImage * tumourMask,
                const ContactSurface &         skullSurface,
                const IntraoperativeData *     intraoperative,
                const BrainModelSettings &     settings,
                StageTimer &                   timer);

/** The preoperative phase of BuildBrainModel, without intraoperative data:
 *  skull stripping (without a mask), classification, grid, materials,
 *  surfaces (and the cortex when `cortex`), regions; no loads and no contact
 *  yet. settings.craniotomy* must be given. Throws bmr::Error. */
BrainModel
PrepareBrainModel(const RegistrationImage *      image,
                  const RegistrationLabelImage * brainMask,
                  const RegistrationLabelImage * tumourMask,
                  const ContactSurface &         skullSurface,
                  const BrainModelSettings &     settings,
                  StageTimer &                   timer,
                  bool                           cortex);

/** The intraoperative phase's first step on a prepared model: the exposed
 *  nodes' displacements from `intraoperative` (the "loads" stage; a surface
 *  scan is matched to model.cortex, which must then be there) and the
 *  skull's contact. Throws bmr::Error naming the bad input. */
void
LoadBrainModel(BrainModel & model, const IntraoperativeData & intraoperative, const BrainModelSettings & settings,
               StageTimer & timer);

// ---------------------------------------------------------------------------
// The registration.
// ---------------------------------------------------------------------------

struct BrainShiftRegistrationSettings
{
  BrainModelSettings model;
  /** Dynamic relaxation to 0.01 mm (far below the 0.1 mm a registration needs). */
  SolverSettings solver = [] {
    SolverSettings settings;
    settings.tolerance = 0.01;
    return settings;
  }();
  /** Gravity's size fitted to the intraoperative image; 0: gravity as given.
   *  After CSF loss the brain sinks under a weight that depends on how much
   *  CSF drained, which nothing measures; the head's position gives only its
   *  direction. With gravity (model.gravity: its direction, and the largest
   *  size tried) and an intraoperative image, this many sizes evenly spread
   *  over [0, |gravity|] are solved, then up to three more towards the best
   *  (a parabola's vertex, or a midpoint at an end of the range); the size
   *  whose registered preoperative image has the highest Mattes mutual
   *  information with the intraoperative image inside its brain (its brain
   *  mask, or the preoperative one) is kept. One parameter, so contrast, noise and a resection cannot bend the
   *  field the way they bend an intensity registration's. */
  int gravityFitCandidates = 0;
  /** Transform fit: largest residual at the nodes, and the finest control-point spacing (mm). */
  double fitTolerance = 0.1;
  double minimumControlPointSpacing = 1.0;
  /** Evaluation: axial slices (axis 2) or whole volume (-1), and the registered-edge distance (mm). */
  int    evaluationSliceAxis = 2;
  double evaluationDistanceThreshold = 1.7;
};

/** The prepared model's Total Lagrangian precomputation (the "precompute"
 *  stage; bmr::SolverPrecomputation with settings.solver's formulation), set
 *  on model.pipelineModel so that every solve of the model uses it: the last
 *  step of `biomech prepare`, stored in the model bundle. Throws bmr::Error. */
void
PrecomputeBrainModel(BrainModel & model, const BrainShiftRegistrationSettings & settings, StageTimer & timer);

/** The registration's settings as one table (bmrSettingsTable.h), read by
 *  `biomech model` and `biomech register` (--name-with-dashes; a flag whose
 *  default is true is --no-name), Python's register() and
 *  build_brain_model() keywords, and docs/registration.md (`biomech settings
 *  --registration --markdown` prints it; a test checks the docs). Groups:
 *  "model" (BrainModelSettings: what `biomech model` takes), "solve", "fit",
 *  "evaluation". What is not one value is not a row, and each face names it
 *  itself: the craniotomy (a sphere or a mask), gravity, the CSF drained
 *  depth, and the intraoperative data's max_distance. */
using RegistrationSettingField = SettingField<BrainShiftRegistrationSettings>;

const std::vector<RegistrationSettingField> &
RegistrationSettingFields();

/** The docs' table (Markdown) of RegistrationSettingFields. */
std::string
RegistrationSettingsMarkdown();

struct BrainShiftRegistrationInputs
{
  RegistrationImage::ConstPointer      preoperativeImage;
  RegistrationLabelImage::ConstPointer brainMask;  // null: atlas skull stripping
  RegistrationLabelImage::ConstPointer tumourMask; // optional
  ContactSurface                       skullSurface; // optional (no triangles: made from the model)
  /** Label maps on the preoperative grid, warped with nearest-neighbour interpolation. */
  std::vector<RegistrationLabelImage::ConstPointer> labelMaps;
  IntraoperativeData                   intraoperative;
};

/** Edge-based Hausdorff evaluation of one registration (itk::EdgeHausdorffDistanceImageFilter). */
struct EdgeEvaluation
{
  bool                valid = false;
  std::string         message;
  std::vector<double> symmetric; // mm at percentiles 1..100
  double              fractionWithinThreshold = 0.0;
  std::size_t         fixedEdges = 0, movingEdges = 0;
  /** Edge images (1 on edges) for overlays, on the intraoperative grid. */
  RegistrationLabelImage::Pointer fixedEdgeImage, movingEdgeImage;
  double Percentile(int k) const { return valid ? symmetric.at(static_cast<std::size_t>(k - 1)) : 0.0; }
};

struct BrainShiftRegistrationResult
{
  BrainModel                     model;
  SolveResult                    solve;
  /** The gravity fit (settings.gravityFitCandidates): the sizes solved
   *  (mm/s^2) with the mutual information of each (higher: better), in the
   *  order solved; empty without a fit. */
  std::vector<std::pair<double, double>> gravityFit;
  /** Each size's solve, in gravityFit's order: its dynamic-relaxation steps
   *  (0: it failed) and the size (mm/s^2) whose steady state it started from
   *  (negative: the update's own start, rest or `previous`). */
  struct GravityFitSolve
  {
    int    steps = 0;
    double startSize = -1.0;
  };
  std::vector<GravityFitSolve>   gravityFitSolves;
  Vector3                        gravity = Vector3::Zero(); // the solve's body acceleration (mm/s^2)
  RegistrationTransform::Pointer transform;      // backward map
  double                         fitMaxResidual = 0.0, fitRmsResidual = 0.0; // mm, at the nodes
  int                            fitLevels = 0;
  bool                           fitToleranceReached = false;
  RegistrationImage::Pointer     warpedImage;    // preoperative grid
  std::vector<RegistrationLabelImage::Pointer> warpedLabelMaps;
  /** With an intraoperative image: the preoperative image before and after
   *  registration, resampled onto the intraoperative grid, and their evaluations. */
  RegistrationImage::Pointer      unregisteredOnIntraoperativeGrid, registeredOnIntraoperativeGrid;
  RegistrationLabelImage::Pointer evaluationMask;
  EdgeEvaluation                  unregistered, registered;
  StageTimer                      timer;
  std::vector<std::string>        warnings;

  bool Evaluated() const { return registeredOnIntraoperativeGrid.IsNotNull(); }
};

/** Runs the pipeline. A solve that does not converge is not an exception:
 *  the result says so (solve.converged false, solve.message), and the caller
 *  decides (the `register` subcommand exits 2). A solve that fails (inverted
 *  element) and bad input throw bmr::Error naming the problem. With
 *  `prepared`, the model before its loads is copied there (what
 *  EstimateBrainShiftUncertainty starts each member from). */
BrainShiftRegistrationResult
RegisterBrainShift(const BrainShiftRegistrationInputs &   inputs,
                   const BrainShiftRegistrationSettings & settings,
                   const StageCallback &                  stageCallback = {},
                   const ProgressCallback &               solverProgress = {},
                   BrainModel *                           prepared = nullptr);

/** What the intraoperative phase needs beside the prepared model. */
struct BrainShiftUpdateInputs
{
  RegistrationImage::ConstPointer                   preoperativeImage; // warped; the gravity fit's moving image
  std::vector<RegistrationLabelImage::ConstPointer> labelMaps;         // on the preoperative grid
  IntraoperativeData                                intraoperative;
  /** A later update of the same surgery: every solve (the gravity fit's
   *  candidates too) starts from the previous update's steady state
   *  (ReadUpdateSolution); empty: from rest. The result is the cold solve's
   *  within the solver tolerance, in fewer steps. */
  WarmStart                                         previous;
};

/** The intraoperative phase on a prepared model (PrepareBrainModel, or a
 *  model bundle read back): loads, (gravity fit,) solve, transform fit,
 *  warp, evaluation. `RegisterBrainShift` is PrepareBrainModel followed by
 *  this, so the two phases give bitwise the same result as the one call.
 *  settings.model is read for the loads, gravity and CSF settings only.
 *  Throws as RegisterBrainShift does. */
BrainShiftRegistrationResult
UpdateBrainShift(BrainModel                             model,
                 const BrainShiftUpdateInputs &         inputs,
                 const BrainShiftRegistrationSettings & settings,
                 const StageCallback &                  stageCallback = {},
                 const ProgressCallback &               solverProgress = {});

/** Edge detection of the evaluation (itk::EdgeHausdorffDistanceImageFilter's
 *  Canny settings); an empty value keeps the filter's default. Fixed
 *  thresholds (both given) turn the automatic ones off. */
struct EdgeDetectionSettings
{
  std::optional<double> variance;               // Gaussian variance, mm^2
  std::optional<double> upperThresholdQuantile; // automatic thresholds
  std::optional<double> lowerThresholdRatio;
  std::optional<double> upperThreshold;         // fixed thresholds (gradient magnitude)
  std::optional<double> lowerThreshold;
};

/** Edge-based Hausdorff between `fixed` and `moving` (same grid) inside `mask` (may be null). */
EdgeEvaluation
EvaluateEdges(const RegistrationImage *      fixed,
              const RegistrationImage *      moving,
              const RegistrationLabelImage * mask,
              int                            sliceAxis = 2,
              double                         distanceThreshold = 1.7,
              const EdgeDetectionSettings &  edges = {});

/** Grey range of edge overlays: the image's minimum and 99.5th percentile
 *  (a few very bright voxels would otherwise leave the anatomy dark). */
std::pair<double, double>
OverlayGreyRange(const RegistrationImage * image);

/** Axial edge-overlay PNGs of an evaluation (fixed edges red, moving blue,
 *  both green, over `background` in grey): `count` slices evenly spread over
 *  those with edges, written as FOLDER/PREFIX-SLICE.png. Returns the paths. */
std::vector<std::string>
WriteEdgeOverlays(const EdgeEvaluation &    evaluation,
                  const RegistrationImage * background,
                  const std::string &       folder,
                  const std::string &       prefix,
                  int                       count = 5);

/** The class that became the CSF: contrast, class (the tissue label's value
 *  1..K), centroid, volume (mL) and why it was chosen; the "csf" entry of
 *  the registration's and `biomech model`'s reports. */
nlohmann::json
CsfClassJson(const BrainModel & model);

/** Report: stage times, model size, solver convergence and estimated error,
 *  fit residual, evaluation (keys in docs/registration.md). */
nlohmann::json
RegistrationReportJson(const BrainShiftRegistrationResult & result, const BrainShiftRegistrationSettings & settings);

/** A short human-readable table of the same; says NOT CONVERGED loudly. */
std::string
FormatRegistrationTable(const BrainShiftRegistrationResult & result);

} // namespace bmr

#endif
