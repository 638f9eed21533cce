// Rigid surgical tools moving along trajectories: contact with separation
// against analytic and triangulated tools, the force and moment on the tool,
// time-accurate dynamics (energy balance, frames) and the steady state.
#include "bmrTestUtilities.h"

#include "bmrMeshGenerators.h"
#include "bmrScene.h"

#include <gtest/gtest.h>

#include <cmath>

namespace bmr
{
namespace
{
using namespace bmr::test;

constexpr double kPi = 3.14159265358979323846;

/** A quarter of a block [0, size]^2 x [0, height] (symmetry planes x = 0 and
 *  y = 0, base fixed) and a probe of radius R above the corner (0, 0, height)
 *  that sinks `depth` mm over `duration` s. */
Model
QuarterBlockUnderProbe(double size, double height, int divisions, double radius, double depth, double duration,
                       double poissonRatio = 0.45)
{
  const int layers = static_cast<int>(std::lround(divisions * height / size));
  Model     model = MakeBlockMesh(Vector3(size, size, height), { divisions, divisions, layers }, GridCells::Hexahedra,
                              MakeMaterial(3000.0, poissonRatio));
  model.fixedConstraints.push_back({ "xmin", { true, false, false } });
  model.fixedConstraints.push_back({ "ymin", { false, true, false } });
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  RigidTool probe;
  probe.name = "probe";
  probe.shape = RigidTool::Shape::Probe;
  probe.radius = radius;
  probe.length = 20.0;
  probe.trajectory = { { 0.0, Vector3(0, 0, height + radius), Vector3::Zero() },
                       { duration, Vector3(0, 0, height + radius - depth), Vector3::Zero() } };
  probe.slaveNodeSet = "zmax";
  model.tools.push_back(probe);
  return model;
}

/** Hertz: a rigid sphere of radius R pressed d into an elastic half-space. */
double
HertzForce(double youngsModulus, double poissonRatio, double radius, double depth)
{
  const double effective = youngsModulus / (1.0 - poissonRatio * poissonRatio) * 1e-6; // N/mm^2
  return 4.0 / 3.0 * effective * std::sqrt(radius) * std::pow(depth, 1.5);
}

SolverSettings
Relaxation(double tolerance)
{
  SolverSettings settings = TightRelaxation(tolerance, 200000);
  settings.threads = 0;
  return settings;
}

TEST(ToolPose, InterpolatesPositionLinearlyAndRotationSpherically)
{
  RigidTool tool;
  tool.trajectory = { { 1.0, Vector3(0, 0, 0), Vector3::Zero() },
                      { 3.0, Vector3(4, -2, 6), Vector3(0, 0, kPi / 2) } };
  const ToolPose middle = ToolPoseAt(tool, 2.0);
  EXPECT_NEAR((middle.position - Vector3(2, -1, 3)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((middle.rotation - Vector3(0, 0, kPi / 4)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((ToolPoseAt(tool, 0.0).position - Vector3::Zero()).norm(), 0.0, 0.0); // held before the start
  EXPECT_NEAR((ToolPoseAt(tool, 9.0).position - Vector3(4, -2, 6)).norm(), 0.0, 0.0); // and after the end
}

// The steady state of a small indentation against Hertz's half-space solution.
// A 10 mm quarter block of 0.4 mm hexahedra under a 5 mm probe sunk 0.3 mm:
// the contact radius sqrt(R d) = 1.2 mm spans 3 elements, the block is 8 contact
// radii wide and deep.
TEST(ToolContact, SmallIndentationMatchesHertz)
{
  const double radius = 5.0, depth = 0.3;
  Model        model = QuarterBlockUnderProbe(10.0, 10.0, 25, radius, depth, 1.0);
  Solver       solver(model, Relaxation(1e-6));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  ASSERT_EQ(result.tools.size(), 1u);
  const ToolHistory & probe = result.tools[0];
  ASSERT_EQ(probe.force.size(), 1u); // the steady state only
  const double hertz = HertzForce(3000.0, 0.45, radius, depth) / 4.0; // a quarter of the contact
  const Vector3 force = probe.force.back();
  // The tissue pushes the probe up; the symmetry planes take the lateral components.
  EXPECT_GT(force.z(), 0.0);
  EXPECT_NEAR(force.z(), hertz, 0.12 * hertz) << "Hertz " << hertz << " N";
  EXPECT_GT(probe.contactNodes.back(), 3);
  // No node inside the probe.
  EXPECT_EQ(ToolPoseAt(model.tools[0], 1.0).position.z(), 10.0 + radius - depth);
  for (Index node : model.NodeSet("zmax"))
  {
    const Vector3 x = model.nodes[node] + result.displacements[node];
    const Vector3 centre(0, 0, 10.0 + radius - depth);
    EXPECT_GE((x - centre).norm(), radius - 1e-9) << "node " << node;
  }
}

// The same indentation driven slowly in time-accurate explicit dynamics (with
// mass-proportional damping) ends at the force of the steady state.
TEST(ToolContact, SlowExplicitIndentationEndsAtTheSteadyStateForce)
{
  const double radius = 5.0, depth = 0.5;
  Model        model = QuarterBlockUnderProbe(8.0, 8.0, 10, radius, depth, 0.4);
  Solver       relaxation(model, Relaxation(1e-7));
  const SolveResult steady = relaxation.Solve();
  ASSERT_TRUE(steady.converged) << steady.message;

  SolverSettings dynamics;
  dynamics.integrator = Integrator::ExplicitDynamics;
  dynamics.endTime = 0.6; // 0.4 s of indentation, then held
  dynamics.dampingCoefficient = 60.0;
  Solver            solver(model, dynamics);
  const SolveResult result = solver.Solve();
  const ToolHistory & probe = result.tools.at(0);
  ASSERT_EQ(probe.time.size(), static_cast<std::size_t>(result.steps));
  EXPECT_NEAR(probe.time.back(), 0.6, 1e-12);
  const double expected = steady.tools[0].force.back().z();
  EXPECT_NEAR(probe.force.back().z(), expected, 0.02 * expected);
  // The probe starts touching the block's corner: the first step's force is next to nothing.
  EXPECT_LT(probe.force.front().norm(), 1e-3 * expected);
}

// Without damping the work the tool does on the tissue is the tissue's strain
// and kinetic energy (central differences conserve energy to O(h^2)).
TEST(ToolContact, WorkOfTheToolEqualsTheEnergyOfTheTissue)
{
  Model model = QuarterBlockUnderProbe(6.0, 6.0, 8, 3.0, 0.6, 0.05);
  SolverSettings dynamics;
  dynamics.integrator = Integrator::ExplicitDynamics;
  dynamics.endTime = 0.08;
  Solver            solver(model, dynamics);
  const SolveResult result = solver.Solve();
  const double      work = result.tools.at(0).work;
  const double      energy = result.strainEnergy + result.kineticEnergy;
  ASSERT_GT(work, 0.0);
  EXPECT_NEAR(energy, work, 0.03 * work) << "strain " << result.strainEnergy << " J, kinetic " << result.kineticEnergy
                                         << " J";
}

// Every contact force on a sphere points through its centre: on a probe that
// touches with its tip only, the moment about the tip's centre vanishes.
TEST(ToolContact, TipForcesPassThroughTheTipCentre)
{
  Model model = QuarterBlockUnderProbe(8.0, 8.0, 10, 4.0, 0.5, 1.0);
  // Tilt the probe and move it off the corner: the forces are no longer along an axis.
  model.tools[0].trajectory = { { 0.0, Vector3(3, 2.5, 8.0 + 4.0), Vector3(0.3, -0.2, 0) },
                                { 1.0, Vector3(3, 2.5, 8.0 + 4.0 - 0.5), Vector3(0.3, -0.2, 0) } };
  Solver            solver(model, Relaxation(1e-7));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  const Vector3 force = result.tools[0].force.back();
  const Vector3 moment = result.tools[0].moment.back();
  EXPECT_GT(force.norm(), 1e-6);
  EXPECT_LT(moment.norm(), 1e-9 * force.norm() * 4.0);
}

/** A 4 mm cube on a frictionless support (symmetry planes xmin, ymin) compressed
 *  0.8 mm (20 %) in 0.1 s by a flat spatula wider than it. Turned by 90 degrees
 *  about x, the blade's normal (tool y) points along z and its length (tool z)
 *  along -y: from the tool origin at y = 10 it covers y in [-10, 10]. */
Model
SpatulaCompression(const OgdenViscoelasticMaterial & ogden, double regionRadius)
{
  const double side = 4.0;
  Model model = MakeBlockMesh(Vector3(side, side, side), { 4, 4, 4 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
  model.fixedConstraints.push_back({ "xmin", { true, false, false } });
  model.fixedConstraints.push_back({ "ymin", { false, true, false } });
  model.fixedConstraints.push_back({ "zmin", { false, false, true } });
  RigidTool spatula;
  spatula.name = "spatula";
  spatula.shape = RigidTool::Shape::Spatula;
  spatula.radius = 0.5;
  spatula.width = 20.0;
  spatula.length = 20.0;
  const Vector3 turn(kPi / 2, 0, 0);
  spatula.trajectory = { { 0.0, Vector3(0, 10.0, side + 0.5), turn }, { 0.1, Vector3(0, 10.0, side + 0.5 - 0.8), turn } };
  spatula.stressRegionRadius = regionRadius;
  spatula.stressMaterial = ogden;
  model.tools.push_back(spatula);
  return model;
}

// A flat spatula wider than the block pressed onto it: uniaxial stress on a
// frictionless support, F = sigma_zz times the deformed area.
TEST(ToolContact, SpatulaCompressesABlockUniaxially)
{
  const double side = 4.0, compression = 0.8;
  Model        model = SpatulaCompression({}, 0.0);
  Solver            solver(model, Relaxation(1e-9));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  const double     lambda = 1.0 - compression / side;
  const NeoHookean material(model.materials[0]);
  const double     lateral = UniaxialLateralStretch(lambda, material);
  const double     sigma = material.Cauchy(Eigen::Vector3d(lateral, lateral, lambda).asDiagonal().toDenseMatrix())(2, 2);
  const double     expected = -sigma * 1e-6 * (side * lateral) * (side * lateral); // N, pushing the blade up
  EXPECT_NEAR(result.tools[0].force.back().z(), expected, 1e-6 * expected);
  EXPECT_NEAR(result.displacements[model.NodeSet("xmax")[0]].x(), side * (lateral - 1.0), 1e-7);
}

// The tool and a rigid contact surface at the same time: the block rests on a
// frictionless rigid plane instead of a fixed base; pressed by the spatula it
// is in the same uniaxial stress, and both contacts carry the same force.
TEST(ToolContact, ToolAndRigidSupportActTogether)
{
  Model fixedBase = SpatulaCompression({}, 0.0);
  Model onPlane = fixedBase;
  onPlane.fixedConstraints.pop_back(); // zmin
  ContactSurface plane = MakePlane(Vector3(2.0, 2.0, 0.0), Vector3::UnitZ(), 50.0);
  plane.bodySide = ContactSurface::Side::Outside;
  onPlane.contactSurfaces.push_back(plane);
  const SolveResult a = Solver(fixedBase, Relaxation(1e-9)).Solve();
  const SolveResult b = Solver(onPlane, Relaxation(1e-9)).Solve();
  ASSERT_TRUE(a.converged && b.converged) << b.message;
  EXPECT_NEAR(b.tools[0].force.back().z(), a.tools[0].force.back().z(), 1e-6 * a.tools[0].force.back().z());
  double onSupport = 0.0;
  for (const Index node : onPlane.NodeSet("zmin"))
  {
    onSupport += b.reactionForces[node].z();
    EXPECT_NEAR(onPlane.nodes[node].z() + b.displacements[node].z(), 0.0, 1e-9) << "node " << node;
  }
  EXPECT_NEAR(std::abs(onSupport), b.tools[0].force.back().z(), 1e-6 * b.tools[0].force.back().z()); // balance
}

// A triangulated sphere as a tool gives the analytic probe's steady state to within its chord error.
TEST(ToolContact, SurfaceToolMatchesTheAnalyticProbe)
{
  const double radius = 4.0;
  Model        analytic = QuarterBlockUnderProbe(8.0, 8.0, 10, radius, 0.6, 1.0);
  Model        triangulated = analytic;
  RigidTool &  tool = triangulated.tools[0];
  tool.shape = RigidTool::Shape::Surface;
  tool.surface = MakeEllipsoidSurface(Vector3::Constant(radius), 5);
  const SolveResult a = Solver(analytic, Relaxation(1e-7)).Solve();
  const SolveResult b = Solver(triangulated, Relaxation(1e-7)).Solve();
  ASSERT_TRUE(a.converged && b.converged);
  const double fa = a.tools[0].force.back().z(), fb = b.tools[0].force.back().z();
  EXPECT_NEAR(fb, fa, 0.03 * fa);
}

TEST(ToolContact, FramesComeAtTheOutputRateAndEndAtTheResult)
{
  Model          model = QuarterBlockUnderProbe(6.0, 6.0, 6, 3.0, 0.4, 0.05);
  SolverSettings dynamics;
  dynamics.integrator = Integrator::ExplicitDynamics;
  dynamics.endTime = 0.05;
  dynamics.outputInterval = 0.01;
  std::vector<double>  times;
  std::vector<Vector3> last;
  Solver               solver(model, dynamics);
  const SolveResult    result = solver.Solve({}, [&](const SolveFrame & frame) {
    times.push_back(frame.time);
    last = frame.displacements;
  });
  ASSERT_EQ(times.size(), 6u);
  for (std::size_t k = 0; k < times.size(); ++k) // the first step at or after each output time
  {
    EXPECT_GE(times[k], 0.01 * k - 1e-12) << k;
    EXPECT_LT(times[k], 0.01 * k + result.timeStep) << k;
  }
  EXPECT_TRUE(BitwiseEqual(last, result.displacements));
}

TEST(ToolContact, BadToolsAreNamed)
{
  Model model = QuarterBlockUnderProbe(6.0, 6.0, 6, 3.0, 0.4, 0.05);
  model.tools[0].trajectory[0].position.z() = 8.0; // starts 1 mm inside the block
  EXPECT_THROW(
    {
      try
      {
        Solver solver(model, Relaxation(1e-6));
      }
      catch (const Error & error)
      {
        EXPECT_NE(std::string(error.what()).find("starts"), std::string::npos) << error.what();
        EXPECT_NE(std::string(error.what()).find("'probe'"), std::string::npos) << error.what();
        throw;
      }
    },
    Error);
  Model backwards = QuarterBlockUnderProbe(6.0, 6.0, 6, 3.0, 0.4, 0.05);
  backwards.tools[0].trajectory[1].time = 0.0;
  EXPECT_THROW(backwards.Validate(), Error);
  Model thin = QuarterBlockUnderProbe(6.0, 6.0, 6, 3.0, 0.4, 0.05);
  thin.tools[0].radius = 0.0;
  EXPECT_THROW(thin.Validate(), Error);
}

// Pushed far too fast into a coarse block, an element under the tool inverts:
// the failure names the element and the step.
TEST(ToolContact, InversionUnderTheToolNamesElementAndStep)
{
  Model          model = QuarterBlockUnderProbe(4.0, 4.0, 2, 1.0, 3.5, 0.002);
  SolverSettings dynamics;
  dynamics.integrator = Integrator::ExplicitDynamics;
  dynamics.endTime = 0.01;
  try
  {
    Solver solver(model, dynamics);
    solver.Solve();
    FAIL() << "the solve did not fail";
  }
  catch (const SolveError & error)
  {
    EXPECT_GE(error.Element(), 0);
    EXPECT_GT(error.Step(), 0);
    EXPECT_NE(std::string(error.what()).find("step " + std::to_string(error.Step())), std::string::npos) << error.what();
  }
}

TEST(ToolScene, ToolsAreReadFromTheScene)
{
  const std::string text = R"({
    "mesh": {"generate": "block", "size": [6, 6, 6], "divisions": [6, 6, 6], "cells": "hexahedra"},
    "materials": [{"name": "brain", "youngs_modulus": 3000, "poisson_ratio": 0.45, "density": 1000}],
    "fixed": [{"node_set": "zmin"}],
    "tools": [{"name": "probe", "shape": "probe", "radius": 2, "length": 30, "slave_node_set": "zmax",
               "trajectory": [{"time": 0, "position": [3, 3, 8]}, {"time": 0.1, "position": [3, 3, 7.5], "rotation": [0, 0, 0.5]}]}],
    "solver": {"integrator": "explicit_dynamics", "end_time": 0.1, "output_interval": 0.02, "damping": 10}
  })";
  const Scene scene = ParseScene(text, "tool.json");
  ASSERT_EQ(scene.model.tools.size(), 1u);
  const RigidTool & tool = scene.model.tools[0];
  EXPECT_EQ(tool.shape, RigidTool::Shape::Probe);
  EXPECT_EQ(tool.radius, 2.0);
  EXPECT_EQ(tool.trajectory.size(), 2u);
  EXPECT_EQ(tool.trajectory[1].rotation.z(), 0.5);
  EXPECT_EQ(scene.settings.outputInterval, 0.02);
  const auto fails = [&](const std::string & from, const std::string & to, const std::string & expected) {
    std::string bad = text;
    bad.replace(bad.find(from), from.size(), to);
    try
    {
      ParseScene(bad, "tool.json");
      ADD_FAILURE() << "accepted: " << to;
    }
    catch (const Error & error)
    {
      EXPECT_NE(std::string(error.what()).find(expected), std::string::npos) << error.what();
    }
  };
  fails("\"shape\": \"probe\"", "\"shape\": \"scalpel\"", "tools[0].shape");
  fails("\"radius\": 2,", "", "tools[0]: missing required key 'radius'");
  fails("{\"time\": 0.1,", "{\"time\": 0,", "tools[0].trajectory[1].time");
  fails("\"length\": 30", "\"length\": 30, \"width\": 4", "tools[0].width");
}

} // namespace
} // namespace bmr

namespace bmr
{
namespace
{
using namespace bmr::test;

SolverSettings
DampedDynamics(double endTime)
{
  SolverSettings settings;
  settings.integrator = Integrator::ExplicitDynamics;
  settings.endTime = endTime;
  settings.dampingCoefficient = 200.0;
  return settings;
}

/** The Ogden law with alpha = 2 is the neo-Hookean law with mu = mu0 (and the same kappa). */
OgdenViscoelasticMaterial
NeoHookeanAsOgden(const Material & material, double stiffness)
{
  OgdenViscoelasticMaterial ogden;
  ogden.mu0 = stiffness * material.ShearModulus();
  ogden.alpha = 2.0;
  ogden.g.clear();
  ogden.tau.clear();
  ogden.poissonRatio = material.poissonRatio;
  return ogden;
}

// Homogeneous uniaxial compression: the region's stresses are the analytic
// Ogden stresses of the deformation, and they relax as the Prony series says.
TEST(ToolStressRegion, UniaxialCompressionGivesTheAnalyticOgdenStressAndItsRelaxation)
{
  OgdenViscoelasticMaterial ogden; // Miller and Chinzei's alpha and mu0, one fast relaxation term
  ogden.g = { 0.5 };
  ogden.tau = { 0.02 };
  const Model       model = SpatulaCompression(ogden, 10.0);
  const SolveResult result = Solver(model, DampedDynamics(0.4)).Solve(); // held 15 relaxation times
  const ToolHistory & spatula = result.tools.at(0);
  ASSERT_EQ(spatula.stressCells.size(), model.cells.size());
  // The steady deformation: uniaxial stress of the neo-Hookean block.
  const NeoHookean      material(model.materials[0]);
  const double          lambda = 0.8, lateral = UniaxialLateralStretch(lambda, material);
  const Eigen::Matrix3d F = Eigen::Vector3d(lateral, lateral, lambda).asDiagonal();
  // Long after the ramp the isochoric part has relaxed to g_inf = 0.5 of it; the volumetric part does not relax.
  const Eigen::Matrix3d elastic = OgdenElasticCauchy(ogden, F);
  const double          pressure = elastic.trace() / 3.0;
  const Eigen::Matrix3d expected = 0.5 * (elastic - pressure * Eigen::Matrix3d::Identity()) +
                                   pressure * Eigen::Matrix3d::Identity();
  for (std::size_t r = 0; r < spatula.stressCells.size(); ++r)
  {
    EXPECT_LT((spatula.ogdenStress[r] - expected).norm(), 0.01 * expected.norm()) << "cell " << spatula.stressCells[r];
    EXPECT_LT((spatula.neoHookeanStress[r] - material.Cauchy(F)).norm(), 0.01 * material.Cauchy(F).norm());
  }
  // The peak stress is recorded every step and falls as the tissue relaxes.
  ASSERT_EQ(spatula.peakStress.size(), static_cast<std::size_t>(result.steps));
  EXPECT_LT(spatula.peakStress.back(), *std::max_element(spatula.peakStress.begin(), spatula.peakStress.end()));
}

// With alpha = 2 the Ogden law is neo-Hookean: an Ogden region of the same
// stiffness leaves the tool force as it is, one twice as stiff doubles it.
TEST(ToolStressRegion, CorrectedForceFollowsTheRegionsStiffness)
{
  const Material material = MakeMaterial(3000.0, 0.45);
  for (const double stiffness : { 1.0, 2.0 })
  {
    const Model       model = SpatulaCompression(NeoHookeanAsOgden(material, stiffness), 10.0);
    const SolveResult result = Solver(model, DampedDynamics(0.3)).Solve();
    const ToolHistory & spatula = result.tools.at(0);
    ASSERT_EQ(spatula.correctedForce.size(), spatula.force.size());
    const Vector3 force = spatula.force.back(), corrected = spatula.correctedForce.back();
    EXPECT_GT(force.z(), 0.0);
    EXPECT_NEAR(corrected.z(), stiffness * force.z(), 0.01 * force.z()) << "stiffness " << stiffness;
  }
}

// The re-evaluation does not feed back: another radius changes no displacement
// and no force, and a cell's stress does not depend on the region around it.
TEST(ToolStressRegion, RadiusChangesNothingOutsideTheRegion)
{
  Model small = QuarterBlockUnderProbe(6.0, 6.0, 6, 2.0, 0.5, 0.05);
  small.tools[0].stressRegionRadius = 1.5;
  Model large = small;
  large.tools[0].stressRegionRadius = 4.0;
  Model none = small;
  none.tools[0].stressRegionRadius = 0.0;
  SolverSettings settings = DampedDynamics(0.06);
  const SolveResult a = Solver(small, settings).Solve();
  const SolveResult b = Solver(large, settings).Solve();
  const SolveResult c = Solver(none, settings).Solve();
  EXPECT_TRUE(BitwiseEqual(a.displacements, b.displacements));
  EXPECT_TRUE(BitwiseEqual(a.displacements, c.displacements));
  EXPECT_TRUE(BitwiseEqual(a.tools[0].force, c.tools[0].force));
  EXPECT_TRUE(c.tools[0].stressCells.empty() && c.tools[0].correctedForce.empty());
  const auto & smallCells = a.tools[0].stressCells;
  const auto & largeCells = b.tools[0].stressCells;
  ASSERT_FALSE(smallCells.empty());
  EXPECT_GT(largeCells.size(), smallCells.size());
  for (std::size_t r = 0; r < smallCells.size(); ++r)
  {
    const auto in = std::find(largeCells.begin(), largeCells.end(), smallCells[r]);
    ASSERT_NE(in, largeCells.end()) << "cell " << smallCells[r] << " left the larger region";
    EXPECT_EQ(a.tools[0].ogdenStress[r], b.tools[0].ogdenStress[static_cast<std::size_t>(in - largeCells.begin())]);
  }
  // Every region cell lies within the radius of the tool's path (its axis here: x = y = 0, the tip descending).
  for (const Index cell : smallCells)
  {
    Vector3 centroid = Vector3::Zero();
    for (int k = 0; k < 8; ++k)
      centroid += small.nodes[small.cells[cell].nodes[k]] / 8.0;
    const double top = 6.0 + 2.0, bottom = 6.0 + 2.0 - 0.5; // the tip centre's path
    const Vector3 nearest(0, 0, std::clamp(centroid.z(), bottom, top));
    EXPECT_LE((centroid - nearest).norm() - 2.0, 1.5 + 1e-9) << "cell " << cell;
  }
  // Dynamic relaxation has no time history to integrate.
  EXPECT_THROW(Solver(small, Relaxation(1e-6)), Error);
}

} // namespace
} // namespace bmr
