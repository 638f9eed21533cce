// Frictionless rigid contact with separation: a block against a rigid plane
// (open surface) and a rigid sphere (closed surface). Checks impenetrability of
// every node analytically, the absence of tangential (friction) forces, the
// absence of sticking, and the analytic solution of a block compressed on a
// frictionless support.
#include "bmrContact.h"
#include "bmrTestUtilities.h"

#include <gtest/gtest.h>

namespace bmr
{
namespace
{
using namespace bmr::test;

// Block [0,4]x[0,4]x[gap, gap+2] mm above the plane z = 0 (normal +z, body on
// the normal side: Side::Outside).
const Vector3            kSize(4.0, 4.0, 2.0);
const std::array<int, 3> kCellsPerAxis{ 4, 4, 2 };

Model
BlockAbovePlane(GridCells cells, double gap, double poissonRatio = 0.45)
{
  Model          model = MakeBlockMesh(kSize, kCellsPerAxis, cells, MakeMaterial(3000.0, poissonRatio), Vector3(0, 0, gap));
  ContactSurface plane = MakePlane(Vector3(2.0, 2.0, 0.0), Vector3::UnitZ(), 50.0);
  plane.bodySide = ContactSurface::Side::Outside;
  model.contactSurfaces.push_back(plane);
  return model;
}

double
LowestDeformedZ(const Model & model, const std::vector<Vector3> & u)
{
  double z = std::numeric_limits<double>::max();
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
    z = std::min(z, model.nodes[n].z() + u[n].z());
  return z;
}

class ContactTest : public testing::TestWithParam<GridCells>
{};

// (a) The block, 0.3 mm above the plane, is pushed down 0.7 mm at its top (z
// only; symmetry planes xmin, ymin): it translates 0.3 mm onto the plane, then
// is compressed by 0.4 mm (20%) on a frictionless support. That is uniaxial
// stress: F = diag(s, s, 0.8) on top of the 0.3 mm translation.
TEST_P(ContactTest, BlockCompressedOnFrictionlessPlaneMatchesUniaxialStress)
{
  const double gap = 0.3, compression = 0.4;
  Model        model = BlockAbovePlane(GetParam(), gap);
  model.fixedConstraints.push_back({ "xmin", { true, false, false } });
  model.fixedConstraints.push_back({ "ymin", { false, true, false } });
  Prescribe(model, model.NodeSet("zmax"), [&](const Vector3 &) { return Vector3(0, 0, -(gap + compression)); },
            { false, false, true });

  Solver            solver(model, TightRelaxation(1e-9));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;

  // Impenetrability, node by node against the analytic plane z = 0.
  EXPECT_GT(LowestDeformedZ(model, result.displacements), -1e-6);
  EXPECT_LE(result.maxPenetration, 1e-6);
  EXPECT_EQ(result.contactNodes, static_cast<int>(model.NodeSet("zmin").size()));

  const NeoHookean law(model.materials[0]);
  const double     lambda = (kSize.z() - compression) / kSize.z();
  const double     s = UniaxialLateralStretch(lambda, law);
  const Matrix3    F = Eigen::Vector3d(s, s, lambda).asDiagonal();
  const Vector3    X0(0.0, 0.0, gap);
  const DisplacementField exact = [&](const Vector3 & X) -> Vector3 {
    return (F - Matrix3::Identity()) * (X - X0) + Vector3(0, 0, -gap);
  };
  const double scale = MaxFieldNorm(model, exact);
  const double error = MaxNodalError(model, result.displacements, exact);
  EXPECT_LT(error, 1e-5 * scale) << "max nodal error " << error << " mm";

  // The plane carries the load: its reaction is normal and equals -P33 A0.
  const Matrix3 P = law.FirstPiola(F);
  const double  expected = -P(2, 2) * kSize.x() * kSize.y() * PascalSquareMillimetreToNewton; // > 0: pushes up
  const Vector3 onPlane = SumOver(result.reactionForces, model.NodeSet("zmin"));
  const Vector3 onTop = SumOver(result.reactionForces, model.NodeSet("zmax"));
  EXPECT_GT(expected, 0.0);
  EXPECT_NEAR(onPlane.z(), expected, 1e-4 * expected);
  EXPECT_NEAR(onTop.z(), -expected, 1e-4 * expected);
  EXPECT_LT(std::hypot(onPlane.x(), onPlane.y()), 1e-4 * expected);
}

// (b) Pressed down and moved sideways: on a frictionless plane the bottom
// slides with the top and the plane transmits no tangential force. The plane
// is invariant under horizontal translation, so the solution must be the one
// without the sideways motion, translated rigidly.
TEST_P(ContactTest, SlidingIsUnresisted)
{
  const double  gap = 0.1;
  const Vector3 press(0.0, 0.0, -(gap + 0.3));
  const Vector3 slide(1.5, -0.7, 0.0);
  Model         pressed = BlockAbovePlane(GetParam(), gap);
  Model         slid = pressed;
  Prescribe(pressed, pressed.NodeSet("zmax"), [&](const Vector3 &) { return press; });
  Prescribe(slid, slid.NodeSet("zmax"), [&](const Vector3 &) { return Vector3(press + slide); });

  Solver            pressedSolver(pressed, TightRelaxation(1e-9));
  const SolveResult reference = pressedSolver.Solve();
  Solver            solver(slid, TightRelaxation(1e-9));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(reference.converged) << reference.message;
  ASSERT_TRUE(result.converged) << result.message;
  EXPECT_GT(LowestDeformedZ(slid, result.displacements), -1e-6);
  EXPECT_GT(result.contactNodes, 0);
  EXPECT_EQ(result.contactNodes, reference.contactNodes);

  const std::vector<Index> & bottom = slid.NodeSet("zmin");
  const Vector3              onPlane = SumOver(result.reactionForces, bottom);
  const Vector3              onTop = SumOver(result.reactionForces, slid.NodeSet("zmax"));
  RecordProperty("tangentialOverNormal", Sci(std::hypot(onPlane.x(), onPlane.y()) / onPlane.z()));
  ASSERT_GT(onPlane.z(), 0.0) << "the plane must push the body up";
  EXPECT_LT(std::hypot(onPlane.x(), onPlane.y()), 1e-4 * onPlane.z()) << "tangential force on the plane";
  EXPECT_LT(std::hypot(onTop.x(), onTop.y()), 1e-4 * onPlane.z()) << "tangential force at the top";
  EXPECT_NEAR(onTop.z(), -onPlane.z(), 1e-4 * onPlane.z());

  const double difference = MaxDifference(result.displacements, reference.displacements, slide);
  RecordProperty("maxDifferenceFromTranslatedSolution_mm", Sci(difference));
  EXPECT_LT(difference, 1e-5);
}

// (c) A block resting on the plane and pulled up leaves it: no sticking.
TEST_P(ContactTest, PulledAwaySeparates)
{
  Model model = BlockAbovePlane(GetParam(), 0.0);
  Prescribe(model, model.NodeSet("zmax"), [](const Vector3 &) { return Vector3(0.0, 0.0, 0.5); });
  Solver            solver(model, TightRelaxation(1e-9));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  EXPECT_EQ(result.contactNodes, 0);
  // Rigid lift: every node rose by 0.5 mm, including the bottom ones.
  const double error =
    MaxNodalError(model, result.displacements, [](const Vector3 &) { return Vector3(0.0, 0.0, 0.5); });
  EXPECT_LT(error, 1e-6);
  EXPECT_LT(MaxNorm(result.reactionForces, model.NodeSet("zmin")), 1e-12);
}

// (c') Gravity pulling the hanging block away from the plane it rests on gives
// the same result as without the plane.
TEST_P(ContactTest, GravityAwayFromPlaneEqualsFreeSolution)
{
  Model model = BlockAbovePlane(GetParam(), 0.0);
  model.fixedConstraints.push_back({ "zmax", { true, true, true } });
  model.bodyAcceleration = Vector3(0.0, 0.0, 9810.0); // pulls up, away from the plane below
  Solver            withPlane(model, TightRelaxation(1e-9));
  const SolveResult result = withPlane.Solve();
  ASSERT_TRUE(result.converged) << result.message;

  Model free = model;
  free.contactSurfaces.clear();
  Solver            withoutPlane(free, TightRelaxation(1e-9));
  const SolveResult reference = withoutPlane.Solve();
  ASSERT_TRUE(reference.converged) << reference.message;

  EXPECT_EQ(result.contactNodes, 0);
  double lowestLift = std::numeric_limits<double>::max();
  for (Index n : model.NodeSet("zmin"))
    lowestLift = std::min(lowestLift, result.displacements[n].z());
  EXPECT_GT(lowestLift, 0.0);
  EXPECT_LT(MaxDifference(result.displacements, reference.displacements), 1e-6 * reference.maxDisplacement);
}

// (a') A contact offset is the surface moved by it: the compressed block of
// (a) on the plane z = 0 with an offset of -0.2 mm (the block may pass it by
// that much) or +0.15 mm (it keeps that far above) gives the solution on the
// plane z = -0.2 or z = +0.15 mm without one.
TEST_P(ContactTest, AnOffsetActsAsTheSurfaceMovedByIt)
{
  const auto solve = [](double planeHeight, double offset) {
    Model model = BlockAbovePlane(GetParam(), 0.3);
    model.contactSurfaces[0] = MakePlane(Vector3(2.0, 2.0, planeHeight), Vector3::UnitZ(), 50.0);
    model.contactSurfaces[0].bodySide = ContactSurface::Side::Outside;
    model.contactSurfaces[0].offset = offset;
    model.fixedConstraints.push_back({ "xmin", { true, false, false } });
    model.fixedConstraints.push_back({ "ymin", { false, true, false } });
    Prescribe(model, model.NodeSet("zmax"), [](const Vector3 &) { return Vector3(0, 0, -0.8); }, { false, false, true });
    Solver      solver(model, TightRelaxation(1e-9));
    SolveResult result = solver.Solve();
    EXPECT_TRUE(result.converged) << result.message;
    EXPECT_EQ(result.contactNodes, static_cast<int>(model.NodeSet("zmin").size()));
    EXPECT_LE(result.maxPenetration, 1e-6);
    return std::make_pair(model, result);
  };
  for (const double offset : { -0.2, 0.15 })
  {
    const auto [model, withOffset] = solve(0.0, offset);
    const auto [moved, reference] = solve(offset, 0.0);
    EXPECT_NEAR(LowestDeformedZ(model, withOffset.displacements), offset, 1e-6) << offset;
    const double difference = MaxDifference(withOffset.displacements, reference.displacements);
    RecordProperty(offset < 0.0 ? "maxDifferenceWiderMm" : "maxDifferenceNarrowerMm", Sci(difference));
    EXPECT_LT(difference, 1e-7) << offset;
    EXPECT_NEAR(SumOver(withOffset.reactionForces, model.NodeSet("zmin")).z(),
                SumOver(reference.reactionForces, moved.NodeSet("zmin")).z(),
                1e-6 * std::abs(SumOver(reference.reactionForces, moved.NodeSet("zmin")).z()));
  }
  Model bad = BlockAbovePlane(GetParam(), 0.3);
  bad.contactSurfaces[0].offset = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(Solver(bad, TightRelaxation(1e-9)), Error);
}

// (d) Block pressed onto a rigid sphere (body outside the closed surface).
TEST_P(ContactTest, BlockPressedOntoSphereStaysOutside)
{
  Model model = MakeBlockMesh(Vector3(8.0, 8.0, 4.0), { 8, 8, 4 }, GetParam(), MakeMaterial(3000.0, 0.45));
  const double   radius = 3.0;
  ContactSurface sphere = MakeEllipsoidSurface(Vector3::Constant(radius), 3, Vector3(4.0, 4.0, -radius - 0.05));
  sphere.bodySide = ContactSurface::Side::Outside;
  model.contactSurfaces.push_back(sphere);
  Prescribe(model, model.NodeSet("zmax"), [](const Vector3 &) { return Vector3(0.0, 0.0, -1.0); });

  Solver            solver(model, TightRelaxation(1e-8));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  ASSERT_TRUE(AllFinite(result.displacements));
  EXPECT_GT(result.contactNodes, 4);
  EXPECT_LE(result.maxPenetration, 1e-6);

  // Every node checked against the polyhedral sphere (convex: depth = distance
  // to the nearest face plane).
  double deepest = -std::numeric_limits<double>::max();
  int    touching = 0;
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    const double depth = DepthInsideConvex(model.contactSurfaces[0], model.nodes[n] + result.displacements[n]);
    deepest = std::max(deepest, depth);
    touching += depth > -1e-6;
  }
  EXPECT_LT(deepest, 1e-6);
  EXPECT_EQ(touching, result.contactNodes);
  EXPECT_GT(MinDeformedJacobian(model, result.displacements), 0.0);

  // Equilibrium: the sphere's push balances the top's reaction, and the
  // sphere pushes up.
  const Vector3 onTop = SumOver(result.reactionForces, model.NodeSet("zmax"));
  const Vector3 total = SumOver(result.reactionForces, model.NodeSet("all"));
  EXPECT_LT(onTop.z(), 0.0);
  EXPECT_LT(total.norm(), 1e-3 * std::abs(onTop.z()));
}

INSTANTIATE_TEST_SUITE_P(Cells,
                         ContactTest,
                         testing::Values(GridCells::Hexahedra, GridCells::Tetrahedra),
                         [](const testing::TestParamInfo<GridCells> & info) {
                           return info.param == GridCells::Hexahedra ? std::string("Hexahedra")
                                                                     : std::string("AnpTetrahedra");
                         });

// An open plane whose normal points away from the body (body on the inside).
TEST(Contact, PlaneWithBodyOnInsideSide)
{
  Model          model = MakeBlockMesh(kSize, kCellsPerAxis, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
  // Plane z = 2.5 above the block, normal +z: the block (below) is inside.
  ContactSurface plane = MakePlane(Vector3(2.0, 2.0, 2.5), Vector3::UnitZ(), 50.0);
  plane.bodySide = ContactSurface::Side::Inside;
  model.contactSurfaces.push_back(plane);
  Prescribe(model, model.NodeSet("zmin"), [](const Vector3 &) { return Vector3(0.0, 0.0, 1.0); });
  Solver            solver(model, TightRelaxation(1e-9));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  double highest = -std::numeric_limits<double>::max();
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
    highest = std::max(highest, model.nodes[n].z() + result.displacements[n].z());
  EXPECT_LT(highest, 2.5 + 1e-6);
  EXPECT_EQ(result.contactNodes, static_cast<int>(model.NodeSet("zmax").size()));
  // Compression by 0.5 mm of 2 mm between the moving bottom and the plane.
  const Vector3 onPlane = SumOver(result.reactionForces, model.NodeSet("zmax"));
  EXPECT_LT(onPlane.z(), 0.0);
  EXPECT_LT(std::hypot(onPlane.x(), onPlane.y()), 1e-4 * std::abs(onPlane.z()));
}

// A surface 0.05 mm inside the block's top face: the first step projects the
// top nodes, which the scene did not ask for; the solve converges and says so
// (how many, how deep), and says nothing when the surface clears the body.
TEST(Contact, NodesStartingBeyondTheSurfaceAreAWarning)
{
  const auto solve = [](double lid) {
    Model          model = MakeBlockMesh(kSize, kCellsPerAxis, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
    ContactSurface plane = MakePlane(Vector3(2.0, 2.0, lid), Vector3::UnitZ(), 50.0, "lid");
    plane.bodySide = ContactSurface::Side::Inside;
    model.contactSurfaces.push_back(plane);
    model.fixedConstraints.push_back({ "zmin", { true, true, true } });
    Solver      solver(model, TightRelaxation(1e-6));
    SolveResult result = solver.Solve();
    EXPECT_TRUE(result.converged) << result.message;
    return result;
  };
  const SolveResult inside = solve(kSize.z() - 0.05);
  ASSERT_EQ(inside.warnings.size(), 1u);
  // The 25 nodes of the top face (4 x 4 cells), all 0.05 mm beyond.
  EXPECT_NE(inside.warnings[0].find("25 contact node(s) start beyond contact surface 'lid'"), std::string::npos)
    << inside.warnings[0];
  EXPECT_NE(inside.warnings[0].find(" by 0.05 mm"), std::string::npos) << inside.warnings[0];
  EXPECT_TRUE(solve(kSize.z() + 0.05).warnings.empty());
}

// Contact code runs only when a surface is given, and says so.
TEST(Contact, ComponentListedOnlyWithSurfaces)
{
  Model                 model = BlockAbovePlane(GridCells::Hexahedra, 0.1);
  Solver                withPlane(model, TightRelaxation());
  const auto &          active = withPlane.ActiveComponents();
  EXPECT_NE(std::find(active.begin(), active.end(), "contact"), active.end());
  model.contactSurfaces.clear();
  Solver       without(model, TightRelaxation());
  const auto & none = without.ActiveComponents();
  EXPECT_EQ(std::find(none.begin(), none.end(), "contact"), none.end());
}

// Held at the top, no load, clear of the surface: nothing moves, nothing touches.
void
ExpectUnloadedModelStaysPut(Model model)
{
  model.fixedConstraints.push_back({ "zmax", { true, true, true } });
  Solver            solver(model, TightRelaxation(1e-9, 1000));
  const SolveResult result = solver.Solve();
  EXPECT_EQ(result.contactNodes, 0);
  EXPECT_EQ(result.maxPenetration, 0.0);
  EXPECT_LT(MaxNorm(result.displacements), 1e-12); // round-off of the internal forces at u = 0 only
}

// Minimal reproductions of contact defects.
//
// Nodes outside a closed surface, never loaded, must stay where they are. The
// block's bottom corners lie outside the sphere with their closest points on
// sphere edges (edge pseudo-normals decide the side there).
TEST(Contact, UnloadedNodesOutsideSphereStayPut)
{
  Model          model = MakeBlockMesh(Vector3(8.0, 8.0, 4.0), { 8, 8, 4 }, GridCells::Hexahedra);
  ContactSurface sphere = MakeEllipsoidSurface(Vector3::Constant(3.0), 3, Vector3(4.0, 4.0, -3.05));
  sphere.bodySide = ContactSurface::Side::Outside;
  model.contactSurfaces.push_back(sphere);
  for (const Vector3 & X : model.nodes)
    ASSERT_LT(DepthInsideConvex(sphere, X), 0.0);
  ExpectUnloadedModelStaysPut(model);
}

// Same with an open plane: nodes above the diagonal edge of its two triangles.
TEST(Contact, UnloadedNodesAbovePlaneDiagonalStayPut)
{
  Model          model = MakeBlockMesh(Vector3(4.0, 4.0, 2.0), { 4, 4, 2 }, GridCells::Hexahedra, Material{},
                                       Vector3(0.0, 0.0, 0.5));
  ContactSurface plane = MakePlane(Vector3(2.0, 2.0, 0.0), Vector3::UnitZ(), 50.0);
  plane.bodySide = ContactSurface::Side::Outside;
  model.contactSurfaces.push_back(plane);
  ExpectUnloadedModelStaysPut(model);
}

// A node held in one component only (a symmetry plane) is still free in the
// others and must not pass through a rigid surface in them.
TEST(Contact, PartiallyConstrainedNodesStillContact)
{
  Model          model = MakeBlockMesh(Vector3(2.0, 2.0, 2.0), { 2, 2, 2 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45),
                                       Vector3(0.0, 0.0, 0.1));
  ContactSurface plane = MakePlane(Vector3(1.0, 1.0, 0.0), Vector3::UnitZ(), 50.0);
  plane.bodySide = ContactSurface::Side::Outside;
  model.contactSurfaces.push_back(plane);
  model.fixedConstraints.push_back({ "xmin", { true, false, false } }); // symmetry plane x = 0
  model.fixedConstraints.push_back({ "ymin", { false, true, false } }); // symmetry plane y = 0
  Prescribe(model, model.NodeSet("zmax"), [](const Vector3 &) { return Vector3(0.0, 0.0, -0.5); },
            { false, false, true });
  Solver            solver(model, TightRelaxation(1e-9));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  for (Index n : model.NodeSet("zmin"))
    EXPECT_GT(model.nodes[n].z() + result.displacements[n].z(), -1e-6) << "bottom node " << n << " at "
                                                                        << model.nodes[n].transpose();
  EXPECT_EQ(result.contactNodes, 9);
}

// The normal a projection reports (the meshless contact's constraint
// direction) is the surface's interpolated normal: it changes continuously
// across an edge. Two points just either side of the bisector below a
// ridge (two facets sloping 15 degrees down from x = 0, the body above)
// project onto different facets; their normals, from the vertices'
// pseudo-normals interpolated at the closest points, differ by about 1
// degree, where the facets' own normals differ by 30. With the facets'
// normals a meshless slave pressed onto a ridge of Colin27's skull flipped
// between two constraint planes in a cycle that never converged
// (docs/solver.md); on a flat surface the normal is the facet's.
TEST(Contact, ReportedNormalsChangeContinuouslyAcrossARidge)
{
  const double   slope = std::tan(15.0 * M_PI / 180.0);
  ContactSurface roof;
  roof.bodySide = ContactSurface::Side::Outside;
  for (const double x : { -5.0, 0.0, 5.0 })
  {
    roof.vertices.emplace_back(x, -5.0, -slope * std::abs(x));
    roof.vertices.emplace_back(x, 5.0, -slope * std::abs(x));
  }
  // Counter-clockwise seen from above: normals up, towards the body.
  roof.triangles = { { 0, 2, 3 }, { 0, 3, 1 }, { 2, 4, 5 }, { 2, 5, 3 } };
  const std::vector<Vector3> reference = { Vector3(-0.01, 0.0, -0.5), Vector3(0.01, 0.0, -0.5),
                                           Vector3(0.0, 0.3, 1.0) };
  RigidContact               contact(roof, { 0, 1, 2 }, reference);
  std::vector<double>        u(3 * reference.size(), 0.0);
  const std::vector<char>    free(u.size(), 0);
  std::vector<char>          inContact(reference.size(), 0);
  std::vector<Vector3>       corrections, normals;
  contact.Enforce(u.data(), free, inContact, 1, &corrections, &normals);
  ASSERT_TRUE(inContact[0] && inContact[1]);
  EXPECT_FALSE(inContact[2]) << "a point above the roof stays free";
  EXPECT_LT(corrections[0].x(), 0.0) << "the left point projects onto the left facet";
  EXPECT_GT(corrections[1].x(), 0.0) << "the right point projects onto the right facet";
  const double degrees = std::acos(std::clamp(normals[0].dot(normals[1]), -1.0, 1.0)) * 180.0 / M_PI;
  RecordProperty("angleBetweenNormals_deg", std::to_string(degrees));
  EXPECT_LT(degrees, 2.0);
  for (int k = 0; k < 2; ++k)
  {
    EXPECT_NEAR(normals[k].norm(), 1.0, 1e-12);
    EXPECT_GT(normals[k].z(), std::cos(2.0 * M_PI / 180.0)) << "towards the body, nearly the ridge's bisector";
  }
}

// Contacts of one surface share its tree (an ensemble's members build it
// once; the last one used serves the next contact of its surface, as a
// gravity fit's solves follow each other), and no other surface's: one with a vertex moved, the other body
// side or the other orientation measures its own distances.
TEST(Contact, ContactsOfEqualSurfacesShareATreeAndOfOtherSurfacesDoNot)
{
  ContactSurface roof;
  roof.bodySide = ContactSurface::Side::Outside;
  roof.vertices = { Vector3(-5, -5, 0), Vector3(-5, 5, 0), Vector3(5, -5, 0), Vector3(5, 5, 0) };
  roof.triangles = { { 0, 2, 3 }, { 0, 3, 1 } }; // normals up, towards the body
  const std::vector<Vector3> reference = { Vector3(0.0, 0.0, 1.0) };
  const Vector3              above(1.0, 1.0, 2.0);
  const std::uint64_t        builtBefore = RigidContact::TreesBuilt();
  {
    const RigidContact earlier(roof, { 0 }, reference); // gone before the next: its tree is kept as the last used
  }
  const RigidContact first(roof, { 0 }, reference);
  EXPECT_EQ(RigidContact::TreesBuilt(), builtBefore + 1) << "the last tree used serves the next contact";
  ContactSurface             copy = roof;
  copy.name = "another name, the same surface";
  const RigidContact second(copy, { 0 }, reference);
  EXPECT_TRUE(second.SharesTreeWith(first));
  EXPECT_EQ(RigidContact::TreesBuilt(), builtBefore + 1);
  EXPECT_EQ(second.SignedDistance(above), first.SignedDistance(above));
  EXPECT_DOUBLE_EQ(first.SignedDistance(above), 2.0);

  ContactSurface lowered = roof;
  for (Vector3 & vertex : lowered.vertices)
  {
    vertex.z() -= 1.0;
  }
  const RigidContact third(lowered, { 0 }, reference);
  EXPECT_FALSE(third.SharesTreeWith(first));
  EXPECT_DOUBLE_EQ(third.SignedDistance(above), 3.0);

  ContactSurface otherSide = roof;
  otherSide.bodySide = ContactSurface::Side::Inside;
  const RigidContact fourth(otherSide, { 0 }, reference);
  EXPECT_FALSE(fourth.SharesTreeWith(first));
  EXPECT_DOUBLE_EQ(fourth.SignedDistance(above), -2.0);

  ContactSurface flipped = roof;
  flipped.flipNormals = true;
  const RigidContact fifth(flipped, { 0 }, reference);
  EXPECT_FALSE(fifth.SharesTreeWith(first));
  EXPECT_DOUBLE_EQ(fifth.SignedDistance(above), -2.0);
  EXPECT_EQ(RigidContact::TreesBuilt(), builtBefore + 4);
}

// An ellipsoidal brain inside a closed rigid skull (contact offset `offset`),
// its top surface nodes held, gravity pulling the rest down onto the skull.
Model
BrainHeldAtItsTopInSkull(double offset)
{
  Model          model = MakeEllipsoidMesh(Vector3(30.0, 36.0, 26.0), 6.0, GridCells::Tetrahedra);
  ContactSurface skull = MakeEllipsoidSurface(Vector3(36.0, 42.0, 32.0), 3);
  skull.bodySide = ContactSurface::Side::Inside;
  skull.offset = offset;
  model.contactSurfaces.push_back(skull);
  std::vector<Index> top;
  for (Index n : model.NodeSet("surface"))
    if (model.nodes[n].z() > 20.0)
      top.push_back(n);
  model.nodeSets["top"] = top;
  model.fixedConstraints.push_back({ "top", { true, true, true } });
  model.bodyAcceleration = Vector3(0.0, 0.0, -9810.0);
  return model;
}

// A body inside a closed rigid skull with gravity: no node leaves the skull.
TEST(Contact, BrainInsideSkullUnderGravity)
{
  const Model            model = BrainHeldAtItsTopInSkull(0.0);
  const ContactSurface & skull = model.contactSurfaces[0];
  for (const Vector3 & X : model.nodes)
    ASSERT_GT(DepthInsideConvex(skull, X), 0.0) << "the mesh must start inside the skull";
  ASSERT_FALSE(model.NodeSet("top").empty());

  Solver            solver(model, TightRelaxation(1e-5));
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  ASSERT_TRUE(AllFinite(result.displacements));
  double outside = -std::numeric_limits<double>::max();
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
    outside = std::max(outside, -DepthInsideConvex(model.contactSurfaces[0], model.nodes[n] + result.displacements[n]));
  EXPECT_LT(outside, 1e-6) << "a node left the skull by " << outside << " mm";
  EXPECT_GT(result.contactNodes, 0);
  EXPECT_GT(MinDeformedJacobian(model, result.displacements), 0.0);
}

// The same brain with the skull's contact offset: +1 mm keeps every node 1 mm
// inside the skull (a narrower gap), -0.3 mm lets them 0.3 mm beyond it (a wider
// one); either way the contact settles, also from the steady state without
// the offset (slaves on the surface, as an uncertainty member starts).
TEST(Contact, BrainInsideSkullUnderGravityWithAnOffset)
{
  for (const double offset : { 1.0, -0.3 })
  {
    const Model       model = BrainHeldAtItsTopInSkull(offset);
    Solver            first(BrainHeldAtItsTopInSkull(0.0), TightRelaxation(1e-5));
    const SolveResult rested = first.Solve();
    Solver            solver(model, TightRelaxation(1e-5));
    solver.SetWarmStart(WarmStartFrom(rested)); // slaves on the surface, as an ensemble member starts
    const SolveResult result = solver.Solve();
    ASSERT_TRUE(result.converged) << "offset " << offset << ": " << result.message;
    double shallowest = std::numeric_limits<double>::max();
    for (std::size_t n = 0; n < model.nodes.size(); ++n)
      shallowest = std::min(shallowest, DepthInsideConvex(model.contactSurfaces[0], model.nodes[n] + result.displacements[n]));
    // Against the polyhedron's face planes, within 1 % of the offset.
    EXPECT_GT(shallowest, offset - 0.01 * std::abs(offset)) << offset;
    EXPECT_LT(shallowest, offset + 0.01 * std::abs(offset)) << offset << ": the brain rests on the offset skull";
    EXPECT_GT(result.contactNodes, 0);
  }
}

} // namespace
} // namespace bmr
