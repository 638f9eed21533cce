#include "bmrSolver.h"

#include "bmrContact.h"
#include "bmrToolContact.h"
#include "bmrToolStress.h"
#include "bmrEssentialBoundary.h"
#include "bmrForceModel.h"
#include "bmrMeshless.h"
#include "bmrShape.h"
#include "bmrUnits.h"

#include <Eigen/Geometry>
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <limits>
#include <sstream>

namespace bmr
{

namespace
{

// Dynamic relaxation: power iterations for the largest eigenvalue, the margin
// put on that estimate, the increment growth over one adaptation window that
// counts as divergence, and the restarts allowed, each with masses this much heavier.
constexpr int    kPowerIterations = 30;
constexpr double kEigenvalueMargin = 1.1;
constexpr double kGrowthLimit = 10.0;
constexpr double kSignificantIncrement = 1e-4; // of the body's size
constexpr int    kMaxRestarts = 6;
constexpr double kRestartMassFactor = 2.0;

// Fixed block partition: sums do not depend on the number of threads.
constexpr Index kReductionBlocks = 64;

template <typename Term>
double
DeterministicSum(Index count, int threads, const Term & term)
{
  double partial[kReductionBlocks];
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index b = 0; b < kReductionBlocks; ++b)
  {
    const Index begin = static_cast<Index>(static_cast<std::int64_t>(count) * b / kReductionBlocks);
    const Index end = static_cast<Index>(static_cast<std::int64_t>(count) * (b + 1) / kReductionBlocks);
    double      sum = 0.0;
    for (Index i = begin; i < end; ++i)
    {
      sum += term(i);
    }
    partial[b] = sum;
  }
  double total = 0.0;
  for (const double p : partial)
  {
    total += p;
  }
  return total;
}

// Size of one step's change of the displacements, in one pass over the dofs:
// largest and root-sum-square increment, and the first unconstrained dof whose
// increment is not finite or larger than `limit`.
struct IncrementStatistics
{
  double maxAbs = 0.0;
  double norm = 0.0;
  Index  firstBad = -1;
};

IncrementStatistics
MeasureIncrement(const std::vector<double> & next,
                 const std::vector<double> & current,
                 const std::vector<char> &   constrained,
                 double                      limit,
                 int                         threads)
{
  const Index count = static_cast<Index>(next.size());
  double      maxima[kReductionBlocks], sums[kReductionBlocks];
  Index       bad[kReductionBlocks];
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index b = 0; b < kReductionBlocks; ++b)
  {
    const Index begin = static_cast<Index>(static_cast<std::int64_t>(count) * b / kReductionBlocks);
    const Index end = static_cast<Index>(static_cast<std::int64_t>(count) * (b + 1) / kReductionBlocks);
    double      largest = 0.0, sum = 0.0;
    Index       firstBad = -1;
    for (Index d = begin; d < end; ++d)
    {
      const double du = std::abs(next[d] - current[d]);
      // A prescribed jump is the user's load, not instability.
      if (!(du <= limit) && firstBad < 0 && !constrained[d])
      {
        firstBad = d;
      }
      largest = std::max(largest, du);
      sum += du * du;
    }
    maxima[b] = largest;
    sums[b] = sum;
    bad[b] = firstBad;
  }
  IncrementStatistics statistics;
  for (Index b = 0; b < kReductionBlocks; ++b)
  {
    statistics.maxAbs = std::max(statistics.maxAbs, maxima[b]);
    statistics.norm += sums[b];
    if (statistics.firstBad < 0)
    {
      statistics.firstBad = bad[b];
    }
  }
  statistics.norm = std::sqrt(statistics.norm);
  return statistics;
}

struct ConstrainedDof
{
  Index  dof;
  double value; // mm at full load
  int    curve; // index into the solver's curves; -1 for fixed (value 0)
};

std::string
StepLabel(int step)
{
  return "step " + std::to_string(step);
}

} // namespace

struct Solver::Impl
{
  Model                                      model;
  SolverSettings                             settings;
  int                                        threads = 1;
  std::unique_ptr<ForceModel>                forces;
  std::vector<std::unique_ptr<RigidContact>> contacts;
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

  // Meshless only: shape functions at the nodes (physical displacement =
  // Phi u), the EBCIEM projection (built per solve, with that solve's masses),
  // and the contact slave nodes with a buffer of their physical displacements.
  bool                               meshless = false;
  std::unique_ptr<MovingLeastSquares> shapeFunctions;
  ShapeFunctionTable                 nodeShapes;
  std::unique_ptr<EssentialBoundary> essential;
  std::vector<Index>                 contactSlaves;
  // Meshless contact, per step: interpolated positions projected onto the
  // surfaces, the slaves penetrating at the last detection with the surface
  // normals there (per contact), per node in contact its normal and target
  // n . u, those slaves (ascending) and, per slave, sum_K phi_K^2 (n . M_K^-1 n)
  // over its movable parameters; the parameters (dofs) that EBCIEM's
  // constrained rows interpolate.
  std::vector<double>                projectedBuffer;
  std::vector<char>                  penetrating;
  std::vector<Vector3>               slaveNormals;
  std::vector<Vector3>               contactNormals;
  std::vector<double>                contactTargets;
  std::vector<Index>                 activeSlaves;
  std::vector<double>                activeNorms;
  std::vector<char>                  essentialSupport;
  std::vector<double>                constraintTargets; // EBCIEM, per step

  Impl(const Model & m, const SolverSettings & s);
  void        CheckSettings() const;
  void        BuildConstraints();
  void        ApplyConstraints(double * u, const std::vector<double> & curveFactors);
  void        PrepareEssentialBoundary(const std::vector<double> & mass);
  void        EnforceContact(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass);
  /** `time`: seconds in explicit dynamics; in dynamic relaxation the fraction
   *  of each tool's trajectory (a ramp from its first to its last pose). */
  void        EnforceTools(double * u, const double * previous, std::vector<char> & inContact,
                           const std::vector<double> & inverseMass, double alpha, double time);
  /** Appends the tools' poses and last-step loads to their histories. */
  void        RecordTools(std::vector<ToolHistory> & histories) const;
  void        EnforceMeshlessContact(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass);
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
  SolveResult SolveDynamicRelaxation(const ProgressCallback & progress);
  SolveResult SolveExplicitDynamics(const ProgressCallback & progress, const FrameCallback & frames);
};

Solver::Impl::Impl(const Model & m, const SolverSettings & s)
  : model(m)
  , settings(s)
{
  CheckSettings();
  model.Validate();
  threads = settings.threads > 0 ? settings.threads : omp_get_max_threads();
  meshless = model.discretization == Discretization::Meshless;
  if (meshless)
  {
    shapeFunctions = MovingLeastSquares::ForModel(model);
    forces = std::make_unique<MeshlessForceModel>(
      model, shapeFunctions->Evaluate(model.meshless.integrationPoints, true, threads, "integration point"), threads);
    nodeShapes = shapeFunctions->Evaluate(model.nodes, false, threads, "node");
  }
  else
  {
    forces = std::make_unique<FiniteElementForceModel>(model, settings, threads);
  }
  physicalMass = forces->LumpedMasses();
  criticalTimeStep = forces->CriticalTimeStep(&criticalCell);

  Eigen::AlignedBox3d box;
  for (const Vector3 & x : model.nodes)
  {
    box.extend(x);
  }
  lengthScale = box.diagonal().norm();

  components.push_back("neo-hookean");
  components.push_back("lumped-mass");
  if (meshless)
  {
    components.push_back("meshless");
    components.push_back(model.meshless.shapeFunctions.basis == MlsBasis::Linear ? "mls-linear"
                                                                                  : "mls-modified-quadratic");
  }
  forces->AddComponents(components);
  components.push_back(settings.integrator == Integrator::DynamicRelaxation ? "dynamic-relaxation"
                                                                            : "explicit-dynamics");
  if (settings.integrator == Integrator::DynamicRelaxation)
  {
    components.push_back("mass-scaling");
  }
  BuildConstraints();
  if (!model.fixedConstraints.empty())
  {
    components.push_back("fixed-constraints");
  }
  if (!model.prescribedDisplacements.empty())
  {
    components.push_back("prescribed-displacements");
  }
  if (meshless && !constrained.empty())
  {
    components.push_back(model.meshless.essentialBoundary == EssentialBoundaryImposition::Ebciem
                           ? "ebciem"
                           : "nodal-essential-boundary");
  }
  if (!model.bodyAcceleration.isZero())
  {
    components.push_back("body-force");
    gravityForce.assign(3 * model.nodes.size(), 0.0);
    const Vector3 up = -model.bodyAcceleration.normalized();
    for (std::size_t n = 0; n < model.nodes.size(); ++n)
    {
      if (model.fluidSurface && (model.nodes[n] - *model.fluidSurface).dot(up) <= 0.0)
      {
        continue; // still buoyed by the CSF
      }
      for (int i = 0; i < 3; ++i)
      {
        gravityForce[3 * n + i] = physicalMass[n] * model.bodyAcceleration[i];
      }
    }
  }
  if (!model.contactSurfaces.empty())
  {
    components.push_back("contact");
    const std::vector<Index> boundary = model.BoundaryNodes();
    for (const ContactSurface & surface : model.contactSurfaces)
    {
      contacts.push_back(std::make_unique<RigidContact>(
        surface, surface.slaveNodeSet.empty() ? boundary : model.NodeSet(surface.slaveNodeSet), model.nodes));
      contactSlaves.insert(contactSlaves.end(), contacts.back()->SlaveNodes().begin(), contacts.back()->SlaveNodes().end());
    }
    std::sort(contactSlaves.begin(), contactSlaves.end());
    contactSlaves.erase(std::unique(contactSlaves.begin(), contactSlaves.end()), contactSlaves.end());
  }
  if (!model.tools.empty())
  {
    if (meshless)
    {
      throw Error("tools need a finite-element model: tool contact acts on nodes, and the meshless discretization's "
                  "nodes do not carry the physical displacement. Mesh the body with hexahedra or tetrahedra.");
    }
    components.push_back("tool-contact");
    const std::vector<Index> boundary = model.BoundaryNodes();
    for (const RigidTool & tool : model.tools)
    {
      tools.push_back(
        std::make_unique<ToolContact>(tool, tool.slaveNodeSet.empty() ? boundary : model.NodeSet(tool.slaveNodeSet), model.nodes));
      if (tool.stressRegionRadius > 0.0)
      {
        if (settings.integrator != Integrator::ExplicitDynamics)
        {
          throw Error("tool '" + tool.name + "' has a stress region: the Ogden stresses integrate the time history, "
                      "so they need explicit dynamics (set stress_region_radius to 0 for a steady state)");
        }
        if (std::find(components.begin(), components.end(), "ogden-stress-region") == components.end())
        {
          components.push_back("ogden-stress-region");
        }
      }
      stressRegions.push_back(tool.stressRegionRadius > 0.0 ? std::make_unique<ToolStressRegion>(model, *tools.back())
                                                             : nullptr);
    }
    toolLoads.resize(tools.size());
    correctedForces.assign(tools.size(), Vector3::Zero());
  }
  if (settings.computeStress)
  {
    components.push_back("stress-recovery");
  }
}

void
Solver::Impl::EnforceTools(double * u, const double * previous, std::vector<char> & inContact,
                           const std::vector<double> & inverseMass, double alpha, double time)
{
  for (std::size_t k = 0; k < tools.size(); ++k)
  {
    const std::vector<ToolPose> & trajectory = tools[k]->Tool().trajectory;
    const bool ramp = settings.integrator == Integrator::DynamicRelaxation;
    tools[k]->MoveTo(ramp ? trajectory.front().time + time * (trajectory.back().time - trajectory.front().time) : time);
    toolLoads[k] = tools[k]->Enforce(u, previous, dofConstrained, inContact, inverseMass, alpha, threads);
  }
}

void
Solver::Impl::RecordTools(std::vector<ToolHistory> & histories) const
{
  histories.resize(tools.size());
  for (std::size_t k = 0; k < tools.size(); ++k)
  {
    ToolHistory & history = histories[k];
    history.name = tools[k]->Tool().name;
    history.time.push_back(tools[k]->Pose().time);
    history.position.push_back(tools[k]->Pose().position);
    history.force.push_back(toolLoads[k].force);
    history.moment.push_back(toolLoads[k].moment);
    history.contactNodes.push_back(static_cast<int>(toolLoads[k].contactNodes));
    history.work += toolLoads[k].work * units::InternalEnergyToJoule;
    if (stressRegions[k])
    {
      history.correctedForce.push_back(correctedForces[k]);
      history.peakStress.push_back(stressRegions[k]->PeakVonMises());
    }
  }
}

void
Solver::Impl::CheckSettings() const
{
  auto require = [](bool ok, const std::string & what) {
    if (!ok)
    {
      throw Error("solver setting " + what);
    }
  };
  require(settings.timeStepSafetyFactor > 0.0 && settings.timeStepSafetyFactor <= 1.0,
          "safety_factor must lie in (0, 1]; 0.8 is a good default.");
  require(settings.hourglassCoefficient >= 0.0 && settings.hourglassCoefficient <= 1.0,
          "hourglass_coefficient must lie in [0, 1]; 0.2 is the default.");
  require(settings.timeStep >= 0.0, "time_step must be 0 (automatic) or positive.");
  require(settings.dampingCoefficient >= 0.0, "damping must not be negative.");
  require(settings.outputInterval >= 0.0 && std::isfinite(settings.outputInterval),
          "output_interval must be 0 (no frames) or a positive number of seconds.");
  if (settings.integrator == Integrator::DynamicRelaxation)
  {
    require(settings.tolerance > 0.0, "tolerance must be positive (mm).");
    require(settings.maxSteps > 0, "max_steps must be positive.");
    require(settings.loadSteps >= 1, "load_steps must be at least 1.");
    require(settings.adaptInterval >= 2, "adapt_interval must be at least 2.");
  }
  else
  {
    require(settings.endTime > 0.0, "end_time must be positive (s).");
  }
}

void
Solver::Impl::BuildConstraints()
{
  const std::size_t dofCount = 3 * model.nodes.size();
  dofConstrained.assign(dofCount, 0);
  nodeConstrained.assign(model.nodes.size(), 0);
  std::vector<int> owner(dofCount, -2); // -2 free, -1 fixed, k: curve of prescribed displacement k
  std::vector<double> value(dofCount, 0.0);

  auto constrain = [&](Index node, int axis, double target, int curve, const std::string & source) {
    const std::size_t dof = 3 * static_cast<std::size_t>(node) + axis;
    if (owner[dof] != -2 && (value[dof] != target || owner[dof] != curve))
    {
      std::ostringstream message;
      message << source << " conflicts with an earlier constraint on node " << node << " component " << "xyz"[axis]
              << " (different value or load curve). Give each degree of freedom one constraint.";
      throw Error(message.str());
    }
    owner[dof] = curve;
    value[dof] = target;
  };
  for (const FixedConstraint & fixed : model.fixedConstraints)
  {
    for (const Index node : model.NodeSet(fixed.nodeSet))
    {
      for (int axis = 0; axis < 3; ++axis)
      {
        if (fixed.components[axis])
        {
          constrain(node, axis, 0.0, -1, "fixed constraint on set '" + fixed.nodeSet + "'");
        }
      }
    }
  }
  for (std::size_t k = 0; k < model.prescribedDisplacements.size(); ++k)
  {
    const PrescribedDisplacement & load = model.prescribedDisplacements[k];
    curves.push_back(load.curve);
    for (std::size_t j = 0; j < load.nodes.size(); ++j)
    {
      for (int axis = 0; axis < 3; ++axis)
      {
        if (load.components[axis])
        {
          constrain(load.nodes[j], axis, load.displacements[j][axis], static_cast<int>(k),
                    "prescribed displacement " + std::to_string(k));
        }
      }
    }
  }
  for (std::size_t dof = 0; dof < dofCount; ++dof)
  {
    if (owner[dof] != -2)
    {
      constrained.push_back({ static_cast<Index>(dof), value[dof], owner[dof] });
      dofConstrained[dof] = 1;
      nodeConstrained[dof / 3] = 1;
    }
  }
}

void
Solver::Impl::ApplyConstraints(double * u, const std::vector<double> & curveFactors)
{
  auto target = [&](const ConstrainedDof & c) { return c.curve < 0 ? 0.0 : c.value * curveFactors[c.curve]; };
  if (essential)
  {
    constraintTargets.resize(constrained.size());
    for (std::size_t k = 0; k < constrained.size(); ++k)
    {
      constraintTargets[k] = target(constrained[k]);
    }
    essential->Impose(u, constraintTargets);
    return;
  }
  for (const ConstrainedDof & c : constrained)
  {
    u[c.dof] = target(c);
  }
}

void
Solver::Impl::PrepareEssentialBoundary(const std::vector<double> & mass)
{
  essential.reset();
  if (meshless && !constrained.empty() && model.meshless.essentialBoundary == EssentialBoundaryImposition::Ebciem)
  {
    std::vector<Index> dofs;
    for (const ConstrainedDof & c : constrained)
    {
      dofs.push_back(c.dof);
    }
    essential = std::make_unique<EssentialBoundary>(nodeShapes, dofs, mass);
    essentialSupport.assign(3 * model.nodes.size(), 0);
    for (const Index dof : dofs)
    {
      const Index node = dof / 3;
      for (Index k = nodeShapes.offsets[node]; k < nodeShapes.offsets[node + 1]; ++k)
      {
        essentialSupport[3 * nodeShapes.nodes[k] + dof % 3] = 1;
      }
    }
  }
}

void
Solver::Impl::EnforceContact(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass)
{
  if (meshless)
  {
    EnforceMeshlessContact(u, inContact, inverseMass);
    return;
  }
  std::fill(inContact.begin(), inContact.end(), 0);
  for (auto & contact : contacts)
  {
    contact->Enforce(u, dofConstrained, inContact, threads);
  }
}

void
Solver::Impl::EnforceMeshlessContact(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass)
{
  // Contact acts on the MLS-interpolated positions of the slave nodes. A
  // slave in contact contributes one constraint, n . (Phi_s u) = n . c, with c
  // its projection onto the surface and n the surface normal there: the
  // linearised gap, so the tangential motion stays free (frictionless).
  // Holding all three components at c instead can, in principle, let the
  // corrections carry tangential forces that depend on the masses (not seen
  // on a flat plane: MeshlessContact.SlidingIsUnresisted passes with both).
  // The shape functions do not interpolate: where nodes are close together a
  // node's own parameter barely moves its interpolated position, and adding
  // each slave's correction to its own parameter (a Jacobi iteration on the
  // shape-function matrix) pumps neighbouring parameters apart in opposite
  // directions, a mode with almost no stiffness that never settles (seen on
  // Colin27). Instead the parameters change by the mass-weighted least amount
  // that meets every constraint, as EBCIEM does for prescribed displacements:
  // Kaczmarz sweeps over the slaves in contact, which converge whatever the
  // coupling. A slave once in contact keeps its constraint for the rest of
  // the step (a neighbour's correction must not release it and make the
  // contact set flicker from step to step); slaves pushed into the surface by
  // the corrections join the set, and the sweeps repeat.
  // With EBCIEM a sweep that moved parameters the constrained nodes
  // interpolate ends with the essential boundary's projection: projecting
  // onto the prescribed values and then the contact once each per step left
  // a steady state that depends on the step's damping (on Colin27 every
  // update of the damping jolted the solution by 2e-4 mm and the termination
  // window never closed); projecting in turn within the step converges to
  // the least change that meets both.
  constexpr int kDetections = 8;
  constexpr int kSweeps = 64;
  if (contacts.empty())
  {
    return;
  }
  // Nodal imposition keeps constrained parameters fixed; EBCIEM restores the
  // constrained interpolated values instead.
  const auto weight = [&](Index dof) { return essential || !dofConstrained[dof] ? inverseMass[dof] : 0.0; };
  projectedBuffer.resize(3 * model.nodes.size(), 0.0);
  contactNormals.resize(model.nodes.size(), Vector3::Zero());
  contactTargets.resize(model.nodes.size(), 0.0);
  std::fill(inContact.begin(), inContact.end(), 0);
  activeSlaves.clear();
  const Index  slaveCount = static_cast<Index>(contactSlaves.size());
  const double tolerance = 1e-9 * lengthScale;
  for (int detection = 0; detection < kDetections; ++detection)
  {
#pragma omp parallel for num_threads(threads) schedule(static)
    for (Index s = 0; s < slaveCount; ++s)
    {
      const Index   node = contactSlaves[s];
      const Vector3 value = nodeShapes.Interpolate(node, u);
      for (int i = 0; i < 3; ++i)
      {
        projectedBuffer[3 * node + i] = value[i];
      }
    }
    penetrating.assign(model.nodes.size(), 0);
    bool added = false;
    for (auto & contact : contacts)
    {
      contact->Enforce(projectedBuffer.data(), dofConstrained, penetrating, threads, nullptr, &slaveNormals);
      const std::vector<Index> & slaves = contact->SlaveNodes();
      for (std::size_t k = 0; k < slaves.size(); ++k)
      {
        const Index     node = slaves[k];
        const Vector3 & normal = slaveNormals[k];
        if (!penetrating[node] || !(normal.norm() > 0.0)) // penetrating another surface
        {
          continue;
        }
        contactNormals[node] = normal;
        contactTargets[node] = normal.dot(Vector3(projectedBuffer[3 * node], projectedBuffer[3 * node + 1],
                                                  projectedBuffer[3 * node + 2]));
        if (!inContact[node])
        {
          inContact[node] = 1;
          activeSlaves.push_back(node);
          added = true;
        }
      }
    }
    if (!added && detection > 0)
    {
      break;
    }
    std::sort(activeSlaves.begin(), activeSlaves.end());
    activeNorms.assign(activeSlaves.size(), 0.0);
    for (std::size_t a = 0; a < activeSlaves.size(); ++a)
    {
      const Index     node = activeSlaves[a];
      const Vector3 & n = contactNormals[node];
      for (Index k = nodeShapes.offsets[node]; k < nodeShapes.offsets[node + 1]; ++k)
      {
        const double phi = nodeShapes.values[k];
        for (int i = 0; i < 3; ++i)
        {
          activeNorms[a] += phi * phi * n[i] * n[i] * weight(3 * nodeShapes.nodes[k] + i);
        }
      }
    }
    for (int sweep = 0; sweep < kSweeps; ++sweep)
    {
      double largest = 0.0;
      bool   movedEssential = false;
      for (std::size_t a = 0; a < activeSlaves.size(); ++a)
      {
        const Index     node = activeSlaves[a];
        const Vector3 & n = contactNormals[node];
        const double    gap = contactTargets[node] - n.dot(nodeShapes.Interpolate(node, u));
        largest = std::max(largest, std::abs(gap));
        if (!(activeNorms[a] > 0.0))
        {
          continue;
        }
        const double multiplier = gap / activeNorms[a];
        for (Index k = nodeShapes.offsets[node]; k < nodeShapes.offsets[node + 1]; ++k)
        {
          for (int i = 0; i < 3; ++i)
          {
            const Index  d = 3 * nodeShapes.nodes[k] + i;
            const double change = multiplier * nodeShapes.values[k] * n[i] * weight(d);
            u[d] += change;
            movedEssential = movedEssential || (essential && change != 0.0 && essentialSupport[d]);
          }
        }
      }
      if (largest <= tolerance)
      {
        break;
      }
      if (movedEssential)
      {
        essential->Impose(u, constraintTargets);
      }
    }
  }
}

std::vector<double>
Solver::Impl::PhysicalDisplacements(const std::vector<double> & u) const
{
  if (!meshless)
  {
    return u;
  }
  std::vector<double> physical(u.size());
  const Index         nodeCount = static_cast<Index>(model.nodes.size());
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index n = 0; n < nodeCount; ++n)
  {
    const Vector3 value = nodeShapes.Interpolate(n, u.data());
    for (int i = 0; i < 3; ++i)
    {
      physical[3 * n + i] = value[i];
    }
  }
  return physical;
}

void
Solver::Impl::CentralDifferenceStep(const std::vector<double> & u,
                                    const std::vector<double> & uPrevious,
                                    const std::vector<double> & f,
                                    const std::vector<double> & inverseMass,
                                    double                      alpha,
                                    double                      beta,
                                    double                      gravityFactor,
                                    const std::vector<double> & curveFactors,
                                    std::vector<double> &       uNext,
                                    std::vector<char> &         inContact,
                                    double                      toolTime)
{
  // u+ = u + beta (u - u-) + alpha M^-1 (f_ext - f_int), then the constraints
  // and the contact projection (both integrators).
  const Index    dofCount = static_cast<Index>(u.size());
  const double * g = gravityForce.empty() ? nullptr : gravityForce.data();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index d = 0; d < dofCount; ++d)
  {
    const double residual = (g ? gravityFactor * g[d] : 0.0) - f[d];
    uNext[d] = u[d] + beta * (u[d] - uPrevious[d]) + alpha * residual * inverseMass[d];
  }
  ApplyConstraints(uNext.data(), curveFactors);
  EnforceContact(uNext.data(), inContact, inverseMass);
  if (!tools.empty())
  {
    EnforceTools(uNext.data(), u.data(), inContact, inverseMass, alpha, toolTime);
  }
}

void
Solver::Impl::CheckForces(Index inverted, int step, bool explicitDynamics, double timeStep) const
{
  if (inverted < 0)
  {
    return;
  }
  std::ostringstream message;
  message << forces->Describe(inverted) << " inverted (J <= 0) at " << StepLabel(step) << ". Likely cause: ";
  if (explicitDynamics && timeStep > criticalTimeStep)
  {
    message << "the time step " << timeStep << " s exceeds the critical time step " << criticalTimeStep
            << " s; use the automatic time step.";
  }
  else
  {
    message << "a load too large or applied too fast for the mesh (increase load_steps or the ramp time, "
               "refine the mesh near the load), a material too soft for the load, or a time step too large "
               "(lower safety_factor).";
  }
  throw SolveError(message.str(), step, inverted);
}

void
Solver::Impl::CheckIncrement(const std::vector<double> & next, const std::vector<double> & current, Index bad, int step,
                             bool explicitDynamics, double timeStep) const
{
  if (bad < 0)
  {
    return;
  }
  const double       du = next[bad] - current[bad];
  std::ostringstream message;
  message << "the solution became unstable at " << StepLabel(step) << ": node " << bad / 3
          << (std::isfinite(du) ? " moved further in one step than the body's size" : " has a NaN or infinite displacement")
          << " (kinetic energy growing without bound). Likely cause: ";
  if (explicitDynamics && timeStep > criticalTimeStep)
  {
    message << "the time step " << timeStep << " s exceeds the critical time step " << criticalTimeStep << " s.";
  }
  else
  {
    message << "a time step too large for the deformed mesh (lower safety_factor), or a load too large.";
  }
  throw SolveError(message.str(), step, -1);
}

void
Solver::Impl::CheckHexahedronCorners(const std::vector<double> & u, int step) const
{
  // The one-point hexahedron sees only its centre: a cell can fold at a corner
  // (hourglassing) while J > 0 there. Such a state is never returned as a result.
  for (Index c = 0; c < static_cast<Index>(model.cells.size()); ++c)
  {
    const Cell & cell = model.cells[c];
    if (cell.type != CellType::Hexahedron)
    {
      continue;
    }
    HexahedronCoordinates x;
    for (int a = 0; a < 8; ++a)
    {
      const std::size_t n = static_cast<std::size_t>(cell.nodes[a]);
      x.row(a) = (model.nodes[n] + Vector3(u[3 * n], u[3 * n + 1], u[3 * n + 2])).transpose();
    }
    if (!(HexahedronMinimumCornerJacobian(x) > 0.0))
    {
      throw SolveError("hexahedron cell " + std::to_string(c) + " is folded at a corner (negative corner Jacobian) at " +
                         StepLabel(step) + ". Likely cause: a load too concentrated for the mesh (refine the mesh "
                         "near the load, or raise hourglass_coefficient).",
                       step, c);
    }
  }
}

SolveResult
Solver::Impl::Finish(const std::vector<double> & u, const std::vector<char> & inContact, double gravityFactor, int steps)
{
  const std::size_t nodeCount = model.nodes.size();
  if (!meshless)
  {
    CheckHexahedronCorners(u, steps);
  }
  const std::vector<double> physical = PhysicalDisplacements(u);
  std::vector<double>       f(3 * nodeCount);
  forces->ComputeInternalForces(u.data(), f.data());
  for (std::size_t d = 0; d < f.size(); ++d)
  {
    // Reaction = internal minus external force: what the support or surface must supply.
    f[d] -= gravityForce.empty() ? 0.0 : gravityFactor * gravityForce[d];
  }
  SolveResult result;
  result.displacements.resize(nodeCount);
  result.reactionForces.assign(nodeCount, Vector3::Zero());
  for (std::size_t n = 0; n < nodeCount; ++n)
  {
    result.displacements[n] = Vector3(physical[3 * n], physical[3 * n + 1], physical[3 * n + 2]);
    result.maxDisplacement = std::max(result.maxDisplacement, result.displacements[n].norm());
    if ((nodeConstrained[n] && !essential) || inContact[n])
    {
      result.reactionForces[n] = Vector3(f[3 * n], f[3 * n + 1], f[3 * n + 2]);
    }
    result.contactNodes += inContact[n] ? 1 : 0;
  }
  if (meshless)
  {
    // The contact set of the last iteration may miss nodes that touch within
    // round-off; a free slave node carries no residual at rest, so every slave
    // reports its residual.
    for (const Index node : contactSlaves)
    {
      result.reactionForces[node] = Vector3(f[3 * node], f[3 * node + 1], f[3 * node + 2]);
    }
  }
  if (essential)
  {
    // EBCIEM: the reaction is the multiplier of each constrained point.
    const std::vector<double> reactions = essential->Reactions(f.data());
    for (std::size_t k = 0; k < constrained.size(); ++k)
    {
      result.reactionForces[constrained[k].dof / 3][constrained[k].dof % 3] = reactions[k];
    }
  }
  if (meshless)
  {
    result.nodalParameters.resize(nodeCount);
    for (std::size_t n = 0; n < nodeCount; ++n)
    {
      result.nodalParameters[n] = Vector3(u[3 * n], u[3 * n + 1], u[3 * n + 2]);
    }
  }
  const Energies energies = forces->ComputeEnergies(u.data());
  result.strainEnergy = energies.strain * units::InternalEnergyToJoule;
  result.hourglassEnergy = energies.hourglass * units::InternalEnergyToJoule;
  for (const auto & contact : contacts)
  {
    result.maxPenetration = std::max(result.maxPenetration, contact->MaxPenetration(physical.data()));
  }
  if (settings.computeStress)
  {
    result.cauchyStress = forces->CauchyStress(u.data());
  }
  result.criticalTimeStep = criticalTimeStep;
  result.activeComponents = components;
  return result;
}

double
Solver::Impl::LargestEigenvalueEstimate(const std::vector<double> & mass)
{
  // Power iteration on M^-1 K at the reference state, K v by the force of a
  // tiny displacement (linear there). A fixed pseudo-random start and fixed
  // sums keep it deterministic.
  const Index         dofCount = static_cast<Index>(3 * model.nodes.size());
  std::vector<double> v(dofCount), f(dofCount);
  std::uint64_t       state = 0x9E3779B97F4A7C15ull;
  for (double & x : v)
  {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    x = static_cast<double>(state >> 11) * 0x1.0p-53 - 0.5;
  }
  double estimate = 0.0;
  for (int iteration = 0; iteration < kPowerIterations; ++iteration)
  {
    const double norm = std::sqrt(DeterministicSum(dofCount, threads, [&](Index d) { return mass[d / 3] * v[d] * v[d]; }));
    const double largest = *std::max_element(v.begin(), v.end(), [](double l, double r) { return std::abs(l) < std::abs(r); });
    const double scale = 1e-8 * lengthScale / std::max(std::abs(largest), 1e-300);
    for (double & x : v)
    {
      x *= scale;
    }
    CheckForces(forces->ComputeInternalForces(v.data(), f.data()), 0, false, 1.0);
    const double numerator = DeterministicSum(dofCount, threads, [&](Index d) { return v[d] * f[d]; });
    const double denominator = norm * norm * scale * scale;
    estimate = numerator / denominator;
    for (Index d = 0; d < dofCount; ++d)
    {
      v[d] = f[d] / mass[d / 3];
    }
  }
  return estimate;
}

SolveResult
Solver::Impl::SolveDynamicRelaxation(const ProgressCallback & progress)
{
  // Pseudo-time step 1 and masses scaled cell by cell to the cells' stiffness,
  // which preconditions the iteration by the local stiffness (stiffness
  // contrasts and graded meshes cost nothing extra). The element bound on the
  // largest eigenvalue is pessimistic for an assembled mesh (2 to 4 times), so
  // the masses are then scaled globally to a power-iteration estimate of it:
  // fewer steps for the same stability margin (safety_factor).
  constexpr double    h = 1.0;
  const double        safety = settings.timeStepSafetyFactor;
  const double        omegaMax = 2.0 * safety / h;
  const Index         dofCount = static_cast<Index>(3 * model.nodes.size());
  std::vector<double> mass = forces->ScaledMasses(h, 1.0); // element bound: omega_max <= 2
  const double        boundScale = 1.0 / (safety * safety);
  const double        largest = LargestEigenvalueEstimate(mass);
  const double massScale = std::clamp(kEigenvalueMargin * largest / (omegaMax * omegaMax), 1e-3 * boundScale, boundScale);

  std::vector<double> u(dofCount, 0.0), uPrevious(dofCount, 0.0), uNext(dofCount, 0.0);
  std::vector<double> f(dofCount, 0.0), fPrevious(dofCount, 0.0), inverseMass(dofCount);
  auto                scaleMasses = [&](double factor) {
    for (double & m : mass)
    {
      m *= factor;
    }
    for (Index d = 0; d < dofCount; ++d)
    {
      inverseMass[d] = 1.0 / mass[d / 3];
    }
  };
  scaleMasses(massScale);
  PrepareEssentialBoundary(mass); // uniform rescaling on restart leaves the projection unchanged
  std::vector<char>   inContact(model.nodes.size(), 0);
  std::vector<double> curveFactors(curves.size(), 0.0);

  // Damping for the current estimate of the lowest eigenvalue: critical damping
  // of that mode, c = omega sqrt(4 - h^2 omega^2), double root sqrt(beta).
  double lowestEigenvalue = 0.01 * omegaMax * omegaMax;
  double alpha = 0.0, beta = 0.0;
  auto   betaFor = [&](double lambda) {
    const double c = std::sqrt(lambda) * std::sqrt(std::max(0.0, 4.0 - h * h * lambda));
    return (2.0 - c * h) / (2.0 + c * h);
  };
  auto setDamping = [&](double lambda) {
    lowestEigenvalue = std::clamp(lambda, 1e-16 * omegaMax * omegaMax, omegaMax * omegaMax);
    const double omega = std::sqrt(lowestEigenvalue);
    const double c = omega * std::sqrt(std::max(0.0, 4.0 - h * h * lowestEigenvalue));
    alpha = 2.0 * h * h / (2.0 + c * h);
    beta = (2.0 - c * h) / (2.0 + c * h);
  };
  setDamping(lowestEigenvalue);
  // The smallest lowest-eigenvalue estimate since the loads were applied: the
  // error estimate uses its rate, as the current estimate can jump up (to
  // the higher modes that dominate right after a restart or a contact event)
  // and would then declare convergence while the slowest mode still creeps.
  double slowestEigenvalue = std::numeric_limits<double>::infinity();

  const int          window = settings.adaptInterval;
  std::deque<double> incrementNorms; // last window + 1 values of ||du||_2
  double             estimatedError = std::numeric_limits<double>::infinity();
  double             rate = 1.0;
  int                satisfied = 0;
  int                step = 0;
  bool               converged = false;
  double             gravityFactor = 0.0;
  int                restarts = 0;
  auto               loadFactor = [&](const LoadCurve & curve, int k) {
    return curve.Factor(static_cast<double>(k) / settings.loadSteps);
  };

  // Checkpoint for restarts: stiffening under large deformation can outgrow
  // the reference-state estimate of the largest eigenvalue. Dynamic relaxation
  // only seeks the steady state, so it may restart from the last good state at
  // rest with heavier masses.
  std::vector<double>         checkpoint(u);
  int                         checkpointStep = 0;
  std::unique_ptr<SolveError> firstFailure;

  for (step = 0; step < settings.maxSteps; ++step)
  {
    try
    {
      CheckForces(forces->ComputeInternalForces(u.data(), f.data()), step, false, h);

      if (step > 0 && step % window == 0)
      {
        // Rayleigh quotient of the last increment: tends to the lowest eigenvalue
        // as the higher modes die out.
        const double numerator = DeterministicSum(dofCount, threads, [&](Index d) {
          return dofConstrained[d] ? 0.0 : (u[d] - uPrevious[d]) * (f[d] - fPrevious[d]);
        });
        const double denominator = DeterministicSum(dofCount, threads, [&](Index d) {
          const double du = u[d] - uPrevious[d];
          return dofConstrained[d] ? 0.0 : mass[d / 3] * du * du;
        });
        if (numerator > 0.0 && denominator > 0.0)
        {
          setDamping(numerator / denominator);
          if (step > settings.loadSteps)
          {
            slowestEigenvalue = std::min(slowestEigenvalue, lowestEigenvalue);
          }
        }
      }

      gravityFactor = gravityForce.empty() ? 0.0 : loadFactor(model.bodyForceCurve, step);
      for (std::size_t k = 0; k < curves.size(); ++k)
      {
        curveFactors[k] = loadFactor(curves[k], step + 1);
      }
      CentralDifferenceStep(u, uPrevious, f, inverseMass, alpha, beta, gravityFactor, curveFactors, uNext, inContact,
                            LoadCurve{}.Factor(static_cast<double>(step + 1) / settings.loadSteps));

      const IncrementStatistics increment = MeasureIncrement(uNext, u, dofConstrained, lengthScale, threads);
      CheckIncrement(uNext, u, increment.firstBad, step, false, h);
      incrementNorms.push_back(increment.norm);
      if (static_cast<int>(incrementNorms.size()) > window + 1)
      {
        incrementNorms.pop_front();
      }
      // Divergence: increments growing tenfold within a window once the loads
      // are applied, and no longer negligible (round-off and contact events
      // near convergence may jump by large factors from tiny values).
      if (step + 1 > settings.loadSteps && static_cast<int>(incrementNorms.size()) == window + 1 &&
          incrementNorms.back() > kGrowthLimit * incrementNorms.front() &&
          increment.maxAbs > kSignificantIncrement * lengthScale)
      {
        std::ostringstream message;
        message << "dynamic relaxation diverged at " << StepLabel(step) << ": the displacement increments grew "
                << kGrowthLimit << "-fold within " << window
                << " steps. Likely cause: stiffening beyond the time-step estimate (lower safety_factor).";
        throw SolveError(message.str(), step, -1);
      }
      std::swap(uPrevious, u);
      std::swap(u, uNext);
      std::swap(f, fPrevious);

      // Termination (Joldes et al. 2009): distance to the solution estimated as
      // rate / (1 - rate) * ||du||_inf, with the rate the largest of the observed
      // decay and the theoretical rate sqrt(beta) of the current and of the
      // slowest lowest-mode estimate.
      if (step + 1 >= settings.loadSteps && static_cast<int>(incrementNorms.size()) == window + 1)
      {
        const double observed = incrementNorms.front() > 0.0
                                  ? std::pow(incrementNorms.back() / incrementNorms.front(), 1.0 / window)
                                  : 0.0;
        const double slowest = std::isfinite(slowestEigenvalue) ? betaFor(slowestEigenvalue) : beta;
        rate = std::max(observed, std::sqrt(std::max(std::max(beta, slowest), 0.0)));
        estimatedError = rate < 1.0 ? rate / (1.0 - rate) * increment.maxAbs : std::numeric_limits<double>::infinity();
        satisfied = estimatedError < settings.tolerance ? satisfied + 1 : 0;
        if (satisfied >= window)
        {
          converged = true;
          ++step;
          break;
        }
      }
      if ((step + 1) % window == 0)
      {
        checkpoint = u;
        checkpointStep = step + 1;
      }
    }
    catch (const SolveError & failure)
    {
      if (!firstFailure)
      {
        firstFailure = std::make_unique<SolveError>(failure);
      }
      if (restarts == kMaxRestarts)
      {
        // The first failure names the cell or node where it started.
        throw SolveError(std::string(firstFailure->what()) + " Restarting " + std::to_string(kMaxRestarts) +
                           " times from the last good state with heavier masses did not help.",
                         firstFailure->Step(), firstFailure->Element());
      }
      ++restarts;
      scaleMasses(kRestartMassFactor);
      setDamping(lowestEigenvalue / kRestartMassFactor);
      slowestEigenvalue /= kRestartMassFactor;
      u = checkpoint;
      uPrevious = checkpoint;
      step = checkpointStep - 1;
      incrementNorms.clear();
      satisfied = 0;
      continue;
    }
    if (progress && (step + 1) % 200 == 0)
    {
      progress(step + 1, -1.0, estimatedError);
    }
  }

  SolveResult result = Finish(u, inContact, gravityFactor, step);
  if (!tools.empty())
  {
    RecordTools(result.tools); // the steady state; the work of pseudo-time steps means nothing
    for (ToolHistory & history : result.tools)
    {
      history.work = 0.0;
    }
  }
  result.converged = converged;
  result.steps = step;
  result.timeStep = h;
  result.estimatedError = estimatedError;
  result.convergenceRate = rate;
  result.restarts = restarts;
  std::ostringstream message;
  if (converged)
  {
    message << "converged: estimated error " << estimatedError << " mm < tolerance " << settings.tolerance << " mm";
  }
  else
  {
    message << "NOT CONVERGED: estimated error " << estimatedError << " mm after " << step
            << " steps is above the tolerance " << settings.tolerance
            << " mm. Increase max_steps, loosen the tolerance, or check that the model is constrained "
               "against rigid-body motion.";
  }
  if (restarts > 0)
  {
    message << " (" << restarts << " restart(s) with heavier masses after the deformation stiffened the model)";
  }
  result.message = message.str();
  return result;
}

SolveResult
Solver::Impl::SolveExplicitDynamics(const ProgressCallback & progress, const FrameCallback & frames)
{
  const double requested = settings.timeStep > 0.0 ? settings.timeStep : settings.timeStepSafetyFactor * criticalTimeStep;
  const double stepCount = std::ceil(settings.endTime / requested - 1e-9);
  // The step counter is an int: a larger count would wrap and "reach" the end time at once.
  if (!(stepCount <= static_cast<double>(std::numeric_limits<int>::max())))
  {
    std::ostringstream message;
    message << "solver setting end_time " << settings.endTime << " s needs " << stepCount << " steps of " << requested
            << " s, more than the " << std::numeric_limits<int>::max()
            << " an explicit dynamics run can take; shorten end_time or use dynamic relaxation for a steady state.";
    throw Error(message.str());
  }
  const int    steps = std::max(1, static_cast<int>(stepCount));
  const double h = settings.endTime / steps; // land exactly on the end time
  const double c = settings.dampingCoefficient;
  const double alpha = 2.0 * h * h / (2.0 + c * h);
  const double beta = (2.0 - c * h) / (2.0 + c * h);
  const Index  dofCount = static_cast<Index>(3 * model.nodes.size());

  std::vector<double> u(dofCount, 0.0), uPrevious(dofCount, 0.0), uNext(dofCount, 0.0);
  std::vector<double> f(dofCount, 0.0), inverseMass(dofCount);
  for (Index d = 0; d < dofCount; ++d)
  {
    inverseMass[d] = 1.0 / physicalMass[d / 3];
  }
  PrepareEssentialBoundary(physicalMass);
  std::vector<char>   inContact(model.nodes.size(), 0);
  std::vector<double> curveFactors(curves.size(), 0.0);
  auto                loadFactor = [](const LoadCurve & curve, double time) {
    return curve.shape == LoadCurve::Shape::Step ? 1.0 : curve.Factor(time / curve.rampTime);
  };
  double gravityFactor = 0.0;
  const int reportEvery = std::max(1, steps / 200);
  std::vector<ToolHistory> toolHistories;

  // Frames at t = 0, every output interval, and at the end time.
  const bool           framesWanted = frames && settings.outputInterval > 0.0;
  int                  nextFrame = 1;
  std::vector<Vector3> frameDisplacements(model.nodes.size());
  auto                 emitFrame = [&](int step) {
    for (std::size_t n = 0; n < model.nodes.size(); ++n)
    {
      frameDisplacements[n] = Vector3(u[3 * n], u[3 * n + 1], u[3 * n + 2]);
    }
    const Energies energies = forces->ComputeEnergies(u.data());
    const double   kinetic = step == 0 ? 0.0
                                       : 0.5 * DeterministicSum(dofCount, threads, [&](Index d) {
                                           const double v = (u[d] - uPrevious[d]) / h;
                                           return physicalMass[d / 3] * v * v;
                                         });
    frames(SolveFrame{ step * h, step, frameDisplacements,
                       energies.strain * units::InternalEnergyToJoule,
                       kinetic * units::InternalEnergyToJoule });
  };
  if (framesWanted)
  {
    emitFrame(0);
  }

  for (int step = 0; step < steps; ++step)
  {
    CheckForces(forces->ComputeInternalForces(u.data(), f.data()), step, true, h);
    gravityFactor = gravityForce.empty() ? 0.0 : loadFactor(model.bodyForceCurve, step * h);
    if (step == 0)
    {
      // Start at rest at t = 0, not at t = -h/2: u(-h) such that the first step
      // gives u(h) = a(0) h^2 / 2 (otherwise the solution lags by half a step).
      for (Index d = 0; d < dofCount; ++d)
      {
        const double acceleration = ((gravityForce.empty() ? 0.0 : gravityFactor * gravityForce[d]) - f[d]) * inverseMass[d];
        uPrevious[d] = dofConstrained[d] ? 0.0 : (alpha - 0.5 * h * h) * acceleration / beta;
      }
    }
    for (std::size_t k = 0; k < curves.size(); ++k)
    {
      curveFactors[k] = loadFactor(curves[k], (step + 1) * h);
    }
    CentralDifferenceStep(u, uPrevious, f, inverseMass, alpha, beta, gravityFactor, curveFactors, uNext, inContact,
                          (step + 1) * h);
    CheckIncrement(uNext, u, MeasureIncrement(uNext, u, dofConstrained, lengthScale, threads).firstBad, step, true, h);
    std::swap(uPrevious, u);
    std::swap(u, uNext);
    for (std::size_t k = 0; k < stressRegions.size(); ++k)
    {
      if (stressRegions[k])
      {
        correctedForces[k] = toolLoads[k].force + stressRegions[k]->Update(u.data(), h, tools[k]->TouchingNodes(), threads);
      }
    }
    if (!tools.empty())
    {
      RecordTools(toolHistories);
    }
    if (framesWanted && (step + 1 == steps || (step + 1) * h >= nextFrame * settings.outputInterval - 1e-9 * h))
    {
      emitFrame(step + 1);
      nextFrame = static_cast<int>(std::floor((step + 1) * h / settings.outputInterval + 1e-9)) + 1;
    }
    if (progress && (step + 1) % reportEvery == 0)
    {
      progress(step + 1, static_cast<double>(step + 1) / steps, 0.0);
    }
  }

  SolveResult result = Finish(u, inContact, gravityFactor, steps);
  for (std::size_t k = 0; k < stressRegions.size() && k < toolHistories.size(); ++k)
  {
    if (stressRegions[k])
    {
      toolHistories[k].stressCells = stressRegions[k]->Cells();
      toolHistories[k].ogdenStress = stressRegions[k]->OgdenStress();
      toolHistories[k].neoHookeanStress = stressRegions[k]->NeoHookeanStress();
    }
  }
  result.tools = std::move(toolHistories);
  result.converged = true;
  result.steps = steps;
  result.timeStep = h;
  // Velocity at the end time: v(n) = (v(n - 1/2) + h/2 a(n)) / (1 + c h / 2);
  // prescribed components by backward difference.
  forces->ComputeInternalForces(u.data(), f.data());
  result.kineticEnergy = 0.5 *
                         DeterministicSum(dofCount, threads, [&](Index d) {
                           double v = (u[d] - uPrevious[d]) / h;
                           if (!dofConstrained[d])
                           {
                             const double external = gravityForce.empty() ? 0.0 : gravityFactor * gravityForce[d];
                             v = (v + 0.5 * h * (external - f[d]) * inverseMass[d]) / (1.0 + 0.5 * c * h);
                           }
                           return physicalMass[d / 3] * v * v;
                         }) *
                         units::InternalEnergyToJoule;
  result.message = "reached end time " + std::to_string(settings.endTime) + " s in " + std::to_string(steps) + " steps";
  return result;
}

Solver::Solver(const Model & model, const SolverSettings & settings)
  : m_Impl(std::make_unique<Impl>(model, settings))
{}

Solver::~Solver() = default;

SolveResult
Solver::Solve(const ProgressCallback & progress, const FrameCallback & frames)
{
  const auto  start = std::chrono::steady_clock::now();
  SolveResult result = m_Impl->settings.integrator == Integrator::DynamicRelaxation
                         ? m_Impl->SolveDynamicRelaxation(progress)
                         : m_Impl->SolveExplicitDynamics(progress, frames);
  result.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

const std::vector<std::string> &
Solver::ActiveComponents() const
{
  return m_Impl->components;
}

double
Solver::CriticalTimeStep() const
{
  return m_Impl->criticalTimeStep;
}

std::vector<Vector3>
Solver::InternalForces(const std::vector<Vector3> & displacements)
{
  const std::size_t nodeCount = m_Impl->model.nodes.size();
  if (displacements.size() != nodeCount)
  {
    throw Error("InternalForces: " + std::to_string(displacements.size()) + " displacement vectors for " +
                std::to_string(nodeCount) + " nodes.");
  }
  std::vector<double> u(3 * nodeCount), f(3 * nodeCount);
  for (std::size_t n = 0; n < nodeCount; ++n)
  {
    for (int i = 0; i < 3; ++i)
    {
      u[3 * n + i] = displacements[n][i];
    }
  }
  const Index inverted = m_Impl->forces->ComputeInternalForces(u.data(), f.data());
  if (inverted >= 0)
  {
    throw SolveError("InternalForces: cell " + std::to_string(inverted) + " is inverted by the given displacements.", 0,
                     inverted);
  }
  std::vector<Vector3> result(nodeCount);
  for (std::size_t n = 0; n < nodeCount; ++n)
  {
    result[n] = Vector3(f[3 * n], f[3 * n + 1], f[3 * n + 2]);
  }
  return result;
}

} // namespace bmr
