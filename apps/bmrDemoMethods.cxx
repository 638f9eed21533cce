// `biomech demo`'s methods (bmrDemo.h): each registration of the ground
// truth's intraoperative data, scored against the truth, and its report row.
#include "bmrImageCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalTransformIO.h"

#include "bmrCommandSupport.h"
#include "bmrDemo.h"

#include "bmrUnits.h"

#include <algorithm>
#include <cstdio>
#include <iostream>
#include <sstream>

namespace fs = std::filesystem;

namespace bmr
{
namespace app
{
namespace demo
{

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

ImageGridSettings
ParseVariant(const std::string & variant, const std::string & option)
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

Scoring::Scoring(const DemoOptions & options, const RegistrationImage * preoperative, const RegistrationLabelImage * brainMask,
        const SyntheticBrainShift & truth, RegistrationTransform::Pointer secondTruth, const fs::path & output)
  : m_Truth(truth)
  , m_SecondTruth(std::move(secondTruth))
{
  // Near the tumour, or the cavity's walls after a resection: the brain within kNearTumourDistance of it.
  const RegistrationLabelImage * structure =
    truth.resectionMask.IsNotNull() ? truth.resectionMask.GetPointer() : truth.tumourMask.GetPointer();
  m_NearTumour =
    structure != nullptr ? RegionNear(structure, truth.intraoperativeBrainOnPreoperativeGrid, kNearTumourDistance)
                         : nullptr;
  if (structure != nullptr)
  {
    m_TumourSurface.emplace(truth.truthTransform, structure);
  }
  // The ventricles' surface, found in the preoperative T1; an image where they are not found (another contrast,
  // part of a brain) is measured without it, and the report says why.
  try
  {
    const RegistrationLabelImage::Pointer ventricles = VentricleMask(preoperative, brainMask, kVentricleDepth);
    WriteImageAtomically(ventricles.GetPointer(), output / "ventricle-mask.nii.gz");
    const auto   spacing = ventricles->GetSpacing();
    const auto * voxels = ventricles->GetBufferPointer();
    const double volume = spacing[0] * spacing[1] * spacing[2] *
                          static_cast<double>(std::count_if(voxels, voxels + ventricles->GetBufferedRegion().GetNumberOfPixels(),
                                                            [](unsigned char v) { return v > 0; }));
    m_VentricleSurface.emplace(truth.truthTransform, ventricles);
    m_VentricleReport = { { "depth_mm", kVentricleDepth },
                          { "volume_mm3", volume },
                          { "mask", "ventricle-mask.nii.gz" },
                          { "definition", "the CSF class deeper than depth_mm below the brain's surface, opened by "
                                          "2 mm, its largest connected component" } };
  }
  catch (const Error & error)
  {
    m_VentricleReport = { { "error", error.what() } };
    if (!options.quiet)
    {
      std::cerr << "the ventricles' surface is not measured: " << error.what() << "\n";
    }
  }
}

void
Scoring::Score(const itk::Transform<double, 3, 3> * transform, MethodResult & method) const
{
  method.error = MeasureDisplacementError(transform, m_Truth.truthTransform, m_Truth.intraoperativeBrainOnPreoperativeGrid);
  if (m_NearTumour)
  {
    method.nearTumourError = MeasureDisplacementError(transform, m_Truth.truthTransform, m_NearTumour);
    method.tumourSurfaceDistance = m_TumourSurface->Percentile95(transform);
  }
  if (m_VentricleSurface)
  {
    method.ventricleSurfaceDistance = m_VentricleSurface->Percentile95(transform);
  }
  if (m_SecondTruth)
  {
    method.details["displacement_error_against_second_truth_mm"] = DisplacementErrorJson(
      MeasureDisplacementError(transform, m_SecondTruth, m_Truth.intraoperativeBrainOnPreoperativeGrid));
  }
}

MethodResult
RegisterVariant(const ImageGridSettings & grid, const DemoOptions & options, const UncertaintySettings & uncertainty,
                const RegistrationImage * preoperative, const RegistrationLabelImage * brainMask,
                const SyntheticBrainShift & truth, const SparseDisplacements * electrodeLoads, const Scoring & scoring,
                const fs::path & output, const StageCallback & stages)
{
  const RegistrationImage *      intraoperative = truth.intraoperativeImage;
  const RegistrationLabelImage * intraoperativeMask = truth.intraoperativeBrainMask;
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
    inputs.intraoperative.sparse = *electrodeLoads;
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
  scoring.Score(result.transform, method);
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
  WriteImageAtomically(result.warpedImage.GetPointer(), output / ("warped-biomechanical-" + tag + ".nii.gz"));
  itk::WriteBiomechanicalTransform(result.transform, (output / ("transform-biomechanical-" + tag + ".h5")).string());
  WriteEdgeOverlays(result.registered, intraoperative, (output / "overlays").string(), "biomechanical-" + tag, options.overlays);
  return method;
}

MethodResult
RegisterBaseline(const DemoOptions & options, const RegistrationImage * preoperative, const SyntheticBrainShift & truth,
                 const Scoring & scoring, const fs::path & output)
{
  const RegistrationImage *      intraoperative = truth.intraoperativeImage;
  const RegistrationLabelImage * intraoperativeMask = truth.intraoperativeBrainMask;
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
  scoring.Score(baseline.transform, method);
  method.edges = EvaluateEdges(intraoperative, baseline.warpedOnFixedGrid, intraoperativeMask);
  WriteImageAtomically(baseline.warpedOnFixedGrid.GetPointer(), output / "warped-bspline-on-intraoperative-grid.nii.gz");
  itk::WriteBiomechanicalTransform(baseline.transform, (output / "transform-bspline.h5").string());
  WriteEdgeOverlays(method.edges, intraoperative, (output / "overlays").string(), "bspline", options.overlays);
  return method;
}

json
GroundTruthJson(const DemoOptions & options, const SyntheticBrainShift & truth)
{
  return {
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
    { "mooney_rivlin_share", options.truth.mooneyRivlinShare > 0.0 ? json(options.truth.mooneyRivlinShare) : json() },
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

} // namespace demo
} // namespace app
} // namespace bmr
