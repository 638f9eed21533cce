// Time accuracy of the explicit central-difference integrator: exact free fall,
// and the vibration of a laterally constrained bar against the modal solution
// of the same discrete system.
#include "bmrTestUtilities.h"

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include <cmath>

namespace bmr
{
namespace
{
using namespace bmr::test;

// The discrete chain of a bar of hexahedral layers held laterally (one-dimensional
// strain), fixed at x = 0, in SI units: layer stiffness (lambda + 2 mu) A / dx and
// lumped layer masses; unknowns are the layers 1..n.
struct BarChain
{
  Eigen::MatrixXd K, M;

  BarChain(int layers, double length, double side, double youngs, double poisson, double density)
    : K(Eigen::MatrixXd::Zero(layers, layers))
    , M(Eigen::MatrixXd::Zero(layers, layers))
  {
    const double pWaveModulus = youngs * (1.0 - poisson) / ((1.0 + poisson) * (1.0 - 2.0 * poisson)); // Pa
    const double area = side * side * 1e-6, dx = length / layers * 1e-3;                             // m^2, m
    const double k = pWaveModulus * area / dx;
    for (int i = 0; i < layers; ++i)
    {
      K(i, i) += k;
      if (i + 1 < layers)
      {
        K(i, i) += k;
        K(i, i + 1) = K(i + 1, i) = -k;
      }
      M(i, i) = density * area * dx * (i + 1 < layers ? 1.0 : 0.5);
    }
  }
};

// An unconstrained block under a suddenly applied gravity translates rigidly:
// u = g t^2 / 2 at every node and v = g T at the end (central differences are
// exact for constant acceleration when started at rest at t = 0).
TEST(ExplicitDynamics, FreeFallIsExact)
{
  Model model = MakeBlockMesh(Vector3(10.0, 10.0, 10.0), { 2, 2, 2 }, GridCells::Mixed, MakeMaterial(3000.0, 0.45));
  model.bodyAcceleration = Vector3(0.0, 0.0, -9810.0); // mm/s^2
  model.bodyForceCurve.shape = LoadCurve::Shape::Step;
  SolverSettings settings;
  settings.integrator = Integrator::ExplicitDynamics;
  settings.endTime = 0.02;
  settings.threads = 1;
  Solver            solver(model, settings);
  const SolveResult result = solver.Solve();

  const double T = settings.endTime;
  const double drop = 0.5 * 9810.0 * T * T; // mm
  for (const Vector3 & u : result.displacements)
  {
    EXPECT_NEAR(u.x(), 0.0, 1e-12);
    EXPECT_NEAR(u.y(), 0.0, 1e-12);
    EXPECT_NEAR(u.z(), -drop, 1e-9 * drop);
  }
  const double mass = 1000.0 * 1e-6;                            // kg: 1000 kg/m^3 x 1000 mm^3
  const double speed = 9.81 * T;                                // m/s
  EXPECT_NEAR(result.kineticEnergy, 0.5 * mass * speed * speed, 1e-9 * 0.5 * mass * speed * speed);
  EXPECT_LT(result.strainEnergy, 1e-12);
}

// A bar 40 x 2 x 2 mm of 8 hexahedra, x = 0 held, every node held laterally
// (one-dimensional strain), suddenly loaded by a small axial body force: a
// chain of 8 masses and springs, whose exact motion is the modal sum
// u(t) = sum_i phi_i (phi_i^T M g / w_i^2) (1 - cos w_i t). The strain stays
// near 1e-4, so the neo-Hookean bar is linear to about that order.
TEST(ExplicitDynamics, BarVibrationMatchesModalSolution)
{
  constexpr int    layers = 8;
  constexpr double length = 40.0, side = 2.0, youngs = 3000.0, poisson = 0.3, density = 1000.0;
  constexpr double gravity = 9.81; // mm/s^2, along +x
  Model model = MakeBlockMesh(Vector3(length, side, side), { layers, 1, 1 }, GridCells::Hexahedra,
                              MakeMaterial(youngs, poisson, density));
  model.fixedConstraints.push_back({ "xmin", { true, true, true } });
  model.fixedConstraints.push_back({ "all", { false, true, true } });
  model.bodyAcceleration = Vector3(gravity, 0.0, 0.0);
  model.bodyForceCurve.shape = LoadCurve::Shape::Step;

  const BarChain          chain(layers, length, side, youngs, poisson, density);
  const Eigen::MatrixXd & K = chain.K;
  const Eigen::MatrixXd & M = chain.M;
  const Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::MatrixXd> modes(K, M);
  const Eigen::VectorXd load = M * Eigen::VectorXd::Constant(layers, gravity * 1e-3); // N
  const double          periodOfFirstMode = 2.0 * M_PI / std::sqrt(modes.eigenvalues()(0));

  for (const double fraction : { 0.3, 0.75 })
  {
    SolverSettings settings;
    settings.integrator = Integrator::ExplicitDynamics;
    settings.endTime = fraction * periodOfFirstMode;
    settings.threads = 1;
    Solver solver(model, settings);
    settings.timeStep = solver.CriticalTimeStep() / 20.0; // small phase error of the central difference
    Solver            accurate(model, settings);
    const SolveResult result = accurate.Solve();

    Eigen::VectorXd exact = Eigen::VectorXd::Zero(layers);
    for (int i = 0; i < layers; ++i)
    {
      const Eigen::VectorXd phi = modes.eigenvectors().col(i); // M-normalised
      const double          w2 = modes.eigenvalues()(i);
      exact += phi * (phi.dot(load) / w2) * (1.0 - std::cos(std::sqrt(w2) * settings.endTime));
    }
    exact *= 1e3; // mm
    const double scale = exact.cwiseAbs().maxCoeff();
    ASSERT_GT(scale, 0.0);
    for (std::size_t n = 0; n < model.nodes.size(); ++n)
    {
      const int layer = static_cast<int>(std::lround(model.nodes[n].x() / (length / layers)));
      const double expected = layer == 0 ? 0.0 : exact(layer - 1);
      EXPECT_NEAR(result.displacements[n].x(), expected, 2e-3 * scale)
        << "node " << n << " at t = " << settings.endTime << " s";
      EXPECT_EQ(result.displacements[n].y(), 0.0);
    }
  }
}

// CSF drainage: with a fluid surface, only the nodes above it (against gravity)
// carry their weight. The bar above, standing on its held end x = 0 with a small
// gravity along -x, its lower two thirds still buoyed: the static dynamic-relaxation
// solution matches the discrete chain loaded on the upper layers only,
// u = K^-1 f (strain about 1e-4, so the neo-Hookean bar is linear to that
// order); loading every layer would nearly double the top's displacement.
TEST(DynamicRelaxation, GravityActsOnlyAboveTheFluidSurface)
{
  constexpr int    layers = 8;
  constexpr double length = 40.0, side = 2.0, youngs = 3000.0, poisson = 0.3, density = 1000.0;
  constexpr double gravity = 10.0, level = 27.5; // mm/s^2 along -x; mm, between the layers at 25 and 30
  Model model = MakeBlockMesh(Vector3(length, side, side), { layers, 1, 1 }, GridCells::Hexahedra,
                              MakeMaterial(youngs, poisson, density));
  model.fixedConstraints.push_back({ "xmin", { true, true, true } });
  model.fixedConstraints.push_back({ "all", { false, true, true } });
  model.bodyAcceleration = Vector3(-gravity, 0.0, 0.0);
  model.fluidSurface = Vector3(level, 5.0, -3.0); // any point of the level plane x = 27.5

  SolverSettings settings;
  settings.tolerance = 1e-9;
  settings.threads = 1;
  const SolveResult result = Solver(model, settings).Solve();
  ASSERT_TRUE(result.converged) << result.message;

  const BarChain  chain(layers, length, side, youngs, poisson, density);
  Eigen::VectorXd drained(layers), full(layers);
  for (int i = 0; i < layers; ++i)
  {
    const double x = (i + 1) * length / layers;
    full(i) = -chain.M(i, i) * gravity * 1e-3; // N
    drained(i) = x > level ? full(i) : 0.0;
  }
  const Eigen::VectorXd expected = chain.K.ldlt().solve(drained) * 1e3; // mm
  const Eigen::VectorXd fullyDrained = chain.K.ldlt().solve(full) * 1e3;
  const double          scale = expected.cwiseAbs().maxCoeff();
  ASSERT_GT(std::abs(fullyDrained(layers - 1)), 1.5 * std::abs(expected(layers - 1))) << "the case cannot tell";
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    const int layer = static_cast<int>(std::lround(model.nodes[n].x() / (length / layers)));
    EXPECT_NEAR(result.displacements[n].x(), layer == 0 ? 0.0 : expected(layer - 1), 2e-3 * scale) << "node " << n;
  }
}

} // namespace
} // namespace bmr

namespace bmr
{
namespace
{
using namespace bmr::test;

/** A 40 x 2 x 2 mm bar held laterally (a one-dimensional P wave), fixed at
 *  x = 0, its end x = 40 moved suddenly by 0.2 mm at t = 0. */
struct SuddenlyPulledBar
{
  static constexpr double length = 40.0, pull = 0.2, youngs = 3000.0, poisson = 0.3, density = 1000.0;
  Model model;
  Index middle = -1; // a node at x = 20

  explicit SuddenlyPulledBar(int layers)
  {
    model = MakeBlockMesh(Vector3(length, 2.0, 2.0), { layers, 1, 1 }, GridCells::Hexahedra,
                          MakeMaterial(youngs, poisson, density));
    model.fixedConstraints.push_back({ "xmin", { true, true, true } });
    model.fixedConstraints.push_back({ "all", { false, true, true } });
    PrescribedDisplacement load;
    load.nodes = model.NodeSet("xmax");
    load.displacements.assign(load.nodes.size(), Vector3(pull, 0, 0));
    load.components = { true, false, false };
    load.curve.shape = LoadCurve::Shape::Step;
    model.prescribedDisplacements.push_back(load);
    for (std::size_t n = 0; n < model.nodes.size(); ++n)
    {
      if (std::abs(model.nodes[n].x() - 0.5 * length) < 1e-9)
      {
        middle = static_cast<Index>(n);
      }
    }
  }

  /** P-wave speed (mm/s) of the linearised material. */
  static double WaveSpeed()
  {
    const double modulus = youngs * (1.0 - poisson) / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    return std::sqrt(modulus / density) * 1e3;
  }

  struct History
  {
    std::vector<double> time, middle, energy;
    SolveResult         result;
  };

  History Run(double endTime, double damping, double interval) const
  {
    SolverSettings settings;
    settings.integrator = Integrator::ExplicitDynamics;
    settings.endTime = endTime;
    settings.dampingCoefficient = damping;
    settings.outputInterval = interval;
    settings.threads = 1;
    History history;
    Solver  solver(model, settings);
    history.result = solver.Solve({}, [&](const SolveFrame & frame) {
      history.time.push_back(frame.time);
      history.middle.push_back(frame.displacements[static_cast<std::size_t>(middle)].x());
      history.energy.push_back(frame.strainEnergy + frame.kineticEnergy);
    });
    return history;
  }
};

/** First time the middle of the bar has moved half the pull: the step front's arrival. */
double
ArrivalTime(const SuddenlyPulledBar::History & history)
{
  for (std::size_t k = 1; k < history.time.size(); ++k)
  {
    if (history.middle[k] >= 0.5 * SuddenlyPulledBar::pull)
    {
      const double s = (0.5 * SuddenlyPulledBar::pull - history.middle[k - 1]) / (history.middle[k] - history.middle[k - 1]);
      return history.time[k - 1] + s * (history.time[k] - history.time[k - 1]);
    }
  }
  return std::numeric_limits<double>::infinity();
}

// The suddenly applied end displacement travels as a step at the P-wave speed:
// it reaches the middle after L/2 / c, in the coarse run and in a run refined
// twice, which agree within one coarse element's transit time; without damping
// the energy put in by the first step stays; with damping the bar settles to
// the uniform stretch.
TEST(ExplicitDynamics, SuddenEndDisplacementTravelsAtTheWaveSpeedAndSettles)
{
  const double c = SuddenlyPulledBar::WaveSpeed();
  const double arrival = 0.5 * SuddenlyPulledBar::length / c;
  const SuddenlyPulledBar coarse(20), fine(40);
  const auto coarseRun = coarse.Run(1.6 * arrival, 0.0, arrival / 200);
  const auto fineRun = fine.Run(1.6 * arrival, 0.0, arrival / 200);
  // The lumped-mass central difference disperses the front (short waves travel
  // slower), which delays the half-amplitude crossing: measured 7.1 % with 20
  // layers and 5.6 % with 40, shrinking as the mesh is refined.
  const double transit = SuddenlyPulledBar::length / 20 / c;
  EXPECT_NEAR(ArrivalTime(coarseRun), arrival, 0.08 * arrival);
  EXPECT_NEAR(ArrivalTime(fineRun), arrival, 0.06 * arrival);
  EXPECT_LT(std::abs(ArrivalTime(fineRun) - arrival), std::abs(ArrivalTime(coarseRun) - arrival));
  EXPECT_NEAR(ArrivalTime(coarseRun), ArrivalTime(fineRun), transit);
  // Before the front arrives the middle has not moved (beyond the scheme's dispersive precursor).
  for (std::size_t k = 0; k < fineRun.time.size() && fineRun.time[k] < 0.8 * arrival; ++k)
  {
    EXPECT_LT(std::abs(fineRun.middle[k]), 0.02 * SuddenlyPulledBar::pull) << "t = " << fineRun.time[k];
  }
  // Energy balance without damping: the first step stretches the last layer
  // by the pull, E = (lambda + 2 mu) A pull^2 / (2 dx); then nothing does work
  // (both ends are held), so the energy at the end time (with the end-of-step
  // velocity) is the same: measured within 0.03 % (40 layers).
  const double modulus = SuddenlyPulledBar::youngs * (1.0 - SuddenlyPulledBar::poisson) /
                         ((1.0 + SuddenlyPulledBar::poisson) * (1.0 - 2.0 * SuddenlyPulledBar::poisson));
  const double injected = 0.5 * modulus * 4e-6 * std::pow(SuddenlyPulledBar::pull * 1e-3, 2) / (SuddenlyPulledBar::length / 40 * 1e-3);
  const double energy = fineRun.result.strainEnergy + fineRun.result.kineticEnergy;
  EXPECT_NEAR(energy, injected, 0.005 * injected) << "strain " << fineRun.result.strainEnergy << " J, kinetic "
                                                 << fineRun.result.kineticEnergy << " J";

  // Damped to rest: the uniform stretch u = pull x / L.
  const auto settled = coarse.Run(0.6, 100.0, 0.6);
  for (std::size_t n = 0; n < coarse.model.nodes.size(); ++n)
  {
    const double expected = SuddenlyPulledBar::pull * coarse.model.nodes[n].x() / SuddenlyPulledBar::length;
    EXPECT_NEAR(settled.result.displacements[n].x(), expected, 1e-3 * SuddenlyPulledBar::pull) << "node " << n;
  }
}

} // namespace
} // namespace bmr
