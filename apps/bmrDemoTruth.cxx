// The demo's ground truth as files (bmrDemoTruth.h).
#include "bmrDemoTruth.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalTransformIO.h"

#include "bmrCommandSupport.h"
#include "bmrMeshIO.h"
#include "bmrSurfaceLoads.h"

#include <fstream>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bmr
{
namespace app
{
namespace
{

// Every demo writes these (the study and users read them).
const char * const kIntraoperativeImage = "intraoperative.nii.gz";
const char * const kIntraoperativeBrainMask = "intraoperative-brain-mask.nii.gz";
const char * const kExposedSurface = "exposed-surface.vtp";
const char * const kTrackedPoints = "tracked-points.csv";
const char * const kTruthTransform = "ground-truth-transform.h5";
// A reusable truth (--truth-only) also these.
const char * const kForwardTransform = "ground-truth-forward-transform.h5";
const char * const kBrainOnPreoperativeGrid = "intraoperative-brain-on-preoperative-grid.nii.gz";
const char * const kTumourMask = "tumour-mask.nii.gz";
const char * const kResectionMask = "resection-mask.nii.gz";
const char * const kSecondTruthTransform = "ground-truth-check-transform.h5"; // --truth-check
const char * const kReport = "demo-report.json";

/** A file of the truth folder; a missing one is an Error that says how to make it. */
std::string
TruthFile(const fs::path & folder, const char * name)
{
  const fs::path path = folder / name;
  std::error_code error;
  if (!fs::is_regular_file(path, error))
  {
    throw Error("--truth-from " + folder.string() + ": " + path.string() +
                " is missing; make the folder with `biomech demo --truth-only -o " + folder.string() + "`");
  }
  return path.string();
}

RegistrationTransform::Pointer
ReadTruthTransform(const fs::path & folder, const char * name)
{
  const std::string path = TruthFile(folder, name);
  try
  {
    const auto transform = itk::ReadBiomechanicalTransform(path);
    RegistrationTransform::Pointer bspline = dynamic_cast<RegistrationTransform *>(transform.GetPointer());
    if (bspline.IsNull())
    {
      throw Error("--truth-from: " + path + " holds a " + transform->GetNameOfClass() +
                  ", not the ground truth's B-spline transform; rerun `biomech demo --truth-only`");
    }
    return bspline;
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error("--truth-from: " + std::string(exception.GetDescription()));
  }
}

Vector3
ReadVector(const json & block, const char * key, const fs::path & report)
{
  if (!block.contains(key) || !block[key].is_array() || block[key].size() != 3)
  {
    throw Error("--truth-from: " + report.string() + " has no ground_truth." + key +
                " (three numbers); it was not written by `biomech demo --truth-only` of this version: rerun it");
  }
  return Vector3(block[key][0].get<double>(), block[key][1].get<double>(), block[key][2].get<double>());
}

} // namespace

void
WriteTruthFiles(const SyntheticBrainShift & truth, const fs::path & folder, bool reusable)
{
  WriteImageAtomically(truth.intraoperativeImage.GetPointer(), folder / kIntraoperativeImage);
  WriteImageAtomically(truth.intraoperativeBrainMask.GetPointer(), folder / kIntraoperativeBrainMask);
  WriteSurface((folder / kExposedSurface).string(), truth.exposedSurface);
  WriteSparseDisplacements((folder / kTrackedPoints).string(), truth.trackedPoints);
  itk::WriteBiomechanicalTransform(truth.truthTransform, (folder / kTruthTransform).string());
  if (!reusable)
  {
    return;
  }
  itk::WriteBiomechanicalTransform(truth.forwardTransform, (folder / kForwardTransform).string());
  WriteImageAtomically(truth.intraoperativeBrainOnPreoperativeGrid.GetPointer(), folder / kBrainOnPreoperativeGrid);
  std::error_code ignored;
  fs::remove(folder / kTumourMask, ignored);
  if (truth.tumourMask.IsNotNull())
  {
    WriteImageAtomically(truth.tumourMask.GetPointer(), folder / kTumourMask);
  }
  fs::remove(folder / kResectionMask, ignored);
  if (truth.resectionMask.IsNotNull())
  {
    WriteImageAtomically(truth.resectionMask.GetPointer(), folder / kResectionMask);
  }
}

TruthFiles
ReadTruthFiles(const fs::path & folder)
{
  const fs::path reportPath = TruthFile(folder, kReport);
  TruthFiles     files;
  json &         report = files.report;
  try
  {
    std::ifstream in(reportPath);
    report = json::parse(in);
  }
  catch (const json::exception & exception)
  {
    throw Error("--truth-from: " + reportPath.string() + " is not a readable report (" + exception.what() +
                "); rerun `biomech demo --truth-only`");
  }
  if (!report.contains("ground_truth") || !report["ground_truth"].value("reusable", false))
  {
    throw Error("--truth-from: " + reportPath.string() +
                " is not the report of a reusable ground truth; make it with `biomech demo --truth-only`");
  }
  const json &          block = report["ground_truth"];
  SyntheticBrainShift & truth = files.truth;
  truth.intraoperativeImage = ReadImage<RegistrationImage>(TruthFile(folder, kIntraoperativeImage), "intraoperative image");
  truth.intraoperativeBrainMask = ReadMaskImage(TruthFile(folder, kIntraoperativeBrainMask), "intraoperative brain mask");
  truth.intraoperativeBrainOnPreoperativeGrid =
    ReadMaskImage(TruthFile(folder, kBrainOnPreoperativeGrid), "intraoperative brain on the preoperative grid");
  truth.exposedSurface = ReadSurface(TruthFile(folder, kExposedSurface));
  truth.trackedPoints = ReadSparseDisplacements(TruthFile(folder, kTrackedPoints));
  truth.truthTransform = ReadTruthTransform(folder, kTruthTransform);
  truth.forwardTransform = ReadTruthTransform(folder, kForwardTransform);
  std::error_code ignored;
  if (fs::is_regular_file(folder / kTumourMask, ignored))
  {
    truth.tumourMask = ReadMaskImage((folder / kTumourMask).string(), "tumour mask");
  }
  truth.gravity = ReadVector(block, "gravity_mm_s2", reportPath);
  truth.down = ReadVector(block, "down", reportPath);
  truth.shift = block.value("shift_mm", 0.0);
  truth.truthFitMaxResidual = block.value("fit_max_residual_mm", 0.0);
  truth.resectionCavityRadius = block.value("resection_cavity_radius_mm", 0.0);
  if (truth.resectionCavityRadius > 0.0)
  {
    truth.resectionMask = ReadMaskImage(TruthFile(folder, kResectionMask), "resection mask");
  }
  SyntheticBrainShiftSettings & scene = files.scene;
  scene.craniotomyCentre = ReadVector(block, "craniotomy_centre_mm", reportPath);
  scene.craniotomyRadius = block.value("craniotomy_radius_mm", scene.craniotomyRadius);
  scene.tumourStiffness = block.value("tumour_stiffness", scene.tumourStiffness);
  scene.csfPoissonRatio = block.value("csf_poisson_ratio", scene.csfPoissonRatio);
  files.preoperativeImage = report.value("preoperative_image", std::string());
  files.brainMask = report.value("brain_mask", std::string());
  if (files.preoperativeImage.empty() || files.brainMask.empty())
  {
    throw Error("--truth-from: " + reportPath.string() +
                " does not name its preoperative image and brain mask; rerun `biomech demo --truth-only`");
  }
  if (report.contains("ground_truth_check"))
  {
    files.secondTruth = ReadTruthTransform(folder, kSecondTruthTransform);
  }
  return files;
}

} // namespace app
} // namespace bmr
