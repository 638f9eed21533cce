// Explicit dynamics: the time-accurate central-difference integration.
#include "bmrSolverImpl.h"
#include "bmrSolverReductions.h"

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
    CheckForces(TimePart(parts.internalForces, [&] { return forces->ComputeInternalForces(u.data(), f.data()); }),
                step, true, h);
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
} // namespace bmr
