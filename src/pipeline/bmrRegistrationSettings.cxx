// The registration's settings as one table (bmrBrainShiftRegistration.h).
#include "bmrBrainShiftRegistration.h"

#include <limits>

namespace bmr
{

namespace
{

using Field = RegistrationSettingField;
using Kind = SettingFieldBase::Kind;
using Settings = BrainShiftRegistrationSettings;

constexpr double kInfinity = std::numeric_limits<double>::infinity();

Field
Row(const char * group, const char * name, Kind kind, const char * unit, double lowest, bool lowestOpen,
    double highest, bool highestOpen, const char * meaning, std::function<double(const Settings &)> get,
    std::function<void(Settings &, double)> set)
{
  return MakeSettingField<Settings>(kind, group, name, unit, lowest, lowestOpen, highest, highestOpen, meaning,
                                    std::move(get), std::move(set));
}

Field
Flag(const char * group, const char * name, const char * meaning, std::function<double(const Settings &)> get,
     std::function<void(Settings &, double)> set)
{
  return Row(group, name, Kind::Flag, "", 0.0, false, 1.0, false, meaning, std::move(get), std::move(set));
}

Field
Text(const char * group, const char * name, const char * meaning, std::function<std::string(const Settings &)> get,
     std::function<void(Settings &, const std::string &)> set)
{
  Field field;
  field.group = group;
  field.name = name;
  field.kind = Kind::Text;
  field.meaning = meaning;
  field.getText = std::move(get);
  field.setText = std::move(set);
  return field;
}

/** The class materials for the number of classes and this CSF (the other classes parenchyma). */
void
SetClassMaterials(Settings & s, const Material & csf)
{
  s.model.materials.classMaterials = DefaultClassMaterials(s.model.classifier.classes, csf);
}

/** A row of one value of the CSF class's material (CsfClassMaterial). */
Field
CsfRow(const char * name, const char * unit, double lowest, bool lowestOpen, double highest, bool highestOpen,
       const char * meaning, double Material::*value)
{
  return Row("model", name, Kind::Number, unit, lowest, lowestOpen, highest, highestOpen, meaning,
             [value](const Settings & s) { return CsfClassMaterial(s.model.materials).*value; },
             [value](Settings & s, double v) {
               Material csf = CsfClassMaterial(s.model.materials);
               csf.*value = v;
               SetClassMaterials(s, csf);
             });
}

std::vector<Field>
MakeFields()
{
  std::vector<Field> fields;
  // The model.
  fields.push_back(Row("model", "classes", Kind::Integer, "", 2, false, 16, false,
                       "tissue classes of fuzzy c-means (2: CSF and parenchyma; 3: CSF, grey, white)",
                       [](const Settings & s) { return s.model.classifier.classes; },
                       [](Settings & s, double v) {
                         const Material csf = CsfClassMaterial(s.model.materials);
                         s.model.classifier.classes = static_cast<int>(v);
                         SetClassMaterials(s, csf);
                       }));
  fields.push_back(Row("model", "fuzziness", Kind::Number, "", 1.0, true, kInfinity, false,
                       "fuzzy c-means exponent m", [](const Settings & s) { return s.model.classifier.fuzziness; },
                       [](Settings & s, double v) { s.model.classifier.fuzziness = v; }));
  fields.push_back(Row("model", "classifier_tolerance", Kind::Number, "", 0.0, true, kInfinity, false,
                       "fuzzy c-means stops when no centroid moves by more than this, relative to the intensity range",
                       [](const Settings & s) { return s.model.classifier.tolerance; },
                       [](Settings & s, double v) { s.model.classifier.tolerance = v; }));
  fields.push_back(Row("model", "classifier_max_iterations", Kind::Integer, "", 1, false,
                       std::numeric_limits<int>::max(), false, "fuzzy c-means iteration limit",
                       [](const Settings & s) { return s.model.classifier.maxIterations; },
                       [](Settings & s, double v) { s.model.classifier.maxIterations = static_cast<int>(v); }));
  fields.push_back(Text("model", "atlas", "atlas T1 image of the skull stripping (when no brain mask is given)",
                        [](const Settings & s) { return s.model.atlas.image; },
                        [](Settings & s, const std::string & v) { s.model.atlas.image = v; }));
  fields.push_back(Text("model", "atlas_mask", "the atlas's brain mask (voxels > 0 are brain)",
                        [](const Settings & s) { return s.model.atlas.mask; },
                        [](Settings & s, const std::string & v) { s.model.atlas.mask = v; }));
  fields.push_back(Flag("model", "affine_only", "skull stripping without its B-spline stage",
                        [](const Settings & s) { return s.model.atlas.bsplineStage ? 0.0 : 1.0; },
                        [](Settings & s, double v) { s.model.atlas.bsplineStage = v == 0.0; }));
  Field grid = Row("model", "grid", Kind::Choice, "", 0, false, 0, false,
                   "the discretization: hexahedra, CGAL tetrahedra (ANP), mixed, or the meshless point cloud (MTLED)",
                   [](const Settings & s) { return static_cast<double>(s.model.grid.kind); },
                   [](Settings & s, double v) { s.model.grid.kind = static_cast<ImageGridKind>(static_cast<int>(v)); });
  grid.choices = { "hexahedra", "tetrahedra", "mixed", "meshless" };
  fields.push_back(grid);
  fields.push_back(Row("model", "element_size", Kind::Number, "mm", 0.0, true, kInfinity, false,
                       "element edge, or the meshless nodal spacing",
                       [](const Settings & s) { return s.model.grid.elementSize; },
                       [](Settings & s, double v) { s.model.grid.elementSize = v; }));
  Field contrast = Row("model", "contrast", Kind::Choice, "", 0, false, 0, false,
                       "where the CSF lies on the image's intensities: t1 darkest, t2 brightest, auto from the "
                       "classes' volumes and spacing (an image it cannot tell is an error); the report names the "
                       "CSF class",
                       [](const Settings & s) { return static_cast<double>(s.model.contrast); },
                       [](Settings & s, double v) { s.model.contrast = static_cast<TissueContrast>(static_cast<int>(v)); });
  contrast.choices = { "auto", "t1", "t2" };
  fields.push_back(contrast);
  fields.push_back(CsfRow("csf_modulus", "Pa", 0.0, true, kInfinity, false, "Young's modulus of the CSF class",
                         &Material::youngsModulus));
  fields.push_back(CsfRow("csf_poisson_ratio", "", 0.0, false, 0.5, true,
                          "Poisson's ratio of the CSF class; 0.49: fluid-like, keeps CSF cells from being crushed by "
                          "shifts of 20 mm and more",
                          &Material::poissonRatio));
  fields.push_back(CsfRow("csf_density", "kg/m^3", 0.0, false, kInfinity, false,
                          "density of the CSF class under gravity; drained CSF weighs almost nothing (1), and 10 Pa "
                          "CSF cells cannot carry a fluid's weight (1000): they are crushed and the brain sinks through them",
                          &Material::density));
  fields.push_back(Row("model", "skull_gap", Kind::Number, "mm", 0.0, false, kInfinity, false,
                       "gap between the brain surface and the rigid skull made from it",
                       [](const Settings & s) { return s.model.skullGap; },
                       [](Settings & s, double v) { s.model.skullGap = v; }));
  fields.push_back(Row("model", "skull_closing", Kind::Number, "mm", 0.0, false, kInfinity, false,
                       "radius of a closing of the brain before the skull is made: the skull stays out of fissures "
                       "narrower than twice (radius + gap), where it would be a thin rigid blade, and its creases are "
                       "rounded to the radius, where contact nodes would cycle in and out; 0: follows every fold",
                       [](const Settings & s) { return s.model.skullClosing; },
                       [](Settings & s, double v) { s.model.skullClosing = v; }));
  fields.push_back(Row("model", "skull_base_height", Kind::Number, "mm", 0.0, false, kInfinity, false,
                       "fixed band above the most inferior surface node: skull base and brain stem",
                       [](const Settings & s) { return s.model.skullBase.height; },
                       [](Settings & s, double v) { s.model.skullBase.height = v; }));
  fields.push_back(Flag("model", "contact", "brain-skull contact of the surface nodes that are neither fixed nor exposed",
                        [](const Settings & s) { return s.model.contact ? 1.0 : 0.0; },
                        [](Settings & s, double v) { s.model.contact = v != 0.0; }));
  fields.push_back(Row("model", "threads", Kind::Integer, "", 0, false, 4096, false,
                       "worker threads, 0 = all; results do not depend on it",
                       [](const Settings & s) { return s.model.threads; },
                       [](Settings & s, double v) {
                         s.model.threads = static_cast<int>(v);
                         s.solver.threads = static_cast<int>(v);
                       }));
  // The solve.
  fields.push_back(Row("solve", "solver_tolerance", Kind::Number, "mm", 0.0, true, kInfinity, false,
                       "dynamic relaxation stops when the estimated distance to the solution is below it",
                       [](const Settings & s) { return s.solver.tolerance; },
                       [](Settings & s, double v) { s.solver.tolerance = v; }));
  fields.push_back(Row("solve", "max_steps", Kind::Integer, "", 1, false, std::numeric_limits<int>::max(), false,
                       "dynamic relaxation step limit; reaching it is reported as not converged",
                       [](const Settings & s) { return s.solver.maxSteps; },
                       [](Settings & s, double v) { s.solver.maxSteps = static_cast<int>(v); }));
  fields.push_back(Row("solve", "gravity_fit_candidates", Kind::Integer, "", 0, false, 100, false,
                       "with gravity and an intraoperative image: sizes of gravity from 0 to the given one solved "
                       "(3 or more), the one whose registered image matches the intraoperative image best (mutual "
                       "information) kept; 0: gravity as given",
                       [](const Settings & s) { return s.gravityFitCandidates; },
                       [](Settings & s, double v) { s.gravityFitCandidates = static_cast<int>(v); }));
  // The transform fit.
  fields.push_back(Row("fit", "fit_tolerance", Kind::Number, "mm", 0.0, true, kInfinity, false,
                       "largest residual of the B-spline transform at the nodes",
                       [](const Settings & s) { return s.fitTolerance; },
                       [](Settings & s, double v) { s.fitTolerance = v; }));
  fields.push_back(Row("fit", "min_control_point_spacing", Kind::Number, "mm", 0.0, true, kInfinity, false,
                       "finest control-point spacing of the B-spline transform",
                       [](const Settings & s) { return s.minimumControlPointSpacing; },
                       [](Settings & s, double v) { s.minimumControlPointSpacing = v; }));
  // The evaluation.
  fields.push_back(Row("evaluation", "evaluation_slice_axis", Kind::Integer, "", -1, false, 2, false,
                       "edge-based evaluation in slices normal to this image axis, or -1: the whole volume",
                       [](const Settings & s) { return s.evaluationSliceAxis; },
                       [](Settings & s, double v) { s.evaluationSliceAxis = static_cast<int>(v); }));
  fields.push_back(Row("evaluation", "evaluation_distance_threshold", Kind::Number, "mm", 0.0, true, kInfinity, false,
                       "an edge within this distance of the other image's edges counts as registered",
                       [](const Settings & s) { return s.evaluationDistanceThreshold; },
                       [](Settings & s, double v) { s.evaluationDistanceThreshold = v; }));
  return fields;
}

} // namespace

const std::vector<RegistrationSettingField> &
RegistrationSettingFields()
{
  static const std::vector<RegistrationSettingField> fields = MakeFields();
  return fields;
}

std::string
RegistrationSettingsMarkdown()
{
  return SettingsMarkdown(RegistrationSettingFields(), BrainShiftRegistrationSettings{});
}

} // namespace bmr
