// The uncertainty map where its answer is known: a perturbation that cannot
// move the solution gives none, one that must shows up where it should.
// Colin27 with 10 mm hexahedra and a 5 mm sag of a parietal opening. Then
// how its calibration is counted, and the ground truths whose physics the
// registration does not model (partial CSF drainage, a bonded skull base,
// grey and white matter), on which the validation study calibrates it.
// And its ITK face, itk::BiomechanicalUncertaintyFilter, on a block whose
// answers are known: stiffness scaled under displacements gives nothing, a
// gravity range scales a hanging block's sag by the drawn factors, two
// tissue classes in series move their interface as two springs.
// Over 800 lines on purpose: one translation unit instantiates the
// uncertainty and deformation filters' slow templates once for the
// pipeline's tests and the filter's.
// The ITK filters first: ITK's bundled Eigen before the core's (the deformation filter's header says why).
#include "itkBiomechanicalUncertaintyFilter.h"

#include "bmrBrainShiftUncertainty.h"
#include "bmrColin27.h"
#include "bmrMeshGenerators.h"
#include "bmrTestUtilities.h"
#include "bmrSagScenes.h"
#include "bmrSolver.h"
#include "bmrSyntheticBrainShift.h"
#include "bmrTemporaryFolderTest.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkTranslationTransform.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <functional>
#include <string>
#include <utility>

namespace
{

using bmr_test::Colin27;
using bmr_test::HaveColin27;
using bmr::test::ErrorMessage;

/** The prepared model (before its loads), the nominal update and its inputs. */
struct Scene
{
  bmr::BrainShiftRegistrationSettings settings;
  bmr::BrainModel                     prepared;
  bmr::BrainShiftUpdateInputs         inputs;
  bmr::BrainShiftRegistrationResult   nominal;
  bmr::Vector3                        centre;

  bmr::BrainShiftUncertaintyResult
  Ensemble(const bmr::UncertaintySettings & uncertainty) const
  {
    return bmr::EstimateBrainShiftUncertainty(prepared, nominal, inputs, settings, uncertainty);
  }
};

/** With `gravity` the brain carries 1 g towards its centroid from the
 *  opening, on drained CSF. */
Scene
MakeScene(bool gravity)
{
  const Colin27 &        colin = Colin27::Get();
  const bmr::LabelVolume mask = bmr::MaskVolume(colin.mask, "Colin27 mask");
  Scene                  scene;
  scene.centre = bmr_test::SurfacePointAlong(mask, bmr::Vector3(-0.2, 0.3, 1.0));
  scene.settings = bmr_test::CoarseRegistration(bmr::ImageGridKind::Hexahedra, 10.0, scene.centre, 30.0);
  if (gravity)
  {
    scene.settings.model.gravity = 9810.0 * (bmr_test::MaskCentroid(mask) - scene.centre).normalized();
    bmr::FindSettingField(bmr::RegistrationSettingFields(), "csf_density")->set(scene.settings, 1.0);
  }
  bmr::StageTimer timer;
  scene.prepared = bmr::PrepareBrainModel(colin.image, colin.mask, nullptr, {}, scene.settings.model, timer, false);
  bmr::PrecomputeBrainModel(scene.prepared, scene.settings, timer);
  scene.inputs.preoperativeImage = colin.image;
  scene.inputs.intraoperative.sparse = bmr_test::SagOfTheOpening(mask, scene.centre, 30.0, 5.0);
  scene.nominal = bmr::UpdateBrainShift(scene.prepared, scene.inputs, scene.settings);
  EXPECT_TRUE(scene.nominal.solve.converged) << scene.nominal.solve.message;
  return scene;
}

/** Every mechanical input off. */
bmr::EnsembleSettings
NoDraws(int members)
{
  bmr::EnsembleSettings settings;
  settings.members = members;
  settings.youngsModulusSpread = 0.0;
  settings.poissonLow = settings.poissonHigh = 0.0;
  return settings;
}

/** Every input off. */
bmr::UncertaintySettings
NothingDrawn(int members)
{
  bmr::UncertaintySettings settings;
  static_cast<bmr::EnsembleSettings &>(settings) = NoDraws(members);
  settings.noiseSigma = 0.0;
  return settings;
}

/** The smallest and largest value the members drew of one input. */
std::pair<double, double>
DrawnRange(const bmr::BrainShiftUncertaintyResult & result, double bmr::UncertaintyMember::*drawn)
{
  const auto [smallest, largest] = std::minmax_element(
    result.members.begin(), result.members.end(),
    [drawn](const bmr::UncertaintyMember & a, const bmr::UncertaintyMember & b) { return a.*drawn < b.*drawn; });
  return { (*smallest).*drawn, (*largest).*drawn };
}

class Uncertainty : public ::testing::Test
{
protected:
  void
  SetUp() override
  {
    if (!HaveColin27())
    {
      GTEST_SKIP() << "Colin27 (mricron-data) is not installed";
    }
  }
};

// Loaded by displacements and a rigid skull only, a hyperelastic brain's
// equilibrium does not depend on the scale of its stiffness: scaling every
// modulus by one factor changes nothing, whatever the factor (bounded here
// by the solver's tolerance, 0.01 mm, and the map's spline fit; measured:
// below 1e-6 mm, as dynamic relaxation's masses scale with the stiffness and
// the iterations with them). The same ensemble repeats bit for bit with 1
// and 2 threads.
TEST_F(Uncertainty, ModuliScaledTogetherUnderPrescribedDisplacementsGiveNone)
{
  const Scene              scene = MakeScene(false);
  bmr::UncertaintySettings settings = NothingDrawn(4);
  settings.youngsModulusSpread = 0.7;
  settings.threads = 2;
  const auto result = scene.Ensemble(settings);
  ASSERT_EQ(result.usedMembers, 4);
  const auto [smallest, largest] = DrawnRange(result, &bmr::UncertaintyMember::modulusFactor);
  EXPECT_GT(largest / smallest, 1.5) << "the draws must differ for the test to mean anything";
  RecordProperty("interiorMax", std::to_string(result.interiorMax));
  RecordProperty("brainMax", std::to_string(result.brainMax));
  EXPECT_LT(result.interiorMax, 0.02);
  EXPECT_LT(result.brainMax, 0.05);

  settings.threads = 1;
  const auto again = scene.Ensemble(settings);
  EXPECT_TRUE(again.nodalUncertainty == result.nodalUncertainty);

  // A factor per tissue class (CSF, grey and white matter, the tumour) does
  // move it: the tissues' stiffness against each other shapes the field.
  bmr::UncertaintySettings classes = NothingDrawn(4);
  classes.tissueModulusSpread = 0.5;
  classes.threads = 2;
  const auto perClass = scene.Ensemble(classes);
  ASSERT_EQ(perClass.usedMembers, 4);
  EXPECT_EQ(perClass.members.front().tissueFactors.size(), 4u);
  RecordProperty("perClassInteriorMax", std::to_string(perClass.interiorMax));
  RecordProperty("perClassBrainP95", std::to_string(perClass.brainP95));
  EXPECT_GT(perClass.interiorMax, 10 * result.interiorMax + 0.05);
}

// Gravity's size after CSF loss is unknown: drawn between 0.5 and 1.5 times
// the registration's, it moves the brain away from the opening, while the
// exposed surface, held at its measured displacements, cannot move at all;
// so do the moduli under gravity and the skull gap. Measurement noise
// instead moves the exposed surface most.
TEST_F(Uncertainty, GravityMattersAwayFromTheOpeningNoiseAtIt)
{
  const Scene              scene = MakeScene(true);
  bmr::UncertaintySettings settings = NothingDrawn(6);
  settings.gravityLow = 0.5;
  settings.gravityHigh = 1.5;
  const auto weight = scene.Ensemble(settings);
  ASSERT_EQ(weight.usedMembers, 6);
  RecordProperty("gravityExposedMax", std::to_string(weight.exposedMax));
  RecordProperty("gravityInteriorMax", std::to_string(weight.interiorMax));
  EXPECT_LT(weight.exposedMax, 1e-9);
  EXPECT_GT(weight.interiorMax, 0.1);
  EXPECT_GT(weight.brainP95, 0.01);

  // Under its own weight the brain's stiffness does matter (the sag scales
  // with rho g / E): the moduli reach the members.
  bmr::UncertaintySettings stiffness = NothingDrawn(4);
  stiffness.youngsModulusSpread = 0.7;
  const auto stiff = scene.Ensemble(stiffness);
  RecordProperty("modulusUnderGravityInteriorMax", std::to_string(stiff.interiorMax));
  EXPECT_GT(stiff.interiorMax, 0.1);
  EXPECT_LT(stiff.exposedMax, 1e-9);

  // A wider or narrower gap lets the brain sink further or less, away from
  // the opening; the skull moved by offsets of both signs.
  bmr::UncertaintySettings gap = NothingDrawn(4);
  gap.skullGapSpread = 0.5;
  const auto skull = scene.Ensemble(gap);
  ASSERT_EQ(skull.usedMembers, 4);
  const auto [narrowest, widest] = DrawnRange(skull, &bmr::UncertaintyMember::skullOffset);
  EXPECT_LT(narrowest, 0.0);
  EXPECT_GT(widest, 0.0);
  RecordProperty("skullGapInteriorMax", std::to_string(skull.interiorMax));
  EXPECT_GT(skull.interiorMax, 0.1);
  EXPECT_LT(skull.exposedMax, 1e-9);

  // The exposed region's radius: a member with a smaller opening holds fewer nodes at their measurements and lets
  // the rest touch the skull, a larger one loads nodes the nominal update left to the model; the map shows it at
  // the rim, and an ensemble that draws nothing shows nothing.
  bmr::UncertaintySettings rim = NothingDrawn(4);
  rim.exposedRadiusSpread = 5.0;
  const auto opening = scene.Ensemble(rim);
  ASSERT_EQ(opening.usedMembers, 4);
  const auto [smallest, largest] = DrawnRange(opening, &bmr::UncertaintyMember::exposedRadius);
  EXPECT_LT(smallest, 30.0);
  EXPECT_GT(largest, 30.0);
  RecordProperty("exposedRadiusBrainMax", std::to_string(opening.brainMax));
  EXPECT_GT(opening.brainMax, 0.1);
  EXPECT_EQ(scene.Ensemble(NothingDrawn(2)).brainMax, 0.0);

  bmr::UncertaintySettings noise = NothingDrawn(6);
  noise.noiseSigma = 0.5;
  const auto measured = scene.Ensemble(noise);
  RecordProperty("noiseExposedMedian", std::to_string(measured.exposedMedian));
  RecordProperty("noiseInteriorMedian", std::to_string(measured.interiorMedian));
  EXPECT_GT(measured.exposedMedian, 0.1);
  EXPECT_GT(measured.exposedMedian, 3.0 * measured.interiorMedian);
}

TEST_F(Uncertainty, BadSettingsAndFailedMembersAreNamed)
{
  bmr::UncertaintySettings settings = NothingDrawn(1);
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::CheckUncertaintySettings(settings); }), "at least 2");
  settings.members = 4;
  settings.youngsModulusSpread = -0.1;
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::CheckUncertaintySettings(settings); }), "Young's modulus spread");
  settings.youngsModulusSpread = 0.0;
  settings.gravityLow = 1.2;
  settings.gravityHigh = 0.8;
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::CheckUncertaintySettings(settings); }), "gravity range");
  settings.gravityLow = settings.gravityHigh = 1.0;
  settings.skullGapSpread = -1.0;
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::CheckUncertaintySettings(settings); }), "skull gap spread");
  settings.skullGapSpread = 0.0;
  settings.exposedRadiusSpread = -2.0;
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::CheckUncertaintySettings(settings); }), "exposed radius spread");
  settings.exposedRadiusSpread = 0.0;
  settings.memberTolerance = -0.01;
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::CheckUncertaintySettings(settings); }), "members' tolerance");
  settings.memberTolerance = 0.05;
  settings.poissonLow = 0.45;
  settings.poissonHigh = 0.5;
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::CheckUncertaintySettings(settings); }), "Poisson's ratio range");

  const Scene              scene = MakeScene(false);
  bmr::UncertaintySettings gravity = NothingDrawn(3);
  gravity.gravityLow = 0.5;
  EXPECT_CONTAINS(ErrorMessage([&] {
                    scene.Ensemble(gravity);
                  }),
                  "no gravity");
  // The opening drawn around a craniotomy the registration was not given as a sphere.
  bmr::BrainShiftRegistrationSettings masked = scene.settings;
  masked.model.craniotomyRadius = 0.0;
  bmr::UncertaintySettings rim = NothingDrawn(2);
  rim.exposedRadiusSpread = 3.0;
  EXPECT_CONTAINS(ErrorMessage([&] {
                    bmr::EstimateBrainShiftUncertainty(scene.prepared, scene.nominal, scene.inputs, masked, rim);
                  }),
                  "spherical craniotomy");
  // Every member stopped after 3 steps: none converged, and the ensemble says so.
  bmr::BrainShiftRegistrationSettings hurried = scene.settings;
  hurried.solver.maxSteps = 3;
  bmr::UncertaintySettings noise = NothingDrawn(3);
  noise.noiseSigma = 0.5;
  EXPECT_CONTAINS(ErrorMessage([&] {
                    bmr::EstimateBrainShiftUncertainty(scene.prepared, scene.nominal, scene.inputs, hurried, noise);
                  }),
                  "0 of 3 members converged");
}

// A map of 6 mm on one half of a region and 4 mm on the other, a
// registration 5 mm from the truth everywhere (a translation): exactly the
// first half's samples lie within the map.
TEST(UncertaintyCalibration, CountsTheErrorsWithinTheMap)
{
  auto region = bmr::RegistrationLabelImage::New();
  bmr::RegistrationLabelImage::SizeType size{ { 10, 8, 6 } };
  region->SetRegions(size);
  region->SetSpacing(std::array<double, 3>{ 2.0, 2.0, 2.0 }.data());
  region->Allocate();
  region->FillBuffer(1);
  auto bound = bmr::RegistrationImage::New();
  bound->CopyInformation(region);
  bound->SetRegions(region->GetBufferedRegion());
  bound->Allocate();
  std::size_t firstHalf = 0, sampled = 0;
  for (itk::IndexValueType k = 0; k < 6; ++k)
    for (itk::IndexValueType j = 0; j < 8; ++j)
      for (itk::IndexValueType i = 0; i < 10; ++i)
      {
        bound->SetPixel({ { i, j, k } }, i < 4 ? 6.0f : 4.0f);
        const bool taken = i % 2 == 0 && j % 2 == 0 && k % 2 == 0; // stride 2
        sampled += taken;
        firstHalf += taken && i < 4;
      }
  auto truth = itk::TranslationTransform<double, 3>::New();
  auto shifted = itk::TranslationTransform<double, 3>::New();
  shifted->SetOffset(itk::Vector<double, 3>(std::array<double, 3>{ 3.0, 4.0, 0.0 }.data()));
  const bmr::UncertaintyCalibration measured = bmr::MeasureUncertaintyCalibration(shifted, truth, region, bound);
  EXPECT_EQ(measured.samples, sampled);
  EXPECT_DOUBLE_EQ(measured.fractionWithinBound, static_cast<double>(firstHalf) / static_cast<double>(sampled));
  EXPECT_NEAR(measured.medianError, 5.0, 1e-12);
  EXPECT_EQ(measured.medianBound, 4.0);
  // Nothing moved: every error (0) lies within any map.
  EXPECT_EQ(bmr::MeasureUncertaintyCalibration(truth, truth, region, bound).fractionWithinBound, 1.0);

  auto other = bmr::RegistrationImage::New();
  other->SetRegions(bmr::RegistrationImage::SizeType{ { 4, 4, 4 } });
  other->Allocate();
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::MeasureUncertaintyCalibration(shifted, truth, region, other); }),
                  "on the region's grid");
}

/** The README demo's scene on 8 mm hexahedra, made and solved; `adjust` sets the physics under test. */
struct SolvedTruth
{
  bmr::SyntheticBrainShift truth;
  bmr::SolveResult         solve;
};

SolvedTruth
SolveTruth(const std::function<void(bmr::SyntheticBrainShiftSettings &)> & adjust)
{
  const Colin27 &                  colin = Colin27::Get();
  bmr::SyntheticBrainShiftSettings settings;
  settings.grid.elementSize = 8.0;
  settings.targetShift = 5.0;
  adjust(settings);
  SolvedTruth solved{ bmr::MakeSyntheticBrainShiftModel(colin.image, colin.mask, settings), {} };
  bmr::SolverSettings solver;
  solver.tolerance = settings.solverTolerance;
  solved.solve = bmr::Solver(solved.truth.model.model, solver).Solve();
  EXPECT_TRUE(solved.solve.converged) << solved.solve.message;
  return solved;
}

/** Largest |u_a - u_b| over the nodes (mm); the models must share their nodes. */
double
LargestDifference(const SolvedTruth & a, const SolvedTruth & b)
{
  EXPECT_EQ(a.solve.displacements.size(), b.solve.displacements.size());
  double largest = 0.0;
  for (std::size_t n = 0; n < a.solve.displacements.size(); ++n)
  {
    largest = std::max(largest, (a.solve.displacements[n] - b.solve.displacements[n]).norm());
  }
  return largest;
}

class TruthOfAnotherKind : public Uncertainty
{};

// The CSF's level bounds the drained tissue: at the brain's top every node
// is still buoyed and the truth is the weightless one; below its lowest node
// every node carries its weight, as when the CSF drains completely; a level
// between them differs from both (the tissue below it stays where the
// weightless truth has it, and the tissue above it sinks).
TEST_F(TruthOfAnotherKind, PartialDrainageLiesBetweenWeightlessAndDrained)
{
  const SolvedTruth drained = SolveTruth([](auto &) {});
  const SolvedTruth weightless = SolveTruth([](auto & s) { s.gravity = 0.0; });
  const SolvedTruth atTheTop = SolveTruth([](auto & s) { s.csfDrainedDepth = 0.0; });
  const SolvedTruth belowTheBrain = SolveTruth([](auto & s) { s.csfDrainedDepth = 500.0; });
  const SolvedTruth halfway = SolveTruth([](auto & s) { s.csfDrainedDepth = 60.0; });
  const double      gravityEffect = LargestDifference(drained, weightless);
  RecordProperty("gravityEffect", std::to_string(gravityEffect));
  ASSERT_GT(gravityEffect, 0.5) << "gravity must matter for the test to mean anything";
  EXPECT_LT(LargestDifference(atTheTop, weightless), 1e-6);
  EXPECT_LT(LargestDifference(belowTheBrain, drained), 1e-6);
  RecordProperty("halfwayFromDrained", std::to_string(LargestDifference(halfway, drained)));
  RecordProperty("halfwayFromWeightless", std::to_string(LargestDifference(halfway, weightless)));
  EXPECT_GT(LargestDifference(halfway, drained), 0.1 * gravityEffect);
  EXPECT_GT(LargestDifference(halfway, weightless), 0.1 * gravityEffect);
}

// A bonded skull base, beyond the 10 mm band that both models hold fixed:
// its nodes leave the contact and do not move, where the sliding truth moves
// them along the skull.
TEST_F(TruthOfAnotherKind, BondedNodesHoldToTheSkull)
{
  const SolvedTruth  sliding = SolveTruth([](auto &) {});
  const SolvedTruth  bonded = SolveTruth([](auto & s) { s.bondedDepth = 70.0; });
  const bmr::Model & model = bonded.truth.model.model;
  const auto &       held = model.NodeSet("bonded to the skull");
  const auto &       contact = model.NodeSet("contact");
  ASSERT_GT(held.size(), 10u);
  EXPECT_EQ(std::count_if(model.fixedConstraints.begin(), model.fixedConstraints.end(),
                          [](const bmr::FixedConstraint & fixed) { return fixed.nodeSet == "bonded to the skull"; }),
            1);
  double slid = 0.0;
  for (const bmr::Index node : held)
  {
    EXPECT_EQ(std::count(contact.begin(), contact.end(), node), 0) << "node " << node << " is bonded and in contact";
    EXPECT_EQ(bonded.solve.displacements[node].norm(), 0.0);
    slid = std::max(slid, sliding.solve.displacements[node].norm());
  }
  RecordProperty("slidingAtTheBondedNodes", std::to_string(slid));
  EXPECT_GT(slid, 0.05);
  EXPECT_CONTAINS(ErrorMessage([] { SolveTruth([](auto & s) { s.bondedDepth = 1000.0; }); }), "bonded depth");
}

// Grey and white matter on three tissue classes: the cells' moduli reach
// white matter's, none exceeds it, and the parenchyma spans the two.
TEST_F(TruthOfAnotherKind, GreyAndWhiteMatterCarryTheirModuli)
{
  const Colin27 &                  colin = Colin27::Get();
  bmr::SyntheticBrainShiftSettings settings;
  settings.grid.elementSize = 8.0;
  settings.greyMatterYoungsModulus = 1390.0;
  settings.whiteMatterYoungsModulus = 1895.0;
  const bmr::SyntheticBrainShift truth = bmr::MakeSyntheticBrainShiftModel(colin.image, colin.mask, settings);
  const bmr::Model &             model = truth.model.model;
  double                         stiffest = 0.0, softestParenchyma = 1e300;
  for (const bmr::Cell & cell : model.cells)
  {
    const double modulus = model.materials[cell.material].youngsModulus;
    stiffest = std::max(stiffest, modulus);
    if (modulus > 0.5 * settings.greyMatterYoungsModulus)
    {
      softestParenchyma = std::min(softestParenchyma, modulus);
    }
  }
  RecordProperty("stiffest", std::to_string(stiffest));
  RecordProperty("softestParenchyma", std::to_string(softestParenchyma));
  EXPECT_LE(stiffest, settings.whiteMatterYoungsModulus * (1.0 + 1e-12));
  EXPECT_GT(stiffest, 0.95 * settings.whiteMatterYoungsModulus);
  EXPECT_LT(softestParenchyma, 1.05 * settings.greyMatterYoungsModulus);
  settings.whiteMatterYoungsModulus = 0.0;
  EXPECT_CONTAINS(ErrorMessage([&] { bmr::MakeSyntheticBrainShiftModel(colin.image, colin.mask, settings); }),
                  "grey and white matter");
}

// Another law: a Mooney-Rivlin parenchyma (same small-strain moduli) moves
// the brain differently from the registration's neo-Hookean one under the
// same opening and gravity, and its cells carry the law; CSF keeps its own.
TEST_F(TruthOfAnotherKind, MooneyRivlinParenchymaFollowsItsOwnLaw)
{
  const SolvedTruth neoHookean = SolveTruth([](auto &) {});
  const SolvedTruth mooneyRivlin = SolveTruth([](auto & s) { s.mooneyRivlinShare = 0.5; });
  const bmr::Model & model = mooneyRivlin.truth.model.model;
  std::size_t        lawCells = 0;
  for (const bmr::Cell & cell : model.cells)
  {
    const bmr::Material & material = model.materials[cell.material];
    lawCells += material.law == bmr::MaterialLaw::MooneyRivlin ? 1 : 0;
    if (material.name == bmr::CsfMaterial().name) // pure CSF
    {
      EXPECT_EQ(material.law, bmr::MaterialLaw::NeoHookean);
    }
  }
  RecordProperty("mooneyRivlinCells", std::to_string(lawCells));
  EXPECT_GT(lawCells, model.cells.size() / 2);
  const double lawEffect = LargestDifference(mooneyRivlin, neoHookean);
  RecordProperty("lawEffect", std::to_string(lawEffect));
  EXPECT_GT(lawEffect, 0.02);
  EXPECT_CONTAINS(ErrorMessage([] { SolveTruth([](auto & s) { s.mooneyRivlinShare = 1.5; }); }), "Mooney-Rivlin share");
}

} // namespace

namespace
{

using EnsembleFilterType = itk::BiomechanicalUncertaintyFilter<>;
using BlockPointSetType = EnsembleFilterType::DisplacementPointSetType;

/** A 10 x 8 x 6 mm block of 5 x 4 x 3 hexahedra (3 kPa, nu 0.45) held at one face. */
bmr::Model
HeldBlock(const std::string & heldFace)
{
  bmr::Model model = bmr::MakeBlockMesh(bmr::Vector3(10.0, 8.0, 6.0), { 5, 4, 3 }, bmr::GridCells::Hexahedra,
                                        bmr::test::MakeMaterial(3000.0, 0.45));
  model.fixedConstraints.push_back({ heldFace, { true, true, true } });
  return model;
}

/** The top face of `model` moved by `displacement`, as a point set of its nodes. */
BlockPointSetType::Pointer
TopMovedBy(const bmr::Model & model, const bmr::Vector3 & displacement)
{
  std::vector<bmr::Vector3> points;
  for (const bmr::Index node : model.NodeSet("zmax"))
  {
    points.push_back(model.nodes[static_cast<std::size_t>(node)]);
  }
  return itk::MakeDisplacementPointSet<BlockPointSetType>(points,
                                                          std::vector<bmr::Vector3>(points.size(), displacement));
}

bmr::SolverSettings
TightSolve()
{
  bmr::SolverSettings solver;
  solver.tolerance = 1e-7;
  return solver;
}

/** The description of the itk::ExceptionObject that updating `filter` throws, or a note that it threw none. */
std::string
UpdateFailure(EnsembleFilterType * filter)
{
  try
  {
    filter->Update();
  }
  catch (const itk::ExceptionObject & error)
  {
    return error.GetDescription();
  }
  return "(no itk::ExceptionObject thrown)";
}

std::vector<double>
NodalUncertainty(EnsembleFilterType * filter)
{
  return filter->GetUncertaintyOutput()->GetPointData()->CastToSTLConstContainer();
}

std::vector<bmr::Vector3>
Displacements(const BlockPointSetType * points)
{
  std::vector<bmr::Vector3> values;
  for (const auto & value : points->GetPointData()->CastToSTLConstContainer())
  {
    values.emplace_back(value[0], value[1], value[2]);
  }
  return values;
}

/** The mean of `values` and the 95th percentile of their distances from it. */
std::pair<double, double>
MeanAndSpread(const std::vector<double> & values)
{
  double mean = 0.0;
  for (const double value : values)
  {
    mean += value / static_cast<double>(values.size());
  }
  std::vector<double> distances;
  for (const double value : values)
  {
    distances.push_back(std::abs(value - mean));
  }
  return { mean, bmr::Percentile(distances, 0.95) };
}

/** The deformation filter's solution of `model` under `load` (may be null) and `gravity`. */
std::vector<bmr::Vector3>
NominalSolve(const bmr::Model & model, const BlockPointSetType * load, const bmr::Vector3 & gravity)
{
  auto deformation = itk::BiomechanicalDeformationFilter<>::New();
  deformation->SetModel(model);
  if (load != nullptr)
  {
    deformation->SetPrescribedDisplacements(load);
  }
  deformation->SetGravity(itk::BiomechanicalDeformationFilter<>::VectorType(gravity.data()));
  deformation->SetSolverSettings(TightSolve());
  deformation->Update();
  EXPECT_TRUE(deformation->GetConverged());
  return Displacements(deformation->GetOutput());
}

} // namespace

// Under prescribed displacements alone the equilibrium does not depend on the
// scale of the stiffness: four members with moduli drawn a factor of two
// apart give no spread, their mean is the nominal solve, and the ensemble
// repeats bit for bit on 1 and 2 threads.
TEST(BiomechanicalUncertaintyFilter, ModuliScaledTogetherUnderPrescribedDisplacementsGiveNone)
{
  const bmr::Model model = HeldBlock("zmin");
  const auto       load = TopMovedBy(model, bmr::Vector3(0.2, 0.0, -0.5));
  auto             filter = EnsembleFilterType::New();
  filter->SetModel(model);
  filter->SetPrescribedDisplacements(load);
  bmr::EnsembleSettings settings = NoDraws(4);
  settings.youngsModulusSpread = 0.7;
  filter->SetEnsembleSettings(settings);
  filter->SetSolverSettings(TightSolve());
  filter->SetNumberOfWorkUnits(2);
  filter->Update();
  ASSERT_EQ(filter->GetNumberOfUsedMembers(), 4u);
  double smallest = 1e9, largest = 0.0;
  for (const bmr::EnsembleMember & member : filter->GetMembers())
  {
    smallest = std::min(smallest, member.modulusFactor);
    largest = std::max(largest, member.modulusFactor);
  }
  EXPECT_GT(largest / smallest, 1.5) << "the draws must differ for the test to mean anything";
  const std::vector<double> uncertainty = NodalUncertainty(filter);
  EXPECT_LT(*std::max_element(uncertainty.begin(), uncertainty.end()), 1e-5);
  const std::vector<bmr::Vector3> nominal = NominalSolve(model, load, bmr::Vector3::Zero());
  const std::vector<bmr::Vector3> mean = Displacements(filter->GetOutput());
  ASSERT_EQ(mean.size(), nominal.size());
  for (std::size_t n = 0; n < mean.size(); ++n)
  {
    EXPECT_LT((mean[n] - nominal[n]).norm(), 1e-5) << "node " << n;
  }
  EXPECT_TRUE(filter->GetUncertaintyImage()->GetBufferedRegion().GetNumberOfPixels() == 0) << "no mask, no map";

  filter->SetNumberOfWorkUnits(1);
  filter->Update();
  EXPECT_TRUE(NodalUncertainty(filter) == uncertainty);
}

// A block hanging from its top face under gravity, at 1/100 of its height's
// strain, sags in proportion to gravity's size: with the size drawn in [0.5,
// 1.5] of 1 g each member is its factor times the nominal sag, so the map at
// a node is the 95th percentile of |f_i - mean f| times the nominal sag there
// (to the small strain's nonlinearity, 2 %): zero at the held face, largest
// at the free bottom. The map on a mask's grid follows the nodes and is 0
// outside the mask.
TEST(BiomechanicalUncertaintyFilter, AGravityRangeScalesAHangingBlocksSagByItsFactors)
{
  const bmr::Model   model = HeldBlock("zmax");
  const bmr::Vector3 gravity(0.0, 0.0, -9810.0);
  auto               filter = EnsembleFilterType::New();
  filter->SetModel(model);
  EnsembleFilterType::VectorType nominalGravity(gravity.data());
  filter->SetGravity(nominalGravity);
  bmr::EnsembleSettings settings = NoDraws(8);
  settings.gravityLow = 0.5;
  settings.gravityHigh = 1.5;
  settings.seed = 7;
  filter->SetEnsembleSettings(settings);
  filter->SetSolverSettings(TightSolve());

  // The mask: the block's voxels (1 mm) in a grid with a 2 mm margin.
  auto mask = EnsembleFilterType::MaskImageType::New();
  mask->SetRegions(EnsembleFilterType::MaskImageType::SizeType{ { 15, 13, 11 } });
  const double origin[3] = { -2.0, -2.0, -2.0 };
  mask->SetOrigin(origin);
  mask->Allocate();
  mask->FillBuffer(0);
  itk::ImageRegionIteratorWithIndex<EnsembleFilterType::MaskImageType> voxel(mask, mask->GetBufferedRegion());
  for (; !voxel.IsAtEnd(); ++voxel)
  {
    EnsembleFilterType::MaskImageType::PointType x;
    mask->TransformIndexToPhysicalPoint(voxel.GetIndex(), x);
    voxel.Set(x[0] >= 0.0 && x[0] <= 10.0 && x[1] >= 0.0 && x[1] <= 8.0 && x[2] >= 0.0 && x[2] <= 6.0 ? 1 : 0);
  }
  filter->SetMaskImage(mask);
  filter->SetFitTolerance(1e-4); // the map's values are a few hundredths of a millimetre
  filter->Update();
  ASSERT_EQ(filter->GetNumberOfUsedMembers(), 8u);

  std::vector<double> factors;
  for (const bmr::EnsembleMember & member : filter->GetMembers())
  {
    factors.push_back(member.gravityFactor);
  }
  const double spreadOfFactors = MeanAndSpread(factors).second;
  EXPECT_GT(spreadOfFactors, 0.2) << "the draws must differ for the test to mean anything";

  const std::vector<bmr::Vector3> sag = NominalSolve(model, nullptr, gravity);
  const std::vector<double>       uncertainty = NodalUncertainty(filter);
  double                          largestSag = 0.0;
  for (const bmr::Vector3 & u : sag)
  {
    largestSag = std::max(largestSag, u.norm());
  }
  EXPECT_GT(largestSag, 0.02);
  EXPECT_LT(largestSag, 0.1) << "small strain, where the sag is linear in gravity";
  for (std::size_t n = 0; n < sag.size(); ++n)
  {
    EXPECT_NEAR(uncertainty[n], spreadOfFactors * sag[n].norm(), 0.02 * spreadOfFactors * largestSag) << "node " << n;
  }
  for (const bmr::Index node : model.NodeSet("zmax"))
  {
    EXPECT_EQ(uncertainty[static_cast<std::size_t>(node)], 0.0) << "a held node cannot move";
  }

  const auto * map = filter->GetUncertaintyImage();
  ASSERT_EQ(map->GetBufferedRegion(), mask->GetBufferedRegion());
  const double largestNodal = *std::max_element(uncertainty.begin(), uncertainty.end());
  double       largestMapped = 0.0;
  for (itk::ImageRegionConstIteratorWithIndex<EnsembleFilterType::UncertaintyImageType> it(map,
                                                                                           map->GetBufferedRegion());
       !it.IsAtEnd(); ++it)
  {
    if (mask->GetPixel(it.GetIndex()) == 0)
    {
      EXPECT_EQ(it.Get(), 0.0f);
    }
    largestMapped = std::max(largestMapped, static_cast<double>(it.Get()));
  }
  EXPECT_NEAR(largestMapped, largestNodal, 0.1 * largestNodal);
  // The bottom's centre sags most, the top's is held.
  EnsembleFilterType::UncertaintyImageType::PointType bottom, top;
  bottom[0] = top[0] = 5.0;
  bottom[1] = top[1] = 4.0;
  bottom[2] = 0.0;
  top[2] = 6.0;
  EnsembleFilterType::UncertaintyImageType::IndexType at;
  map->TransformPhysicalPointToIndex(bottom, at);
  EXPECT_GT(map->GetPixel(at), 0.8 * largestNodal);
  map->TransformPhysicalPointToIndex(top, at);
  EXPECT_LT(map->GetPixel(at), 0.1 * largestNodal);
}

// A member's own prescribed displacements replace the shared ones: members
// loaded by 0.5, 1, 1.5 and 2 times one small displacement of the top face
// average, in the small-strain limit, to 1.25 times its solve; the members
// without their own load take the shared one.
TEST(BiomechanicalUncertaintyFilter, MemberInputsReplaceTheSharedOnes)
{
  const bmr::Model   model = HeldBlock("zmin");
  const bmr::Vector3 top(0.01, 0.0, -0.04);
  auto               filter = EnsembleFilterType::New();
  filter->SetModel(model);
  filter->SetEnsembleSettings(NoDraws(5));
  filter->SetSolverSettings(TightSolve());
  filter->SetPrescribedDisplacements(TopMovedBy(model, top));
  const double scales[4] = { 0.5, 1.0, 1.5, 2.0 };
  for (unsigned int m = 0; m < 4; ++m)
  {
    filter->SetMemberPrescribedDisplacements(m, TopMovedBy(model, scales[m] * top));
  }
  filter->Update();
  ASSERT_EQ(filter->GetNumberOfUsedMembers(), 5u);
  const std::vector<bmr::Vector3> unit = NominalSolve(model, TopMovedBy(model, top), bmr::Vector3::Zero());
  const std::vector<bmr::Vector3> mean = Displacements(filter->GetOutput());
  const double                    expected = (0.5 + 1.0 + 1.5 + 2.0 + 1.0) / 5.0; // the fifth: the shared load
  for (std::size_t n = 0; n < unit.size(); ++n)
  {
    EXPECT_LT((mean[n] - expected * unit[n]).norm(), 0.01 * top.norm()) << "node " << n;
  }
}

// Two tissue classes in series, a bar of 3 mm of 1 kPa under 3 mm of 4 kPa
// (nu = 0: uniaxial stress is uniaxial strain, so the 1D answer is exact to
// the small strain's nonlinearity, 0.1 %), its top pressed 6 um on rollers:
// a member whose classes' moduli are scaled by f_soft and f_stiff moves the
// interface by U (h / f_soft E_soft) / (h / f_soft E_soft + h / f_stiff
// E_stiff), two springs in series. The map at the interface is the 95th
// percentile of those moves' distance from their mean, and a common factor
// alone would give none.
TEST(BiomechanicalUncertaintyFilter, TissueModuliOfABarInSeriesMoveItsInterfaceAsTwoSprings)
{
  const double   soft = 1000.0, stiff = 4000.0, height = 3.0, pressed = 0.006;
  bmr::Material  softMaterial = bmr::test::MakeMaterial(soft, 0.0, 1000.0, "soft");
  bmr::Material  stiffMaterial = bmr::test::MakeMaterial(stiff, 0.0, 1000.0, "stiff");
  bmr::Model     model = bmr::MakeBlockMesh(bmr::Vector3(4.0, 4.0, 2.0 * height), { 2, 2, 6 }, bmr::GridCells::Hexahedra,
                                            softMaterial);
  model.materials = { softMaterial, stiffMaterial };
  model.tissueMixture.classes = model.materials;
  for (bmr::Cell & cell : model.cells)
  {
    const bool upper = model.nodes[static_cast<std::size_t>(cell.nodes[6])].z() > height + 1e-9; // its top corner
    cell.material = upper ? 1 : 0;
    model.tissueMixture.shares.push_back(upper ? 0.0 : 1.0);
    model.tissueMixture.shares.push_back(upper ? 1.0 : 0.0);
  }
  model.fixedConstraints = { { "zmin", { false, false, true } }, { "xmin", { true, false, false } },
                             { "ymin", { false, true, false } } };
  bmr::PrescribedDisplacement top;
  top.nodes = model.NodeSet("zmax");
  top.displacements.assign(top.nodes.size(), bmr::Vector3(0.0, 0.0, -pressed));
  top.components = { false, false, true };
  model.prescribedDisplacements = { top };

  auto filter = EnsembleFilterType::New();
  filter->SetModel(model);
  bmr::EnsembleSettings settings = NoDraws(8);
  settings.tissueModulusSpread = 0.5;
  settings.seed = 3;
  filter->SetEnsembleSettings(settings);
  bmr::SolverSettings solver;
  solver.tolerance = 1e-9;
  filter->SetSolverSettings(solver);
  filter->Update();
  ASSERT_EQ(filter->GetNumberOfUsedMembers(), 8u);

  std::vector<double> moves;
  for (const bmr::EnsembleMember & member : filter->GetMembers())
  {
    ASSERT_EQ(member.tissueFactors.size(), 2u);
    const double softCompliance = height / (member.tissueFactors[0] * soft);
    const double stiffCompliance = height / (member.tissueFactors[1] * stiff);
    moves.push_back(-pressed * softCompliance / (softCompliance + stiffCompliance));
  }
  const auto [meanMove, spread] = MeanAndSpread(moves);
  EXPECT_GT(spread, 0.1 * pressed) << "the draws must move the interface for the test to mean anything";

  const std::vector<double>       uncertainty = NodalUncertainty(filter);
  const std::vector<bmr::Vector3> mean = Displacements(filter->GetOutput());
  int                             interfaceNodes = 0;
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    if (std::abs(model.nodes[n].z() - height) < 1e-9)
    {
      ++interfaceNodes;
      EXPECT_NEAR(uncertainty[n], spread, 0.02 * spread) << "node " << n;
      EXPECT_NEAR(mean[n].z(), meanMove, 0.002 * pressed) << "node " << n;
    }
  }
  EXPECT_EQ(interfaceNodes, 9);
}

// Bad settings and an ensemble with too few converged members throw
// exceptions that name them; each member's outcome is reported.
TEST(BiomechanicalUncertaintyFilter, BadSettingsAndFailedMembersAreNamed)
{
  const bmr::Model model = HeldBlock("zmin");
  auto             filter = EnsembleFilterType::New();
  filter->SetModel(model);
  filter->SetPrescribedDisplacements(TopMovedBy(model, bmr::Vector3(0.0, 0.0, -0.5)));
  filter->SetEnsembleSettings(NoDraws(1));
  EXPECT_CONTAINS(UpdateFailure(filter), "at least 2");
  bmr::EnsembleSettings settings = NoDraws(3);
  settings.youngsModulusSpread = -0.2;
  filter->SetEnsembleSettings(settings);
  EXPECT_CONTAINS(UpdateFailure(filter), "Young's modulus spread");
  settings.youngsModulusSpread = 0.0;
  settings.skullGapSpread = 0.5;
  filter->SetEnsembleSettings(settings);
  EXPECT_CONTAINS(UpdateFailure(filter), "nominal gap");
  settings.skullGapSpread = 0.0;
  filter->SetEnsembleSettings(settings);
  bmr::SolverSettings hurried = TightSolve();
  hurried.maxSteps = 3;
  filter->SetSolverSettings(hurried);
  EXPECT_CONTAINS(UpdateFailure(filter), "0 of 3 members converged");
  ASSERT_EQ(filter->GetMembers().size(), 3u);
  for (const bmr::EnsembleMember & member : filter->GetMembers())
  {
    EXPECT_FALSE(member.converged);
    EXPECT_EQ(member.steps, 3);
  }
}
