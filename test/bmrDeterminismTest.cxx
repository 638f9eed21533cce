// Same input, same result, for 1 or N threads: displacements, reaction forces
// and step counts bitwise identical (forces are assembled in a fixed order);
// and the same again from a stored precomputation (a model bundle's).
#include "bmrBinaryStream.h"
#include "bmrForceModel.h"
#include "bmrMeshless.h"
#include "bmrTemporaryFolderTest.h" // EXPECT_CONTAINS
#include "bmrTestUtilities.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <random>

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

// ---------------------------------------------------------------------------
// The meshless kernel renumbers the nodes for itself (MortonNumbering); what
// it returns must not depend on how the model numbers its nodes.
// ---------------------------------------------------------------------------

/** The model with node n renumbered newId[n] (positions and cells; the force
 *  models read nothing else that names nodes). */
Model
Renumbered(const Model & model, const std::vector<Index> & newId)
{
  Model renumbered = model;
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    renumbered.nodes[newId[n]] = model.nodes[n];
  }
  for (Cell & cell : renumbered.cells)
  {
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      cell.nodes[a] = newId[cell.nodes[a]];
    }
  }
  return renumbered;
}

std::vector<Index>
ShuffledIds(std::size_t count)
{
  std::vector<Index> ids(count);
  std::iota(ids.begin(), ids.end(), Index{ 0 });
  std::shuffle(ids.begin(), ids.end(), std::mt19937(7));
  return ids;
}

/** Forces, lumped and scaled masses of `a` and `b` (= a renumbered by newId)
 *  at the same displacements; every value of b must equal a's for the same
 *  node, to `tolerance` relative to the largest (0: bitwise). */
void
ExpectSameNodalQuantities(ForceModel & a, ForceModel & b, const std::vector<Index> & newId, double tolerance)
{
  const std::size_t                      count = newId.size();
  std::mt19937                           random(3);
  std::uniform_real_distribution<double> displacement(-0.1, 0.1);
  std::vector<double>                    uA(3 * count), uB(3 * count), fA(3 * count), fB(3 * count);
  for (std::size_t n = 0; n < count; ++n)
  {
    for (int i = 0; i < 3; ++i)
    {
      uA[3 * n + i] = uB[3 * newId[n] + i] = displacement(random);
    }
  }
  ASSERT_EQ(a.ComputeInternalForces(uA.data(), fA.data()), -1);
  ASSERT_EQ(b.ComputeInternalForces(uB.data(), fB.data()), -1);
  const auto expectSame = [&](const std::vector<double> & valuesA, const std::vector<double> & valuesB, int width,
                              const char * what) {
    double largest = 0.0, worst = 0.0;
    for (std::size_t n = 0; n < count; ++n)
    {
      for (int i = 0; i < width; ++i)
      {
        largest = std::max(largest, std::abs(valuesA[width * n + i]));
        worst = std::max(worst, std::abs(valuesA[width * n + i] - valuesB[width * newId[n] + i]));
      }
    }
    EXPECT_GT(largest, 0.0) << what;
    EXPECT_LE(worst, tolerance * largest) << what << ": largest " << largest;
  };
  expectSame(fA, fB, 3, "internal forces");
  expectSame(a.LumpedMasses(), b.LumpedMasses(), 1, "lumped masses");
  expectSame(a.ScaledMasses(1.0, 0.8, true), b.ScaledMasses(1.0, 0.8, true), 1, "scaled masses");
  EXPECT_NEAR(a.ComputeEnergies(uA.data()).strain, b.ComputeEnergies(uB.data()).strain,
              1e-12 * a.ComputeEnergies(uA.data()).strain);
}

TEST(Determinism, MeshlessForcesDoNotDependOnTheNodeNumbering)
{
  // The MLS tables list each point's neighbours in node order, so the sums
  // over them run in another order: equal to rounding.
  Model a = MakeBlockMesh(Vector3(6.0, 5.0, 4.0), { 6, 5, 4 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
  DistortInteriorNodes(a, 0.2, 5);
  MakeMeshlessFromCells(a, {}, {}, 1);
  const std::vector<Index> newId = ShuffledIds(a.nodes.size());
  const Model              b = Renumbered(a, newId);
  const SolverSettings     settings;
  const auto               table = [](const Model & model) {
    return MovingLeastSquares::ForModel(model)->Evaluate(model.meshless.integrationPoints, true, 1);
  };
  MeshlessForceModel forcesA(a, table(a), settings, 2), forcesB(b, table(b), settings, 2);
  ExpectSameNodalQuantities(forcesA, forcesB, newId, 1e-12);
}

// ---------------------------------------------------------------------------
// The Total Lagrangian precomputation made apart (before surgery, from the
// model without its loads), written, read back and handed to the solver: the
// same solve bit for bit. Made for another model or other settings, or
// damaged: a named error, never a solve.
// ---------------------------------------------------------------------------

/** The model as `biomech prepare` has it: no loads, no contact, no gravity. */
Model
Unloaded(Model model)
{
  model.prescribedDisplacements.clear();
  model.fixedConstraints.clear();
  model.contactSurfaces.clear();
  model.bodyAcceleration.setZero();
  return model;
}

std::string
Stored(const SolverPrecomputation & precomputation)
{
  BinaryWriter out;
  precomputation.Write(out);
  return out.Bytes();
}

SolverPrecomputation
ReadBack(const std::string & bytes)
{
  BinaryReader in(bytes, "the precomputation", "make it again");
  return SolverPrecomputation::Read(in);
}

/** Precomputed with 1 thread and read back, the solve with 2 equals the one that computes its own. */
void
ExpectStoredPrecomputationSolvesTheSame(const Model & model, SolverSettings settings)
{
  settings.threads = 1;
  const std::string          bytes = Stored(SolverPrecomputation(Unloaded(model), settings));
  const SolverPrecomputation read = ReadBack(bytes);
  EXPECT_EQ(Stored(read), bytes) << "written again: the same bytes";
  EXPECT_EQ(read.Mismatch(model, settings), "");
  settings.threads = 2;
  const SolveResult own = Solver(model, settings).Solve();
  const SolveResult stored = Solver(model, settings, &read).Solve();
  EXPECT_TRUE(own.converged);
  EXPECT_GT(own.maxDisplacement, 0.1);
  EXPECT_EQ(own.steps, stored.steps);
  EXPECT_TRUE(BitwiseEqual(own.displacements, stored.displacements));
  EXPECT_TRUE(BitwiseEqual(own.reactionForces, stored.reactionForces));
  EXPECT_TRUE(BitwiseEqual(own.nodalParameters, stored.nodalParameters));
  EXPECT_EQ(own.strainEnergy, stored.strainEnergy);
  EXPECT_EQ(own.activeComponents, stored.activeComponents);
}

TEST(StoredPrecomputation, HexahedraSolveBitwiseTheSame)
{
  ExpectStoredPrecomputationSolvesTheSame(ContactScene(GridCells::Hexahedra), TightRelaxation(1e-6, 100000));
}

TEST(StoredPrecomputation, AnpTetrahedraSolveBitwiseTheSame)
{
  ExpectStoredPrecomputationSolvesTheSame(ContactScene(GridCells::Tetrahedra), TightRelaxation(1e-6, 100000));
}

TEST(StoredPrecomputation, MixedCellsSolveBitwiseTheSame)
{
  ExpectStoredPrecomputationSolvesTheSame(ContactScene(GridCells::Mixed), TightRelaxation(1e-6, 100000));
}

Model
MeshlessBlock()
{
  Model model = MakeBlockMesh(Vector3(6.0, 5.0, 4.0), { 6, 5, 4 }, GridCells::Hexahedra, MakeMaterial(3000.0, 0.45));
  DistortInteriorNodes(model, 0.2, 5);
  MakeMeshlessFromCells(model, {}, {}, 1);
  Prescribe(model, model.NodeSet("zmax"), [](const Vector3 & X) { return Vector3(0.05 * X.y(), 0.0, -0.4); });
  Prescribe(model, model.NodeSet("zmin"), [](const Vector3 &) { return Vector3::Zero(); });
  model.bodyAcceleration = Vector3(0.0, 0.0, -9810.0);
  return model;
}

TEST(StoredPrecomputation, MeshlessSolvesBitwiseTheSame)
{
  ExpectStoredPrecomputationSolvesTheSame(MeshlessBlock(), TightRelaxation(1e-6, 100000));
}

TEST(StoredPrecomputation, AnotherModelOrOtherSettingsAreNamed)
{
  const Model                hexahedra = ContactScene(GridCells::Hexahedra);
  const SolverSettings       settings = TightRelaxation(1e-6, 100000);
  const SolverPrecomputation precomputation(Unloaded(hexahedra), settings);
  const auto expectRefused = [&](const Model & model, const SolverSettings & other, const std::string & words) {
    EXPECT_CONTAINS(precomputation.Mismatch(model, other), words);
    try
    {
      Solver solver(model, other, &precomputation);
      ADD_FAILURE() << "a solver took a precomputation made " << words;
    }
    catch (const Error & error)
    {
      EXPECT_CONTAINS(error.what(), "precomputation was made");
      EXPECT_CONTAINS(error.what(), words);
    }
  };
  Model moved = hexahedra;
  moved.nodes[7].x() += 1e-9;
  expectRefused(moved, settings, "for another model");
  Model stiffer = hexahedra;
  stiffer.materials[0].youngsModulus *= 2.0;
  expectRefused(stiffer, settings, "for another model");
  SolverSettings hourglass = settings;
  hourglass.hourglassCoefficient = 0.1;
  expectRefused(hexahedra, hourglass, "hourglass coefficient 0.2, not 0.1");
  SolverSettings collapse = settings;
  collapse.collapseBulkModulus = 1e5;
  expectRefused(hexahedra, collapse, "collapse bulk modulus");
  expectRefused(MeshlessBlock(), settings, "for a finite-element model, not a meshless one");
  // What a solve may change freely: loads, contact, gravity, tolerance, threads.
  SolverSettings looser = settings;
  looser.tolerance = 0.01;
  looser.threads = 2;
  EXPECT_EQ(precomputation.Mismatch(hexahedra, looser), "");
}

TEST(StoredPrecomputation, FormatVersionOneIsStillRead)
{
  // Version 1 (before the materials' laws) is version 2 without the force
  // model's second-invariant table: for a neo-Hookean finite-element model
  // that table's count (8 zero bytes) comes just before the node-shape
  // tables that end the file (36 bytes: offsets {0}, three empty tables).
  const Model       model = ContactScene(GridCells::Hexahedra);
  SolverSettings    settings = TightRelaxation(1e-6, 100000);
  settings.threads = 1;
  const std::string bytes = Stored(SolverPrecomputation(Unloaded(model), settings));
  ASSERT_EQ(bytes[8], 2) << "the format version's low byte";
  ASSERT_EQ(bytes.substr(bytes.size() - 44, 8), std::string(8, '\0'));
  std::string versionOne = bytes.substr(0, bytes.size() - 44) + bytes.substr(bytes.size() - 36);
  versionOne[8] = 1;
  const SolverPrecomputation read = ReadBack(versionOne);
  EXPECT_EQ(read.Mismatch(model, settings), "");
  EXPECT_EQ(Stored(read), bytes) << "written again as version 2";
  EXPECT_TRUE(BitwiseEqual(Solver(model, settings, &read).Solve().displacements, Solver(model, settings).Solve().displacements));
}

TEST(StoredPrecomputation, DamagedIsNamed)
{
  const std::string bytes = Stored(SolverPrecomputation(Unloaded(MeshlessBlock()), SolverSettings{}));
  const auto expectDamaged = [&](const std::string & damaged, const std::string & words) {
    try
    {
      ReadBack(damaged);
      ADD_FAILURE() << "read a damaged precomputation: " << words;
    }
    catch (const Error & error)
    {
      EXPECT_CONTAINS(error.what(), "the precomputation is damaged");
      EXPECT_CONTAINS(error.what(), words);
      EXPECT_CONTAINS(error.what(), "make it again");
    }
  };
  expectDamaged(bytes.substr(0, bytes.size() / 2), "");
  expectDamaged(bytes + "x", "bytes after the end");
  expectDamaged("BMRMODEL" + bytes.substr(8), "not a solver precomputation");
  std::string otherVersion = bytes;
  otherVersion[8] = 9;
  expectDamaged(otherVersion, "format version 9");
}

} // namespace
} // namespace bmr
