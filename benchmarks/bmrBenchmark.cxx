// Benchmark driver (not a test): throughput of the TLED force kernels, time to
// dynamic-relaxation convergence for a brain-sized model, peak memory, and
// error against run time for a CalculiX-referenced indentation problem; the
// meshless (MTLED) discretization on the same nodes beside the TLED elements.
// Writes a Markdown report (docs/benchmarks.md) and a CSV for the plot script
// (scripts/plot-benchmarks.py); scripts/run-benchmarks.sh runs both.
//
//   bmrBenchmark [--output docs/benchmarks.md] [--csv docs/benchmark-error-vs-time.csv]
//                [--threads 1,2] [--rounds 3] [--quick] [--skip-brain] [--skip-indentation]
//                [--reference-divisions 16] [--indentation-divisions 4,8,16,32]
//                [--indentation-tolerance 1e-4] [--indentation-poisson 0.45]
//                [--calculix-threads 1] [--wait-quiet 300] [--reference-cache DIR]
//
// Each brain-sized case runs in a child process (the same executable with
// --child), so that its peak memory (getrusage ru_maxrss) is its own. The
// child modes also serve to reproduce or profile one case:
//   bmrBenchmark --child brain hex|tet|mtled THREADS SPACING STEPS REPEATS
//   bmrBenchmark --child indentation hex|tet DIVISIONS THREADS TOLERANCE POISSON [HOURGLASS]
//   bmrBenchmark --child triad THREADS   (memory bandwidth: STREAM's triad)
#include "bmrBenchmarkSupport.h"
#include "bmrCalculix.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshless.h"
#include "bmrModel.h"
#include "bmrSolver.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <sys/resource.h>
#include <unistd.h>

#ifdef _OPENMP
#  include <omp.h>
#endif

#ifndef BMR_BUILD_TYPE
#  define BMR_BUILD_TYPE "unknown"
#endif
#ifndef BMR_CXX_FLAGS
#  define BMR_CXX_FLAGS ""
#endif
#ifndef BMR_NATIVE_ARCH_SETTING
#  define BMR_NATIVE_ARCH_SETTING "unknown"
#endif

namespace
{

using bmr::Index;
using bmr::Vector3;
using bmr::benchmark::CpuModel;
using bmr::benchmark::LoadAverage;
using bmr::benchmark::ReadTextFile;
using Json = nlohmann::json;
using Clock = std::chrono::steady_clock;

// ---------------------------------------------------------------------------
// Targets of the issue and the published reference.
// ---------------------------------------------------------------------------
constexpr double kTargetTetElementStepsPerSecond = 20e6; // ANP tetrahedra, 2 threads
constexpr double kTargetBrainHexSeconds = 2.0;
constexpr double kTargetBrainTetSeconds = 6.0;
constexpr double kTargetBrainMeshlessSeconds = 6.0; // including precomputation, 2 threads
constexpr double kMillerDesktopSeconds = 19.2; // ~100,000 DOF, desktop CPU (Joldes, Wittek, Miller)
constexpr double kMillerGpuSeconds = 4.0;
constexpr int    kMeshlessIndentationMaxDivisions = 16; // meshless indentation runs on n = 4, 8, 16 only

// Brain-sized model (as examples/scenes/brain-sized-*.json, spacing chosen for ~33,000 nodes).
const Vector3       kBrainSemiAxes(70.0, 85.0, 60.0);
constexpr double    kBrainTargetNodes = 33000.0;
constexpr double    kBrainBaseZ = -45.0;       // surface nodes with z <= this are held
constexpr double    kCraniotomyRadius = 25.0;  // surface nodes within this of (0,0,60) ...
constexpr double    kCraniotomyDepth = 10.0;   // ... are pushed 10 mm in (-z)
constexpr double    kBrainTolerance = 0.01;    // mm
const bmr::Material kBrain{ "brain", 3000.0, 0.49, 1000.0 };

double
Seconds(Clock::time_point start)
{
  return std::chrono::duration<double>(Clock::now() - start).count();
}

double
PeakMemoryMiB()
{
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0; // Linux: kB
}

double
Median(std::vector<double> values)
{
  if (values.empty())
  {
    return 0.0;
  }
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

std::string
Fixed(double value, int digits)
{
  std::ostringstream text;
  text << std::fixed << std::setprecision(digits) << value;
  return text.str();
}

std::string
Sci(double value, int digits = 2)
{
  std::ostringstream text;
  text << std::scientific << std::setprecision(digits) << value;
  return text.str();
}

// ---------------------------------------------------------------------------
// Contention: how much CPU other processes used while a case ran.
// ---------------------------------------------------------------------------
struct CpuSample
{
  double busySeconds = 0.0; // all CPUs, from /proc/stat
  double idleSeconds = 0.0;
};

CpuSample
ReadCpu()
{
  std::ifstream      stat("/proc/stat");
  std::string        label;
  CpuSample          sample;
  unsigned long long value = 0;
  stat >> label;
  const double tick = static_cast<double>(sysconf(_SC_CLK_TCK));
  for (int field = 0; field < 8 && stat >> value; ++field) // user nice system idle iowait irq softirq steal
  {
    (field == 3 || field == 4 ? sample.idleSeconds : sample.busySeconds) += value / tick;
  }
  return sample;
}

double
OwnCpuSeconds()
{
  double total = 0.0;
  for (const int who : { RUSAGE_SELF, RUSAGE_CHILDREN })
  {
    rusage usage{};
    getrusage(who, &usage);
    total += usage.ru_utime.tv_sec + 1e-6 * usage.ru_utime.tv_usec + usage.ru_stime.tv_sec + 1e-6 * usage.ru_stime.tv_usec;
  }
  return total;
}

/** Average number of cores other processes kept busy between Start() and OtherCores(). */
class ContentionMeter
{
public:
  void Start()
  {
    m_Cpu = ReadCpu();
    m_Own = OwnCpuSeconds();
    m_Start = Clock::now();
  }
  double OtherCores() const
  {
    const double wall = Seconds(m_Start);
    const double busy = ReadCpu().busySeconds - m_Cpu.busySeconds;
    const double own = OwnCpuSeconds() - m_Own;
    return wall > 0.0 ? std::max(0.0, (busy - own) / wall) : 0.0;
  }

private:
  CpuSample         m_Cpu;
  double            m_Own = 0.0;
  Clock::time_point m_Start;
};

/** Waits (up to maxSeconds) until other processes use less than `threshold`
 *  cores over a 3 s window; returns the last measured use. */
double
WaitForQuiet(double maxSeconds, double threshold = 0.15)
{
  const auto start = Clock::now();
  double     others = 0.0;
  do
  {
    ContentionMeter meter;
    meter.Start();
    std::this_thread::sleep_for(std::chrono::seconds(3));
    others = meter.OtherCores();
    if (others < threshold)
    {
      break;
    }
  } while (Seconds(start) < maxSeconds);
  return others;
}

/** First line of `ccx -v` that names the version, e.g. "Version 2.20". */
std::string
CalculixVersion(const std::string & executable)
{
  FILE * pipe = ::popen(("'" + executable + "' -v 2>&1").c_str(), "r");
  if (!pipe)
  {
    return "unknown version";
  }
  std::string version = "unknown version";
  char        buffer[512];
  while (std::fgets(buffer, sizeof buffer, pipe))
  {
    const std::string line(buffer);
    const auto        at = line.find("Version");
    if (at != std::string::npos && version == "unknown version")
    {
      version = line.substr(at);
      version.erase(version.find_last_not_of(" \r\n") + 1);
    }
  }
  ::pclose(pipe);
  return version;
}

std::string
CellsName(bmr::GridCells cells)
{
  return cells == bmr::GridCells::Hexahedra ? "hexahedra" : "ANP tetrahedra";
}

std::string
CellsKey(bmr::GridCells cells)
{
  return cells == bmr::GridCells::Hexahedra ? "hex" : "tet";
}

bmr::GridCells
CellsFromKey(const std::string & key)
{
  if (key == "hex")
  {
    return bmr::GridCells::Hexahedra;
  }
  if (key == "tet")
  {
    return bmr::GridCells::Tetrahedra;
  }
  throw bmr::Error("bmrBenchmark: cells must be 'hex' or 'tet', not '" + key + "'");
}

/** Brain-sized cases: "hex" and "tet" (TLED), "mtled" (meshless on the hexahedral model's nodes and body). */
std::string
KindName(const std::string & key)
{
  return key == "hex" ? "hexahedra" : key == "tet" ? "ANP tetrahedra" : "meshless (MTLED)";
}

std::vector<int>
ParseIntList(const std::string & text)
{
  std::vector<int>  values;
  std::stringstream stream(text);
  std::string       item;
  while (std::getline(stream, item, ','))
  {
    if (!item.empty())
    {
      values.push_back(std::stoi(item));
    }
  }
  return values;
}

// ---------------------------------------------------------------------------
// Brain-sized model.
// ---------------------------------------------------------------------------
bmr::Model
MakeBrainModel(double spacing, bmr::GridCells cells, double depth = kCraniotomyDepth)
{
  bmr::Model model = bmr::MakeEllipsoidMesh(kBrainSemiAxes, spacing, cells, kBrain);
  const Vector3      top(0.0, 0.0, kBrainSemiAxes.z());
  std::vector<Index> base, craniotomy;
  for (const Index node : model.NodeSet("surface"))
  {
    const Vector3 & p = model.nodes[node];
    if (p.z() <= kBrainBaseZ)
    {
      base.push_back(node);
    }
    else if ((p - top).norm() <= kCraniotomyRadius)
    {
      craniotomy.push_back(node);
    }
  }
  model.nodeSets["base"] = base;
  model.nodeSets["craniotomy"] = craniotomy;
  model.fixedConstraints.push_back(bmr::FixedConstraint{ "base", { true, true, true } });
  bmr::PrescribedDisplacement push;
  push.nodes = craniotomy;
  push.displacements.assign(craniotomy.size(), Vector3(0.0, 0.0, -depth));
  model.prescribedDisplacements.push_back(push);
  return model;
}

/** Grid spacing (mm) whose ellipsoid mesh has the node count closest to the target. */
double
BrainSpacing(double targetNodes, int & nodes)
{
  const double volume = 4.0 / 3.0 * M_PI * kBrainSemiAxes.prod();
  double       best = std::cbrt(volume / targetNodes);
  int          bestNodes = 0;
  double       spacing = best;
  for (int iteration = 0; iteration < 8; ++iteration)
  {
    const int count =
      static_cast<int>(bmr::MakeEllipsoidMesh(kBrainSemiAxes, spacing, bmr::GridCells::Hexahedra, kBrain).nodes.size());
    if (bestNodes == 0 || std::abs(count - targetNodes) < std::abs(bestNodes - targetNodes))
    {
      best = spacing;
      bestNodes = count;
    }
    if (std::abs(count - targetNodes) < 0.01 * targetNodes)
    {
      break;
    }
    spacing *= std::cbrt(count / targetNodes);
    spacing = std::round(spacing * 1000.0) / 1000.0;
  }
  nodes = bestNodes;
  return best;
}

/** Child process: one brain-sized case (cells, threads): dynamic relaxation to
 *  0.01 mm, then the throughput of explicit time steps. Prints one JSON line. */
Json
RunBrainCase(double spacing, const std::string & kind, int threads, int throughputSteps, int repeats)
{
  const bool           meshless = kind == "mtled";
  const bmr::GridCells cells = meshless ? bmr::GridCells::Hexahedra : CellsFromKey(kind);
  Json                 out;
  out["cells"] = kind;
  out["threads"] = threads;
  out["spacing_mm"] = spacing;

  auto       start = Clock::now();
  bmr::Model model = MakeBrainModel(spacing, cells);
  out["mesh_seconds"] = Seconds(start);
  out["integration_seconds"] = 0.0;
  if (meshless)
  {
    // Precomputation, part 1: integration points (background grid, inside test, materials).
    start = Clock::now();
    bmr::MakeMeshlessFromCells(model, bmr::MlsSettings{}, bmr::IntegrationSettings{}, threads);
    out["integration_seconds"] = Seconds(start);
    out["integration_points"] = model.meshless.integrationPoints.size();
  }
  // Units of work per step: elements, or integration points for the meshless model.
  const std::size_t units = meshless ? model.meshless.integrationPoints.size() : model.cells.size();
  out["nodes"] = model.nodes.size();
  out["dofs"] = 3 * model.nodes.size();
  out["elements"] = units;
  out["craniotomy_nodes"] = model.NodeSet("craniotomy").size();
  out["base_nodes"] = model.NodeSet("base").size();

  double critical = 0.0;
  {
    bmr::SolverSettings settings;
    settings.integrator = bmr::Integrator::DynamicRelaxation;
    settings.tolerance = kBrainTolerance;
    settings.threads = threads;
    start = Clock::now();
    bmr::Solver solver(model, settings);
    out["setup_seconds"] = Seconds(start);
    critical = solver.CriticalTimeStep();
    const bmr::SolveResult result = solver.Solve();
    out["dr_seconds"] = result.wallSeconds;
    out["total_seconds"] = out["integration_seconds"].get<double>() + out["setup_seconds"].get<double>() + result.wallSeconds;
    out["dr_steps"] = result.steps;
    out["dr_estimated_error_mm"] = result.estimatedError;
    out["dr_converged"] = result.converged;
    out["dr_message"] = result.message;
    out["max_displacement_mm"] = result.maxDisplacement;
    out["active_components"] = result.activeComponents;
    // Fingerprint for the thread-count determinism check.
    double sum = 0.0;
    for (std::size_t n = 0; n < result.displacements.size(); ++n)
    {
      sum += (n % 7 + 1) * result.displacements[n].sum();
    }
    std::ostringstream fingerprint;
    fingerprint << std::setprecision(17) << sum;
    out["dr_fingerprint"] = fingerprint.str();
  }

  // Throughput: explicit dynamics for a fixed number of steps at 0.8 x the
  // critical step (a 1 mm smooth push over the run), median of the repeats.
  {
    bmr::Model pushed = MakeBrainModel(spacing, cells, 1.0);
    if (meshless)
    {
      pushed.discretization = model.discretization;
      pushed.meshless = model.meshless;
    }
    bmr::SolverSettings settings;
    settings.integrator = bmr::Integrator::ExplicitDynamics;
    settings.timeStepSafetyFactor = 0.8;
    settings.endTime = throughputSteps * 0.8 * critical;
    settings.threads = threads;
    bmr::Model loaded = pushed;
    loaded.prescribedDisplacements.front().curve.rampTime = settings.endTime;
    bmr::Solver         solver(loaded, settings);
    std::vector<double> nsPerElementStep;
    int                 steps = 0;
    for (int r = 0; r < repeats; ++r)
    {
      const bmr::SolveResult result = solver.Solve();
      steps = result.steps;
      nsPerElementStep.push_back(1e9 * result.wallSeconds / (static_cast<double>(steps) * units));
    }
    const double median = Median(nsPerElementStep);
    out["throughput_steps"] = steps;
    out["throughput_repeats"] = repeats;
    out["ns_per_element_step"] = median;
    out["ns_per_element_step_min"] = *std::min_element(nsPerElementStep.begin(), nsPerElementStep.end());
    out["ns_per_element_step_max"] = *std::max_element(nsPerElementStep.begin(), nsPerElementStep.end());
    out["element_steps_per_second"] = 1e9 / median;
  }
  out["peak_memory_mib"] = PeakMemoryMiB();
  if (meshless)
  {
    // Size of the shape-function tables (after the peak-memory reading: this
    // evaluation repeats the solver's, only to count the neighbours).
    const auto                    mls = bmr::MovingLeastSquares::ForModel(model);
    const bmr::ShapeFunctionTable table = mls->Evaluate(model.meshless.integrationPoints, false, threads);
    const double entries = static_cast<double>(table.nodes.size());
    out["table_entries"] = entries;
    out["mean_neighbours"] = entries / std::max<Index>(1, table.PointCount());
    // The per-point table (node, value, gradient) and the force kernel's copy in schedule order (node, gradient).
    out["table_bytes"] = entries * ((sizeof(Index) + 8.0 + 24.0) + (sizeof(Index) + 24.0));
  }
  return out;
}

Json
RunChild(const std::string & self, const std::string & arguments)
{
  const std::string command = "'" + self + "' --child " + arguments;
  FILE *            pipe = ::popen(command.c_str(), "r");
  if (!pipe)
  {
    throw bmr::Error("bmrBenchmark: could not start " + command);
  }
  std::string output;
  char        buffer[4096];
  while (std::fgets(buffer, sizeof buffer, pipe))
  {
    output += buffer;
  }
  const int   status = ::pclose(pipe);
  const auto  at = output.rfind("BMR_RESULT ");
  if (status != 0 || at == std::string::npos)
  {
    throw bmr::Error("bmrBenchmark: child '" + arguments + "' failed (status " + std::to_string(status) +
                     "). Output:\n" + output);
  }
  return Json::parse(output.substr(at + 11));
}

// ---------------------------------------------------------------------------
// Indentation: error against run time, CalculiX reference.
// ---------------------------------------------------------------------------
struct Reference
{
  bmr::IndentationProblem problem;
  int                     divisions = 16; // quarter model, per axis
  std::vector<Vector3>    nodes;
  std::vector<Vector3>    displacements;
  double                  forceZ = 0.0; // full block, N
  double                  seconds = 0.0;
  int                     meshNodes = 0;
  int                     elements = 0;
  int                     increments = 0;
  int                     iterations = 0;
  bool                    cached = false; // read from the cache, not computed in this run
};

/** Cache file name for a reference: everything the solution depends on. */
std::string
ReferenceKey(const bmr::IndentationProblem & problem, int divisions)
{
  std::ostringstream key;
  key << std::setprecision(10) << "indentation-c3d10-quarter-" << divisions << "-E" << problem.material.youngsModulus
      << "-nu" << problem.material.poissonRatio << "-depth" << problem.depth << "-patch" << problem.patchHalfWidth
      << "-size" << problem.size.x() << "x" << problem.size.y() << "x" << problem.size.z() << "-v2";
  return key.str();
}

bool
LoadReference(const std::string & path, const std::string & key, Reference & reference)
{
  std::ifstream stream(path);
  std::string   header;
  if (!stream || !std::getline(stream, header) || header != key)
  {
    return false;
  }
  std::size_t count = 0;
  stream >> reference.forceZ >> reference.seconds >> reference.meshNodes >> reference.elements >>
    reference.increments >> reference.iterations >> count;
  reference.nodes.resize(count);
  reference.displacements.resize(count);
  for (std::size_t i = 0; i < count; ++i)
  {
    Vector3 & p = reference.nodes[i];
    Vector3 & u = reference.displacements[i];
    stream >> p.x() >> p.y() >> p.z() >> u.x() >> u.y() >> u.z();
  }
  return static_cast<bool>(stream);
}

void
SaveReference(const std::string & path, const std::string & key, const Reference & reference)
{
  std::ostringstream text;
  text << key << "\n"
       << std::setprecision(17) << reference.forceZ << " " << reference.seconds << " " << reference.meshNodes << " "
       << reference.elements << " " << reference.increments << " " << reference.iterations << " "
       << reference.nodes.size() << "\n";
  for (std::size_t i = 0; i < reference.nodes.size(); ++i)
  {
    const Vector3 & p = reference.nodes[i];
    const Vector3 & u = reference.displacements[i];
    text << p.x() << " " << p.y() << " " << p.z() << " " << u.x() << " " << u.y() << " " << u.z() << "\n";
  }
  std::filesystem::create_directories(std::filesystem::path(path).parent_path());
  const std::string temporary = path + ".tmp";
  std::ofstream(temporary) << text.str();
  std::filesystem::rename(temporary, path);
}

Reference
RunReference(const bmr::IndentationProblem & problem, int divisions, int threads, const std::string & cache = {})
{
  const std::string key = ReferenceKey(problem, divisions);
  const std::string path = cache.empty() ? std::string{} : (std::filesystem::path(cache) / (key + ".txt")).string();
  if (!path.empty())
  {
    Reference cached;
    if (LoadReference(path, key, cached))
    {
      cached.problem = problem;
      cached.divisions = divisions;
      cached.cached = true;
      return cached;
    }
  }
  Reference reference;
  reference.problem = problem;
  reference.divisions = divisions;
  const bmr::Model quarter =
    bmr::MakeIndentationQuarterModel(problem, { divisions, divisions, divisions }, bmr::GridCells::Tetrahedra);
  bmr::CalculixSettings settings;
  settings.quadratic = true;
  settings.initialIncrement = 0.25;
  settings.threads = threads;
  const bmr::CalculixResult result = bmr::RunCalculix(quarter, settings);
  reference.nodes = result.mesh.nodes;
  reference.displacements = result.meshDisplacements;
  reference.forceZ = 4.0 * result.TotalReactionForce(quarter.NodeSet("patch")).z();
  reference.seconds = result.wallSeconds;
  reference.meshNodes = static_cast<int>(result.mesh.nodes.size());
  reference.elements = static_cast<int>(quarter.cells.size());
  reference.increments = result.increments;
  reference.iterations = result.iterations;
  if (!path.empty())
  {
    SaveReference(path, key, reference);
  }
  return reference;
}

struct IndentationRun
{
  bmr::GridCells cells = bmr::GridCells::Hexahedra;
  int            divisions = 4; // x and y; z has half
  double         spacing = 0.0;
  int            nodes = 0;
  int            elements = 0;
  int            threads = 1;
  double         setupSeconds = 0.0;
  double         solveSeconds = 0.0;
  int            steps = 0;
  bool           converged = false;
  double         estimatedError = 0.0;
  double         rmsError = 0.0; // relative to the indentation depth
  double         maxError = 0.0;
  double         forceError = 0.0; // relative to the reference force
  double         forceZ = 0.0;
  std::string    failure;          // the solver's error, if it failed
  double         hourglassCoefficient = -1.0; // < 0: default
  bool           meshless = false;            // MTLED on the hexahedral grid's nodes (elements = integration points)
};

std::string
RunLabel(const IndentationRun & run)
{
  if (run.meshless)
  {
    return "meshless (MTLED)";
  }
  std::string label = CellsName(run.cells);
  if (run.hourglassCoefficient >= 0.0)
  {
    std::ostringstream k;
    k << label << ", hourglass k = " << run.hourglassCoefficient;
    label = k.str();
  }
  return label;
}

std::string
RunKey(const IndentationRun & run)
{
  if (run.meshless)
  {
    return "mtled";
  }
  std::string key = CellsKey(run.cells);
  if (run.hourglassCoefficient >= 0.0)
  {
    std::ostringstream k;
    k << key << "-k" << run.hourglassCoefficient;
    key = k.str();
  }
  return key;
}

IndentationRun
RunIndentation(const Reference & reference,
               bmr::GridCells    cells,
               int               divisions,
               int               threads,
               double            tolerance,
               double            hourglassCoefficient = -1.0, // < 0: the solver's default
               bool              meshless = false)            // MTLED on the grid's nodes (cells: the body)
{
  IndentationRun run;
  run.meshless = meshless;
  run.hourglassCoefficient = hourglassCoefficient;
  run.cells = cells;
  run.divisions = divisions;
  run.threads = threads;
  run.spacing = reference.problem.size.x() / divisions;
  bmr::Model model = bmr::MakeIndentationModel(reference.problem, { divisions, divisions, divisions / 2 }, cells);
  run.nodes = static_cast<int>(model.nodes.size());
  run.elements = static_cast<int>(model.cells.size());
  double integrationSeconds = 0.0; // meshless precomputation, part 1: counted in the setup time
  if (meshless)
  {
    const auto start = Clock::now();
    bmr::MakeMeshlessFromCells(model, bmr::MlsSettings{}, bmr::IntegrationSettings{}, threads);
    integrationSeconds = Seconds(start);
    run.elements = static_cast<int>(model.meshless.integrationPoints.size());
  }

  bmr::SolverSettings settings;
  settings.integrator = bmr::Integrator::DynamicRelaxation;
  settings.tolerance = tolerance;
  settings.threads = threads;
  if (hourglassCoefficient >= 0.0)
  {
    settings.hourglassCoefficient = hourglassCoefficient;
  }
  auto        start = Clock::now();
  bmr::Solver solver(model, settings);
  run.setupSeconds = integrationSeconds + Seconds(start);
  // Small cases take milliseconds: repeat (at least 3 runs, until 2 s are spent, at most 7) and take the median.
  bmr::SolveResult    result = solver.Solve();
  std::vector<double> times{ result.wallSeconds };
  double              spent = result.wallSeconds;
  while (times.size() < 7 && (times.size() < 3 || spent < 2.0))
  {
    const double seconds = solver.Solve().wallSeconds;
    times.push_back(seconds);
    spent += seconds;
  }
  run.solveSeconds = Median(times);
  run.steps = result.steps;
  run.converged = result.converged;
  run.estimatedError = result.estimatedError;

  const std::vector<Vector3> expected =
    bmr::UnfoldQuarterDisplacements(reference.problem, reference.nodes, reference.displacements, model.nodes);
  const bmr::DisplacementComparison comparison =
    bmr::CompareDisplacements(model.nodes, result.displacements, model.nodes, expected);
  run.rmsError = comparison.rmsError / reference.problem.depth;
  run.maxError = comparison.maxError / reference.problem.depth;
  for (const Index node : model.NodeSet("patch"))
  {
    run.forceZ += result.reactionForces[node].z();
  }
  run.forceError = std::abs(run.forceZ - reference.forceZ) / std::abs(reference.forceZ);
  return run;
}

// ---------------------------------------------------------------------------
// Driver.
// ---------------------------------------------------------------------------
struct Options
{
  std::string      output = "docs/benchmarks.md";
  std::string      csv = "docs/benchmark-error-vs-time.csv";
  std::vector<int> threads{ 1, 2 };
  bool             quick = false;
  bool             skipBrain = false;
  bool             skipIndentation = false;
  int              referenceDivisions = 16;
  std::vector<int> indentationDivisions{ 4, 8, 16, 32 };
  double           indentationTolerance = 1e-4;
  double           indentationPoisson = 0.45;
  int              calculixThreads = 1;
  double           waitQuiet = 300.0; // s to wait for a quiet machine before each timed case
  std::string      referenceCache;    // folder for CalculiX reference solutions (empty: none)
  int              rounds = 3;        // brain-sized cases run this many times in turn
};

void
WriteAtomically(const std::string & path, const std::string & text)
{
  const std::filesystem::path target(path);
  if (target.has_parent_path())
  {
    std::filesystem::create_directories(target.parent_path());
  }
  const std::string temporary = path + ".tmp";
  {
    std::ofstream stream(temporary);
    stream << text;
    if (!stream)
    {
      throw bmr::Error("bmrBenchmark: could not write " + temporary);
    }
  }
  std::filesystem::rename(temporary, target);
}

int
Driver(const Options & options, const std::string & self)
{
  const auto         started = Clock::now();
  const std::string  loadBefore = LoadAverage();
  std::ostringstream md;
  const auto         log = [](const std::string & line) { std::cerr << "[bmrBenchmark] " << line << std::endl; };

  const unsigned hardwareThreads = std::thread::hardware_concurrency();
  std::time_t    now = std::time(nullptr);
  char           date[64];
  std::strftime(date, sizeof date, "%Y-%m-%d %H:%M UTC", std::gmtime(&now));

  md << "# Benchmarks\n\n"
     << "Written by `bmrBenchmark` (benchmarks/bmrBenchmark.cxx); run `scripts/run-benchmarks.sh` to reproduce. "
     << "Timings are wall-clock seconds on the machine below; per-unit costs are per element and time step.\n\n"
     << "## Machine and build\n\n"
     << "| | |\n|---|---|\n"
     << "| CPU | " << CpuModel() << " |\n"
     << "| Hardware threads | " << hardwareThreads << " |\n"
     << "| Compiler | " <<
#if defined(__clang__)
    "clang "
#elif defined(__GNUC__)
    "GCC "
#endif
     << __VERSION__ << " |\n"
     << "| Build type, flags | " << BMR_BUILD_TYPE << ", `" << BMR_CXX_FLAGS
     << "`; core library -O3, BMR_NATIVE_ARCH=" << BMR_NATIVE_ARCH_SETTING << " (-march=native when ON) |\n"
#ifdef _OPENMP
     << "| OpenMP | " << _OPENMP << " |\n"
#endif
     << "| Precision | double (64-bit) throughout |\n"
     << "| Thread counts measured | ";
  for (std::size_t i = 0; i < options.threads.size(); ++i)
  {
    md << (i ? ", " : "") << options.threads[i];
  }
  md << " |\n"
     << "| Date | " << date << " |\n"
     << "| Load average at start (1, 5, 15 min) | " << loadBefore << " |\n\n";
  const std::string        header = md.str();
  std::vector<std::string> summary; // rows of the targets table
  md.str("");

  // -------------------------------------------------------------------------
  // Brain-sized cases: throughput and dynamic relaxation.
  // -------------------------------------------------------------------------
  std::vector<Json> brain;
  if (!options.skipBrain)
  {
    int          nodes = 0;
    const double spacing = options.quick ? 6.0 : BrainSpacing(kBrainTargetNodes, nodes);
    const int    steps = options.quick ? 50 : 300;
    const int    repeats = options.quick ? 2 : 5;
    // Rounds: the cases run in turn, `rounds` times; each case's figures are the
    // median over the rounds (run-to-run variation on a shared machine is large).
    const int                      rounds = options.quick ? 1 : options.rounds;
    std::vector<std::vector<Json>> perCase;
    for (int round = 0; round < rounds; ++round)
    {
      std::size_t index = 0;
      for (const std::string kind : { "hex", "tet", "mtled" })
      {
        for (const int threads : options.threads)
        {
          log("brain-sized " + KindName(kind) + ", " + std::to_string(threads) + " thread(s), round " +
              std::to_string(round + 1) + "/" + std::to_string(rounds) + "...");
          std::ostringstream arguments;
          arguments << "brain " << kind << " " << threads << " " << std::setprecision(17) << spacing << " "
                    << steps << " " << repeats;
          const double    before = WaitForQuiet(options.waitQuiet);
          ContentionMeter meter;
          meter.Start();
          Json result = RunChild(self, arguments.str());
          result["other_cores_before"] = before;
          result["other_cores"] = meter.OtherCores();
          log("  DR " + Fixed(result["dr_seconds"].get<double>(), 2) + " s, " +
              std::to_string(result["dr_steps"].get<int>()) + " steps; " +
              Fixed(result["ns_per_element_step"].get<double>(), 1) + " ns/element-step");
          if (perCase.size() <= index)
          {
            perCase.emplace_back();
          }
          perCase[index++].push_back(result);
        }
      }
    }
    for (const std::vector<Json> & results : perCase)
    {
      Json                combined = results.front();
      std::vector<double> ns, dr, integration, setup, total;
      double              otherCores = 0.0, memory = 0.0;
      bool                sameResult = true;
      for (const Json & r : results)
      {
        ns.push_back(r["ns_per_element_step"].get<double>());
        dr.push_back(r["dr_seconds"].get<double>());
        integration.push_back(r["integration_seconds"].get<double>());
        setup.push_back(r["setup_seconds"].get<double>());
        total.push_back(r["total_seconds"].get<double>());
        otherCores = std::max(otherCores, r["other_cores"].get<double>());
        memory = std::max(memory, r["peak_memory_mib"].get<double>());
        sameResult = sameResult && r["dr_fingerprint"] == results.front()["dr_fingerprint"];
      }
      combined["rounds"] = results.size();
      combined["ns_per_element_step"] = Median(ns);
      combined["ns_round_min"] = *std::min_element(ns.begin(), ns.end());
      combined["ns_round_max"] = *std::max_element(ns.begin(), ns.end());
      combined["element_steps_per_second"] = 1e9 / Median(ns);
      combined["dr_seconds"] = Median(dr);
      combined["dr_seconds_min"] = *std::min_element(dr.begin(), dr.end());
      combined["dr_seconds_max"] = *std::max_element(dr.begin(), dr.end());
      combined["integration_seconds"] = Median(integration);
      combined["setup_seconds"] = Median(setup);
      combined["total_seconds"] = Median(total);
      combined["total_seconds_min"] = *std::min_element(total.begin(), total.end());
      combined["total_seconds_max"] = *std::max_element(total.begin(), total.end());
      combined["other_cores"] = otherCores;
      combined["peak_memory_mib"] = memory;
      combined["repeatable"] = sameResult;
      brain.push_back(combined);
    }

    const Json & first = brain.front();
    md << "## Brain-sized model\n\n"
       << "Ellipsoid with semi-axes (70, 85, 60) mm on a regular grid of spacing " << Fixed(spacing, 3)
       << " mm (chosen for about 33,000 nodes; the demo scenes in examples/scenes use 3.6 mm), E = 3000 Pa, "
       << "nu = 0.49, density 1000 kg/m^3. Surface nodes with z <= " << kBrainBaseZ
       << " mm are held; surface nodes within " << kCraniotomyRadius
       << " mm of the top (0, 0, 60) are pushed 10 mm in (-z): " << first["craniotomy_nodes"].get<int>()
       << " craniotomy nodes, " << first["base_nodes"].get<int>() << " base nodes.\n\n";

    // (i) throughput
    md << "### Force-kernel throughput\n\n"
       << "Explicit dynamics (central difference) for a fixed number of steps at 0.8 x the critical time step, "
       << "on the brain-sized mesh (a 1 mm smooth push of the craniotomy over the run); the whole time step is "
       << "counted (internal forces, hourglass control or nodal pressure averaging, integration, constraints), "
       << "divided by elements x steps (meshless: integration points x steps, on the hexahedral model's nodes and body "
       << "made meshless with the default settings: linear MLS, dilatation 1.6, 2 x 2 x 2 Gauss points per background "
       << "cell of the median nodal spacing, EBCIEM). Each round times " << brain.front()["throughput_repeats"].get<int>()
       << " runs of " << brain.front()["throughput_steps"].get<int>() << " steps and keeps their median; the table "
       << "gives the median over " << brain.front()["rounds"].get<int>() << " rounds and the range of the rounds.\n\n"
       << "| Elements (meshless: integration points) | Count | Threads | ns / element-step (median) | rounds min..max | element-steps / s | Other load (cores, max) | Target |\n"
       << "|---|---|---|---|---|---|---|---|\n";
    for (const Json & r : brain)
    {
      const bool        tet = r["cells"] == "tet";
      const std::string kind = r["cells"].get<std::string>();
      const int         threads = r["threads"].get<int>();
      const double      rate = r["element_steps_per_second"].get<double>();
      std::string       target = "";
      if (tet && threads == 2)
      {
        target = std::string(">= 20 M/s: ") + (rate >= kTargetTetElementStepsPerSecond ? "**met**" : "**MISSED**");
      }
      md << "| " << (kind == "hex" ? std::string("hexahedra (hourglass control)") : KindName(kind) + (kind == "mtled" ? " integration points" : "")) << " | "
         << r["elements"].get<int>() << " | " << threads << " | " << Fixed(r["ns_per_element_step"].get<double>(), 1)
         << " | " << Fixed(r["ns_round_min"].get<double>(), 1) << ".." << Fixed(r["ns_round_max"].get<double>(), 1)
         << " | " << Fixed(rate / 1e6, 2) << " M | "
         << Fixed(r["other_cores"].get<double>(), 2) << " | " << target << " |\n";
    }
    for (const Json & r : brain)
    {
      if (r["cells"] == "tet" && r["threads"] == 2)
      {
        const double rate = r["element_steps_per_second"].get<double>();
        summary.push_back("| ANP tetrahedra, element-steps per second, 2 threads | >= 20 M | " + Fixed(rate / 1e6, 1) +
                          " M | " + (rate >= kTargetTetElementStepsPerSecond ? "met" : "**MISSED**") + " |");
      }
    }
    // Speed-up per element type.
    md << "\n";
    for (const std::string key : { "hex", "tet", "mtled" })
    {
      double one = 0.0, two = 0.0;
      for (const Json & r : brain)
      {
        if (r["cells"] == key && r["threads"] == 1)
        {
          one = r["ns_per_element_step"].get<double>();
        }
        if (r["cells"] == key && r["threads"] == 2)
        {
          two = r["ns_per_element_step"].get<double>();
        }
      }
      if (one > 0.0 && two > 0.0)
      {
        md << "Speed-up 1 -> 2 threads, " << KindName(key) << ": " << Fixed(one / two, 2)
           << "x.\n";
      }
    }

    // (ii) dynamic relaxation
    md << "\n### Time to dynamic-relaxation convergence (tolerance " << kBrainTolerance << " mm)\n\n"
       << "Adaptive dynamic relaxation from rest to an estimated max nodal error below 0.01 mm. \"Solve\" is the "
       << "time-stepping loop (Solver::Solve); \"setup\" is the solver's precomputation (shape functions, masses, "
       << "hourglass vectors); the mesh generation is not counted. Solve: median over the rounds (range).\n\n"
       << "| Elements | Nodes | DOF | Threads | Setup s | Solve s (median) | rounds min..max | DR steps | Estimated error mm | Converged | Peak memory MiB | Other load (cores, max) | Target (solve) |\n"
       << "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const Json & r : brain)
    {
      const bool   tet = r["cells"] == "tet";
      if (r["cells"] == "mtled")
      {
        continue; // below, with its precomputation
      }
      const double solve = r["dr_seconds"].get<double>();
      const double target = tet ? kTargetBrainTetSeconds : kTargetBrainHexSeconds;
      md << "| " << (tet ? "ANP tetrahedra" : "hexahedra") << " | " << r["nodes"].get<int>() << " | "
         << r["dofs"].get<int>() << " | " << r["threads"].get<int>() << " | "
         << Fixed(r["setup_seconds"].get<double>(), 2) << " | " << Fixed(solve, 2) << " | "
         << Fixed(r["dr_seconds_min"].get<double>(), 2) << ".." << Fixed(r["dr_seconds_max"].get<double>(), 2) << " | "
         << r["dr_steps"].get<int>() << " | " << Sci(r["dr_estimated_error_mm"].get<double>()) << " | "
         << (r["dr_converged"].get<bool>() ? "yes" : "**NO**") << " | " << Fixed(r["peak_memory_mib"].get<double>(), 0)
         << " | " << Fixed(r["other_cores"].get<double>(), 2) << " | < " << target << " s: " << (solve < target && r["dr_converged"].get<bool>() ? "**met**" : "**MISSED**")
         << " |\n";
    }
    for (const Json & r : brain)
    {
      const bool   tet = r["cells"] == "tet";
      if (r["cells"] == "mtled")
      {
        continue;
      }
      const double solve = r["dr_seconds"].get<double>();
      const double target = tet ? kTargetBrainTetSeconds : kTargetBrainHexSeconds;
      const bool   met = solve < target && r["dr_converged"].get<bool>();
      summary.push_back(std::string("| Brain-sized (") + std::to_string(r["dofs"].get<int>()) + " DOF) dynamic relaxation to " +
                        "0.01 mm, " + (tet ? "ANP tetrahedra" : "hexahedra") + ", " +
                        std::to_string(r["threads"].get<int>()) + " thread(s) | < " + Fixed(target, 0) + " s | " +
                        Fixed(solve, 2) + " s (+ " + Fixed(r["setup_seconds"].get<double>(), 2) + " s setup) | " +
                        (met ? "met" : "**MISSED**") + " |");
    }
    // (iii) meshless: precomputation split, tables, and the total beside TLED.
    bool meshlessHeader = false;
    for (const Json & r : brain)
    {
      if (r["cells"] != "mtled")
      {
        continue;
      }
      if (!meshlessHeader)
      {
        meshlessHeader = true;
        md << "\n### Meshless (MTLED): precomputation, tables and total time\n\n"
           << "The hexahedral brain-sized model's nodes (" << r["nodes"].get<int>() << ") and body made meshless with "
           << "the defaults (linear MLS, dilatation 1.6, 2 x 2 x 2 Gauss points per background cell of the median nodal "
           << "spacing, EBCIEM), then the same dynamic relaxation to 0.01 mm. Precomputation: \"integration points\" is "
           << "bmr::MakeMeshlessFromCells (background grid, inside test, materials); \"solver construction\" is the "
           << "bmr::Solver constructor (k-d tree neighbour search, MLS shape functions and derivatives at the integration "
           << "points and the nodes, force model, the force kernel's schedule). Shape-function table memory = entries x "
           << "((4 + 8 + 24) + (4 + 24)) bytes (the per-integration-point table: node index, value, gradient; the force "
           << "kernel's copy in its schedule's order: node index, gradient), "
           << "entries = integration points x mean neighbours (estimate; the nodal EBCIEM table is not counted). "
           << "Medians over the rounds.\n\n"
           << "| Threads | Integration points | Points / node | Mean neighbours / point | Table entries | Table memory MiB | "
              "Integration points s | Solver construction s | Solve s | Total s | rounds min..max (total) | DR steps | "
              "Estimated error mm | Converged | Peak memory MiB |\n"
           << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
      }
      md << "| " << r["threads"].get<int>() << " | " << r["integration_points"].get<int>() << " | "
         << Fixed(r["integration_points"].get<double>() / r["nodes"].get<double>(), 2) << " | "
         << Fixed(r["mean_neighbours"].get<double>(), 1) << " | " << Sci(r["table_entries"].get<double>()) << " | "
         << Fixed(r["table_bytes"].get<double>() / (1024.0 * 1024.0), 0) << " | "
         << Fixed(r["integration_seconds"].get<double>(), 2) << " | " << Fixed(r["setup_seconds"].get<double>(), 2)
         << " | " << Fixed(r["dr_seconds"].get<double>(), 2) << " | " << Fixed(r["total_seconds"].get<double>(), 2)
         << " | " << Fixed(r["total_seconds_min"].get<double>(), 2) << ".." << Fixed(r["total_seconds_max"].get<double>(), 2)
         << " | " << r["dr_steps"].get<int>() << " | " << Sci(r["dr_estimated_error_mm"].get<double>()) << " | "
         << (r["dr_converged"].get<bool>() ? "yes" : "**NO**") << " | " << Fixed(r["peak_memory_mib"].get<double>(), 0) << " |\n";
    }
    if (meshlessHeader)
    {
      md << "\nBrain-sized dynamic relaxation, meshless beside TLED (total = precomputation + solve; the mesh generation "
         << "is not counted; medians over the rounds):\n\n"
         << "| Discretization | Threads | Work units | DR steps | Solve s | Total s incl. precomputation | Target (meshless: < "
         << Fixed(kTargetBrainMeshlessSeconds, 0) << " s total, 2 threads) |\n|---|---|---|---|---|---|---|\n";
      for (const Json & r : brain)
      {
        const std::string kind = r["cells"].get<std::string>();
        const double      total = r["total_seconds"].get<double>();
        std::string       target;
        if (kind == "mtled" && r["threads"] == 2)
        {
          const bool met = total < kTargetBrainMeshlessSeconds && r["dr_converged"].get<bool>();
          target = std::string(met ? "**met**" : "**MISSED**") + " (" + Fixed(total, 2) + " s)";
          summary.push_back("| Brain-sized (" + std::to_string(r["dofs"].get<int>()) + " DOF) meshless (MTLED) dynamic "
                            "relaxation to 0.01 mm, 2 threads, including precomputation | < " +
                            Fixed(kTargetBrainMeshlessSeconds, 0) + " s | " + Fixed(total, 2) + " s (" +
                            Fixed(r["integration_seconds"].get<double>(), 2) + " s integration points + " +
                            Fixed(r["setup_seconds"].get<double>(), 2) + " s solver construction + " +
                            Fixed(r["dr_seconds"].get<double>(), 2) + " s solve) | " + (met ? "met" : "**MISSED**") + " |");
        }
        md << "| " << KindName(kind) << " | " << r["threads"].get<int>() << " | " << r["elements"].get<int>()
           << (kind == "mtled" ? " integration points" : " elements") << " | " << r["dr_steps"].get<int>() << " | "
           << Fixed(r["dr_seconds"].get<double>(), 2) << " | " << Fixed(total, 2) << " | " << target << " |\n";
      }
      for (const Json & r : brain)
      {
        if (r["cells"] == "mtled" && r["threads"] == 2)
        {
          const double total = r["total_seconds"].get<double>();
          md << "\nThe issue's target for the meshless solver, under " << Fixed(kTargetBrainMeshlessSeconds, 0)
             << " s for the brain-sized (~100,000 DOF) model including precomputation on this 2-core machine, is "
             << (total < kTargetBrainMeshlessSeconds && r["dr_converged"].get<bool>() ? "met" : "**not met**")
             << ": measured " << Fixed(total, 2) << " s = " << Fixed(r["integration_seconds"].get<double>(), 2)
             << " s integration points + " << Fixed(r["setup_seconds"].get<double>(), 2) << " s solver construction + "
             << Fixed(r["dr_seconds"].get<double>(), 2) << " s solve (" << r["dr_steps"].get<int>() << " steps).\n";
        }
      }
    }

    md << "\nPublished reference: Miller et al. (TLED with dynamic relaxation) report " << kMillerDesktopSeconds
       << " s for about 100,000 DOF on a desktop CPU and under " << kMillerGpuSeconds << " s on a GPU.\n\n";

    // Determinism across thread counts.
    for (const std::string key : { "hex", "tet", "mtled" })
    {
      std::vector<std::string> prints;
      for (const Json & r : brain)
      {
        if (r["cells"] == key)
        {
          prints.push_back(r["dr_fingerprint"].get<std::string>());
        }
      }
      if (prints.size() > 1)
      {
        const bool same = std::all_of(prints.begin(), prints.end(), [&](const std::string & p) { return p == prints[0]; });
        bool repeatable = true;
        for (const Json & r : brain)
        {
          repeatable = repeatable && (r["cells"] != key || r["repeatable"].get<bool>());
        }
        md << "Dynamic-relaxation displacements, " << KindName(key) << ", "
           << (same ? "bit-identical" : "**DIFFERENT**") << " across the thread counts and "
           << (repeatable ? "identical" : "**DIFFERENT**") << " across the rounds (checksum).\n";
      }
    }
    double spread = 1.0;
    for (const Json & r : brain)
    {
      spread = std::max(spread, r["ns_round_max"].get<double>() / r["ns_round_min"].get<double>());
      spread = std::max(spread, r["dr_seconds_max"].get<double>() / r["dr_seconds_min"].get<double>());
    }
    md << "\nThe slowest round of a case took up to " << Fixed(spread, 2) << "x as long as its fastest"
       << (spread > 1.3 ? " although this machine showed no other load: the host's other tenants (not visible from "
                          "inside the virtual machine) also vary the timings, so compare medians and ranges, not single runs."
                        : ".")
       << "\n";
    md << "\nPeak memory is the child process's ru_maxrss (getrusage) for the whole case: mesh, solver, the "
       << "relaxation and the throughput runs. \"Other load\" is the average number of cores that other processes "
       << "kept busy while the case ran (/proc/stat minus this process's CPU time); above about 0.2 the timings, "
       << "the 2-thread ones most, are pessimistic. Each case waited up to " << options.waitQuiet
       << " s for a quiet machine before it started.\n\n";
  }

  // -------------------------------------------------------------------------
  // Error against run time, CalculiX reference.
  // -------------------------------------------------------------------------
  if (!options.skipIndentation)
  {
    bmr::IndentationProblem problem; // 20 x 20 x 10 mm, 10 x 10 mm patch, 2 mm, E 3000 Pa
    problem.material.poissonRatio = options.indentationPoisson;
    const std::string       ccx = bmr::FindCalculix();
    md << "## Error against run time (block indentation, CalculiX reference)\n\n";
    if (ccx.empty())
    {
      md << "Not measured: CalculiX (`ccx`) was not found. Install Debian's calculix-ccx.\n\n";
    }
    else
    {
      const int referenceThreads = options.calculixThreads;
      const int referenceDivisions = options.quick ? 8 : options.referenceDivisions;
      log("CalculiX reference, quarter model, " + std::to_string(referenceDivisions) + "^3 grid cells...");
      const Reference reference = RunReference(problem, referenceDivisions, referenceThreads, options.referenceCache);
      log("  " + Fixed(reference.seconds, 1) + " s" + (reference.cached ? " (from the cache)" : ""));

      // The reference's own discretisation error, estimated against half its resolution.
      double selfCheck = -1.0;
      double selfForce = -1.0;
      double coarseSeconds = 0.0;
      if (referenceDivisions % 2 == 0 && referenceDivisions >= 8)
      {
        log("CalculiX reference at half resolution (self-check)...");
        const Reference coarse = RunReference(problem, referenceDivisions / 2, referenceThreads, options.referenceCache);
        coarseSeconds = coarse.seconds;
        // Compare at the coarse quadratic mesh's nodes (all are fine-mesh nodes).
        const std::vector<Vector3> fine =
          bmr::UnfoldQuarterDisplacements(problem, reference.nodes, reference.displacements, coarse.nodes);
        const bmr::DisplacementComparison c =
          bmr::CompareDisplacements(coarse.nodes, coarse.displacements, coarse.nodes, fine);
        selfCheck = c.rmsError / problem.depth;
        selfForce = std::abs(coarse.forceZ - reference.forceZ) / std::abs(reference.forceZ);
      }

      const std::vector<int> divisionsList = options.quick ? std::vector<int>{ 4, 8 } : options.indentationDivisions;
      const int              threads = *std::max_element(options.threads.begin(), options.threads.end());
      std::vector<IndentationRun> runs;
      WaitForQuiet(options.waitQuiet);
      ContentionMeter meter;
      meter.Start();
      // TLED hexahedra, ANP tetrahedra, then meshless (MTLED) on the hexahedral grid's nodes.
      const std::vector<std::pair<bmr::GridCells, bool>> discretizations{ { bmr::GridCells::Hexahedra, false },
                                                                          { bmr::GridCells::Tetrahedra, false },
                                                                          { bmr::GridCells::Hexahedra, true } };
      for (const auto & [cells, meshless] : discretizations)
      {
        for (const int n : divisionsList)
        {
          if (meshless && n > kMeshlessIndentationMaxDivisions)
          {
            log("skipping meshless " + std::to_string(n) + " divisions (finer than " +
                std::to_string(kMeshlessIndentationMaxDivisions) + ")");
            continue;
          }
          // TLED nodes (spacing 20/n mm) must be nodes of the quadratic reference (spacing 5/R mm),
          // and the patch edges (5 mm from the block's sides) grid lines.
          if ((4 * referenceDivisions) % n != 0 || n % 4 != 0)
          {
            log("skipping " + std::to_string(n) + " divisions: not a refinement of the reference");
            continue;
          }
          log("indentation " + (meshless ? std::string("meshless (MTLED)") : CellsName(cells)) + " " + std::to_string(n) + "x" + std::to_string(n) + "x" +
              std::to_string(n / 2) + "...");
          try
          {
            runs.push_back(RunIndentation(reference, cells, n, threads, options.indentationTolerance, -1.0, meshless));
            const IndentationRun & r = runs.back();
            log("  " + Fixed(r.setupSeconds + r.solveSeconds, 2) + " s, rms error " + Fixed(100 * r.rmsError, 3) +
                " %, force error " + Fixed(100 * r.forceError, 2) + " %");
          }
          catch (const bmr::Error & error)
          {
            IndentationRun failed;
            failed.cells = cells;
            failed.divisions = n;
            failed.threads = threads;
            failed.spacing = problem.size.x() / n;
            failed.failure = error.what();
            failed.meshless = meshless;
            runs.push_back(failed);
            log("  FAILED: " + failed.failure);
            if (cells == bmr::GridCells::Hexahedra && !meshless)
            {
              // The solver suggests a stiffer hourglass control; show what it gives.
              const double k = 2.0 * bmr::SolverSettings{}.hourglassCoefficient;
              log("  again with hourglass coefficient " + Fixed(k, 2) + "...");
              try
              {
                runs.push_back(RunIndentation(reference, cells, n, threads, options.indentationTolerance, k));
                const IndentationRun & r = runs.back();
                log("  " + Fixed(r.setupSeconds + r.solveSeconds, 2) + " s, rms error " + Fixed(100 * r.rmsError, 3) +
                    " %, force error " + Fixed(100 * r.forceError, 2) + " %");
              }
              catch (const bmr::Error & again)
              {
                log("  FAILED again: " + std::string(again.what()));
              }
            }
          }
        }
      }

      const double otherCores = meter.OtherCores();
      const double h = 0.5 * problem.size.x() / referenceDivisions;
      md << "Block 20 x 20 x 10 mm, bottom face held, top-face nodes in the centred 10 x 10 mm square pushed (0, 0, "
         << -problem.depth << ") mm (all components prescribed), neo-Hookean E = 3000 Pa, nu = " << problem.material.poissonRatio << ". "
         << "TLED: dynamic relaxation to an estimated error of " << Sci(options.indentationTolerance, 0) << " mm, "
         << threads << " threads, on n x n x n/2 grids (hexahedra, or 6 ANP tetrahedra per grid cell). Meshless (MTLED): "
         << "the hexahedral grid's nodes with the default settings (linear MLS, dilatation 1.6, 2 x 2 x 2 Gauss points per "
         << "background cell, EBCIEM), n <= " << kMeshlessIndentationMaxDivisions << "; its \"Elements\" are integration "
         << "points and its setup includes MakeMeshlessFromCells and the Solver construction.\n\n"
         << "Reference: CalculiX " << ccx << " (" << CalculixVersion(ccx) << "; static, NLGEOM, Newton to a residual of 1e-5 of the mean force), "
         << "C3D10 quadratic tetrahedra (6 per grid cell) on the quarter model x, y >= 10 mm with symmetry "
         << "conditions (the problem is symmetric about both mid-planes), " << referenceDivisions << "^3 grid cells: corner "
         << "spacing h = " << Fixed(h, 4) << " mm (quadratic node spacing " << Fixed(h / 2, 4) << " mm), "
         << reference.elements << " elements, " << reference.meshNodes << " nodes, " << 3 * reference.meshNodes
         << " DOF; " << Fixed(reference.seconds, 1) << " s" << (reference.cached ? " when it was computed (read from --reference-cache)" : "") << " (" << reference.increments << " increments, "
         << reference.iterations << " Newton iterations, " << referenceThreads << " threads). "
         << "Reference reaction force on the patch: " << Fixed(reference.forceZ, 5) << " N.";
      if (selfCheck >= 0.0)
      {
        md << " Self-check: the same reference at half the resolution (h = " << Fixed(2 * h, 4) << " mm, "
           << Fixed(coarseSeconds, 1) << " s) differs from it by " << Fixed(100 * selfCheck, 3)
           << " % RMS (of the 2 mm depth) and " << Fixed(100 * selfForce, 2)
           << " % in force, a bound on the reference's own error at that resolution.";
      }
      md << "\n\nErrors are at every TLED node (all are nodes of the reference mesh after reflection): RMS and max "
         << "of |u - u_ref| as a percentage of the 2 mm indentation, and the relative error of the total vertical "
         << "reaction force on the patch. Time = setup + solve (the median of 3 to 7 solves). Other processes kept " << Fixed(otherCores, 2)
         << " cores busy on average during these runs.\n\n"
         << "| Elements | Grid | h mm | Nodes | Elements | DR steps | Setup s | Solve s | RMS error % | Max error % | Force error % | Converged |\n"
         << "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
      std::ostringstream csv;
      csv << "cells,divisions,h_mm,nodes,elements,threads,setup_s,solve_s,total_s,steps,converged,rms_error_pct,max_"
             "error_pct,force_error_pct,reference_h_mm\n";
      std::vector<std::string> failures;
      for (const IndentationRun & r : runs)
      {
        if (!r.failure.empty())
        {
          md << "| " << RunLabel(r) << " | " << r.divisions << "x" << r.divisions << "x" << r.divisions / 2
             << " | " << Fixed(r.spacing, 3) << " | | | | | | **FAILED** (see below) | | | no |\n";
          failures.push_back(RunLabel(r) + " " + std::to_string(r.divisions) + "x" + std::to_string(r.divisions) +
                             "x" + std::to_string(r.divisions / 2) + ": " + r.failure);
          continue;
        }
        md << "| " << RunLabel(r) << " | " << r.divisions << "x" << r.divisions << "x" << r.divisions / 2
           << " | " << Fixed(r.spacing, 3) << " | " << r.nodes << " | " << r.elements << " | " << r.steps << " | "
           << Fixed(r.setupSeconds, 3) << " | " << Fixed(r.solveSeconds, 3) << " | " << Fixed(100 * r.rmsError, 3)
           << " | " << Fixed(100 * r.maxError, 2) << " | " << Fixed(100 * r.forceError, 2) << " | "
           << (r.converged ? "yes" : "**NO**") << " |\n";
        if (!r.failure.empty())
        {
          continue;
        }
        csv << RunKey(r) << "," << r.divisions << "," << r.spacing << "," << r.nodes << "," << r.elements << ","
            << r.threads << "," << r.setupSeconds << "," << r.solveSeconds << "," << r.setupSeconds + r.solveSeconds
            << "," << r.steps << "," << (r.converged ? 1 : 0) << "," << 100 * r.rmsError << "," << 100 * r.maxError
            << "," << 100 * r.forceError << "," << h << "\n";
      }
      for (const std::string & failure : failures)
      {
        md << "\n**Solver failure**, " << failure << "\n";
      }
      md << "\n![Error against run time](benchmark-error-vs-time.png)\n\n"
         << "The plot (scripts/plot-benchmarks.py) is drawn from " << std::filesystem::path(options.csv).filename().string()
         << ".\n\n";
      WriteAtomically(options.csv, csv.str());
    }
  }

  md << "---\nTotal benchmark time " << Fixed(Seconds(started), 0) << " s; load average at the end: " << LoadAverage()
     << ". Other processes may have shared the machine; a load average above the number of hardware threads "
     << "means the timings are pessimistic.\n";

  std::ostringstream report;
  report << header;
  if (!summary.empty())
  {
    report << "## Targets\n\n"
           << "Targets of the issue beside the measurements (details below). Published reference: Miller et al., "
           << kMillerDesktopSeconds << " s for about 100,000 DOF on a desktop CPU, under " << kMillerGpuSeconds
           << " s on a GPU.\n\n"
           << "| Measure | Target | Measured | |\n|---|---|---|---|\n";
    for (const std::string & row : summary)
    {
      report << row << "\n";
    }
    report << "\n";
  }
  report << md.str();
  std::cout << report.str();
  // The image benchmark's section (bmrImageBenchmark) is kept as it is.
  const std::string imageSection = bmr::benchmark::ImageSection(ReadTextFile(options.output));
  WriteAtomically(options.output, imageSection.empty() ? report.str()
                                                       : bmr::benchmark::WithImageSection(report.str(), imageSection));
  log("wrote " + options.output);
  return 0;
}

int
Child(int argc, char ** argv)
{
  const std::string kind = argc > 2 ? argv[2] : "";
  if (kind == "brain" && argc == 8)
  {
    const std::string    kind = argv[3];
    if (kind != "mtled")
    {
      CellsFromKey(kind); // validates
    }
    const int            threads = std::stoi(argv[4]);
    const double         spacing = std::stod(argv[5]);
    const int            steps = std::stoi(argv[6]);
    const int            repeats = std::stoi(argv[7]);
    const Json           result = RunBrainCase(spacing, kind, threads, steps, repeats);
    std::cout << "BMR_RESULT " << result.dump() << std::endl;
    return 0;
  }
  if (kind == "indentation" && (argc == 8 || argc == 9))
  {
    // TLED only (no reference): for reproducing a solver failure or profiling.
    bmr::IndentationProblem problem;
    problem.material.poissonRatio = std::stod(argv[7]);
    const int        n = std::stoi(argv[4]);
    const bmr::Model model = bmr::MakeIndentationModel(problem, { n, n, n / 2 }, CellsFromKey(argv[3]));
    bmr::SolverSettings settings;
    settings.integrator = bmr::Integrator::DynamicRelaxation;
    settings.threads = std::stoi(argv[5]);
    settings.tolerance = std::stod(argv[6]);
    if (argc == 9)
    {
      settings.hourglassCoefficient = std::stod(argv[8]);
    }
    Json out;
    out["nodes"] = model.nodes.size();
    out["elements"] = model.cells.size();
    try
    {
      bmr::Solver            solver(model, settings);
      const bmr::SolveResult result = solver.Solve();
      out["converged"] = result.converged;
      out["steps"] = result.steps;
      out["seconds"] = result.wallSeconds;
      out["message"] = result.message;
      double force = 0.0;
      for (const Index node : model.NodeSet("patch"))
      {
        force += result.reactionForces[node].z();
      }
      out["force_z"] = force;
    }
    catch (const bmr::Error & error)
    {
      out["error"] = error.what();
    }
    std::cout << "BMR_RESULT " << out.dump() << std::endl;
    return 0;
  }
  if (kind == "triad" && argc == 4)
  {
    // Memory bandwidth, STREAM's triad a = b + 3 c over 3 x 256 MiB: the
    // roofline of kernels whose data do not fit in the caches. Best of 8.
    const int           threads = std::stoi(argv[3]);
    const std::size_t   n = std::size_t{ 1 } << 25;
    std::vector<double> a(n), b(n), c(n);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (std::size_t i = 0; i < n; ++i)
    {
      a[i] = 0.0;
      b[i] = 1.0;
      c[i] = 2.0;
    }
    double best = std::numeric_limits<double>::infinity();
    for (int round = 0; round < 8; ++round)
    {
      const auto start = std::chrono::steady_clock::now();
#pragma omp parallel for num_threads(threads) schedule(static)
      for (std::size_t i = 0; i < n; ++i)
      {
        a[i] = b[i] + 3.0 * c[i];
      }
      best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    }
    const Json out = { { "threads", threads }, { "triad_gb_per_s", 24.0 * static_cast<double>(n) / best / 1e9 },
                       { "check", a[n / 2] } };
    std::cout << "BMR_RESULT " << out.dump() << std::endl;
    return 0;
  }
  std::cerr << "bmrBenchmark --child brain hex|tet|mtled THREADS SPACING STEPS REPEATS\n"
               "bmrBenchmark --child indentation hex|tet DIVISIONS THREADS TOLERANCE POISSON [HOURGLASS]\n"
               "bmrBenchmark --child triad THREADS\n";
  return 2;
}

} // namespace

int
main(int argc, char ** argv)
{
  try
  {
    if (argc > 1 && std::string(argv[1]) == "--child")
    {
      return Child(argc, argv);
    }
    Options options;
    for (int i = 1; i < argc; ++i)
    {
      const std::string argument = argv[i];
      const auto        value = [&]() -> std::string {
        if (i + 1 >= argc)
        {
          throw bmr::Error("bmrBenchmark: " + argument + " needs a value");
        }
        return argv[++i];
      };
      if (argument == "--output")
      {
        options.output = value();
      }
      else if (argument == "--csv")
      {
        options.csv = value();
      }
      else if (argument == "--threads")
      {
        options.threads = ParseIntList(value());
      }
      else if (argument == "--quick")
      {
        options.quick = true;
      }
      else if (argument == "--skip-brain")
      {
        options.skipBrain = true;
      }
      else if (argument == "--skip-indentation")
      {
        options.skipIndentation = true;
      }
      else if (argument == "--reference-divisions")
      {
        options.referenceDivisions = std::stoi(value());
      }
      else if (argument == "--indentation-divisions")
      {
        options.indentationDivisions = ParseIntList(value());
      }
      else if (argument == "--indentation-poisson")
      {
        options.indentationPoisson = std::stod(value());
      }
      else if (argument == "--rounds")
      {
        options.rounds = std::max(1, std::stoi(value()));
      }
      else if (argument == "--reference-cache")
      {
        options.referenceCache = value();
      }
      else if (argument == "--wait-quiet")
      {
        options.waitQuiet = std::stod(value());
      }
      else if (argument == "--calculix-threads")
      {
        options.calculixThreads = std::stoi(value());
      }
      else if (argument == "--indentation-tolerance")
      {
        options.indentationTolerance = std::stod(value());
      }
      else if (argument == "--help" || argument == "-h")
      {
        std::cout << "bmrBenchmark [--output docs/benchmarks.md] [--csv docs/benchmark-error-vs-time.csv]\n"
                     "             [--threads 1,2] [--quick] [--skip-brain] [--skip-indentation]\n"
                     "             [--reference-divisions 16] [--indentation-divisions 4,8,16,32]\n"
                     "             [--indentation-tolerance 1e-4] [--indentation-poisson 0.45]\n"
                     "             [--calculix-threads 1] [--wait-quiet 300] [--reference-cache DIR] [--rounds 3]\n"
                     "bmrBenchmark --child brain hex|tet|mtled THREADS SPACING STEPS REPEATS\n"
                     "bmrBenchmark --child indentation hex|tet DIVISIONS THREADS TOLERANCE POISSON [HOURGLASS]\n";
        return 0;
      }
      else
      {
        throw bmr::Error("bmrBenchmark: unknown argument '" + argument + "' (see --help)");
      }
    }
    if (options.threads.empty())
    {
      throw bmr::Error("bmrBenchmark: --threads needs at least one count");
    }
    const std::string self = std::filesystem::canonical("/proc/self/exe").string();
    return Driver(options, self);
  }
  catch (const std::exception & error)
  {
    std::cerr << "bmrBenchmark: " << error.what() << std::endl;
    return 1;
  }
}
