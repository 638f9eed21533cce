// Bad input and failing solves end with a bmr::Error / bmr::SolveError that
// names the offending object; a non-converged solve is never reported as
// converged.
#include "bmrTestUtilities.h"

#include <gtest/gtest.h>

#include <sstream>

namespace bmr
{
namespace
{
using namespace bmr::test;

bool
Contains(const std::string & text, const std::string & part)
{
  return text.find(part) != std::string::npos;
}

/** Message of the bmr::Error thrown by Validate() and by the Solver constructor
 *  (which must validate too); empty if either did not throw. */
std::string
ValidationMessage(const Model & model)
{
  std::string fromValidate, fromSolver;
  try
  {
    model.Validate();
  }
  catch (const Error & e)
  {
    fromValidate = e.what();
  }
  try
  {
    Solver solver(model, SolverSettings{});
  }
  catch (const Error & e)
  {
    fromSolver = e.what();
  }
  EXPECT_EQ(fromValidate, fromSolver) << "the solver must report the same validation error";
  return fromValidate;
}

Model
TwoTetrahedra()
{
  Model model;
  model.materials.push_back(MakeMaterial(3000.0, 0.45));
  model.nodes = { { 0, 0, 0 }, { 1, 0, 0 }, { 0, 1, 0 }, { 0, 0, 1 }, { 1, 1, 1 } };
  Cell a;
  a.type = CellType::Tetrahedron;
  a.nodes = { 0, 1, 2, 3 };
  Cell b = a;
  b.nodes = { 1, 2, 3, 4 };
  if (TetrahedronVolume(model.nodes[1], model.nodes[2], model.nodes[3], model.nodes[4]) < 0.0)
    std::swap(b.nodes[1], b.nodes[2]);
  model.cells = { a, b };
  model.nodeSets["all"] = { 0, 1, 2, 3, 4 };
  return model;
}

TEST(Failure, ValidModelPasses)
{
  EXPECT_EQ(ValidationMessage(TwoTetrahedra()), "");
  EXPECT_EQ(ValidationMessage(MakeBlockMesh(Vector3(2, 2, 2), { 2, 2, 2 }, GridCells::Mixed)), "");
}

TEST(Failure, DegenerateTetrahedronIsNamed)
{
  Model model = TwoTetrahedra();
  model.nodes[4] = (model.nodes[1] + model.nodes[2] + model.nodes[3]) / 3.0; // in the plane of nodes 1, 2, 3
  const std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "cell 1")) << message;
  EXPECT_TRUE(Contains(message, "degenerate")) << message;
}

// Degenerate means flat, not small: CGAL meshes a voxel-scale feature of
// Colin27 at 5.5 mm with well-shaped tetrahedra 0.1 mm across (volume 1e-5
// mm^3), which a threshold relative to the whole mesh's size (1e-12 of its
// 250 mm diagonal cubed) had rejected as "zero volume".
TEST(Failure, SmallWellShapedTetrahedronIsNotDegenerate)
{
  Model model = TwoTetrahedra();
  const Index first = static_cast<Index>(model.nodes.size());
  const double edge = 0.04; // mm: volume 1.1e-5 mm^3
  for (const Vector3 & corner : { Vector3(0, 0, 0), Vector3(edge, 0, 0), Vector3(0, edge, 0), Vector3(0, 0, edge) })
  {
    model.nodes.push_back(Vector3(250.0, 0.0, 0.0) + corner);
  }
  Cell small = model.cells.front();
  small.nodes = { first, first + 1, first + 2, first + 3 };
  model.cells.push_back(small);
  EXPECT_EQ(ValidationMessage(model), "");
  // The same cell flattened to a thousandth of a nanometre is degenerate.
  model.nodes[first + 3] = Vector3(250.0 + edge / 3.0, edge / 3.0, 1e-12);
  const std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "cell 2")) << message;
  EXPECT_TRUE(Contains(message, "degenerate")) << message;
}

TEST(Failure, DegenerateHexahedronIsNamed)
{
  Model model = MakeBlockMesh(Vector3(3, 1, 1), { 3, 1, 1 }, GridCells::Hexahedra);
  // Flatten cell 2 (x in [2,3]): its x = 3 face collapses onto x = 2.
  for (Index n : model.NodeSet("xmax"))
    model.nodes[n].x() = 2.0;
  const std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "hexahedron cell 2")) << message;
  EXPECT_TRUE(Contains(message, "degenerate")) << message;
}

TEST(Failure, InvertedCellIsNamed)
{
  Model model = TwoTetrahedra();
  std::swap(model.cells[1].nodes[0], model.cells[1].nodes[1]);
  std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "cell 1")) << message;
  EXPECT_TRUE(Contains(message, "inverted")) << message;

  Model block = MakeBlockMesh(Vector3(2, 2, 2), { 2, 2, 2 }, GridCells::Hexahedra);
  // Mirror cell 5: swap its bottom and top faces.
  auto & nodes = block.cells[5].nodes;
  for (int a = 0; a < 4; ++a)
    std::swap(nodes[a], nodes[a + 4]);
  message = ValidationMessage(block);
  EXPECT_TRUE(Contains(message, "hexahedron cell 5")) << message;
  EXPECT_TRUE(Contains(message, "inverted")) << message;
}

// A point outside every cell would get no mass (a NaN at the first step).
TEST(Failure, NodeOutsideEveryCellIsNamed)
{
  Model model = TwoTetrahedra();
  model.nodes.push_back(Vector3(9.0, 9.0, 9.0));
  const std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "node " + std::to_string(model.nodes.size() - 1))) << message;
  EXPECT_TRUE(Contains(message, "no cell")) << message;
}

TEST(Failure, NodeIndexOutOfRangeIsNamed)
{
  Model model = TwoTetrahedra();
  model.cells[1].nodes[3] = 17;
  std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "cell 1")) << message;
  EXPECT_TRUE(Contains(message, "17")) << message;

  Model load = TwoTetrahedra();
  load.prescribedDisplacements.push_back({ { 0, 99 }, { Vector3::Zero(), Vector3::Zero() }, { true, true, true }, {} });
  message = ValidationMessage(load);
  EXPECT_TRUE(Contains(message, "prescribed displacement 0")) << message;
  EXPECT_TRUE(Contains(message, "99")) << message;

  Model set = TwoTetrahedra();
  set.nodeSets["top"] = { 3, -1 };
  message = ValidationMessage(set);
  EXPECT_TRUE(Contains(message, "'top'")) << message;
  EXPECT_TRUE(Contains(message, "-1")) << message;
}

TEST(Failure, MissingNodeSetIsNamed)
{
  Model model = TwoTetrahedra();
  model.fixedConstraints.push_back({ "skull_contact", { true, true, true } });
  std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "'skull_contact'")) << message;

  Model contact = TwoTetrahedra();
  contact.contactSurfaces.push_back(MakePlane(Vector3::Zero(), Vector3::UnitZ(), 5.0));
  contact.contactSurfaces.back().slaveNodeSet = "cortex";
  message = ValidationMessage(contact);
  EXPECT_TRUE(Contains(message, "'cortex'")) << message;
}

TEST(Failure, FluidSurfaceNeedsGravityAndAFinitePoint)
{
  Model model = TwoTetrahedra();
  model.fluidSurface = Vector3(0.0, 0.0, 0.5);
  std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "without gravity")) << message;

  model.bodyAcceleration = Vector3(0.0, 0.0, -9810.0);
  EXPECT_EQ(ValidationMessage(model), "");
  model.fluidSurface->z() = std::nan("");
  message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "fluid surface point is not finite")) << message;
}

TEST(Failure, MaterialIndexOutOfRangeIsNamed)
{
  Model model = TwoTetrahedra();
  model.cells[0].material = 3;
  const std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "cell 0")) << message;
  EXPECT_TRUE(Contains(message, "material index 3")) << message;
}

TEST(Failure, BadMaterialIsNamed)
{
  Model model = TwoTetrahedra();
  model.materials[0].poissonRatio = 0.5;
  model.materials[0].name = "parenchyma";
  const std::string message = ValidationMessage(model);
  EXPECT_TRUE(Contains(message, "parenchyma")) << message;
  EXPECT_TRUE(Contains(message, "Poisson")) << message;
}

// A displacement applied in a single step inverts the cells around the moved
// node: the solve stops with a SolveError naming the cell and the step.
void
ExpectInversionNamed(GridCells cells, double push)
{
  Model model = MakeBlockMesh(Vector3(3, 3, 3), { 3, 3, 3 }, cells, MakeMaterial(3000.0, 0.45));
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  // A top node (interior of the top face) pushed down at once.
  const Index node = model.NodeSet("zmax")[5];
  LoadCurve   step;
  step.shape = LoadCurve::Shape::Step;
  Prescribe(model, { node }, [push](const Vector3 &) { return Vector3(0.0, 0.0, -push); }, { true, true, true }, step);
  SolverSettings settings = TightRelaxation(1e-6, 10000);
  settings.loadSteps = 1;
  Solver solver(model, settings);
  try
  {
    solver.Solve();
    ADD_FAILURE() << "an inverted element must stop the solve";
  }
  catch (const SolveError & e)
  {
    const std::string message = e.what();
    ASSERT_GE(e.Element(), 0) << message;
    ASSERT_LT(e.Element(), static_cast<Index>(model.cells.size()));
    EXPECT_GE(e.Step(), 0) << message;
    EXPECT_TRUE(Contains(message, "cell " + std::to_string(e.Element()))) << message;
    EXPECT_TRUE(Contains(message, "step " + std::to_string(e.Step()))) << message;
    EXPECT_TRUE(Contains(message, "inverted")) << message;
    // The inverted cell is one of those around the moved node.
    const Cell & cell = model.cells[e.Element()];
    const auto   end = cell.nodes.begin() + NodesPerCell(cell.type);
    EXPECT_TRUE(std::find(cell.nodes.begin(), end, node) != end) << message;
  }
}

// A rigid surface that starts inside the body: the first step projects the
// nodes beyond it onto it, whatever the load ramp, and the upper cells
// collapse. The error must say so, naming the surface and the deepest node,
// not only blame the loads.
TEST(Failure, ContactNodesStartingBeyondTheSurfaceAreNamed)
{
  Model model = MakeBlockMesh(Vector3(3, 3, 3), { 3, 3, 3 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  ContactSurface lid = MakePlane(Vector3(1.5, 1.5, 0.4), Vector3::UnitZ(), 50.0);
  lid.name = "lid";
  lid.bodySide = ContactSurface::Side::Inside; // the body is below the plane z = 0.4
  model.contactSurfaces.push_back(lid);
  Solver solver(model, TightRelaxation(1e-6, 10000));
  try
  {
    solver.Solve();
    ADD_FAILURE() << "a surface 2.6 mm inside the body must stop the solve";
  }
  catch (const SolveError & e)
  {
    const std::string message = e.what();
    EXPECT_TRUE(Contains(message, "inverted")) << message;
    // 40 boundary nodes at z = 1, 2, 3 (12 + 12 + 16) are beyond the lid; the top ones by 2.6 mm.
    EXPECT_TRUE(Contains(message, "40 contact node(s) start beyond contact surface 'lid'")) << message;
    EXPECT_TRUE(Contains(message, " by 2.6 mm")) << message;
    const Index deepest = std::stoi(message.substr(message.find("(node ") + 6));
    EXPECT_NEAR(model.nodes.at(static_cast<std::size_t>(deepest)).z(), 3.0, 1e-12) << message;
  }
}

// Tetrahedra, 2.5 mm (through more than two cell layers of 1 mm, less than the
// body's size): the cells under the moved node invert at the first step.
TEST(Failure, InversionDuringSolveNamesElementAndStep)
{
  ExpectInversionNamed(GridCells::Tetrahedra, 2.5);
}

// 9 mm (three block heights) in one step: the prescribed node moves further
// than the body's size in that step, but it is the user who moved it; the
// error must still name the inverted cell, not report an instability with
// Element() = -1.
TEST(Failure, HugeStepDisplacementNamesInvertedElement)
{
  ExpectInversionNamed(GridCells::Hexahedra, 9.0);
  ExpectInversionNamed(GridCells::Tetrahedra, 9.0);
}

// The top of a 3 mm block pushed down 1.5 mm over loadSteps steps (in one,
// the top cells invert at once however heavy the masses); the static answer
// (50 % compression) is harmless.
SolveResult
SolvePushedBlock(int loadSteps, int adaptInterval)
{
  Model model = MakeBlockMesh(Vector3(3, 3, 3), { 3, 3, 3 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  Prescribe(model, model.NodeSet("zmax"), [](const Vector3 &) { return Vector3(0.0, 0.0, -1.5); },
            { true, true, true });
  SolverSettings settings = TightRelaxation(1e-6, 100000);
  settings.loadSteps = loadSteps;
  settings.adaptInterval = adaptInterval;
  return Solver(model, settings).Solve();
}

double
LargestDifference(const SolveResult & a, const SolveResult & b)
{
  double difference = 0.0;
  for (std::size_t n = 0; n < a.displacements.size(); ++n)
  {
    difference = std::max(difference, (a.displacements[n] - b.displacements[n]).norm());
  }
  return difference;
}

// A failure while the loads still ramp restarts with the rest of the ramp
// twice as slow (and heavier masses), so the solve converges to the same
// answer as a slow ramp from the start.
TEST(Failure, InversionWhileTheLoadsRampSlowsTheRamp)
{
  const SolveResult slow = SolvePushedBlock(200, 20);
  ASSERT_TRUE(slow.converged) << slow.message;
  const SolveResult fast = SolvePushedBlock(1, 20);
  ASSERT_TRUE(fast.converged) << fast.message;
  EXPECT_GE(fast.restarts, 1);
  EXPECT_TRUE(Contains(fast.message, "load ramp twice as slow")) << fast.message;
  EXPECT_LT(LargestDifference(fast, slow), 1e-4);
}

// A state can pass its checks (no inverted cell, a bounded increment) and
// still be one no restart survives: far out of balance in the middle of a
// fast ramp, its forces move a node too far at once however heavy the
// masses. Which state becomes a restart point depends on the adaptation
// interval; before restarts fell back past such a state, ramps over 1 and 2
// steps failed with intervals 5 and 3 after six restarts from it.
TEST(Failure, RestartsFallBackPastAStateNoRestartSurvives)
{
  const SolveResult slow = SolvePushedBlock(200, 20);
  ASSERT_TRUE(slow.converged) << slow.message;
  for (int loadSteps : { 1, 2, 3, 4, 6 })
  {
    for (int adaptInterval = 2; adaptInterval <= 8; ++adaptInterval)
    {
      SCOPED_TRACE("load_steps " + std::to_string(loadSteps) + ", adapt_interval " + std::to_string(adaptInterval));
      try
      {
        const SolveResult fast = SolvePushedBlock(loadSteps, adaptInterval);
        ASSERT_TRUE(fast.converged) << fast.message;
        EXPECT_LT(LargestDifference(fast, slow), 1e-4);
      }
      catch (const SolveError & e)
      {
        ADD_FAILURE() << e.what();
      }
    }
  }
}

// A collapse modulus that is negative or not a number is named before any work.
TEST(Failure, BadCollapseModulusIsNamed)
{
  for (double modulus : { -1.0, std::nan("") })
  {
    Model model = MakeBlockMesh(Vector3(3, 3, 3), { 3, 3, 3 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
    model.fixedConstraints.push_back({ "zmin", { true, true, true } });
    SolverSettings settings;
    settings.collapseBulkModulus = modulus;
    try
    {
      Solver(model, settings).Solve();
      ADD_FAILURE() << "collapse modulus " << modulus << " accepted";
    }
    catch (const Error & e)
    {
      EXPECT_TRUE(Contains(e.what(), "collapse_bulk_modulus")) << e.what();
    }
  }
}

// One-point hexahedra check J only at the cell centre, where it can stay
// positive while the cell is folded at its corners. A node pushed 1.5 mm down
// through the 1 mm cell below it must not come back as a converged result
// with tangled cells: either a SolveError naming the cell, or a result whose
// every corner Jacobian is positive.
TEST(Failure, HexahedronFoldedAtCornersIsNotReturnedAsConverged)
{
  for (double push : { 1.5, 2.5 })
  {
    Model model = MakeBlockMesh(Vector3(3, 3, 3), { 3, 3, 3 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
    model.fixedConstraints.push_back({ "zmin", { true, true, true } });
    const Index node = model.NodeSet("zmax")[5];
    LoadCurve   step;
    step.shape = LoadCurve::Shape::Step;
    Prescribe(model, { node }, [push](const Vector3 &) { return Vector3(0.0, 0.0, -push); }, { true, true, true },
              step);
    SolverSettings settings = TightRelaxation(1e-6, 10000);
    settings.loadSteps = 1;
    Solver solver(model, settings);
    try
    {
      const SolveResult result = solver.Solve();
      const double      minimum = MinDeformedJacobian(model, result.displacements);
      EXPECT_GT(minimum, 0.0) << "push " << push << " mm: returned converged=" << result.converged
                              << " with a corner Jacobian of " << minimum << " (cell folded)";
    }
    catch (const SolveError & e)
    {
      EXPECT_GE(e.Element(), 0) << e.what();
      EXPECT_TRUE(Contains(e.what(), "cell " + std::to_string(e.Element()))) << e.what();
    }
  }
}

// Explicit dynamics with a time step 20x the critical one diverges: it must
// stop with an error that says so, not return garbage.
TEST(Failure, ExplicitTimeStepAboveCriticalIsReported)
{
  Model model = MakeBlockMesh(Vector3(4, 4, 4), { 4, 4, 4 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  model.bodyAcceleration = Vector3(0.0, 0.0, -9810.0);
  SolverSettings settings;
  settings.integrator = Integrator::ExplicitDynamics;
  settings.threads = 1;
  {
    Solver probe(model, settings);
    settings.timeStep = 20.0 * probe.CriticalTimeStep();
  }
  settings.endTime = 2000 * settings.timeStep;
  std::string message;
  try
  {
    Solver      solver(model, settings);
    SolveResult result = solver.Solve();
    ADD_FAILURE() << "unstable time step returned converged=" << result.converged << " max displacement "
                  << result.maxDisplacement;
  }
  catch (const SolveError & e)
  {
    message = e.what();
  }
  catch (const Error & e)
  {
    message = e.what();
    ADD_FAILURE() << "expected a bmr::SolveError, got bmr::Error: " << message;
  }
  EXPECT_TRUE(Contains(message, "time step")) << message;
}

// A model without loads is already at its solution. Its internal forces are
// round-off (about 1e-16 N for tetrahedra: ANP nodal averaging), so the
// displacement increments are round-off too; their relative growth must not
// be mistaken for divergence.
TEST(Failure, UnloadedModelIsNotReportedAsDiverged)
{
  for (GridCells cells : { GridCells::Hexahedra, GridCells::Tetrahedra, GridCells::Mixed })
  {
    Model model = MakeBlockMesh(Vector3(4.0, 4.0, 2.0), { 4, 4, 2 }, cells);
    model.fixedConstraints.push_back({ "zmax", { true, true, true } });
    for (double tolerance : { 1e-3, 1e-9 })
    {
      Solver      solver(model, TightRelaxation(tolerance, 100000));
      SolveResult result;
      ASSERT_NO_THROW(result = solver.Solve()) << "cells " << static_cast<int>(cells) << ", tolerance " << tolerance;
      EXPECT_TRUE(result.converged) << result.message;
      EXPECT_LT(result.maxDisplacement, 1e-12);
    }
  }
}

// Too few steps: not converged, and the estimated error says why.
TEST(Failure, TooFewRelaxationStepsIsNotConverged)
{
  Model model = MakeBlockMesh(Vector3(4, 4, 4), { 3, 3, 3 }, GridCells::Tetrahedra, MakeMaterial(3000.0, 0.49));
  AddSymmetryConstraints(model);
  Prescribe(model, model.NodeSet("xmax"), [](const Vector3 &) { return Vector3(-1.0, 0, 0); }, { true, false, false });
  SolverSettings settings = TightRelaxation(1e-6, 250);
  settings.loadSteps = 200;
  Solver            solver(model, settings);
  const SolveResult result = solver.Solve();
  EXPECT_FALSE(result.converged);
  EXPECT_GT(result.estimatedError, settings.tolerance);
  EXPECT_LE(result.steps, settings.maxSteps);
  EXPECT_FALSE(result.message.empty());
  EXPECT_TRUE(Contains(result.message, "is above the tolerance")) << result.message;
  // It names where it still moves.
  const std::size_t at = result.message.find("moves most at node ");
  ASSERT_NE(at, std::string::npos) << result.message;
  const Index node = std::stoi(result.message.substr(at + std::string("moves most at node ").size()));
  ASSERT_GE(node, 0);
  ASSERT_LT(static_cast<std::size_t>(node), model.nodes.size());
  std::ostringstream position;
  position << "(" << model.nodes[node].x() << ", " << model.nodes[node].y() << ", " << model.nodes[node].z() << " mm)";
  EXPECT_TRUE(Contains(result.message, position.str())) << result.message;
  // Its last increment is the largest one, which the estimate multiplies by rate / (1 - rate) >= 1.
  const double increment = std::stod(result.message.substr(result.message.find(" mm), ", at) + 6));
  EXPECT_GT(increment, 0.0) << result.message;
  EXPECT_LE(increment, result.estimatedError) << result.message;
}

// Stopped within the tolerance but before the convergence test's hold ran
// out: not converged, and the message does not claim the estimate is too large.
TEST(Failure, StoppedDuringTheConvergenceHoldSaysSo)
{
  Model model = BrainMaterialsBlock(GridCells::Hexahedra);
  Prescribe(model, model.NodeSet("zmax"), [](const Vector3 &) { return Vector3(0.0, 0.0, -1.0); });
  SolverSettings    settings = TightRelaxation(1e-3, 100000);
  const SolveResult full = Solver(model, settings).Solve();
  ASSERT_TRUE(full.converged) << full.message;
  settings.maxSteps = full.steps - 1; // deterministic: the same path, one step short
  const SolveResult cut = Solver(model, settings).Solve();
  EXPECT_FALSE(cut.converged);
  EXPECT_LT(cut.estimatedError, settings.tolerance);
  EXPECT_TRUE(Contains(cut.message, "is below the tolerance")) << cut.message;
  EXPECT_TRUE(Contains(cut.message, "Increase max_steps")) << cut.message;
}

} // namespace
} // namespace bmr
