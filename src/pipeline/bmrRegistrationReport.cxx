// The registration's report (registration-report.json, the table `biomech
// register` prints) and its edge overlays: what RegisterBrainShift and
// UpdateBrainShift (bmrBrainShiftRegistration.cxx) did, for a reader.
#include "bmrBrainShiftRegistration.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalImageIO.h"
#include "itkEdgeHausdorffDistanceImageFilter.h"

#include "bmrPipelineDetail.h"
#include "bmrScene.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <sstream>

namespace bmr
{

std::pair<double, double>
OverlayGreyRange(const RegistrationImage * image)
{
  const float *      begin = image->GetBufferPointer();
  std::vector<float> values(begin, begin + image->GetBufferedRegion().GetNumberOfPixels());
  const auto         top = values.begin() + static_cast<std::ptrdiff_t>(0.995 * static_cast<double>(values.size() - 1));
  std::nth_element(values.begin(), top, values.end());
  const double maximum = *top;
  const double minimum = *std::min_element(values.begin(), top + 1);
  return { minimum, maximum };
}

std::vector<std::string>
WriteEdgeOverlays(const EdgeEvaluation &    evaluation,
                  const RegistrationImage * background,
                  const std::string &       folder,
                  const std::string &       prefix,
                  int                       count)
{
  std::vector<std::string> paths;
  if (!evaluation.valid || evaluation.fixedEdgeImage.IsNull() || count <= 0)
  {
    return paths;
  }
  constexpr unsigned int axial = 2;
  const auto slices = itk::EdgeOverlaySlices(evaluation.fixedEdgeImage.GetPointer(),
                                             evaluation.movingEdgeImage.GetPointer(), axial);
  if (slices.empty())
  {
    return paths;
  }
  const auto [grey0, grey1] = OverlayGreyRange(background);
  std::filesystem::create_directories(folder);
  for (int k = 0; k < count && k < static_cast<int>(slices.size()); ++k)
  {
    // Evenly spread, away from the first and last slices with edges (the brain's caps).
    const std::size_t position = (2 * static_cast<std::size_t>(k) + 1) * slices.size() / (2 * static_cast<std::size_t>(count));
    const itk::IndexValueType slice = slices[std::min(position, slices.size() - 1)];
    const auto overlay = itk::MakeEdgeOverlaySlice(evaluation.fixedEdgeImage.GetPointer(),
                                                   evaluation.movingEdgeImage.GetPointer(), background, axial, slice,
                                                   grey0, grey1);
    char name[32];
    std::snprintf(name, sizeof(name), "-%04ld.png", static_cast<long>(slice));
    const std::string path = (std::filesystem::path(folder) / (prefix + name)).string();
    itk::WriteBiomechanicalImage(overlay.GetPointer(), path);
    paths.push_back(path);
  }
  return paths;
}

// ---------------------------------------------------------------------------
// Reports.
// ---------------------------------------------------------------------------

namespace
{

nlohmann::json
EvaluationJson(const EdgeEvaluation & evaluation, double threshold)
{
  if (!evaluation.valid)
  {
    return { { "valid", false }, { "message", evaluation.message } };
  }
  return { { "valid", true },
           { "hausdorff_mm", { { "p50", evaluation.Percentile(50) },
                               { "p75", evaluation.Percentile(75) },
                               { "p90", evaluation.Percentile(90) },
                               { "p95", evaluation.Percentile(95) },
                               { "p100", evaluation.Percentile(100) } } },
           { "fraction_within_threshold", evaluation.fractionWithinThreshold },
           { "threshold_mm", threshold },
           { "fixed_edges", evaluation.fixedEdges },
           { "moving_edges", evaluation.movingEdges },
           { "symmetric_curve_mm", evaluation.symmetric } };
}

std::string
SolveState(const SolveResult & solve)
{
  return solve.converged ? "converged" : "NOT CONVERGED (" + solve.message + ")";
}

} // namespace

nlohmann::json
CsfClassJson(const BrainModel & model)
{
  const auto & centroids = model.classificationFit.centroids;
  const int    csfClass = model.csfClass.csfClass;
  return { { "contrast", TissueContrastName(model.csfClass.contrast) },
           { "class", csfClass + 1 }, // the tissue label image's value (1..K)
           { "centroid", csfClass < static_cast<int>(centroids.size()) ? centroids[csfClass] : 0.0 },
           { "volume_ml", model.csfVolume / 1000.0 },
           { "chosen", model.csfClass.reason } };
}

nlohmann::json
RegistrationReportJson(const BrainShiftRegistrationResult & result, const BrainShiftRegistrationSettings & settings)
{
  const ModelCounts counts = CountModel(result.model.model);
  const Material    csf = CsfClassMaterial(settings.model.materials);
  nlohmann::json    report;
  report["seconds"] = result.timer.Json();
  report["model"] = { { "grid", ImageGridKindName(settings.model.grid.kind) },
                      { "element_size_mm", settings.model.grid.elementSize },
                      { "nodes", counts.nodes },
                      { "cells", counts.cells },
                      { "dofs", counts.dofs },
                      { "integration_points", counts.integrationPoints },
                      { "materials", counts.materials },
                      { "volume_error", result.model.gridQuality.volumeError },
                      { "exposed_nodes", result.model.exposedNodes.size() },
                      { "loaded_nodes", result.model.load.nodes.size() },
                      { "fixed_nodes", result.model.model.nodeSets.count("skull_base")
                                         ? result.model.model.nodeSets.at("skull_base").size()
                                         : 0 },
                      { "contact", !result.model.model.contactSurfaces.empty() },
                      { "classes", settings.model.classifier.classes },
                      { "csf", { { "youngs_modulus_pa", csf.youngsModulus }, { "poisson_ratio", csf.poissonRatio } } } };
  report["model"]["csf"].update(CsfClassJson(result.model));
  if (settings.model.csfDrainedDepth)
  {
    report["model"]["csf"]["drained_depth_mm"] = *settings.model.csfDrainedDepth;
  }
  if (settings.model.resectionMask.IsNotNull())
  {
    report["model"]["resected_volume_mm3"] = result.model.resectedVolume;
  }
  const LoadReport & load = result.model.loadReport;
  report["loads"] = { { "used", load.usedPoints },
                      { "rejected", load.rejectedPoints },
                      { "max_correspondence_distance_mm", load.maxCorrespondenceDistance },
                      { "rms_correspondence_distance_mm", load.rmsCorrespondenceDistance } };
  const SolveResult & solve = result.solve;
  report["solve"] = { { "converged", solve.converged },
                      { "message", solve.message },
                      { "steps", solve.steps },
                      { "estimated_error_mm", solve.estimatedError },
                      { "tolerance_mm", settings.solver.tolerance },
                      { "restarts", solve.restarts },
                      { "lowest_eigenvalue", solve.lowestEigenvalue },
                      { "warm_started", solve.warmStarted },
                      { "max_displacement_mm", solve.maxDisplacement },
                      { "contact_nodes", solve.contactNodes },
                      { "max_penetration_mm", solve.maxPenetration },
                      { "active_components", solve.activeComponents },
                      { "seconds", solve.wallSeconds },
                      { "parts", nlohmann::json::parse(MakeSolvePartsJson(solve)) } };
  report["gravity_mm_s2"] = { result.gravity.x(), result.gravity.y(), result.gravity.z() };
  if (!result.gravityFit.empty())
  {
    nlohmann::json candidates = nlohmann::json::array();
    int            steps = 0;
    for (std::size_t k = 0; k < result.gravityFit.size(); ++k)
    {
      const auto [size, information] = result.gravityFit[k];
      const auto & solve = result.gravityFitSolves.at(k);
      // A size whose solve failed has no information (null); one solved from the update's own start no start size.
      candidates.push_back({ { "gravity_g", size / units::StandardGravity },
                             { "mutual_information",
                               std::isfinite(information) ? nlohmann::json(information) : nlohmann::json() },
                             { "steps", solve.steps },
                             { "started_from_g", solve.startSize >= 0.0
                                                   ? nlohmann::json(solve.startSize / units::StandardGravity)
                                                   : nlohmann::json() } });
      steps += solve.steps;
    }
    report["gravity_fit"] = { { "gravity_g", result.gravity.norm() / units::StandardGravity },
                              { "steps", steps },
                              { "candidates", candidates } };
  }
  report["fit"] = { { "max_residual_mm", result.fitMaxResidual },
                    { "rms_residual_mm", result.fitRmsResidual },
                    { "levels", result.fitLevels },
                    { "tolerance_mm", settings.fitTolerance },
                    { "tolerance_reached", result.fitToleranceReached } };
  if (result.Evaluated())
  {
    report["evaluation"] = {
      { "unregistered", EvaluationJson(result.unregistered, settings.evaluationDistanceThreshold) },
      { "registered", EvaluationJson(result.registered, settings.evaluationDistanceThreshold) },
      { "slice_axis", settings.evaluationSliceAxis }
    };
  }
  report["warnings"] = result.warnings;
  return report;
}

std::string
FormatRegistrationTable(const BrainShiftRegistrationResult & result)
{
  const ModelCounts  counts = CountModel(result.model.model);
  std::ostringstream text;
  text << std::fixed << std::setprecision(2);
  text << "brain-shift registration\n";
  text << "  model             " << counts.nodes << " nodes, " << counts.cells << " cells, " << counts.dofs << " DOF";
  if (counts.integrationPoints > 0)
  {
    text << ", " << counts.integrationPoints << " integration points";
  }
  text << "\n  CSF               class " << result.model.csfClass.csfClass + 1 << " of "
       << result.model.classificationFit.centroids.size() << " (" << TissueContrastName(result.model.csfClass.contrast)
       << " contrast), " << result.model.csfVolume / 1000.0 << " mL";
  text << "\n  loads             " << result.model.load.nodes.size() << " of " << result.model.exposedNodes.size()
       << " exposed nodes, correspondence up to " << result.model.loadReport.maxCorrespondenceDistance << " mm\n";
  if (!result.gravityFit.empty())
  {
    text << "  gravity fit       " << InG(result.gravity.norm()) << " of " << result.gravityFit.size()
         << " sizes tried (the best mutual information with the intraoperative image)\n";
  }
  text << "  solve             " << SolveState(result.solve) << ", " << result.solve.steps << " steps, estimated error "
       << std::setprecision(4) << result.solve.estimatedError << std::setprecision(2) << " mm, max displacement "
       << result.solve.maxDisplacement << " mm\n";
  text << "  transform fit     max residual " << std::setprecision(3) << result.fitMaxResidual << " mm, rms "
       << result.fitRmsResidual << std::setprecision(2) << " mm, " << result.fitLevels << " levels\n";
  if (result.Evaluated())
  {
    const auto line = [&text](const char * name, const EdgeEvaluation & evaluation) {
      text << "  " << name;
      if (!evaluation.valid)
      {
        text << "not evaluated: " << evaluation.message << "\n";
        return;
      }
      text << "Hausdorff p50 " << evaluation.Percentile(50) << "  p90 " << evaluation.Percentile(90) << "  p95 "
           << evaluation.Percentile(95) << " mm, edges within 1.7 mm " << 100.0 * evaluation.fractionWithinThreshold
           << " %\n";
    };
    line("unregistered      ", result.unregistered);
    line("registered        ", result.registered);
  }
  text << "  time              ";
  for (const auto & [stage, seconds] : result.timer.Stages())
  {
    text << stage << " " << seconds << "  ";
  }
  text << "| total " << result.timer.Json()["total"].get<double>() << " s\n";
  return text.str();
}

} // namespace bmr
