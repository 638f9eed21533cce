// Brain-sized model cases: the model, one case as a child process runs it, and
// the report's section on them (throughput, dynamic relaxation, meshless, memory).
#include "bmrBenchmarkDriver.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshless.h"
#include "bmrModel.h"
#include "bmrSolver.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <sys/resource.h>

namespace bmr
{
namespace benchmark
{

namespace
{

// Brain-sized model (as examples/scenes/brain-sized-*.json, spacing chosen for ~33,000 nodes).
const Vector3       kBrainSemiAxes(70.0, 85.0, 60.0);
constexpr double    kBrainTargetNodes = 33000.0;
constexpr double    kBrainBaseZ = -45.0;       // surface nodes with z <= this are held
constexpr double    kCraniotomyRadius = 25.0;  // surface nodes within this of (0,0,60) ...
constexpr double    kCraniotomyDepth = 10.0;   // ... are pushed 10 mm in (-z)
constexpr double    kBrainTolerance = 0.01;    // mm
const bmr::Material kBrain{ "brain", 3000.0, 0.49, 1000.0 };

/** Brain-sized cases: "hex" and "tet" (TLED), "mtled" (meshless on the hexahedral model's nodes and body). */
std::string
KindName(const std::string & key)
{
  return key == "hex" ? "hexahedra" : key == "tet" ? "ANP tetrahedra" : "meshless (MTLED)";
}

bmr::Model
MakeBrainModel(double spacing, bmr::GridCells cells, double depth = kCraniotomyDepth,
               const bmr::Material & material = kBrain)
{
  bmr::Model model = bmr::MakeEllipsoidMesh(kBrainSemiAxes, spacing, cells, material);
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

/** Bytes a force kernel streams from memory per unit and step, and its
 *  multiply-adds, counted from the kernels' arrays and loops
 *  (src/mechanics/bmrForceModel.cxx, bmrMeshlessForceModel.cxx); node arrays
 *  (u, f, nodal pressures: under 1 MiB each) stay in the caches and are not
 *  counted. */
struct KernelTraffic
{
  double bytes = 0.0;
  double multiplyAdds = 0.0;
};

KernelTraffic
TrafficPerUnit(const std::string & kind, double meanNeighbours)
{
  if (kind == "hex")
  {
    // B (24 doubles), X^T h (12), 8 node indices, mu, kappa, collapse modulus, volume, hourglass stiffness;
    // F 72, cofactor and J 21, hourglass modes 132, the law about 60, hourglass in A 36, nodal forces 168.
    return { 24 * 8 + 12 * 8 + 8 * 4 + 5 * 8, 72 + 21 + 132 + 60 + 36 + 168 };
  }
  if (kind == "tet")
  {
    // Dilatation pass: B (12 doubles), 4 node indices, J written; nodal pressures: per cell 4 incidences of
    // (cell index, weight, J); force pass: B, node indices, mu, kappa, collapse modulus, volume, ANP flag.
    // F 36 twice, determinant 12, cofactor and J 21, pressure 4, the law about 60, nodal forces 36, averages 4.
    return { (96 + 16 + 8) + 4 * (4 + 8 + 8) + (96 + 16 + 5 * 8), 36 + 12 + 36 + 21 + 4 + 60 + 36 + 4 };
  }
  // Meshless: per neighbour a node index and grad phi (3 floats); per point weight, mu, kappa, collapse
  // modulus, its offset and its integration point's index. Per neighbour 9 for F and 9 for the forces.
  return { 16.0 * meanNeighbours + 4 * 8 + 4 + 4, 18.0 * meanNeighbours + 60 };
}

/** Runs every brain-sized case (kind x thread count), each in a child process,
 *  `rounds` times in turn, and combines each case's rounds (medians, ranges). */
std::vector<Json>
RunBrainCases(const Options & options, const std::string & self, double spacing, int steps, int repeats, int rounds)
{
  std::vector<std::vector<Json>> perCase;
  for (int round = 0; round < rounds; ++round)
  {
    std::size_t index = 0;
    for (const std::string kind : { "hex", "tet", "mtled" })
    {
      for (const int threads : options.threads)
      {
        Log("brain-sized " + KindName(kind) + ", " + std::to_string(threads) + " thread(s), round " +
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
        Log("  DR " + Fixed(result["dr_seconds"].get<double>(), 2) + " s, " +
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
  std::vector<Json> brain;
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
  return brain;
}

} // namespace

/** Child process: one brain-sized case (cells, threads): dynamic relaxation to
 *  0.01 mm, then the throughput of explicit time steps. Prints one JSON line. */
Json
RunBrainCase(double spacing, const std::string & kind, int threads, int throughputSteps, int repeats,
             const std::string & law)
{
  bmr::Material material = kBrain;
  material.law = bmr::MaterialLawNamed(law);
  material.secondInvariantShare = bmr::DescribeMaterialLaw(material.law).secondInvariant ? 0.5 : 0.0;
  const bool           meshless = kind == "mtled";
  const bmr::GridCells cells = meshless ? bmr::GridCells::Hexahedra : CellsFromKey(kind);
  Json                 out;
  out["cells"] = kind;
  out["threads"] = threads;
  out["spacing_mm"] = spacing;
  out["law"] = law;

  auto       start = Clock::now();
  bmr::Model model = MakeBrainModel(spacing, cells, kCraniotomyDepth, material);
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
    bmr::Model pushed = MakeBrainModel(spacing, cells, 1.0, material);
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
    // What the solve holds (MeshlessForceModel): per entry the node and grad phi; per point its offset, index,
    // kernel index, weight and moduli. The MLS table (node, value, gradient) is released once the kernel's is built.
    out["table_bytes"] = entries * (sizeof(Index) + 3.0 * sizeof(float)) + table.PointCount() * (3.0 * sizeof(Index) + 32.0);
  }
  return out;
}

namespace
{
// Force-kernel throughput per element kind and thread count, and its targets.
void
BrainThroughput(const std::vector<Json> & brain, std::ostream & md, std::vector<std::string> & summary)
{
  // (i) throughput
  md << "### Force-kernel throughput\n\n"
     << "Explicit dynamics (central difference) for a fixed number of steps at 0.8 x the critical time step, "
     << "on the brain-sized mesh (a 1 mm smooth push of the craniotomy over the run); the whole time step is "
     << "counted (internal forces, hourglass control or nodal pressure averaging, integration, constraints), "
     << "divided by elements x steps (meshless: integration points x steps, on the hexahedral model's nodes and body "
     << "made meshless with the default settings: linear MLS, dilatation 1.6, 2 x 2 x 2 Gauss points per background "
     << "cell of the median nodal spacing and per coarse interior block of 2 x 2 x 2 cells, EBCIEM). Each round times " << brain.front()["throughput_repeats"].get<int>()
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
  // Issue 20's rates on 2 threads, by how much met or missed.
  for (const Json & r : brain)
  {
    if (r["threads"] != 2)
    {
      continue;
    }
    const std::string key = r["cells"].get<std::string>();
    const double      target = key == "hex" ? kTargetHexElementStepsPerSecondIssue20
                               : key == "tet" ? kTargetTetElementStepsPerSecondIssue20
                                              : kTargetMeshlessPointStepsPerSecondIssue20;
    const double      rate = r["element_steps_per_second"].get<double>();
    summary.push_back("| Issue 20: " + KindName(key) + (key == "mtled" ? ", integration-point" : ", element") +
                      "-steps per second, 2 threads | >= " + Fixed(target / 1e6, 0) + " M | " + Fixed(rate / 1e6, 1) +
                      " M | " + (rate >= target ? "met" : "**MISSED** by " + Fixed((target - rate) / 1e6, 1) + " M") +
                      " |");
  }
  // Speed-up per element type: the kernel, and the whole dynamic-relaxation solve.
  md << "\n";
  for (const std::string key : { "hex", "tet", "mtled" })
  {
    double one = 0.0, two = 0.0, solveOne = 0.0, solveTwo = 0.0;
    for (const Json & r : brain)
    {
      if (r["cells"] == key && r["threads"] == 1)
      {
        one = r["ns_per_element_step"].get<double>();
        solveOne = r["dr_seconds"].get<double>();
      }
      if (r["cells"] == key && r["threads"] == 2)
      {
        two = r["ns_per_element_step"].get<double>();
        solveTwo = r["dr_seconds"].get<double>();
      }
    }
    if (one > 0.0 && two > 0.0)
    {
      md << "Speed-up 1 -> 2 threads, " << KindName(key) << ": " << Fixed(one / two, 2)
         << "x.\n";
      for (const auto & [what, ratio] : { std::pair<std::string, double>{ "kernel", one / two },
                                          std::pair<std::string, double>{ "whole solve", solveOne / solveTwo } })
      {
        summary.push_back("| Issue 20: 2 threads against 1, " + KindName(key) + ", " + what + " | >= " +
                          Fixed(kTargetTwoThreadSpeedUp, 1) + "x | " + Fixed(ratio, 2) + "x | " +
                          (ratio >= kTargetTwoThreadSpeedUp
                             ? std::string("met")
                             : "**MISSED** by " + Fixed(kTargetTwoThreadSpeedUp - ratio, 2) + "x") +
                          " |");
      }
    }
  }
}

// The kernels' streamed bytes against STREAM's triad.
void
BrainRoofline(const std::vector<Json> & brain, const std::string & self, std::ostream & md)
{
  // (i b) the memory roofline: the kernels' streamed bytes against STREAM's triad
  std::map<int, double> triad;
  for (const Json & r : brain)
  {
    const int threads = r["threads"].get<int>();
    if (!triad.count(threads))
    {
      triad[threads] = RunChild(self, "triad " + std::to_string(threads))["triad_gb_per_s"].get<double>();
    }
  }
  md << "\n### Memory roofline\n\n"
     << "Bytes each force kernel streams from memory per unit and step, counted from its arrays (node arrays such as "
     << "u, f and the nodal pressures, under 1 MiB each, stay in the caches and are not counted), times the measured "
     << "units per second above, against STREAM's triad (`bmrBenchmark --child triad T`: a = b + 3 c over 3 x 256 "
     << "MiB, best of 8, 24 bytes per element counted). Multiply-adds are counted from the kernels' loops (the "
     << "constitutive law as about 60). The time per unit above is the whole explicit step, so the achieved rate is "
     << "a lower bound of the kernel's own.\n\n"
     << "| Kernel | Threads | Bytes / unit-step | Multiply-adds / unit-step | Multiply-adds / byte | Achieved GB/s | "
        "Triad GB/s | Fraction of the triad |\n"
     << "|---|---|---|---|---|---|---|---|\n";
  double      highest = 0.0;
  std::string highestKernel;
  for (const Json & r : brain)
  {
    const std::string  kind = r["cells"].get<std::string>();
    const int          threads = r["threads"].get<int>();
    const double       neighbours = r.contains("mean_neighbours") ? r["mean_neighbours"].get<double>() : 0.0;
    const KernelTraffic traffic = TrafficPerUnit(kind, neighbours);
    const double       achieved = traffic.bytes * r["element_steps_per_second"].get<double>() / 1e9;
    md << "| " << KindName(kind) << " | " << threads << " | " << Fixed(traffic.bytes, 0) << " | "
       << Fixed(traffic.multiplyAdds, 0) << " | " << Fixed(traffic.multiplyAdds / traffic.bytes, 2) << " | "
       << Fixed(achieved, 1) << " | " << Fixed(triad[threads], 1) << " | " << Fixed(100.0 * achieved / triad[threads], 0)
       << " % |\n";
    if (achieved / triad[threads] > highest)
    {
      highest = achieved / triad[threads];
      highestKernel = KindName(kind) + ", " + std::to_string(threads) + " thread(s)";
    }
  }
  md << "\nThe closest to the roof is " << highestKernel << " at " << Fixed(100.0 * highest, 0) << " % of the triad. "
     << (highest < 0.5 ? "No kernel reaches half of it, so none is limited by memory bandwidth on this machine; "
                         "docs/thread-scaling.md has what was measured instead (the latency of streamed tables and "
                         "scattered node accesses, the law's divisions)."
                       : "Kernels above half of it are near the bandwidth roof, but fewer bytes do not simply "
                         "buy time: the ANP kernel with its shape-function derivatives in single precision (a "
                         "quarter less traffic) was 2-3 % faster (docs/thread-scaling.md, 2026-11-26), since its "
                         "node-indexed gathers wait on latency, not on the stream.")
     << "\n";
}

// Time to dynamic-relaxation convergence, finite elements.
void
BrainRelaxation(const std::vector<Json> & brain, std::ostream & md, std::vector<std::string> & summary)
{
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
}

// Meshless: precomputation split, tables, and the total beside TLED.
void
BrainMeshless(const std::vector<Json> & brain, std::ostream & md, std::vector<std::string> & summary)
{
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
         << "spacing and per coarse interior block of 2 x 2 x 2 cells (docs/solver.md), EBCIEM), then the same dynamic relaxation to 0.01 mm. Precomputation: \"integration points\" is "
         << "bmr::MakeMeshlessFromCells (background grid, inside test, materials); \"solver construction\" is the "
         << "bmr::Solver constructor (k-d tree neighbour search, MLS shape functions and derivatives at the integration "
         << "points and the nodes, force model, the force kernel's schedule). Shape-function table memory is what the solve "
         << "holds: entries x (4 + 24) bytes (the force kernel's table in its schedule's order: node index, gradient) "
         << "+ integration points x (3 x 4 + 32) bytes (offset, point and kernel indices, weight and moduli), "
         << "entries = integration points x mean neighbours (the nodal EBCIEM table is not counted). The MLS table the "
         << "constructor evaluates (node index, value, gradient: 36 bytes per entry) is released once the kernel's is "
         << "built, so it counts in the peak memory only. "
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
        const double tableMiB = r["table_bytes"].get<double>() / (1024.0 * 1024.0);
        summary.push_back("| Meshless shape-function tables held by the solve, brain-sized (" +
                          std::to_string(r["dofs"].get<int>()) + " DOF) | <= " + Fixed(kTargetMeshlessTableMiB, 0) +
                          " MiB | " + Fixed(tableMiB, 0) + " MiB (peak memory of the case " +
                          Fixed(r["peak_memory_mib"].get<double>(), 0) + " MiB) | " +
                          (tableMiB <= kTargetMeshlessTableMiB ? "met" : "**MISSED**") + " |");
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
}

// The published reference, determinism across thread counts and rounds, the rounds' spread, the notes.
void
BrainNotes(const std::vector<Json> & brain, const Options & options, std::ostream & md)
{
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

} // namespace

void
BrainSection(const Options & options, const std::string & self, std::ostream & md, std::vector<std::string> & summary)
{
  int          nodes = 0;
  const double spacing = options.quick ? 6.0 : BrainSpacing(kBrainTargetNodes, nodes);
  const int    steps = options.quick ? 50 : 300;
  const int    repeats = options.quick ? 2 : 5;
  // Rounds: the cases run in turn, `rounds` times; each case's figures are the
  // median over the rounds (run-to-run variation on a shared machine is large).
  const int         rounds = options.quick ? 1 : options.rounds;
  std::vector<Json> brain = RunBrainCases(options, self, spacing, steps, repeats, rounds);

  const Json & first = brain.front();
  md << "## Brain-sized model\n\n"
     << "Ellipsoid with semi-axes (70, 85, 60) mm on a regular grid of spacing " << Fixed(spacing, 3)
     << " mm (chosen for about 33,000 nodes; the demo scenes in examples/scenes use 3.6 mm), E = 3000 Pa, "
     << "nu = 0.49, density 1000 kg/m^3. Surface nodes with z <= " << kBrainBaseZ
     << " mm are held; surface nodes within " << kCraniotomyRadius
     << " mm of the top (0, 0, 60) are pushed 10 mm in (-z): " << first["craniotomy_nodes"].get<int>()
     << " craniotomy nodes, " << first["base_nodes"].get<int>() << " base nodes.\n\n";

  BrainThroughput(brain, md, summary);
  BrainRoofline(brain, self, md);
  BrainRelaxation(brain, md, summary);
  BrainMeshless(brain, md, summary);
  BrainNotes(brain, options, md);
}

} // namespace benchmark
} // namespace bmr
