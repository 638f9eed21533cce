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
#include "bmrDemo.h"

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

using namespace demo;

/** The options' vectors into the truth's settings, and the elastix peer's programs checked: before the long
 *  ground-truth solve. */
void
ApplySceneOptions(DemoOptions & options)
{
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
  // The peer's files.
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
}

/** --peer-details: a JSON object describing a peer run elsewhere (empty path: an empty object). */
json
ReadPeerDetails(const std::string & path)
{
  json peerDetails = json::object();
  if (path.empty())
  {
    return peerDetails;
  }
  try
  {
    std::ifstream in(path);
    peerDetails = json::parse(in);
  }
  catch (const json::exception & exception)
  {
    throw Error("--peer-details: " + path + " is not readable JSON (" + exception.what() + ")");
  }
  if (!peerDetails.is_object())
  {
    throw Error("--peer-details: " + path + " must hold a JSON object (what the peer was)");
  }
  return peerDetails;
}

/** The biomechanical registrations' grids (--variant; none with --truth-only, which also skips the baseline). */
std::vector<ImageGridSettings>
ParseVariants(DemoOptions & options)
{
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
  return variants;
}

/** The epilepsy workflow (--load electrodes): a grid on the shifted brain, seen in a CT; its contacts, found and
 *  projected along gravity (the head's position in the operating room tells its direction), load the registration.
 *  Without it: nothing, and `report` stays null. */
std::optional<ElectrodeLocalisation>
LocaliseElectrodes(const DemoOptions & options, const RegistrationImage * preoperative,
                   const RegistrationLabelImage * brainMask, const SyntheticBrainShift & truth, const fs::path & output,
                   const StageCallback & stages, json & report)
{
  if (options.load != "electrodes")
  {
    return std::nullopt;
  }
  StageTimer                 timer(stages);
  const SyntheticElectrodeCt ct = timer.Run("electrode-ct", [&] {
    return MakeSyntheticElectrodeCt(preoperative, brainMask, truth, options.truth.craniotomyCentre);
  });
  WriteImageAtomically(ct.image.GetPointer(), output / "electrodes-ct.nii.gz");
  ElectrodeLocalisationSettings settings;
  settings.detection.expectedContacts = static_cast<int>(ct.contacts.size());
  settings.projectionDirection = truth.down;
  std::optional<ElectrodeLocalisation> electrodes = timer.Run("electrodes", [&] {
    return LocateElectrodes(ct.image, preoperative, ElectrodeReferenceSurface(brainMask), settings);
  });
  WriteSparseDisplacements((output / "electrode-displacements.csv").string(), electrodes->loads);
  const ElectrodeLocalisationErrors errors = MeasureElectrodeLocalisation(*electrodes, ct);
  report = { { "contacts", ct.contacts.size() },
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
  return electrodes;
}

/** A second ground truth of the same scene on another discretization (--truth-check): how far two truths differ is
 *  the smallest error a registration can be judged by. Its report entry; `secondTruth` its transform. */
json
SolveSecondTruth(const DemoOptions & options, const ImageGridSettings & grid, const RegistrationImage * preoperative,
                 const RegistrationLabelImage * brainMask, const SyntheticBrainShift & truth, const fs::path & output,
                 RegistrationTransform::Pointer & secondTruth)
{
  SyntheticBrainShiftSettings checkSettings = options.truth;
  checkSettings.grid.kind = grid.kind;
  checkSettings.grid.elementSize = grid.elementSize;
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
  const DisplacementError difference =
    MeasureDisplacementError(check.truthTransform, truth.truthTransform, truth.intraoperativeBrainOnPreoperativeGrid);
  itk::WriteBiomechanicalTransform(check.truthTransform, (output / "ground-truth-check-transform.h5").string());
  secondTruth = check.truthTransform;
  const json report = { { "grid", ImageGridKindName(checkSettings.grid.kind) },
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
  return report;
}

/** The intensity peers' rows: elastix run here (--elastix) and a peer run elsewhere (--peer-field), each with its
 *  error, its own warped image's edges and its overlays. */
void
AddPeerRows(const DemoOptions & options, const RegistrationImage * preoperative, const SyntheticBrainShift & truth,
            const std::optional<IntensityPeer> & externalPeer, const json & peerDetails, const Scoring & scoring,
            const fs::path & output, std::vector<MethodResult> & methods)
{
  const RegistrationImage *      intraoperative = truth.intraoperativeImage;
  const RegistrationLabelImage * intraoperativeMask = truth.intraoperativeBrainMask;
  // A peer's method row: its error, its own warped image's edges, its overlays.
  const auto addPeer = [&](const IntensityPeer & peer, MethodResult method, const std::string & overlayName) {
    method.seconds = peer.seconds;
    method.edges = EvaluateEdges(intraoperative, peer.warpedOnFixedGrid, intraoperativeMask);
    scoring.Score(peer.transform, method);
    methods.push_back(method);
    WriteEdgeOverlays(method.edges, intraoperative, (output / "overlays").string(), overlayName, options.overlays);
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
}

/** demo-report.json: the scene, the ground truth (solved here or read with --truth-from), what the scores measure,
 *  and every method's row. */
json
DemoReportJson(const DemoOptions & options, const SyntheticBrainShift & truth, const std::optional<TruthFiles> & cached,
               const json & truthCheckReport, const Scoring & scoring, const json & electrodeReport,
               const std::vector<MethodResult> & methods)
{
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
    report["ground_truth"] = GroundTruthJson(options, truth);
  }
  if (!truthCheckReport.is_null())
  {
    report["ground_truth_check"] = truthCheckReport;
  }
  if (scoring.NearTumour() != nullptr)
  {
    // What the methods' displacement_error_near_tumour_mm measures.
    report["near_tumour"] = { { "structure", truth.resectionMask.IsNotNull() ? "resection cavity" : "tumour" },
                              { "distance_mm", kNearTumourDistance },
                              { "region", "the intraoperative brain within the distance of the structure" },
                              { "surface_distance", "95th percentile of the symmetric distances between the "
                                                    "structure's boundary moved by the method and by the truth" } };
  }
  // What the methods' ventricle_surface_distance_p95_mm measures.
  report["ventricles"] = scoring.VentricleReport();
  if (!electrodeReport.is_null())
  {
    report["electrodes"] = electrodeReport;
  }
  report["methods"] = json::array();
  for (const MethodResult & method : methods)
  {
    report["methods"].push_back(MethodJson(method));
  }
  return report;
}

int
RunDemo(DemoOptions options)
{
  const fs::path output(options.outputDirectory);
  const bool     terminal = !options.quiet && ::isatty(STDERR_FILENO) != 0;
  const StageCallback stages = terminal ? StageCallback(StepTimer::PrintStage) : StageCallback();

  ApplySceneOptions(options);
  const json                peerDetails = ReadPeerDetails(options.peerDetails);
  const UncertaintySettings uncertainty = options.uncertainty.Checked();
  const std::vector<ImageGridSettings> variants = ParseVariants(options);
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
  json                                       electrodeReport;
  const std::optional<ElectrodeLocalisation> electrodes =
    LocaliseElectrodes(options, preoperative, brainMask, truth, output, stages, electrodeReport);
  const fs::path overlays = output / "overlays";

  // A second ground truth of the same scene on another discretization: how far
  // two truths differ is the smallest error a registration can be judged by.
  json                           truthCheckReport = cached ? cached->report.value("ground_truth_check", json()) : json();
  RegistrationTransform::Pointer secondTruth = cached ? cached->secondTruth : nullptr;
  if (truthCheckGrid)
  {
    truthCheckReport = SolveSecondTruth(options, *truthCheckGrid, preoperative, brainMask, truth, output, secondTruth);
  }

  std::vector<MethodResult> methods;
  const Scoring scoring(options, preoperative, brainMask, truth, secondTruth, output);
  {
    // The preoperative image as it is, against the intraoperative one: what every method improves on.
    MethodResult none;
    none.name = "no registration";
    scoring.Score(nullptr, none);
    const auto identity = itk::IdentityTransform<double, 3>::New();
    none.edges = EvaluateEdges(intraoperative, WarpImage(preoperative, identity, intraoperative), intraoperativeMask);
    methods.push_back(none);
    WriteEdgeOverlays(none.edges, intraoperative, overlays.string(), "none", options.overlays);
  }

  for (const ImageGridSettings & grid : variants)
  {
    methods.push_back(RegisterVariant(grid, options, uncertainty, preoperative, brainMask, truth,
                                      electrodes ? &electrodes->loads : nullptr, scoring, output, stages));
  }

  if (!options.noBaseline)
  {
    methods.push_back(RegisterBaseline(options, preoperative, truth, scoring, output));
  }

  AddPeerRows(options, preoperative, truth, externalPeer, peerDetails, scoring, output, methods);

  const json report = DemoReportJson(options, truth, cached, truthCheckReport, scoring, electrodeReport, methods);
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

namespace
{
// The scene: images, craniotomy, the ground truth's model and physics, the intraoperative image.
void
AddDemoSceneOptions(CLI::App & demo, DemoOptions & options)
{
  demo.add_option("--image", options.image, "Preoperative T1 image")->capture_default_str();
  demo.add_option("--mask", options.mask, "Its brain mask (voxels > 0)")->capture_default_str();
  demo.add_option("-o,--output-dir", options.outputDirectory, "Output folder")->capture_default_str();
  demo.add_option("--craniotomy-centre", options.craniotomyCentre, "Craniotomy centre X Y Z (mm); default -11 43 84")
    ->expected(3);
  demo.add_option("--craniotomy-radius", options.truth.craniotomyRadius, "Craniotomy radius (mm)")
    ->capture_default_str();
  demo.add_option("--shift", options.truth.targetShift, "Largest displacement of the exposed surface (mm)")
    ->capture_default_str();
  demo.add_option("--free-rim", options.truth.freeRim,
                   "Width of the craniotomy's rim left to the model, as a fraction of its radius (0: the sag is "
                   "pinned at the rim; 0.2 for shifts of 15 mm and more)")
    ->capture_default_str()
    ->check(CLI::Range(0.0, 0.9));
  demo.add_option("--gravity", options.truth.gravity, "Gravity on the brain (g), towards the brain's centroid")
    ->capture_default_str();
  demo.add_option("--poisson-ratio", options.truth.poissonRatio, "Poisson's ratio of parenchyma and tumour")
    ->capture_default_str();
  demo.add_option("--csf-modulus", options.truth.csfYoungsModulus, "Young's modulus of the CSF class (Pa)")
    ->capture_default_str();
  demo.add_option("--csf-poisson-ratio", options.truth.csfPoissonRatio,
                   "Poisson's ratio of the CSF class (ground truth and registration); 0.49: fluid-like, keeps "
                   "CSF cells from being crushed by shifts of 20 mm and more")
    ->capture_default_str()
    ->check(CLI::Range(0.0, 0.4999));
  demo.add_option("--tumour-centre", options.tumourCentre, "Synthetic spherical tumour centre X Y Z (mm)")->expected(3);
  demo.add_option("--tumour-radius", options.truth.tumourRadius, "Tumour radius (mm); 0: none")->capture_default_str();
  demo.add_option("--tumour-stiffness", options.truth.tumourStiffness, "Tumour Young's modulus / parenchyma's")
    ->capture_default_str();
  demo.add_option("--truth-grid", options.truthGrid, "Ground-truth grid: hexahedra, tetrahedra, mixed, meshless")
    ->capture_default_str();
  demo.add_option("--truth-element-size", options.truth.grid.elementSize, "Ground-truth element size (mm)")
    ->capture_default_str();
  demo.add_option("--truth-max-steps", options.truth.solverMaxSteps,
                   "Dynamic-relaxation steps before the ground-truth solve gives up (0: the solver's 100,000)")
    ->capture_default_str()
    ->check(CLI::NonNegativeNumber);
  demo.add_option("--truth-skull-closing", options.truth.skullClosing,
                   "Radius (mm) of the closing of the ground truth's brain before its skull is made: the skull stays "
                   "out of fissures narrower than twice (radius + gap) and its creases are rounded to the radius, as the "
                   "registration's skull_closing; 0: it follows every fold (a meshless truth under gravity at large "
                   "shifts then cycles in its contact: docs/model-building.md)")
    ->capture_default_str()
    ->check(CLI::NonNegativeNumber);
  // Physics only the truth has (docs/validation.md, "Truths of another kind"): the registration does not model them.
  demo.add_option("--truth-csf-drained-depth", options.truth.csfDrainedDepth,
                   "The ground truth's CSF drained only to this depth (mm) below the brain's top along gravity: the "
                   "tissue below stays buoyed (weightless); the registration assumes it drained completely")
    ->check(CLI::NonNegativeNumber);
  demo.add_option("--truth-bonded-depth", options.truth.bondedDepth,
                   "The ground truth's skull-contact nodes deeper than this (mm below the craniotomy's centre along "
                   "gravity) are bonded to the skull instead of sliding; the registration lets them slide")
    ->check(CLI::NonNegativeNumber);
  demo.add_option("--truth-grey-white-moduli", options.greyWhiteModuli,
                   "The ground truth's grey and white matter Young's moduli (Pa) on three tissue classes, e.g. 1390 "
                   "1895 (Budday et al. 2015); the registration has one parenchyma of 3 kPa")
    ->expected(2)
    ->check(CLI::PositiveNumber);
  demo.add_option("--truth-mooney-rivlin-share", options.truth.mooneyRivlinShare,
                   "The ground truth's parenchyma and tumour Mooney-Rivlin with this C01 / (C10 + C01) and the same "
                   "small-strain moduli (docs/materials.md); the registration is neo-Hookean")
    ->check(CLI::Range(0.0, 1.0));
  demo.add_option("--noise", options.truth.noise, "Noise of the intraoperative image (fraction of the bright level)")
    ->capture_default_str();
  demo.add_option("--noise-model", options.noiseModel,
                   "Noise of the intraoperative image: gaussian, or rician (magnitude images at low field)")
    ->check(CLI::IsMember({ "gaussian", "rician" }))
    ->capture_default_str();
  demo.add_option("--intraoperative-contrast", options.contrast,
                   "Contrast of the intraoperative image: preoperative (the T1's), t2 (CSF bright), low-field-t1 "
                   "(half the tissue contrast)")
    ->check(CLI::IsMember({ "preoperative", "t2", "low-field-t1" }))
    ->capture_default_str();
  demo.add_option("--bias-field", options.truth.biasField,
                   "Smooth multiplicative bias field of the intraoperative image: largest deviation from 1 (0.2: +-20 %)")
    ->check(CLI::Range(0.0, 0.9))
    ->capture_default_str();
  demo.add_option("--intraoperative-spacing", options.intraoperativeSpacing,
                   "Voxel spacing of the intraoperative image X Y Z (mm); default 0.86 0.86 2.5")
    ->expected(3)
    ->check(CLI::PositiveNumber);
  demo.add_option("--field-of-view", options.truth.fieldOfView,
                   "Edge of the intraoperative image's cubic field of view around the craniotomy and beneath it (mm); "
                   "0: the whole head")
    ->check(CLI::NonNegativeNumber)
    ->capture_default_str();
  demo.add_option("--resection-margin", options.truth.resectionMargin,
                   "Resect the tumour and this margin (mm) before the intraoperative image: a fluid-filled cavity whose "
                   "walls sag (needs --tumour-radius)")
    ->check(CLI::NonNegativeNumber);
}

// The methods compared: the registrations, their loads, the baselines and peers, the outputs.
void
AddDemoMethodOptions(CLI::App & demo, DemoOptions & options)
{
  demo.add_option("--variant", options.variants,
                   "Registration grid KIND:SIZE (hexahedra, tetrahedra, mixed, meshless); repeat for several; none: "
                   "the intensity registrations only")
    ->capture_default_str();
  demo.add_option("--truth-check", options.truthCheck,
                   "Solve the ground truth a second time on this grid KIND:SIZE (e.g. tetrahedra:5 beside the "
                   "hexahedral truth) and report how far the two truths differ (ground_truth_check)");
  demo.add_option("--load", options.load,
                   "What the registration is given: the displaced exposed surface, its tracked points, or the "
                   "contacts of an 8 x 8 electrode grid found in a simulated CT")
    ->check(CLI::IsMember({ "surface", "points", "electrodes" }))
    ->capture_default_str();
  demo.add_option("--surface-match", options.surfaceMatch,
                   "With --load surface: match the displaced surface by closest points, or along gravity (the "
                   "direction the head's position gives, in which the brain sinks)")
    ->check(CLI::IsMember({ "closest", "gravity" }))
    ->capture_default_str();
  demo.add_option("--registration-gravity", options.registrationGravity,
                   "Gravity in the registration's model (g, along the ground truth's direction); 0: surface only")
    ->capture_default_str();
  demo.add_option("--gravity-fit-candidates", options.gravityFitCandidates,
                   "Fit the registration's gravity to the intraoperative image: this many sizes from 0 to "
                   "--registration-gravity solved, the best match (mutual information) kept (3 or more); 0: as given")
    ->check(CLI::NonNegativeNumber)
    ->needs("--registration-gravity");
  options.uncertainty.Add(&demo); // each row then also reports how well the map bounds its true error
  demo.add_flag("--no-baseline", options.noBaseline, "Skip the B-spline intensity registration");
  demo.add_flag("--no-registration-resection", options.noRegistrationResection,
                 "On a scene with a resection, do not give the biomechanical registration the planned resection "
                 "(the tumour and its margin, filled with fluid in its model)");
  demo.add_flag("--elastix", options.elastix,
                 "Also register with elastix (Debian's elastix; affine then B-spline, Mattes mutual information; "
                 "the parameter files in examples/elastix)");
  demo.add_option("--elastix-parameters", options.elastixParameters,
                   "elastix parameter files, in order (default: the module's affine.txt and bspline.txt)")
    ->check(CLI::ExistingFile);
  // A peer registration run elsewhere (examples/validation_peers.py: ANTs SyN, itk-elastix), scored like the others.
  CLI::Option * peerField =
    demo.add_option("--peer-field", options.peerField,
                     "Also score a peer registration of the --truth-from scene run elsewhere: its displacement "
                     "field over the preoperative grid (3-vector image: the intraoperative point's preoperative "
                     "point minus the point, LPS mm)")
      ->check(CLI::ExistingFile);
  CLI::Option * peerWarped =
    demo.add_option("--peer-warped", options.peerWarped,
                     "The peer's preoperative image warped onto the intraoperative grid (its edges are measured)")
      ->check(CLI::ExistingFile);
  CLI::Option * peerName = demo.add_option("--peer-name", options.peerName, "The peer's name in the report");
  demo.add_option("--peer-seconds", options.peerSeconds, "The peer's registration time (s)")->needs(peerField);
  demo.add_option("--peer-details", options.peerDetails, "JSON object describing the peer (tool, version, parameters)")
    ->check(CLI::ExistingFile)
    ->needs(peerField);
  peerField->needs(peerWarped)->needs(peerName);
  peerWarped->needs(peerField);
  peerName->needs(peerField);
  demo.add_option("--baseline-shrink-factors", options.baselineShrinkFactors, "Baseline pyramid")
    ->capture_default_str();
  demo.add_option("--baseline-iterations", options.baselineIterations, "Baseline iterations per level (0: default)")
    ->capture_default_str();
  demo.add_option("--overlays", options.overlays, "Edge-overlay PNGs per method")->capture_default_str();
  demo.add_option("--threads", options.truth.threads, "Worker threads (0: all)");
  demo.add_flag("--quiet,-q", options.quiet, "Print nothing but warnings and errors");
}

} // namespace

std::function<int()>
AddDemoCommand(CLI::App & app)
{
  auto options = std::make_shared<DemoOptions>();
  CLI::App * demo = app.add_subcommand(
    "demo", "Brain-shift registration against a known answer: ground truth from a finer, independent model, "
            "biomechanical registration from the displaced exposed surface, B-spline baseline, report");
  AddDemoSceneOptions(*demo, *options);
  AddDemoMethodOptions(*demo, *options);
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
  demo->get_option("--peer-field")->needs(truthFrom);
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
