// The uncertainty map where its answer is known: a perturbation that cannot
// move the solution gives none, one that must shows up where it should.
// Colin27 with 10 mm hexahedra and a 5 mm sag of a parietal opening.
// The deformation filter first: ITK's bundled Eigen before the core's (its header says why).
#include "itkBiomechanicalDeformationFilter.h"

#include "bmrBrainShiftUncertainty.h"
#include "bmrColin27.h"
#include "bmrSagScenes.h"
#include "bmrTemporaryFolderTest.h"

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

/** Every input off. */
bmr::UncertaintySettings
NothingDrawn(int members)
{
  bmr::UncertaintySettings settings;
  settings.members = members;
  settings.noiseSigma = 0.0;
  settings.youngsModulusSpread = 0.0;
  settings.poissonLow = settings.poissonHigh = 0.0;
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
  gap.skullGapSpread = 1.0;
  const auto skull = scene.Ensemble(gap);
  ASSERT_EQ(skull.usedMembers, 4);
  const auto [narrowest, widest] = DrawnRange(skull, &bmr::UncertaintyMember::skullOffset);
  EXPECT_LT(narrowest, 0.0);
  EXPECT_GT(widest, 0.0);
  RecordProperty("skullGapInteriorMax", std::to_string(skull.interiorMax));
  EXPECT_GT(skull.interiorMax, 0.1);
  EXPECT_LT(skull.exposedMax, 1e-9);

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

} // namespace
