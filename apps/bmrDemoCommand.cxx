// `biomech demo`: brain-shift registration against a known answer. Makes a
// ground-truth brain shift of Colin27 with an independent, finer model
// (bmrSyntheticBrainShift.h), registers from the displaced exposed surface
// only, runs the B-spline intensity baseline (and elastix, the peer users
// pick) on the same pair, and reports time, displacement error against the
// ground truth and edge-based Hausdorff distances for each method.
#include "bmrImageCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBSplineTransform.h"
#include "itkBiomechanicalTransformIO.h"
#include "itkIdentityTransform.h"
#include "itkImageFileWriter.h"

#include "bmrElastixPeer.h"

#include "bmrCommandSupport.h"
#include "bmrDemoTruth.h"
#include "bmrUncertaintyOptions.h"

#include "bmrMeshIO.h"
#include "bmrSyntheticElectrodeCt.h"
#include "bmrSyntheticBrainShift.h"
#include "bmrUnits.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>

#include <unistd.h>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bmr
{
namespace app
{
namespace
{

// The largest brain shift the module is built for (mm): the cut-off of matches along gravity.
constexpr double kLargestExpectedShift = 25.0;
// The error near a tumour or a resection cavity is measured within this distance (mm) of it.
constexpr double kNearTumourDistance = 10.0;
// The ventricles: the CSF class deeper than this (mm) below the brain's surface (VentricleMask).
constexpr double kVentricleDepth = 10.0;

struct DemoOptions
{
  std::string                 image = "/usr/share/mricron/templates/ch2.nii.gz";
  std::string                 mask = "/usr/share/mricron/templates/ch2bet.nii.gz";
  std::string                 outputDirectory = "out/demo";
  SyntheticBrainShiftSettings truth;
  std::vector<double>         craniotomyCentre;
  std::vector<double>         tumourCentre;
  std::vector<double>         greyWhiteModuli; // the truth's grey and white matter (Pa); empty: one parenchyma
  std::string                 truthGrid = "hexahedra";
  std::vector<std::string>    variants{ "hexahedra:5" };
  std::string                 truthCheck; // KIND:SIZE of a second ground truth; empty: none
  std::string                 load = "points";
  std::string                 surfaceMatch = "closest";
  double                      registrationGravity = 0.0; // g
  int                         gravityFitCandidates = 0;
  UncertaintyOptions          uncertainty; // an ensemble after each biomechanical registration, calibrated on the truth
  bool                        noBaseline = false;
  bool                        noRegistrationResection = false; // the registration is not told the planned resection
  bool                        truthOnly = false; // solve and write the truth, register nothing
  std::string                 truthFrom;         // a --truth-only folder to read the truth from
  bool                        elastix = false;
  std::vector<std::string>    elastixParameters;
  std::string                 peerField;  // a peer registration run elsewhere: its displacement field,
  std::string                 peerWarped; // its warped image,
  std::string                 peerName;   // the method's name in the report,
  double                      peerSeconds = 0.0; // its run time
  std::string                 peerDetails; // and a JSON object of what it was (tool, version, parameters)
  std::string                 contrast = "preoperative";
  std::string                 noiseModel = "gaussian";
  std::vector<double>         intraoperativeSpacing;
  std::vector<unsigned int>   baselineShrinkFactors{ 4, 2, 1 };
  unsigned int                baselineIterations = 0;
  int                         overlays = 3;
  bool                        quiet = false;
};

/** One registration method's numbers. */
struct MethodResult
{
  std::string       name;
  double            seconds = 0.0;
  json              stages = json::object();
  DisplacementError error;
  std::optional<DisplacementError> nearTumourError; // within kNearTumourDistance of the tumour or the cavity
  std::optional<double>            tumourSurfaceDistance; // 95th percentile, mm (StructureSurfaceDistance)
  std::optional<double>            ventricleSurfaceDistance; // 95th percentile, mm; none: not measured
  EdgeEvaluation    edges;
  json              details = json::object();
};

/** A displacement error's statistics (mm) as the report writes them. */
json
DisplacementErrorJson(const DisplacementError & error)
{
  return { { "mean", error.mean }, { "p95", error.p95 }, { "max", error.max }, { "samples", error.samples } };
}

json
MethodJson(const MethodResult & method)
{
  json result = { { "name", method.name },
                  { "seconds", method.seconds },
                  { "stages", method.stages },
                  { "displacement_error_mm", DisplacementErrorJson(method.error) },
                  { "details", method.details } };
  if (method.nearTumourError)
  {
    result["displacement_error_near_tumour_mm"] = DisplacementErrorJson(*method.nearTumourError);
  }
  if (method.tumourSurfaceDistance)
  {
    result["tumour_surface_distance_p95_mm"] = *method.tumourSurfaceDistance;
  }
  if (method.ventricleSurfaceDistance)
  {
    result["ventricle_surface_distance_p95_mm"] = *method.ventricleSurfaceDistance;
  }
  if (method.edges.valid)
  {
    result["hausdorff_mm"] = { { "p50", method.edges.Percentile(50) },
                               { "p90", method.edges.Percentile(90) },
                               { "p95", method.edges.Percentile(95) },
                               { "p100", method.edges.Percentile(100) } };
    result["fraction_within_1_7_mm"] = method.edges.fractionWithinThreshold;
    result["hausdorff_curve_mm"] = method.edges.symmetric;
  }
  else
  {
    result["hausdorff_mm"] = nullptr;
    result["evaluation_message"] = method.edges.message;
  }
  return result;
}

void
PrintTable(const std::vector<MethodResult> & methods)
{
  // The name column as wide as the longest name ("biomechanical mixed 5 mm + fitted gravity").
  int width = 26;
  for (const MethodResult & method : methods)
  {
    width = std::max(width, static_cast<int>(method.name.size()));
  }
  std::printf("\n%-*s %9s | %27s | %27s | %9s | %10s\n", width, "", "time", "displacement error (mm)",
              "edge Hausdorff (mm)", "edges", "ventricles");
  std::printf("%-*s %9s | %8s %8s %9s | %8s %8s %9s | %9s | %10s\n", width, "method", "s", "mean", "p95", "max", "p50",
              "p90", "p95", "<1.7 mm", "p95 (mm)");
  for (const MethodResult & method : methods)
  {
    char ventricles[32] = "-";
    if (method.ventricleSurfaceDistance)
    {
      std::snprintf(ventricles, sizeof ventricles, "%.2f", *method.ventricleSurfaceDistance);
    }
    std::printf("%-*s %9.2f | %8.2f %8.2f %9.2f | %8.2f %8.2f %9.2f | %8.1f%% | %10s\n", width, method.name.c_str(),
                method.seconds, method.error.mean, method.error.p95, method.error.max, method.edges.Percentile(50),
                method.edges.Percentile(90), method.edges.Percentile(95), 100.0 * method.edges.fractionWithinThreshold,
                ventricles);
  }
  std::printf("\ntime per stage (s)\n");
  for (const MethodResult & method : methods)
  {
    if (method.stages.empty())
    {
      continue;
    }
    std::printf("  %-*s", width, method.name.c_str());
    for (const auto & [stage, seconds] : method.stages.items())
    {
      std::printf(" %s %.2f", stage.c_str(), seconds.get<double>());
    }
    std::printf("\n");
  }
}

std::string
FormatNumber(double value)
{
  std::ostringstream text;
  text << value;
  return text.str();
}

/** "hexahedra:5" -> grid settings; `option` names the option in errors. */
ImageGridSettings
ParseVariant(const std::string & variant, const std::string & option = "--variant")
{
  const auto colon = variant.find(':');
  if (colon == std::string::npos)
  {
    throw Error(option + " '" + variant + "': write it as KIND:SIZE, e.g. hexahedra:5 or meshless:7");
  }
  ImageGridSettings settings;
  settings.kind = ParseImageGridKind(variant.substr(0, colon));
  try
  {
    settings.elementSize = std::stod(variant.substr(colon + 1));
  }
  catch (const std::exception &)
  {
    throw Error(option + " '" + variant + "': the size after ':' must be a number (mm)");
  }
  return settings;
}

int
RunDemo(DemoOptions options)
{
  const fs::path output(options.outputDirectory);
  const bool     terminal = !options.quiet && ::isatty(STDERR_FILENO) != 0;
  const StageCallback stages = terminal ? StageCallback(StepTimer::PrintStage) : StageCallback();

  if (!options.craniotomyCentre.empty())
  {
    options.truth.craniotomyCentre = Vector3(options.craniotomyCentre.at(0), options.craniotomyCentre.at(1),
                                             options.craniotomyCentre.at(2));
  }
  if (!options.tumourCentre.empty())
  {
    options.truth.tumourCentre = Vector3(options.tumourCentre.at(0), options.tumourCentre.at(1), options.tumourCentre.at(2));
  }
  if (!options.greyWhiteModuli.empty())
  {
    options.truth.greyMatterYoungsModulus = options.greyWhiteModuli.at(0);
    options.truth.whiteMatterYoungsModulus = options.greyWhiteModuli.at(1);
  }
  options.truth.grid.kind = ParseImageGridKind(options.truthGrid);
  options.truth.contrast = ParseIntraoperativeContrast(options.contrast);
  options.truth.noiseModel = options.noiseModel == "rician" ? NoiseModel::Rician : NoiseModel::Gaussian;
  if (!options.intraoperativeSpacing.empty())
  {
    options.truth.intraoperativeSpacing =
      Vector3(options.intraoperativeSpacing.at(0), options.intraoperativeSpacing.at(1), options.intraoperativeSpacing.at(2));
  }
  // Before the long ground-truth solve: the peer's files.
  options.elastix = options.elastix || !options.elastixParameters.empty();
  if (options.elastix)
  {
    for (const char * program : { "elastix", "transformix" })
    {
      if (!OnPath(program))
      {
        throw Error(std::string(program) + " is not on PATH: install Debian's elastix (scripts/install-dependencies.sh) "
                    "or leave out --elastix");
      }
    }
    if (options.elastixParameters.empty())
    {
      options.elastixParameters = DefaultElastixParameters();
    }
  }
  json peerDetails = json::object();
  if (!options.peerDetails.empty())
  {
    try
    {
      std::ifstream in(options.peerDetails);
      peerDetails = json::parse(in);
    }
    catch (const json::exception & exception)
    {
      throw Error("--peer-details: " + options.peerDetails + " is not readable JSON (" + exception.what() + ")");
    }
    if (!peerDetails.is_object())
    {
      throw Error("--peer-details: " + options.peerDetails + " must hold a JSON object (what the peer was)");
    }
  }
  const UncertaintySettings uncertainty = options.uncertainty.Checked();
  std::vector<ImageGridSettings> variants;
  if (options.truthOnly)
  {
    options.variants.clear();
    options.noBaseline = true;
  }
  for (const std::string & variant : options.variants)
  {
    if (variant == "none" && options.variants.size() == 1)
    {
      break; // the intensity registrations alone
    }
    variants.push_back(ParseVariant(variant));
  }
  std::optional<ImageGridSettings> truthCheckGrid;
  if (!options.truthCheck.empty())
  {
    truthCheckGrid = ParseVariant(options.truthCheck, "--truth-check");
  }

  // A cached truth brings its scene: the images it was made from and what the registration shares with it.
  std::optional<TruthFiles> cached;
  if (!options.truthFrom.empty())
  {
    std::error_code same;
    if (fs::weakly_canonical(options.truthFrom, same) == fs::weakly_canonical(output, same))
    {
      throw Error("--truth-from " + options.truthFrom + " is also the output folder: the registration would replace "
                  "the truth's report; write it elsewhere with -o");
    }
    cached = ReadTruthFiles(options.truthFrom);
    options.image = cached->preoperativeImage;
    options.mask = cached->brainMask;
    options.truth.craniotomyCentre = cached->scene.craniotomyCentre;
    options.truth.craniotomyRadius = cached->scene.craniotomyRadius;
    options.truth.tumourStiffness = cached->scene.tumourStiffness;
    options.truth.csfPoissonRatio = cached->scene.csfPoissonRatio;
  }
  const RegistrationImage::Pointer      preoperative = ReadImage<RegistrationImage>(options.image, "preoperative image");
  const RegistrationLabelImage::Pointer brainMask = ReadMaskImage(options.mask, "brain mask");

  if (!options.quiet)
  {
    if (!options.truthFrom.empty())
    {
      std::cerr << "ground truth: read from " << options.truthFrom << "\n";
    }
    else
    {
      std::cerr << "ground truth: " << ImageGridKindName(options.truth.grid.kind) << " "
                << options.truth.grid.elementSize << " mm, " << options.truth.targetShift
                << " mm sag of the exposed surface, gravity " << options.truth.gravity << " g\n";
    }
  }
  const SyntheticBrainShift truth =
    cached ? std::move(cached->truth) : MakeSyntheticBrainShift(preoperative, brainMask, options.truth, stages);
  const RegistrationImage *      intraoperative = truth.intraoperativeImage;
  const RegistrationLabelImage * intraoperativeMask = truth.intraoperativeBrainMask;
  // A peer run elsewhere on the truth's images: its files checked before anything is written.
  std::optional<IntensityPeer> externalPeer;
  if (!options.peerField.empty())
  {
    externalPeer = ReadIntensityPeer(options.peerField, options.peerWarped, preoperative, intraoperative);
    externalPeer->seconds = options.peerSeconds;
  }

  CreateFolder(output);
  std::error_code ignored;
  fs::remove(output / "demo-report.json", ignored);
  WriteTruthFiles(truth, output, options.truthOnly);
  // The epilepsy workflow: a grid on the shifted brain, seen in a CT; its
  // contacts, found and projected along gravity (the head's position in the
  // operating room tells its direction), load the registration.
  std::optional<ElectrodeLocalisation> electrodes;
  json                                 electrodeReport;
  if (options.load == "electrodes")
  {
    StageTimer                 timer(stages);
    const SyntheticElectrodeCt ct = timer.Run("electrode-ct", [&] {
      return MakeSyntheticElectrodeCt(preoperative, brainMask, truth, options.truth.craniotomyCentre);
    });
    WriteImageAtomically(ct.image.GetPointer(), output / "electrodes-ct.nii.gz");
    ElectrodeLocalisationSettings settings;
    settings.detection.expectedContacts = static_cast<int>(ct.contacts.size());
    settings.projectionDirection = truth.down;
    electrodes = timer.Run("electrodes", [&] { return LocateElectrodes(ct.image, preoperative, ElectrodeReferenceSurface(brainMask), settings); });
    WriteSparseDisplacements((output / "electrode-displacements.csv").string(), electrodes->loads);
    const ElectrodeLocalisationErrors errors = MeasureElectrodeLocalisation(*electrodes, ct);
    electrodeReport = { { "contacts", ct.contacts.size() },
                        { "found", electrodes->contacts.size() },
                        { "each_found_once", errors.eachContactFoundOnce },
                        { "detection_max_mm", errors.detectionMax },
                        { "location_mean_mm", errors.locationMean },
                        { "location_max_mm", errors.locationMax },
                        { "displacement_error_mean_mm", errors.displacementMean },
                        { "displacement_error_max_mm", errors.displacementMax },
                        { "alignment_seconds", electrodes->alignment.seconds },
                        { "seconds", timer.Json() } };
    if (!options.quiet)
    {
      std::cerr << "electrodes: " << electrodes->contacts.size() << " of " << ct.contacts.size()
                << " contacts found, located within " << errors.locationMax
                << " mm, measured displacements within " << errors.displacementMax << " mm\n";
    }
  }
  const fs::path overlays = output / "overlays";

  // A second ground truth of the same scene on another discretization: how far
  // two truths differ is the smallest error a registration can be judged by.
  json                           truthCheckReport = cached ? cached->report.value("ground_truth_check", json()) : json();
  RegistrationTransform::Pointer secondTruth = cached ? cached->secondTruth : nullptr;
  if (truthCheckGrid)
  {
    SyntheticBrainShiftSettings checkSettings = options.truth;
    checkSettings.grid.kind = truthCheckGrid->kind;
    checkSettings.grid.elementSize = truthCheckGrid->elementSize;
    if (!options.quiet)
    {
      std::cerr << "second ground truth: " << ImageGridKindName(checkSettings.grid.kind) << " "
                << checkSettings.grid.elementSize << " mm\n";
    }
    const SyntheticBrainShift check = [&] {
      try
      {
        return MakeSyntheticBrainShift(preoperative, brainMask, checkSettings);
      }
      catch (const Error & error)
      {
        throw Error("--truth-check " + options.truthCheck + ": the second ground truth failed: " + error.what());
      }
    }();
    const DisplacementError   difference = MeasureDisplacementError(check.truthTransform, truth.truthTransform,
                                                                  truth.intraoperativeBrainOnPreoperativeGrid);
    itk::WriteBiomechanicalTransform(check.truthTransform, (output / "ground-truth-check-transform.h5").string());
    secondTruth = check.truthTransform;
    truthCheckReport = { { "grid", ImageGridKindName(checkSettings.grid.kind) },
                         { "element_size_mm", checkSettings.grid.elementSize },
                         { "nodes", check.model.model.nodes.size() },
                         { "cells", check.model.model.cells.size() },
                         { "shift_mm", check.shift },
                         { "solve_steps", check.solve.steps },
                         { "solve_estimated_error_mm", check.solve.estimatedError },
                         { "fit_max_residual_mm", check.truthFitMaxResidual },
                         { "difference_from_truth_mm", DisplacementErrorJson(difference) },
                         { "seconds", check.timer.Json() } };
    if (!options.quiet)
    {
      std::cerr << "the two ground truths differ by " << difference.mean << " / " << difference.p95 << " / "
                << difference.max << " mm (mean / p95 / max over the brain)\n";
    }
  }

  std::vector<MethodResult> methods;
  // Near the tumour, or the cavity's walls after a resection: the brain within kNearTumourDistance of it.
  const RegistrationLabelImage * structure =
    truth.resectionMask.IsNotNull() ? truth.resectionMask.GetPointer() : truth.tumourMask.GetPointer();
  const RegistrationLabelImage::Pointer nearTumour =
    structure != nullptr ? RegionNear(structure, truth.intraoperativeBrainOnPreoperativeGrid, kNearTumourDistance)
                         : nullptr;
  const std::optional<StructureSurfaceDistance> tumourSurface =
    structure != nullptr ? std::make_optional<StructureSurfaceDistance>(truth.truthTransform, structure) : std::nullopt;
  // The ventricles' surface, found in the preoperative T1; an image where they are not found (another contrast,
  // part of a brain) is measured without it, and the report says why.
  json                                    ventricleReport;
  std::optional<StructureSurfaceDistance> ventricleSurface;
  try
  {
    const RegistrationLabelImage::Pointer ventricles = VentricleMask(preoperative, brainMask, kVentricleDepth);
    WriteImageAtomically(ventricles.GetPointer(), output / "ventricle-mask.nii.gz");
    const auto   spacing = ventricles->GetSpacing();
    const auto * voxels = ventricles->GetBufferPointer();
    const double volume = spacing[0] * spacing[1] * spacing[2] *
                          static_cast<double>(std::count_if(voxels, voxels + ventricles->GetBufferedRegion().GetNumberOfPixels(),
                                                            [](unsigned char v) { return v > 0; }));
    ventricleSurface.emplace(truth.truthTransform, ventricles);
    ventricleReport = { { "depth_mm", kVentricleDepth },
                        { "volume_mm3", volume },
                        { "mask", "ventricle-mask.nii.gz" },
                        { "definition", "the CSF class deeper than depth_mm below the brain's surface, opened by 2 mm, "
                                        "its largest connected component" } };
  }
  catch (const Error & error)
  {
    ventricleReport = { { "error", error.what() } };
    if (!options.quiet)
    {
      std::cerr << "the ventricles' surface is not measured: " << error.what() << "\n";
    }
  }
  // A method's error against the ground truth (also near the tumour), and against the second truth when there is one.
  const auto score = [&](const itk::Transform<double, 3, 3> * transform, MethodResult & method) {
    method.error = MeasureDisplacementError(transform, truth.truthTransform, truth.intraoperativeBrainOnPreoperativeGrid);
    if (nearTumour)
    {
      method.nearTumourError = MeasureDisplacementError(transform, truth.truthTransform, nearTumour);
      method.tumourSurfaceDistance = tumourSurface->Percentile95(transform);
    }
    if (ventricleSurface)
    {
      method.ventricleSurfaceDistance = ventricleSurface->Percentile95(transform);
    }
    if (secondTruth)
    {
      method.details["displacement_error_against_second_truth_mm"] = DisplacementErrorJson(
        MeasureDisplacementError(transform, secondTruth, truth.intraoperativeBrainOnPreoperativeGrid));
    }
  };
  {
    // The preoperative image as it is, against the intraoperative one: what every method improves on.
    MethodResult none;
    none.name = "no registration";
    score(nullptr, none);
    const auto identity = itk::IdentityTransform<double, 3>::New();
    none.edges = EvaluateEdges(intraoperative, WarpImage(preoperative, identity, intraoperative), intraoperativeMask);
    methods.push_back(none);
    WriteEdgeOverlays(none.edges, intraoperative, overlays.string(), "none", options.overlays);
  }

  for (const ImageGridSettings & grid : variants)
  {
    if (!options.quiet)
    {
      std::cerr << "biomechanical registration: " << ImageGridKindName(grid.kind) << " " << grid.elementSize << " mm\n";
    }
    BrainShiftRegistrationInputs inputs;
    inputs.preoperativeImage = preoperative;
    inputs.brainMask = brainMask;
    inputs.tumourMask = truth.tumourMask;
    if (options.load == "surface")
    {
      inputs.intraoperative.surface = truth.exposedSurface;
      if (options.surfaceMatch == "gravity")
      {
        // Along gravity a match's length is the shift itself, not a distance across a gap: the cut-off
        // that keeps closest-point outliers out (10 mm) would drop the deepest points of a 10 mm sag.
        inputs.intraoperative.surfaceMatchDirection = truth.down;
        inputs.intraoperative.maxDistance = kLargestExpectedShift;
      }
    }
    else if (options.load == "electrodes")
    {
      inputs.intraoperative.sparse = electrodes->loads;
    }
    else
    {
      inputs.intraoperative.sparse = truth.trackedPoints;
    }
    inputs.intraoperative.image = intraoperative;
    inputs.intraoperative.imageBrainMask = intraoperativeMask;
    BrainShiftRegistrationSettings settings;
    settings.model.grid = grid;
    settings.model.threads = options.truth.threads;
    settings.model.craniotomyCentre = options.truth.craniotomyCentre;
    settings.model.craniotomyRadius = options.truth.craniotomyRadius;
    // The head's position gives gravity's direction in the operating room; its effective size is a model choice.
    settings.model.gravity = options.registrationGravity * units::StandardGravity * truth.down;
    settings.model.materials.tumour.youngsModulus = options.truth.tumourStiffness * ParenchymaMaterial().youngsModulus;
    // The surgeon's plan (the tumour and its margin) says what was removed; fluid fills it, as in the truth.
    if (!options.noRegistrationResection)
    {
      settings.model.resectionMask = truth.resectionMask;
    }
    settings.gravityFitCandidates = options.gravityFitCandidates;
    // The registration's CSF has the ground truth's Poisson's ratio (its stiffness stays the default) and, as
    // the drained CSF it is, the ground truth's (almost no) weight.
    Material csf = CsfMaterial();
    csf.poissonRatio = options.truth.csfPoissonRatio;
    csf.density = options.truth.csfDensity;
    settings.model.materials.classMaterials = DefaultClassMaterials(settings.model.classifier.classes, csf);
    BrainModel                   prepared; // the ensemble's model before the loads
    BrainShiftRegistrationResult result =
      RegisterBrainShift(inputs, settings, stages, {}, uncertainty.members > 0 ? &prepared : nullptr);
    std::optional<BrainShiftUncertaintyResult> ensemble;
    if (uncertainty.members > 0)
    {
      const BrainShiftUpdateInputs update{ inputs.preoperativeImage, inputs.labelMaps, inputs.intraoperative };
      ensemble = RunEnsemble(prepared, result, update, settings, uncertainty, {});
    }
    MethodResult method;
    method.name = "biomechanical " + std::string(ImageGridKindName(grid.kind)) + " " +
                  FormatNumber(grid.elementSize) + " mm" +
                  (options.gravityFitCandidates > 0 ? " + fitted gravity"
                   : options.registrationGravity > 0.0 ? " + " + FormatNumber(options.registrationGravity) + " g"
                                                       : "") +
                  (ensemble ? ", uncertainty " + std::to_string(uncertainty.members) : "");
    method.stages = result.timer.Json();
    // The registration's time: everything but the evaluation, which needs the intraoperative image.
    method.seconds = method.stages["total"].get<double>() - result.timer.Seconds("evaluate");
    method.edges = result.registered;
    method.details = RegistrationReportJson(result, settings);
    method.details.erase("evaluation");
    score(result.transform, method);
    const std::string tag = std::string(ImageGridKindName(grid.kind)) + "-" + FormatNumber(grid.elementSize);
    if (ensemble)
    {
      // How often the true error lies within the map's 95 % bound: the registration's and the ensemble mean's.
      const auto calibration = [&](const itk::Transform<double, 3, 3> * transform) {
        const UncertaintyCalibration measured = MeasureUncertaintyCalibration(
          transform, truth.truthTransform, truth.intraoperativeBrainOnPreoperativeGrid, ensemble->uncertaintyImage);
        return json{ { "fraction_within_bound", measured.fractionWithinBound },
                     { "median_error_mm", measured.medianError },
                     { "median_bound_mm", measured.medianBound },
                     { "samples", measured.samples } };
      };
      method.details["uncertainty"] = UncertaintyReportJson(*ensemble, uncertainty);
      method.details["uncertainty"]["calibration"] = { { "transform", calibration(result.transform) },
                                                       { "mean_transform", calibration(ensemble->meanTransform) } };
      const fs::path folder = output / ("uncertainty-biomechanical-" + tag);
      CreateFolder(folder);
      json files;
      WriteEnsemble(*ensemble, preoperative, folder, files);
      method.details["uncertainty"]["files"] = files;
    }
    methods.push_back(method);
    WriteImageAtomically(result.warpedImage.GetPointer(), output / ("warped-biomechanical-" + tag + ".nii.gz"));
    itk::WriteBiomechanicalTransform(result.transform, (output / ("transform-biomechanical-" + tag + ".h5")).string());
    WriteEdgeOverlays(result.registered, intraoperative, overlays.string(), "biomechanical-" + tag, options.overlays);
  }

  if (!options.noBaseline)
  {
    if (!options.quiet)
    {
      std::cerr << "B-spline intensity registration (baseline)\n";
    }
    BaselineSettings settings;
    settings.shrinkFactors = options.baselineShrinkFactors;
    settings.smoothingSigmas.clear();
    for (const unsigned int factor : options.baselineShrinkFactors)
    {
      settings.smoothingSigmas.push_back(factor > 1 ? factor / 2.0 : 0.0);
    }
    settings.iterations = options.baselineIterations;
    const BaselineRegistration baseline = RegisterWithBSplineBaseline(intraoperative, preoperative, intraoperativeMask, settings);
    MethodResult method;
    method.name = "B-spline intensity";
    method.seconds = baseline.seconds;
    method.stages = { { "register", baseline.seconds } };
    score(baseline.transform, method);
    method.edges = EvaluateEdges(intraoperative, baseline.warpedOnFixedGrid, intraoperativeMask);
    methods.push_back(method);
    WriteImageAtomically(baseline.warpedOnFixedGrid.GetPointer(), output / "warped-bspline-on-intraoperative-grid.nii.gz");
    itk::WriteBiomechanicalTransform(baseline.transform, (output / "transform-bspline.h5").string());
    WriteEdgeOverlays(method.edges, intraoperative, overlays.string(), "bspline", options.overlays);
  }

  // A peer's method row: its error, its own warped image's edges, its overlays.
  const auto addPeer = [&](const IntensityPeer & peer, MethodResult method, const std::string & overlayName) {
    method.seconds = peer.seconds;
    method.edges = EvaluateEdges(intraoperative, peer.warpedOnFixedGrid, intraoperativeMask);
    score(peer.transform, method);
    methods.push_back(method);
    WriteEdgeOverlays(method.edges, intraoperative, overlays.string(), overlayName, options.overlays);
  };
  if (options.elastix)
  {
    if (!options.quiet)
    {
      std::cerr << "elastix (peer): " << options.elastixParameters.size() << " parameter files\n";
    }
    const IntensityPeer peer =
      RegisterWithElastix(output / "intraoperative.nii.gz", options.image, output / "intraoperative-brain-mask.nii.gz",
                          options.elastixParameters, preoperative, output / "elastix", options.truth.threads);
    if (peer.warpedOnFixedGrid->GetLargestPossibleRegion() != intraoperative->GetLargestPossibleRegion())
    {
      throw Error("transformix's warped image is not on the intraoperative grid; check the parameter files' output settings");
    }
    // The same grid, read back from single-precision NIfTI: take the exact geometry.
    peer.warpedOnFixedGrid->CopyInformation(intraoperative);
    MethodResult method;
    method.name = "elastix B-spline";
    method.stages = { { "register", peer.seconds }, { "transformix", peer.outputSeconds } };
    method.details = { { "parameter_files", options.elastixParameters }, { "folder", (output / "elastix").string() } };
    addPeer(peer, method, "elastix");
  }
  if (externalPeer)
  {
    MethodResult method;
    method.name = options.peerName;
    method.stages = { { "register", externalPeer->seconds } };
    method.details = peerDetails;
    method.details["field"] = options.peerField;
    method.details["warped"] = options.peerWarped;
    addPeer(*externalPeer, method, "peer");
  }

  json report;
  report["preoperative_image"] = options.image;
  report["brain_mask"] = options.mask;
  report["load"] = options.load;
  report["surface_match"] = options.surfaceMatch;
  if (!options.truthFrom.empty())
  {
    report["ground_truth"] = cached->report["ground_truth"];
    report["ground_truth"]["read_from"] = options.truthFrom;
    report["ground_truth"]["reusable"] = false; // this folder has the truth's common files only
  }
  else
  {
    report["ground_truth"] = {
      { "grid", ImageGridKindName(options.truth.grid.kind) },
      { "element_size_mm", options.truth.grid.elementSize },
      { "nodes", truth.model.model.nodes.size() },
      { "cells", truth.model.model.cells.size() },
      { "craniotomy_centre_mm", { options.truth.craniotomyCentre.x(), options.truth.craniotomyCentre.y(),
                                  options.truth.craniotomyCentre.z() } },
      { "craniotomy_radius_mm", options.truth.craniotomyRadius },
      { "target_shift_mm", options.truth.targetShift },
      { "free_rim", options.truth.freeRim },
      { "skull_closing_mm", options.truth.skullClosing },
      { "shift_mm", truth.shift },
      { "gravity_mm_s2", { truth.gravity.x(), truth.gravity.y(), truth.gravity.z() } },
      { "gravity_g", truth.gravity.norm() / units::StandardGravity },
      { "solve_steps", truth.solve.steps },
      { "solve_restarts", truth.solve.restarts },
      { "solve_estimated_error_mm", truth.solve.estimatedError },
      { "fit_max_residual_mm", truth.truthFitMaxResidual },
      { "poisson_ratio", options.truth.poissonRatio },
      { "csf_youngs_modulus_pa", options.truth.csfYoungsModulus },
      { "csf_poisson_ratio", options.truth.csfPoissonRatio },
      { "csf_drained_depth_mm", options.truth.csfDrainedDepth >= 0.0 ? json(options.truth.csfDrainedDepth) : json() },
      { "bonded_depth_mm", options.truth.bondedDepth >= 0.0 ? json(options.truth.bondedDepth) : json() },
      { "bonded_nodes", truth.model.model.nodeSets.count("bonded to the skull") > 0
                          ? truth.model.model.nodeSets.at("bonded to the skull").size() : 0 },
      { "grey_white_youngs_moduli_pa", options.greyWhiteModuli.empty() ? json() : json(options.greyWhiteModuli) },
      { "tumour_radius_mm", options.truth.tumourRadius },
      { "tumour_stiffness", options.truth.tumourStiffness },
      { "intraoperative_spacing_mm", { options.truth.intraoperativeSpacing.x(), options.truth.intraoperativeSpacing.y(),
                                       options.truth.intraoperativeSpacing.z() } },
      { "noise", options.truth.noise },
      { "noise_model", options.noiseModel },
      { "intraoperative_contrast", IntraoperativeContrastName(options.truth.contrast) },
      { "bias_field", options.truth.biasField },
      { "field_of_view_mm", options.truth.fieldOfView },
      { "resection_cavity_radius_mm", truth.resectionCavityRadius },
      { "down", { truth.down.x(), truth.down.y(), truth.down.z() } },
      { "reusable", options.truthOnly },
      { "seconds", truth.timer.Json() } };
  }
  if (!truthCheckReport.is_null())
  {
    report["ground_truth_check"] = truthCheckReport;
  }
  if (nearTumour)
  {
    // What the methods' displacement_error_near_tumour_mm measures.
    report["near_tumour"] = { { "structure", truth.resectionMask.IsNotNull() ? "resection cavity" : "tumour" },
                              { "distance_mm", kNearTumourDistance },
                              { "region", "the intraoperative brain within the distance of the structure" },
                              { "surface_distance", "95th percentile of the symmetric distances between the "
                                                    "structure's boundary moved by the method and by the truth" } };
  }
  // What the methods' ventricle_surface_distance_p95_mm measures.
  report["ventricles"] = ventricleReport;
  if (!electrodeReport.is_null())
  {
    report["electrodes"] = electrodeReport;
  }
  report["methods"] = json::array();
  for (const MethodResult & method : methods)
  {
    report["methods"].push_back(MethodJson(method));
  }
  WriteTextFileAtomically((output / "demo-report.json").string(), report.dump(2) + "\n");

  if (!options.quiet)
  {
    // From the report, which a truth read from a folder carries over.
    const json & made = report["ground_truth"];
    std::printf("ground truth: %s %.1f mm (%zu nodes), shift %.2f mm, gravity %.2f g, %d steps, %.1f s%s\n",
                made["grid"].get<std::string>().c_str(), made["element_size_mm"].get<double>(),
                made["nodes"].get<std::size_t>(), made["shift_mm"].get<double>(), made["gravity_g"].get<double>(),
                made["solve_steps"].get<int>(), made["seconds"]["total"].get<double>(),
                options.truthFrom.empty() ? "" : (", read from " + options.truthFrom).c_str());
    PrintTable(methods);
    std::printf("\nwrote %s (report demo-report.json, images, transforms, overlays/)\n", output.string().c_str());
  }
  return 0;
}

} // namespace

std::function<int()>
AddDemoCommand(CLI::App & app)
{
  auto options = std::make_shared<DemoOptions>();
  CLI::App * demo = app.add_subcommand(
    "demo", "Brain-shift registration against a known answer: ground truth from a finer, independent model, "
            "biomechanical registration from the displaced exposed surface, B-spline baseline, report");
  demo->add_option("--image", options->image, "Preoperative T1 image")->capture_default_str();
  demo->add_option("--mask", options->mask, "Its brain mask (voxels > 0)")->capture_default_str();
  demo->add_option("-o,--output-dir", options->outputDirectory, "Output folder")->capture_default_str();
  demo->add_option("--craniotomy-centre", options->craniotomyCentre, "Craniotomy centre X Y Z (mm); default -11 43 84")
    ->expected(3);
  demo->add_option("--craniotomy-radius", options->truth.craniotomyRadius, "Craniotomy radius (mm)")
    ->capture_default_str();
  demo->add_option("--shift", options->truth.targetShift, "Largest displacement of the exposed surface (mm)")
    ->capture_default_str();
  demo->add_option("--free-rim", options->truth.freeRim,
                   "Width of the craniotomy's rim left to the model, as a fraction of its radius (0: the sag is "
                   "pinned at the rim; 0.2 for shifts of 15 mm and more)")
    ->capture_default_str()
    ->check(CLI::Range(0.0, 0.9));
  demo->add_option("--gravity", options->truth.gravity, "Gravity on the brain (g), towards the brain's centroid")
    ->capture_default_str();
  demo->add_option("--poisson-ratio", options->truth.poissonRatio, "Poisson's ratio of parenchyma and tumour")
    ->capture_default_str();
  demo->add_option("--csf-modulus", options->truth.csfYoungsModulus, "Young's modulus of the CSF class (Pa)")
    ->capture_default_str();
  demo->add_option("--csf-poisson-ratio", options->truth.csfPoissonRatio,
                   "Poisson's ratio of the CSF class (ground truth and registration); 0.49: fluid-like, keeps "
                   "CSF cells from being crushed by shifts of 20 mm and more")
    ->capture_default_str()
    ->check(CLI::Range(0.0, 0.4999));
  demo->add_option("--tumour-centre", options->tumourCentre, "Synthetic spherical tumour centre X Y Z (mm)")->expected(3);
  demo->add_option("--tumour-radius", options->truth.tumourRadius, "Tumour radius (mm); 0: none")->capture_default_str();
  demo->add_option("--tumour-stiffness", options->truth.tumourStiffness, "Tumour Young's modulus / parenchyma's")
    ->capture_default_str();
  demo->add_option("--truth-grid", options->truthGrid, "Ground-truth grid: hexahedra, tetrahedra, mixed, meshless")
    ->capture_default_str();
  demo->add_option("--truth-element-size", options->truth.grid.elementSize, "Ground-truth element size (mm)")
    ->capture_default_str();
  demo->add_option("--truth-max-steps", options->truth.solverMaxSteps,
                   "Dynamic-relaxation steps before the ground-truth solve gives up (0: the solver's 100,000)")
    ->capture_default_str()
    ->check(CLI::NonNegativeNumber);
  demo->add_option("--truth-skull-closing", options->truth.skullClosing,
                   "Radius (mm) of the closing of the ground truth's brain before its skull is made: the skull stays "
                   "out of fissures narrower than twice (radius + gap) and its creases are rounded to the radius, as the "
                   "registration's skull_closing; 0: it follows every fold (a meshless truth under gravity at large "
                   "shifts then cycles in its contact: docs/model-building.md)")
    ->capture_default_str()
    ->check(CLI::NonNegativeNumber);
  // Physics only the truth has (docs/validation.md, "Truths of another kind"): the registration does not model them.
  demo->add_option("--truth-csf-drained-depth", options->truth.csfDrainedDepth,
                   "The ground truth's CSF drained only to this depth (mm) below the brain's top along gravity: the "
                   "tissue below stays buoyed (weightless); the registration assumes it drained completely")
    ->check(CLI::NonNegativeNumber);
  demo->add_option("--truth-bonded-depth", options->truth.bondedDepth,
                   "The ground truth's skull-contact nodes deeper than this (mm below the craniotomy's centre along "
                   "gravity) are bonded to the skull instead of sliding; the registration lets them slide")
    ->check(CLI::NonNegativeNumber);
  demo->add_option("--truth-grey-white-moduli", options->greyWhiteModuli,
                   "The ground truth's grey and white matter Young's moduli (Pa) on three tissue classes, e.g. 1390 "
                   "1895 (Budday et al. 2015); the registration has one parenchyma of 3 kPa")
    ->expected(2)
    ->check(CLI::PositiveNumber);
  demo->add_option("--noise", options->truth.noise, "Noise of the intraoperative image (fraction of the bright level)")
    ->capture_default_str();
  demo->add_option("--noise-model", options->noiseModel,
                   "Noise of the intraoperative image: gaussian, or rician (magnitude images at low field)")
    ->check(CLI::IsMember({ "gaussian", "rician" }))
    ->capture_default_str();
  demo->add_option("--intraoperative-contrast", options->contrast,
                   "Contrast of the intraoperative image: preoperative (the T1's), t2 (CSF bright), low-field-t1 "
                   "(half the tissue contrast)")
    ->check(CLI::IsMember({ "preoperative", "t2", "low-field-t1" }))
    ->capture_default_str();
  demo->add_option("--bias-field", options->truth.biasField,
                   "Smooth multiplicative bias field of the intraoperative image: largest deviation from 1 (0.2: +-20 %)")
    ->check(CLI::Range(0.0, 0.9))
    ->capture_default_str();
  demo->add_option("--intraoperative-spacing", options->intraoperativeSpacing,
                   "Voxel spacing of the intraoperative image X Y Z (mm); default 0.86 0.86 2.5")
    ->expected(3)
    ->check(CLI::PositiveNumber);
  demo->add_option("--field-of-view", options->truth.fieldOfView,
                   "Edge of the intraoperative image's cubic field of view around the craniotomy and beneath it (mm); "
                   "0: the whole head")
    ->check(CLI::NonNegativeNumber)
    ->capture_default_str();
  demo->add_option("--resection-margin", options->truth.resectionMargin,
                   "Resect the tumour and this margin (mm) before the intraoperative image: a fluid-filled cavity whose "
                   "walls sag (needs --tumour-radius)")
    ->check(CLI::NonNegativeNumber);
  demo->add_option("--variant", options->variants,
                   "Registration grid KIND:SIZE (hexahedra, tetrahedra, mixed, meshless); repeat for several; none: "
                   "the intensity registrations only")
    ->capture_default_str();
  demo->add_option("--truth-check", options->truthCheck,
                   "Solve the ground truth a second time on this grid KIND:SIZE (e.g. tetrahedra:5 beside the "
                   "hexahedral truth) and report how far the two truths differ (ground_truth_check)");
  demo->add_option("--load", options->load,
                   "What the registration is given: the displaced exposed surface, its tracked points, or the "
                   "contacts of an 8 x 8 electrode grid found in a simulated CT")
    ->check(CLI::IsMember({ "surface", "points", "electrodes" }))
    ->capture_default_str();
  demo->add_option("--surface-match", options->surfaceMatch,
                   "With --load surface: match the displaced surface by closest points, or along gravity (the "
                   "direction the head's position gives, in which the brain sinks)")
    ->check(CLI::IsMember({ "closest", "gravity" }))
    ->capture_default_str();
  demo->add_option("--registration-gravity", options->registrationGravity,
                   "Gravity in the registration's model (g, along the ground truth's direction); 0: surface only")
    ->capture_default_str();
  demo->add_option("--gravity-fit-candidates", options->gravityFitCandidates,
                   "Fit the registration's gravity to the intraoperative image: this many sizes from 0 to "
                   "--registration-gravity solved, the best match (mutual information) kept (3 or more); 0: as given")
    ->check(CLI::NonNegativeNumber)
    ->needs("--registration-gravity");
  options->uncertainty.Add(demo); // each row then also reports how well the map bounds its true error
  demo->add_flag("--no-baseline", options->noBaseline, "Skip the B-spline intensity registration");
  demo->add_flag("--no-registration-resection", options->noRegistrationResection,
                 "On a scene with a resection, do not give the biomechanical registration the planned resection "
                 "(the tumour and its margin, filled with fluid in its model)");
  demo->add_flag("--elastix", options->elastix,
                 "Also register with elastix (Debian's elastix; affine then B-spline, Mattes mutual information; "
                 "the parameter files in examples/elastix)");
  demo->add_option("--elastix-parameters", options->elastixParameters,
                   "elastix parameter files, in order (default: the module's affine.txt and bspline.txt)")
    ->check(CLI::ExistingFile);
  // A peer registration run elsewhere (examples/validation_peers.py: ANTs SyN, itk-elastix), scored like the others.
  CLI::Option * peerField =
    demo->add_option("--peer-field", options->peerField,
                     "Also score a peer registration of the --truth-from scene run elsewhere: its displacement "
                     "field over the preoperative grid (3-vector image: the intraoperative point's preoperative "
                     "point minus the point, LPS mm)")
      ->check(CLI::ExistingFile);
  CLI::Option * peerWarped =
    demo->add_option("--peer-warped", options->peerWarped,
                     "The peer's preoperative image warped onto the intraoperative grid (its edges are measured)")
      ->check(CLI::ExistingFile);
  CLI::Option * peerName = demo->add_option("--peer-name", options->peerName, "The peer's name in the report");
  demo->add_option("--peer-seconds", options->peerSeconds, "The peer's registration time (s)")->needs(peerField);
  demo->add_option("--peer-details", options->peerDetails, "JSON object describing the peer (tool, version, parameters)")
    ->check(CLI::ExistingFile)
    ->needs(peerField);
  peerField->needs(peerWarped)->needs(peerName);
  peerWarped->needs(peerField);
  peerName->needs(peerField);
  demo->add_option("--baseline-shrink-factors", options->baselineShrinkFactors, "Baseline pyramid")
    ->capture_default_str();
  demo->add_option("--baseline-iterations", options->baselineIterations, "Baseline iterations per level (0: default)")
    ->capture_default_str();
  demo->add_option("--overlays", options->overlays, "Edge-overlay PNGs per method")->capture_default_str();
  demo->add_option("--threads", options->truth.threads, "Worker threads (0: all)");
  demo->add_flag("--quiet,-q", options->quiet, "Print nothing but warnings and errors");
  // A study solves each scene's truth once and registers it in separate jobs (examples/validation).
  CLI::Option * truthOnly =
    demo->add_flag("--truth-only", options->truthOnly,
                   "Solve the ground truth and write it (with the no-registration row) for --truth-from; register "
                   "nothing");
  CLI::Option * truthFrom =
    demo->add_option("--truth-from", options->truthFrom,
                     "Read the ground truth that --truth-only wrote into this folder instead of solving it; the "
                     "scene (images, craniotomy, materials, intraoperative image) is the folder's")
      ->check(CLI::ExistingDirectory);
  peerField->needs(truthFrom);
  for (const char * scene :
       { "--image", "--mask", "--craniotomy-centre", "--craniotomy-radius", "--shift", "--free-rim", "--gravity",
         "--poisson-ratio", "--csf-modulus", "--csf-poisson-ratio", "--tumour-centre", "--tumour-radius",
         "--tumour-stiffness", "--truth-grid", "--truth-element-size", "--truth-max-steps", "--truth-skull-closing",
         "--truth-csf-drained-depth", "--truth-bonded-depth", "--truth-grey-white-moduli",
         "--noise", "--noise-model", "--intraoperative-contrast", "--bias-field", "--intraoperative-spacing",
         "--field-of-view", "--resection-margin", "--truth-check" })
  {
    truthFrom->excludes(demo->get_option(scene));
  }
  for (const char * registration : { "--variant", "--load", "--surface-match", "--registration-gravity", "--uncertainty",
                                     "--gravity-fit-candidates", "--no-registration-resection", "--elastix",
                                     "--elastix-parameters", "--baseline-shrink-factors", "--baseline-iterations",
                                     "--truth-from", "--peer-field" })
  {
    truthOnly->excludes(demo->get_option(registration));
  }
  return [=]() -> int { return demo->parsed() ? RunDemo(*options) : -1; };
}

} // namespace app
} // namespace bmr
