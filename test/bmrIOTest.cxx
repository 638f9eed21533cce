// Mesh, surface and result file I/O: exact round trips, clear errors, and
// nothing half-written left behind.
#include "bmrMeshIO.h"

#include <Eigen/Geometry>
#include "bmrTemporaryFolderTest.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;

namespace
{

// Each test gets its own folder (TemporaryFolderTest).
class IOTest : public bmr::test::TemporaryFolderTest
{
protected:

  std::string Path(const std::string & name) const { return (m_Folder / name).string(); }

  std::vector<std::string> FilesInFolder() const
  {
    std::vector<std::string> names;
    for (const auto & entry : fs::directory_iterator(m_Folder))
    {
      names.push_back(entry.path().filename().string());
    }
    std::sort(names.begin(), names.end());
    return names;
  }

  void WriteText(const std::string & name, const std::string & text) const
  {
    std::ofstream stream(Path(name));
    stream << text;
  }

};

/** One unit hexahedron and a tetrahedron on its top face, two materials, and
 *  coordinates that are not short decimals (a round trip must be exact). */
bmr::Model
TwoCellModel()
{
  bmr::Model model;
  const double a = 1.0 / 3.0;
  model.nodes = { { 0.1, 0.2, 0.3 },     { 1.0 + a, 0.2, 0.3 }, { 1.0 + a, 1.0 + a, 0.3 }, { 0.1, 1.0 + a, 0.3 },
                  { 0.1, 0.2, 1.0 + a }, { 1.0 + a, 0.2, 1.0 + a }, { 1.0 + a, 1.0 + a, 1.0 + a },
                  { 0.1, 1.0 + a, 1.0 + a }, { 0.5, 0.6, 2.0 + a } };
  bmr::Cell hexahedron;
  hexahedron.type = bmr::CellType::Hexahedron;
  hexahedron.nodes = { 0, 1, 2, 3, 4, 5, 6, 7 };
  hexahedron.material = 0;
  bmr::Cell tetrahedron;
  tetrahedron.type = bmr::CellType::Tetrahedron;
  tetrahedron.nodes = { 4, 5, 6, 8 };
  tetrahedron.material = 1;
  model.cells = { hexahedron, tetrahedron };
  model.materials = { bmr::Material{ "soft", 1000.0, 0.45, 1000.0 }, bmr::Material{ "stiff", 6000.0, 0.49, 1100.0 } };
  model.nodeSets["top"] = { 4, 5, 6, 7, 8 };
  model.nodeSets["corner"] = { 0 };
  return model;
}

using bmr::test::ErrorMessage;


void
ExpectSameMesh(const bmr::Model & expected, const bmr::MeshData & read)
{
  ASSERT_EQ(read.model.nodes.size(), expected.nodes.size());
  for (std::size_t node = 0; node < expected.nodes.size(); ++node)
  {
    EXPECT_EQ(read.model.nodes[node], expected.nodes[node]) << "node " << node;
  }
  ASSERT_EQ(read.model.cells.size(), expected.cells.size());
  for (std::size_t cell = 0; cell < expected.cells.size(); ++cell)
  {
    EXPECT_EQ(read.model.cells[cell].type, expected.cells[cell].type) << "cell " << cell;
    for (int local = 0; local < bmr::NodesPerCell(expected.cells[cell].type); ++local)
    {
      EXPECT_EQ(read.model.cells[cell].nodes[local], expected.cells[cell].nodes[local]) << "cell " << cell;
    }
  }
  ASSERT_EQ(read.cellLabels.size(), expected.cells.size());
  for (std::size_t cell = 0; cell < expected.cells.size(); ++cell)
  {
    EXPECT_EQ(read.cellLabels[cell], expected.cells[cell].material);
  }
}

/** Enclosed volume by the divergence theorem: positive for outward normals. */
double
EnclosedVolume(const bmr::ContactSurface & surface)
{
  double volume = 0.0;
  for (const auto & triangle : surface.triangles)
  {
    volume += surface.vertices[triangle[0]].dot(surface.vertices[triangle[1]].cross(surface.vertices[triangle[2]]));
  }
  return volume / 6.0;
}

/** ASCII STL of the unit cube with outward normals: 12 facets, each vertex repeated. */
std::string
UnitCubeStl()
{
  const int faces[6][4] = { { 0, 3, 2, 1 }, { 4, 5, 6, 7 }, { 0, 1, 5, 4 }, { 1, 2, 6, 5 }, { 2, 3, 7, 6 }, { 3, 0, 4, 7 } };
  const double corners[8][3] = { { 0, 0, 0 }, { 1, 0, 0 }, { 1, 1, 0 }, { 0, 1, 0 },
                                 { 0, 0, 1 }, { 1, 0, 1 }, { 1, 1, 1 }, { 0, 1, 1 } };
  std::ostringstream stl;
  stl << "solid cube\n";
  const auto vertex = [&](int corner) {
    stl << "      vertex " << corners[corner][0] << " " << corners[corner][1] << " " << corners[corner][2] << "\n";
  };
  for (const auto & face : faces)
  {
    for (const auto & triangle : { std::array<int, 3>{ face[0], face[1], face[2] }, std::array<int, 3>{ face[0], face[2], face[3] } })
    {
      stl << "  facet normal 0 0 0\n    outer loop\n";
      for (const int corner : triangle)
      {
        vertex(corner);
      }
      stl << "    endloop\n  endfacet\n";
    }
  }
  stl << "endsolid cube\n";
  return stl.str();
}

} // namespace

TEST_F(IOTest, VtuMeshRoundTripIsExact)
{
  const bmr::Model model = TwoCellModel();
  bmr::WriteMesh(Path("two-cells.vtu"), model);
  EXPECT_EQ(FilesInFolder(), std::vector<std::string>{ "two-cells.vtu" }); // no temporary left

  const bmr::MeshData read = bmr::ReadMesh(Path("two-cells.vtu"));
  ExpectSameMesh(model, read);
  EXPECT_TRUE(read.model.materials.empty()); // materials come from the scene

  // Node sets travel as point-data masks.
  ASSERT_EQ(read.pointData.count("top"), 1u);
  const bmr::DataArray & top = read.pointData.at("top");
  EXPECT_EQ(top.components, 1);
  EXPECT_EQ(top.values, (std::vector<double>{ 0, 0, 0, 0, 1, 1, 1, 1, 1 }));
  EXPECT_EQ(read.pointData.at("corner").values, (std::vector<double>{ 1, 0, 0, 0, 0, 0, 0, 0, 0 }));
}

TEST_F(IOTest, LegacyVtkMeshRoundTrip)
{
  bmr::Model model = TwoCellModel();
  // The legacy ASCII format is for small hand-readable files: short decimals.
  model.nodes = { { 0, 0, 0 }, { 1, 0, 0 }, { 1, 1, 0 }, { 0, 1, 0 }, { 0, 0, 1 },
                  { 1, 0, 1 }, { 1, 1, 1 }, { 0, 1, 1 }, { 0.5, 0.25, 2.5 } };
  bmr::WriteMesh(Path("two-cells.vtk"), model);
  const bmr::MeshData read = bmr::ReadMesh(Path("two-cells.vtk"));
  ExpectSameMesh(model, read);
}

TEST_F(IOTest, OtherLabelArrayAndMissingLabelArray)
{
  bmr::WriteMesh(Path("two-cells.vtu"), TwoCellModel());
  const bmr::MeshData unlabelled = bmr::ReadMesh(Path("two-cells.vtu"), "tissue");
  EXPECT_TRUE(unlabelled.cellLabels.empty());
  EXPECT_EQ(unlabelled.cellData.count("material"), 1u);
}

TEST_F(IOTest, UnsupportedCellTypeIsNamed)
{
  // A hexahedron followed by a wedge (VTK type 13).
  WriteText("wedge.vtk", "# vtk DataFile Version 3.0\nwedge\nASCII\nDATASET UNSTRUCTURED_GRID\n"
                         "POINTS 8 double\n0 0 0 1 0 0 1 1 0 0 1 0 0 0 1 1 0 1 1 1 1 0 1 1\n"
                         "CELLS 2 16\n8 0 1 2 3 4 5 6 7\n6 0 1 2 4 5 6\n"
                         "CELL_TYPES 2\n12\n13\n");
  const std::string message = ErrorMessage([&] { bmr::ReadMesh(Path("wedge.vtk")); });
  EXPECT_CONTAINS(message, "cell 1 ");
  EXPECT_CONTAINS(message, "VTK_WEDGE");
  EXPECT_CONTAINS(message, "VTK_HEXAHEDRON");
  EXPECT_CONTAINS(message, "VTK_TETRA");
  EXPECT_CONTAINS(message, Path("wedge.vtk"));
}

TEST_F(IOTest, NonIntegerLabelIsNamed)
{
  WriteText("labels.vtk", "# vtk DataFile Version 3.0\nlabels\nASCII\nDATASET UNSTRUCTURED_GRID\n"
                          "POINTS 5 double\n0 0 0 1 0 0 0 1 0 0 0 1 1 1 1\n"
                          "CELLS 2 10\n4 0 1 2 3\n4 1 2 3 4\nCELL_TYPES 2\n10\n10\n"
                          "CELL_DATA 2\nSCALARS material double 1\nLOOKUP_TABLE default\n1\n2.5\n");
  const std::string message = ErrorMessage([&] { bmr::ReadMesh(Path("labels.vtk")); });
  EXPECT_CONTAINS(message, "cell 1 ");
  EXPECT_CONTAINS(message, "2.5");
  EXPECT_CONTAINS(message, "integers");
}

TEST_F(IOTest, MissingAndUnreadableMeshesNameThePath)
{
  const std::string missing = Path("no-such-mesh.vtu");
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::ReadMesh(missing); }), missing);
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::ReadMesh(missing); }), "does not exist");

  WriteText("garbage.vtu", "this is not XML");
  const std::string garbage = ErrorMessage([&] { bmr::ReadMesh(Path("garbage.vtu")); });
  EXPECT_CONTAINS(garbage, Path("garbage.vtu"));

  WriteText("mesh.msh", "$MeshFormat");
  const std::string extension = ErrorMessage([&] { bmr::ReadMesh(Path("mesh.msh")); });
  EXPECT_CONTAINS(extension, ".msh");
  EXPECT_CONTAINS(extension, ".vtu");
}

TEST_F(IOTest, ResultVtuHoldsDisplacementsForcesAndStress)
{
  const bmr::Model model = TwoCellModel();
  bmr::SolveResult result;
  for (std::size_t node = 0; node < model.nodes.size(); ++node)
  {
    const bmr::Vector3 & x = model.nodes[node];
    result.displacements.emplace_back(0.1 * x.z(), -0.2 * x.x() + 1.0 / 7.0, std::sqrt(2.0) * x.y());
    result.reactionForces.emplace_back(node == 0 ? 1.5e-3 : 0.0, 0.0, node == 8 ? -2.25e-3 : 0.0);
  }
  for (std::size_t cell = 0; cell < model.cells.size(); ++cell)
  {
    Eigen::Matrix3d stress;
    stress << 1, 2, 3, 4, 5, 6, 7, 8, 9 + static_cast<double>(cell);
    result.cauchyStress.push_back(stress);
  }
  bmr::WriteResultVtu(Path("result.vtu"), model, result);
  EXPECT_EQ(FilesInFolder(), std::vector<std::string>{ "result.vtu" });

  const bmr::MeshData read = bmr::ReadMesh(Path("result.vtu"));
  ExpectSameMesh(model, read); // "material" holds the material indices
  const bmr::DataArray & displacement = read.pointData.at("displacement");
  ASSERT_EQ(displacement.components, 3);
  ASSERT_EQ(displacement.Tuples(), model.nodes.size());
  const bmr::DataArray & reaction = read.pointData.at("reaction_force");
  ASSERT_EQ(reaction.components, 3);
  for (std::size_t node = 0; node < model.nodes.size(); ++node)
  {
    for (int c = 0; c < 3; ++c)
    {
      EXPECT_EQ(displacement.values[3 * node + c], result.displacements[node][c]);
      EXPECT_EQ(reaction.values[3 * node + c], result.reactionForces[node][c]);
    }
  }
  const bmr::DataArray & stress = read.cellData.at("cauchy_stress");
  ASSERT_EQ(stress.components, 9);
  EXPECT_EQ(stress.values[1], 2.0);  // row-major: sigma(0, 1)
  EXPECT_EQ(stress.values[3], 4.0);  // sigma(1, 0)
  EXPECT_EQ(stress.values[9 + 8], 10.0);
}

TEST_F(IOTest, ResultWithoutStressHasNoStressArray)
{
  const bmr::Model model = TwoCellModel();
  bmr::SolveResult result;
  result.displacements.assign(model.nodes.size(), bmr::Vector3(0.0, 0.0, -1.0));
  bmr::WriteResultVtu(Path("result.vtu"), model, result);
  const bmr::MeshData read = bmr::ReadMesh(Path("result.vtu"));
  EXPECT_EQ(read.cellData.count("cauchy_stress"), 0u);
  EXPECT_EQ(read.pointData.at("displacement").values[2], -1.0);
  EXPECT_EQ(read.pointData.at("reaction_force").values, std::vector<double>(3 * model.nodes.size(), 0.0));
}

TEST_F(IOTest, BadResultLeavesNoFile)
{
  const bmr::Model model = TwoCellModel();
  bmr::SolveResult result;
  result.displacements.assign(3, bmr::Vector3::Zero()); // wrong size
  const std::string message = ErrorMessage([&] { bmr::WriteResultVtu(Path("result.vtu"), model, result); });
  EXPECT_CONTAINS(message, "3 displacements for 9 nodes");
  EXPECT_TRUE(FilesInFolder().empty());

  result.displacements.assign(model.nodes.size(), bmr::Vector3::Zero());
  const std::string folder = Path("missing-folder/result.vtu");
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::WriteResultVtu(folder, model, result); }), "does not exist");
  EXPECT_TRUE(FilesInFolder().empty());
}

TEST_F(IOTest, StlSurfaceIsMergedAndKeepsOrientation)
{
  WriteText("cube.stl", UnitCubeStl());
  const bmr::ContactSurface surface = bmr::ReadSurface(Path("cube.stl"));
  EXPECT_EQ(surface.triangles.size(), 12u);
  EXPECT_EQ(surface.vertices.size(), 8u); // 36 STL vertices merged
  EXPECT_NEAR(EnclosedVolume(surface), 1.0, 1e-12);
  EXPECT_EQ(surface.name, "cube");
  EXPECT_FALSE(surface.flipNormals);
}

TEST_F(IOTest, ObjQuadsAreTriangulated)
{
  WriteText("cube.obj", "v 0 0 0\nv 2 0 0\nv 2 2 0\nv 0 2 0\nv 0 0 2\nv 2 0 2\nv 2 2 2\nv 0 2 2\n"
                        "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n");
  const bmr::ContactSurface surface = bmr::ReadSurface(Path("cube.obj"));
  EXPECT_EQ(surface.triangles.size(), 12u);
  EXPECT_EQ(surface.vertices.size(), 8u);
  EXPECT_NEAR(EnclosedVolume(surface), 8.0, 1e-12);
}

TEST_F(IOTest, LegacyPolyDataWithStripAndDegenerateTriangle)
{
  // A strip of 4 points (2 triangles) and one triangle that collapses after merging.
  WriteText("strip.vtk", "# vtk DataFile Version 3.0\nstrip\nASCII\nDATASET POLYDATA\n"
                         "POINTS 6 double\n0 0 0 1 0 0 0 1 0 1 1 0 0 0 0 5 5 5\n"
                         "POLYGONS 1 4\n3 0 4 5\nTRIANGLE_STRIPS 1 5\n4 0 1 2 3\n");
  const bmr::ContactSurface surface = bmr::ReadSurface(Path("strip.vtk"));
  ASSERT_EQ(surface.triangles.size(), 2u);
  EXPECT_EQ(surface.vertices.size(), 4u); // the point (5,5,5) is used by no remaining triangle
  for (const auto & triangle : surface.triangles)
  {
    const bmr::Vector3 normal = (surface.vertices[triangle[1]] - surface.vertices[triangle[0]])
                                  .cross(surface.vertices[triangle[2]] - surface.vertices[triangle[0]]);
    EXPECT_GT(normal.z(), 0.0); // strip triangles keep one orientation
  }
}

TEST_F(IOTest, EmptySurfaceIsRejected)
{
  WriteText("points.vtk", "# vtk DataFile Version 3.0\npoints\nASCII\nDATASET POLYDATA\n"
                          "POINTS 2 double\n0 0 0 1 0 0\nLINES 1 3\n2 0 1\n");
  const std::string message = ErrorMessage([&] { bmr::ReadSurface(Path("points.vtk")); });
  EXPECT_CONTAINS(message, Path("points.vtk"));
  EXPECT_CONTAINS(message, "no triangles");

  EXPECT_CONTAINS(ErrorMessage([&] { bmr::ReadSurface(Path("missing.stl")); }), Path("missing.stl"));
  WriteText("surface.ply", "ply");
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::ReadSurface(Path("surface.ply")); }), ".stl");
}

TEST_F(IOTest, AtomicTextFileReplacesWholeFile)
{
  WriteText("report.json", "old contents that are longer than the new ones");
  bmr::WriteTextFileAtomically(Path("report.json"), "{}\n");
  std::ifstream     stream(Path("report.json"));
  const std::string text((std::istreambuf_iterator<char>(stream)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text, "{}\n");
  EXPECT_EQ(FilesInFolder(), std::vector<std::string>{ "report.json" });
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::WriteTextFileAtomically(Path("nowhere/report.json"), "{}"); }),
                  "does not exist");
}
