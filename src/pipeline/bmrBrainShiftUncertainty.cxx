// The deformation filter first: ITK's bundled Eigen before the core's (its header says why).
#include "itkBiomechanicalDeformationFilter.h"

#include "bmrBrainShiftUncertainty.h"

#include "bmrBSplineField.h"
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
  const auto fail = [](const std::string & message) { throw Error("uncertainty: " + message); };
  if (settings.members < 2)
  {
    fail(std::to_string(settings.members) + " members; an ensemble needs at least 2 (16 is a good start)");
  }
  if (!std::isfinite(settings.noiseSigma))
  {
    fail("the measurement noise is not a number; give a standard deviation in mm (0: none; negative: from the "
         "loads' correspondence distances)");
  }
  if (!(settings.gravityLow >= 0.0 && settings.gravityLow <= settings.gravityHigh))
  {
    std::ostringstream message;
    message << "the gravity range [" << settings.gravityLow << ", " << settings.gravityHigh
            << "] is not a range of non-negative fractions; give low <= high, e.g. 0.5 1.5";
    fail(message.str());
  }
  if (!(settings.youngsModulusSpread >= 0.0))
  {
    std::ostringstream message;
    message << "the Young's modulus spread is " << settings.youngsModulusSpread
            << "; give the standard deviation of its logarithm, 0 or more (0.3: within a factor of 1.8 at 2 sigma)";
    fail(message.str());
  }
  const bool poisson = settings.poissonLow != 0.0 || settings.poissonHigh != 0.0;
  if (poisson && !(settings.poissonLow > 0.0 && settings.poissonLow <= settings.poissonHigh && settings.poissonHigh < 0.5))
  {
    std::ostringstream message;
    message << "the Poisson's ratio range [" << settings.poissonLow << ", " << settings.poissonHigh
            << "] is not within (0, 0.5) with low <= high; give e.g. 0.45 0.499, or 0 0 to keep the model's";
    fail(message.str());
  }
  if (!(settings.skullGapSpread >= 0.0))
  {
    std::ostringstream message;
    message << "the skull gap spread is " << settings.skullGapSpread << " mm; give a standard deviation of 0 mm or more";
    fail(message.str());
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

/** Materials with a Poisson's ratio above this are the nearly incompressible
 *  tissues whose ratio the ensemble draws (the soft CSF keeps its own). */
constexpr double kIncompressibleFrom = 0.4;

/** The parenchyma's Poisson's ratio the drawn offsets are measured from: the
 *  largest of the model's materials. */
double
NominalPoissonRatio(const Model & model)
{
  double largest = 0.0;
  for (const Material & material : model.materials)
  {
    largest = std::max(largest, material.poissonRatio);
  }
  return largest;
}

/** Linear-interpolation percentile (q in [0, 1]) of `values`, which it sorts. */
double
Percentile(std::vector<double> & values, double q)
{
  std::sort(values.begin(), values.end());
  const double      position = q * static_cast<double>(values.size() - 1);
  const std::size_t below = static_cast<std::size_t>(std::floor(position));
  const std::size_t above = std::min(values.size() - 1, below + 1);
  return values[below] + (position - static_cast<double>(below)) * (values[above] - values[below]);
}

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

/** The skull moved `depth` (mm) towards the brain along its area-weighted
 *  vertex normals: a narrower gap. Towards the body a closed skull's surface
 *  crosses itself only in pockets narrower than twice the depth (a skull made
 *  at a 1.5 mm gap after a 1 mm closing has none narrower than 3 mm, and the
 *  depth stays below 0.9 of the gap). */
ContactSurface
NarrowedSkull(const ContactSurface & skull, double depth)
{
  ContactSurface       narrowed = skull;
  std::vector<Vector3> normals(skull.vertices.size(), Vector3::Zero());
  for (const auto & triangle : skull.OutwardTriangles())
  {
    const Vector3 normal = (skull.vertices[triangle[1]] - skull.vertices[triangle[0]])
                             .cross(skull.vertices[triangle[2]] - skull.vertices[triangle[0]]);
    for (const Index vertex : triangle)
    {
      normals[static_cast<std::size_t>(vertex)] += normal;
    }
  }
  const double towardBody = skull.bodySide == ContactSurface::Side::Inside ? -1.0 : 1.0;
  for (std::size_t v = 0; v < normals.size(); ++v)
  {
    if (normals[v].norm() > 0.0)
    {
      narrowed.vertices[v] += towardBody * depth * normals[v].normalized();
    }
  }
  return narrowed;
}

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
  const bool   gravity = uncertainty.gravityLow != uncertainty.gravityHigh;
  const bool   poisson = uncertainty.poissonLow != 0.0 || uncertainty.poissonHigh != 0.0;
  const double sigma = uncertainty.noiseSigma < 0.0 ? nominal.model.loadReport.rmsCorrespondenceDistance
                                                    : uncertainty.noiseSigma;
  std::mt19937_64                        random(uncertainty.seed);
  std::normal_distribution<double>       standard(0.0, 1.0); // times each spread: a spread of 0 draws nothing
  std::uniform_real_distribution<double> gravityFactor(uncertainty.gravityLow, uncertainty.gravityHigh);
  std::uniform_real_distribution<double> poissonRatio(uncertainty.poissonLow, uncertainty.poissonHigh);
  const double                           nominalPoisson = NominalPoissonRatio(nominal.model.model);
  members.assign(static_cast<std::size_t>(uncertainty.members), {});
  std::vector<BrainModel> models(members.size());
  for (std::size_t m = 0; m < members.size(); ++m)
  {
    UncertaintyMember & member = members[m];
    member.noiseSigma = noisy ? sigma : 0.0;
    member.modulusFactor =
      uncertainty.youngsModulusSpread > 0.0 ? std::exp(uncertainty.youngsModulusSpread * standard(random)) : 1.0;
    member.gravityFactor = gravity ? gravityFactor(random) : 1.0;
    member.poissonOffset = poisson ? poissonRatio(random) - nominalPoisson : 0.0;
    member.skullOffset = uncertainty.skullGapSpread > 0.0
                           ? std::max(uncertainty.skullGapSpread * standard(random), -0.9 * settings.model.skullGap)
                           : 0.0;
    models[m] = prepared;
    if (uncertainty.exposedRadiusSpread > 0.0)
    {
      const double radius = settings.model.craniotomyRadius;
      member.exposedRadius = std::max(0.5 * radius, radius + uncertainty.exposedRadiusSpread * standard(random));
      SetExposedRegion(models[m], settings.model, inputs.preoperativeImage, member.exposedRadius);
    }
    StageTimer timer;
    LoadBrainModel(models[m], NoisyMeasurements(inputs.intraoperative, member.noiseSigma, random), settings.model, timer);
  }
  return models;
}

/** One member's solve from the nominal steady state, with its gravity and
 *  materials; its nodal displacements (the interpolated values when meshless). */
std::vector<Vector3>
SolveMember(const BrainModel & model, UncertaintyMember & member, const Vector3 & nominalGravity,
            const WarmStart & nominalState, SolverSettings solver, int threads)
{
  Model solved = model.pipelineModel->GetModel();
  solved.bodyAcceleration = member.gravityFactor * nominalGravity;
  for (Material & material : solved.materials)
  {
    material.youngsModulus *= member.modulusFactor;
    if (material.poissonRatio > kIncompressibleFrom)
    {
      material.poissonRatio = std::clamp(material.poissonRatio + member.poissonOffset, kIncompressibleFrom, 0.4999);
    }
  }
  auto object = itk::BiomechanicalModelObject::New();
  object->SetModel(std::move(solved));
  if (member.modulusFactor == 1.0 && member.poissonOffset == 0.0)
  {
    object->SetPrecomputation(model.pipelineModel->GetPrecomputation()); // the same reference configuration
  }
  using DeformationType = itk::BiomechanicalDeformationFilter<PointSetType>;
  auto deformation = DeformationType::New();
  deformation->SetModelInput(object);
  if (model.prescribedDisplacements.IsNotNull())
  {
    deformation->SetPrescribedDisplacements(model.prescribedDisplacements);
  }
  if (model.contactSurface.IsNotNull())
  {
    // The skull at the drawn gap. Wider: the contact's offset, the level set
    // of the skull's distance behind it (moved along its normals, the skull
    // kept its ridges where they were and crossed itself in its folds, and
    // every such member folded a cell or started beyond it). Narrower: the
    // skull moved towards the brain (the offset's level set on the brain's
    // side has creases in the skull's valleys, where pressed slaves did not
    // settle: docs/solver.md, contact offset).
    if (member.skullOffset < 0.0)
    {
      deformation->SetContactSurface(itk::MakeMeshFromContactSurface<itk::BiomechanicalSurfaceMeshType>(
        NarrowedSkull(model.surfaces.skull, -member.skullOffset)));
    }
    else
    {
      deformation->SetContactSurface(model.contactSurface);
      deformation->SetContactOffset(-member.skullOffset);
    }
  }
  solver.threads = threads;
  deformation->SetSolverSettings(solver);
  deformation->SetWarmStart(nominalState);
  deformation->SetNumberOfWorkUnits(static_cast<itk::ThreadIdType>(threads));
  deformation->Update();
  const SolveResult & solve = deformation->GetSolveResult();
  member.converged = solve.converged;
  member.steps = solve.steps;
  member.message = solve.message;
  return solve.displacements;
}

/** Per node the mean of the converged members and the 95th percentile of
 *  the distances from it; the medians and largest values at the exposed
 *  nodes and the others. Returns the mean. */
std::vector<Vector3>
NodalSpread(const std::vector<std::vector<Vector3>> & displacements, const std::vector<std::size_t> & used,
            const std::vector<Index> & exposedNodes, BrainShiftUncertaintyResult & result)
{
  const std::size_t    nodeCount = displacements[used.front()].size();
  std::vector<Vector3> mean(nodeCount, Vector3::Zero());
  for (const std::size_t m : used)
  {
    for (std::size_t n = 0; n < nodeCount; ++n)
    {
      mean[n] += displacements[m][n] / static_cast<double>(used.size());
    }
  }
  result.nodalUncertainty.resize(nodeCount);
  std::vector<double> distances(used.size());
  for (std::size_t n = 0; n < nodeCount; ++n)
  {
    for (std::size_t k = 0; k < used.size(); ++k)
    {
      distances[k] = (displacements[used[k]][n] - mean[n]).norm();
    }
    result.nodalUncertainty[n] = Percentile(distances, 0.95);
  }
  std::vector<char> exposed(nodeCount, 0);
  for (const Index node : exposedNodes)
  {
    exposed[static_cast<std::size_t>(node)] = 1;
  }
  std::vector<double> atExposed, atInterior;
  for (std::size_t n = 0; n < nodeCount; ++n)
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
  return mean;
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

/** The nodal values on the brain of the preoperative grid, between the
 *  nodes by the multilevel B-spline approximation the transforms use; the
 *  map's percentiles inside the brain. */
void
MapUncertainty(const std::vector<Vector3> & nodes, const LabelVolume & brain,
               const BrainShiftRegistrationSettings & settings, int threads, BrainShiftUncertaintyResult & result)
{
  std::vector<Vector3> values(nodes.size(), Vector3::Zero());
  for (std::size_t n = 0; n < nodes.size(); ++n)
  {
    values[n].x() = result.nodalUncertainty[n];
  }
  BSplineFitSettings fit;
  fit.tolerance = settings.fitTolerance;
  fit.minimumSpacing = settings.minimumControlPointSpacing;
  const BSplineFitResult field = FitMultilevelBSpline(nodes, values, brain.geometry, fit);
  std::vector<double>    sampled(3 * brain.geometry.VoxelCount());
  SampleBSplineField(field.lattice, brain.geometry, sampled.data(), threads);
  ScalarVolume map;
  map.geometry = brain.geometry;
  map.values.assign(brain.geometry.VoxelCount(), 0.0f);
  const auto inBrain = [&](std::size_t v) { return brain.values[v] != 0; };
  for (std::size_t v = 0; v < map.values.size(); ++v)
  {
    if (inBrain(v))
    {
      map.values[v] = static_cast<float>(std::max(0.0, sampled[3 * v])); // the spline's undershoot is no spread
    }
  }
  result.uncertaintyImage = itk::MakeImageFromBiomechanicalVolume<RegistrationImage>(map);
  const auto spread = RegionSpread("brain", result.uncertaintyImage, inBrain);
  result.brainMedian = spread.median;
  result.brainP95 = spread.p95;
  result.brainMax = spread.max;
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
  std::vector<BrainModel>     models = DrawAndLoadMembers(prepared, nominal, inputs, settings, uncertainty, result.members);

  // The solves in parallel: single-threaded members when there are at least
  // as many as threads.
  const int threads = uncertainty.threads > 0 ? uncertainty.threads : omp_get_max_threads();
  const int count = uncertainty.members;
  const int concurrent = std::max(1, std::min(count, threads));
  const int memberThreads = std::max(1, threads / concurrent);
  const WarmStart                   nominalState = WarmStartFrom(nominal.solve);
  SolverSettings                    memberSolver = settings.solver;
  if (uncertainty.memberTolerance > 0.0)
  {
    memberSolver.tolerance = uncertainty.memberTolerance;
  }
  std::vector<std::vector<Vector3>> displacements(static_cast<std::size_t>(count));
#pragma omp parallel for num_threads(concurrent) schedule(dynamic, 1)
  for (int m = 0; m < count; ++m)
  {
    UncertaintyMember & member = result.members[static_cast<std::size_t>(m)];
    try
    {
      displacements[static_cast<std::size_t>(m)] = SolveMember(models[static_cast<std::size_t>(m)], member,
                                                               drawnGravity, nominalState, memberSolver, memberThreads);
    }
    catch (const std::exception & error)
    {
      member.failed = true;
      member.message = error.what();
    }
  }
  models.clear();

  std::vector<std::size_t> used;
  for (int m = 0; m < count; ++m)
  {
    const UncertaintyMember & member = result.members[static_cast<std::size_t>(m)];
    if (member.converged)
    {
      used.push_back(static_cast<std::size_t>(m));
    }
    else
    {
      result.warnings.push_back("uncertainty: member " + std::to_string(m + 1) +
                                (member.failed ? " failed" : " did not converge") + " and is left out (" +
                                member.message + ")");
    }
  }
  result.usedMembers = static_cast<int>(used.size());
  if (used.size() < 2)
  {
    throw Error("uncertainty: " + std::to_string(used.size()) + " of " + std::to_string(count) +
                " members converged, too few for a spread (" +
                (result.warnings.empty() ? std::string() : result.warnings.front()) +
                "); narrow the distributions or raise max_steps");
  }
  const std::vector<Vector3> & nodes = nominal.model.model.nodes;
  const std::vector<Vector3>   mean = NodalSpread(displacements, used, nominal.model.exposedNodes, result);

  // The mean transform, fitted as the registration's is.
  auto fitter = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>::New();
  fitter->SetInput(itk::MakeDisplacementPointSet<PointSetType>(nodes, mean));
  fitter->SetReferenceImage(inputs.preoperativeImage);
  fitter->SetTolerance(settings.fitTolerance);
  fitter->SetMinimumControlPointSpacing(settings.minimumControlPointSpacing);
  fitter->Update();
  result.meanTransform = const_cast<RegistrationTransform *>(fitter->GetTransform());
  MapUncertainty(nodes, nominal.model.brainMask, settings, threads, result);
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
