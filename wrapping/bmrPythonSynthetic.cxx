// The synthetic scenes of the Python binding: the demo's brain shift with a
// known answer, its displacement error, and the electrode CT and its
// localisation (bmrSyntheticBrainShift.h, bmrElectrodes.h).

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "bmrSyntheticElectrodeCt.h"

#include "bmrPythonItk.h"

namespace bmr::python
{
namespace
{

// ---------------------------------------------------------------------------
// The synthetic brain shift of the demo (a known answer for notebooks and studies).
// ---------------------------------------------------------------------------

// The synthetic brain shift (the demo's ground truth).
void
BindSyntheticScene(py::module_ & module)
{
  py::class_<SyntheticBrainShift>(module, "SyntheticBrainShift",
                                  "A ground-truth brain shift (the README demo's): a finer model under a prescribed "
                                  "sag of the exposed surface and gravity, and what a scanner would see.")
    .def_readonly("brain_model", &SyntheticBrainShift::model)
    .def_readonly("solve", &SyntheticBrainShift::solve)
    .def_readonly("shift", &SyntheticBrainShift::shift)
    .def_property_readonly("truth_transform",
                           [](const SyntheticBrainShift & truth) { return PythonTransform{ truth.truthTransform.GetPointer() }; })
    .def_property_readonly("intraoperative_image",
                           [](const SyntheticBrainShift & truth) { return PythonImage(truth.intraoperativeImage.GetPointer()); })
    .def_property_readonly("intraoperative_brain_mask",
                           [](const SyntheticBrainShift & truth) { return PythonImage(truth.intraoperativeBrainMask.GetPointer()); })
    .def_property_readonly("intraoperative_brain_on_preoperative_grid",
                           [](const SyntheticBrainShift & truth) {
                             return PythonImage(truth.intraoperativeBrainOnPreoperativeGrid.GetPointer());
                           })
    .def_property_readonly("down",
                           [](const SyntheticBrainShift & truth) {
                             return py::make_tuple(truth.down.x(), truth.down.y(), truth.down.z());
                           },
                           "Unit vector from the craniotomy towards the brain's centroid: gravity's direction.")
    .def_property_readonly("tumour_mask", [](const SyntheticBrainShift & truth) { return PythonImage(truth.tumourMask.GetPointer()); },
                           "The tumour on the preoperative grid; None without a tumour.")
    .def_property_readonly("resection_mask",
                           [](const SyntheticBrainShift & truth) { return PythonImage(truth.resectionMask.GetPointer()); },
                           "The planned resection (the tumour and its margin) on the preoperative grid, for "
                           "register(resection_mask=); None without a resection.")
    .def_readonly("exposed_surface", &SyntheticBrainShift::exposedSurface)
    .def_property_readonly("tracked_points", [](const SyntheticBrainShift & truth) { return ArrayFromPoints(truth.trackedPoints.points); })
    .def_property_readonly("tracked_displacements",
                           [](const SyntheticBrainShift & truth) { return ArrayFromPoints(truth.trackedPoints.displacements); })
    .def_property_readonly("stage_seconds", [](const SyntheticBrainShift & truth) { return StageSeconds(truth.timer); });

  module.def(
    "make_synthetic_brain_shift",
    [](const py::object & image, const py::object & brainMask, const py::object & craniotomyCentre,
       double craniotomyRadius, double shift, double freeRim, double gravity, double elementSize,
       const py::object & intraoperativeSpacing,
       double noise, const std::string & noiseModel, const std::string & contrast, double biasField,
       double fieldOfView, const py::object & tumourCentre, double tumourRadius, double tumourStiffness,
       const py::object & resectionMargin, std::uint32_t seed, int threads, const py::object & progress) {
      const auto                  preoperative = ItkImage(image, "image");
      const auto                  mask = ItkLabelImage(brainMask, "brain_mask");
      SyntheticBrainShiftSettings settings;
      settings.craniotomyCentre = VectorFromObject(craniotomyCentre, "craniotomy_centre");
      settings.craniotomyRadius = craniotomyRadius;
      settings.targetShift = shift;
      settings.freeRim = freeRim;
      settings.gravity = gravity;
      settings.grid.elementSize = elementSize;
      settings.intraoperativeSpacing = VectorFromObject(intraoperativeSpacing, "intraoperative_spacing");
      settings.noise = noise;
      if (noiseModel != "gaussian" && noiseModel != "rician")
      {
        throw py::value_error("noise_model must be 'gaussian' or 'rician', not '" + noiseModel + "'");
      }
      settings.noiseModel = noiseModel == "rician" ? NoiseModel::Rician : NoiseModel::Gaussian;
      settings.contrast = ParseIntraoperativeContrast(contrast);
      settings.biasField = biasField;
      settings.fieldOfView = fieldOfView;
      if (!tumourCentre.is_none())
      {
        settings.tumourCentre = VectorFromObject(tumourCentre, "tumour_centre");
      }
      settings.tumourRadius = tumourRadius;
      settings.tumourStiffness = tumourStiffness;
      settings.resectionMargin = resectionMargin.is_none() ? -1.0 : resectionMargin.cast<double>();
      settings.seed = seed;
      settings.threads = threads;
      if (mask.IsNull())
      {
        throw py::value_error("brain_mask is required: the ground truth is made on a known brain");
      }
      ProgressReporter reporter(progress);
      return RunWithoutGil(reporter, [&] {
        return TranslateItkErrors([&] {
          return MakeSyntheticBrainShift(preoperative, mask, settings, reporter.StageCallback());
        });
      });
    },
    py::arg("image"), py::arg("brain_mask"), py::kw_only(),
    py::arg("craniotomy_centre") = py::make_tuple(SyntheticBrainShiftSettings{}.craniotomyCentre.x(),
                                                  SyntheticBrainShiftSettings{}.craniotomyCentre.y(),
                                                  SyntheticBrainShiftSettings{}.craniotomyCentre.z()),
    py::arg("craniotomy_radius") = SyntheticBrainShiftSettings{}.craniotomyRadius,
    py::arg("shift") = SyntheticBrainShiftSettings{}.targetShift, py::arg("free_rim") = SyntheticBrainShiftSettings{}.freeRim,
    py::arg("gravity") = SyntheticBrainShiftSettings{}.gravity,
    py::arg("element_size") = SyntheticBrainShiftSettings{}.grid.elementSize,
    py::arg("intraoperative_spacing") = py::make_tuple(SyntheticBrainShiftSettings{}.intraoperativeSpacing.x(),
                                                       SyntheticBrainShiftSettings{}.intraoperativeSpacing.y(),
                                                       SyntheticBrainShiftSettings{}.intraoperativeSpacing.z()),
    py::arg("noise") = SyntheticBrainShiftSettings{}.noise, py::arg("noise_model") = "gaussian",
    py::arg("intraoperative_contrast") = "preoperative", py::arg("bias_field") = 0.0, py::arg("field_of_view") = 0.0,
    py::arg("tumour_centre") = py::none(), py::arg("tumour_radius") = 0.0,
    py::arg("tumour_stiffness") = SyntheticBrainShiftSettings{}.tumourStiffness, py::arg("resection_margin") = py::none(),
    py::arg("seed") = SyntheticBrainShiftSettings{}.seed, py::arg("threads") = 0, py::arg("progress") = py::none(),
    "The README demo's ground truth on any brain: shift mm sag of the craniotomy, gravity in g, a noisy "
    "intraoperative image; realistic with another contrast ('t2', 'low-field-t1'), a bias field (largest deviation "
    "from 1), Rician noise, a partial field of view (mm) and a resection cavity (a tumour and resection_margin mm).");
}

// What the study measures against it: displacement errors and the ventricles.
void
BindSyntheticMeasures(py::module_ & module)
{
  module.def(
    "measure_displacement_error",
    [](const py::object & transform, const PythonTransform & truth, const py::object & region, int stride) {
      const TransformType * mapped = transform.is_none() ? nullptr : transform.cast<const PythonTransform &>().transform.GetPointer();
      const auto            mask = ItkLabelImage(region, "region");
      if (stride < 1)
      {
        throw py::value_error("stride must be 1 or more");
      }
      DisplacementError error;
      {
        py::gil_scoped_release release;
        error = MeasureDisplacementError(mapped, truth.transform, mask, stride);
      }
      py::dict result;
      result["mean_mm"] = error.mean;
      result["p95_mm"] = error.p95;
      result["max_mm"] = error.max;
      result["samples"] = error.samples;
      return result;
    },
    py::arg("transform"), py::arg("truth"), py::arg("region"), py::kw_only(), py::arg("stride") = 2,
    "|T(x) - T_truth(x)| (mm) over the voxels of region (> 0): mean, 95th percentile, maximum. None: no registration.");

  module.def(
    "surface_distance_p95",
    [](const py::object & transform, const PythonTransform & truth, const py::object & structure, double spacing) {
      const TransformType * mapped = transform.is_none() ? nullptr : transform.cast<const PythonTransform &>().transform.GetPointer();
      const auto            mask = ItkLabelImage(structure, "structure");
      py::gil_scoped_release release;
      return StructureSurfaceDistance(truth.transform, mask, spacing).Percentile95(mapped);
    },
    py::arg("transform"), py::arg("truth"), py::arg("structure"), py::kw_only(), py::arg("spacing") = 0.5,
    "How far transform puts a structure's surface (structure: voxels > 0 on the preoperative grid, e.g. a tumour or "
    "ventricle_mask's) from where truth puts it: the 95th percentile (mm) of the symmetric distances between the two "
    "warped masks' boundaries on an isotropic grid of spacing mm. None: no registration.");

  module.def(
    "ventricle_mask",
    [](const py::object & image, const py::object & brainMask, double depth) {
      const auto t1 = ItkImage(image, "image");
      const auto mask = ItkLabelImage(brainMask, "brain_mask");
      RegistrationLabelImage::Pointer ventricles;
      {
        py::gil_scoped_release release;
        ventricles = VentricleMask(t1, mask, depth);
      }
      return PythonImage(ventricles.GetPointer());
    },
    py::arg("image"), py::arg("brain_mask"), py::kw_only(), py::arg("depth") = 10.0,
    "The lateral ventricles of a T1 image: its CSF class deeper than depth mm below the brain mask's surface, opened "
    "by 2 mm, the largest component (what biomech demo's ventricle surface distance measures).");
}

void
BindSyntheticBrainShift(py::module_ & module)
{
  BindSyntheticScene(module);
  BindSyntheticMeasures(module);
}

// ---------------------------------------------------------------------------
// Electrodes from an intraoperative CT.
// ---------------------------------------------------------------------------

void
BindElectrodes(py::module_ & module)
{
  py::class_<SyntheticElectrodeCt>(module, "SyntheticElectrodeCt",
                                   "A CT-like image after a synthetic brain shift with an electrode grid on the "
                                   "shifted surface, and where its contacts truly are.")
    .def_property_readonly("image", [](const SyntheticElectrodeCt & ct) { return PythonImage(ct.image.GetPointer()); })
    .def_property_readonly("contacts", [](const SyntheticElectrodeCt & ct) { return ArrayFromPoints(ct.contacts); },
                           "MRI space, on the shifted brain (mm).")
    .def_property_readonly("preoperative_contacts",
                           [](const SyntheticElectrodeCt & ct) { return ArrayFromPoints(ct.preoperativeContacts); },
                           "MRI space, on the undeformed brain surface (mm).")
    .def_property_readonly("mri_to_ct", [](const SyntheticElectrodeCt & ct) { return PythonTransform{ ct.mriToCt.GetPointer() }; });

  module.def(
    "make_synthetic_electrode_ct",
    [](const py::object & image, const py::object & brainMask, const SyntheticBrainShift & truth,
       const py::object & craniotomyCentre, int rows, int columns, double contactSpacing, std::uint32_t seed) {
      SyntheticElectrodeCtSettings settings;
      settings.rows = rows;
      settings.columns = columns;
      settings.contactSpacing = contactSpacing;
      settings.seed = seed;
      const auto    preoperative = ItkImage(image, "image");
      const auto    mask = ItkLabelImage(brainMask, "brain_mask");
      const Vector3 centre = VectorFromObject(craniotomyCentre, "craniotomy_centre");
      py::gil_scoped_release release;
      return TranslateItkErrors([&] { return MakeSyntheticElectrodeCt(preoperative, mask, truth, centre, settings); });
    },
    py::arg("image"), py::arg("brain_mask"), py::arg("truth"), py::kw_only(),
    py::arg("craniotomy_centre") = py::make_tuple(SyntheticBrainShiftSettings{}.craniotomyCentre.x(),
                                                  SyntheticBrainShiftSettings{}.craniotomyCentre.y(),
                                                  SyntheticBrainShiftSettings{}.craniotomyCentre.z()),
    py::arg("rows") = SyntheticElectrodeCtSettings{}.rows, py::arg("columns") = SyntheticElectrodeCtSettings{}.columns,
    py::arg("contact_spacing") = SyntheticElectrodeCtSettings{}.contactSpacing,
    py::arg("seed") = SyntheticElectrodeCtSettings{}.seed,
    "biomech demo --load electrodes's CT: a rows x columns grid on the brain around the craniotomy, moved by the "
    "ground truth `truth` (make_synthetic_brain_shift), in Hounsfield units, 7 degrees and 33 mm from the MRI.");

  module.def(
    "locate_electrodes",
    [](const py::object & ct, const py::object & image, const py::object & brainMask, int contacts, double threshold,
       const py::object & projectAlong) {
      const auto                    ctImage = ItkImage(ct, "ct");
      const auto                    mri = ItkImage(image, "preoperative_image");
      const auto                    mask = ItkLabelImage(brainMask, "brain_mask");
      ElectrodeLocalisationSettings settings;
      settings.detection.expectedContacts = contacts;
      settings.detection.threshold = threshold;
      if (!projectAlong.is_none())
      {
        settings.projectionDirection = VectorFromObject(projectAlong, "project_along");
      }
      if (ctImage.IsNull() || mri.IsNull() || mask.IsNull())
      {
        throw py::value_error("locate_electrodes needs the CT, the preoperative image and its brain mask");
      }
      ElectrodeLocalisation located;
      {
        py::gil_scoped_release release;
        located = TranslateItkErrors([&] {
          return LocateElectrodes(ctImage, mri, ElectrodeReferenceSurface(mask), settings);
        });
      }
      std::vector<Vector3> inCt;
      for (const ElectrodeContact & contact : located.contactsInCt)
      {
        inCt.push_back(contact.position);
      }
      py::dict result;
      result["contacts_in_ct"] = ArrayFromPoints(inCt);
      result["contacts"] = ArrayFromPoints(located.contacts);
      result["sparse_points"] = ArrayFromPoints(located.loads.points);
      result["sparse_displacements"] = ArrayFromPoints(located.loads.displacements);
      result["ct_to_mri"] = PythonTransform{ located.alignment.ctToMri.GetPointer() };
      result["alignment_seconds"] = located.alignment.seconds;
      result["warnings"] = located.warnings;
      return result;
    },
    py::arg("ct"), py::arg("preoperative_image"), py::arg("brain_mask"), py::kw_only(), py::arg("contacts") = 0,
    py::arg("threshold") = ElectrodeDetectionSettings{}.threshold, py::arg("project_along") = py::none(),
    "Electrode contacts of a CT (Hounsfield units) in the MRI's space and as sparse displacements of the undeformed "
    "brain surface (closest point, or along project_along): pass sparse_points and sparse_displacements to register().");
}

} // namespace

void
BindSyntheticScenes(py::module_ & module)
{
  BindSyntheticBrainShift(module);
  BindElectrodes(module);
}

} // namespace bmr::python
