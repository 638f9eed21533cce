// Scene parsing (every field mapped, every bad input named), the run report,
// the example scenes, and the biomech command-line tool.
// Over 800 lines: one test per scene field and bad input, all on the same
// small scenes.
#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"
#include "bmrMeshless.h"
#include "bmrScene.h"
#include "bmrSolver.h"
#include "bmrSolverSettingsTable.h"

#include "bmrTemporaryFolderTest.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace
{


using bmr::test::ErrorMessage;
using bmr::test::ReadText;

void
WriteText(const fs::path & path, const std::string & text)
{
  std::ofstream stream(path);
  stream << text;
}

/** 40 x 20 x 20 mm block, 4 x 2 x 2 hexahedra of 10 mm: 45 nodes, 3 of them interior. */
json
BlockScene()
{
  return json::parse(R"({
    "mesh": {"generate": "block", "size": [40, 20, 20], "divisions": [4, 2, 2]},
    "materials": [{"name": "brain", "youngs_modulus": 3000, "poisson_ratio": 0.49}],
    "node_sets": {"top": {"nodes_in_box": {"min": [-1, -1, 19], "max": [41, 21, 21]}}},
    "fixed": [{"node_set": "zmin"}],
    "prescribed_displacements": [{"node_set": "top", "displacement": [0, 0, -1]}]
  })");
}

// Each test gets its own folder (TemporaryFolderTest).
class SceneTest : public bmr::test::TemporaryFolderTest
{
protected:

  bmr::Scene Parse(const json & scene) const { return bmr::ParseScene(scene.dump(), (m_Folder / "scene.json").string()); }

  std::string ParseError(const json & scene) const
  {
    return ErrorMessage([&] { Parse(scene); });
  }

};

std::size_t
CountNodes(const bmr::Model & model, const std::function<bool(const bmr::Vector3 &)> & inside)
{
  return static_cast<std::size_t>(std::count_if(model.nodes.begin(), model.nodes.end(), inside));
}

} // namespace

/** The solver settings' one table: every row reaches SolverSettings through the
 *  scene file and through `--set` text alike, a value outside its range is
 *  refused by both with the row's range, and docs/scene-format.md holds the
 *  table as `biomech settings --markdown` prints it. */
TEST_F(SceneTest, SolverSettingsTableIsTheSceneKeysAndTheDocs)
{
  const bmr::SolverSettings defaults;
  for (const bmr::SolverSettingField & field : bmr::SolverSettingFields())
  {
    SCOPED_TRACE(field.name);
    // A value that is not the default: the other choice, the other flag, or a changed number within the range.
    json   value;
    std::string text;
    double expected = 0.0;
    switch (field.kind)
    {
      case bmr::SolverSettingField::Kind::Choice:
        expected = 1.0 - field.get(defaults);
        value = field.choices.at(static_cast<std::size_t>(expected));
        text = value.get<std::string>();
        break;
      case bmr::SolverSettingField::Kind::Flag:
        expected = 1.0 - field.get(defaults);
        value = expected != 0.0;
        text = expected != 0.0 ? "true" : "false";
        break;
      case bmr::SolverSettingField::Kind::Integer:
        expected = field.get(defaults) + 3.0;
        value = static_cast<long long>(expected);
        text = std::to_string(static_cast<long long>(expected));
        break;
      case bmr::SolverSettingField::Kind::Number:
        expected = std::isfinite(field.highest) ? 0.5 * field.highest : field.get(defaults) + 0.25;
        value = expected;
        text = value.dump();
        break;
    }
    ASSERT_NE(expected, field.get(defaults));
    ASSERT_EQ(field.Check(expected), "");
    json scene = BlockScene();
    scene["solver"] = { { field.name, value } };
    EXPECT_EQ(field.get(Parse(scene).settings), expected);
    bmr::SolverSettings settings;
    bmr::SetSolverSetting(settings, field.name, text);
    EXPECT_EQ(field.get(settings), expected);

    // Outside the range (or of the wrong kind): both refuse, naming the key.
    json bad = field.kind == bmr::SolverSettingField::Kind::Choice  ? json("bogus")
               : field.kind == bmr::SolverSettingField::Kind::Flag  ? json(2)
               : std::isfinite(field.lowest)                       ? json(field.lowest - 1.0)
                                                                   : json("many");
    scene["solver"] = { { field.name, bad } };
    EXPECT_CONTAINS(ParseError(scene), "solver." + field.name);
    const std::string badText = bad.is_string() ? bad.get<std::string>() : bad.dump();
    EXPECT_CONTAINS(ErrorMessage([&] { bmr::SetSolverSetting(settings, field.name, badText); }), field.name);
  }
  EXPECT_CONTAINS(ErrorMessage([] {
                    bmr::SolverSettings settings;
                    bmr::SetSolverSetting(settings, "tolerence", "0.01");
                  }),
                  "tolerance");
  EXPECT_CONTAINS(ReadText(fs::path(BMR_SOURCE_DIR) / "docs" / "scene-format.md"), bmr::SolverSettingsMarkdown());
}

TEST_F(SceneTest, EveryFieldIsMapped)
{
  json scene = BlockScene();
  scene["description"] = "all fields";
  scene["materials"] = json::parse(R"([
    {"name": "brain", "youngs_modulus": 3000, "poisson_ratio": 0.49, "density": 1040},
    {"name": "tumour", "label": 2, "youngs_modulus": 6000, "poisson_ratio": 0.45}])");
  scene["node_sets"] = json::parse(R"({
    "top": {"nodes_in_box": {"min": [9, -1, 19], "max": [31, 21, 21]}},
    "corner": {"nodes_in_sphere": {"center": [0, 0, 0], "radius": 10.5}},
    "listed": {"ids": [0, 5, 3, 5]},
    "skin": {"surface_nodes_in_box": {"min": [-1, -1, -1], "max": [41, 21, 21]}},
    "cap": {"surface_nodes_in_sphere": {"centre": [20, 10, 20], "radius": 10.1}}})");
  scene["fixed"] = json::parse(R"([{"node_set": "zmin", "components": [true, false, true]}, {"node_set": "corner"}])");
  scene["prescribed_displacements"] = json::parse(R"([
    {"node_set": "top", "displacement": [0.5, 0, -2], "components": [false, false, true],
     "curve": {"shape": "linear", "ramp_time": 0.25}}])");
  scene["gravity"] = { 0, 0, -9810 };
  scene["gravity_curve"] = json::parse(R"({"shape": "step"})");
  scene["fluid_surface"] = { 0, 0, 12.5 };
  scene["contact"] = json::parse(R"([{"name": "skull",
    "surface": {"generate": "ellipsoid", "semi_axes": [30, 20, 20], "subdivisions": 2, "centre": [20, 10, 10]},
    "body_side": "outside", "flip_normals": true, "slave_node_set": "skin"}])");
  scene["solver"] = json::parse(R"({"integrator": "explicit_dynamics", "tetrahedron": "linear", "tolerance": 0.002,
    "max_steps": 1234, "load_steps": 77, "adapt_interval": 9, "time_step": 1e-5, "safety_factor": 0.6,
    "end_time": 0.3, "damping": 12.5, "hourglass_coefficient": 0.1, "threads": 2, "compute_stress": true,
    "collapse_bulk_modulus": 25000})");
  scene["output"] = json::parse(R"({"vtu": "out/r.vtu", "report": "out/r.json"})");

  const bmr::Scene parsed = Parse(scene);
  const bmr::Model & model = parsed.model;
  EXPECT_EQ(parsed.description, "all fields");
  EXPECT_EQ(parsed.path, (m_Folder / "scene.json").string());
  EXPECT_EQ(model.nodes.size(), 45u);
  EXPECT_EQ(model.cells.size(), 16u);

  ASSERT_EQ(model.materials.size(), 2u);
  EXPECT_EQ(model.materials[0].name, "brain");
  EXPECT_EQ(model.materials[0].youngsModulus, 3000.0);
  EXPECT_EQ(model.materials[0].poissonRatio, 0.49);
  EXPECT_EQ(model.materials[0].density, 1040.0);
  EXPECT_EQ(model.materials[1].name, "tumour");
  EXPECT_EQ(model.materials[1].youngsModulus, 6000.0);
  EXPECT_EQ(model.materials[1].poissonRatio, 0.45);
  EXPECT_EQ(model.materials[1].density, 1000.0); // default
  for (const auto & cell : model.cells)
  {
    EXPECT_EQ(cell.material, 0); // generated meshes use the first material
  }

  // Node sets: sizes from the 10 mm grid, members checked by position.
  ASSERT_EQ(model.NodeSet("top").size(), 9u); // x in {10, 20, 30}, y in {0, 10, 20}, z = 20
  for (const bmr::Index node : model.NodeSet("top"))
  {
    EXPECT_EQ(model.nodes[node].z(), 20.0);
    EXPECT_GE(model.nodes[node].x(), 10.0);
    EXPECT_LE(model.nodes[node].x(), 30.0);
  }
  EXPECT_EQ(model.NodeSet("corner").size(), 4u); // the origin and its 3 neighbours
  EXPECT_EQ(model.NodeSet("listed"), (std::vector<bmr::Index>{ 0, 3, 5 }));
  EXPECT_EQ(model.NodeSet("skin").size(), 42u); // 45 nodes less 3 interior
  // The sphere holds 6 nodes; the interior one (20, 10, 10) is not on the surface.
  EXPECT_EQ(CountNodes(model, [](const bmr::Vector3 & x) { return (x - bmr::Vector3(20, 10, 20)).norm() <= 10.1; }), 6u);
  EXPECT_EQ(model.NodeSet("cap").size(), 5u);
  for (const bmr::Index node : model.NodeSet("cap"))
  {
    EXPECT_NE(model.nodes[node], bmr::Vector3(20, 10, 10));
  }
  EXPECT_EQ(model.NodeSet("zmin").size(), 15u); // the generator's sets remain

  ASSERT_EQ(model.fixedConstraints.size(), 2u);
  EXPECT_EQ(model.fixedConstraints[0].nodeSet, "zmin");
  EXPECT_EQ(model.fixedConstraints[0].components, (std::array<bool, 3>{ true, false, true }));
  EXPECT_EQ(model.fixedConstraints[1].nodeSet, "corner");
  EXPECT_EQ(model.fixedConstraints[1].components, (std::array<bool, 3>{ true, true, true }));

  ASSERT_EQ(model.prescribedDisplacements.size(), 1u);
  const bmr::PrescribedDisplacement & prescribed = model.prescribedDisplacements[0];
  EXPECT_EQ(prescribed.nodes, model.NodeSet("top"));
  ASSERT_EQ(prescribed.displacements.size(), 9u);
  for (const auto & displacement : prescribed.displacements)
  {
    EXPECT_EQ(displacement, bmr::Vector3(0.5, 0.0, -2.0));
  }
  EXPECT_EQ(prescribed.components, (std::array<bool, 3>{ false, false, true }));
  EXPECT_EQ(prescribed.curve.shape, bmr::LoadCurve::Shape::Linear);
  EXPECT_EQ(prescribed.curve.rampTime, 0.25);

  EXPECT_EQ(model.bodyAcceleration, bmr::Vector3(0, 0, -9810));
  EXPECT_EQ(model.bodyForceCurve.shape, bmr::LoadCurve::Shape::Step);
  ASSERT_TRUE(model.fluidSurface.has_value());
  EXPECT_EQ(*model.fluidSurface, bmr::Vector3(0, 0, 12.5));

  ASSERT_EQ(model.contactSurfaces.size(), 1u);
  const bmr::ContactSurface & contact = model.contactSurfaces[0];
  const bmr::ContactSurface   expectedSurface =
    bmr::MakeEllipsoidSurface(bmr::Vector3(30, 20, 20), 2, bmr::Vector3(20, 10, 10));
  EXPECT_EQ(contact.name, "skull");
  EXPECT_EQ(contact.vertices, expectedSurface.vertices);
  EXPECT_EQ(contact.triangles, expectedSurface.triangles);
  EXPECT_EQ(contact.bodySide, bmr::ContactSurface::Side::Outside);
  EXPECT_TRUE(contact.flipNormals);
  EXPECT_EQ(contact.slaveNodeSet, "skin");

  const bmr::SolverSettings & settings = parsed.settings;
  EXPECT_EQ(settings.integrator, bmr::Integrator::ExplicitDynamics);
  EXPECT_EQ(settings.tetrahedron, bmr::TetrahedronFormulation::Linear);
  EXPECT_EQ(settings.tolerance, 0.002);
  EXPECT_EQ(settings.maxSteps, 1234);
  EXPECT_EQ(settings.loadSteps, 77);
  EXPECT_EQ(settings.adaptInterval, 9);
  EXPECT_EQ(settings.timeStep, 1e-5);
  EXPECT_EQ(settings.timeStepSafetyFactor, 0.6);
  EXPECT_EQ(settings.endTime, 0.3);
  EXPECT_EQ(settings.dampingCoefficient, 12.5);
  EXPECT_EQ(settings.hourglassCoefficient, 0.1);
  EXPECT_EQ(settings.collapseBulkModulus, 25000.0);
  EXPECT_EQ(settings.threads, 2);
  EXPECT_TRUE(settings.computeStress);

  EXPECT_EQ(parsed.resultVtuFile, "out/r.vtu");
  EXPECT_EQ(parsed.reportFile, "out/r.json");
}

TEST_F(SceneTest, DefaultsFollowTheDocumentation)
{
  const bmr::Scene          parsed = Parse(BlockScene());
  const bmr::SolverSettings defaults;
  EXPECT_EQ(parsed.settings.integrator, bmr::Integrator::DynamicRelaxation);
  EXPECT_EQ(parsed.settings.tetrahedron, bmr::TetrahedronFormulation::AverageNodalPressure);
  EXPECT_EQ(parsed.settings.tolerance, defaults.tolerance);
  EXPECT_EQ(parsed.settings.maxSteps, defaults.maxSteps);
  EXPECT_EQ(parsed.settings.hourglassCoefficient, 0.2);
  EXPECT_EQ(parsed.settings.collapseBulkModulus, 0.0); // the model's median bulk modulus
  EXPECT_EQ(parsed.settings.timeStepSafetyFactor, 0.8);
  EXPECT_FALSE(parsed.settings.computeStress);
  EXPECT_EQ(parsed.model.materials[0].density, 1000.0);
  EXPECT_EQ(parsed.model.bodyAcceleration, bmr::Vector3::Zero());
  EXPECT_FALSE(parsed.model.fluidSurface.has_value());
  EXPECT_TRUE(parsed.model.contactSurfaces.empty());
  EXPECT_EQ(parsed.model.prescribedDisplacements[0].components, (std::array<bool, 3>{ true, true, true }));
  EXPECT_EQ(parsed.model.prescribedDisplacements[0].curve.shape, bmr::LoadCurve::Shape::Smooth);
  EXPECT_EQ(parsed.resultVtuFile, "scene-result.vtu");
  EXPECT_EQ(parsed.reportFile, "scene-report.json");
}

TEST_F(SceneTest, MeshFileWithLabelsPointDataAndCsv)
{
  // Two materials by position; WriteMesh stores material indices as labels.
  bmr::Model mesh = bmr::MakeBlockMesh(bmr::Vector3(20, 20, 10), { 2, 2, 1 }, bmr::GridCells::Hexahedra);
  for (auto & cell : mesh.cells)
  {
    cell.material = mesh.nodes[cell.nodes[0]].x() < 10.0 ? 0 : 1;
  }
  mesh.materials.resize(2);
  fs::create_directories(m_Folder / "meshes");
  bmr::WriteMesh((m_Folder / "meshes" / "block.vtu").string(), mesh);

  // Two nodes of the top face by id, one with a header line and a comment.
  const bmr::Index first = mesh.NodeSet("zmax")[0];
  const bmr::Index second = mesh.NodeSet("zmax")[3];
  WriteText(m_Folder / "top.csv", "id,ux,uy,uz\n# pushed down\n" + std::to_string(first) + ", 0.25, 0, -1.5\n\n" +
                                    std::to_string(second) + ",0,-0.125,-1\n");

  const json scene = json::parse(R"({
    "mesh": "meshes/block.vtu",
    "material_array": "material",
    "materials": [{"name": "stiff", "label": 1, "youngs_modulus": 6000, "poisson_ratio": 0.49},
                  {"name": "soft", "label": 0, "youngs_modulus": 1500, "poisson_ratio": 0.45}],
    "node_sets": {"base": {"point_data": "zmin"}},
    "fixed": [{"node_set": "base"}],
    "prescribed_displacements": [{"csv": "top.csv"}]
  })");
  const bmr::Scene parsed = Parse(scene);
  const bmr::Model & model = parsed.model;
  EXPECT_EQ(parsed.meshSource, (m_Folder / "meshes" / "block.vtu").string());
  ASSERT_EQ(model.cells.size(), mesh.cells.size());
  for (std::size_t cell = 0; cell < mesh.cells.size(); ++cell)
  {
    // label 1 -> materials[0] ("stiff"), label 0 -> materials[1] ("soft")
    EXPECT_EQ(model.cells[cell].material, mesh.cells[cell].material == 1 ? 0 : 1) << "cell " << cell;
  }
  EXPECT_EQ(model.NodeSet("base"), mesh.NodeSet("zmin"));
  ASSERT_EQ(model.prescribedDisplacements.size(), 1u);
  EXPECT_EQ(model.prescribedDisplacements[0].nodes, (std::vector<bmr::Index>{ first, second }));
  EXPECT_EQ(model.prescribedDisplacements[0].displacements[0], bmr::Vector3(0.25, 0.0, -1.5));
  EXPECT_EQ(model.prescribedDisplacements[0].displacements[1], bmr::Vector3(0.0, -0.125, -1.0));

  // Without a label array in the file, every cell takes the first material.
  WriteText(m_Folder / "plain.vtk", "# vtk DataFile Version 3.0\nplain\nASCII\nDATASET UNSTRUCTURED_GRID\n"
                                    "POINTS 5 double\n0 0 0 10 0 0 0 10 0 0 0 10 10 10 10\n"
                                    "CELLS 2 10\n4 0 1 2 3\n4 1 2 3 4\nCELL_TYPES 2\n10\n10\n");
  const json plainScene = json::parse(R"({"mesh": "plain.vtk",
    "materials": [{"youngs_modulus": 3000, "poisson_ratio": 0.49}, {"youngs_modulus": 10, "poisson_ratio": 0.1}],
    "node_sets": {"base": {"ids": [0, 1, 2]}}, "fixed": [{"node_set": "base"}]})");
  const bmr::Scene plain = Parse(plainScene);
  ASSERT_EQ(plain.model.cells.size(), 2u);
  EXPECT_EQ(plain.model.cells[0].material, 0);
  EXPECT_EQ(plain.model.cells[1].material, 0);
  EXPECT_EQ(plain.model.cells[1].nodes[3], 4);
}

TEST_F(SceneTest, MaterialFieldsGiveEachCellItsProperties)
{
  // Properties vary per cell, as a membership-weighted mixture gives them.
  bmr::Model mesh = bmr::MakeBlockMesh(bmr::Vector3(30, 10, 10), { 3, 1, 1 }, bmr::GridCells::Hexahedra);
  mesh.materials = { bmr::Material{ "a", 3000.0, 0.49, 1000.0 }, bmr::Material{ "b", 1505.0, 0.295, 1000.0 },
                     bmr::Material{ "c", 10.0, 0.1, 1040.0 } };
  for (std::size_t cell = 0; cell < 3; ++cell)
  {
    mesh.cells[cell].material = static_cast<bmr::Index>(2 - cell);
  }
  bmr::WriteMesh((m_Folder / "mixed.vtu").string(), mesh);
  json scene = json::parse(R"({
    "mesh": "mixed.vtu",
    "material_fields": {"youngs_modulus": "youngs_modulus", "poisson_ratio": "poisson_ratio", "density": "density"},
    "node_sets": {"base": {"point_data": "xmin"}},
    "fixed": [{"node_set": "base"}]
  })");
  const bmr::Scene parsed = Parse(scene);
  ASSERT_EQ(parsed.model.materials.size(), 3u);
  for (std::size_t cell = 0; cell < 3; ++cell)
  {
    const bmr::Material & expected = mesh.materials[2 - cell];
    const bmr::Material & got = parsed.model.materials[parsed.model.cells[cell].material];
    EXPECT_EQ(got.youngsModulus, expected.youngsModulus) << "cell " << cell;
    EXPECT_EQ(got.poissonRatio, expected.poissonRatio) << "cell " << cell;
    EXPECT_EQ(got.density, expected.density) << "cell " << cell;
  }

  // Equal properties share one material.
  mesh.cells[0].material = 0;
  mesh.cells[2].material = 0;
  bmr::WriteMesh((m_Folder / "mixed.vtu").string(), mesh);
  EXPECT_EQ(Parse(scene).model.materials.size(), 2u);

  json both = scene;
  both["materials"] = json::parse(R"([{"youngs_modulus": 3000, "poisson_ratio": 0.49}])");
  EXPECT_CONTAINS(ParseError(both), "not both");
  json missingArray = scene;
  missingArray["material_fields"]["youngs_modulus"] = "stiffness";
  EXPECT_CONTAINS(ParseError(missingArray), "no one-component cell-data array 'stiffness'");
  json noPoisson = scene;
  noPoisson["material_fields"].erase("poisson_ratio");
  EXPECT_CONTAINS(ParseError(noPoisson), "needs \"youngs_modulus\" and \"poisson_ratio\"");
  json generated = BlockScene();
  generated.erase("materials");
  generated["material_fields"] = scene["material_fields"];
  generated.erase("node_sets");
  generated["fixed"] = json::parse(R"([{"node_set": "zmin"}])");
  EXPECT_CONTAINS(ParseError(generated), "applies only to a mesh read from a file");
}

TEST_F(SceneTest, MeshlessIntegrationPointsFromAFile)
{
  // Write a meshless model's integration points with two materials, read them back through a scene.
  bmr::Model mesh = bmr::MakeBlockMesh(bmr::Vector3(20, 10, 10), { 4, 2, 2 }, bmr::GridCells::Hexahedra);
  mesh.materials = { bmr::Material{ "brain", 3000.0, 0.49, 1000.0 }, bmr::Material{ "csf", 10.0, 0.1, 1000.0 } };
  bmr::WriteMesh((m_Folder / "cloud.vtu").string(), mesh);
  bmr::Model meshless = mesh;
  bmr::MakeMeshlessFromCells(meshless, bmr::MlsSettings{}, bmr::IntegrationSettings{});
  for (std::size_t point = 0; point < meshless.meshless.integrationPoints.size(); ++point)
  {
    meshless.meshless.integrationMaterials[point] = meshless.meshless.integrationPoints[point].x() < 10.0 ? 0 : 1;
  }
  bmr::WriteIntegrationPoints((m_Folder / "points.vtu").string(), meshless);

  json scene = json::parse(R"({
    "mesh": "cloud.vtu",
    "materials": [{"youngs_modulus": 3000, "poisson_ratio": 0.49}],
    "discretization": "meshless",
    "meshless": {"integration_points": "points.vtu"},
    "node_sets": {"base": {"point_data": "xmin"}},
    "fixed": [{"node_set": "base"}]
  })");
  const bmr::Scene parsed = Parse(scene);
  const bmr::MeshlessDiscretization & read = parsed.model.meshless;
  ASSERT_EQ(parsed.model.discretization, bmr::Discretization::Meshless);
  ASSERT_EQ(read.integrationPoints.size(), meshless.meshless.integrationPoints.size());
  for (std::size_t point = 0; point < read.integrationPoints.size(); ++point)
  {
    EXPECT_EQ(read.integrationPoints[point], meshless.meshless.integrationPoints[point]);
    EXPECT_EQ(read.integrationWeights[point], meshless.meshless.integrationWeights[point]);
    const double expectedModulus = meshless.meshless.integrationPoints[point].x() < 10.0 ? 3000.0 : 10.0;
    EXPECT_EQ(parsed.model.materials[read.integrationMaterials[point]].youngsModulus, expectedModulus);
  }

  json both = scene;
  both["meshless"]["integration"] = json::parse(R"({"points_per_direction": 2})");
  EXPECT_CONTAINS(ParseError(both), "not both");
  json missing = scene;
  missing["meshless"]["integration_points"] = "nothing.vtu";
  EXPECT_CONTAINS(ParseError(missing), "nothing.vtu");
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::WriteIntegrationPoints((m_Folder / "fe.vtu").string(), mesh); }),
                  "not meshless");
}

TEST_F(SceneTest, BadInputsNameTheOffendingKey)
{
  struct Case
  {
    std::string                     what;
    std::function<void(json &)>     change;
    std::vector<std::string>        expected;
  };
  const std::vector<Case> cases = {
    { "unknown top-level key", [](json & s) { s["solvr"] = json::object(); }, { "solvr", "unknown key" } },
    { "unknown nested key", [](json & s) { s["solver"] = { { "tolerence", 1e-3 } }; }, { "solver.tolerence", "unknown key", "tolerance" } },
    { "wrong type", [](json & s) { s["solver"] = { { "max_steps", "many" } }; }, { "solver.max_steps", "integer" } },
    { "fractional integer", [](json & s) { s["solver"] = { { "max_steps", 2.5 } }; }, { "solver.max_steps", "2.5" } },
    { "missing mesh", [](json & s) { s.erase("mesh"); }, { "missing required key 'mesh'" } },
    { "missing materials", [](json & s) { s.erase("materials"); }, { "missing required key 'materials'" } },
    { "empty materials", [](json & s) { s["materials"] = json::array(); }, { "materials", "at least one" } },
    { "missing modulus", [](json & s) { s["materials"][0].erase("youngs_modulus"); }, { "materials[0]", "youngs_modulus" } },
    { "incompressible", [](json & s) { s["materials"][0]["poisson_ratio"] = 0.5; }, { "materials[0].poisson_ratio" } },
    { "negative modulus", [](json & s) { s["materials"][0]["youngs_modulus"] = -1; }, { "materials[0].youngs_modulus", "greater than 0" } },
    { "duplicate label",
      [](json & s) {
        s["materials"][0]["label"] = 3;
        s["materials"].push_back({ { "label", 3 }, { "youngs_modulus", 10 }, { "poisson_ratio", 0.1 } });
      },
      { "materials[1].label", "already used" } },
    { "unknown generator", [](json & s) { s["mesh"]["generate"] = "sphere"; }, { "mesh.generate", "sphere", "block" } },
    { "mesh key of another generator", [](json & s) { s["mesh"]["spacing"] = 2; }, { "mesh.spacing", "unknown key" } },
    { "bad divisions", [](json & s) { s["mesh"]["divisions"] = { 4, 0, 2 }; }, { "mesh.divisions[1]" } },
    { "bad cells", [](json & s) { s["mesh"]["cells"] = "prisms"; }, { "mesh.cells", "prisms" } },
    { "mesh of wrong type", [](json & s) { s["mesh"] = 3; }, { "mesh", "file name" } },
    { "material_array with generated mesh", [](json & s) { s["material_array"] = "labels"; }, { "material_array" } },
    { "unknown node set",
      [](json & s) { s["prescribed_displacements"].push_back({ { "node_set", "tpo" }, { "displacement", { 0, 0, 1 } } }); },
      { "prescribed_displacements[1].node_set", "'tpo'", "top" } },
    { "unknown fixed set", [](json & s) { s["fixed"][0]["node_set"] = "bottom"; }, { "fixed[0].node_set", "bottom", "zmin" } },
    { "short components", [](json & s) { s["fixed"][0]["components"] = { true, false }; }, { "fixed[0].components", "3 values" } },
    { "no components", [](json & s) { s["fixed"][0]["components"] = { false, false, false }; }, { "fixed[0].components", "at least one" } },
    { "empty node set",
      [](json & s) { s["node_sets"]["far"] = { { "nodes_in_box", { { "min", { 100, 100, 100 } }, { "max", { 200, 200, 200 } } } } }; },
      { "node_sets.far", "selects no nodes", "spans" } },
    { "node id out of range", [](json & s) { s["node_sets"]["bad"] = { { "ids", { 1, 9999 } } }; }, { "node_sets.bad.ids[1]", "node 9999 does not exist" } },
    { "two selectors",
      [](json & s) { s["node_sets"]["two"] = { { "ids", { 1 } }, { "point_data", "x" } }; },
      { "node_sets.two", "exactly one" } },
    { "point data on a generated mesh", [](json & s) { s["node_sets"]["mask"] = { { "point_data", "zmin" } }; }, { "node_sets.mask.point_data", "zmin" } },
    { "box min above max",
      [](json & s) { s["node_sets"]["box"] = { { "nodes_in_box", { { "min", { 1, 1, 1 } }, { "max", { 0, 2, 2 } } } } }; },
      { "node_sets.box.nodes_in_box", "min" } },
    { "sphere without radius", [](json & s) { s["node_sets"]["ball"] = { { "nodes_in_sphere", { { "center", { 0, 0, 0 } } } } }; }, { "node_sets.ball.nodes_in_sphere", "radius" } },
    { "redefined generated set", [](json & s) { s["node_sets"]["zmin"] = { { "ids", { 0 } } }; }, { "node_sets.zmin", "already exists" } },
    { "node_set and csv", [](json & s) { s["prescribed_displacements"][0]["csv"] = "d.csv"; }, { "prescribed_displacements[0]", "either" } },
    { "missing displacement", [](json & s) { s["prescribed_displacements"][0].erase("displacement"); }, { "prescribed_displacements[0]", "displacement" } },
    { "missing csv", [](json & s) { s["prescribed_displacements"][0] = { { "csv", "nowhere.csv" } }; }, { "prescribed_displacements[0].csv", "nowhere.csv" } },
    { "bad curve", [](json & s) { s["prescribed_displacements"][0]["curve"] = { { "shape", "cubic" } }; }, { "prescribed_displacements[0].curve.shape", "cubic" } },
    { "zero ramp", [](json & s) { s["prescribed_displacements"][0]["curve"] = { { "ramp_time", 0 } }; }, { "prescribed_displacements[0].curve.ramp_time" } },
    { "short gravity", [](json & s) { s["gravity"] = { 0, -9810 }; }, { "gravity", "3 values" } },
    { "gravity curve alone", [](json & s) { s["gravity_curve"] = { { "shape", "linear" } }; }, { "gravity_curve", "gravity" } },
    { "fluid surface alone", [](json & s) { s["fluid_surface"] = { 0, 0, 1 }; }, { "fluid_surface", "gravity" } },
    { "short fluid surface", [](json & s) { s["gravity"] = { 0, 0, -9810 }; s["fluid_surface"] = { 0, 1 }; }, { "fluid_surface", "3 values" } },
    { "missing contact surface file", [](json & s) { s["contact"] = { { { "surface", "skull.stl" } } }; }, { "contact[0].surface", "skull.stl" } },
    { "bad body side",
      [](json & s) { s["contact"] = { { { "surface", { { "generate", "ellipsoid" }, { "semi_axes", { 50, 50, 50 } } } }, { "body_side", "above" } } }; },
      { "contact[0].body_side", "above" } },
    { "unknown slave set",
      [](json & s) { s["contact"] = { { { "surface", { { "generate", "ellipsoid" }, { "semi_axes", { 50, 50, 50 } } } }, { "slave_node_set", "skin" } } }; },
      { "contact[0].slave_node_set", "skin" } },
    { "unknown integrator", [](json & s) { s["solver"] = { { "integrator", "implicit" } }; }, { "solver.integrator", "dynamic_relaxation" } },
    { "safety factor above 1", [](json & s) { s["solver"] = { { "safety_factor", 1.5 } }; }, { "solver.safety_factor" } },
    { "zero tolerance", [](json & s) { s["solver"] = { { "tolerance", 0 } }; }, { "solver.tolerance" } },
    { "negative threads", [](json & s) { s["solver"] = { { "threads", -1 } }; }, { "solver.threads" } },
    { "negative collapse modulus", [](json & s) { s["solver"] = { { "collapse_bulk_modulus", -1 } }; },
      { "solver.collapse_bulk_modulus" } },
    { "result not vtu", [](json & s) { s["output"] = { { "vtu", "result.txt" } }; }, { "output.vtu", ".vtu" } },
    { "unknown output key", [](json & s) { s["output"] = { { "vtk", "r.vtk" } }; }, { "output.vtk", "unknown key" } },
  };
  for (const auto & testCase : cases)
  {
    SCOPED_TRACE(testCase.what);
    json scene = BlockScene();
    testCase.change(scene);
    const std::string message = ParseError(scene);
    EXPECT_CONTAINS(message, (m_Folder / "scene.json").string());
    for (const auto & part : testCase.expected)
    {
      EXPECT_CONTAINS(message, part);
    }
  }
}

TEST_F(SceneTest, BadFileInputsAreNamed)
{
  bmr::Model mesh = bmr::MakeBlockMesh(bmr::Vector3(10, 10, 10), { 1, 1, 1 }, bmr::GridCells::Hexahedra);
  mesh.cells[0].material = 7;
  bmr::WriteMesh((m_Folder / "block.vtu").string(), mesh);
  json scene = json::parse(R"({"mesh": "block.vtu",
    "materials": [{"label": 1, "youngs_modulus": 3000, "poisson_ratio": 0.49}]})");

  // A label without a material names the cell and the label.
  std::string message = ParseError(scene);
  EXPECT_CONTAINS(message, "cell 0 has label 7");
  EXPECT_CONTAINS(message, "material labels: 1");

  // A single material without a label applies to every cell, whatever its label.
  scene["materials"][0].erase("label");
  EXPECT_EQ(Parse(scene).model.cells[0].material, 0);

  // With several materials, labels in the mesh need labels on every material.
  scene["materials"].push_back(json::parse(R"({"label": 7, "youngs_modulus": 10, "poisson_ratio": 0.1})"));
  EXPECT_CONTAINS(ParseError(scene), "materials[0]: missing key 'label'");
  scene["materials"].erase(1);

  // An explicitly named label array must exist.
  scene["material_array"] = "tissue";
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "material_array");
  EXPECT_CONTAINS(message, "'tissue'");
  scene.erase("material_array");

  // Point-data masks must exist.
  scene["materials"][0]["label"] = 7;
  scene["node_sets"] = { { "base", { { "point_data", "bottom" } } } };
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "node_sets.base.point_data");
  EXPECT_CONTAINS(message, "zmin"); // lists the arrays the file has

  // CSV lines: wrong node, wrong field count, a second header.
  scene.erase("node_sets");
  scene["prescribed_displacements"] = { { { "csv", "d.csv" } } };
  WriteText(m_Folder / "d.csv", "id,ux,uy,uz\n0,0,0,1\n500,0,0,1\n");
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "prescribed_displacements[0].csv");
  EXPECT_CONTAINS(message, "line 3");
  EXPECT_CONTAINS(message, "node 500 does not exist");
  WriteText(m_Folder / "d.csv", "0,0,0\n");
  EXPECT_CONTAINS(ParseError(scene), "line 1: expected 4 comma-separated values");
  WriteText(m_Folder / "d.csv", "id,ux,uy,uz\n0,0,0,1\nid,ux,uy,uz\n");
  EXPECT_CONTAINS(ParseError(scene), "line 3: expected numbers");
  WriteText(m_Folder / "d.csv", "1,0,0,1\n1,0,0,2\n");
  EXPECT_CONTAINS(ParseError(scene), "node 1 appears twice");
  WriteText(m_Folder / "d.csv", "id,ux,uy,uz\n");
  EXPECT_CONTAINS(ParseError(scene), "has no displacements");

  // Missing mesh file names the key and the path.
  scene["mesh"] = "no-such.vtu";
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "mesh: ");
  EXPECT_CONTAINS(message, (m_Folder / "no-such.vtu").string());

  // Not JSON at all.
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::ParseScene("{\"mesh\": ", "broken.json"); }), "broken.json: not valid JSON");
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::ParseScene("[1, 2]", "list.json"); }), "JSON object");
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::ReadScene((m_Folder / "missing.json").string()); }), "missing.json");
}

// Inputs that the fuzzer (test/fuzz_inputs.py) once turned into a crash, a
// wrapped-around result or an unclear message.
TEST_F(SceneTest, FuzzedInputsEndInNamedErrors)
{
  // nlohmann's "[json.exception.parse_error.101]" prefix is not for users.
  std::string message = ErrorMessage([&] { bmr::ParseScene("{\"mesh\": NaN}", "nan.json"); });
  EXPECT_CONTAINS(message, "nan.json: not valid JSON");
  EXPECT_CONTAINS(message, "line 1");
  EXPECT_EQ(message.find("json.exception"), std::string::npos) << message;
  // A number beyond double was nlohmann's uncaught out_of_range exception.
  message = ErrorMessage([&] { bmr::ParseScene("{\"mesh\": 1e999}", "huge.json"); });
  EXPECT_CONTAINS(message, "huge.json: not valid JSON: number overflow parsing '1e999'");

  // 2^63 was read as -2^63 ("must be between 1 and ..., got -9223372036854775808").
  json scene = BlockScene();
  scene["solver"] = { { "max_steps", 9223372036854775808ull } };
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "solver.max_steps: integer 9223372036854775808 is too large");

  // A choice with a line break in it was echoed verbatim: a two-line error.
  scene = BlockScene();
  scene["discretization"] = "a\nb";
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "\"a\\nb\" is not one of");
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;

  // A grid too large to number was a std::bad_alloc (or a wrapped-around index).
  scene = BlockScene();
  scene["mesh"]["divisions"] = { 100000, 100000, 100000 };
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "mesh: MakeBlockMesh");
  EXPECT_CONTAINS(message, "use fewer divisions");
  scene["mesh"] = { { "generate", "ellipsoid" }, { "semi_axes", { 1e300, 1e300, 1e300 } }, { "spacing", 1e-300 } };
  scene.erase("node_sets");
  scene.erase("fixed");
  scene.erase("prescribed_displacements");
  EXPECT_CONTAINS(ParseError(scene), "MakeEllipsoidMesh");

  // An end time of more steps than an int counts wrapped around and "converged" at once.
  scene = BlockScene();
  scene["solver"] = { { "integrator", "explicit_dynamics" }, { "end_time", 1e308 } };
  const bmr::Scene parsed = Parse(scene);
  message = ErrorMessage([&] { bmr::Solver(parsed.model, parsed.settings).Solve(); });
  EXPECT_CONTAINS(message, "end_time");
  EXPECT_CONTAINS(message, "more than");

  // A legacy VTK file with damaged cell offsets crashed VTK's GetCellPoints;
  // a point id past the points was read as a node.
  const std::string original = ReadText(fs::path(BMR_SOURCE_DIR) / "examples/scenes/data/small-block.vtk");
  scene = json::parse(R"({"mesh": "damaged.vtk", "materials": [{"youngs_modulus": 3000, "poisson_ratio": 0.45}]})");
  std::string damaged = original;
  const auto offsets = damaged.find("256 264 272");
  ASSERT_NE(offsets, std::string::npos);
  damaged.replace(offsets, 11, "256 24 272");
  WriteText(m_Folder / "damaged.vtk", damaged);
  message = ParseError(scene);
  EXPECT_CONTAINS(message, "damaged.vtk' is damaged");
  EXPECT_CONTAINS(message, "cell 56");
  damaged = original;
  const auto connectivity = damaged.find('\n', damaged.find("CONNECTIVITY")) + 1;
  damaged.replace(connectivity, damaged.find(' ', connectivity) - connectivity, "9999");
  WriteText(m_Folder / "damaged.vtk", damaged);
  EXPECT_CONTAINS(ParseError(scene), "cell 0 refers to point 9999, which does not exist");
}

TEST_F(SceneTest, ReportHoldsEveryResultField)
{
  json scene = BlockScene();
  scene["description"] = "report test";
  const bmr::Scene parsed = Parse(scene);
  bmr::SolveResult result;
  result.converged = false;
  result.message = "step limit reached";
  result.steps = 321;
  result.timeStep = 1.5e-3;
  result.criticalTimeStep = 2.5e-4;
  result.wallSeconds = 0.75;
  result.estimatedError = 0.125;
  result.convergenceRate = 0.999;
  result.lowestEigenvalue = 2.5e-5;
  result.maxDisplacement = 1.0;
  result.strainEnergy = 2e-6;
  result.hourglassEnergy = 3e-9;
  result.kineticEnergy = 4e-8;
  result.contactNodes = 17;
  result.maxPenetration = 0.0625;
  result.activeComponents = { "hexahedra", "hourglass-control", "dynamic-relaxation" };

  const json report = json::parse(bmr::MakeReportJson(parsed, result, "out/result.vtu"));
  EXPECT_EQ(report["scene"], parsed.path);
  EXPECT_EQ(report["description"], "report test");
  EXPECT_EQ(report["result_vtu"], "out/result.vtu");
  EXPECT_EQ(report["converged"], false);
  EXPECT_EQ(report["message"], "step limit reached");
  EXPECT_EQ(report["integrator"], "dynamic_relaxation");
  EXPECT_EQ(report["steps"], 321);
  EXPECT_EQ(report["time_step"], 1.5e-3);
  EXPECT_EQ(report["critical_time_step"], 2.5e-4);
  EXPECT_EQ(report["wall_seconds"], 0.75);
  EXPECT_EQ(report["estimated_error_mm"], 0.125);
  EXPECT_EQ(report["convergence_rate"], 0.999);
  EXPECT_EQ(report["lowest_eigenvalue"], 2.5e-5);
  EXPECT_EQ(report["max_displacement_mm"], 1.0);
  EXPECT_EQ(report["strain_energy_J"], 2e-6);
  EXPECT_EQ(report["hourglass_energy_J"], 3e-9);
  EXPECT_EQ(report["kinetic_energy_J"], 4e-8);
  EXPECT_EQ(report["contact_nodes"], 17);
  EXPECT_EQ(report["max_penetration_mm"], 0.0625);
  EXPECT_EQ(report["active_components"], json({ "hexahedra", "hourglass-control", "dynamic-relaxation" }));
  EXPECT_EQ(report["nodes"], 45);
  EXPECT_EQ(report["cells"], 16);
  EXPECT_EQ(report["hexahedra"], 16);
  EXPECT_EQ(report["tetrahedra"], 0);
  EXPECT_EQ(report["dofs"], 135);
  EXPECT_EQ(report["materials"], 1);
  EXPECT_GE(report["threads"].get<int>(), 1);

  const std::string table = bmr::FormatReportTable(parsed, result);
  EXPECT_CONTAINS(table, "NOT CONVERGED");
  EXPECT_CONTAINS(table, "45 nodes, 135 DOF, 16 cells (16 hexahedra, 0 tetrahedra)");
  EXPECT_CONTAINS(table, "step limit reached");
  result.converged = true;
  EXPECT_EQ(bmr::FormatReportTable(parsed, result).find("NOT CONVERGED"), std::string::npos);
}

TEST(SceneExamples, EveryExampleSceneParses)
{
  const fs::path folder = fs::path(BMR_SOURCE_DIR) / "examples" / "scenes";
  int            scenes = 0;
  for (const auto & entry : fs::directory_iterator(folder))
  {
    if (entry.path().extension() == ".json")
    {
      SCOPED_TRACE(entry.path().string());
      EXPECT_NO_THROW(bmr::ReadScene(entry.path().string()));
      ++scenes;
    }
  }
  EXPECT_GE(scenes, 4);
}

TEST(SceneExamples, BrainSizedScenesHaveAboutOneHundredThousandDofs)
{
  const fs::path   folder = fs::path(BMR_SOURCE_DIR) / "examples" / "scenes";
  const bmr::Scene hexahedra = bmr::ReadScene((folder / "brain-sized-hex.json").string());
  const bmr::Scene tetrahedra = bmr::ReadScene((folder / "brain-sized-tet.json").string());
  const bmr::ModelCounts hexCounts = bmr::CountModel(hexahedra.model);
  const bmr::ModelCounts tetCounts = bmr::CountModel(tetrahedra.model);
  EXPECT_GT(hexCounts.dofs, 90000u);
  EXPECT_LT(hexCounts.dofs, 115000u);
  EXPECT_EQ(hexCounts.tetrahedra, 0u);
  EXPECT_EQ(tetCounts.hexahedra, 0u);
  EXPECT_EQ(tetCounts.nodes, hexCounts.nodes);       // same grid
  EXPECT_EQ(tetCounts.cells, 6 * hexCounts.cells);    // 6 tetrahedra per grid cell

  const bmr::Model & model = hexahedra.model;
  const std::vector<bmr::Index> boundary = model.BoundaryNodes();
  for (const bmr::Index node : model.NodeSet("craniotomy"))
  {
    EXPECT_LE((model.nodes[node] - bmr::Vector3(0, 0, 60)).norm(), 25.0);
    EXPECT_TRUE(std::binary_search(boundary.begin(), boundary.end(), node));
  }
  for (const bmr::Index node : model.NodeSet("base"))
  {
    EXPECT_LE(model.nodes[node].z(), -45.0);
  }
  EXPECT_GT(model.NodeSet("craniotomy").size(), 20u);
  EXPECT_GT(model.NodeSet("base").size(), 20u);
  EXPECT_EQ(hexahedra.settings.tolerance, 0.01);
  ASSERT_EQ(model.prescribedDisplacements.size(), 1u);
  EXPECT_EQ(model.prescribedDisplacements[0].displacements[0], bmr::Vector3(0, 0, -10));
}

// ---------------------------------------------------------------------------
// The biomech command-line tool.
// ---------------------------------------------------------------------------
namespace
{

using bmr::test::CommandResult;

class SceneCliTest : public bmr::test::TemporaryFolderTest
{
protected:

  CommandResult Biomech(const std::string & arguments) const { return bmr::test::RunBiomech(m_Folder, arguments); }

  std::string Example(const std::string & name) const
  {
    return "'" + (fs::path(BMR_SOURCE_DIR) / "examples" / "scenes" / name).string() + "'";
  }

  std::vector<std::string> FilesIn(const fs::path & folder) const
  {
    std::vector<std::string> names;
    if (fs::exists(folder))
    {
      for (const auto & entry : fs::recursive_directory_iterator(folder))
      {
        if (entry.is_regular_file())
        {
          names.push_back(entry.path().filename().string());
        }
      }
    }
    std::sort(names.begin(), names.end());
    return names;
  }

};

} // namespace

TEST_F(SceneCliTest, HelpListsSubcommands)
{
  const CommandResult help = Biomech("--help");
  EXPECT_EQ(help.exitCode, 0);
  EXPECT_CONTAINS(help.out, "solve");
  EXPECT_CONTAINS(help.out, "make-mesh");
  const CommandResult wrong = Biomech("dance");
  EXPECT_EQ(wrong.exitCode, 1);
  EXPECT_CONTAINS(wrong.err, "biomech: error:");
}

TEST_F(SceneCliTest, BlockIndentationConvergesToThePrescribedDisplacement)
{
  const fs::path output = m_Folder / "out";
  const CommandResult run = Biomech("solve " + Example("block-indentation.json") + " --output-dir '" +
                                    output.string() + "' --threads 2");
  ASSERT_EQ(run.exitCode, 0) << run.out << run.err;
  EXPECT_CONTAINS(run.out, "converged");
  EXPECT_EQ(run.out.find("NOT CONVERGED"), std::string::npos);
  EXPECT_TRUE(run.err.empty()) << run.err; // no progress line when stderr is not a terminal

  const json report = json::parse(ReadText(output / "block-indentation-report.json"));
  EXPECT_EQ(report["converged"], true);
  EXPECT_NEAR(report["max_displacement_mm"].get<double>(), 2.0, 1e-6);
  EXPECT_EQ(report["nodes"], 9 * 9 * 5);
  EXPECT_EQ(report["hexahedra"], 8 * 8 * 4);
  EXPECT_LE(report["estimated_error_mm"].get<double>(), 1e-3);
  EXPECT_EQ(report["threads"], 2);
  // Leave out what the scene does not need: no contact, no tetrahedra.
  for (const auto & component : report["active_components"])
  {
    EXPECT_EQ(component.get<std::string>().find("contact"), std::string::npos) << component;
    EXPECT_EQ(component.get<std::string>().find("tetra"), std::string::npos) << component;
  }

  // The result file: the indenter nodes moved exactly 2 mm down, the base stayed.
  const bmr::Scene    scene = bmr::ReadScene((fs::path(BMR_SOURCE_DIR) / "examples/scenes/block-indentation.json").string());
  const bmr::MeshData result = bmr::ReadMesh((output / "block-indentation-result.vtu").string());
  const bmr::DataArray & displacement = result.pointData.at("displacement");
  ASSERT_EQ(displacement.Tuples(), scene.model.nodes.size());
  ASSERT_EQ(scene.model.NodeSet("indenter").size(), 9u);
  for (const bmr::Index node : scene.model.NodeSet("indenter"))
  {
    EXPECT_NEAR(displacement.values[3 * node + 0], 0.0, 1e-9);
    EXPECT_NEAR(displacement.values[3 * node + 1], 0.0, 1e-9);
    EXPECT_NEAR(displacement.values[3 * node + 2], -2.0, 1e-9);
  }
  for (const bmr::Index node : scene.model.NodeSet("zmin"))
  {
    EXPECT_EQ(displacement.values[3 * node + 2], 0.0);
  }
  // At equilibrium the reactions of the indenter and of the base cancel.
  const bmr::DataArray & reaction = result.pointData.at("reaction_force");
  bmr::Vector3           total = bmr::Vector3::Zero();
  bmr::Vector3           indenter = bmr::Vector3::Zero();
  for (std::size_t node = 0; node < reaction.Tuples(); ++node)
  {
    total += bmr::Vector3(reaction.values[3 * node], reaction.values[3 * node + 1], reaction.values[3 * node + 2]);
  }
  for (const bmr::Index node : scene.model.NodeSet("indenter"))
  {
    indenter.z() += reaction.values[3 * node + 2];
  }
  // Reactions are the forces the constraints exert on the body: the indenter pushes down.
  EXPECT_LT(indenter.z(), 0.0);
  EXPECT_LT(total.norm(), 0.02 * std::abs(indenter.z()));
}

TEST_F(SceneCliTest, MeshFileSceneHonoursCsvDisplacements)
{
  const fs::path      output = m_Folder / "out";
  const CommandResult run = Biomech("solve " + Example("block-from-file.json") + " -d '" + output.string() + "'");
  ASSERT_EQ(run.exitCode, 0) << run.out << run.err;
  const bmr::Scene scene = bmr::ReadScene((fs::path(BMR_SOURCE_DIR) / "examples/scenes/block-from-file.json").string());
  const bmr::MeshData result = bmr::ReadMesh((output / "block-from-file-result.vtu").string());
  const bmr::DataArray & displacement = result.pointData.at("displacement");
  const bmr::PrescribedDisplacement & prescribed = scene.model.prescribedDisplacements.at(0);
  ASSERT_FALSE(prescribed.nodes.empty());
  for (std::size_t k = 0; k < prescribed.nodes.size(); ++k)
  {
    for (int c = 0; c < 3; ++c)
    {
      EXPECT_NEAR(displacement.values[3 * prescribed.nodes[k] + c], prescribed.displacements[k][c], 1e-9);
    }
  }
  // Both materials are used.
  const json report = json::parse(ReadText(output / "block-from-file-report.json"));
  EXPECT_EQ(report["materials"], 2);
  EXPECT_GT(report["hexahedra"].get<int>(), 0);
  EXPECT_GT(report["tetrahedra"].get<int>(), 0);
}

TEST_F(SceneCliTest, BadMeshPathExitsOneAndWritesNothing)
{
  json scene = BlockScene();
  scene["mesh"] = "missing-mesh.vtu";
  WriteText(m_Folder / "bad.json", scene.dump());
  const fs::path      output = m_Folder / "out";
  const CommandResult run = Biomech("solve '" + (m_Folder / "bad.json").string() + "' --output-dir '" + output.string() + "'");
  EXPECT_EQ(run.exitCode, 1);
  EXPECT_CONTAINS(run.err, "biomech: error:");
  EXPECT_CONTAINS(run.err, "missing-mesh.vtu");
  EXPECT_TRUE(FilesIn(output).empty());
}

TEST_F(SceneCliTest, StepLimitExitsTwoAndReportsNotConverged)
{
  json scene = BlockScene();
  scene["solver"] = { { "max_steps", 5 }, { "tolerance", 1e-6 } };
  WriteText(m_Folder / "short.json", scene.dump());
  const fs::path output = m_Folder / "out";
  // A stale result from an earlier run must not survive as if it were this one's.
  fs::create_directories(output);
  WriteText(output / "short-report.json", R"({"converged": true})");

  const CommandResult run = Biomech("solve '" + (m_Folder / "short.json").string() + "' --output-dir '" + output.string() + "'");
  EXPECT_EQ(run.exitCode, 2) << run.out << run.err;
  EXPECT_CONTAINS(run.out, "NOT CONVERGED");
  EXPECT_CONTAINS(run.err, "NOT CONVERGED");
  const json report = json::parse(ReadText(output / "short-report.json"));
  EXPECT_EQ(report["converged"], false);
  EXPECT_EQ(report["steps"], 5);
  EXPECT_TRUE(fs::exists(output / "short-result.vtu"));
}

TEST_F(SceneCliTest, MakeMeshWritesAReadableMesh)
{
  const fs::path      mesh = m_Folder / "block.vtu";
  const CommandResult run =
    Biomech("make-mesh --shape block --size 40 20 20 --divisions 4 2 2 --cells tetrahedra -o '" + mesh.string() + "'");
  ASSERT_EQ(run.exitCode, 0) << run.err;
  const bmr::MeshData read = bmr::ReadMesh(mesh.string());
  EXPECT_EQ(read.model.nodes.size(), 45u);
  EXPECT_EQ(read.model.cells.size(), 6u * 16u);
  EXPECT_EQ(read.pointData.count("zmin"), 1u);

  const CommandResult wrong = Biomech("make-mesh --shape ellipsoid --size 1 2 3 -o '" + mesh.string() + "'");
  EXPECT_EQ(wrong.exitCode, 1);
  EXPECT_CONTAINS(wrong.err, "--semi-axes");
}

TEST_F(SceneCliTest, FailedSolveExitsOneAndWritesNothing)
{
  // Pushing a 20 mm thick block down by 25 mm inverts elements.
  json scene = json::parse(ReadText(fs::path(BMR_SOURCE_DIR) / "examples/scenes/block-indentation.json"));
  scene["prescribed_displacements"][0]["displacement"] = { 0, 0, -25 };
  WriteText(m_Folder / "crush.json", scene.dump());
  const fs::path output = m_Folder / "out";
  const CommandResult run = Biomech("solve '" + (m_Folder / "crush.json").string() + "' --output-dir '" + output.string() + "'");
  EXPECT_EQ(run.exitCode, 1) << run.out << run.err;
  EXPECT_CONTAINS(run.err, "biomech: error: the solve failed");
  EXPECT_CONTAINS(run.err, "element");
  EXPECT_TRUE(FilesIn(output).empty());
}

TEST_F(SceneCliTest, DamagedImagesAndTransformsGiveOneLineErrors)
{
  // 6 x 6 x 6 voxels of MetaImage, whole and cut in half.
  std::string image = "ObjectType = Image\nNDims = 3\nDimSize = 6 6 6\nElementSpacing = 2 2 2\n"
                      "ElementType = MET_UCHAR\nElementDataFile = LOCAL\n";
  image += std::string(216, '\1');
  WriteText(m_Folder / "mask.mha", image);
  WriteText(m_Folder / "truncated.mha", image.substr(0, image.size() - 150));
  WriteText(m_Folder / "garbage.nii.gz", "not an image");
  WriteText(m_Folder / "bad.tfm", "#Insight Transform File V1.0\n#Transform 0\nTransform: Nothing\n");
  const auto quoted = [&](const std::string & name) { return "'" + (m_Folder / name).string() + "'"; };
  const auto expectOneLineError = [&](const CommandResult & run, const std::string & part) {
    EXPECT_EQ(run.exitCode, 1) << run.err;
    EXPECT_EQ(run.err.rfind("biomech: error: ", 0), 0u) << run.err;
    EXPECT_EQ(run.err.find('\n'), run.err.size() - 1) << run.err;
    EXPECT_CONTAINS(run.err, part);
  };

  // MetaIO only printed its complaint and the garbage voxels were used.
  expectOneLineError(Biomech("grid " + quoted("truncated.mha") + " -o " + quoted("grid.vtu")), "fewer voxels");
  // ITK's several-line list of the IO classes it tried.
  expectOneLineError(Biomech("grid " + quoted("garbage.nii.gz") + " -o " + quoted("grid.vtu")),
                     "no ITK reader recognises the file");
  // ITK's text transform reader threw std::out_of_range ("basic_string::replace").
  expectOneLineError(Biomech("warp " + quoted("mask.mha") + " " + quoted("bad.tfm") + " -o " + quoted("w.mha")),
                     "cannot read transform");
  // A grid too large to number: std::bad_alloc.
  expectOneLineError(Biomech("make-mesh --shape block --size 1 1 1 --divisions 100000 100000 100000 -o " +
                             quoted("big.vtu")),
                     "use fewer divisions");
  EXPECT_EQ(FilesIn(m_Folder).size(), 4u); // nothing written
}
