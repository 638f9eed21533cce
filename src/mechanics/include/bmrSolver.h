// Total Lagrangian explicit dynamics (TLED) solver: one set of force kernels,
// two integrators (time-accurate central difference, adaptive dynamic relaxation).
#ifndef bmrSolver_h
#define bmrSolver_h

#include "bmrModel.h"

#include <Eigen/Core>

#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace bmr
{

enum class Integrator
{
  DynamicRelaxation, // steady state (Joldes, Wittek, Miller 2009, 2011)
  ExplicitDynamics   // time-accurate central difference
};

enum class TetrahedronFormulation
{
  AverageNodalPressure, // non-locking ANP (Joldes et al. 2009/2010), default
  Linear                // plain constant-strain tetrahedron, for comparison
};

struct SolverSettings
{
  Integrator             integrator = Integrator::DynamicRelaxation;
  TetrahedronFormulation tetrahedron = TetrahedronFormulation::AverageNodalPressure;

  /** Hourglass coefficient k of the one-point hexahedron (perturbation control
   *  after Flanagan-Belytschko): hourglass stiffness k 2 mu V (B:B) / 8 per cell.
   *  Scaled with the shear modulus, not lambda + 2 mu, so that nearly
   *  incompressible tissue does not lock (see docs/solver.md). */
  double hourglassCoefficient = 0.2;

  /** Bulk modulus (Pa) with which a cell or integration point resists
   *  collapse below half its reference volume (the collapse barrier of
   *  docs/solver.md: soft CSF squeezed by stiffer tissue would otherwise be
   *  crushed until it inverts). 0: the volume-weighted median bulk modulus of
   *  the model, i.e. that of its bulk tissue. A unit stiffer than this keeps its
   *  own. Masses are scaled for it, so dynamic relaxation stays stable when the
   *  barrier engages. */
  double collapseBulkModulus = 0.0;

  /** Fraction of the critical time step actually used. */
  double timeStepSafetyFactor = 0.8;
  /** Explicit dynamics: time step in s; 0 = automatic (critical step x safety). */
  double timeStep = 0.0;
  /** Explicit dynamics: end time in s. */
  double endTime = 1.0;
  /** Explicit dynamics: mass-proportional damping coefficient in 1/s. */
  double dampingCoefficient = 0.0;

  /** Dynamic relaxation: steps over which loads are ramped (smooth ramp). */
  int loadSteps = 200;
  /** Dynamic relaxation: stop when the estimated distance to the solution
   *  (max nodal displacement error, mm) is below this. */
  double tolerance = 1e-3;
  /** Dynamic relaxation: step limit; at the limit the result is marked not converged. */
  int maxSteps = 100000;
  /** Dynamic relaxation: steps between updates of the lowest-eigenvalue estimate. */
  int adaptInterval = 20;

  /** Explicit dynamics: seconds between frames passed to Solve's frame
   *  callback (0: no frames). */
  double outputInterval = 0.0;

  /** Compute Cauchy stress per cell at the end. */
  bool computeStress = false;

  /** Worker threads (OpenMP); 0 = OpenMP default. Results do not depend on it. */
  int threads = 0;
};

/** Progress report: fraction done in [0,1] (explicit dynamics) or -1 when
 *  unknown, and the current estimated error (mm) for dynamic relaxation. */
using ProgressCallback = std::function<void(int step, double fraction, double estimatedError)>;

/** A rigid tool's motion and the tissue's load on it (Model::tools): one
 *  entry per time step in explicit dynamics, the steady state alone in
 *  dynamic relaxation. */
struct ToolHistory
{
  std::string          name;
  std::vector<double>  time;         // s
  std::vector<Vector3> position;     // mm, the tool frame's origin
  std::vector<Vector3> force;        // N, on the tool
  std::vector<Vector3> moment;       // N mm, on the tool about its origin
  std::vector<int>     contactNodes; // nodes it touches
  double               work = 0.0;   // J, done by the tool on the tissue over the solve

  // With a stress region (RigidTool::stressRegionRadius > 0), explicit dynamics:
  std::vector<Vector3>         correctedForce;   // N per step: `force` with the region's cells as Ogden tissue
  std::vector<double>          peakStress;       // Pa per step: largest von Mises stress of the region (Ogden)
  std::vector<Index>           stressCells;      // the region's cells
  std::vector<Eigen::Matrix3d> ogdenStress;      // Pa, Cauchy, per region cell at the end
  std::vector<Eigen::Matrix3d> neoHookeanStress; // Pa, Cauchy of the same deformation gradient
};

/** The state at an output time of explicit dynamics (SolverSettings::outputInterval). */
struct SolveFrame
{
  double                       time = 0.0; // s
  int                          step = 0;
  const std::vector<Vector3> & displacements; // mm, per node
  double                       strainEnergy = 0.0;  // J, hourglass energy included (as SolveResult::strainEnergy)
  double                       kineticEnergy = 0.0; // J, from the velocity of the last half step
};
using FrameCallback = std::function<void(const SolveFrame & frame)>;

/** Where a solve's wall time went (s), measured around each part of every
 *  step: for profiling and the benchmarks' roofline of the whole step. The
 *  rest of the wall time is the update, the convergence measure and the
 *  damping's estimates. */
struct SolvePartSeconds
{
  double internalForces = 0.0;    // the force kernel (ForceModel::ComputeInternalForces)
  double essentialBoundary = 0.0; // prescribed values (meshless with EBCIEM: its projection)
  double contact = 0.0;           // contact surfaces and tools
  /** Meshless contact: Kaczmarz sweeps over the slaves in contact, all steps. */
  long long contactSweeps = 0;
  /** Bytes of the tables each force pass streams (ForceModel), the memory
   *  roofline's numerator per step. */
  std::size_t forceTableBytes = 0;
};

struct SolveResult
{
  std::vector<Vector3>         displacements;  // mm, per node
  std::vector<Vector3>         reactionForces; // N, per node; nonzero only at constrained or contacting nodes
                                               // (meshless with EBCIEM: the point reaction at each constrained node)
  std::vector<Eigen::Matrix3d> cauchyStress;   // Pa, per cell (meshless: per integration point), if computeStress
  /** Meshless only: the nodal parameters u_I of the MLS field u(x) = sum phi_I(x) u_I
   *  (`displacements` holds the interpolated, physical values at the nodes).
   *  Evaluate anywhere in the body with bmr::InterpolateDisplacements. */
  std::vector<Vector3>         nodalParameters;

  bool        converged = false; // explicit dynamics: reached end time
  int         steps = 0;
  double      timeStep = 0.0;         // s (explicit) or pseudo-time step (dynamic relaxation)
  double      criticalTimeStep = 0.0; // s, physical density, before the safety factor
  double      estimatedError = 0.0;   // mm, dynamic relaxation
  double      convergenceRate = 0.0;  // dynamic relaxation: estimated spectral radius per step
  int         restarts = 0;           // dynamic relaxation: restarts with heavier masses after divergence
  double      wallSeconds = 0.0;
  SolvePartSeconds parts;             // of wallSeconds
  double      maxDisplacement = 0.0;  // mm
  double      strainEnergy = 0.0;     // J (N*m)
  double      hourglassEnergy = 0.0;  // J, hexahedra only
  double      kineticEnergy = 0.0;    // J, explicit dynamics
  int         contactNodes = 0;       // nodes on a contact surface at the end
  double      maxPenetration = 0.0;   // mm, after the last projection
  std::vector<std::string> activeComponents;
  std::vector<ToolHistory> tools; // one per Model::tools entry
  /** Dynamic relaxation: the lowest-eigenvalue estimate the damping ended
   *  with, for the masses before any restart (a diagnostic). */
  double      lowestEigenvalue = 0.0;
  bool        warmStarted = false; // began from a WarmStart
  std::string message; // why it stopped
  /** What the solve did that the model did not ask for, e.g. contact nodes
   *  that started beyond their surface and were projected onto it. */
  std::vector<std::string> warnings;
};

/** Where a dynamic-relaxation solve begins instead of the reference state: the
 *  steady state of an earlier solve of the same model (the previous
 *  intraoperative update of one surgery). The loads then ramp from the ones
 *  that state balances to the model's: prescribed values from their value in
 *  the state, body and surface forces from its internal forces, so the solve
 *  starts at rest in equilibrium; without body forces or tools the ramp is
 *  shortened to the prescribed values' relative change (at least a tenth).
 *  The equilibrium reached is the model's whatever the start; only the steps
 *  differ, and where the contact admits neighbouring equilibria (a node
 *  sliding on the faceted skull) which one (docs/registration.md). */
struct WarmStart
{
  /** Per node: SolveResult::nodalParameters for a meshless model, else
   *  SolveResult::displacements (mm). Empty: no warm start. */
  std::vector<Vector3> state;

  bool Empty() const { return state.empty(); }
};

/** The warm start at `result`'s steady state (its nodal parameters when meshless). */
WarmStart
WarmStartFrom(const SolveResult & result);

/** Thrown when a solve fails (inverted element, NaN, unbounded energy). */
class SolveError : public Error
{
public:
  SolveError(const std::string & what, int step, Index element)
    : Error(what)
    , m_Step(step)
    , m_Element(element)
  {}
  int   Step() const { return m_Step; }
  Index Element() const { return m_Element; }

private:
  int   m_Step;
  Index m_Element;
};

class BinaryWriter; // bmrBinaryStream.h
class BinaryReader;

/** What a Solver computes from the model's reference configuration alone
 *  (the Total Lagrangian precomputation): the force model's shape-function
 *  derivatives, volumes, hourglass vectors and stiffnesses, the ANP
 *  tetrahedra's nodal averaging, the kernels' schedules and, for a meshless
 *  model, the MLS shape-function tables at the integration points and at the
 *  nodes. Made once (before surgery: `biomech prepare`), stored (Write / Read:
 *  the model bundle's precomputation.bin) and handed to every Solver of the
 *  same model, whatever its loads, constraints, contact and gravity.
 *  Not in it: the masses (they follow the solve's time step and collapse
 *  barrier) and the contact search trees (CGAL's AABB trees point into the
 *  surfaces and cannot be stored; building Colin27's skull contact took about
 *  0.09 CPU-s a solve, perf of a gravity-fit update, 2026-12-06). */
class SolverPrecomputation
{
public:
  /** Validates the model first (Model::Validate). */
  SolverPrecomputation(const Model & model, const SolverSettings & settings);
  ~SolverPrecomputation();
  SolverPrecomputation(SolverPrecomputation &&) noexcept;
  SolverPrecomputation & operator=(SolverPrecomputation &&) noexcept;

  /** Empty when it was made from `model`'s reference configuration (nodes,
   *  cells, materials, integration points and shape-function settings) with
   *  `settings`' tetrahedron formulation, hourglass coefficient and collapse
   *  bulk modulus; else what differs, in words. */
  std::string Mismatch(const Model & model, const SolverSettings & settings) const;

  /** The settings it was made with: those it depends on (the rest are the defaults). */
  SolverSettings Settings() const;

  void Write(BinaryWriter & out) const;
  /** Throws bmr::Error (the reader's) for a damaged or inconsistent one. */
  static SolverPrecomputation Read(BinaryReader & in);

  struct Impl; // private to the core (bmrSolverImpl.h)
  const Impl & State() const { return *m_Impl; }

private:
  explicit SolverPrecomputation(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> m_Impl;
};

/** Precomputes everything the Total Lagrangian formulation allows (shape
 *  function derivatives, volumes, hourglass vectors, masses, contact trees) on
 *  construction, or takes what `precomputed` holds of it (a
 *  SolverPrecomputation of the same model: results bitwise the same);
 *  Solve() then only time-steps. Validates the model first; throws bmr::Error
 *  naming the difference when `precomputed` was made for another model or
 *  other settings. */
class Solver
{
public:
  Solver(const Model & model, const SolverSettings & settings, const SolverPrecomputation * precomputed = nullptr);
  ~Solver();
  Solver(const Solver &) = delete;
  Solver & operator=(const Solver &) = delete;

  /** `frames`: called at t = 0, at the first step at or after every
   *  multiple of SolverSettings::outputInterval, and at the end time
   *  (explicit dynamics with an output interval only). */
  SolveResult Solve(const ProgressCallback & progress = {}, const FrameCallback & frames = {});

  /** Dynamic relaxation begins from `start` (WarmStart) in the next Solve;
   *  an empty one: from the reference state. Throws bmr::Error when its size
   *  is not the model's node count or the integrator is explicit dynamics. */
  void SetWarmStart(const WarmStart & start);

  /** Components built for this model (e.g. "hexahedra", "hourglass-control",
   *  "anp-tetrahedra", "contact", "dynamic-relaxation"). */
  const std::vector<std::string> & ActiveComponents() const;

  /** Critical time step (s) for the model's physical densities, before the safety factor. */
  double CriticalTimeStep() const;

  /** Internal nodal forces (N) for given nodal displacements (mm); for tests. */
  std::vector<Vector3> InternalForces(const std::vector<Vector3> & displacements);

private:
  struct Impl;
  std::unique_ptr<Impl> m_Impl;
};

} // namespace bmr

#endif
