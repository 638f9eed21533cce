// Error against run time: the CalculiX reference for the block indentation (and
// its cache), the TLED and meshless runs against it, and their report section and CSV.
#include "bmrBenchmarkDriver.h"
#include "bmrCalculix.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshless.h"
#include "bmrModel.h"
#include "bmrSolver.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace bmr
{
namespace benchmark
{

namespace
{

constexpr int kMeshlessIndentationMaxDivisions = 16; // meshless indentation runs on n = 4, 8, 16 only

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
  WriteCreatingFolder(path, text.str());
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

// TLED hexahedra, ANP tetrahedra, then meshless (MTLED) on the hexahedral
// grid's nodes, on every grid that refines the reference; a failed solve is a
// row with its failure (hexahedra: tried again with stiffer hourglass control).
std::vector<IndentationRun>
MeasureIndentation(const bmr::IndentationProblem & problem, const Reference & reference, const Options & options,
                   const std::vector<int> & divisionsList, int referenceDivisions, int threads, double & otherCores)
{
  std::vector<IndentationRun> runs;
  WaitForQuiet(options.waitQuiet);
  ContentionMeter meter;
  meter.Start();
  const std::vector<std::pair<bmr::GridCells, bool>> discretizations{ { bmr::GridCells::Hexahedra, false },
                                                                      { bmr::GridCells::Tetrahedra, false },
                                                                      { bmr::GridCells::Hexahedra, true } };
  for (const auto & [cells, meshless] : discretizations)
  {
    for (const int n : divisionsList)
    {
      if (meshless && n > kMeshlessIndentationMaxDivisions)
      {
        Log("skipping meshless " + std::to_string(n) + " divisions (finer than " +
            std::to_string(kMeshlessIndentationMaxDivisions) + ")");
        continue;
      }
      // TLED nodes (spacing 20/n mm) must be nodes of the quadratic reference (spacing 5/R mm),
      // and the patch edges (5 mm from the block's sides) grid lines.
      if ((4 * referenceDivisions) % n != 0 || n % 4 != 0)
      {
        Log("skipping " + std::to_string(n) + " divisions: not a refinement of the reference");
        continue;
      }
      Log("indentation " + (meshless ? std::string("meshless (MTLED)") : CellsName(cells)) + " " + std::to_string(n) + "x" + std::to_string(n) + "x" +
          std::to_string(n / 2) + "...");
      try
      {
        runs.push_back(RunIndentation(reference, cells, n, threads, options.indentationTolerance, -1.0, meshless));
        const IndentationRun & r = runs.back();
        Log("  " + Fixed(r.setupSeconds + r.solveSeconds, 2) + " s, rms error " + Fixed(100 * r.rmsError, 3) +
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
        Log("  FAILED: " + failed.failure);
        if (cells == bmr::GridCells::Hexahedra && !meshless)
        {
          // The solver suggests a stiffer hourglass control; show what it gives.
          const double k = 2.0 * bmr::SolverSettings{}.hourglassCoefficient;
          Log("  again with hourglass coefficient " + Fixed(k, 2) + "...");
          try
          {
            runs.push_back(RunIndentation(reference, cells, n, threads, options.indentationTolerance, k));
            const IndentationRun & r = runs.back();
            Log("  " + Fixed(r.setupSeconds + r.solveSeconds, 2) + " s, rms error " + Fixed(100 * r.rmsError, 3) +
                " %, force error " + Fixed(100 * r.forceError, 2) + " %");
          }
          catch (const bmr::Error & again)
          {
            Log("  FAILED again: " + std::string(again.what()));
          }
        }
      }
    }
  }

  otherCores = meter.OtherCores();
  return runs;
}

} // namespace

void
IndentationSection(const Options & options, std::ostream & md)
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
    Log("CalculiX reference, quarter model, " + std::to_string(referenceDivisions) + "^3 grid cells...");
    const Reference reference = RunReference(problem, referenceDivisions, referenceThreads, options.referenceCache);
    Log("  " + Fixed(reference.seconds, 1) + " s" + (reference.cached ? " (from the cache)" : ""));

    // The reference's own discretisation error, estimated against half its resolution.
    double selfCheck = -1.0;
    double selfForce = -1.0;
    double coarseSeconds = 0.0;
    if (referenceDivisions % 2 == 0 && referenceDivisions >= 8)
    {
      Log("CalculiX reference at half resolution (self-check)...");
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
    double                            otherCores = 0.0;
    const std::vector<IndentationRun> runs =
      MeasureIndentation(problem, reference, options, divisionsList, referenceDivisions, threads, otherCores);
    const double h = 0.5 * problem.size.x() / referenceDivisions;
    md << "Block 20 x 20 x 10 mm, bottom face held, top-face nodes in the centred 10 x 10 mm square pushed (0, 0, "
       << -problem.depth << ") mm (all components prescribed), neo-Hookean E = 3000 Pa, nu = " << problem.material.poissonRatio << ". "
       << "TLED: dynamic relaxation to an estimated error of " << Sci(options.indentationTolerance, 0) << " mm, "
       << threads << " threads, on n x n x n/2 grids (hexahedra, or 6 ANP tetrahedra per grid cell). Meshless (MTLED): "
       << "the hexahedral grid's nodes with the default settings (linear MLS, dilatation 1.6, 2 x 2 x 2 Gauss points per "
       << "background cell and per coarse interior block, EBCIEM), n <= " << kMeshlessIndentationMaxDivisions << "; its \"Elements\" are integration "
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
    WriteCreatingFolder(options.csv, csv.str());
  }
}

} // namespace benchmark
} // namespace bmr
