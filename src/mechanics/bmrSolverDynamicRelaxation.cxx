// Dynamic relaxation (Joldes et al. 2009/2011): the steady state of a damped
// pseudo-dynamic system with masses scaled for the largest stable step,
// damping adapted to the lowest eigenvalue's estimate, restarts with heavier
// masses, and the termination test on the estimated distance to the solution.
#include "bmrSolverImpl.h"
#include "bmrSolverReductions.h"

#include <algorithm>
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

// Dynamic relaxation's pseudo-time step (the masses are scaled to it).
constexpr double kPseudoTimeStep = 1.0;


// Damping for an estimate of the lowest eigenvalue: critical damping of that
// mode, c = omega sqrt(4 - h^2 omega^2), double root sqrt(beta).
class AdaptiveDamping
{
public:
  explicit AdaptiveDamping(double omegaMax)
    : m_OmegaMax(omegaMax)
  {
    Set(0.01 * omegaMax * omegaMax);
  }

  double
  BetaFor(double lambda) const
  {
    const double c = std::sqrt(lambda) * std::sqrt(std::max(0.0, 4.0 - m_H * m_H * lambda));
    return (2.0 - c * m_H) / (2.0 + c * m_H);
  }

  void
  Set(double lambda)
  {
    lowest = std::clamp(lambda, 1e-16 * m_OmegaMax * m_OmegaMax, m_OmegaMax * m_OmegaMax);
    const double omega = std::sqrt(lowest);
    const double c = omega * std::sqrt(std::max(0.0, 4.0 - m_H * m_H * lowest));
    alpha = 2.0 * m_H * m_H / (2.0 + c * m_H);
    beta = (2.0 - c * m_H) / (2.0 + c * m_H);
  }

  /** Damped for the smallest estimate since the loads were applied: a
   *  Rayleigh quotient is never below the lowest eigenvalue, so the smallest
   *  is the closest, and damping for a higher mode (the current estimate
   *  after a restart, a contact event or while faster modes still dominate
   *  the increment) overdamps the slowest mode, which then creeps while the
   *  error estimate declares convergence (docs/solver.md: 10 % fewer steps
   *  on Colin27). */
  void
  SetSlowest(double lambda)
  {
    slowest = std::min(slowest, lambda);
    Set(slowest);
  }

  /** After a restart with masses `massFactor` times heavier. */
  void
  Restart(double massFactor)
  {
    Set(lowest / massFactor);
    slowest /= massFactor;
  }

  double lowest = 0.0, alpha = 0.0, beta = 0.0;
  double slowest = std::numeric_limits<double>::infinity();

private:
  static constexpr double m_H = kPseudoTimeStep; // a constant: a run-time 1 changes round-off (FMA contraction)
  double                  m_OmegaMax;
};

// The state at the start of the current long span (step -1: none yet, e.g.
// before the loads were fully applied or after a restart).
struct SpanStart
{
  int                 step = -1;
  std::vector<double> u, f;
};

// Each adaptation window: damping for the Rayleigh quotient of the last
// increment, which tends to the lowest eigenvalue as the higher modes die
// out; once the loads are applied, also for the quotient of the change over
// several windows: the fast modes, which dominate one increment, have
// oscillated or died out within the span while the slow ones moved on, so it
// is closer to the slowest mode (docs/solver.md: 19 % fewer steps for the
// meshless Colin27 solve). `quotient(uTo, uFrom, fTo, fFrom)`: the secant
// Rayleigh quotient, 0 where undefined.
template <typename Quotient>
void
AdaptDamping(int step, int window, int rampEndStep, const std::vector<double> & u, const std::vector<double> & uPrevious,
             const std::vector<double> & f, const std::vector<double> & fPrevious, const Quotient & quotient,
             SpanStart & span, AdaptiveDamping & damping)
{
  const double last = quotient(u, uPrevious, f, fPrevious);
  if (last > 0.0)
  {
    damping.Set(last);
    if (step > rampEndStep)
    {
      damping.SetSlowest(damping.lowest);
    }
  }
  if (step < rampEndStep)
  {
    return;
  }
  const bool spanStarted = span.step >= rampEndStep;
  const bool spanComplete = spanStarted && step - span.step >= kLongSpanWindows * window;
  if (spanComplete)
  {
    const double spanQuotient = quotient(u, span.u, f, span.f);
    if (spanQuotient > 0.0)
    {
      damping.SetSlowest(spanQuotient);
    }
  }
  if (!spanStarted || spanComplete)
  {
    span.step = step;
    span.u = u; // copied into the vectors' storage, no allocation after the first span
    span.f = f;
  }
}

// The load ramp: the loads' curves are at Position(k) in [0, 1] at step k,
// and fully applied from step endStep on. A failure while the loads still
// ramp (a cell inverted where the body had not caught up with a fast-moving
// boundary: 25 mm shifts of Colin27) restarts with the rest of the ramp twice
// as slow, as well as with heavier masses.
struct LoadRamp
{
  explicit LoadRamp(double steps)
    : length(steps)
    , endStep(static_cast<int>(std::ceil(steps - 1e-9)))
  {}

  double
  Position(int k) const
  {
    return std::min(1.0, origin + (k - originStep) / length);
  }

  void
  SlowDownFrom(int step, double position)
  {
    origin = position;
    originStep = step;
    length *= 2.0;
    endStep = originStep + static_cast<int>(std::ceil((1.0 - origin) * length - 1e-9));
    ++slowdowns;
  }

  double origin = 0.0;
  int    originStep = 0;
  double length;
  int    endStep;
  int    slowdowns = 0;
};

// Restart points: stiffening under large deformation can outgrow the
// reference-state estimate of the largest eigenvalue. Dynamic relaxation only
// seeks the steady state, so it may restart from a good state at rest with
// heavier masses. A state that passed its checks can still be one that no
// restart survives (far out of balance, its forces move a node too far at
// once however heavy the masses): a restart that fails before reaching the
// next restart point drops the point it began from, back to the initial
// state, which is kept.
class RestartPoints
{
public:
  struct Point
  {
    std::vector<double> u;
    int                 step;
    double              rampPosition;
  };

  explicit RestartPoints(const std::vector<double> & initial)
    : m_Points{ { initial, 0, 0.0 } }
  {}

  int
  LastStep() const
  {
    return m_Points.back().step;
  }

  void
  Add(const std::vector<double> & u, int step, double rampPosition)
  {
    if (m_Points.size() > kRecentRestartPoints)
    {
      m_Points.erase(m_Points.begin() + 1);
    }
    m_Points.push_back({ u, step, rampPosition });
    m_Passed = true;
  }

  const Point &
  ForRestart()
  {
    if (!m_Passed && m_Points.size() > 1)
    {
      m_Points.pop_back();
    }
    m_Passed = false;
    return m_Points.back();
  }

private:
  std::vector<Point> m_Points;
  bool               m_Passed = true; // a point since the last restart
};

// Termination (Joldes et al. 2009): distance to the solution estimated as
// rate / (1 - rate) * ||du||_inf, with the rate the largest of the observed
// decay over one window and the theoretical rate sqrt(beta) of the current
// and of the slowest lowest-mode estimate; divergence: increments growing
// tenfold within a window.
class ConvergenceTest
{
public:
  explicit ConvergenceTest(int window)
    : window(window)
    , required(window)
  {}

  void
  Record(double incrementNorm)
  {
    m_Norms.push_back(incrementNorm);
    if (static_cast<int>(m_Norms.size()) > window + 1)
    {
      m_Norms.pop_front();
    }
  }

  bool
  WindowFull() const
  {
    return static_cast<int>(m_Norms.size()) == window + 1;
  }

  /** Growing tenfold within the window and no longer negligible (round-off
   *  and contact events near convergence may jump by large factors from tiny
   *  values). */
  bool
  Diverging(double largestIncrement, double lengthScale) const
  {
    return WindowFull() && m_Norms.back() > kGrowthLimit * m_Norms.front() &&
           largestIncrement > kSignificantIncrement * lengthScale;
  }

  /** Updates the estimate after a step whose largest increment was
   *  `largestIncrement`; true once it has stayed below the tolerance long enough. */
  bool
  Converged(double largestIncrement, const AdaptiveDamping & damping, double lengthScale, double tolerance, int maxSteps)
  {
    const double observed = m_Norms.front() > 0.0 ? std::pow(m_Norms.back() / m_Norms.front(), 1.0 / window) : 0.0;
    const double slowest = std::isfinite(damping.slowest) ? damping.BetaFor(damping.slowest) : damping.beta;
    rate = std::max(observed, std::sqrt(std::max(std::max(damping.beta, slowest), 0.0)));
    estimatedError = rate < 1.0 ? rate / (1.0 - rate) * largestIncrement : std::numeric_limits<double>::infinity();
    const bool atRest = largestIncrement <= kRoundOffIncrement * lengthScale;
    if (atRest)
    {
      // Increments of round-off have no decay rate (their ratio is noise,
      // often above 1); a state at rest to round-off is in equilibrium, as
      // any force out of balance would move it.
      estimatedError = largestIncrement;
    }
    satisfied = estimatedError < tolerance ? satisfied + 1 : 0;
    // Held for as many steps as the slowest estimated mode takes to show
    // itself: after an event that stops the body (a contact, a jump of the
    // estimate) the increments are tiny while a slow mode, at rest far from
    // its equilibrium, only starts to move again; one window was too short
    // (Colin27, meshless 4.25 mm: stopped 0.11 mm from the solution). At rest
    // to round-off any force out of balance would show at once.
    const double slowestRate = std::sqrt(std::max(slowest, 0.0));
    const int    hold = atRest || slowestRate >= 1.0
                          ? window
                          : static_cast<int>(std::min<double>(maxSteps, std::ceil(1.0 / (1.0 - slowestRate))));
    required = std::max(window, hold);
    return satisfied >= required;
  }

  void
  Restart()
  {
    m_Norms.clear();
    satisfied = 0;
  }

  const int window;
  double    estimatedError = std::numeric_limits<double>::infinity();
  double    rate = 1.0;
  int       satisfied = 0;
  int       required; // steps the estimate must stay below the tolerance

private:
  std::deque<double> m_Norms; // last window + 1 values of ||du||_2
};

// The result's message: converged, or why not and where it still moves.
std::string
RelaxationMessage(bool converged, const ConvergenceTest & test, double tolerance, int steps,
                  const std::vector<double> & u, const std::vector<double> & uPrevious,
                  const std::vector<Vector3> & nodes, const std::vector<char> & inContact, int restarts,
                  int rampSlowdowns)
{
  std::ostringstream message;
  if (converged)
  {
    message << "converged: estimated error " << test.estimatedError << " mm < tolerance " << tolerance << " mm";
  }
  else
  {
    message << "NOT CONVERGED: estimated error " << test.estimatedError << " mm after " << steps << " steps is ";
    if (test.estimatedError < tolerance)
    {
      message << "below the tolerance " << tolerance << " mm, but only for the last " << test.satisfied
              << " steps; the convergence test requires " << test.required << " in a row ("
              << (test.required > test.window
                    ? "the slowest mode's e-folding time: a stopped slow mode shows in the increments only after it"
                    : "adapt_interval")
              << "). Increase max_steps; an estimate that keeps crossing the tolerance points at an oscillation "
                 "the damping does not reach (e.g. in contact).";
    }
    else
    {
      message << "above the tolerance " << tolerance
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
    const Vector3 & at = nodes[node];
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
  return message.str();
}

// Rayleigh quotient of K (the secant stiffness between two states) for their
// displacement difference, over the free dofs; 0 where undefined.
struct SecantRayleighQuotient
{
  const std::vector<char> &   dofConstrained;
  const std::vector<double> & mass; // per node
  int                         threads;

  double
  operator()(const std::vector<double> & uTo, const std::vector<double> & uFrom, const std::vector<double> & fTo,
             const std::vector<double> & fFrom) const
  {
    const Index  dofCount = static_cast<Index>(uTo.size());
    const double numerator = DeterministicSum(dofCount, threads, [&](Index d) {
      return dofConstrained[d] ? 0.0 : (uTo[d] - uFrom[d]) * (fTo[d] - fFrom[d]);
    });
    const double denominator = DeterministicSum(dofCount, threads, [&](Index d) {
      const double du = uTo[d] - uFrom[d];
      return dofConstrained[d] ? 0.0 : mass[d / 3] * du * du;
    });
    return numerator > 0.0 && denominator > 0.0 ? numerator / denominator : 0.0;
  }
};

[[noreturn]] void
ThrowDiverged(int step, int window)
{
  std::ostringstream message;
  message << "dynamic relaxation diverged at " << StepLabel(step) << ": the displacement increments grew " << kGrowthLimit
          << "-fold within " << window
          << " steps. Likely cause: stiffening beyond the time-step estimate (lower safety_factor).";
  throw SolveError(message.str(), step, -1);
}

[[noreturn]] void
ThrowRestartsExhausted(const SolveError & firstFailure, int rampSlowdowns)
{
  // The first failure names the cell or node where it started.
  throw SolveError(std::string(firstFailure.what()) + " Restarting " + std::to_string(kMaxRestarts) +
                     " times from earlier good states with heavier masses" +
                     (rampSlowdowns > 0
                        ? " and a load ramp up to " + std::to_string(1 << rampSlowdowns) + " times slower"
                        : std::string()) +
                     " did not help.",
                   firstFailure.Step(), firstFailure.Element());
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
  constexpr double    h = kPseudoTimeStep;
  const double        omegaMax = 2.0 * settings.timeStepSafetyFactor / h;
  const Index         dofCount = static_cast<Index>(3 * model.nodes.size());
  std::vector<double> mass = RelaxationMasses(omegaMax); // scaled at restarts

  std::vector<double> u(dofCount, 0.0), uPrevious(dofCount, 0.0), uNext(dofCount, 0.0);
  std::vector<double> f(dofCount, 0.0), fPrevious(dofCount, 0.0), inverseMass(dofCount);
  auto                invertMasses = [&] {
    for (Index d = 0; d < dofCount; ++d)
    {
      inverseMass[d] = 1.0 / mass[d / 3];
    }
  };
  invertMasses();
  PrepareEssentialBoundary(mass);
  StartFromWarmState(u, uPrevious, h);
  std::vector<char>   inContact(model.nodes.size(), 0);
  std::vector<double> curveFactors(curves.size(), 0.0);
  // Without contact, tools or EBCIEM's projection, the constraints are values
  // per dof and the update can be fused with them and with the increment's measure.
  const bool fusedUpdate = !essential && model.contactSurfaces.empty() && tools.empty();
  dofTargets.assign(fusedUpdate ? dofConstrained.size() : 0, 0.0);

  AdaptiveDamping damping(omegaMax);
  SpanStart       spanStart;
  const int       window = settings.adaptInterval;
  ConvergenceTest test(window);
  LoadRamp        ramp(settings.loadSteps * WarmStartRampFraction());
  RestartPoints   restartPoints(u);
  auto loadFactor = [&](const LoadCurve & curve, int k) { return curve.Factor(ramp.Position(k)); };
  const SecantRayleighQuotient secantRayleighQuotient{ dofConstrained, mass, threads };
  int                         step = 0;
  bool                        converged = false;
  double                      gravityFactor = 0.0;
  int                         restarts = 0;
  std::unique_ptr<SolveError> firstFailure;

  for (step = 0; step < settings.maxSteps; ++step)
  {
    try
    {
      CheckForces(TimePart(parts.internalForces, [&] { return forces->ComputeInternalForces(u.data(), f.data()); }),
                  step, false, h);
      if (step > 0 && step % window == 0)
      {
        AdaptDamping(step, window, ramp.endStep, u, uPrevious, f, fPrevious, secantRayleighQuotient, spanStart, damping);
      }
      gravityFactor = gravityForce.empty() ? 0.0 : loadFactor(model.bodyForceCurve, step);
      for (std::size_t k = 0; k < curves.size(); ++k)
      {
        curveFactors[k] = loadFactor(curves[k], step + 1);
      }
      startForceWeight = 1.0 - LoadCurve{}.Factor(ramp.Position(step));
      startTargetWeight = 1.0 - LoadCurve{}.Factor(ramp.Position(step + 1));
      const IncrementStatistics increment =
        RelaxationStep(fusedUpdate, u, uPrevious, f, inverseMass, damping.alpha, damping.beta, gravityFactor,
                       curveFactors, uNext, inContact, LoadCurve{}.Factor(ramp.Position(step + 1)));
      CheckIncrement(uNext, u, increment.firstBad, step, false, h);
      test.Record(increment.norm);
      if (step + 1 > ramp.endStep && test.Diverging(increment.maxAbs, lengthScale))
      {
        ThrowDiverged(step, window);
      }
      // A restart point is a state whose forces had no inverted unit and whose
      // increment was bounded. Saved before its forces were checked, it was
      // the state about to invert in the 25 mm truth of Colin27 on
      // Morton-numbered tetrahedra, and all six restarts failed at once.
      if (step > restartPoints.LastStep() && step % window == 0)
      {
        restartPoints.Add(u, step, ramp.Position(step));
      }
      std::swap(uPrevious, u);
      std::swap(u, uNext);
      std::swap(f, fPrevious);
      if (!fusedUpdate)
      {
        ForgetProjectionVelocities(u, uPrevious);
      }
      if (step + 1 >= ramp.endStep && test.WindowFull() &&
          test.Converged(increment.maxAbs, damping, lengthScale, settings.tolerance, settings.maxSteps))
      {
        converged = true;
        ++step;
        break;
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
        ThrowRestartsExhausted(*firstFailure, ramp.slowdowns);
      }
      ++restarts;
      const RestartPoints::Point & from = restartPoints.ForRestart();
      if (from.step < ramp.endStep)
      {
        ramp.SlowDownFrom(from.step, from.rampPosition);
      }
      for (double & m : mass)
      {
        m *= kRestartMassFactor;
      }
      invertMasses();
      PrepareEssentialBoundary(mass); // its projection does not change, but the contact's use of it must see the masses
      damping.Restart(kRestartMassFactor);
      u = from.u;
      uPrevious = from.u;
      step = from.step - 1;
      test.Restart();
      spanStart.step = -1;
      continue;
    }
    if (progress && (step + 1) % 200 == 0)
    {
      progress(step + 1, -1.0, test.estimatedError);
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
  result.lowestEigenvalue =
    (std::isfinite(damping.slowest) ? damping.slowest : damping.lowest) * std::pow(kRestartMassFactor, restarts);
  result.estimatedError = test.estimatedError;
  result.convergenceRate = test.rate;
  result.restarts = restarts;
  result.message = RelaxationMessage(converged, test, settings.tolerance, step, u, uPrevious, model.nodes, inContact,
                                     restarts, ramp.slowdowns);
  return result;
}

IncrementStatistics
Solver::Impl::RelaxationStep(bool fused, const std::vector<double> & u, const std::vector<double> & uPrevious,
                             const std::vector<double> & f, const std::vector<double> & inverseMass, double alpha,
                             double beta, double gravityFactor, const std::vector<double> & curveFactors,
                             std::vector<double> & uNext, std::vector<char> & inContact, double toolTime)
{
  const Index dofCount = static_cast<Index>(u.size());
  if (fused)
  {
    // Update, constraints and the increment's size in one pass over the dofs
    // (one parallel region instead of two, u read once): nothing moves the
    // dofs between them.
    for (std::size_t k = 0; k < constrained.size(); ++k)
    {
      dofTargets[constrained[k].dof] = ConstraintTarget(k, curveFactors);
    }
    return MeasureIncrements(dofCount, dofConstrained, lengthScale, threads, [&](Index d) {
      uNext[d] = dofConstrained[d] ? dofTargets[d]
                                   : CentralDifferenceUpdate(u[d], uPrevious[d], f[d], ExternalForce(d, gravityFactor),
                                                             inverseMass[d], alpha, beta);
      return std::abs(uNext[d] - u[d]);
    });
  }
  CentralDifferenceStep(u, uPrevious, f, inverseMass, alpha, beta, gravityFactor, curveFactors, uNext, inContact,
                        toolTime);
  return MeasureIncrement(uNext, u, dofConstrained, lengthScale, threads);
}

std::vector<double>
Solver::Impl::RelaxationMasses(double omegaMax)
{
  constexpr double h = kPseudoTimeStep;
  // Masses scaled cell by cell to the cells' stiffness, which preconditions
  // the iteration by the local stiffness (stiffness contrasts and graded
  // meshes cost nothing extra). The element bound on the largest eigenvalue
  // is pessimistic for an assembled mesh (2 to 4 times), so the masses are
  // then scaled globally to a power-iteration estimate of it: fewer steps for
  // the same stability margin (safety_factor).
  const double safety = settings.timeStepSafetyFactor;
  // The global scale comes from the reference state's masses; it is then
  // applied to the masses made for the collapse barrier's stiffness, which
  // the reference state does not show (in a body of soft cells alone the
  // estimate would otherwise scale the barrier's masses away).
  std::vector<double> mass = forces->ScaledMasses(h, 1.0, false); // element bound: omega_max <= 2
  const double        boundScale = 1.0 / (safety * safety);
  const double        largest = LargestEigenvalueEstimate(mass);
  const double massScale = std::clamp(kEigenvalueMargin * largest / (omegaMax * omegaMax), 1e-3 * boundScale, boundScale);
  mass = forces->ScaledMasses(h, 1.0, true);
  for (double & m : mass)
  {
    m *= massScale;
  }
  return mass;
}

void
Solver::Impl::StartFromWarmState(std::vector<double> & u, std::vector<double> & uPrevious, double h)
{
  startForces.clear();
  startTargets.clear();
  if (warmState.empty())
  {
    return;
  }
  // At rest in the warm state, under the loads it balances (its internal
  // forces; at constrained dofs their values in it): those fade out with the
  // ramp as the model's loads fade in.
  u = warmState;
  uPrevious = warmState;
  startForces.resize(static_cast<std::size_t>(3 * model.nodes.size()));
  CheckForces(forces->ComputeInternalForces(u.data(), startForces.data()), 0, false, h);
  const std::vector<double> physical = PhysicalDisplacements(u);
  startTargets.resize(constrained.size());
  for (std::size_t k = 0; k < constrained.size(); ++k)
  {
    startTargets[k] = physical[constrained[k].dof];
  }
}

} // namespace bmr
