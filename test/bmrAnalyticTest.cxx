// Homogeneous deformations of a neo-Hookean block against their analytic
// solutions: uniaxial compression and tension (lateral faces traction-free) and
// simple shear, for hexahedra, ANP tetrahedra and mixed meshes, nu = 0.45 and
// 0.49. Every element type reproduces a homogeneous deformation exactly, so the
// only error left is the dynamic-relaxation termination error (tolerance 1e-9 mm):
// displacements and reaction forces are asserted to 1e-6 relative.
#include "bmrTestUtilities.h"

#include <gtest/gtest.h>

#include <cmath>
#include <sstream>
#include <tuple>

namespace bmr
{
namespace
{
using namespace bmr::test;

const Vector3            kBlockSize(10.0, 8.0, 6.0); // mm
const std::array<int, 3> kDivisions{ 4, 3, 3 };

struct AnalyticCase
{
  GridCells cells;
  double    poissonRatio;
};

std::string
CaseName(const testing::TestParamInfo<AnalyticCase> & info)
{
  std::ostringstream name;
  switch (info.param.cells)
  {
    case GridCells::Hexahedra:
      name << "Hexahedra";
      break;
    case GridCells::Tetrahedra:
      name << "AnpTetrahedra";
      break;
    case GridCells::Mixed:
      name << "Mixed";
      break;
  }
  name << "_nu" << static_cast<int>(std::lround(info.param.poissonRatio * 1000));
  return name.str();
}

class AnalyticTest : public testing::TestWithParam<AnalyticCase>
{
protected:
  Material TissueMaterial() const { return MakeMaterial(3000.0, GetParam().poissonRatio); }

  /** Uniaxial stress with axial stretch lambda along x, symmetry planes at the
   *  minimum faces, x-displacement prescribed on xmax, lateral faces free. */
  void CheckUniaxial(double lambda)
  {
    const Material   material = TissueMaterial();
    const NeoHookean law(material);
    Model            model = MakeBlockMesh(kBlockSize, kDivisions, GetParam().cells, material);
    AddSymmetryConstraints(model);
    const Matrix3           F = UniaxialDeformationGradient(lambda, law);
    const DisplacementField exact = HomogeneousField(F);
    Prescribe(model, model.NodeSet("xmax"), exact, { true, false, false });

    SolverSettings settings = TightRelaxation();
    settings.computeStress = true;
    Solver            solver(model, settings);
    const SolveResult result = solver.Solve();
    ASSERT_TRUE(result.converged) << result.message;
    ASSERT_EQ(result.displacements.size(), model.nodes.size());

    // Cauchy stress (Pa) in every cell: sigma_11 analytic, all else zero.
    const Matrix3 sigma = law.Cauchy(F);
    EXPECT_NEAR(sigma(1, 1), 0.0, 1e-9 * std::abs(sigma(0, 0)));
    ASSERT_EQ(result.cauchyStress.size(), model.cells.size());
    double stressError = 0.0;
    for (const Matrix3 & cellStress : result.cauchyStress)
      stressError = std::max(stressError, (cellStress - sigma).cwiseAbs().maxCoeff());
    RecordProperty("relativeStressError", Sci(stressError / std::abs(sigma(0, 0))));
    EXPECT_LT(stressError, 1e-6 * std::abs(sigma(0, 0))) << "sigma_11 = " << sigma(0, 0) << " Pa";

    const double scale = MaxFieldNorm(model, exact);
    RecordProperty("relativeDisplacementError", Sci(MaxNodalError(model, result.displacements, exact) / scale));
    RecordProperty("steps", result.steps);
    EXPECT_LT(MaxNodalError(model, result.displacements, exact), 1e-6 * scale)
      << "lambda " << lambda << " lateral stretch " << F(1, 1);
    EXPECT_NEAR(result.maxDisplacement, scale, 1e-6 * scale);

    // Total axial reaction on xmax (N) = P11 * A0; the symmetry plane xmin carries
    // the opposite force; the lateral faces carry no x-force.
    const Matrix3 P = law.FirstPiola(F);
    const double  area = kBlockSize.y() * kBlockSize.z();
    const double  expected = P(0, 0) * area * PascalSquareMillimetreToNewton;
    const Vector3 onXmax = SumOver(result.reactionForces, model.NodeSet("xmax"));
    const Vector3 onXmin = SumOver(result.reactionForces, model.NodeSet("xmin"));
    RecordProperty("relativeForceError", Sci(std::abs(onXmax.x() - expected) / std::abs(expected)));
    EXPECT_NEAR(onXmax.x(), expected, 1e-6 * std::abs(expected)) << "P11 = " << P(0, 0) << " Pa";
    EXPECT_NEAR(onXmin.x(), -expected, 1e-6 * std::abs(expected));
    // No net force on the body: every reaction sums to zero.
    const Vector3 total = SumOver(result.reactionForces, model.NodeSet("all"));
    EXPECT_LT(total.norm(), 1e-6 * std::abs(expected));

    // Strain energy (J) = W * V0; Pa * mm^3 -> J is 1e-9.
    const double volume = kBlockSize.prod();
    const double energy = law.EnergyDensity(F) * volume * 1e-9;
    EXPECT_NEAR(result.strainEnergy, energy, 1e-6 * energy); // includes hourglass energy (zero here)
    EXPECT_LT(std::abs(result.hourglassEnergy), 1e-9 * energy);
  }
};

TEST_P(AnalyticTest, UniaxialCompression30Percent)
{
  CheckUniaxial(0.7);
}

TEST_P(AnalyticTest, UniaxialTension20Percent)
{
  CheckUniaxial(1.2);
}

TEST_P(AnalyticTest, SimpleShear)
{
  const double     gamma = 0.3;
  const Material   material = TissueMaterial();
  const NeoHookean law(material);
  Model            model = MakeBlockMesh(kBlockSize, kDivisions, GetParam().cells, material);
  const Matrix3    F = SimpleShearDeformationGradient(gamma);
  const DisplacementField exact = HomogeneousField(F); // u = (gamma z, 0, 0)
  const std::vector<Index> boundary = BlockBoundaryNodes(model);
  const std::vector<Index> interior = ComplementNodes(model, boundary);
  ASSERT_FALSE(interior.empty());
  Prescribe(model, boundary, exact);

  Solver            solver(model, TightRelaxation());
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;

  const double scale = MaxFieldNorm(model, exact); // gamma * height
  RecordProperty("relativeDisplacementError",
                 Sci(MaxNodalError(model, result.displacements, exact, interior) / scale));
  RecordProperty("steps", result.steps);
  EXPECT_LT(MaxNodalError(model, result.displacements, exact, interior), 1e-6 * scale);

  // Resultant on the top face = P e3 * A0: x (shear) P13 = mu gamma, z (normal)
  // P33 = -mu gamma^2 / 3 (J = 1). The side faces' contributions at the top
  // edges cancel pairwise (opposite normals, identical face meshes).
  const Matrix3 P = law.FirstPiola(F);
  EXPECT_NEAR(P(0, 2), law.mu * gamma, 1e-9 * law.mu);
  EXPECT_NEAR(P(2, 2), -law.mu * gamma * gamma / 3.0, 1e-9 * law.mu);
  const double  area = kBlockSize.x() * kBlockSize.y();
  const Vector3 expected = P.col(2) * area * PascalSquareMillimetreToNewton;
  const Vector3 onTop = SumOver(result.reactionForces, model.NodeSet("zmax"));
  const Vector3 onBottom = SumOver(result.reactionForces, model.NodeSet("zmin"));
  const double  forceScale = expected.norm();
  EXPECT_NEAR(onTop.x(), expected.x(), 1e-6 * forceScale);
  EXPECT_NEAR(onTop.y(), 0.0, 1e-6 * forceScale);
  EXPECT_NEAR(onTop.z(), expected.z(), 1e-6 * forceScale);
  EXPECT_NEAR(onBottom.x(), -expected.x(), 1e-6 * forceScale);
  EXPECT_NEAR(onBottom.z(), -expected.z(), 1e-6 * forceScale);
  // Interior nodes are free: no reaction there.
  EXPECT_EQ(MaxNorm(result.reactionForces, interior), 0.0);

  const double energy = law.EnergyDensity(F) * kBlockSize.prod() * 1e-9;
  EXPECT_NEAR(result.strainEnergy, energy, 1e-6 * energy); // includes hourglass energy (zero here)
}

// A warm start (the steady state of an earlier solve, as a later
// intraoperative update begins from the previous one) reaches the same
// analytic solution: tension 20 % from the solved 10 %, its prescribed values
// ramping from the state's to the model's.
TEST_P(AnalyticTest, WarmStartFromAnotherStretchReachesTheSameSolution)
{
  const Material   material = TissueMaterial();
  const NeoHookean law(material);
  const auto       stretched = [&](double lambda) {
    Model model = MakeBlockMesh(kBlockSize, kDivisions, GetParam().cells, material);
    AddSymmetryConstraints(model);
    Prescribe(model, model.NodeSet("xmax"), HomogeneousField(UniaxialDeformationGradient(lambda, law)),
              { true, false, false });
    return model;
  };
  const Model       first = stretched(1.1);
  const SolveResult previous = Solver(first, TightRelaxation()).Solve();
  ASSERT_TRUE(previous.converged) << previous.message;
  EXPECT_FALSE(previous.warmStarted);
  EXPECT_GT(previous.lowestEigenvalue, 0.0);

  const Model             model = stretched(1.2);
  const DisplacementField exact = HomogeneousField(UniaxialDeformationGradient(1.2, law));
  const SolveResult       cold = Solver(model, TightRelaxation()).Solve();
  Solver                  solver(model, TightRelaxation());
  solver.SetWarmStart(WarmStartFrom(previous));
  const SolveResult warm = solver.Solve();
  ASSERT_TRUE(warm.converged) << warm.message;
  EXPECT_TRUE(warm.warmStarted);
  const double scale = MaxFieldNorm(model, exact);
  EXPECT_LT(MaxNodalError(model, warm.displacements, exact), 1e-6 * scale);
  RecordProperty("coldSteps", cold.steps);
  RecordProperty("warmSteps", warm.steps);
  EXPECT_LT(warm.steps, cold.steps);
}

INSTANTIATE_TEST_SUITE_P(Cells,
                         AnalyticTest,
                         testing::Values(AnalyticCase{ GridCells::Hexahedra, 0.45 },
                                         AnalyticCase{ GridCells::Hexahedra, 0.49 },
                                         AnalyticCase{ GridCells::Tetrahedra, 0.45 },
                                         AnalyticCase{ GridCells::Tetrahedra, 0.49 },
                                         AnalyticCase{ GridCells::Mixed, 0.45 },
                                         AnalyticCase{ GridCells::Mixed, 0.49 }),
                         CaseName);

// The collapse barrier (docs/solver.md): a soft, compressible block (CSF: 10
// Pa, nu 0.1, kappa 4.2 Pa) squeezed hydrostatically to 30 % of its volume
// by its whole boundary. Without the barrier its pressure could never exceed
// kappa; with it, sigma = (kappa (J - 1) - Kc (0.5 / J - 1)^2) I, Kc the
// setting (1000 Pa here), on every cell type (the ANP tetrahedron's own J
// carries the barrier). Reactions, stress and energy to 1e-6 relative.
class CollapseBarrierTest : public testing::TestWithParam<GridCells>
{};

TEST_P(CollapseBarrierTest, HydrostaticCollapseToThirtyPercentOfTheVolume)
{
  const Material material = MakeMaterial(10.0, 0.1, 1000.0, "csf");
  NeoHookean     law(material);
  law.collapseModulus = 1000.0;
  Model          model = MakeBlockMesh(kBlockSize, kDivisions, GetParam(), material);
  const double   J = 0.3;
  const Matrix3  F = std::cbrt(J) * Matrix3::Identity();
  const DisplacementField  exact = HomogeneousField(F);
  const std::vector<Index> boundary = BlockBoundaryNodes(model);
  Prescribe(model, boundary, exact);

  SolverSettings settings = TightRelaxation();
  settings.collapseBulkModulus = law.collapseModulus;
  settings.computeStress = true;
  Solver            solver(model, settings);
  const SolveResult result = solver.Solve();
  ASSERT_TRUE(result.converged) << result.message;

  const Matrix3 sigma = law.Cauchy(F);
  const double  pressure = law.kappa * (J - 1.0) - law.collapseModulus * (0.5 / J - 1.0) * (0.5 / J - 1.0);
  EXPECT_NEAR(sigma(0, 0), pressure, 1e-12 * std::abs(pressure));
  EXPECT_LT(pressure, -100.0 * law.kappa); // the barrier, not the neo-Hookean kappa, carries the load
  for (const Matrix3 & cellStress : result.cauchyStress)
  {
    EXPECT_LT((cellStress - sigma).cwiseAbs().maxCoeff(), 1e-6 * std::abs(pressure));
  }
  // Reaction on the top face: P33 A0 with P = J sigma F^-T.
  const Matrix3 P = J * sigma * F.inverse().transpose();
  const double  expected = P(2, 2) * kBlockSize.x() * kBlockSize.y() * PascalSquareMillimetreToNewton;
  const Vector3 onTop = SumOver(result.reactionForces, model.NodeSet("zmax"));
  EXPECT_NEAR(onTop.z(), expected, 1e-6 * std::abs(expected));
  const double energy = law.EnergyDensity(F) * kBlockSize.prod() * 1e-9;
  EXPECT_NEAR(result.strainEnergy, energy, 1e-6 * energy);

  // The automatic barrier of a single-material model is its own kappa: about 240 times weaker here.
  settings.collapseBulkModulus = 0.0;
  const SolveResult own = Solver(model, settings).Solve();
  ASSERT_TRUE(own.converged) << own.message;
  NeoHookean ownLaw(material);
  ownLaw.collapseModulus = ownLaw.kappa;
  const double ownExpected = (J * ownLaw.Cauchy(F) * F.inverse().transpose())(2, 2) * kBlockSize.x() *
                             kBlockSize.y() * PascalSquareMillimetreToNewton;
  EXPECT_NEAR(SumOver(own.reactionForces, model.NodeSet("zmax")).z(), ownExpected, 1e-6 * std::abs(ownExpected));
}

INSTANTIATE_TEST_SUITE_P(Cells,
                         CollapseBarrierTest,
                         testing::Values(GridCells::Hexahedra, GridCells::Tetrahedra, GridCells::Mixed),
                         [](const testing::TestParamInfo<GridCells> & info) {
                           return info.param == GridCells::Hexahedra    ? std::string("Hexahedra")
                                  : info.param == GridCells::Tetrahedra ? std::string("AnpTetrahedra")
                                                                        : std::string("Mixed");
                         });

// A warm start under body loads: the state's own loads (its internal forces)
// fade out as the model's gravity fades in, so a tissue block standing on its
// fixed base under full gravity, started from its steady state under half of
// it, reaches the cold solve's state (solved to 1e-9 mm both, no contact:
// one equilibrium), and started from the full-gravity state itself it is
// there at once, at rest to the tolerance, in far fewer steps. A state of
// another model, or for explicit dynamics, is refused.
TEST(WarmStart, BodyLoadsFadeFromTheStatesToTheModels)
{
  for (const GridCells cells : { GridCells::Hexahedra, GridCells::Tetrahedra })
  {
    SCOPED_TRACE(cells == GridCells::Hexahedra ? "hexahedra" : "ANP tetrahedra");
    Model half = MakeBlockMesh(Vector3(20.0, 20.0, 10.0), { 8, 8, 4 }, cells, MakeMaterial(3000.0, 0.49));
    half.fixedConstraints.push_back({ "zmin", { true, true, true } });
    half.bodyAcceleration = Vector3(0.0, 0.0, -0.5 * 9810.0);
    Model full = half;
    full.bodyAcceleration = Vector3(0.0, 0.0, -9810.0);
    const SolverSettings settings = TightRelaxation();
    const SolveResult    previous = Solver(half, settings).Solve();
    const SolveResult    cold = Solver(full, settings).Solve();
    ASSERT_TRUE(previous.converged && cold.converged) << previous.message << cold.message;
    ASSERT_GT(cold.maxDisplacement, 0.1);

    Solver fromHalf(full, settings);
    fromHalf.SetWarmStart(WarmStartFrom(previous));
    const SolveResult warm = fromHalf.Solve();
    ASSERT_TRUE(warm.converged) << warm.message;
    double difference = 0.0;
    for (std::size_t n = 0; n < full.nodes.size(); ++n)
    {
      difference = std::max(difference, (warm.displacements[n] - cold.displacements[n]).norm());
    }
    EXPECT_LT(difference, 1e-7) << "mm; cold " << cold.steps << " steps, warm " << warm.steps;
    EXPECT_LT(warm.steps, cold.steps);

    Solver fromItself(full, settings);
    fromItself.SetWarmStart(WarmStartFrom(cold));
    const SolveResult again = fromItself.Solve();
    ASSERT_TRUE(again.converged) << again.message;
    EXPECT_LT(again.steps, warm.steps / 2);
    double moved = 0.0;
    for (std::size_t n = 0; n < full.nodes.size(); ++n)
    {
      moved = std::max(moved, (again.displacements[n] - cold.displacements[n]).norm());
    }
    EXPECT_LT(moved, 1e-7);

    WarmStart shorter = WarmStartFrom(cold);
    shorter.state.pop_back();
    Solver other(full, settings);
    EXPECT_NE(ThrownMessage([&] { other.SetWarmStart(shorter); }).find("the solution of another model"), std::string::npos);
    SolverSettings explicitDynamics = settings;
    explicitDynamics.integrator = Integrator::ExplicitDynamics;
    Solver dynamics(full, explicitDynamics);
    EXPECT_NE(ThrownMessage([&] { dynamics.SetWarmStart(WarmStartFrom(cold)); }).find("for dynamic relaxation"),
              std::string::npos);
  }
}

// The analytic helper itself: uniaxial stress has zero lateral Cauchy stress
// and, for the nearly incompressible limit, J close to 1.
TEST(AnalyticHelpers, UniaxialLateralStressVanishes)
{
  const NeoHookean law(MakeMaterial(3000.0, 0.49));
  for (double lambda : { 0.5, 0.7, 1.2, 1.5 })
  {
    const Matrix3 F = UniaxialDeformationGradient(lambda, law);
    const Matrix3 sigma = law.Cauchy(F);
    EXPECT_NEAR(sigma(1, 1), 0.0, 1e-9 * law.mu);
    EXPECT_NEAR(sigma(2, 2), 0.0, 1e-9 * law.mu);
    EXPECT_NEAR(F.determinant(), 1.0, 0.05);
    // Finite-difference check of P = dW/dF for the axial component.
    const double h = 1e-6;
    Matrix3      Fp = F, Fm = F;
    Fp(0, 0) += h;
    Fm(0, 0) -= h;
    const double dW = (law.EnergyDensity(Fp) - law.EnergyDensity(Fm)) / (2 * h);
    EXPECT_NEAR(law.FirstPiola(F)(0, 0), dW, 1e-5 * std::abs(dW));
  }
  // The collapse barrier's stress is the derivative of its energy, on both sides of J = 0.5.
  NeoHookean soft(MakeMaterial(10.0, 0.1));
  soft.collapseModulus = 1000.0;
  for (double J : { 0.2, 0.45, 0.55 })
  {
    Matrix3 F = Matrix3::Identity();
    F(0, 0) = J;
    F(0, 1) = 0.2;
    const double h = 1e-7;
    Matrix3      Fp = F, Fm = F;
    Fp(0, 0) += h;
    Fm(0, 0) -= h;
    const double dW = (soft.EnergyDensity(Fp) - soft.EnergyDensity(Fm)) / (2 * h);
    EXPECT_NEAR(soft.FirstPiola(F)(0, 0), dW, 1e-5 * std::abs(dW)) << "J " << J;
  }
}

} // namespace
} // namespace bmr
