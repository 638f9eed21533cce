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

  // The discrete chain in SI units: layer stiffness (lambda + 2 mu) A / dx, lumped layer masses.
  const double pWaveModulus = youngs * (1.0 - poisson) / ((1.0 + poisson) * (1.0 - 2.0 * poisson)); // Pa
  const double area = side * side * 1e-6, dx = length / layers * 1e-3;                             // m^2, m
  const double k = pWaveModulus * area / dx;
  Eigen::MatrixXd K = Eigen::MatrixXd::Zero(layers, layers), M = Eigen::MatrixXd::Zero(layers, layers);
  for (int i = 0; i < layers; ++i) // unknowns: layers 1..8
  {
    K(i, i) += k;
    if (i + 1 < layers)
    {
      K(i, i) += k;
      K(i, i + 1) = K(i + 1, i) = -k;
    }
    M(i, i) = density * area * dx * (i + 1 < layers ? 1.0 : 0.5);
  }
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

} // namespace
} // namespace bmr
