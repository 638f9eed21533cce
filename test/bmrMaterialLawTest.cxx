// The constitutive laws (src/mechanics/include/bmrMaterialLaw.h, src/mechanics/materials/):
// the Mooney-Rivlin kernel law against the textbook Cauchy stress of the same
// strain energy (written here independently, in spatial form) and against
// the derivative of its own energy; homogeneous uniaxial compression solved
// on every grid kind against the analytic answer; the law carried through
// scenes, integration-point files and the solver's precomputation; bad law
// parameters named. CalculiX's *HYPERELASTIC, MOONEY-RIVLIN is the
// independent reference in test/bmrCalculixTest.cxx (MooneyRivlin*).
#include "bmrBinaryStream.h"
#include "bmrConstitutiveLaw.h"
#include "bmrMeshIO.h"
#include "bmrMeshless.h"
#include "bmrScene.h"
#include "bmrSolver.h"
#include "bmrTemporaryFolderTest.h"
#include "bmrTestUtilities.h"
#include "bmrUnits.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <set>
#include <string>
#include <vector>

namespace bmr
{
namespace
{

using test::ErrorMessage;
using test::Matrix3;
using test::MooneyRivlin;
using test::MooneyRivlinMaterial;

/** Deformation gradients with stretch, shear and rotation, J from 0.7 to 1.3. */
std::vector<Matrix3>
SampleDeformations()
{
  std::vector<Matrix3> samples;
  for (const double J : { 0.7, 0.95, 1.0, 1.3 })
  {
    Matrix3 F = test::RotationAboutAxis(Vector3(1.0, 2.0, 3.0), 0.4) * test::SimpleShearDeformationGradient(0.35);
    F.col(0) *= 1.2;
    F.col(1) *= 0.9;
    F *= std::cbrt(J / F.determinant());
    samples.push_back(F);
  }
  return samples;
}

TEST(MaterialLaw, MooneyRivlinStressIsTheTextbookOneAndTheDerivativeOfItsEnergy)
{
  for (const double share : { 0.0, 0.3, 1.0 })
  {
    const Material     material = MooneyRivlinMaterial(share);
    const MooneyRivlin reference(material);
    const double       mu = material.ShearModulus(), second = material.SecondInvariantModulus(),
                 kappa = material.BulkModulus();
    for (const Matrix3 & F : SampleDeformations())
    {
      SCOPED_TRACE(testing::Message() << "share " << share << ", J " << F.determinant());
      const Matrix3 cof = Cofactor(F);
      const double  J = F.determinant();
      const UnitModuli moduli{ mu, second, kappa, 0.0 };
      const Matrix3    P = FirstPiolaOfLaw(F, cof, J, J, moduli);
      EXPECT_LT((P - reference.FirstPiola(F)).norm(), 1e-12 * reference.FirstPiola(F).norm() + 1e-12 * mu);
      // The kernels' template, scaled by a volume, gives the same stress.
      const Matrix3 scaled = ToEigen(
        ScaledMooneyRivlinFirstPiola<true>(ToPlain(F), ToPlain(cof), J, kappa * (J - 1.0), mu, second, 0.0, 2.5));
      EXPECT_LT((scaled - 2.5 * P).norm(), 1e-13 * P.norm() + 1e-12 * mu);
      // P = dW/dF by central differences, every component.
      for (int i = 0; i < 3; ++i)
      {
        for (int j = 0; j < 3; ++j)
        {
          const double h = 1e-6;
          Matrix3      plus = F, minus = F;
          plus(i, j) += h;
          minus(i, j) -= h;
          const double derivative = (StrainEnergyDensityOfLaw(plus, plus.determinant(), plus.determinant(), moduli) -
                                     StrainEnergyDensityOfLaw(minus, minus.determinant(), minus.determinant(), moduli)) /
                                    (2.0 * h);
          EXPECT_NEAR(P(i, j), derivative, 1e-6 * P.norm()) << "component " << i << j;
        }
      }
    }
  }
}

TEST(MaterialLaw, NoSecondInvariantIsTheNeoHookeanLaw)
{
  // A Mooney-Rivlin solid with C01 = 0 is the neo-Hookean one, and the
  // neo-Hookean path of the law functions is the neo-Hookean law itself.
  const Material           neoHookean = test::MakeMaterial(3000.0, 0.45);
  const test::NeoHookean   reference(neoHookean);
  const MooneyRivlin       noSecond(MooneyRivlinMaterial(0.0));
  for (const Matrix3 & F : SampleDeformations())
  {
    const double J = F.determinant();
    EXPECT_LT((noSecond.FirstPiola(F) - reference.FirstPiola(F)).norm(), 1e-10 * reference.FirstPiola(F).norm());
    const Matrix3 P =
      FirstPiolaOfLaw(F, Cofactor(F), J, J, { neoHookean.ShearModulus(), 0.0, neoHookean.BulkModulus(), 0.0 });
    EXPECT_EQ(P, FirstPiola(F, Cofactor(F), J, J, neoHookean.ShearModulus(), neoHookean.BulkModulus(), 0.0));
    EXPECT_LT((P - reference.FirstPiola(F)).norm(), 1e-10 * P.norm());
  }
}

/** Homogeneous uniaxial compression to lambda on a 10 mm block (symmetry
 *  planes, the xmax face moved in x only): the reaction on the moved face. */
double
UniaxialReaction(const Material & material, GridCells cells, bool meshless, double lambda,
                 std::vector<std::string> * components = nullptr)
{
  Model model = test::UniaxialStressBlock(cells, lambda, 10.0, material);
  if (meshless)
  {
    MakeMeshlessFromCells(model, {}, {}, 1);
  }
  SolverSettings settings;
  settings.integrator = Integrator::DynamicRelaxation;
  settings.tetrahedron = TetrahedronFormulation::AverageNodalPressure;
  settings.tolerance = 1e-7;
  settings.threads = 1;
  const SolveResult result = Solver(model, settings).Solve();
  EXPECT_TRUE(result.converged) << result.message;
  if (components)
  {
    *components = result.activeComponents;
  }
  double force = 0.0;
  for (const Index node : model.NodeSet("xmax"))
  {
    force += result.reactionForces[node].x();
  }
  return force;
}

TEST(MaterialLaw, UniaxialCompressionOnEveryGridIsTheAnalyticOne)
{
  // A homogeneous deformation is exact on the elements (linear fields), so
  // they must give the law's own reaction; the meshless integration of MLS
  // gradients is not exact (1.5e-4 measured here; its neo-Hookean patch tests
  // allow 0.5 %). The neo-Hookean reaction differs by more than 3 %, so a law
  // ignored anywhere shows.
  const double       lambda = 0.7;
  const Material     material = MooneyRivlinMaterial(0.5);
  const MooneyRivlin law(material);
  const Matrix3      F = law.Uniaxial(lambda);
  const double       expected = law.FirstPiola(F)(0, 0) * 100.0 * test::PascalSquareMillimetreToNewton;
  const test::NeoHookean neoHookean(test::MakeMaterial(3000.0, 0.45));
  const double           neoHookeanForce =
    neoHookean.FirstPiola(test::UniaxialDeformationGradient(lambda, neoHookean))(0, 0) * 100.0 *
    test::PascalSquareMillimetreToNewton;
  ASSERT_GT(std::abs(neoHookeanForce - expected), 0.03 * std::abs(expected));
  struct Grid
  {
    const char * name;
    GridCells    cells;
    bool         meshless;
    double       tolerance;
  };
  for (const Grid & grid : { Grid{ "hexahedra", GridCells::Hexahedra, false, 1e-4 },
                             Grid{ "ANP tetrahedra", GridCells::Tetrahedra, false, 1e-4 },
                             Grid{ "meshless", GridCells::Hexahedra, true, 1e-3 } })
  {
    std::vector<std::string> components;
    const double             force = UniaxialReaction(material, grid.cells, grid.meshless, lambda, &components);
    EXPECT_NEAR(force, expected, grid.tolerance * std::abs(expected)) << grid.name;
    EXPECT_NE(std::find(components.begin(), components.end(), "mooney-rivlin"), components.end()) << grid.name;
    EXPECT_EQ(std::find(components.begin(), components.end(), "neo-hookean"), components.end()) << grid.name;
  }
}

TEST(MaterialLaw, NamesAndBadParametersAreNamedErrors)
{
  for (const MaterialLawDescription & law : MaterialLaws())
  {
    EXPECT_EQ(MaterialLawNamed(law.name), law.law);
    EXPECT_EQ(MaterialLawOfCode(static_cast<double>(law.law)), law.law);
  }
  EXPECT_EQ(MaterialLawNames(), "neo-hookean, mooney-rivlin");
  // docs/materials.md has a row for every law of the table, with its CalculiX card.
  const std::string docs = test::ReadText(std::string(BMR_SOURCE_DIR) + "/docs/materials.md");
  for (const MaterialLawDescription & law : MaterialLaws())
  {
    EXPECT_CONTAINS(docs, "| `" + std::string(law.name) + "`");
    EXPECT_CONTAINS(docs, "`" + std::string(law.calculixKeyword) + "`");
    EXPECT_CONTAINS(docs, law.formula);
  }
  EXPECT_CONTAINS(ErrorMessage([] { MaterialLawNamed("ogden"); }), "the laws are neo-hookean, mooney-rivlin");
  EXPECT_CONTAINS(ErrorMessage([] { MaterialLawOfCode(7.0); }), "0 neo-hookean, 1 mooney-rivlin");

  Material shareWithoutLaw = test::MakeMaterial(3000.0, 0.45);
  shareWithoutLaw.secondInvariantShare = 0.3;
  EXPECT_CONTAINS(MaterialLawProblem(shareWithoutLaw), "set the law to mooney-rivlin");
  for (const double share : { -0.1, 1.5, std::nan("") })
  {
    EXPECT_CONTAINS(MaterialLawProblem(MooneyRivlinMaterial(share)), "must lie in [0, 1]");
    Model model = MakeBlockMesh(Vector3::Constant(10.0), { 1, 1, 1 }, GridCells::Hexahedra, MooneyRivlinMaterial(share));
    EXPECT_CONTAINS(ErrorMessage([&] { model.Validate(); }), "material 0 ('tissue') has a second-invariant share");
  }
  // CalculiX's constants: C10 + C01 = mu / 2, D1 = 2 / kappa (MPa).
  const Material            material = MooneyRivlinMaterial(0.25);
  const std::vector<double> constants = CalculixMaterialConstants(material);
  ASSERT_EQ(constants.size(), 3u);
  EXPECT_NEAR(constants[0] + constants[1], 0.5 * material.ShearModulus() * units::PascalToInternal, 1e-18);
  EXPECT_NEAR(constants[1] / (constants[0] + constants[1]), 0.25, 1e-15);
  EXPECT_NEAR(constants[2], 2.0 / (material.BulkModulus() * units::PascalToInternal), 1e-12);
}

// A law's parameters are named once (MaterialParameters()): each is a member
// of Material at its neutral value by default and part of MaterialKey, which
// the scene parser, the material mapping and the mesh files go by.
TEST(MaterialLaw, EveryParameterIsNamedOnceAndTellsMaterialsApart)
{
  const Material plain;
  std::set<std::string> names;
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    EXPECT_TRUE(names.insert(parameter.name).second) << parameter.name;
    EXPECT_EQ(plain.*parameter.value, parameter.neutral) << parameter.name;
    EXPECT_GT(std::string(parameter.meaning).size(), 10u);
    Material other = plain;
    other.*parameter.value = parameter.neutral + 0.5;
    EXPECT_NE(MaterialKey(other), MaterialKey(plain)) << parameter.name;
  }
  EXPECT_EQ(MaterialKey(plain).size(), 4 + MaterialParameters().size());
  EXPECT_EQ(MaterialKey(plain)[3], static_cast<double>(MaterialLaw::NeoHookean));
  Material renamed = plain;
  renamed.name = "another name";
  EXPECT_EQ(MaterialKey(renamed), MaterialKey(plain));
  ASSERT_EQ(MaterialParameters().size(), 1u); // Mooney-Rivlin's share; a new one needs the formats' versions raised
  EXPECT_EQ(std::string(MaterialParameters()[0].name), "second_invariant_share");
}

TEST(MaterialLaw, ScenesCarryTheLawAndNameItsMistakes)
{
  const auto scene = [](const std::string & material) {
    return R"({"mesh": {"generate": "block", "size": [10, 10, 10], "divisions": [1, 1, 1]},
               "materials": [)" +
           material + R"(], "fixed": [{"node_set": "zmin"}]})";
  };
  const Scene parsed = ParseScene(
    scene(R"({"youngs_modulus": 3000, "poisson_ratio": 0.45, "law": "mooney-rivlin", "second_invariant_share": 0.4})"),
    "law.json");
  ASSERT_EQ(parsed.model.materials.size(), 1u);
  EXPECT_EQ(parsed.model.materials[0].law, MaterialLaw::MooneyRivlin);
  EXPECT_EQ(parsed.model.materials[0].secondInvariantShare, 0.4);
  EXPECT_EQ(ParseScene(scene(R"({"youngs_modulus": 3000, "poisson_ratio": 0.45})"), "default.json").model.materials[0].law,
            MaterialLaw::NeoHookean);
  EXPECT_CONTAINS(ErrorMessage([&] {
                    ParseScene(scene(R"({"youngs_modulus": 3000, "poisson_ratio": 0.45, "law": "hooke"})"), "bad.json");
                  }),
                  "\"hooke\" is not one of: neo-hookean, mooney-rivlin");
  EXPECT_CONTAINS(ErrorMessage([&] {
                    ParseScene(scene(R"({"youngs_modulus": 3000, "poisson_ratio": 0.45, "second_invariant_share": 0.2})"),
                               "bad.json");
                  }),
                  "materials[0]: has a second-invariant share of 0.2 but the neo-hookean law has none");
}

class MaterialLawFiles : public test::TemporaryFolderTest
{};

// Integration points that carry a law's code but not its parameters' arrays
// (here Mooney-Rivlin's share renamed away) are a named error, not materials
// at the parameters' neutral values.
TEST_F(MaterialLawFiles, IntegrationPointsWithALawButNotItsParametersAreANamedError)
{
  Model model = MakeBlockMesh(Vector3::Constant(10.0), { 2, 2, 2 }, GridCells::Hexahedra, MooneyRivlinMaterial(0.3));
  MakeMeshlessFromCells(model, {}, {}, 1);
  const std::filesystem::path written = m_Folder / "points.vtu", crafted = m_Folder / "crafted.vtu";
  WriteIntegrationPoints(written.string(), model);
  std::string       text = test::ReadText(written);
  const std::string name = "Name=\"second_invariant_share\"";
  ASSERT_NE(text.find(name), std::string::npos);
  text.replace(text.find(name), name.size(), "Name=\"second_invariant_shareX\"");
  std::ofstream(crafted, std::ios::binary) << text;
  const std::string message = test::ErrorMessage([&] { ReadIntegrationPoints(crafted.string()); });
  EXPECT_CONTAINS(message, "needs all the point-data arrays 'material_law', 'second_invariant_share' with one value "
                           "per point, or none (neo-Hookean)");
}

TEST_F(MaterialLawFiles, IntegrationPointsAndPrecomputationsKeepTheLaw)
{
  Model model = MakeBlockMesh(Vector3::Constant(10.0), { 2, 2, 2 }, GridCells::Hexahedra, MooneyRivlinMaterial(0.3));
  model.materials.push_back(test::MakeMaterial(1000.0, 0.3, 1000.0, "soft"));
  model.cells[0].material = 1;
  MakeMeshlessFromCells(model, {}, {}, 1);
  const std::string path = (m_Folder / "points.vtu").string();
  WriteIntegrationPoints(path, model);
  const IntegrationPointData points = ReadIntegrationPoints(path);
  ASSERT_EQ(points.materials.size(), model.meshless.integrationMaterials.size());
  for (std::size_t p = 0; p < points.materials.size(); ++p)
  {
    const Material & written = model.materials[model.meshless.integrationMaterials[p]];
    EXPECT_EQ(points.materials[p].law, written.law);
    EXPECT_EQ(points.materials[p].secondInvariantShare, written.secondInvariantShare);
  }

  // A precomputation made for the neo-Hookean model is not taken for the
  // Mooney-Rivlin one, and one read back solves as the model does.
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  PrescribedDisplacement push;
  push.nodes = model.NodeSet("zmax");
  push.displacements.assign(push.nodes.size(), Vector3(0.0, 0.0, -2.0));
  model.prescribedDisplacements.push_back(push);
  SolverSettings settings;
  settings.integrator = Integrator::DynamicRelaxation;
  settings.threads = 1;
  Model neoHookean = model;
  neoHookean.materials[0].law = MaterialLaw::NeoHookean;
  neoHookean.materials[0].secondInvariantShare = 0.0;
  EXPECT_NE(SolverPrecomputation(neoHookean, settings).Mismatch(model, settings), "");
  BinaryWriter out;
  SolverPrecomputation(model, settings).Write(out);
  BinaryReader in(out.Bytes(), "precomputation", "make it again");
  const SolverPrecomputation        read = SolverPrecomputation::Read(in);
  EXPECT_EQ(read.Mismatch(model, settings), "");
  const SolveResult direct = Solver(model, settings).Solve();
  Solver            fromFile(model, settings, &read);
  const SolveResult stored = fromFile.Solve();
  ASSERT_TRUE(direct.converged) << direct.message;
  EXPECT_EQ(stored.displacements, direct.displacements);
  const SolveResult plain = Solver(neoHookean, settings).Solve();
  EXPECT_GT((plain.displacements[model.NodeSet("all")[13]] - direct.displacements[model.NodeSet("all")[13]]).norm(), 1e-3);
}

} // namespace
} // namespace bmr
