// Stability matrix (not a test): the stiff and extreme cases a user meets, on
// every discretization, each either converged (with its error) or stopped with
// the solver's named error. Writes docs/stability-matrix.md and a JSON file.
//
//   bmrStabilityBenchmark [--output docs/stability-matrix.md] [--json FILE]
//                         [--quick] [--threads 2] [--check]
//
// Families (blocks, so that every cell runs in seconds):
//   * nearly incompressible: 30 % uniaxial compression, nu 0.49 / 0.499 / 0.4999,
//     against the analytic neo-Hookean solution;
//   * stiff tumour: a central inclusion 1, 10, 100 and 1000 times as stiff as
//     the parenchyma, 10 % compression;
//   * soft CSF: a central CSF cavity of 1, 3 and 10 Pa (nu 0.1) in parenchyma,
//     10 % compression;
//   * bonded flat punch at 30 % of the block's height (the indentation problem
//     of the CalculiX verification, deeper), against CalculiX C3D10 when ccx
//     is installed;
//   * a 25 mm shift of Colin27 (unless --quick or without mricron-data): the
//     demo's ground truth, registered from its tracked points on 5 mm
//     hexahedra, 7 mm ANP tetrahedra and the 7 mm meshless cloud, against
//     that truth (minutes, not seconds).
// Every solve's dynamic-relaxation error estimate is set beside its true
// error: the distance to the same model solved to a 1000 times tighter
// tolerance. A solve must never report convergence with a wrong answer:
// --check exits 1 if a converged cell's true error exceeds 10 times the
// tolerance, if a cell stopped without a message, or if an ANP-tetrahedral
// or meshless cell did not converge.
#include "bmrBenchmarkSupport.h"
#include "bmrBrainShiftRegistration.h"
#include "bmrCalculix.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"
#include "bmrMeshless.h"
#include "bmrModel.h"
#include "bmrSolver.h"
#include "bmrSyntheticBrainShift.h"
#include "itkBiomechanicalImageIO.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace
{

using bmr::Index;
using bmr::Vector3;
using Json = nlohmann::json;

constexpr double kParenchymaModulus = 3000.0; // Pa
constexpr double kTolerance = 1e-3;           // mm, on blocks 10-20 mm across (1e-4 of the size, as 0.01 mm on a brain)
constexpr double kTightFactor = 1e-3;         // the reference solve's tolerance, relative
constexpr double kWrongAnswerFactor = 10.0;   // --check: true error above this times the tolerance is a wrong answer
constexpr int    kMaxSteps = 2000000;
constexpr double kBrainTolerance = 0.01;     // mm, the registration's default on Colin27
constexpr double kBrainTightFactor = 1e-2;   // Colin27's reference solve: 100 (not 1000) times tighter, for time
const char *     kColin27Image = "/usr/share/mricron/templates/ch2.nii.gz";
const char *     kColin27Mask = "/usr/share/mricron/templates/ch2bet.nii.gz";

enum class Discretization
{
  Hexahedra,
  AnpTetrahedra,
  Meshless
};
const Discretization kDiscretizations[] = { Discretization::Hexahedra, Discretization::AnpTetrahedra,
                                            Discretization::Meshless };

const char *
Name(Discretization discretization)
{
  switch (discretization)
  {
    case Discretization::Hexahedra:
      return "hexahedra";
    case Discretization::AnpTetrahedra:
      return "ANP tetrahedra";
    case Discretization::Meshless:
      break;
  }
  return "meshless";
}

bmr::Material
Tissue(double youngsModulus, double poissonRatio, const std::string & name)
{
  return bmr::Material{ name, youngsModulus, poissonRatio, 1000.0 };
}

/** A grid-based model as the discretization asks: hexahedra, the same grid's
 *  tetrahedra, or the hexahedra's nodes and cells made meshless. */
bmr::Model
Discretize(const std::function<bmr::Model(bmr::GridCells)> & build, Discretization discretization)
{
  bmr::Model model = build(discretization == Discretization::AnpTetrahedra ? bmr::GridCells::Tetrahedra
                                                                           : bmr::GridCells::Hexahedra);
  if (discretization == Discretization::Meshless)
  {
    bmr::MakeMeshlessFromCells(model, bmr::MlsSettings{}, bmr::IntegrationSettings{}, 1);
  }
  return model;
}

/** Cells whose centroid lies in the axis-aligned box [low, high] get material `inside`. */
void
AssignBox(bmr::Model & model, const Vector3 & low, const Vector3 & high, const bmr::Material & inside)
{
  model.materials.push_back(inside);
  const Index material = static_cast<Index>(model.materials.size() - 1);
  for (bmr::Cell & cell : model.cells)
  {
    const int count = bmr::NodesPerCell(cell.type);
    Vector3   centroid = Vector3::Zero();
    for (int k = 0; k < count; ++k)
    {
      centroid += model.nodes[cell.nodes[k]] / count;
    }
    if ((centroid.array() >= low.array()).all() && (centroid.array() <= high.array()).all())
    {
      cell.material = material;
    }
  }
}

/** Top face moved down by `fraction` of the height, the three symmetry planes held. */
void
CompressFromTop(bmr::Model & model, double height, double fraction)
{
  model.fixedConstraints.push_back({ "xmin", { true, false, false } });
  model.fixedConstraints.push_back({ "ymin", { false, true, false } });
  model.fixedConstraints.push_back({ "zmin", { false, false, true } });
  bmr::PrescribedDisplacement top;
  top.nodes = model.NodeSet("zmax");
  top.displacements.assign(top.nodes.size(), Vector3(0.0, 0.0, -fraction * height));
  top.components = { false, false, true };
  model.prescribedDisplacements.push_back(top);
}

/** Lateral stretch s of uniaxial stress at axial stretch lambda for
 *  W = mu/2 (I1bar - 3) + kappa/2 (J - 1)^2: the lateral stress vanishes,
 *  mu J^(-5/3) (s^2 - lambda^2) / 3 + kappa (J - 1) = 0, J = lambda s^2 (Newton). */
double
UniaxialLateralStretch(double lambda, const bmr::Material & material)
{
  const double E = material.youngsModulus, nu = material.poissonRatio;
  const double mu = E / (2.0 * (1.0 + nu)), kappa = E / (3.0 * (1.0 - 2.0 * nu));
  double       s = 1.0 / std::sqrt(lambda);
  for (int iteration = 0; iteration < 200; ++iteration)
  {
    const double J = lambda * s * s;
    const double g = mu * std::pow(J, -5.0 / 3.0) * (s * s - lambda * lambda) / 3.0 + kappa * (J - 1.0);
    const double dg = mu * (-5.0 / 3.0) * std::pow(J, -8.0 / 3.0) * 2.0 * lambda * s * (s * s - lambda * lambda) / 3.0 +
                      mu * std::pow(J, -5.0 / 3.0) * 2.0 * s / 3.0 + kappa * 2.0 * lambda * s;
    const double next = std::max(0.5 * s, s - g / dg);
    if (std::abs(next - s) < 1e-15 * s)
    {
      return next;
    }
    s = next;
  }
  return s;
}

double
MaxDifference(const std::vector<Vector3> & a, const std::vector<Vector3> & b)
{
  double largest = 0.0;
  for (std::size_t n = 0; n < a.size(); ++n)
  {
    largest = std::max(largest, (a[n] - b[n]).norm());
  }
  return largest;
}

/** One solve, caught: converged, not converged, or stopped with the solver's message. */
struct Outcome
{
  std::string          state; // "converged", "not converged", "stopped"
  std::string          message;
  int                  steps = 0;
  int                  restarts = 0;
  double               seconds = 0.0;
  double               estimatedError = 0.0;
  std::vector<Vector3> displacements;
};

Outcome
OutcomeOf(const bmr::SolveResult & result)
{
  Outcome outcome;
  outcome.state = result.converged ? "converged" : "not converged";
  outcome.message = result.message;
  outcome.steps = result.steps;
  outcome.restarts = result.restarts;
  outcome.seconds = result.wallSeconds;
  outcome.estimatedError = result.estimatedError;
  outcome.displacements = result.displacements;
  return outcome;
}

Outcome
Stopped(const std::exception & error)
{
  Outcome outcome;
  outcome.state = "stopped";
  outcome.message = error.what();
  return outcome;
}

Outcome
Solve(const bmr::Model & model, double tolerance, int threads)
{
  bmr::SolverSettings settings;
  settings.integrator = bmr::Integrator::DynamicRelaxation;
  settings.tetrahedron = bmr::TetrahedronFormulation::AverageNodalPressure;
  settings.tolerance = tolerance;
  settings.maxSteps = kMaxSteps;
  settings.threads = threads;
  try
  {
    bmr::Solver solver(model, settings);
    return OutcomeOf(solver.Solve());
  }
  catch (const bmr::Error & error)
  {
    return Stopped(error);
  }
}

/** A cell of the matrix: the case's model on one discretization, its
 *  solve at kTolerance, the reference solve at kTightFactor * kTolerance and,
 *  where one exists, the error against an independent solution. */
struct Cell
{
  std::string family, name, discretization;
  double      tolerance = kTolerance; // mm, of the solve
  Outcome     solve;
  std::string referenceState; // of the tight solve
  double      trueError = -1.0;      // mm, against the tight solve; -1: none
  double      independentError = -1.0; // mm, largest nodal error against the analytic or CalculiX solution
  std::string independent;          // what that solution is
};

using Exact = std::function<std::vector<Vector3>(const bmr::Model &)>;

Cell
RunCell(const std::string &                              family,
        const std::string &                              name,
        Discretization                                   discretization,
        const std::function<bmr::Model(bmr::GridCells)> & build,
        int                                              threads,
        const Exact &                                    exact = {},
        const std::string &                              independent = {})
{
  Cell cell;
  cell.family = family;
  cell.name = name;
  cell.discretization = Name(discretization);
  const bmr::Model model = Discretize(build, discretization);
  cell.solve = Solve(model, kTolerance, threads);
  std::cerr << family << " | " << name << " | " << cell.discretization << ": " << cell.solve.state << " ("
            << cell.solve.steps << " steps, " << cell.solve.seconds << " s)\n";
  if (cell.solve.state != "converged")
  {
    return cell;
  }
  const Outcome reference = Solve(model, kTightFactor * kTolerance, threads);
  cell.referenceState = reference.state;
  if (reference.state == "converged")
  {
    cell.trueError = MaxDifference(cell.solve.displacements, reference.displacements);
  }
  if (exact)
  {
    cell.independentError = MaxDifference(cell.solve.displacements, exact(model));
    cell.independent = independent;
  }
  return cell;
}

std::string
Format(double value, int digits = 2)
{
  std::ostringstream text;
  text << std::setprecision(digits) << value;
  return text.str();
}

std::string
Describe(const Cell & cell)
{
  const Outcome & solve = cell.solve;
  if (solve.state == "stopped")
  {
    return "**stopped**: " + solve.message;
  }
  std::ostringstream text;
  text << (solve.state == "converged" ? "converged" : "**not converged**") << ", " << solve.steps << " steps"
       << (solve.restarts > 0 ? " (" + std::to_string(solve.restarts) + " restarts)" : "") << ", "
       << Format(solve.seconds) << " s; estimated " << Format(solve.estimatedError) << " mm";
  if (cell.trueError >= 0.0)
  {
    text << ", true " << Format(cell.trueError) << " mm";
  }
  else if (solve.state == "converged")
  {
    text << ", true: reference " << cell.referenceState;
  }
  if (cell.independentError >= 0.0)
  {
    text << "; " << cell.independent << " " << Format(cell.independentError) << " mm";
  }
  return text.str();
}

Json
CellJson(const Cell & cell)
{
  return { { "family", cell.family },
           { "case", cell.name },
           { "discretization", cell.discretization },
           { "state", cell.solve.state },
           { "message", cell.solve.message },
           { "steps", cell.solve.steps },
           { "restarts", cell.solve.restarts },
           { "seconds", cell.solve.seconds },
           { "estimated_error_mm", cell.solve.estimatedError },
           { "true_error_mm", cell.trueError },
           { "independent", cell.independent },
           { "independent_error_mm", cell.independentError } };
}

struct Options
{
  std::string output = "docs/stability-matrix.md";
  std::string json;
  bool        quick = false;
  bool        check = false;
  int         threads = 2;
};

Options
ParseOptions(int argc, char ** argv)
{
  Options options;
  for (int k = 1; k < argc; ++k)
  {
    const std::string argument = argv[k];
    const auto        value = [&]() -> std::string {
      if (k + 1 >= argc)
      {
        throw std::runtime_error(argument + " needs a value");
      }
      return argv[++k];
    };
    if (argument == "--output")
    {
      options.output = value();
    }
    else if (argument == "--json")
    {
      options.json = value();
    }
    else if (argument == "--threads")
    {
      const std::string text = value();
      char *            end = nullptr;
      options.threads = static_cast<int>(std::strtol(text.c_str(), &end, 10));
      if (text.empty() || *end != '\0' || options.threads < 0)
      {
        throw std::runtime_error("--threads needs a whole number >= 0 (0: all cores), got '" + text + "'");
      }
    }
    else if (argument == "--quick" || argument == "--check")
    {
      (argument == "--quick" ? options.quick : options.check) = true;
    }
    else
    {
      throw std::runtime_error("unknown option " + argument +
                               "; use --output FILE, --json FILE, --threads N, --quick, --check");
    }
  }
  return options;
}

/** The demo's 25 mm parietal shift of Colin27 (6 mm ANP tetrahedral ground
 *  truth, free rim 0.2, gravity 0.3 g), registered from its tracked points on
 *  each discretization at kBrainTolerance and again kBrainTightFactor times
 *  tighter (the true error), against the ground truth (the 95th percentile
 *  of the displacement error over the brain: the registration's error, the
 *  discretization's and the loads' included). */
std::vector<Cell>
RunColin27Cells(int threads)
{
  const auto image = itk::ReadBiomechanicalImage<bmr::RegistrationImage>(kColin27Image, "Colin27");
  const auto mask = bmr::ThresholdMask(itk::ReadBiomechanicalImage<bmr::RegistrationImage>(kColin27Mask, "brain mask"));
  bmr::SyntheticBrainShiftSettings scene;
  scene.targetShift = 25.0;
  scene.freeRim = 0.2;
  scene.grid.kind = bmr::ImageGridKind::Tetrahedra;
  scene.grid.elementSize = 6.0;
  scene.threads = threads;
  const bmr::SyntheticBrainShift truth = bmr::MakeSyntheticBrainShift(image, mask.GetPointer(), scene);
  const std::string family = "25 mm shift on Colin27, registered from the tracked points";
  const std::string name = "parietal, 6 mm tetrahedral truth";
  std::vector<Cell> cells;
  const std::pair<bmr::ImageGridKind, double> grids[] = { { bmr::ImageGridKind::Hexahedra, 5.0 },
                                                          { bmr::ImageGridKind::Tetrahedra, 7.0 },
                                                          { bmr::ImageGridKind::Meshless, 7.0 } };
  for (std::size_t k = 0; k < std::size(grids); ++k)
  {
    const bmr::ImageGridKind kind = grids[k].first; // named, not bound: lambdas capture them (C++17)
    const double             size = grids[k].second;
    const auto register_ = [&](double tolerance, bmr::BrainShiftRegistrationResult * result) {
      bmr::BrainShiftRegistrationInputs inputs;
      inputs.preoperativeImage = image;
      inputs.brainMask = mask;
      inputs.intraoperative.sparse = truth.trackedPoints;
      bmr::BrainShiftRegistrationSettings settings;
      settings.model.grid.kind = kind;
      settings.model.grid.elementSize = size;
      settings.model.craniotomyCentre = scene.craniotomyCentre;
      settings.model.craniotomyRadius = scene.craniotomyRadius;
      settings.model.threads = threads;
      settings.solver.tolerance = tolerance;
      settings.solver.maxSteps = kMaxSteps;
      try
      {
        *result = bmr::RegisterBrainShift(inputs, settings);
        return OutcomeOf(result->solve);
      }
      catch (const std::exception & error)
      {
        return Stopped(error);
      }
    };
    Cell cell;
    cell.family = family;
    cell.name = name;
    cell.discretization = Name(kDiscretizations[k]) + std::string(" ") + Format(size) + " mm";
    cell.tolerance = kBrainTolerance;
    bmr::BrainShiftRegistrationResult result, tight;
    cell.solve = register_(kBrainTolerance, &result);
    std::cerr << family << " | " << cell.discretization << ": " << cell.solve.state << " (" << cell.solve.steps
              << " steps, " << cell.solve.seconds << " s)\n";
    if (cell.solve.state == "converged")
    {
      const Outcome reference = register_(kBrainTightFactor * kBrainTolerance, &tight);
      cell.referenceState = reference.state;
      if (reference.state == "converged" && reference.displacements.size() == cell.solve.displacements.size())
      {
        cell.trueError = MaxDifference(cell.solve.displacements, reference.displacements);
      }
      cell.independentError = bmr::MeasureDisplacementError(result.transform, truth.truthTransform,
                                                            truth.intraoperativeBrainOnPreoperativeGrid)
                                .p95;
      cell.independent = "ground truth (p95 over the brain)";
    }
    cells.push_back(cell);
  }
  return cells;
}

std::vector<Cell>
RunMatrix(const Options & options)
{
  std::vector<Cell> cells;
  const int         n = options.quick ? 2 : 4; // cells along the 10 mm edge of the uniaxial block
  const int         threads = options.threads;

  // Nearly incompressible: 30 % uniaxial compression of a 10 mm cube.
  for (const double nu : { 0.49, 0.499, 0.4999 })
  {
    const bmr::Material material = Tissue(kParenchymaModulus, nu, "parenchyma");
    const double        lambda = 0.7;
    const double        lateral = UniaxialLateralStretch(lambda, material);
    const auto          build = [&](bmr::GridCells kind) {
      bmr::Model model = bmr::MakeBlockMesh(Vector3(10.0, 10.0, 10.0), { n, n, n }, kind, material);
      CompressFromTop(model, 10.0, 1.0 - lambda);
      return model;
    };
    const Exact exact = [&](const bmr::Model & model) {
      std::vector<Vector3> u;
      for (const Vector3 & x : model.nodes)
      {
        u.emplace_back((lateral - 1.0) * x.x(), (lateral - 1.0) * x.y(), (lambda - 1.0) * x.z());
      }
      return u;
    };
    for (const Discretization discretization : kDiscretizations)
    {
      cells.push_back(RunCell("nearly incompressible, 30 % compression", "nu " + Format(nu, 4), discretization, build,
                              threads, exact, "analytic"));
    }
  }

  // Stiff tumour: an 8 mm inclusion at the centre of a 20 mm block (an eighth by symmetry).
  const int m = options.quick ? 5 : 10; // cells along the eighth's 10 mm edge (the inclusion's 4 mm must fall on grid lines)
  for (const double ratio : { 1.0, 10.0, 100.0, 1000.0 })
  {
    const auto build = [&](bmr::GridCells kind) {
      bmr::Model model =
        bmr::MakeBlockMesh(Vector3(10.0, 10.0, 10.0), { m, m, m }, kind, Tissue(kParenchymaModulus, 0.49, "parenchyma"));
      AssignBox(model, Vector3::Zero(), Vector3(4.0, 4.0, 4.0), Tissue(ratio * kParenchymaModulus, 0.49, "tumour"));
      CompressFromTop(model, 10.0, 0.1);
      return model;
    };
    for (const Discretization discretization : kDiscretizations)
    {
      cells.push_back(RunCell("stiff tumour, 10 % compression", Format(ratio, 4) + ":1", discretization, build, threads));
    }
  }

  // Soft CSF: a central 8 mm cavity of CSF (nu 0.1) in parenchyma.
  for (const double csf : { 1.0, 3.0, 10.0 })
  {
    const auto build = [&](bmr::GridCells kind) {
      bmr::Model model =
        bmr::MakeBlockMesh(Vector3(10.0, 10.0, 10.0), { m, m, m }, kind, Tissue(kParenchymaModulus, 0.49, "parenchyma"));
      AssignBox(model, Vector3::Zero(), Vector3(4.0, 4.0, 4.0), Tissue(csf, 0.1, "csf"));
      CompressFromTop(model, 10.0, 0.1);
      return model;
    };
    for (const Discretization discretization : kDiscretizations)
    {
      cells.push_back(RunCell("soft CSF cavity, 10 % compression", Format(csf, 3) + " Pa", discretization, build,
                              threads));
    }
  }

  // Bonded flat punch, 3 mm into a 10 mm high block (30 %): the reference is
  // CalculiX C3D10 on the symmetric quarter, its corner nodes on every other
  // node of the block's grid.
  const int p = options.quick ? 4 : 16; // cells along the 20 mm edge
  for (const double nu : { 0.49, 0.499 })
  {
    bmr::IndentationProblem punch;
    punch.depth = 3.0;
    punch.material = Tissue(kParenchymaModulus, nu, "tissue");
    std::vector<Vector3> referenceNodes, referenceDisplacements;
    std::string          calculix = "CalculiX C3D10";
    if (!bmr::FindCalculix().empty())
    {
      try
      {
        const bmr::Model quarter =
          bmr::MakeIndentationQuarterModel(punch, { p / 2, p / 2, p / 2 }, bmr::GridCells::Tetrahedra);
        bmr::CalculixSettings settings;
        settings.initialIncrement = 0.1;
        settings.threads = threads;
        const bmr::CalculixResult result = bmr::RunCalculix(quarter, settings);
        referenceNodes = result.mesh.nodes;
        referenceDisplacements = result.meshDisplacements;
      }
      catch (const bmr::Error & error)
      {
        std::cerr << "CalculiX: " << error.what() << "\n";
      }
    }
    for (const Discretization discretization : kDiscretizations)
    {
      const auto build = [&](bmr::GridCells kind) { return bmr::MakeIndentationModel(punch, { p, p, p / 2 }, kind); };
      Exact      exact;
      if (!referenceNodes.empty())
      {
        exact = [&](const bmr::Model & model) {
          return bmr::UnfoldQuarterDisplacements(punch, referenceNodes, referenceDisplacements, model.nodes);
        };
      }
      cells.push_back(RunCell("bonded flat punch, 30 % of the height", "nu " + Format(nu, 4), discretization, build,
                              threads, exact, calculix));
    }
  }

  if (!options.quick && std::filesystem::exists(kColin27Image) && std::filesystem::exists(kColin27Mask))
  {
    const std::vector<Cell> brain = RunColin27Cells(threads);
    cells.insert(cells.end(), brain.begin(), brain.end());
  }
  return cells;
}

std::string
Report(const std::vector<Cell> & cells, const Options & options)
{
  std::ostringstream report;
  report << "# Stability matrix\n\n"
         << "Written by `bmrStabilityBenchmark" << (options.quick ? " --quick" : "")
         << "` (benchmarks/bmrStabilityBenchmark.cxx; `scripts/run-benchmarks.sh` runs it). Every case on every "
            "discretization, dynamic relaxation to "
         << kTolerance << " mm; *estimated* is the solver's error estimate, *true* the largest nodal distance to "
         << "the same model solved to " << kTightFactor * kTolerance << " mm, and *analytic* / *CalculiX* the largest "
         << "nodal distance to that solution (discretization error included). Compression, tumour and CSF: a 10 mm cube "
         << "(for tumour and CSF an eighth of a 20 mm block with the inclusion at its centre, by symmetry), "
         << (options.quick ? "2 and 5" : "4 and 10") << " cells along an edge; punch: a 20 x 20 x 10 mm block, "
         << (options.quick ? 4 : 16) << " cells along 20 mm, a 10 mm square punch bonded to the top, the bottom "
         << "fixed. E = 3000 Pa parenchyma; tetrahedra are the hexahedral grid's cells split in six; meshless: the "
         << "hexahedra's nodes, 2 x 2 x 2 integration points per cell."
         << (options.quick ? ""
                           : " Colin27 (when mricron-data is installed): the demo's parietal 25 mm shift (`biomech demo "
                             "--shift 25 --free-rim 0.2 --truth-grid tetrahedra --truth-element-size 6`), registered "
                             "from its tracked points on each grid (`biomech register --sparse-displacements`, skull "
                             "contact) to " + Format(kBrainTolerance) + " mm, *true* against the same registration solved to " +
                               Format(kBrainTightFactor * kBrainTolerance) + " mm, and the 95th percentile of its "
                               "displacement error against the ground truth.")
         << "\n\n"
         << "Machine: " << bmr::benchmark::CpuModel() << ", " << options.threads
         << " threads, load average at the end " << bmr::benchmark::LoadAverage() << ".\n";
  std::string family;
  for (std::size_t k = 0; k < cells.size(); k += 3)
  {
    if (cells[k].family != family)
    {
      family = cells[k].family;
      report << "\n## " << family << "\n\n| case | " << cells[k].discretization << " | " << cells[k + 1].discretization
             << " | " << cells[k + 2].discretization << " |\n|---|---|---|---|\n";
    }
    report << "| " << cells[k].name << " | " << Describe(cells[k]) << " | " << Describe(cells[k + 1]) << " | "
           << Describe(cells[k + 2]) << " |\n";
  }
  // Computed summary: how the estimate compares with the true error.
  int    converged = 0, stopped = 0, notConverged = 0, wrong = 0;
  double worstRatio = 0.0;
  for (const Cell & cell : cells)
  {
    converged += cell.solve.state == "converged";
    stopped += cell.solve.state == "stopped";
    notConverged += cell.solve.state == "not converged";
    if (cell.trueError >= 0.0)
    {
      wrong += cell.trueError > kWrongAnswerFactor * cell.tolerance;
      worstRatio = std::max(worstRatio, cell.trueError / std::max(cell.solve.estimatedError, 1e-300));
    }
  }
  report << "\n## Summary\n\n"
         << converged << " of " << cells.size() << " cells converged, " << notConverged << " did not within "
         << kMaxSteps << " steps, " << stopped << " stopped with a named error. Of the converged cells with a "
         << "reference, " << wrong << " had a true error above " << kWrongAnswerFactor << " times its tolerance; "
         << "the true error was at most " << Format(worstRatio) << " times the estimate.\n";
  return report.str();
}

} // namespace

int
main(int argc, char ** argv)
{
  try
  {
    const Options options = ParseOptions(argc, argv);
    for (const std::string & path : { options.output, options.json })
    {
      // Before minutes of solves, not after. (absolute("") throws: skip an option not given.)
      if (path.empty())
      {
        continue;
      }
      const std::filesystem::path folder = std::filesystem::absolute(path).parent_path();
      if (!std::filesystem::is_directory(folder))
      {
        throw std::runtime_error("cannot write '" + path + "': folder '" + folder.string() + "' does not exist");
      }
    }
    const std::vector<Cell> cells = RunMatrix(options);
    const std::string       report = Report(cells, options);
    bmr::WriteTextFileAtomically(options.output, report);
    if (!options.json.empty())
    {
      Json all = Json::array();
      for (const Cell & cell : cells)
      {
        all.push_back(CellJson(cell));
      }
      bmr::WriteTextFileAtomically(options.json, all.dump(2) + "\n");
    }
    std::cout << report;
    if (options.check)
    {
      bool failed = false;
      for (const Cell & cell : cells)
      {
        if (cell.solve.state == "stopped" && cell.solve.message.empty())
        {
          std::cerr << "check: " << cell.family << " | " << cell.name << " | " << cell.discretization
                    << " stopped without a message\n";
          failed = true;
        }
        // Hexahedra may fold under the punch (named); the others must hold in every cell.
        if (cell.solve.state != "converged" && cell.discretization != Name(Discretization::Hexahedra))
        {
          std::cerr << "check: " << cell.family << " | " << cell.name << " | " << cell.discretization << " "
                    << cell.solve.state << ": " << cell.solve.message << "\n";
          failed = true;
        }
        if (cell.solve.state == "converged" && cell.trueError > kWrongAnswerFactor * cell.tolerance)
        {
          std::cerr << "check: " << cell.family << " | " << cell.name << " | " << cell.discretization
                    << " reports convergence " << cell.trueError << " mm from the solution\n";
          failed = true;
        }
      }
      return failed ? 1 : 0;
    }
    return 0;
  }
  catch (const std::exception & error)
  {
    std::cerr << "bmrStabilityBenchmark: error: " << error.what() << "\n";
    return 1;
  }
}
