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

namespace
{

// Dynamic relaxation: power iterations for the largest eigenvalue, the margin
// put on that estimate, the increment growth over one adaptation window that
// counts as divergence, and the restarts allowed, each with masses this much heavier.
constexpr int    kPowerIterations = 30;
constexpr double kEigenvalueMargin = 1.1;
constexpr double kGrowthLimit = 10.0;
constexpr double kSignificantIncrement = 1e-4; // of the body's size
constexpr double kRoundOffIncrement = 1e-12;   // of the body's size: a state at rest to round-off
constexpr int    kMaxRestarts = 6;
constexpr double kRestartMassFactor = 2.0;
// Restart points kept besides the initial state: a restart that fails again
// before passing a new one falls back to the one before.
constexpr std::size_t kRecentRestartPoints = 3;
// Adaptation windows spanned by the second lowest-eigenvalue estimate, the
// Rayleigh quotient of the displacement change over that span.
constexpr int kLongSpanWindows = 5;

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

// `increment(d)` returns |du| of dof d (and may write the dof's new value):
// fixed blocks, so the sums do not depend on the number of threads.
template <typename Increment>
IncrementStatistics
MeasureIncrements(Index count, const std::vector<char> & constrained, double limit, int threads, const Increment & increment)
{
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
      const double du = increment(d);
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

IncrementStatistics
MeasureIncrement(const std::vector<double> & next,
                 const std::vector<double> & current,
                 const std::vector<char> &   constrained,
                 double                      limit,
                 int                         threads)
{
  return MeasureIncrements(static_cast<Index>(next.size()), constrained, limit, threads,
                           [&](Index d) { return std::abs(next[d] - current[d]); });
}
} // namespace

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
  // The global scale comes from the reference state's masses; it is then
  // applied to the masses made for the collapse barrier's stiffness, which
  // the reference state does not show (in a body of soft cells alone the
  // estimate would otherwise scale the barrier's masses away).
  std::vector<double> mass = forces->ScaledMasses(h, 1.0, false); // element bound: omega_max <= 2
  const double        boundScale = 1.0 / (safety * safety);
  const double        largest = LargestEigenvalueEstimate(mass);
  const double massScale = std::clamp(kEigenvalueMargin * largest / (omegaMax * omegaMax), 1e-3 * boundScale, boundScale);
  mass = forces->ScaledMasses(h, 1.0, true);

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
  PrepareEssentialBoundary(mass);
  startForces.clear();
  startTargets.clear();
  if (!warmState.empty())
  {
    // At rest in the warm state, under the loads it balances (its internal
    // forces; at constrained dofs their values in it): those fade out with
    // the ramp as the model's loads fade in.
    u = warmState;
    uPrevious = warmState;
    startForces.resize(dofCount);
    CheckForces(forces->ComputeInternalForces(u.data(), startForces.data()), 0, false, h);
    const std::vector<double> physical = PhysicalDisplacements(u);
    startTargets.resize(constrained.size());
    for (std::size_t k = 0; k < constrained.size(); ++k)
    {
      startTargets[k] = physical[constrained[k].dof];
    }
  }
  std::vector<char>   inContact(model.nodes.size(), 0);
  std::vector<double> curveFactors(curves.size(), 0.0);
  // Without contact, tools or EBCIEM's projection, the constraints are values
  // per dof and the update can be fused with them and with the increment's measure.
  const bool fusedUpdate = !essential && model.contactSurfaces.empty() && tools.empty();
  dofTargets.assign(fusedUpdate ? dofConstrained.size() : 0, 0.0);

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
  // damping and the error estimate use it, as the current estimate can jump
  // up (to the higher modes that dominate right after a restart or a contact
  // event), and would then overdamp the slowest mode and declare convergence
  // while it still creeps.
  double slowestEigenvalue = std::numeric_limits<double>::infinity();

  const int          window = settings.adaptInterval;
  std::deque<double> incrementNorms; // last window + 1 values of ||du||_2
  double             estimatedError = std::numeric_limits<double>::infinity();
  double             rate = 1.0;
  int                satisfied = 0;
  int                required = window; // steps the estimate must stay below the tolerance
  int                step = 0;
  bool               converged = false;
  double             gravityFactor = 0.0;
  int                restarts = 0;
  // The load ramp: the loads' curves are at rampPosition(k) in [0, 1] at step
  // k, and fully applied from step rampEndStep on. A failure while the loads
  // still ramp (a cell inverted where the body had not caught up with a
  // fast-moving boundary: 25 mm shifts of Colin27) restarts with the rest of
  // the ramp twice as slow, as well as with heavier masses.
  double rampOrigin = 0.0;
  int    rampOriginStep = 0;
  double rampLength = settings.loadSteps * WarmStartRampFraction();
  int    rampEndStep = static_cast<int>(std::ceil(rampLength - 1e-9));
  int    rampSlowdowns = 0;
  auto   rampPosition = [&](int k) { return std::min(1.0, rampOrigin + (k - rampOriginStep) / rampLength); };
  auto   loadFactor = [&](const LoadCurve & curve, int k) { return curve.Factor(rampPosition(k)); };

  // Restart points: stiffening under large deformation can outgrow the
  // reference-state estimate of the largest eigenvalue. Dynamic relaxation
  // only seeks the steady state, so it may restart from a good state at rest
  // with heavier masses. A state that passed its checks can still be one that
  // no restart survives (far out of balance, its forces move a node too far
  // at once however heavy the masses): a restart that fails before reaching
  // the next restart point drops the point it began from, back to the initial
  // state, which is kept.
  struct RestartPoint
  {
    std::vector<double> u;
    int                 step;
    double              rampPosition;
  };
  std::vector<RestartPoint>   restartPoints{ { u, 0, 0.0 } };

  // Rayleigh quotient of K (the secant stiffness between two states) for
  // their displacement difference, over the free dofs; 0 where undefined.
  auto secantRayleighQuotient = [&](const std::vector<double> & uTo, const std::vector<double> & uFrom,
                                    const std::vector<double> & fTo, const std::vector<double> & fFrom) {
    const double numerator = DeterministicSum(dofCount, threads, [&](Index d) {
      return dofConstrained[d] ? 0.0 : (uTo[d] - uFrom[d]) * (fTo[d] - fFrom[d]);
    });
    const double denominator = DeterministicSum(dofCount, threads, [&](Index d) {
      const double du = uTo[d] - uFrom[d];
      return dofConstrained[d] ? 0.0 : mass[d / 3] * du * du;
    });
    return numerator > 0.0 && denominator > 0.0 ? numerator / denominator : 0.0;
  };
  // The state at the start of the current span (a step before the loads were
  // fully applied, or before a restart, means none).
  struct SpanStart
  {
    int                 step;
    std::vector<double> u, f;
  } spanStart{ -1, {}, {} };
  bool                        passedRestartPoint = true; // since the last restart
  std::unique_ptr<SolveError> firstFailure;

  for (step = 0; step < settings.maxSteps; ++step)
  {
    try
    {
      CheckForces(TimePart(parts.internalForces, [&] { return forces->ComputeInternalForces(u.data(), f.data()); }),
                  step, false, h);
      if (step > 0 && step % window == 0)
      {
        // Rayleigh quotient of the last increment: tends to the lowest eigenvalue
        // as the higher modes die out.
        const double quotient = secantRayleighQuotient(u, uPrevious, f, fPrevious);
        if (quotient > 0.0)
        {
          setDamping(quotient);
          if (step > rampEndStep)
          {
            // Damped for the smallest estimate since the loads were applied:
            // a Rayleigh quotient is never below the lowest eigenvalue, so the
            // smallest is the closest, and damping for a higher mode (the
            // current estimate after a contact event or while faster modes
            // still dominate the increment) overdamps the slowest mode, which
            // then creeps (docs/solver.md: 10 % fewer steps on Colin27).
            slowestEigenvalue = std::min(slowestEigenvalue, lowestEigenvalue);
            setDamping(slowestEigenvalue);
          }
        }
        if (step >= rampEndStep)
        {
          // The same quotient of the change over several windows: the fast
          // modes, which dominate one increment, have oscillated or died out
          // within the span while the slow ones moved on, so it is closer to
          // the slowest mode (docs/solver.md: 19 % fewer steps for the
          // meshless Colin27 solve).
          const bool spanStarted = spanStart.step >= rampEndStep;
          const bool spanComplete = spanStarted && step - spanStart.step >= kLongSpanWindows * window;
          if (spanComplete)
          {
            const double spanQuotient = secantRayleighQuotient(u, spanStart.u, f, spanStart.f);
            if (spanQuotient > 0.0)
            {
              slowestEigenvalue = std::min(slowestEigenvalue, spanQuotient);
              setDamping(slowestEigenvalue);
            }
          }
          if (!spanStarted || spanComplete)
          {
            spanStart.step = step;
            spanStart.u = u; // copied into the vectors' storage, no allocation after the first span
            spanStart.f = f;
          }
        }
      }

      gravityFactor = gravityForce.empty() ? 0.0 : loadFactor(model.bodyForceCurve, step);
      for (std::size_t k = 0; k < curves.size(); ++k)
      {
        curveFactors[k] = loadFactor(curves[k], step + 1);
      }
      startForceWeight = 1.0 - LoadCurve{}.Factor(rampPosition(step));
      startTargetWeight = 1.0 - LoadCurve{}.Factor(rampPosition(step + 1));
      IncrementStatistics increment;
      if (fusedUpdate)
      {
        // Update, constraints and the increment's size in one pass over the
        // dofs (one parallel region instead of two, u read once): nothing
        // moves the dofs between them.
        for (std::size_t k = 0; k < constrained.size(); ++k)
        {
          dofTargets[constrained[k].dof] = ConstraintTarget(k, curveFactors);
        }
        increment = MeasureIncrements(dofCount, dofConstrained, lengthScale, threads, [&](Index d) {
          uNext[d] = dofConstrained[d] ? dofTargets[d]
                                       : CentralDifferenceUpdate(u[d], uPrevious[d], f[d], ExternalForce(d, gravityFactor),
                                                                 inverseMass[d], alpha, beta);
          return std::abs(uNext[d] - u[d]);
        });
      }
      else
      {
        CentralDifferenceStep(u, uPrevious, f, inverseMass, alpha, beta, gravityFactor, curveFactors, uNext, inContact,
                              LoadCurve{}.Factor(rampPosition(step + 1)));
        increment = MeasureIncrement(uNext, u, dofConstrained, lengthScale, threads);
      }
      CheckIncrement(uNext, u, increment.firstBad, step, false, h);
      incrementNorms.push_back(increment.norm);
      if (static_cast<int>(incrementNorms.size()) > window + 1)
      {
        incrementNorms.pop_front();
      }
      // Divergence: increments growing tenfold within a window once the loads
      // are applied, and no longer negligible (round-off and contact events
      // near convergence may jump by large factors from tiny values).
      if (step + 1 > rampEndStep && static_cast<int>(incrementNorms.size()) == window + 1 &&
          incrementNorms.back() > kGrowthLimit * incrementNorms.front() &&
          increment.maxAbs > kSignificantIncrement * lengthScale)
      {
        std::ostringstream message;
        message << "dynamic relaxation diverged at " << StepLabel(step) << ": the displacement increments grew "
                << kGrowthLimit << "-fold within " << window
                << " steps. Likely cause: stiffening beyond the time-step estimate (lower safety_factor).";
        throw SolveError(message.str(), step, -1);
      }
      // A restart point is a state whose forces had no inverted unit and whose
      // increment was bounded. Saved before its forces were checked, it was
      // the state about to invert in the 25 mm truth of Colin27 on
      // Morton-numbered tetrahedra, and all six restarts failed at once.
      if (step > restartPoints.back().step && step % window == 0)
      {
        if (restartPoints.size() > kRecentRestartPoints)
        {
          restartPoints.erase(restartPoints.begin() + 1);
        }
        restartPoints.push_back({ u, step, rampPosition(step) });
        passedRestartPoint = true;
      }
      std::swap(uPrevious, u);
      std::swap(u, uNext);
      std::swap(f, fPrevious);
      if (!fusedUpdate)
      {
        ForgetProjectionVelocities(u, uPrevious);
      }

      // Termination (Joldes et al. 2009): distance to the solution estimated as
      // rate / (1 - rate) * ||du||_inf, with the rate the largest of the observed
      // decay and the theoretical rate sqrt(beta) of the current and of the
      // slowest lowest-mode estimate.
      if (step + 1 >= rampEndStep && static_cast<int>(incrementNorms.size()) == window + 1)
      {
        const double observed = incrementNorms.front() > 0.0
                                  ? std::pow(incrementNorms.back() / incrementNorms.front(), 1.0 / window)
                                  : 0.0;
        const double slowest = std::isfinite(slowestEigenvalue) ? betaFor(slowestEigenvalue) : beta;
        rate = std::max(observed, std::sqrt(std::max(std::max(beta, slowest), 0.0)));
        estimatedError = rate < 1.0 ? rate / (1.0 - rate) * increment.maxAbs : std::numeric_limits<double>::infinity();
        const bool atRest = increment.maxAbs <= kRoundOffIncrement * lengthScale;
        if (atRest)
        {
          // Increments of round-off have no decay rate (their ratio is noise,
          // often above 1); a state at rest to round-off is in equilibrium,
          // as any force out of balance would move it.
          estimatedError = increment.maxAbs;
        }
        satisfied = estimatedError < settings.tolerance ? satisfied + 1 : 0;
        // Held for as many steps as the slowest estimated mode takes to show
        // itself: after an event that stops the body (a contact, a jump of the
        // estimate) the increments are tiny while a slow mode, at rest far from
        // its equilibrium, only starts to move again; one window was too short
        // (Colin27, meshless 4.25 mm: stopped 0.11 mm from the solution). At
        // rest to round-off any force out of balance would show at once.
        const double slowestRate = std::sqrt(std::max(slowest, 0.0));
        const int    hold = atRest || slowestRate >= 1.0
                              ? window
                              : static_cast<int>(std::min<double>(settings.maxSteps, std::ceil(1.0 / (1.0 - slowestRate))));
        required = std::max(window, hold);
        if (satisfied >= required)
        {
          converged = true;
          ++step;
          break;
        }
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
                           " times from earlier good states with heavier masses" +
                           (rampSlowdowns > 0 ? " and a load ramp up to " + std::to_string(1 << rampSlowdowns) +
                                                  " times slower"
                                              : std::string()) +
                           " did not help.",
                         firstFailure->Step(), firstFailure->Element());
      }
      ++restarts;
      if (!passedRestartPoint && restartPoints.size() > 1)
      {
        restartPoints.pop_back();
      }
      passedRestartPoint = false;
      const RestartPoint & from = restartPoints.back();
      if (from.step < rampEndStep)
      {
        rampOrigin = from.rampPosition;
        rampOriginStep = from.step;
        rampLength *= 2.0;
        rampEndStep = rampOriginStep + static_cast<int>(std::ceil((1.0 - rampOrigin) * rampLength - 1e-9));
        ++rampSlowdowns;
      }
      scaleMasses(kRestartMassFactor);
      PrepareEssentialBoundary(mass); // its projection does not change, but the contact's use of it must see the masses
      setDamping(lowestEigenvalue / kRestartMassFactor);
      slowestEigenvalue /= kRestartMassFactor;
      u = from.u;
      uPrevious = from.u;
      step = from.step - 1;
      incrementNorms.clear();
      satisfied = 0;
      spanStart.step = -1;
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
  result.warmStarted = !warmState.empty();
  // For the masses before the restarts, each of which made them heavier.
  result.lowestEigenvalue = (std::isfinite(slowestEigenvalue) ? slowestEigenvalue : lowestEigenvalue) *
                            std::pow(kRestartMassFactor, restarts);
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
    message << "NOT CONVERGED: estimated error " << estimatedError << " mm after " << step << " steps is ";
    if (estimatedError < settings.tolerance)
    {
      message << "below the tolerance " << settings.tolerance << " mm, but only for the last " << satisfied
              << " steps; the convergence test requires " << required << " in a row ("
              << (required > window ? "the slowest mode's e-folding time: a stopped slow mode shows in the increments only after it"
                                    : "adapt_interval")
              << "). Increase max_steps; an estimate that keeps crossing the tolerance points at an oscillation "
                 "the damping does not reach (e.g. in contact).";
    }
    else
    {
      message << "above the tolerance " << settings.tolerance
              << " mm. Increase max_steps, loosen the tolerance, or check that the model is constrained "
                 "against rigid-body motion.";
    }
    // Where it still moves: the first thing to look at.
    std::size_t moving = 0;
    for (std::size_t d = 1; d < u.size(); ++d)
    {
      if (std::abs(u[d] - uPrevious[d]) > std::abs(u[moving] - uPrevious[moving]))
      {
        moving = d;
      }
    }
    const auto      node = static_cast<Index>(moving / 3);
    const Vector3 & at = model.nodes[node];
    message << " It moves most at node " << node << " (" << at.x() << ", " << at.y() << ", " << at.z() << " mm), "
            << std::abs(u[moving] - uPrevious[moving]) << " mm in the last step"
            << (inContact[node] ? ", in contact with a surface: a contact that opens and closes from step to step "
                                  "(e.g. at a crease of the surface) does not settle"
                                : "")
            << ".";
  }
  if (restarts > 0)
  {
    message << " (" << restarts << " restart(s) with heavier masses after the deformation stiffened the model";
    if (rampSlowdowns > 0)
    {
      message << ", " << rampSlowdowns << " of them with a load ramp twice as slow";
    }
    message << ")";
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
