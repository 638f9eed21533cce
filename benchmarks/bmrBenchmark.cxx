// Benchmark driver (not a test): throughput of the TLED force kernels, time to
// dynamic-relaxation convergence for a brain-sized model, peak memory, and
// error against run time for a CalculiX-referenced indentation problem; the
// meshless (MTLED) discretization on the same nodes beside the TLED elements;
// ANP tetrahedra beside CalculiX's implicit solve of a brain-like case.
// Writes a Markdown report (docs/benchmarks.md) and a CSV for the plot script
// (scripts/plot-benchmarks.py); scripts/run-benchmarks.sh runs both.
//
//   bmrBenchmark [--output docs/benchmarks.md] [--csv docs/benchmark-error-vs-time.csv]
//                [--threads 1,2] [--rounds 3] [--quick] [--skip-brain] [--skip-indentation] [--skip-implicit]
//                [--reference-divisions 16] [--indentation-divisions 4,8,16,32]
//                [--indentation-tolerance 1e-4] [--indentation-poisson 0.45]
//                [--calculix-threads 1] [--wait-quiet 300] [--reference-cache DIR]
//
// Each brain-sized case runs in a child process (the same executable with
// --child), so that its peak memory (getrusage ru_maxrss) is its own. The
// child modes also serve to reproduce or profile one case:
//   bmrBenchmark --child brain hex|tet|mtled THREADS SPACING STEPS REPEATS [LAW]
//                                        (LAW: a material law's name; mooney-rivlin with C01 = C10)
//   bmrBenchmark --child indentation hex|tet DIVISIONS THREADS TOLERANCE POISSON [HOURGLASS]
//   bmrBenchmark --child implicit anp|mtled|c3d4|c3d10|c3d10-quarter BODY_SPACING SUBDIVISIONS THREADS [INITIAL_INCREMENT [TOLERANCE]]
//                                        (the brain-like case beside CalculiX)
//   bmrBenchmark --child triad THREADS   (memory bandwidth: STREAM's triad)
//
// This file: the options, the driver that writes the report (its header, the
// targets table, the footer) and the child modes. bmrBenchmarkBrain.cxx,
// bmrBenchmarkIndentation.cxx and bmrBenchmarkImplicit.cxx run and write the
// three measured sections;
// bmrBenchmarkCommon.cxx holds the helpers they share (bmrBenchmarkDriver.h).
#include "bmrBenchmarkDriver.h"
#include "bmrBenchmarkSupport.h"
#include "bmrCalculix.h"
#include "bmrModel.h"
#include "bmrSolver.h"

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <ctime>
#include <exception>
#include <filesystem>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

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

namespace bmr
{
namespace benchmark
{
namespace
{

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

int
Driver(const Options & options, const std::string & self)
{
  const auto         started = Clock::now();
  const std::string  loadBefore = LoadAverage();
  std::ostringstream md;

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

  if (!options.skipBrain)
  {
    BrainSection(options, self, md, summary);
  }
  if (!options.skipIndentation)
  {
    IndentationSection(options, md);
  }
  if (!options.skipImplicit)
  {
    ImplicitSection(options, self, md, summary);
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
  // The sections other programs write on the page (bmrImageBenchmark and the
  // scripts' sections) are kept as they are, so that this
  // program can be rerun alone.
  const std::string previous = ReadTextFile(options.output);
  const std::string imageSection = bmr::benchmark::ImageSection(previous);
  std::string       page = imageSection.empty() ? report.str() : bmr::benchmark::WithImageSection(report.str(), imageSection);
  for (const std::string name : bmr::benchmark::ScriptSections)
  {
    const std::string begin = "<!-- " + name + ":begin -->";
    const std::string end = "<!-- " + name + ":end -->";
    const std::string section = bmr::benchmark::MarkedSection(previous, begin.c_str(), end.c_str());
    if (!section.empty())
    {
      page += "\n" + section;
    }
  }
  WriteCreatingFolder(options.output, page);
  Log("wrote " + options.output);
  return 0;
}

int
Child(int argc, char ** argv)
{
  const std::string kind = argc > 2 ? argv[2] : "";
  if (kind == "brain" && (argc == 8 || argc == 9))
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
    const Json           result = RunBrainCase(spacing, kind, threads, steps, repeats, argc == 9 ? argv[8] : "neo-hookean");
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
  if (kind == "implicit" && argc >= 7 && argc <= 9)
  {
    const Json result = RunImplicitCase(argv[3], std::stod(argv[4]), std::stoi(argv[5]), std::stoi(argv[6]),
                                        argc >= 8 ? std::stod(argv[7]) : 1.0, argc == 9 ? std::stod(argv[8]) : 0.0);
    std::cout << "BMR_RESULT " << result.dump() << std::endl;
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
  std::cerr << "bmrBenchmark --child brain hex|tet|mtled THREADS SPACING STEPS REPEATS [LAW]\n"
               "bmrBenchmark --child indentation hex|tet DIVISIONS THREADS TOLERANCE POISSON [HOURGLASS]\n"
               "bmrBenchmark --child implicit anp|mtled|c3d4|c3d10|c3d10-quarter BODY_SPACING SUBDIVISIONS THREADS [INITIAL_INCREMENT [TOLERANCE]]\n"
               "bmrBenchmark --child triad THREADS\n";
  return 2;
}

} // namespace
} // namespace benchmark
} // namespace bmr

int
main(int argc, char ** argv)
{
  try
  {
    if (argc > 1 && std::string(argv[1]) == "--child")
    {
      return bmr::benchmark::Child(argc, argv);
    }
    bmr::benchmark::Options options;
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
        options.threads = bmr::benchmark::ParseIntList(value());
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
      else if (argument == "--skip-implicit")
      {
        options.skipImplicit = true;
      }
      else if (argument == "--reference-divisions")
      {
        options.referenceDivisions = std::stoi(value());
      }
      else if (argument == "--indentation-divisions")
      {
        options.indentationDivisions = bmr::benchmark::ParseIntList(value());
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
                     "             [--threads 1,2] [--quick] [--skip-brain] [--skip-indentation] [--skip-implicit]\n"
                     "             [--reference-divisions 16] [--indentation-divisions 4,8,16,32]\n"
                     "             [--indentation-tolerance 1e-4] [--indentation-poisson 0.45]\n"
                     "             [--calculix-threads 1] [--wait-quiet 300] [--reference-cache DIR] [--rounds 3]\n"
                     "bmrBenchmark --child brain hex|tet|mtled THREADS SPACING STEPS REPEATS [LAW]\n"
                     "bmrBenchmark --child indentation hex|tet DIVISIONS THREADS TOLERANCE POISSON [HOURGLASS]\n"
                     "bmrBenchmark --child implicit anp|mtled|c3d4|c3d10|c3d10-quarter BODY_SPACING SUBDIVISIONS THREADS [INITIAL_INCREMENT [TOLERANCE]]\n"
                     "bmrBenchmark --child triad THREADS\n";
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
    return bmr::benchmark::Driver(options, self);
  }
  catch (const std::exception & error)
  {
    std::cerr << "bmrBenchmark: " << error.what() << std::endl;
    return 1;
  }
}
