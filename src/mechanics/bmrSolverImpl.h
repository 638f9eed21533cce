// Private to the core: the solver's state shared by its translation units
// (bmrSolver.cxx: set-up, constraints, the step's checks and the result;
// bmrSolverContact.cxx: rigid surfaces and tools, with meshless contact in
// bmrMeshlessContact.cxx; bmrSolverDynamicRelaxation.cxx and
// bmrSolverExplicitDynamics.cxx: the integrators).
#ifndef bmrSolverImpl_h
#define bmrSolverImpl_h

#include "bmrSolver.h"

#include "bmrContact.h"
#include "bmrEssentialBoundary.h"
#include "bmrForceModel.h"
#include "bmrMeshless.h"
#include "bmrMeshlessContact.h"
#include "bmrSolverReductions.h"
#include "bmrToolContact.h"
#include "bmrToolStress.h"

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace bmr
{

struct ConstrainedDof
{
  Index  dof;
  double value; // mm at full load
  int    curve; // index into the solver's curves; -1 for fixed (value 0)

  /** Its value at the curves' present factors. */
  double Target(const std::vector<double> & curveFactors) const { return curve < 0 ? 0.0 : value * curveFactors[curve]; }
};

/** The central-difference update of one dof, u+ = u + beta (u - u-) + alpha
 *  M^-1 (f_ext - f_int): the one form of both integrators' steps. */
inline double
CentralDifferenceUpdate(double u, double uPrevious, double force, double externalForce, double inverseMass, double alpha,
                        double beta)
{
  return u + beta * (u - uPrevious) + alpha * (externalForce - force) * inverseMass;
}

/** Runs `work` and adds its wall time to `seconds` (SolvePartSeconds). */
template <typename Work>
decltype(auto)
TimePart(double & seconds, Work && work)
{
  struct Add
  {
    double &                              seconds;
    std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
    ~Add() { seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(); }
  } add{ seconds };
  return work();
}

inline std::string
StepLabel(int step)
{
  return "step " + std::to_string(step);
}

struct SolverPrecomputation::Impl
{
  /** Of what it was made from (SolverPrecomputation::Mismatch). */
  std::uint64_t          modelKey = 0;
  Index                  nodeCount = 0;
  bool                   meshless = false;
  TetrahedronFormulation tetrahedron = TetrahedronFormulation::AverageNodalPressure;
  double                 hourglassCoefficient = 0.0;
  double                 collapseBulkModulus = 0.0;

  std::unique_ptr<ForceModel> forces;
  ShapeFunctionTable          nodeShapes; // meshless: at the nodes (physical displacement = Phi u)
};

/** The force model of `model` and, for a meshless model, the shape
 *  functions at its nodes (into `nodeShapes`): the costly part of the Total
 *  Lagrangian precomputation, for Solver and SolverPrecomputation alike. */
std::unique_ptr<ForceModel>
MakeForceModel(const Model & model, const SolverSettings & settings, int threads, ShapeFunctionTable & nodeShapes);

/** A fingerprint (64-bit FNV-1a) of what the force model reads from a
 *  model: nodes, cells, materials' constants, the meshless integration points
 *  and shape-function settings. */
std::uint64_t
ReferenceConfigurationKey(const Model & model);

struct Solver::Impl
{
  Model                                      model;
  SolverSettings                             settings;
  int                                        threads = 1;
  std::unique_ptr<ForceModel>                forces;
  std::vector<std::unique_ptr<RigidContact>> contacts;
  // Per contact, each slave's projection in the last step (zero when not projected).
  std::vector<std::vector<Vector3>>          contactCorrections;
  // Slave nodes that start beyond their contact surface, in words (empty if
  // none): the first step projects them, however slowly the loads ramp.
  std::string                                initialPenetration;
  std::vector<std::unique_ptr<ToolContact>>  tools;
  std::vector<ToolLoad>                      toolLoads; // of the last step
  std::vector<std::unique_ptr<ToolStressRegion>> stressRegions; // per tool; null without a region
  std::vector<Vector3>                       correctedForces;   // of the last step, per tool
  std::vector<double>                        physicalMass;
  std::vector<ConstrainedDof>                constrained;
  std::vector<LoadCurve>                     curves;
  std::vector<char>                          dofConstrained;
  std::vector<char>                          nodeConstrained;
  std::vector<double>                        gravityForce; // N at full load
  std::vector<std::string>                   components;
  double                                     criticalTimeStep = 0.0;
  Index                                      criticalCell = -1;
  double                                     lengthScale = 1.0;
  SolvePartSeconds                           parts; // of the present solve

  // Meshless only: shape functions at the nodes (physical displacement =
  // Phi u), the EBCIEM projection (built per solve, with that solve's masses)
  // and contact on the interpolated positions (null without contact surfaces).
  bool                               meshless = false;
  ShapeFunctionTable                 nodeShapes;
  std::unique_ptr<EssentialBoundary> essential;
  std::unique_ptr<MeshlessContact>   meshlessContact;
  std::vector<double>                constraintTargets; // EBCIEM, per step
  std::vector<double>                dofTargets;        // per dof, the constrained dofs' targets of the step (fused update)

  // Dynamic relaxation from a warm start (Solver::SetWarmStart): its state
  // (dofs; empty: from rest); per solve, the loads it balances, which fade
  // out with the ramp as the model's fade in: its internal forces per dof and
  // the value of each constrained dof in it, with their weights of the step.
  std::vector<double>                warmState;
  std::vector<double>                startForces;
  std::vector<double>                startTargets;
  double                             startForceWeight = 0.0;
  double                             startTargetWeight = 0.0;

  Impl(const Model & m, const SolverSettings & s, const SolverPrecomputation * precomputed);
  void        CheckSettings() const;
  void        BuildConstraints();
  void        ApplyConstraints(double * u, const std::vector<double> & curveFactors);
  /** Constraint k's value at the curves' present factors (and, from a warm
   *  start, its fading start value). */
  double      ConstraintTarget(std::size_t k, const std::vector<double> & curveFactors) const
  {
    const double target = constrained[k].Target(curveFactors);
    return startTargets.empty() ? target : target + startTargetWeight * startTargets[k];
  }
  /** The load ramp's length as a fraction of SolverSettings::loadSteps:
   *  1 from rest; from a warm start the largest change of a prescribed value
   *  over the largest value (at least kMinimumWarmRamp). */
  double      WarmStartRampFraction() const;
  /** External force on dof d besides contact (N): gravity at `gravityFactor`
   *  and a warm start's fading forces. */
  double      ExternalForce(Index d, double gravityFactor) const
  {
    const double gravity = gravityForce.empty() ? 0.0 : gravityFactor * gravityForce[d];
    return startForces.empty() ? gravity : gravity + startForceWeight * startForces[d];
  }
  void        PrepareEssentialBoundary(const std::vector<double> & mass);
  void        EnforceContact(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass);
  /** Dynamic relaxation: removes from each slave projected in the last step
   *  the velocity along its projection (u - uPrevious; finite elements). */
  void        ForgetProjectionVelocities(const std::vector<double> & u, std::vector<double> & uPrevious) const;
  /** `time`: seconds in explicit dynamics; in dynamic relaxation the fraction
   *  of each tool's trajectory (a ramp from its first to its last pose). */
  void        EnforceTools(double * u, const double * previous, std::vector<char> & inContact,
                           const std::vector<double> & inverseMass, double alpha, double time);
  /** Appends the tools' poses and last-step loads to their histories. */
  void        RecordTools(std::vector<ToolHistory> & histories) const;
  std::vector<double> PhysicalDisplacements(const std::vector<double> & u) const;
  void        CentralDifferenceStep(const std::vector<double> & u,
                                    const std::vector<double> & uPrevious,
                                    const std::vector<double> & f,
                                    const std::vector<double> & inverseMass,
                                    double                      alpha,
                                    double                      beta,
                                    double                      gravityFactor,
                                    const std::vector<double> & curveFactors,
                                    std::vector<double> &       uNext,
                                    std::vector<char> &         inContact,
                                    double                      toolTime);
  void        CheckForces(Index inverted, int step, bool explicitDynamics, double timeStep) const;
  void        CheckIncrement(const std::vector<double> & next, const std::vector<double> & current, Index bad, int step,
                             bool explicitDynamics, double timeStep) const;
  void        CheckHexahedronCorners(const std::vector<double> & u, int step) const;
  SolveResult Finish(const std::vector<double> & u, const std::vector<char> & inContact, double gravityFactor, int steps);
  double      LargestEigenvalueEstimate(const std::vector<double> & mass);
  /** Dynamic relaxation's masses for its pseudo-time step: scaled to the
   *  cells' stiffness, then to the largest eigenvalue's estimate, which they
   *  bring to omegaMax^2 (with a margin). */
  std::vector<double> RelaxationMasses(double omegaMax);
  /** u and uPrevious at the warm state (if any), with the loads it balances
   *  (startForces, startTargets); clears those from rest. */
  /** One step of dynamic relaxation, u -> uNext with the constraints,
   *  contact and tools (`fused`: constraints only, in the update's pass);
   *  the increment's size. */
  IncrementStatistics RelaxationStep(bool fused, const std::vector<double> & u, const std::vector<double> & uPrevious,
                                     const std::vector<double> & f, const std::vector<double> & inverseMass,
                                     double alpha, double beta, double gravityFactor,
                                     const std::vector<double> & curveFactors, std::vector<double> & uNext,
                                     std::vector<char> & inContact, double toolTime);
  void        StartFromWarmState(std::vector<double> & u, std::vector<double> & uPrevious, double h);
  SolveResult SolveDynamicRelaxation(const ProgressCallback & progress);
  SolveResult SolveExplicitDynamics(const ProgressCallback & progress, const FrameCallback & frames);
};

} // namespace bmr

#endif
