// Private to bmrBenchmark: what its parts (bmrBenchmark.cxx, bmrBenchmarkCommon.cxx,
// bmrBenchmarkBrain.cxx, bmrBenchmarkIndentation.cxx) share: targets, options, helpers, report sections.
#ifndef bmrBenchmarkDriver_h
#define bmrBenchmarkDriver_h

#include "bmrBenchmarkSupport.h"
#include "bmrMeshGenerators.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <ostream>
#include <string>
#include <vector>

#include <sys/resource.h>

namespace bmr
{
namespace benchmark
{

using Json = nlohmann::json;
using Clock = std::chrono::steady_clock;

// ---------------------------------------------------------------------------
// Targets of the issue and the published reference.
// ---------------------------------------------------------------------------
constexpr double kTargetTetElementStepsPerSecond = 20e6; // ANP tetrahedra, 2 threads
// Issue 20, 2 threads: element-steps (meshless: integration-point-steps) per
// second, and two threads against one on each kernel and on each whole solve.
constexpr double kTargetHexElementStepsPerSecondIssue20 = 50e6;
constexpr double kTargetTetElementStepsPerSecondIssue20 = 60e6;
constexpr double kTargetMeshlessPointStepsPerSecondIssue20 = 25e6;
constexpr double kTargetTwoThreadSpeedUp = 1.7;
constexpr double kTargetBrainHexSeconds = 2.0;
constexpr double kTargetBrainTetSeconds = 6.0;
constexpr double kTargetBrainMeshlessSeconds = 6.0; // including precomputation, 2 threads
constexpr double kTargetMeshlessTableMiB = 150.0;   // shape-function tables at about 100,000 DOF
constexpr double kMillerDesktopSeconds = 19.2; // ~100,000 DOF, desktop CPU (Joldes, Wittek, Miller)
constexpr double kMillerGpuSeconds = 4.0;

// ---------------------------------------------------------------------------
// Options (bmrBenchmark.cxx parses them).
// ---------------------------------------------------------------------------
struct Options
{
  std::string      output = "docs/benchmarks.md";
  std::string      csv = "docs/benchmark-error-vs-time.csv";
  std::vector<int> threads{ 1, 2 };
  bool             quick = false;
  bool             skipBrain = false;
  bool             skipIndentation = false;
  bool             skipImplicit = false;
  int              referenceDivisions = 16;
  std::vector<int> indentationDivisions{ 4, 8, 16, 32 };
  double           indentationTolerance = 1e-4;
  double           indentationPoisson = 0.45;
  int              calculixThreads = 1;
  double           waitQuiet = 300.0; // s to wait for a quiet machine before each timed case
  std::string      referenceCache;    // folder for CalculiX reference solutions (empty: none)
  int              rounds = 3;        // brain-sized cases run this many times in turn
};

// ---------------------------------------------------------------------------
// Helpers (bmrBenchmarkCommon.cxx).
// ---------------------------------------------------------------------------
double
Seconds(Clock::time_point start);

double
Median(std::vector<double> values);

/** A line of progress on stderr, "[bmrBenchmark] " first. */
void
Log(const std::string & line);

struct CpuSample
{
  double busySeconds = 0.0; // all CPUs, from /proc/stat
  double idleSeconds = 0.0;
};

/** Average number of cores other processes kept busy between Start() and OtherCores(). */
class ContentionMeter
{
public:
  void   Start();
  double OtherCores() const;

private:
  CpuSample         m_Cpu;
  double            m_Own = 0.0;
  Clock::time_point m_Start;
};

/** Waits (up to maxSeconds) until other processes use less than `threshold`
 *  cores over a 3 s window; returns the last measured use. */
double
WaitForQuiet(double maxSeconds, double threshold = 0.15);

bmr::GridCells
CellsFromKey(const std::string & key);

/** Peak resident memory (MiB) of this process (RUSAGE_SELF) or of its
 *  finished children (RUSAGE_CHILDREN, e.g. a CalculiX run). */
double
PeakMemoryMiB(int who = RUSAGE_SELF);

/** Runs `self --child ARGUMENTS` and returns the JSON of its BMR_RESULT line;
 *  throws bmr::Error with the child's output when it fails. */
Json
RunChild(const std::string & self, const std::string & arguments);

/** Writes `text` to `path` (bmr::WriteTextFileAtomically), creating its folder first. */
void
WriteCreatingFolder(const std::string & path, const std::string & text);

// ---------------------------------------------------------------------------
// Brain-sized model (bmrBenchmarkBrain.cxx).
// ---------------------------------------------------------------------------
/** Child process: one brain-sized case (cells, threads): dynamic relaxation to
 *  0.01 mm, then the throughput of explicit time steps. Prints one JSON line. */
Json
RunBrainCase(double spacing, const std::string & kind, int threads, int throughputSteps, int repeats,
             const std::string & law = "neo-hookean");

/** Runs the brain-sized cases (each in a child process of `self`) and writes
 *  their section of the report to `md` and their rows of the targets table to `summary`. */
void
BrainSection(const Options & options, const std::string & self, std::ostream & md, std::vector<std::string> & summary);

// ---------------------------------------------------------------------------
// Error against run time, CalculiX reference (bmrBenchmarkIndentation.cxx).
// ---------------------------------------------------------------------------
/** Runs the CalculiX reference and the indentation cases, writes their section
 *  of the report to `md` and their figures to options.csv. */
void
IndentationSection(const Options & options, std::ostream & md);

// ---------------------------------------------------------------------------
// Side by side with an implicit solver, CalculiX (bmrBenchmarkImplicit.cxx).
// ---------------------------------------------------------------------------
/** Child process: the brain-like case solved once: "anp" (TLED, dynamic
 *  relaxation), "c3d4" (CalculiX on the same tetrahedra) or "c3d10-quarter"
 *  (the CalculiX reference on the quarter model). Returns the time, the peak
 *  memory and the nodes' positions and displacements. */
Json
RunImplicitCase(const std::string & kind, double bodySpacing, int subdivisions, int threads, double initialIncrement,
                double relaxationTolerance);

/** Runs the CalculiX reference and the brain-like cases (children of `self`),
 *  writes their section to `md` and the target's row to `summary`. */
void
ImplicitSection(const Options & options, const std::string & self, std::ostream & md, std::vector<std::string> & summary);

} // namespace benchmark
} // namespace bmr

#endif
