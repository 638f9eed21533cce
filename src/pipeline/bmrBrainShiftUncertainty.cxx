// The ITK filters first: ITK's bundled Eigen before the core's (the deformation filter's header says why).
#include "itkBiomechanicalUncertaintyFilter.h"

#include "bmrBrainShiftUncertainty.h"

#include "bmrPipelineDetail.h"

#include "itkBiomechanicalImageConversion.h"
#include "itkBiomechanicalImageIO.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkEdgeHausdorffDistanceImageFilter.h"
#include "itkSignedMaurerDistanceMapImageFilter.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <functional>
#include <random>
#include <sstream>

namespace bmr
{

void
CheckUncertaintySettings(const UncertaintySettings & settings)
{
  CheckEnsembleSettings(settings);
  const auto fail = [](const std::string & message) { throw Error("uncertainty: " + message); };
  if (!std::isfinite(settings.noiseSigma))
  {
    fail("the measurement noise is not a number; give a standard deviation in mm (0: none; negative: from the "
         "loads' correspondence distances)");
  }
  if (!(settings.exposedRadiusSpread >= 0.0))
  {
    std::ostringstream message;
    message << "the exposed radius spread is " << settings.exposedRadiusSpread
            << " mm; give a standard deviation of 0 mm or more";
    fail(message.str());
  }
  if (!(settings.memberTolerance >= 0.0))
  {
    std::ostringstream message;
    message << "the members' tolerance is " << settings.memberTolerance
            << " mm; give 0 mm (the registration's) or more";
    fail(message.str());
  }
  if (settings.threads < 0)
  {
    fail(std::to_string(settings.threads) + " threads; give 0 (OpenMP's default) or more");
  }
}

namespace
{

double
Median(std::vector<double> values)
{
  return values.empty() ? 0.0 : Percentile(values, 0.5);
}

/** The member's measurements: each measured displacement (or displaced
 *  surface vertex) moved by a normal deviate per component. */
IntraoperativeData
NoisyMeasurements(const IntraoperativeData & data, double sigma, std::mt19937_64 & random)
{
  IntraoperativeData noisy = data;
  if (!(sigma > 0.0))
  {
    return noisy;
  }
  std::normal_distribution<double> deviate(0.0, sigma);
  for (Vector3 & displacement : noisy.sparse.displacements)
  {
    for (int i = 0; i < 3; ++i)
    {
      displacement[i] += deviate(random);
    }
  }
  for (Vector3 & vertex : noisy.surface.vertices)
  {
    for (int i = 0; i < 3; ++i)
    {
      vertex[i] += deviate(random);
    }
  }
  return noisy;
}

using PointSetType = itk::DisplacementPointSetType<3>;
using UncertaintyFilterType = itk::BiomechanicalUncertaintyFilter<PointSetType, itk::BiomechanicalSurfaceMeshType,
                                                                  RegistrationLabelImage, RegistrationImage>;

/** The model's regions made again for a craniotomy of `radius` (the registration's centre, skull base and
 *  contact): the exposed nodes, the contact slaves and the fixed band, as PrepareBrainModel makes them. The
 *  precomputation is left behind (a meshless model's essential-boundary correction depends on the exposed nodes). */
void
SetExposedRegion(BrainModel & model, const BrainModelSettings & settings, const RegistrationImage * image, double radius)
{
  const auto regions = BrainRegionsFilter(model.pipelineModel, settings, image, radius);
  UpdateStage(regions.GetPointer(),
              "uncertainty: the regions for a craniotomy of radius " + std::to_string(radius) + " mm");
  TakeRegions(model, regions->GetOutput());
}

/** Each member's draws (into `members`, one seeded stream in member order:
 *  the ensemble repeats exactly whatever the threads) and the prepared model
 *  loaded from its noisy measurements (serial: the loads are cheap, the
 *  solves are what runs in parallel). */
std::vector<BrainModel>
DrawAndLoadMembers(const BrainModel & prepared, const BrainShiftRegistrationResult & nominal,
                   const BrainShiftUpdateInputs & inputs, const BrainShiftRegistrationSettings & settings,
                   const UncertaintySettings & uncertainty, std::vector<UncertaintyMember> & members)
{
  const bool   noisy = uncertainty.noiseSigma != 0.0;
  const double sigma = uncertainty.noiseSigma < 0.0 ? nominal.model.loadReport.rmsCorrespondenceDistance
                                                    : uncertainty.noiseSigma;
  EnsembleDrawer drawer(uncertainty, nominal.model.model, settings.model.skullGap);
  members.assign(static_cast<std::size_t>(uncertainty.members), {});
  std::vector<BrainModel> models(members.size());
  for (std::size_t m = 0; m < members.size(); ++m)
  {
    UncertaintyMember & member = members[m];
    member.noiseSigma = noisy ? sigma : 0.0;
    static_cast<EnsembleDraw &>(member) = drawer.Next();
    models[m] = prepared;
    if (uncertainty.exposedRadiusSpread > 0.0)
    {
      const double radius = settings.model.craniotomyRadius;
      member.exposedRadius = std::max(0.5 * radius, radius + uncertainty.exposedRadiusSpread * drawer.StandardNormal());
      SetExposedRegion(models[m], settings.model, inputs.preoperativeImage, member.exposedRadius);
    }
    StageTimer timer;
    LoadBrainModel(models[m], NoisyMeasurements(inputs.intraoperative, member.noiseSigma, drawer.Random()), settings.model, timer);
  }
  return models;
}

/** The nodal uncertainty's medians and largest values at the exposed nodes and the others. */
void
SpreadAtExposedNodes(const std::vector<Index> & exposedNodes, BrainShiftUncertaintyResult & result)
{
  std::vector<char> exposed(result.nodalUncertainty.size(), 0);
  for (const Index node : exposedNodes)
  {
    exposed[static_cast<std::size_t>(node)] = 1;
  }
  std::vector<double> atExposed, atInterior;
  for (std::size_t n = 0; n < result.nodalUncertainty.size(); ++n)
  {
    (exposed[n] ? atExposed : atInterior).push_back(result.nodalUncertainty[n]);
  }
  const auto largest = [](const std::vector<double> & values) {
    return values.empty() ? 0.0 : *std::max_element(values.begin(), values.end());
  };
  result.exposedMedian = Median(atExposed);
  result.exposedMax = largest(atExposed);
  result.interiorMedian = Median(atInterior);
  result.interiorMax = largest(atInterior);
}

/** The map's percentiles over the voxels where `inside` holds. */
BrainShiftUncertaintyResult::Region
RegionSpread(const std::string & name, const RegistrationImage * map, const std::function<bool(std::size_t)> & inside)
{
  BrainShiftUncertaintyResult::Region region;
  region.name = name;
  std::vector<double> values;
  const float *       data = map->GetBufferPointer();
  const std::size_t   count = map->GetLargestPossibleRegion().GetNumberOfPixels();
  for (std::size_t v = 0; v < count; ++v)
  {
    if (inside(v))
    {
      values.push_back(data[v]);
    }
  }
  region.voxels = values.size();
  if (!values.empty())
  {
    region.p95 = Percentile(values, 0.95);
    region.median = Percentile(values, 0.5);
    region.max = values.back();
  }
  return region;
}

/** The ventricles (the CSF class deep inside the brain) and the label maps. */
void
SpreadInRegions(const BrainModel & model, const std::vector<RegistrationLabelImage::ConstPointer> & labelMaps,
                BrainShiftUncertaintyResult & result)
{
  const RegistrationImage * map = result.uncertaintyImage.GetPointer();
  if (model.tissueLabelImage.IsNotNull() &&
      model.tissueLabelImage->GetLargestPossibleRegion() == map->GetLargestPossibleRegion())
  {
    auto brain = itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(model.brainMask);
    auto depth = itk::SignedMaurerDistanceMapImageFilter<RegistrationLabelImage, RegistrationImage>::New();
    depth->SetInput(brain);
    depth->SetUseImageSpacing(true);
    depth->SetSquaredDistance(false);
    depth->SetInsideIsPositive(true);
    depth->Update();
    const float *         inside = depth->GetOutput()->GetBufferPointer();
    const unsigned char * classes = model.tissueLabelImage->GetBufferPointer();
    const unsigned char   csf = static_cast<unsigned char>(model.csfClass.csfClass + 1); // labels are 1..K
    std::ostringstream    name;
    name << "ventricles (CSF class at least " << kVentricleDepth << " mm inside the brain)";
    result.regions.push_back(
      RegionSpread(name.str(), map, [&](std::size_t v) { return classes[v] == csf && inside[v] >= kVentricleDepth; }));
  }
  for (std::size_t k = 0; k < labelMaps.size(); ++k)
  {
    const RegistrationLabelImage * labels = labelMaps[k].GetPointer();
    if (labels->GetLargestPossibleRegion() != map->GetLargestPossibleRegion())
    {
      continue; // label maps lie on the preoperative grid (CheckUpdateInputs); kept safe here
    }
    const unsigned char * values = labels->GetBufferPointer();
    result.regions.push_back(
      RegionSpread("label map " + std::to_string(k + 1), map, [&](std::size_t v) { return values[v] != 0; }));
    result.regions.back().labelMap = static_cast<int>(k);
  }
}

} // namespace

BrainShiftUncertaintyResult
EstimateBrainShiftUncertainty(const BrainModel &                     prepared,
                              const BrainShiftRegistrationResult &   nominal,
                              const BrainShiftUpdateInputs &         inputs,
                              const BrainShiftRegistrationSettings & settings,
                              const UncertaintySettings &            uncertainty)
{
  CheckUncertaintySettings(uncertainty);
  const auto started = std::chrono::steady_clock::now();
  if (uncertainty.noiseSigma != 0.0 && inputs.intraoperative.sparse.points.empty() &&
      inputs.intraoperative.surface.vertices.empty())
  {
    throw Error("uncertainty: measurement noise needs measured points or a displaced surface, and this update "
                "takes its surface from an image; give the noise as 0 (--uncertainty-noise 0)");
  }
  if (uncertainty.exposedRadiusSpread > 0.0 &&
      (!(settings.model.craniotomyRadius > 0.0) || settings.model.craniotomyMask.IsNotNull()))
  {
    throw Error("uncertainty: the exposed radius can be drawn only around a spherical craniotomy (a radius, no "
                "mask); give the exposed radius spread as 0 (--uncertainty-exposed-radius 0)");
  }
  BrainShiftUncertaintyResult result;
  Vector3                     drawnGravity = nominal.gravity; // what the members' factors scale
  if (uncertainty.gravityLow != uncertainty.gravityHigh && nominal.gravity.isZero())
  {
    // A fit that chose no gravity cannot tell sizes below the smallest it tried from none: draw around that one.
    double smallest = std::numeric_limits<double>::infinity();
    for (const auto & tried : nominal.gravityFit)
    {
      smallest = tried.first > 0.0 ? std::min(smallest, tried.first) : smallest;
    }
    if (!std::isfinite(smallest) || settings.model.gravity.isZero())
    {
      throw Error("uncertainty: a gravity range is given but the registration has no gravity; give gravity "
                  "(--gravity) or no range");
    }
    drawnGravity = smallest * settings.model.gravity.normalized();
    result.warnings.push_back("uncertainty: the gravity fit chose no gravity; the members draw their gravity's size "
                              "as fractions of the smallest size it tried, " + std::to_string(smallest) + " mm/s^2");
  }
  std::vector<BrainModel> models = DrawAndLoadMembers(prepared, nominal, inputs, settings, uncertainty, result.members);

  // The solves (in parallel), the mean, the nodal spread and its map: the ITK filter.
  auto ensemble = UncertaintyFilterType::New();
  ensemble->SetModelInput(models.front().pipelineModel);
  std::vector<EnsembleDraw> draws(result.members.begin(), result.members.end());
  ensemble->SetMemberDraws(draws);
  for (std::size_t m = 0; m < models.size(); ++m)
  {
    ensemble->SetMemberModelInput(static_cast<unsigned int>(m), models[m].pipelineModel);
    if (models[m].prescribedDisplacements.IsNotNull())
    {
      ensemble->SetMemberPrescribedDisplacements(static_cast<unsigned int>(m), models[m].prescribedDisplacements);
    }
  }
  if (models.front().contactSurface.IsNotNull())
  {
    ensemble->SetContactSurface(models.front().contactSurface);
    ensemble->SetContactGap(settings.model.skullGap);
  }
  UncertaintyFilterType::VectorType gravity;
  for (unsigned int d = 0; d < 3; ++d)
  {
    gravity[d] = drawnGravity[d];
  }
  ensemble->SetGravity(gravity);
  SolverSettings memberSolver = settings.solver;
  if (uncertainty.memberTolerance > 0.0)
  {
    memberSolver.tolerance = uncertainty.memberTolerance;
  }
  ensemble->SetSolverSettings(memberSolver);
  ensemble->SetWarmStart(WarmStartFrom(nominal.solve));
  ensemble->SetMaskImage(itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(nominal.model.brainMask));
  ensemble->SetFitTolerance(settings.fitTolerance);
  ensemble->SetMinimumControlPointSpacing(settings.minimumControlPointSpacing);
  const int threads = uncertainty.threads > 0 ? uncertainty.threads : omp_get_max_threads();
  ensemble->SetNumberOfWorkUnits(static_cast<itk::ThreadIdType>(threads));
  std::string failure;
  try
  {
    ensemble->Update();
  }
  catch (const itk::ExceptionObject & error)
  {
    failure = itk::PlainDescription(error.GetDescription());
  }
  models.clear();
  for (std::size_t m = 0; m < result.members.size() && m < ensemble->GetMembers().size(); ++m)
  {
    static_cast<EnsembleMember &>(result.members[m]) = ensemble->GetMembers()[m];
    const UncertaintyMember & member = result.members[m];
    if (!member.converged)
    {
      result.warnings.push_back("uncertainty: member " + std::to_string(m + 1) +
                                (member.failed ? " failed" : " did not converge") + " and is left out (" +
                                member.message + ")");
    }
  }
  if (!failure.empty())
  {
    throw Error(failure);
  }
  result.usedMembers = static_cast<int>(ensemble->GetNumberOfUsedMembers());
  result.nodalUncertainty = ensemble->GetUncertaintyOutput()->GetPointData()->CastToSTLConstContainer();
  SpreadAtExposedNodes(nominal.model.exposedNodes, result);

  // The mean transform, fitted as the registration's is.
  auto fitter = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>::New();
  fitter->SetInput(ensemble->GetOutput());
  fitter->SetReferenceImage(inputs.preoperativeImage);
  fitter->SetTolerance(settings.fitTolerance);
  fitter->SetMinimumControlPointSpacing(settings.minimumControlPointSpacing);
  fitter->Update();
  result.meanTransform = const_cast<RegistrationTransform *>(fitter->GetTransform());
  result.uncertaintyImage = ensemble->GetUncertaintyImage();
  result.uncertaintyImage->DisconnectPipeline();
  const LabelVolume & brain = nominal.model.brainMask;
  const auto spread = RegionSpread("brain", result.uncertaintyImage, [&](std::size_t v) { return brain.values[v] != 0; });
  result.brainMedian = spread.median;
  result.brainP95 = spread.p95;
  result.brainMax = spread.max;
  SpreadInRegions(nominal.model, inputs.labelMaps, result);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  return result;
}

BrainShiftUncertaintyResult
EstimateUncertaintyAfter(BrainShiftRegistrationResult &         result,
                         const BrainModel &                     prepared,
                         const BrainShiftUpdateInputs &         inputs,
                         const BrainShiftRegistrationSettings & settings,
                         const UncertaintySettings &            uncertainty)
{
  BrainShiftUncertaintyResult ensemble = result.timer.Run("uncertainty", [&] {
    return EstimateBrainShiftUncertainty(prepared, result, inputs, settings, uncertainty);
  });
  result.warnings.insert(result.warnings.end(), ensemble.warnings.begin(), ensemble.warnings.end());
  return ensemble;
}

nlohmann::json
UncertaintyReportJson(const BrainShiftUncertaintyResult & result, const UncertaintySettings & settings)
{
  nlohmann::json members = nlohmann::json::array();
  for (const UncertaintyMember & member : result.members)
  {
    members.push_back({ { "noise_sigma_mm", member.noiseSigma },
                        { "gravity_factor", member.gravityFactor },
                        { "youngs_modulus_factor", member.modulusFactor },
                        { "tissue_modulus_factors", member.tissueFactors },
                        { "poisson_ratio_offset", member.poissonOffset },
                        { "skull_offset_mm", member.skullOffset },
                        { "exposed_radius_mm", member.exposedRadius },
                        { "converged", member.converged },
                        { "failed", member.failed },
                        { "steps", member.steps },
                        { "message", member.message } });
  }
  nlohmann::json regions = nlohmann::json::array();
  for (const auto & region : result.regions)
  {
    regions.push_back({ { "name", region.name },
                        { "voxels", region.voxels },
                        { "median_mm", region.median },
                        { "p95_mm", region.p95 },
                        { "max_mm", region.max } });
  }
  return { { "members", settings.members },
           { "used_members", result.usedMembers },
           { "seed", settings.seed },
           { "distributions",
             { { "noise_sigma_mm", settings.noiseSigma },
               { "gravity_fraction", { settings.gravityLow, settings.gravityHigh } },
               { "youngs_modulus_log_sd", settings.youngsModulusSpread },
               { "tissue_modulus_log_sd", settings.tissueModulusSpread },
               { "poisson_ratio", { settings.poissonLow, settings.poissonHigh } },
               { "skull_gap_sd_mm", settings.skullGapSpread },
               { "exposed_radius_sd_mm", settings.exposedRadiusSpread } } },
           { "member_tolerance_mm", settings.memberTolerance },
           { "map_mm", { { "brain_p50", result.brainMedian }, { "brain_p95", result.brainP95 }, { "brain_max", result.brainMax } } },
           { "nodes_mm",
             { { "exposed_median", result.exposedMedian },
               { "exposed_max", result.exposedMax },
               { "interior_median", result.interiorMedian },
               { "interior_max", result.interiorMax } } },
           { "regions", regions },
           { "seconds", result.seconds },
           { "member_results", members },
           { "warnings", result.warnings } };
}

void
WriteUncertaintyOverlay(const BrainShiftUncertaintyResult & result, const RegistrationImage * preoperative,
                        const std::string & path)
{
  const RegistrationImage * map = result.uncertaintyImage.GetPointer();
  if (map == nullptr || preoperative->GetLargestPossibleRegion() != map->GetLargestPossibleRegion())
  {
    throw Error("uncertainty overlay: the map and the preoperative image do not share a grid (internal error; please "
                "report it)");
  }
  const auto         region = map->GetLargestPossibleRegion();
  const float *      values = map->GetBufferPointer();
  const std::size_t  voxels = region.GetNumberOfPixels();
  const std::size_t  peak = static_cast<std::size_t>(std::max_element(values, values + voxels) - values);
  const double       largest = values[peak];
  const auto         size = region.GetSize();
  const std::size_t  slice = peak / (size[0] * size[1]);
  const auto [grey0, grey1] = OverlayGreyRange(preoperative);
  auto overlay = itk::EdgeOverlayImageType::New();
  itk::EdgeOverlayImageType::SizeType planeSize{ { size[0], size[1] } };
  overlay->SetRegions(itk::EdgeOverlayImageType::RegionType(planeSize));
  overlay->Allocate();
  const float * grey = preoperative->GetBufferPointer();
  const double  greyScale = grey1 > grey0 ? 255.0 / (grey1 - grey0) : 0.0;
  for (std::size_t j = 0; j < size[1]; ++j)
  {
    for (std::size_t i = 0; i < size[0]; ++i)
    {
      const std::size_t v = i + size[0] * (j + size[1] * slice);
      const double      g = std::clamp((grey[v] - grey0) * greyScale, 0.0, 255.0);
      // Transparent at 0; yellow (low) to red (the map's largest value) above.
      const double t = largest > 0.0 ? values[v] / largest : 0.0;
      const double alpha = t > 0.0 ? 0.35 + 0.65 * t : 0.0;
      const double red = 255.0, green = 255.0 * (1.0 - t), blue = 0.0;
      itk::RGBPixel<unsigned char> pixel;
      pixel.Set(static_cast<unsigned char>(std::lround((1 - alpha) * g + alpha * red)),
                static_cast<unsigned char>(std::lround((1 - alpha) * g + alpha * green)),
                static_cast<unsigned char>(std::lround((1 - alpha) * g + alpha * blue)));
      overlay->SetPixel({ { static_cast<itk::IndexValueType>(i), static_cast<itk::IndexValueType>(j) } }, pixel);
    }
  }
  itk::WriteBiomechanicalImage(overlay.GetPointer(), path);
}

} // namespace bmr
