#include "bmrSolverImpl.h"

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

Solver::Impl::Impl(const Model & m, const SolverSettings & s, const SolverPrecomputation * precomputed)
  : model(m)
  , settings(s)
{
  CheckSettings();
  model.Validate();
  threads = settings.threads > 0 ? settings.threads : omp_get_max_threads();
  meshless = model.discretization == Discretization::Meshless;
  if (precomputed != nullptr)
  {
    if (const std::string mismatch = precomputed->Mismatch(model, settings); !mismatch.empty())
    {
      throw Error("the solver's precomputation was made " + mismatch +
                  ": make it again for this model and these settings, or solve without it");
    }
    forces = precomputed->State().forces->Clone(threads);
    nodeShapes = precomputed->State().nodeShapes;
  }
  else
  {
    forces = MakeForceModel(model, settings, threads, nodeShapes);
  }
  physicalMass = forces->LumpedMasses();
  criticalTimeStep = forces->CriticalTimeStep(&criticalCell);

  lengthScale = BoundingBox(model.nodes).diagonal().norm();

  for (const MaterialLawDescription & law : MaterialLaws())
  {
    if (std::any_of(model.materials.begin(), model.materials.end(),
                    [&](const Material & material) { return material.law == law.law; }))
    {
      components.push_back(law.name);
    }
  }
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
    const std::vector<Index>  boundary = model.BoundaryNodes();
    const std::vector<double> zero(3 * model.nodes.size(), 0.0);
    for (const ContactSurface & surface : model.contactSurfaces)
    {
      contacts.push_back(std::make_unique<RigidContact>(
        surface, surface.slaveNodeSet.empty() ? boundary : model.NodeSet(surface.slaveNodeSet), model.nodes));
      const RigidContact::Penetrations start = contacts.back()->FindPenetrations(zero.data(), 1e-6); // mm
      if (start.count > 0)
      {
        std::ostringstream words;
        words << (initialPenetration.empty() ? "" : "; ") << start.count
              << " contact node(s) start beyond contact surface '" << surface.name << "' (node " << start.deepestNode
              << " by " << start.depth << " mm)";
        initialPenetration += words.str();
      }
    }
    if (meshless)
    {
      meshlessContact = std::make_unique<MeshlessContact>(contacts, nodeShapes, static_cast<Index>(model.nodes.size()));
    }
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
  require(settings.collapseBulkModulus >= 0.0 && std::isfinite(settings.collapseBulkModulus),
          "collapse_bulk_modulus must be 0 (the model's median bulk modulus) or a positive number of Pa.");
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
  if (essential)
  {
    constraintTargets.resize(constrained.size());
    for (std::size_t k = 0; k < constrained.size(); ++k)
    {
      constraintTargets[k] = ConstraintTarget(k, curveFactors);
    }
    essential->Impose(u, constraintTargets, threads);
    return;
  }
  for (std::size_t k = 0; k < constrained.size(); ++k)
  {
    u[constrained[k].dof] = ConstraintTarget(k, curveFactors);
  }
}

void
Solver::Impl::PrepareEssentialBoundary(const std::vector<double> & mass)
{
  essential.reset();
  std::vector<Index> dofs;
  if (meshless && !constrained.empty() && model.meshless.essentialBoundary == EssentialBoundaryImposition::Ebciem)
  {
    for (const ConstrainedDof & c : constrained)
    {
      dofs.push_back(c.dof);
    }
    essential = std::make_unique<EssentialBoundary>(nodeShapes, dofs, mass);
  }
  if (meshlessContact)
  {
    meshlessContact->SetEssentialBoundary(essential.get(), dofs);
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
  const Index dofCount = static_cast<Index>(u.size());
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index d = 0; d < dofCount; ++d)
  {
    uNext[d] = CentralDifferenceUpdate(u[d], uPrevious[d], f[d], ExternalForce(d, gravityFactor), inverseMass[d], alpha, beta);
  }
  TimePart(parts.essentialBoundary, [&] { ApplyConstraints(uNext.data(), curveFactors); });
  TimePart(parts.contact, [&] {
    EnforceContact(uNext.data(), inContact, inverseMass);
    if (!tools.empty())
    {
      EnforceTools(uNext.data(), u.data(), inContact, inverseMass, alpha, toolTime);
    }
  });
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
  if (!initialPenetration.empty() && step <= 2)
  {
    message << initialPenetration << ", and the first step projects them onto it however slowly the loads ramp; "
            << "make the surface clear the body (a larger skull gap, a finer mesh or surface), or ";
  }
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
  if (meshlessContact)
  {
    // The contact set of the last iteration may miss nodes that touch within
    // round-off; a free slave node carries no residual at rest, so every slave
    // reports its residual.
    for (const Index node : meshlessContact->SlaveNodes())
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
  if (!initialPenetration.empty())
  {
    result.warnings.push_back(initialPenetration + "; the first step projected them onto it (an imposed "
                                                   "displacement the model does not state)");
  }
  return result;
}


Solver::Solver(const Model & model, const SolverSettings & settings, const SolverPrecomputation * precomputed)
  : m_Impl(std::make_unique<Impl>(model, settings, precomputed))
{}

Solver::~Solver() = default;

WarmStart
WarmStartFrom(const SolveResult & result)
{
  return { result.nodalParameters.empty() ? result.displacements : result.nodalParameters };
}

void
Solver::SetWarmStart(const WarmStart & start)
{
  Impl & impl = *m_Impl;
  impl.warmState.clear();
  if (start.Empty())
  {
    return;
  }
  if (impl.settings.integrator != Integrator::DynamicRelaxation)
  {
    throw Error("a warm start is for dynamic relaxation (a steady state); explicit dynamics starts at rest");
  }
  if (start.state.size() != impl.model.nodes.size())
  {
    throw Error("the warm start has " + std::to_string(start.state.size()) + " nodes' values, the model " +
                std::to_string(impl.model.nodes.size()) + " nodes: it is the solution of another model");
  }
  impl.warmState.resize(3 * start.state.size());
  for (std::size_t n = 0; n < start.state.size(); ++n)
  {
    if (!start.state[n].allFinite())
    {
      throw Error("the warm start's value at node " + std::to_string(n) + " is not finite");
    }
    for (int i = 0; i < 3; ++i)
    {
      impl.warmState[3 * n + i] = start.state[n][i];
    }
  }
}

double
Solver::Impl::WarmStartRampFraction() const
{
  // The ramp keeps the loads from arriving faster than the body follows;
  // from a warm start only their change arrives. Body forces and tools keep
  // the whole ramp (their change is not measured here).
  constexpr double kMinimumWarmRamp = 0.1;
  if (startTargets.empty() || !gravityForce.empty() || !tools.empty())
  {
    return 1.0;
  }
  std::vector<double> fullFactors(curves.size());
  for (std::size_t k = 0; k < curves.size(); ++k)
  {
    fullFactors[k] = curves[k].Factor(1.0);
  }
  double change = 0.0, size = 0.0;
  for (std::size_t k = 0; k < constrained.size(); ++k)
  {
    const double target = constrained[k].Target(fullFactors);
    change = std::max(change, std::abs(target - startTargets[k]));
    size = std::max(size, std::abs(target));
  }
  return size > 0.0 ? std::clamp(change / size, kMinimumWarmRamp, 1.0) : 1.0;
}

SolveResult
Solver::Solve(const ProgressCallback & progress, const FrameCallback & frames)
{
  const auto  start = std::chrono::steady_clock::now();
  m_Impl->parts = SolvePartSeconds{};
  if (m_Impl->meshlessContact)
  {
    m_Impl->meshlessContact->StartSolve();
  }
  SolveResult result = m_Impl->settings.integrator == Integrator::DynamicRelaxation
                         ? m_Impl->SolveDynamicRelaxation(progress)
                         : m_Impl->SolveExplicitDynamics(progress, frames);
  result.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  result.parts = m_Impl->parts;
  result.parts.forceTableBytes = m_Impl->forces->StreamedBytesPerStep();
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
