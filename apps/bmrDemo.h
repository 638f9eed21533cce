// `biomech demo`'s parts shared by its two files: the options, a method's
// row, how every method is scored against the ground truth, and the methods
// (bmrDemoMethods.cxx); the command, its ground truth and its report are
// bmrDemoCommand.cxx's.
#ifndef bmrDemo_h
#define bmrDemo_h

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkTransform.h"

#include "bmrRegistrationMetrics.h"
#include "bmrSyntheticBrainShift.h"
#include "bmrUncertaintyOptions.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace bmr
{
namespace app
{
namespace demo
{

using json = nlohmann::json;

// The largest brain shift the module is built for (mm): the cut-off of matches along gravity.
constexpr double kLargestExpectedShift = 25.0;
// The error near a tumour or a resection cavity is measured within this distance (mm) of it.
constexpr double kNearTumourDistance = 10.0;

struct DemoOptions
{
  std::string                 image = "/usr/share/mricron/templates/ch2.nii.gz";
  std::string                 mask = "/usr/share/mricron/templates/ch2bet.nii.gz";
  std::string                 outputDirectory = "out/demo";
  SyntheticBrainShiftSettings truth;
  std::vector<double>         craniotomyCentre;
  std::vector<double>         tumourCentre;
  std::vector<double>         greyWhiteModuli; // the truth's grey and white matter (Pa); empty: one parenchyma
  std::string                 truthGrid = "hexahedra";
  std::vector<std::string>    variants{ "hexahedra:5" };
  std::string                 truthCheck; // KIND:SIZE of a second ground truth; empty: none
  std::string                 load = "points";
  std::string                 surfaceMatch = "closest";
  double                      registrationGravity = 0.0; // g
  int                         gravityFitCandidates = 0;
  UncertaintyOptions          uncertainty; // an ensemble after each biomechanical registration, calibrated on the truth
  bool                        noBaseline = false;
  bool                        noRegistrationResection = false; // the registration is not told the planned resection
  bool                        truthOnly = false; // solve and write the truth, register nothing
  std::string                 truthFrom;         // a --truth-only folder to read the truth from
  bool                        elastix = false;
  std::vector<std::string>    elastixParameters;
  std::string                 peerField;  // a peer registration run elsewhere: its displacement field,
  std::string                 peerWarped; // its warped image,
  std::string                 peerName;   // the method's name in the report,
  double                      peerSeconds = 0.0; // its run time
  std::string                 peerDetails; // and a JSON object of what it was (tool, version, parameters)
  std::string                 contrast = "preoperative";
  std::string                 noiseModel = "gaussian";
  std::vector<double>         intraoperativeSpacing;
  std::vector<unsigned int>   baselineShrinkFactors{ 4, 2, 1 };
  unsigned int                baselineIterations = 0;
  int                         overlays = 3;
  bool                        quiet = false;
};

/** One registration method's numbers. */
struct MethodResult
{
  std::string       name;
  double            seconds = 0.0;
  json              stages = json::object();
  DisplacementError error;
  std::optional<DisplacementError> nearTumourError; // within kNearTumourDistance of the tumour or the cavity
  std::optional<double>            tumourSurfaceDistance; // 95th percentile, mm (StructureSurfaceDistance)
  std::optional<double>            ventricleSurfaceDistance; // 95th percentile, mm; none: not measured
  EdgeEvaluation    edges;
  json              details = json::object();
};

/** A displacement error's statistics (mm) as the report writes them. */
json
DisplacementErrorJson(const DisplacementError & error);

/** A method's row of demo-report.json. */
json
MethodJson(const MethodResult & method);

/** The table the demo prints. */
void
PrintTable(const std::vector<MethodResult> & methods);

std::string
FormatNumber(double value);

/** "hexahedra:5" -> grid settings; `option` names the option in errors. */
ImageGridSettings
ParseVariant(const std::string & variant, const std::string & option = "--variant");

/** Every method's scores against the ground truth: the displacement error over the intraoperative brain, near the
 *  tumour (or the resection cavity's walls) and the structures' surfaces, and against the second truth when there
 *  is one. The ventricles are found in the preoperative T1 once (their mask written); an image where they are not
 *  found (another contrast, part of a brain) is measured without them, and the report says why. */
class Scoring
{
public:
  Scoring(const DemoOptions & options, const RegistrationImage * preoperative, const RegistrationLabelImage * brainMask,
          const SyntheticBrainShift & truth, RegistrationTransform::Pointer secondTruth, const std::filesystem::path & output);

  /** What the methods' ventricle_surface_distance_p95_mm measures (or why it is missing). */
  const json & VentricleReport() const { return m_VentricleReport; }
  /** The region near the tumour or the cavity; null without either. */
  const RegistrationLabelImage * NearTumour() const { return m_NearTumour; }

  /** A method's error against the ground truth (also near the tumour), and against the second truth when there is one. */
  void
  Score(const itk::Transform<double, 3, 3> * transform, MethodResult & method) const;

private:
  const SyntheticBrainShift &             m_Truth;
  RegistrationTransform::Pointer          m_SecondTruth;
  RegistrationLabelImage::Pointer         m_NearTumour;
  std::optional<StructureSurfaceDistance> m_TumourSurface, m_VentricleSurface;
  json                                    m_VentricleReport;
};

/** One biomechanical registration of the truth's intraoperative data on `grid` (and, with --uncertainty, its
 *  ensemble and the map's calibration against the truth); its files written into `output`. */
MethodResult
RegisterVariant(const ImageGridSettings & grid, const DemoOptions & options, const UncertaintySettings & uncertainty,
                const RegistrationImage * preoperative, const RegistrationLabelImage * brainMask,
                const SyntheticBrainShift & truth, const SparseDisplacements * electrodeLoads, const Scoring & scoring,
                const std::filesystem::path & output, const StageCallback & stages);

/** The module's ITK B-spline intensity registration of the same pair (the baseline). */
MethodResult
RegisterBaseline(const DemoOptions & options, const RegistrationImage * preoperative, const SyntheticBrainShift & truth,
                 const Scoring & scoring, const std::filesystem::path & output);

/** The report's ground_truth entry of a truth solved here. */
json
GroundTruthJson(const DemoOptions & options, const SyntheticBrainShift & truth);

} // namespace demo
} // namespace app
} // namespace bmr

#endif
