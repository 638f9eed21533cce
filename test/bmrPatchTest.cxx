// Patch tests on distorted meshes: a linear displacement field prescribed on the
// boundary must be reproduced exactly at the interior nodes (the homogeneous
// deformation is also the exact nonlinear solution), for hexahedra with
// hourglass control, ANP and linear tetrahedra and mixed meshes. And internal
// forces: zero for a large rigid rotation, zero at interior nodes for a
// homogeneous stretch.
#include "bmrTestUtilities.h"

#include <gtest/gtest.h>

#include <sstream>

namespace bmr
{
namespace
{
using namespace bmr::test;

struct PatchCase
{
  GridCells              cells;
  TetrahedronFormulation tetrahedron;
  const char *           name;
};

std::string
PatchName(const testing::TestParamInfo<PatchCase> & info)
{
  return info.param.name;
}

class PatchTest : public testing::TestWithParam<PatchCase>
{
protected:
  Model DistortedBlock() const
  {
    Model model = MakeBlockMesh(Vector3(10.0, 9.0, 8.0), { 4, 4, 4 }, GetParam().cells, MakeMaterial(3000.0, 0.49));
    const std::vector<Vector3> regular = model.nodes;
    DistortInteriorNodes(model, 0.2, 7);
    // The generator must actually distort the interior (else this is no patch test).
    double moved = 0.0;
    for (std::size_t n = 0; n < regular.size(); ++n)
      moved = std::max(moved, (model.nodes[n] - regular[n]).norm());
    EXPECT_GT(moved, 0.1 * 2.0) << "interior nodes should move by up to 0.2 x spacing (2 mm)";
    return model;
  }

  SolverSettings Settings() const
  {
    SolverSettings settings = TightRelaxation(1e-11);
    settings.tetrahedron = GetParam().tetrahedron;
    return settings;
  }
};

TEST_P(PatchTest, LinearFieldReproducedAtInteriorNodes)
{
  Model   model = DistortedBlock();
  Matrix3 A;
  A << 1.0e-3, -0.5e-3, 0.8e-3, //
    0.3e-3, -1.2e-3, 0.4e-3,    //
    -0.7e-3, 0.9e-3, 0.6e-3;
  const Vector3           c(0.01, -0.02, 0.015); // mm
  const DisplacementField exact = HomogeneousField(Matrix3::Identity() + A, c);
  const std::vector<Index> boundary = BlockBoundaryNodes(model);
  const std::vector<Index> interior = ComplementNodes(model, boundary);
  ASSERT_EQ(interior.size(), 27u);
  Prescribe(model, boundary, exact);

  Solver            solver(model, Settings());
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;
  const double scale = MaxFieldNorm(model, exact);
  const double error = MaxNodalError(model, result.displacements, exact, interior);
  RecordProperty("relativeError", Sci(error / scale));
  RecordProperty("steps", result.steps);
  EXPECT_LT(error, 1e-6 * scale) << "max interior error " << error << " mm, field scale " << scale << " mm";
}

TEST_P(PatchTest, RigidRotationGivesNoInternalForce)
{
  Model model = DistortedBlock();
  // Reference: the internal forces of a 1% stretch along x.
  Solver                     solver(model, Settings());
  std::vector<Vector3>       stretch(model.nodes.size());
  const Matrix3              S = Eigen::Vector3d(1.01, 1.0, 1.0).asDiagonal();
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
    stretch[n] = (S - Matrix3::Identity()) * model.nodes[n];
  const double reference = MaxNorm(solver.InternalForces(stretch));
  ASSERT_GT(reference, 0.0);

  // 90 degrees about a skew axis, about a point away from the origin.
  const Matrix3        R = RotationAboutAxis(Vector3(1.0, 2.0, -0.5), M_PI / 2.0);
  const Vector3        pivot(3.0, -2.0, 1.0);
  std::vector<Vector3> rotation(model.nodes.size());
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
    rotation[n] = R * (model.nodes[n] - pivot) + pivot - model.nodes[n];
  const double rotated = MaxNorm(solver.InternalForces(rotation));
  RecordProperty("relativeForce", Sci(rotated / reference));
  EXPECT_LT(rotated, 1e-9 * reference) << "max |f| of rotation " << rotated << " N, of 1% stretch " << reference
                                       << " N";
}

TEST_P(PatchTest, HomogeneousStretchLoadsOnlyBoundaryNodes)
{
  Model                    model = DistortedBlock();
  Solver                   solver(model, Settings());
  const Matrix3            F = Eigen::Vector3d(1.15, 0.9, 0.95).asDiagonal();
  const DisplacementField  field = HomogeneousField(F);
  std::vector<Vector3>     u(model.nodes.size());
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
    u[n] = field(model.nodes[n]);
  const std::vector<Vector3> forces = solver.InternalForces(u);
  const std::vector<Index>   boundary = BlockBoundaryNodes(model);
  const std::vector<Index>   interior = ComplementNodes(model, boundary);
  const double               boundaryForce = MaxNorm(forces, boundary);
  ASSERT_GT(boundaryForce, 0.0);
  EXPECT_LT(MaxNorm(forces, interior), 1e-9 * boundaryForce);

  // Resultant on the xmax face = P e1 A0 (N). Its nodes include edge nodes whose
  // side-face tractions (P e2, P e3) have no x-component for diagonal F, and the
  // lateral faces xmin/xmax have flat, undistorted node positions.
  const NeoHookean law(model.materials[0]);
  const Matrix3    P = law.FirstPiola(F);
  const double     expected = P(0, 0) * 9.0 * 8.0 * PascalSquareMillimetreToNewton;
  const Vector3    onXmax = SumOver(forces, model.NodeSet("xmax"));
  EXPECT_NEAR(onXmax.x(), expected, 1e-9 * std::abs(expected));
  // Equilibrium: internal forces of any displacement field sum to zero.
  EXPECT_LT(SumOver(forces, model.NodeSet("all")).norm(), 1e-9 * std::abs(expected));
}

INSTANTIATE_TEST_SUITE_P(Meshes,
                         PatchTest,
                         testing::Values(PatchCase{ GridCells::Hexahedra, TetrahedronFormulation::AverageNodalPressure,
                                                    "Hexahedra" },
                                         PatchCase{ GridCells::Tetrahedra, TetrahedronFormulation::AverageNodalPressure,
                                                    "AnpTetrahedra" },
                                         PatchCase{ GridCells::Tetrahedra, TetrahedronFormulation::Linear,
                                                    "LinearTetrahedra" },
                                         PatchCase{ GridCells::Mixed, TetrahedronFormulation::AverageNodalPressure,
                                                    "Mixed" }),
                         PatchName);

// The generator keeps every cell valid and leaves the box faces in place.
TEST(MeshGenerators, DistortionKeepsCellsValidAndBoundaryFixed)
{
  for (GridCells cells : { GridCells::Hexahedra, GridCells::Tetrahedra, GridCells::Mixed })
  {
    Model model = MakeBlockMesh(Vector3(4.0, 5.0, 6.0), { 4, 5, 6 }, cells);
    const std::vector<Vector3> regular = model.nodes;
    DistortInteriorNodes(model, 0.25, 3);
    for (Index n : BlockBoundaryNodes(model))
      EXPECT_EQ(model.nodes[n], regular[n]);
    double volume = 0.0;
    for (std::size_t c = 0; c < model.cells.size(); ++c)
    {
      const double v = CellVolume(model, static_cast<Index>(c));
      EXPECT_GT(v, 0.0) << "cell " << c;
      volume += v;
    }
    // Conforming meshes tile the box exactly (hexahedra share bilinear faces);
    // a mixed mesh's hexahedron-tetrahedron interface is a bilinear face against
    // two flat triangles, so there the sum is only close.
    EXPECT_NEAR(volume, 120.0, cells == GridCells::Mixed ? 0.1 : 1e-9);
    EXPECT_GT(MinDeformedJacobian(model, std::vector<Vector3>(model.nodes.size(), Vector3::Zero())), 0.0);
    EXPECT_NO_THROW(model.Validate());
    // Same seed, same mesh.
    Model again = MakeBlockMesh(Vector3(4.0, 5.0, 6.0), { 4, 5, 6 }, cells);
    DistortInteriorNodes(again, 0.25, 3);
    EXPECT_TRUE(BitwiseEqual(model.nodes, again.nodes));
  }
}

// Conforming Kuhn split: every interior triangle is shared by exactly two
// tetrahedra and the boundary has 2 triangles per boundary grid face.
TEST(MeshGenerators, KuhnSplitIsConforming)
{
  Model model = MakeBlockMesh(Vector3(3.0, 4.0, 5.0), { 3, 4, 5 }, GridCells::Tetrahedra);
  ASSERT_EQ(model.cells.size(), 6u * 60u);
  std::map<std::array<Index, 3>, int> faces;
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const Cell & cell = model.cells[c];
    ASSERT_EQ(cell.type, CellType::Tetrahedron);
    EXPECT_NEAR(CellVolume(model, static_cast<Index>(c)), 1.0 / 6.0, 1e-12);
    const int local[4][3] = { { 0, 1, 2 }, { 0, 1, 3 }, { 0, 2, 3 }, { 1, 2, 3 } };
    for (const auto & f : local)
    {
      std::array<Index, 3> key{ cell.nodes[f[0]], cell.nodes[f[1]], cell.nodes[f[2]] };
      std::sort(key.begin(), key.end());
      ++faces[key];
    }
  }
  int boundaryFaces = 0;
  for (const auto & entry : faces)
  {
    EXPECT_LE(entry.second, 2);
    boundaryFaces += entry.second == 1;
  }
  EXPECT_EQ(boundaryFaces, 2 * 2 * (3 * 4 + 4 * 5 + 3 * 5));
  EXPECT_EQ(model.BoundaryTriangles().size(), static_cast<std::size_t>(boundaryFaces));
}

TEST(MeshGenerators, BlockNodeSetsAndHexOrdering)
{
  const Vector3 origin(1.0, -2.0, 3.0);
  Model         model = MakeBlockMesh(Vector3(2.0, 3.0, 4.0), { 2, 3, 4 }, GridCells::Mixed, Material{}, origin);
  EXPECT_EQ(model.nodes.size(), 3u * 4u * 5u);
  EXPECT_EQ(model.NodeSet("xmin").size(), 20u);
  EXPECT_EQ(model.NodeSet("ymax").size(), 15u);
  EXPECT_EQ(model.NodeSet("zmin").size(), 12u);
  EXPECT_EQ(model.NodeSet("all").size(), model.nodes.size());
  for (Index n : model.NodeSet("xmax"))
    EXPECT_DOUBLE_EQ(model.nodes[n].x(), 3.0);
  for (Index n : model.NodeSet("zmin"))
    EXPECT_DOUBLE_EQ(model.nodes[n].z(), 3.0);
  int hexahedra = 0, tetrahedra = 0;
  for (const Cell & cell : model.cells)
  {
    if (cell.type == CellType::Hexahedron)
    {
      ++hexahedra;
      // VTK order: corner c at offset (c&1 ^ c>>1&1, c>>1&1, c>>2) of the cell.
      const Vector3 base = model.nodes[cell.nodes[0]];
      const int     offsets[8][3] = { { 0, 0, 0 }, { 1, 0, 0 }, { 1, 1, 0 }, { 0, 1, 0 },
                                      { 0, 0, 1 }, { 1, 0, 1 }, { 1, 1, 1 }, { 0, 1, 1 } };
      for (int c = 0; c < 8; ++c)
        EXPECT_LT((model.nodes[cell.nodes[c]] - base - Vector3(offsets[c][0], offsets[c][1], offsets[c][2])).norm(),
                  1e-12);
      EXPECT_LT(base.x() + 0.5, origin.x() + 1.0);
    }
    else
    {
      ++tetrahedra;
    }
  }
  EXPECT_EQ(hexahedra, 12);
  EXPECT_EQ(tetrahedra, 6 * 12);
}

TEST(MeshGenerators, EllipsoidMeshAndSurface)
{
  const Vector3 semiAxes(70.0, 85.0, 60.0);
  Model         model = MakeEllipsoidMesh(semiAxes, 10.0, GridCells::Hexahedra);
  double        volume = 0.0;
  for (std::size_t c = 0; c < model.cells.size(); ++c)
    volume += CellVolume(model, static_cast<Index>(c));
  const double exact = 4.0 / 3.0 * M_PI * semiAxes.prod();
  EXPECT_NEAR(volume, exact, 0.1 * exact); // staircase approximation of the ellipsoid
  EXPECT_NO_THROW(model.Validate());
  // "surface" is exactly the boundary of the cell union.
  EXPECT_EQ(model.NodeSet("surface"), model.BoundaryNodes());
  Model tets = MakeEllipsoidMesh(semiAxes, 10.0, GridCells::Tetrahedra);
  EXPECT_EQ(tets.cells.size(), 6 * model.cells.size());
  EXPECT_EQ(tets.NodeSet("surface"), tets.BoundaryNodes());

  const Vector3        centre(1.0, 2.0, 3.0);
  const ContactSurface skull = MakeEllipsoidSurface(Vector3(75.0, 90.0, 65.0), 3, centre);
  EXPECT_EQ(skull.triangles.size(), 20u * 64u);
  EXPECT_EQ(skull.vertices.size(), 10u * 64u + 2u);
  double enclosed = 0.0;
  for (const auto & t : skull.triangles)
  {
    const Vector3 a = skull.vertices[t[0]] - centre, b = skull.vertices[t[1]] - centre,
                  c = skull.vertices[t[2]] - centre;
    EXPECT_GT(TriangleNormal(skull, t).dot((a + b + c) / 3.0), 0.0); // outward
    enclosed += a.dot(b.cross(c)) / 6.0;
  }
  const double ellipsoidVolume = 4.0 / 3.0 * M_PI * 75.0 * 90.0 * 65.0;
  EXPECT_NEAR(enclosed, ellipsoidVolume, 0.02 * ellipsoidVolume);
  EXPECT_LT(enclosed, ellipsoidVolume); // inscribed polyhedron
  for (const auto & v : skull.vertices)
    EXPECT_NEAR((v - centre).cwiseQuotient(Vector3(75.0, 90.0, 65.0)).norm(), 1.0, 1e-12);
}

} // namespace
} // namespace bmr
