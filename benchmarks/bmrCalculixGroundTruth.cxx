// An independent ground truth for the validation study (issue 19, item 6):
// the study's scenes on Colin27 (docs/validation.md: the exposed surface sunk
// by a smooth sag, gravity, frictionless contact with the rigid skull) solved
// by CalculiX with quadratic tetrahedra (C3D10, Newton, penalty contact) on a
// conforming tetrahedral mesh of the brain, and compared with
//  - the study's ground truth (the module's dynamic relaxation on its own
//    discretization), both fitted with the same B-spline transform and
//    compared voxel by voxel over the intraoperative brain, as
//    docs/ground-truth-agreement.md compares two truths;
//  - the module's ANP tetrahedra on the very mesh CalculiX solved, node by
//    node (what the element and the contact formulation add, without the mesh).
// Writes docs/calculix-ground-truth.md and a JSON record.
//
// By default CalculiX starts cold (nothing of the module's solution enters):
// the brain's boundary tied by springs to anchors that follow it step by step
// (12 proximal steps, CalculixSettings::stabilisationStiffness), the loading
// step's springs handed over gradually, the skull's slaves paired once per
// increment (SMALL SLIDING), the skull closed by 5 mm (no rigid blades in the
// coarse mesh's folds) and decimated to 2 mm. --warm-start true
// --stabilisation-stiffness 0 starts from the ANP solution instead (a first
// step holds the boundary's corner nodes there, the last releases them);
// --stabilisation-extrapolations N restarts the proximal steps from their
// extrapolated limit.
//
// Status (2026-11-28): docs/calculix-ground-truth.md holds both scenes, from
// the defaults. On Colin27 the warm start's release and a cold start without
// springs diverge in the skull contact, and before the slave was written as
// element faces the brain sank through the skull's floor (docs/registration.md,
// "A truth from CalculiX").

// ITK's headers first: they bring ITK's own Eigen, which must precede the system's.
#include "bmrSyntheticBrainShift.h"
#include "itkBiomechanicalImageIO.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"

#include "bmrBenchmarkSupport.h"
#include "bmrCalculix.h"
#include "bmrSolver.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <chrono>
#include <ctime>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <thread>

namespace
{

using bmr::Vector3;
using json = nlohmann::json;
using bmr::benchmark::Fixed;

struct Scene
{
  std::string name;
  double      shift = 10.0;
  double      freeRim = 0.0;
  // The study's ground truth (examples/validation_study.py).
  bmr::ImageGridKind truthKind = bmr::ImageGridKind::Hexahedra;
  double             truthElementSize = 4.0;
};

const std::vector<Scene> kScenes = {
  { "parietal-10mm", 10.0, 0.0, bmr::ImageGridKind::Hexahedra, 4.0 },
  // Hexahedra fold at 20 mm; the study's truth is ANP tetrahedra (docs/model-building.md).
  { "parietal-20mm", 20.0, 0.2, bmr::ImageGridKind::Tetrahedra, 5.0 },
};
const Vector3 kParietal(-11.0, 43.0, 84.0);

/** The model with its per-cell materials (fuzzy tissue classes mix them cell
 *  by cell) grouped into bins of relative width `step` in Young's modulus,
 *  1 - 2 nu (the bulk modulus's sensitivity) and density, each group given
 *  its members' mean: CalculiX reads tens of thousands of materials slowly,
 *  a few hundred quickly. Returns the number of materials. */
std::size_t
BinMaterials(bmr::Model & model, double step)
{
  std::map<std::array<long, 3>, std::vector<bmr::Index>> bins; // key -> old materials
  const auto bin = [&](double value) { return std::lround(std::log(value) / std::log1p(step)); };
  std::vector<char> used(model.materials.size(), 0);
  for (const bmr::Cell & cell : model.cells)
  {
    used[static_cast<std::size_t>(cell.material)] = 1;
  }
  for (std::size_t m = 0; m < model.materials.size(); ++m)
  {
    const bmr::Material & material = model.materials[m];
    if (used[m])
    {
      bins[{ bin(material.youngsModulus), bin(1.0 - 2.0 * material.poissonRatio), bin(material.density) }].push_back(
        static_cast<bmr::Index>(m));
    }
  }
  std::vector<bmr::Material> materials;
  std::vector<bmr::Index>    renumbered(model.materials.size(), -1);
  for (const auto & [key, members] : bins)
  {
    bmr::Material mean = model.materials[static_cast<std::size_t>(members.front())];
    mean.youngsModulus = mean.poissonRatio = mean.density = 0.0;
    for (const bmr::Index m : members)
    {
      mean.youngsModulus += model.materials[static_cast<std::size_t>(m)].youngsModulus / members.size();
      mean.poissonRatio += model.materials[static_cast<std::size_t>(m)].poissonRatio / members.size();
      mean.density += model.materials[static_cast<std::size_t>(m)].density / members.size();
      renumbered[static_cast<std::size_t>(m)] = static_cast<bmr::Index>(materials.size());
    }
    mean.name = "bin " + std::to_string(materials.size());
    materials.push_back(mean);
  }
  for (bmr::Cell & cell : model.cells)
  {
    cell.material = renumbered[static_cast<std::size_t>(cell.material)];
  }
  model.materials = std::move(materials);
  return model.materials.size();
}

/** Mean, 95th percentile and maximum of |a - b| over the nodes. */
json
NodeDifference(const std::vector<Vector3> & a, const std::vector<Vector3> & b)
{
  std::vector<double> distances;
  for (std::size_t i = 0; i < a.size(); ++i)
  {
    distances.push_back((a[i] - b[i]).norm());
  }
  std::sort(distances.begin(), distances.end());
  double sum = 0.0;
  for (const double d : distances)
  {
    sum += d;
  }
  const std::size_t p95 = std::min(distances.size() - 1, static_cast<std::size_t>(0.95 * distances.size()));
  return { { "mean", sum / distances.size() }, { "p95", distances[p95] }, { "max", distances.back() } };
}

/** How far the proximal steps have settled, over the brain's mesh nodes: the
 *  last step's motion (mean, p95, max), and the nodes that moved more than
 *  0.1 mm in it but less than half that over the last two steps: they
 *  alternate between two states (e.g. two contact pairings) instead of
 *  settling. Empty without two steps before the result's. */
json
Settling(const bmr::CalculixResult & result, std::size_t bodyNodes)
{
  const auto & before = result.stabilisationStepsBefore;
  if (before.size() < 2)
  {
    return json::object();
  }
  const std::vector<Vector3> now(result.meshDisplacements.begin(), result.meshDisplacements.begin() + bodyNodes);
  const std::vector<Vector3> last(before.back().begin(), before.back().begin() + bodyNodes);
  int    alternating = 0;
  double largestAlternation = 0.0;
  for (std::size_t i = 0; i < bodyNodes; ++i)
  {
    const double step = (now[i] - last[i]).norm();
    if (step > 0.1 && (now[i] - before.front()[i]).norm() < 0.5 * step)
    {
      ++alternating;
      largestAlternation = std::max(largestAlternation, step);
    }
  }
  return { { "last_step_motion_mm", NodeDifference(now, last) },
           { "alternating_nodes", alternating },
           { "largest_alternation_mm", largestAlternation } };
}

/** The command line's settings of CalculiX's scene and solve. */
struct Options
{
  double      elementSize = 12.0;      // CalculiX's tetrahedra, mm
  double      skullClosing = 5.0;      // mm, both truths' skull (BrainModelSettings::skullClosing)
  double      skullEdge = 2.0;         // mm, the skull decimated for CalculiX's mesh
  double      materialStep = 0.02;     // relative width of the material bins
  double      initialIncrement = 0.05; // fraction of a step
  double      residualTolerance = 0.005;
  bool        smallSliding = true;     // CalculixSettings::smallSliding
  bool        warmStart = false;       // CalculiX starts from the ANP solution
  bool        gradualRelease = true;   // CalculixSettings::gradualRelease
  double      csfModulus = 10.0;       // Pa, the CSF class of both truths (the study's: 10)
  double      stabilisationStiffness = 3e-4; // N/mm, CalculixSettings::stabilisationStiffness (0: off)
  int         stabilisationSteps = 12;   // per stage
  int         stabilisationStages = 1;
  double      stabilisationSoftening = 10.0;
  int         stabilisationExtrapolations = 0; // CalculixSettings::stabilisationExtrapolations
  int         threads = 2;
  std::string workDirectory;           // keep CalculiX's job folders here
};

/** The first line of a message, shortened for a table cell. */
std::string
Short(const std::string & message)
{
  std::string line = message.substr(0, message.find('\n'));
  if (line.size() > 160)
  {
    line = line.substr(0, 157) + "...";
  }
  std::replace(line.begin(), line.end(), '|', '/');
  return line;
}

/** The restarts of a stabilised CalculiX run, for its JSON record. */
json
Extrapolations(const bmr::CalculixResult & result)
{
  json restarts = json::array();
  for (const auto & restart : result.stabilisationExtrapolations)
  {
    restarts.push_back({ { "ratio", restart.ratio },
                         { "largest_shift_mm", restart.largestShift },
                         { "first_step", restart.firstStep } });
  }
  return restarts;
}

json
Run(const Scene & scene, const bmr::RegistrationImage * image, const bmr::RegistrationLabelImage * mask,
    const Options & options)
{
  const double elementSize = options.elementSize;
  const double materialStep = options.materialStep;
  const bool   warmStart = options.warmStart;
  const int    threads = options.threads;
  bmr::SyntheticBrainShiftSettings settings;
  settings.craniotomyCentre = kParietal;
  settings.targetShift = scene.shift;
  settings.freeRim = scene.freeRim;
  settings.threads = threads;
  settings.skullClosing = options.skullClosing;
  settings.csfYoungsModulus = options.csfModulus; // Pa, as Material holds it
  settings.grid.kind = scene.truthKind;
  settings.grid.elementSize = scene.truthElementSize;

  std::cerr << scene.name << ": the study's ground truth (" << bmr::ImageGridKindName(scene.truthKind) << " "
            << scene.truthElementSize << " mm, dynamic relaxation)" << std::endl;
  const bmr::SyntheticBrainShift truth = bmr::MakeSyntheticBrainShift(image, mask, settings);

  bmr::SyntheticBrainShiftSettings tetrahedral = settings;
  tetrahedral.grid.kind = bmr::ImageGridKind::Tetrahedra;
  tetrahedral.grid.elementSize = elementSize;
  bmr::SyntheticBrainShift scenario = bmr::MakeSyntheticBrainShiftModel(image, mask, tetrahedral);
  bmr::Model &             model = scenario.model.model;
  // Both solvers of this mesh solve the same model: materials in bins, the
  // skull (the model's dilated cells, marching cubes of 1 mm voxels: about
  // 270,000 triangles) decimated to a few mm.
  const std::size_t cellMaterials = model.materials.size();
  const std::size_t materials = BinMaterials(model, materialStep);
  const std::size_t skullTriangles = model.contactSurfaces.at(0).triangles.size();
  model.contactSurfaces[0] = bmr::DecimateSurface(model.contactSurfaces[0], options.skullEdge);

  // The module's ANP solve of this very mesh: compared with CalculiX node by
  // node, and (with a warm start) the state CalculiX starts its Newton from.
  std::cerr << scene.name << ": ANP tetrahedra (dynamic relaxation) on CalculiX's mesh" << std::endl;
  bmr::SolverSettings solverSettings;
  solverSettings.tolerance = settings.solverTolerance;
  solverSettings.threads = threads;
  const auto              start = std::chrono::steady_clock::now();
  bmr::Solver             solver(model, solverSettings);
  const bmr::SolveResult  anp = solver.Solve();
  const double            anpSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!anp.converged)
  {
    throw bmr::Error(scene.name + ": the ANP solve on CalculiX's mesh did not converge: " + anp.message);
  }

  std::cerr << scene.name << ": CalculiX C3D10 on " << model.nodes.size() << " nodes, " << model.cells.size()
            << " tetrahedra of " << elementSize << " mm" << (warmStart ? ", started from the ANP solution" : "")
            << std::endl;
  bmr::CalculixSettings calculix;
  calculix.threads = threads;
  // Small first increments (the brain settles onto the skull through 10 Pa CSF).
  calculix.initialIncrement = options.initialIncrement;
  calculix.minimumIncrement = 1e-5;
  calculix.residualTolerance = options.residualTolerance;
  calculix.smallSliding = options.smallSliding;
  calculix.correctionTolerance = 2.0 * options.residualTolerance;
  calculix.gradualRelease = options.gradualRelease;
  calculix.stabilisationStiffness = options.stabilisationStiffness;
  calculix.stabilisationSteps = options.stabilisationSteps;
  calculix.stabilisationStages = options.stabilisationStages;
  calculix.stabilisationSoftening = options.stabilisationSoftening;
  calculix.stabilisationExtrapolations = options.stabilisationExtrapolations;
  if (warmStart)
  {
    calculix.startDisplacements = anp.displacements;
  }
  calculix.workDirectory = options.workDirectory.empty() ? std::string{} : options.workDirectory + "/" + scene.name;
  calculix.keepFiles = !options.workDirectory.empty();
  const bmr::CalculixResult reference = bmr::RunCalculix(model, calculix);
  const std::size_t         bodyNodes = static_cast<std::size_t>(reference.mesh.firstRigidNode);

  // CalculiX's field at every node of its mesh (mid-edge nodes too: the
  // quadratic field), fitted like the study's truth.
  using PointSetType = itk::DisplacementPointSetType<3>;
  using FitterType = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>;
  auto fitter = FitterType::New();
  fitter->SetInput(itk::MakeDisplacementPointSet<PointSetType>(
    std::vector<Vector3>(reference.mesh.nodes.begin(), reference.mesh.nodes.begin() + bodyNodes),
    std::vector<Vector3>(reference.meshDisplacements.begin(), reference.meshDisplacements.begin() + bodyNodes)));
  fitter->SetReferenceImage(image);
  fitter->SetTolerance(0.05);
  fitter->Update();
  const bmr::DisplacementError difference =
    bmr::MeasureDisplacementError(fitter->GetTransform(), truth.truthTransform, truth.intraoperativeBrainOnPreoperativeGrid);
  const bmr::DisplacementError noRegistration =
    bmr::MeasureDisplacementError(nullptr, truth.truthTransform, truth.intraoperativeBrainOnPreoperativeGrid);

  return { { "scene", scene.name },
           { "shift_mm", scene.shift },
           { "free_rim", scene.freeRim },
           { "truth", { { "grid", bmr::ImageGridKindName(scene.truthKind) },
                        { "element_size_mm", scene.truthElementSize },
                        { "nodes", truth.model.model.nodes.size() },
                        { "steps", truth.solve.steps },
                        { "estimated_error_mm", truth.solve.estimatedError },
                        { "fit_max_residual_mm", truth.truthFitMaxResidual },
                        { "seconds", truth.timer.Seconds("truth-solve") } } },
           { "calculix", { { "element_size_mm", elementSize },
                           { "materials", materials },
                           { "cell_materials", cellMaterials },
                           { "material_bin_width", materialStep },
                           { "skull_triangles", model.contactSurfaces[0].triangles.size() },
                           { "skull_triangles_before", skullTriangles },
                           { "model_nodes", model.nodes.size() },
                           { "tetrahedra", model.cells.size() },
                           { "mesh_nodes", bodyNodes },
                           { "slave_faces", reference.mesh.contactPairs.empty() ? 0 : reference.mesh.contactPairs[0].slaveFaces.size() },
                           { "warm_start", warmStart },
                           { "csf_modulus_pa", options.csfModulus },
                           { "residual_tolerance", options.residualTolerance },
                           { "small_sliding", options.smallSliding },
                           { "skull_closing_mm", options.skullClosing },
                           { "contact_slaves", "element faces" }, // before 2026-11-28 17:00: nodes
                           { "gradual_release", (warmStart || options.stabilisationStiffness > 0.0) && options.gradualRelease },
                           { "stabilisation_stiffness_n_per_mm", options.stabilisationStiffness },
                           { "stabilisation_steps", options.stabilisationStiffness > 0.0 ? options.stabilisationSteps : 0 },
                           { "stabilisation_stages", options.stabilisationStiffness > 0.0 ? options.stabilisationStages : 0 },
                           { "stabilisation_forces_n", reference.stabilisationForces },
                           { "stabilisation_stiffnesses_n_per_mm", reference.stabilisationStiffnesses },
                           { "stabilisation_stopped", reference.stabilisationStopped },
                           { "stabilisation_extrapolations", Extrapolations(reference) },
                           { "settling", Settling(reference, bodyNodes) },
                           { "hold_run_seconds", reference.holdRunSeconds },
                           { "increments", reference.increments },
                           { "iterations", reference.iterations },
                           { "release_increments", warmStart ? reference.lastStepIncrements : 0 },
                           { "release_iterations", warmStart ? reference.lastStepIterations : 0 },
                           { "seconds", reference.wallSeconds },
                           { "fit_max_residual_mm", fitter->GetReport().maximumResidual } } },
           { "anp_same_mesh", { { "steps", anp.steps },
                                { "estimated_error_mm", anp.estimatedError },
                                { "seconds", anpSeconds },
                                { "difference_mm", NodeDifference(anp.displacements, reference.displacements) } } },
           { "truth_difference_mm", { { "mean", difference.mean }, { "p95", difference.p95 }, { "max", difference.max } } },
           { "no_registration_mm", { { "mean", noRegistration.mean }, { "p95", noRegistration.p95 }, { "max", noRegistration.max } } } };
}

std::string
Triple(const json & value, int digits = 2)
{
  return Fixed(value["mean"], digits) + " / " + Fixed(value["p95"], digits) + " / " + Fixed(value["max"], digits);
}

/** The stabilisation cell of a run's record, "none" for a run without it. */
std::string
Stabilisation(const json & calculix)
{
  const double stiffness = calculix.value("stabilisation_stiffness_n_per_mm", 0.0);
  if (!(stiffness > 0.0) || !calculix.contains("stabilisation_forces_n") || calculix["stabilisation_forces_n"].empty())
  {
    return "none";
  }
  using bmr::benchmark::Sci;
  const json &       forces = calculix["stabilisation_forces_n"];
  const json &       stiffnesses = calculix["stabilisation_stiffnesses_n_per_mm"];
  const int          stages = calculix["stabilisation_stages"];
  std::ostringstream cell;
  cell << Sci(stiffness, 1) << " N/mm";
  if (stages > 1)
  {
    cell << " to " << Sci(stiffnesses.back().get<double>(), 1) << " N/mm in " << stages << " stages";
  }
  const json restarts = calculix.value("stabilisation_extrapolations", json::array());
  cell << ", " << forces.size() - 1 - restarts.size() << " steps";
  if (!restarts.empty())
  {
    // Each restart's first proximal step (anchored at the extrapolated state):
    // its springs' force is how far the extrapolation missed.
    cell << " in " << restarts.size() + 1 << " runs, restarted from the extrapolated limit (contraction, largest "
         << "anchor shift, first spring force:";
    const char * separator = " ";
    for (const json & restart : restarts)
    {
      cell << separator << Fixed(restart["ratio"], 2) << ", " << Fixed(restart["largest_shift_mm"], 2) << " mm, "
           << Sci(forces[restart["first_step"].get<std::size_t>()].get<double>(), 1) << " N";
      separator = "; ";
    }
    cell << ")";
  }
  if (calculix.value("gradual_release", false))
  {
    cell << ", the loading step's springs handed over gradually";
  }
  cell << "; " << Sci(forces.front().get<double>(), 1) << " / " << Sci(forces.back().get<double>(), 1) << " N ("
       << Sci(forces.back().get<double>() / stiffnesses.back().get<double>(), 1) << " mm)";
  const std::string stopped = calculix.value("stabilisation_stopped", std::string{});
  if (stopped.find("failed, so the result is the run before") != std::string::npos)
  {
    cell << "; a restart after it failed (" << Short(stopped.substr(stopped.find("restart"))) << "), so the result is "
         << "this run's";
  }
  else if (!stopped.empty())
  {
    cell << "; Newton stopped in the next step, so the result is this step's";
  }
  return cell.str();
}

/** docs/calculix-ground-truth.md: every number and every conclusion from `runs`. */
std::string
Report(const json & runs, const std::string & machine, const std::string & command)
{
  std::ostringstream out;
  out << "# An independent ground truth: CalculiX with skull contact\n\n"
      << "Written by `" << command << "` (benchmarks/bmrCalculixGroundTruth.cxx). The validation study's scenes on "
      << "Colin27 (docs/validation.md: the exposed surface sunk by a smooth sag, gravity 0.3 g, frictionless contact "
      << "with the rigid skull, CSF drained) solved twice more:\n\n"
      << "* by **CalculiX** (Newton, NLGEOM, neo-Hookean) with quadratic tetrahedra **C3D10** on a conforming "
      << "tetrahedral mesh of the brain (CGAL Mesh_3, the module's `tetrahedra` grid), the skull as node-to-face "
      << "penalty contact (verification/bmrCalculix.h: the skull's triangles are the faces of a fixed layer of "
      << "wedges, the brain's boundary faces the slave as element faces; the penalty slope is 10 x the stiffest "
      << "Young's modulus per slave edge length; where the record says `small_sliding`, slaves are paired with "
      << "skull faces once per increment). Runs before 2026-11-28 17:00 wrote the slave as nodes, which gave the "
      << "penalty a wrong area (docs/registration.md). This mesh's "
      << "per-cell materials (fuzzy tissue classes) are grouped into bins of the stated relative width and its "
      << "skull decimated, for CalculiX's sake; the module's solve of the same mesh uses the same model;\n"
      << "* by the module's **ANP tetrahedra** (dynamic relaxation, projection contact) on that very mesh.\n\n"
      << "The study's ground truth is the module's dynamic relaxation on its own grid, recomputed here with the "
      << "same skull as CalculiX's scene: the body closed by the `skull_closing_mm` of each row's JSON record before "
      << "the skull is made, so that it has no rigid blades in the folds of CalculiX's coarse mesh. CalculiX starts "
      << "from the ANP solution where the record says `warm_start` (its boundary's corner nodes held there, then "
      << "released: the result is CalculiX's own equilibrium). Where the table gives a stabilisation, CalculiX "
      << "starts cold with every node of the brain's boundary tied by springs of the stated stiffness to anchors: "
      << "at the reference state in the loading step, then, in each proximal step, where the step before ended "
      << "(verification/bmrCalculix.h, `CalculixSettings::stabilisationStiffness`). The fixed point of these steps "
      << "is CalculiX's own equilibrium, nothing of the module's solution enters, and what the springs still carry "
      << "at the end, divided by their stiffness, is how far the last step moved any boundary node. Where the cell "
      << "gives restarts, CalculiX ran the whole deck again with the first proximal step's anchors where the steps' "
      << "measured contraction r says they would end, u_n + r / (1 - r) (u_n - u_n-1) "
      << "(`CalculixSettings::stabilisationExtrapolations`): the fixed point is the same, and the restart's first "
      << "spring force says how far the extrapolation missed. CalculiX's field (at every "
      << "node of its quadratic mesh) and the study's truth are fitted with the same B-spline transform and compared "
      << "as docs/ground-truth-agreement.md compares two truths: |T_1(x) - T_2(x)| of the two backward maps on every "
      << "second voxel of the intraoperative brain. The ANP solve is compared with CalculiX node by node, on the "
      << "mesh's corner nodes: what the element and the contact formulation add, without the mesh.\n\n"
      << "Machine: " << machine << "\n\n"
      << "| scene | study's truth | CalculiX C3D10 mesh | materials (bins) / skull triangles | Newton increments / "
         "iterations | stabilisation: springs, steps; largest spring force first / last step (last step's motion) | "
         "CalculiX s | truths differ: mean / p95 / max mm | no registration: mean / p95 / max mm |\n"
      << "|---|---|---|---|---|---|---|---|---|\n";
  for (const json & run : runs)
  {
    const json & truth = run["truth"];
    const json & calculix = run["calculix"];
    out << "| " << run["scene"].get<std::string>() << " | " << truth["grid"].get<std::string>() << " "
        << Fixed(truth["element_size_mm"], 0) << " mm, " << truth["nodes"] << " nodes, " << truth["steps"]
        << " steps | " << Fixed(calculix["element_size_mm"], 0) << " mm: " << calculix["model_nodes"] << " corner + "
        << calculix["mesh_nodes"].get<long>() - calculix["model_nodes"].get<long>() << " mid-edge nodes, "
        << calculix["tetrahedra"] << " tetrahedra | " << calculix["materials"] << " of " << calculix["cell_materials"]
        << " (" << Fixed(100.0 * calculix["material_bin_width"].get<double>(), 0) << " %) / "
        << calculix["skull_triangles"] << " of " << calculix["skull_triangles_before"] << " | "
        << calculix["increments"] << " / " << calculix["iterations"] << " | " << Stabilisation(calculix) << " | "
        << Fixed(calculix["seconds"], 0)
        << " | " << Triple(run["truth_difference_mm"]) << " | " << Triple(run["no_registration_mm"]) << " |\n";
  }
  out << "\n| scene | ANP on CalculiX's mesh: steps, s | ANP against CalculiX, corner nodes: mean / p95 / max mm | "
         "B-spline fits' largest residuals: study's truth / CalculiX mm |\n|---|---|---|---|\n";
  for (const json & run : runs)
  {
    const json & anp = run["anp_same_mesh"];
    out << "| " << run["scene"].get<std::string>() << " | " << anp["steps"] << ", " << Fixed(anp["seconds"], 1)
        << " | " << Triple(anp["difference_mm"]) << " | " << Fixed(run["truth"]["fit_max_residual_mm"], 2) << " / "
        << Fixed(run["calculix"]["fit_max_residual_mm"], 2) << " |\n";
  }
  out << "\n## Reading the results\n\n";
  for (const json & run : runs)
  {
    const json & difference = run["truth_difference_mm"];
    const json & none = run["no_registration_mm"];
    const double p95 = difference["p95"];
    const double largest = difference["max"];
    const double fits = run["truth"]["fit_max_residual_mm"].get<double>() + run["calculix"]["fit_max_residual_mm"].get<double>();
    const json & anp = run["anp_same_mesh"]["difference_mm"];
    out << "* **" << run["scene"].get<std::string>() << "**: CalculiX's truth and the study's differ by "
        << Fixed(p95, 2) << " mm at the 95th percentile, " << Fixed(100.0 * p95 / none["p95"].get<double>(), 0)
        << " % of the " << Fixed(none["p95"], 2) << " mm that no registration leaves; their largest difference, "
        << Fixed(largest, 2) << " mm, is " << (largest < fits ? "below" : "above")
        << " the sum of the two B-spline fits' largest residuals (" << Fixed(fits, 2) << " mm)"
        << (largest < fits ? ", so it may come from the fits as much as from the solvers"
                           : ": the solutions differ by more than the fits can explain")
        << ". On CalculiX's own mesh the module's ANP tetrahedra differ from C3D10 by " << Fixed(anp["p95"], 2)
        << " mm at the 95th percentile of the nodes (" << Fixed(anp["max"], 2) << " mm at most).";
    const json settling = run["calculix"].value("settling", json::object());
    if (settling.contains("last_step_motion_mm"))
    {
      const json & motion = settling["last_step_motion_mm"];
      out << " CalculiX's last proximal step moved its mesh's nodes by " << Fixed(motion["mean"], 3) << " mm on average ("
          << Fixed(motion["p95"], 3) << " mm at the 95th percentile, " << Fixed(motion["max"], 2) << " mm at most)";
      const int alternating = settling["alternating_nodes"];
      if (alternating > 0)
      {
        out << "; " << alternating << " nodes moved more than 0.1 mm (up to " << Fixed(settling["largest_alternation_mm"], 2)
            << " mm) and came back to where they were two steps before: they alternate between two states instead of "
               "settling";
      }
      out << ".";
    }
    out << "\n";
  }
  return out.str();
}

} // namespace

int
main(int argc, char ** argv)
{
  CLI::App    app{ "CalculiX C3D10 ground truths of the validation study's scenes on Colin27 (docs/calculix-ground-truth.md)" };
  std::string imagePath = "/usr/share/mricron/templates/ch2.nii.gz";
  std::string maskPath = "/usr/share/mricron/templates/ch2bet.nii.gz";
  std::string output = "docs/calculix-ground-truth.md";
  std::string jsonPath;
  Options     options;
  std::vector<std::string> names;
  std::string              earlier;
  app.add_option("--image", imagePath, "preoperative image (Colin27)");
  app.add_option("--mask", maskPath, "its brain (> 0)");
  app.add_option("--output", output, "the Markdown report");
  app.add_option("--json", jsonPath, "also write the numbers as JSON");
  app.add_option("--element-size", options.elementSize, "CalculiX's tetrahedra (mm)")->check(CLI::PositiveNumber);
  app.add_option("--skull-closing", options.skullClosing,
                 "closing radius (mm) of both truths' body before the skull is made: no rigid blades in the fissures")
    ->check(CLI::NonNegativeNumber);
  app.add_option("--skull-edge", options.skullEdge, "mean edge length (mm) of the skull decimated for both solvers of CalculiX's mesh")
    ->check(CLI::PositiveNumber);
  app.add_option("--material-bins", options.materialStep, "relative width of the material bins (E, 1 - 2 nu, density)")
    ->check(CLI::PositiveNumber);
  app.add_option("--initial-increment", options.initialIncrement, "CalculiX's first load increment (fraction of the step)")
    ->check(CLI::Range(1e-4, 1.0));
  app.add_option("--residual-tolerance", options.residualTolerance,
                 "CalculiX's Newton tolerance on the residual force relative to the mean force (the correction's is twice it)")
    ->check(CLI::Range(1e-8, 0.1));
  app.add_option("--small-sliding", options.smallSliding,
                 "CalculiX pairs contact slaves with master faces once per increment, not at every iteration");
  app.add_option("--warm-start", options.warmStart,
                 "start CalculiX from the ANP solution (a first step holds the boundary there, a second releases it)");
  app.add_option("--gradual-release", options.gradualRelease,
                 "with --warm-start: release the held boundary gradually (its reaction forces falling to zero) instead "
                 "of at once; with --stabilisation-stiffness: the same for the loading step's springs in the first "
                 "proximal step (one more CalculiX run, of the loading step alone)");
  app.add_option("--csf-modulus", options.csfModulus,
                 "Young's modulus (Pa) of the CSF class in both truths; the study's scene has 10")
    ->check(CLI::PositiveNumber);
  app.add_option("--stabilisation-stiffness", options.stabilisationStiffness,
                 "N/mm: CalculiX's boundary nodes tied by springs to anchors that follow them step by step (a "
                 "proximal-point iteration to CalculiX's own equilibrium; needs --warm-start false); 0: off")
    ->check(CLI::NonNegativeNumber);
  app.add_option("--stabilisation-steps", options.stabilisationSteps, "proximal steps of each stage")
    ->check(CLI::PositiveNumber);
  app.add_option("--stabilisation-stages", options.stabilisationStages,
                 "stages of proximal steps, each with springs --stabilisation-softening times softer than the one before")
    ->check(CLI::PositiveNumber);
  app.add_option("--stabilisation-softening", options.stabilisationSoftening, "stiffness ratio of one stage to the next")
    ->check(CLI::Range(1.0, 1e6));
  app.add_option("--stabilisation-extrapolations", options.stabilisationExtrapolations,
                 "restarts from the proximal steps' extrapolated limit (each a whole CalculiX run; needs "
                 "--stabilisation-steps >= 2)")
    ->check(CLI::NonNegativeNumber);
  app.add_option("--threads", options.threads, "threads of both solvers")->check(CLI::PositiveNumber);
  app.add_option("--scenes", names, "only these scenes (parietal-10mm, parietal-20mm)");
  app.add_option("--earlier", earlier, "an earlier run's --json: its scenes that are not rerun go into the report too")
    ->check(CLI::ExistingFile);
  app.add_option("--keep", options.workDirectory, "keep CalculiX's job folders under this folder");
  CLI11_PARSE(app, argc, argv);
  if (options.stabilisationStiffness > 0.0 && options.warmStart)
  {
    std::cerr << "bmrCalculixGroundTruth: --stabilisation-stiffness is a cold start of its own; give --warm-start "
                 "true with --stabilisation-stiffness 0, or --warm-start false"
              << std::endl;
    return 2;
  }

  try
  {
    const std::string loadBefore = bmr::benchmark::LoadAverage();
    const auto   image = itk::ReadBiomechanicalImage<bmr::RegistrationImage>(imagePath, "preoperative image");
    const auto   mask = bmr::ThresholdMask(itk::ReadBiomechanicalImage<bmr::RegistrationImage>(maskPath, "brain mask").GetPointer());
    json         runs = json::array();
    for (const Scene & scene : kScenes)
    {
      if (names.empty() || std::find(names.begin(), names.end(), scene.name) != names.end())
      {
        runs.push_back(Run(scene, image, mask, options));
      }
    }
    std::string previousMachine;
    if (!earlier.empty())
    {
      json before;
      std::ifstream(earlier) >> before;
      previousMachine = before.value("machine", "");
      for (const json & run : before.at("runs"))
      {
        const bool rerun = std::any_of(runs.begin(), runs.end(), [&](const json & r) { return r["scene"] == run["scene"]; });
        if (!rerun)
        {
          runs.push_back(run);
        }
      }
      std::sort(runs.begin(), runs.end(), [](const json & a, const json & b) {
        const auto order = [](const json & run) {
          return std::find_if(kScenes.begin(), kScenes.end(), [&](const Scene & s) { return s.name == run["scene"]; }) - kScenes.begin();
        };
        return order(a) < order(b);
      });
    }
    const std::time_t now = std::time(nullptr);
    char              date[32];
    std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M", std::localtime(&now));
    std::ostringstream machine;
    machine << bmr::benchmark::CpuModel() << ", " << std::thread::hardware_concurrency() << " cores, " << date
            << ", load average (1, 5, 15 min) " << loadBefore << " at the start and " << bmr::benchmark::LoadAverage()
            << " at the end, " << options.threads << " threads";
    if (!previousMachine.empty())
    {
      machine << " (scenes " << (names.empty() ? std::string("all") : names.front()) << "); earlier scenes: " << previousMachine;
    }
    if (!jsonPath.empty())
    {
      std::ofstream(jsonPath) << json{ { "machine", machine.str() }, { "runs", runs } }.dump(2) << "\n";
    }
    std::ostringstream command;
    command << "bmrCalculixGroundTruth --element-size " << options.elementSize << " --skull-closing "
            << options.skullClosing << " --skull-edge " << options.skullEdge << " --material-bins " << options.materialStep
            << " --initial-increment " << options.initialIncrement << " --residual-tolerance " << options.residualTolerance
            << " --small-sliding " << (options.smallSliding ? "true" : "false")
            << " --warm-start " << (options.warmStart ? "true" : "false") << " --gradual-release "
            << (options.gradualRelease ? "true" : "false") << " --csf-modulus " << options.csfModulus
            << " --stabilisation-stiffness " << options.stabilisationStiffness << " --stabilisation-steps "
            << options.stabilisationSteps << " --stabilisation-stages " << options.stabilisationStages
            << " --stabilisation-softening " << options.stabilisationSoftening
            << " --stabilisation-extrapolations " << options.stabilisationExtrapolations << " --threads "
            << options.threads;
    std::ofstream(output) << Report(runs, machine.str(), command.str());
    std::cout << json{ { "machine", machine.str() }, { "runs", runs } }.dump(2) << std::endl;
  }
  catch (const std::exception & error)
  {
    std::cerr << "bmrCalculixGroundTruth: " << error.what() << std::endl;
    return 1;
  }
  return 0;
}
