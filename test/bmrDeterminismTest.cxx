// Same input, same result, for 1 or N threads: displacements, reaction forces
// and step counts bitwise identical (forces are assembled in a fixed order).
#include "bmrTestUtilities.h"

#include <gtest/gtest.h>

namespace bmr
{
namespace
{
using namespace bmr::test;

/** A block squeezed between a prescribed top and a rigid sphere below it, with
 *  gravity: hexahedra (hourglass control), tetrahedra (ANP nodal averaging) and
 *  contact all take part. */
Model
ContactScene(GridCells cells)
{
  Model model = MakeBlockMesh(Vector3(6.0, 6.0, 3.0), { 6, 6, 3 }, cells, MakeMaterial(3000.0, 0.49));
  DistortInteriorNodes(model, 0.2, 11);
  ContactSurface sphere = MakeEllipsoidSurface(Vector3(2.5, 2.5, 2.5), 2, Vector3(3.0, 3.0, -2.55));
  sphere.bodySide = ContactSurface::Side::Outside;
  model.contactSurfaces.push_back(sphere);
  Prescribe(model, model.NodeSet("zmax"), [](const Vector3 & X) { return Vector3(0.05 * X.y(), 0.0, -0.8); });
  model.bodyAcceleration = Vector3(0.0, 0.0, -9810.0);
  return model;
}

/** Solves with 1 and 2 threads (and 2 again), expects bitwise equal results,
 *  and returns the 1- and 2-thread results for further checks. */
std::pair<SolveResult, SolveResult>
ExpectIdenticalAcrossThreads(const Model & model, SolverSettings settings)
{
  settings.threads = 1;
  Solver      one(model, settings);
  SolveResult a = one.Solve();
  settings.threads = 2;
  Solver      two(model, settings);
  SolveResult b = two.Solve();
  Solver      twoAgain(model, settings);
  SolveResult c = twoAgain.Solve();

  EXPECT_GT(a.contactNodes, 0);
  EXPECT_GT(a.maxDisplacement, 0.5);
  EXPECT_EQ(a.steps, b.steps);
  EXPECT_EQ(a.converged, b.converged);
  EXPECT_EQ(a.contactNodes, b.contactNodes);
  EXPECT_TRUE(BitwiseEqual(a.displacements, b.displacements)) << "1 vs 2 threads";
  EXPECT_TRUE(BitwiseEqual(a.reactionForces, b.reactionForces)) << "1 vs 2 threads";
  EXPECT_TRUE(BitwiseEqual(b.displacements, c.displacements)) << "2 threads, repeated";
  EXPECT_EQ(a.strainEnergy, b.strainEnergy);
  EXPECT_EQ(a.estimatedError, b.estimatedError);
  // Spot check with EXPECT_EQ on doubles for a readable failure message.
  for (std::size_t n = 0; n < a.displacements.size(); n += 37)
    for (int d = 0; d < 3; ++d)
      EXPECT_EQ(a.displacements[n][d], b.displacements[n][d]) << "node " << n << " component " << d;
  return { a, b };
}

TEST(Determinism, HexahedraWithContactRelaxation)
{
  ExpectIdenticalAcrossThreads(ContactScene(GridCells::Hexahedra), TightRelaxation(1e-6, 100000));
}

TEST(Determinism, AnpTetrahedraWithContactRelaxation)
{
  ExpectIdenticalAcrossThreads(ContactScene(GridCells::Tetrahedra), TightRelaxation(1e-6, 100000));
}

TEST(Determinism, MixedWithContactExplicitDynamics)
{
  SolverSettings settings;
  settings.integrator = Integrator::ExplicitDynamics;
  settings.endTime = 0.01;
  settings.dampingCoefficient = 50.0;
  settings.computeStress = true;
  Model model = ContactScene(GridCells::Mixed);
  for (auto & load : model.prescribedDisplacements)
    load.curve.rampTime = 0.008;
  model.bodyForceCurve.rampTime = 0.008;
  const auto [a, b] = ExpectIdenticalAcrossThreads(model, settings);

  // Stresses too.
  ASSERT_EQ(a.cauchyStress.size(), model.cells.size());
  ASSERT_EQ(b.cauchyStress.size(), model.cells.size());
  EXPECT_EQ(std::memcmp(a.cauchyStress.data(), b.cauchyStress.data(), a.cauchyStress.size() * sizeof(Matrix3)), 0);
}

} // namespace
} // namespace bmr
