// The ITK layer of the Python binding: image and transform files, atlas skull
// stripping, brain surfaces, the transform fitter, warping, the edge-based
// Hausdorff evaluator, the B-spline baseline, the patient model and the
// one-call registration (the synthetic scenes: bmrPythonSynthetic.cxx). It calls the pipeline library
// (bmrBrainShiftRegistration.h), which holds the filters compiled on float
// images and unsigned char masks, so that this file instantiates few templates.
// Over 800 lines: another translation unit would compile ITK's and pybind11's
// headers once more in every build.

// ITK before the core: ITK's bundled Eigen must be seen before the system
// Eigen (the pipeline headers include ITK's first).
#include "bmrBrainShiftRegistration.h"
#include "bmrBrainShiftUncertainty.h"
#include "bmrModelBundle.h"

#include "itkBiomechanicalImageConversion.h"
#include "itkBiomechanicalImageIO.h"
#include "itkBiomechanicalTransformIO.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkIdentityTransform.h"
#include "itkImageIOFactory.h"
#include "itkVectorImage.h"

#include "bmrSyntheticBrainShift.h"

#include "bmrPythonItk.h"

#include <pybind11/functional.h>

#include <sstream>
#include <type_traits>

namespace bmr::python
{
namespace
{

/** uint8 or bool voxels; anything that is not an image is left to the conversions, which name the problem. */
bool
IsLabelImage(const py::handle & image)
{
  if (!py::hasattr(image, "array"))
  {
    return false;
  }
  const py::array array = py::array::ensure(image.attr("array"));
  return array && (array.dtype().kind() == 'u' || array.dtype().kind() == 'b') && array.itemsize() == 1;
}

py::dict
JsonToDict(const nlohmann::json & value)
{
  return py::module_::import("json").attr("loads")(value.dump());
}

// ---------------------------------------------------------------------------

// Image files: reading (DICOM series too) and writing.
void
BindImageFiles(py::module_ & module)
{
  module.def(
    "imread",
    [](const std::filesystem::path & pathArgument, const std::string & pixelType, const std::string & series) -> py::object {
      const std::string path = pathArgument.string();
      if (pixelType != "auto" && pixelType != "float32" && pixelType != "uint8")
      {
        throw py::value_error("pixel_type must be 'auto', 'float32' or 'uint8', not '" + pixelType + "'");
      }
      return TranslateItkErrors([&]() -> py::object {
        if (itk::IsBiomechanicalDicomPath(path) || !series.empty())
        {
          // A DICOM series (its folder or one of its files): scanner intensities as float32 unless asked otherwise.
          if (pixelType == "uint8")
          {
            return PythonImage(itk::ReadBiomechanicalImage<RegistrationLabelImage>(path, "image", series).GetPointer());
          }
          return PythonImage(itk::ReadBiomechanicalImage<RegistrationImage>(path, "image", series).GetPointer());
        }
        auto io = itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::CommonEnums::IOFileMode::ReadMode);
        if (io.IsNull())
        {
          throw Error("cannot read image '" + path + "': the file does not exist or its format is unknown "
                      "(NIfTI .nii/.nii.gz, MetaImage .mha/.mhd, PNG and the other formats of ITK)");
        }
        io->SetFileName(path);
        io->ReadImageInformation();
        if (io->GetNumberOfDimensions() != 3 && io->GetNumberOfDimensions() != 2)
        {
          throw Error("'" + path + "' has " + std::to_string(io->GetNumberOfDimensions()) +
                      " dimensions; the module works on 3-D images");
        }
        if (io->GetNumberOfComponents() > 1)
        {
          if (pixelType == "uint8")
          {
            throw Error("'" + path + "' has " + std::to_string(io->GetNumberOfComponents()) +
                        " components per voxel; read it as float32");
          }
          const auto image = itk::ReadBiomechanicalImage<VectorImageType>(path, "image");
          return ImageFromVolume(itk::MakeBiomechanicalVolume<float>(image.GetPointer()));
        }
        const bool labels = pixelType == "uint8" ||
                            (pixelType == "auto" && io->GetComponentType() == itk::IOComponentEnum::UCHAR);
        if (labels)
        {
          return PythonImage(itk::ReadBiomechanicalImage<RegistrationLabelImage>(path, "image").GetPointer());
        }
        return PythonImage(itk::ReadBiomechanicalImage<RegistrationImage>(path, "image").GetPointer());
      });
    },
    py::arg("path"), py::arg("pixel_type") = "auto", py::arg("series") = "",
    "Reads an image (.nii.gz, .nrrd, .mha, ..., or a DICOM series given as its folder or one of its files; "
    "series: the Series Instance UID when the folder holds several, else the file's own series or the one with "
    "most slices): uint8 files as uint8, everything else (DICOM too) as float32 (pixel_type 'float32' or 'uint8' "
    "forces one); multi-component files as float32 [z, y, x, component].");

  module.def(
    "imwrite",
    [](const py::object & image, const std::filesystem::path & pathArgument) {
      const std::string path = pathArgument.string();
      TranslateItkErrors([&] {
        GeometryFromImage(image, "image"); // names a malformed image before its array is read
        if (py::array::ensure(image.attr("array")).ndim() == 4)
        {
          const ScalarVolume volume = ScalarVolumeFromImage(image, "image");
          auto               vectorImage = VectorImageType::New();
          itk::ApplyBiomechanicalGeometry(volume.geometry, vectorImage.GetPointer());
          vectorImage->SetNumberOfComponentsPerPixel(static_cast<unsigned int>(volume.components));
          vectorImage->Allocate();
          std::copy(volume.values.begin(), volume.values.end(), vectorImage->GetBufferPointer());
          itk::WriteBiomechanicalImage(vectorImage.GetPointer(), path);
        }
        else if (IsLabelImage(image))
        {
          itk::WriteBiomechanicalImage(ItkLabelImage(image, "image").GetPointer(), path);
        }
        else
        {
          itk::WriteBiomechanicalImage(ItkImage(image, "image").GetPointer(), path);
        }
      });
    },
    py::arg("image"), py::arg("path"),
    "Writes an image (uint8/bool arrays as uint8, others as float32), through a temporary file: never half-written.");
}

// Transforms: their files, composition and the points they map.
void
BindTransforms(py::module_ & module)
{
  py::class_<PythonTransform>(module, "Transform",
                              "An ITK transform of 3-D points (mm). The registrations' transforms are backward maps: "
                              "intraoperative point -> preoperative point, what resampling needs.")
    .def_property_readonly("name", [](const PythonTransform & self) { return std::string(self.transform->GetNameOfClass()); })
    .def_property_readonly("number_of_parameters",
                           [](const PythonTransform & self) { return self.transform->GetNumberOfParameters(); })
    .def(
      "transform_points",
      [](const PythonTransform & self, const py::object & points) {
        std::vector<Vector3> values = PointsFromArray(points, "points");
        for (Vector3 & value : values)
        {
          TransformType::InputPointType point;
          for (int d = 0; d < 3; ++d)
            point[d] = value[d];
          const auto mapped = self.transform->TransformPoint(point);
          value = Vector3(mapped[0], mapped[1], mapped[2]);
        }
        return ArrayFromPoints(values);
      },
      py::arg("points"), "T(x) for an (N, 3) array of points (mm).")
    .def(
      "displacement_field",
      [](const PythonTransform & self, const py::object & reference) {
        ScalarVolume field;
        field.geometry = GeometryFromImage(reference, "reference");
        field.components = 3;
        field.values.resize(field.geometry.VoxelCount() * 3);
        {
          py::gil_scoped_release release;
          const auto & size = field.geometry.size;
          for (int k = 0; k < size[2]; ++k)
            for (int j = 0; j < size[1]; ++j)
              for (int i = 0; i < size[0]; ++i)
              {
                const Vector3                 x = field.geometry.IndexToPoint(Vector3(i, j, k));
                TransformType::InputPointType point;
                for (int d = 0; d < 3; ++d)
                  point[d] = x[d];
                const auto mapped = self.transform->TransformPoint(point);
                for (int d = 0; d < 3; ++d)
                  field.At(i, j, k, d) = static_cast<float>(mapped[d] - x[d]);
              }
        }
        return ImageFromVolume(field);
      },
      py::arg("reference"),
      "T(x) - x (mm) at the voxel centres of `reference`: an Image with array [z, y, x, 3] (x, y, z components).")
    .def(
      "write", [](const PythonTransform & self, const std::filesystem::path & pathArgument) {
      const std::string path = pathArgument.string();
        TranslateItkErrors([&] { itk::WriteBiomechanicalTransform(self.transform, path); });
      },
      py::arg("path"), "Writes the transform (.h5, .tfm, .txt) as `biomech register` does.")
    .def("__repr__", [](const PythonTransform & self) {
      return std::string("Transform(") + self.transform->GetNameOfClass() + ", " +
             std::to_string(self.transform->GetNumberOfParameters()) + " parameters)";
    });

  module.def(
    "read_transform",
    [](const std::filesystem::path & pathArgument) {
      const std::string path = pathArgument.string();
      return TranslateItkErrors([&] {
        auto transform = itk::ReadBiomechanicalTransform(path);
        const auto * typed = dynamic_cast<const TransformType *>(transform.GetPointer());
        if (typed == nullptr)
        {
          throw Error("'" + path + "' holds a " + transform->GetNameOfClass() + ", not a 3-D transform of doubles");
        }
        return PythonTransform{ typed };
      });
    },
    py::arg("path"), "Reads a transform file written by `biomech register` or ITK (.h5, .tfm, .txt).");
  module.def(
    "identity_transform", [] { return PythonTransform{ itk::IdentityTransform<double, 3>::New().GetPointer() }; },
    "The identity: 'no registration' in comparisons.");
}

void
BindFilesAndTransforms(py::module_ & module)
{
  BindImageFiles(module);
  BindTransforms(module);
}

// Skull stripping, brain surfaces and the transform fitter.
void
BindModelBuildingFilters(py::module_ & module)
{
  module.def(
    "atlas_brain_mask",
    [](const py::object & image, const std::filesystem::path & atlasImage, const std::filesystem::path & atlasMask,
       bool bsplineStage) {
      const auto    input = ItkImage(image, "image");
      AtlasSettings settings;
      settings.image = atlasImage.string();
      settings.mask = atlasMask.string();
      settings.bsplineStage = bsplineStage;
      RegistrationLabelImage::Pointer mask;
      {
        py::gil_scoped_release release;
        mask = TranslateItkErrors([&] { return AtlasBrainMask(input, settings); });
      }
      return PythonImage(mask.GetPointer());
    },
    py::arg("image"), py::kw_only(), py::arg("atlas_image") = AtlasSettings{}.image,
    py::arg("atlas_mask") = AtlasSettings{}.mask, py::arg("bspline_stage") = AtlasSettings{}.bsplineStage,
    "Brain mask (uint8, 1 inside) of a T1 image by registering an atlas (itk::AtlasBrainMaskImageFilter; Colin27 from "
    "mricron-data by default).");

  module.def(
    "brain_surfaces",
    [](const py::object & mask, double skullGap, double skullClosing, const std::optional<Model> & body, bool skull) {
      LabelVolume              volume = LabelVolumeFromImage(mask, "mask");
      std::vector<std::string> warnings;
      BrainSurfaces            surfaces;
      {
        py::gil_scoped_release release;
        if (body)
        {
          volume = RasterizeCells(*body, volume.geometry);
        }
        surfaces = BrainSurfacesOfMask(volume, skullGap, warnings, skull, skullClosing);
      }
      WarnInPython(warnings);
      return py::make_tuple(surfaces.brain, skull ? py::cast(surfaces.skull) : py::none());
    },
    py::arg("mask"), py::kw_only(), py::arg("skull_gap") = BrainSurfaceSettings{}.skullGap,
    py::arg("skull_closing") = BrainSurfaceSettings{}.skullClosing, py::arg("body") = py::none(), py::arg("skull") = true,
    "(brain, skull): the smoothed brain surface of a mask and a rigid skull skull_gap mm outside it "
    "(outside the mask closed by skull_closing mm: no blades in the fissures) "
    "(itk::BrainSurfaceMeshSource). With body= (a grid's model, or a point cloud's meshless_body), the "
    "surfaces of the body's cells on the mask's grid instead, as build_brain_model makes them: the "
    "corners of a staircase hexahedral grid stick out of the mask, and the skull must enclose them. "
    "skull=False: (brain, None), the cortex alone, as the surface a scan is matched to (about half the time).");

  module.def(
    "fit_transform",
    [](const py::object & points, const py::object & displacements, const py::object & reference, double tolerance,
       double minimumControlPointSpacing, bool extendDomainToPoints) {
      const std::vector<Vector3> nodes = PointsFromArray(points, "points");
      const std::vector<Vector3> values = PointsFromArray(displacements, "displacements");
      if (nodes.size() != values.size())
      {
        throw py::value_error("points and displacements differ in length (" + std::to_string(nodes.size()) + " and " +
                              std::to_string(values.size()) + ")");
      }
      const auto referenceImage = ItkImage(reference, "reference");
      using PointSetType = itk::DisplacementPointSetType<3>;
      using FitterType = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>;
      auto fitter = FitterType::New();
      fitter->SetInput(itk::MakeDisplacementPointSet<PointSetType>(nodes, values));
      fitter->SetReferenceImage(referenceImage);
      fitter->SetTolerance(tolerance);
      fitter->SetMinimumControlPointSpacing(minimumControlPointSpacing);
      fitter->SetExtendDomainToPoints(extendDomainToPoints);
      {
        py::gil_scoped_release release;
        TranslateItkErrors([&] { fitter->Update(); });
      }
      const itk::BSplineFitReport & fit = fitter->GetReport();
      py::dict                      report;
      report["max_residual_mm"] = fit.maximumResidual;
      report["rms_residual_mm"] = fit.rmsResidual;
      report["levels"] = fit.levels;
      report["control_point_spacing_mm"] = fit.controlPointSpacing;
      report["mesh_size"] = fit.meshSize;
      report["tolerance_reached"] = fit.toleranceReached;
      report["domain_extended"] = fitter->GetDomainExtended();
      return py::make_tuple(PythonTransform{ fitter->GetTransform() }, report);
    },
    py::arg("points"), py::arg("displacements"), py::arg("reference"), py::kw_only(), py::arg("tolerance") = 0.1,
    py::arg("minimum_control_point_spacing") = 1.0, py::arg("extend_domain_to_points") = true,
    "Fits the backward B-spline map T(x + u) = x to displacements u at points (e.g. model nodes) over the grid of "
    "`reference` (itk::DisplacementPointSetToBSplineTransformFilter): (Transform, report).");
}

// Warping, the edge-based Hausdorff evaluation and the B-spline baseline.
void
BindWarpingAndEvaluation(py::module_ & module)
{
  module.def(
    "warp_image",
    [](const py::object & image, const PythonTransform & transform, const py::object & reference,
       const std::string & interpolation) {
      if (interpolation != "auto" && interpolation != "linear" && interpolation != "nearest")
      {
        throw py::value_error("interpolation must be 'auto', 'linear' or 'nearest', not '" + interpolation + "'");
      }
      const bool labels = interpolation == "nearest" || (interpolation == "auto" && IsLabelImage(image));
      const auto grid = reference.is_none() ? nullptr : ItkImage(reference, "reference");
      if (labels)
      {
        const auto                      input = ItkLabelImage(image, "image");
        RegistrationLabelImage::Pointer output;
        {
          py::gil_scoped_release release;
          output = WarpLabelImage(input, transform.transform, grid.GetPointer());
        }
        return PythonImage(output.GetPointer());
      }
      const auto                 input = ItkImage(image, "image");
      RegistrationImage::Pointer output;
      {
        py::gil_scoped_release release;
        output = WarpImage(input, transform.transform, grid.GetPointer());
      }
      return PythonImage(output.GetPointer());
    },
    py::arg("image"), py::arg("transform"), py::arg("reference") = py::none(), py::kw_only(),
    py::arg("interpolation") = "auto",
    "The image resampled through the backward map onto the grid of `reference` (default: its own) "
    "(itk::TransformWarpImageFilter). interpolation 'auto': nearest neighbour for uint8/bool images (label maps, "
    "masks; the result is uint8), linear for the others (float32); 'linear' or 'nearest' choose, and 'nearest' "
    "needs labels 0..255.");

  py::class_<EdgeEvaluation>(module, "EdgeEvaluation",
                             "Edge-based Hausdorff distance (Garlapati et al.): distances (mm) at percentiles 1..100.")
    .def_readonly("valid", &EdgeEvaluation::valid)
    .def_readonly("message", &EdgeEvaluation::message)
    .def_property_readonly("percentiles",
                           [](const EdgeEvaluation & evaluation) {
                             return py::array_t<double>(static_cast<py::ssize_t>(evaluation.symmetric.size()),
                                                        evaluation.symmetric.data());
                           },
                           "Symmetric edge distance (mm) at percentiles 1, 2, ..., 100.")
    .def("percentile", &EdgeEvaluation::Percentile, py::arg("k"))
    .def_readonly("fraction_within_threshold", &EdgeEvaluation::fractionWithinThreshold)
    .def_readonly("fixed_edges", &EdgeEvaluation::fixedEdges)
    .def_readonly("moving_edges", &EdgeEvaluation::movingEdges)
    .def_property_readonly("fixed_edge_image",
                           [](const EdgeEvaluation & evaluation) { return PythonImage(evaluation.fixedEdgeImage.GetPointer()); })
    .def_property_readonly("moving_edge_image",
                           [](const EdgeEvaluation & evaluation) { return PythonImage(evaluation.movingEdgeImage.GetPointer()); })
    .def("__repr__", [](const EdgeEvaluation & evaluation) {
      if (!evaluation.valid)
        return "EdgeEvaluation(invalid: " + evaluation.message + ")";
      std::ostringstream text;
      text << "EdgeEvaluation(95th percentile " << evaluation.Percentile(95) << " mm, "
           << 100.0 * evaluation.fractionWithinThreshold << " % of edges within the threshold)";
      return text.str();
    });

  module.def(
    "evaluate_edges",
    [](const py::object & fixed, const py::object & moving, const py::object & mask, int sliceAxis,
       double distanceThreshold, std::optional<double> variance, std::optional<double> upperThresholdQuantile,
       std::optional<double> lowerThresholdRatio, std::optional<double> upperThreshold,
       std::optional<double> lowerThreshold) {
      const auto            fixedImage = ItkImage(fixed, "fixed");
      const auto            movingImage = ItkImage(moving, "moving");
      const auto            maskImage = ItkLabelImage(mask, "mask");
      EdgeDetectionSettings edges{ variance, upperThresholdQuantile, lowerThresholdRatio, upperThreshold, lowerThreshold };
      py::gil_scoped_release release;
      return TranslateItkErrors(
        [&] { return EvaluateEdges(fixedImage, movingImage, maskImage, sliceAxis, distanceThreshold, edges); });
    },
    py::arg("fixed"), py::arg("moving"), py::arg("mask") = py::none(), py::kw_only(), py::arg("slice_axis") = 2,
    py::arg("distance_threshold") = 1.7, py::arg("variance") = py::none(),
    py::arg("upper_threshold_quantile") = py::none(), py::arg("lower_threshold_ratio") = py::none(),
    py::arg("upper_threshold") = py::none(), py::arg("lower_threshold") = py::none(),
    "Edge-based Hausdorff evaluation of two images on the same grid inside `mask` "
    "(itk::EdgeHausdorffDistanceImageFilter): slice_axis 0..2 for slice by slice, -1 for the whole volume; Canny "
    "settings left None keep the filter's defaults (variance 2 mm^2, automatic thresholds at the 0.8 quantile and "
    "0.4 of it).");

  py::class_<BaselineRegistration>(module, "BSplineRegistration")
    .def_property_readonly("transform",
                           [](const BaselineRegistration & result) { return PythonTransform{ result.transform.GetPointer() }; })
    .def_property_readonly("warped", [](const BaselineRegistration & result) { return PythonImage(result.warpedOnFixedGrid.GetPointer()); },
                           "The moving image warped onto the fixed grid.")
    .def_readonly("seconds", &BaselineRegistration::seconds);

  module.def(
    "bspline_registration",
    [](const py::object & fixed, const py::object & moving, const py::object & fixedMask,
       const std::vector<unsigned int> & shrinkFactors, const std::vector<double> & smoothingSigmas,
       unsigned int iterations, std::optional<double> controlPointSpacing, std::optional<bool> useTranslationStage,
       std::optional<unsigned int> translationIterations, std::optional<bool> refineMeshPerLevel,
       std::optional<unsigned int> histogramBins, std::optional<double> metricSamplingPercentage,
       std::optional<double> costFunctionConvergenceFactor, std::optional<int> randomSeed) {
      if (shrinkFactors.empty() || shrinkFactors.size() != smoothingSigmas.size())
      {
        throw py::value_error("shrink_factors and smoothing_sigmas must name the same number (>= 1) of levels");
      }
      const auto fixedImage = ItkImage(fixed, "fixed");
      const auto movingImage = ItkImage(moving, "moving");
      const auto maskImage = ItkLabelImage(fixedMask, "fixed_mask");
      BaselineSettings settings;
      settings.shrinkFactors = shrinkFactors;
      settings.smoothingSigmas = smoothingSigmas;
      settings.iterations = iterations;
      settings.controlPointSpacing = controlPointSpacing;
      settings.useTranslationStage = useTranslationStage;
      settings.translationIterations = translationIterations;
      settings.refineMeshPerLevel = refineMeshPerLevel;
      settings.histogramBins = histogramBins;
      settings.metricSamplingPercentage = metricSamplingPercentage;
      settings.costFunctionConvergenceFactor = costFunctionConvergenceFactor;
      settings.randomSeed = randomSeed;
      py::gil_scoped_release release;
      return TranslateItkErrors(
        [&] { return RegisterWithBSplineBaseline(fixedImage, movingImage, maskImage, settings); });
    },
    py::arg("fixed"), py::arg("moving"), py::arg("fixed_mask") = py::none(), py::kw_only(),
    py::arg("shrink_factors") = BaselineSettings{}.shrinkFactors,
    py::arg("smoothing_sigmas") = BaselineSettings{}.smoothingSigmas, py::arg("iterations") = 0,
    py::arg("control_point_spacing") = py::none(), py::arg("use_translation_stage") = py::none(),
    py::arg("translation_iterations") = py::none(), py::arg("refine_mesh_per_level") = py::none(),
    py::arg("histogram_bins") = py::none(), py::arg("metric_sampling_percentage") = py::none(),
    py::arg("cost_function_convergence_factor") = py::none(), py::arg("random_seed") = py::none(),
    "Intensity-based B-spline registration, the baseline (itk::BSplineIntensityRegistrationFilter: translation, then "
    "B-spline, Mattes mutual information, L-BFGS-B); iterations 0 and settings left None keep the filter's defaults "
    "(control points 20 mm at the finest level, 50 histogram bins, 20 % of the voxels sampled, seed 121212).");
}

void
BindFilters(py::module_ & module)
{
  BindModelBuildingFilters(module);
  BindWarpingAndEvaluation(module);
}

// ---------------------------------------------------------------------------
// The patient model and the one-call registration: settings from keywords.
// ---------------------------------------------------------------------------

/** The keywords of build_brain_model and register, with their defaults: the
 *  rows of the registration's settings table (bmr::RegistrationSettingFields,
 *  the names of `biomech register`'s options with underscores) and the
 *  settings that are not one value. The Python layer checks names. */
py::dict
DefaultRegistrationSettings()
{
  const BrainShiftRegistrationSettings defaults;
  py::dict                             settings;
  for (const RegistrationSettingField & row : RegistrationSettingFields())
  {
    settings[py::str(row.name)] = SettingValueToPython(row, defaults);
  }
  settings["craniotomy_centre"] = py::none();
  settings["craniotomy_radius"] = 0.0;
  settings["craniotomy_mask"] = py::none();
  settings["resection_mask"] = py::none();
  settings["gravity"] = py::make_tuple(0.0, 0.0, 0.0);
  settings["csf_drained_depth"] = py::none();
  settings["max_distance"] = IntraoperativeData{}.maxDistance;
  return settings;
}

BrainShiftRegistrationSettings
RegistrationSettingsFrom(const py::dict & values, BrainShiftRegistrationSettings settings = {})
{
  const py::dict known = DefaultRegistrationSettings();
  for (const auto & [key, value] : values)
  {
    if (!known.contains(key))
    {
      throw py::type_error("unknown setting '" + std::string(py::str(key)) + "'");
    }
  }
  const auto get = [&](const char * name) -> py::object {
    return values.contains(name) ? py::reinterpret_borrow<py::object>(values[name]) : py::object(known[name]);
  };
  for (const RegistrationSettingField & row : RegistrationSettingFields())
  {
    if (!values.contains(row.name.c_str()))
    {
      continue;
    }
    const py::object value = values[row.name.c_str()];
    if (row.kind == SettingFieldBase::Kind::Text)
    {
      if (!py::isinstance<py::str>(value) && !py::hasattr(value, "__fspath__"))
      {
        throw py::type_error("setting '" + row.name + "' must be a string or a path, got " +
                             std::string(py::repr(value)));
      }
      row.setText(settings, py::module_::import("os").attr("fspath")(value).cast<std::string>());
    }
    else
    {
      row.set(settings, SettingValueFromPython(row, value));
    }
  }
  // The settings that are not one value.
  BrainModelSettings & model = settings.model;
  const py::object     centre = get("craniotomy_centre");
  const py::object     mask = get("craniotomy_mask");
  // A sphere and a mask together: bmr::CheckCraniotomyRegion's error, in BuildBrainModel.
  if (!centre.is_none())
  {
    const py::object radius = get("craniotomy_radius");
    if (!py::isinstance<py::int_>(radius) && !py::isinstance<py::float_>(radius))
    {
      throw py::type_error("setting 'craniotomy_radius' must be a number, got " + std::string(py::repr(radius)));
    }
    const CraniotomyRegion sphere = CraniotomySphereFrom(centre, radius.cast<double>());
    model.craniotomyCentre = sphere.centre;
    model.craniotomyRadius = sphere.radius;
  }
  if (!mask.is_none())
  {
    model.craniotomyMask = ItkLabelImage(mask, "craniotomy_mask");
  }
  if (const py::object resection = get("resection_mask"); !resection.is_none())
  {
    model.resectionMask = ItkLabelImage(resection, "resection_mask");
  }
  model.gravity = VectorFromObject(get("gravity"), "gravity");
  if (const py::object depth = get("csf_drained_depth"); !depth.is_none())
  {
    if (!py::isinstance<py::int_>(depth) && !py::isinstance<py::float_>(depth))
    {
      throw py::type_error("setting 'csf_drained_depth' must be a number or None, got " + std::string(py::repr(depth)));
    }
    model.csfDrainedDepth = depth.cast<double>();
  }
  if (const py::object distance = get("max_distance");
      py::isinstance<py::bool_>(distance) || (!py::isinstance<py::int_>(distance) && !py::isinstance<py::float_>(distance)))
  {
    throw py::type_error("setting 'max_distance' must be a number, got " + std::string(py::repr(distance)));
  }
  return settings;
}

double
MaxDistanceFrom(const py::dict & values)
{
  return values.contains("max_distance") ? values["max_distance"].cast<double>() : IntraoperativeData{}.maxDistance;
}

/** Intraoperative measurements: a surface, sparse points with displacements, or an image (+ mask). */
IntraoperativeData
IntraoperativeFrom(const py::object & surface, const py::object & points, const py::object & displacements,
                   const py::object & image, const py::object & imageMask, double maxDistance)
{
  IntraoperativeData data;
  data.maxDistance = maxDistance;
  if (!surface.is_none())
  {
    data.surface = surface.cast<ContactSurface>();
  }
  if (points.is_none() != displacements.is_none())
  {
    throw py::value_error("sparse measurements need both sparse_points and sparse_displacements (N x 3 each, mm)");
  }
  if (!points.is_none())
  {
    data.sparse.points = PointsFromArray(points, "sparse_points");
    data.sparse.displacements = PointsFromArray(displacements, "sparse_displacements");
  }
  data.image = OptionalItkImage(image, "intraoperative_image");
  data.imageBrainMask = ItkLabelImage(imageMask, "intraoperative_mask");
  return data;
}

/** (result, report, None or (uncertainty map, mean transform, nodal uncertainty)) for register() and update(). */
py::tuple
ResultWithEnsemble(BrainShiftRegistrationResult result, const BrainShiftRegistrationSettings & settings,
                   const std::optional<UncertaintySettings> &          uncertainty,
                   const std::optional<BrainShiftUncertaintyResult> & ensemble)
{
  nlohmann::json report = RegistrationReportJson(result, settings);
  py::object     spread = py::none();
  if (ensemble)
  {
    report["uncertainty"] = UncertaintyReportJson(*ensemble, *uncertainty);
    spread = py::make_tuple(PythonImage(ensemble->uncertaintyImage.GetPointer()),
                            PythonTransform{ ensemble->meanTransform.GetPointer() }, ensemble->nodalUncertainty);
  }
  return py::make_tuple(std::move(result), JsonToDict(report), spread);
}

// The patient model (PrepareBrainModel) and its uncertainty settings.
void
BindBrainModel(py::module_ & module)
{
  module.def("_default_registration_settings", &DefaultRegistrationSettings);

  py::class_<BrainModel>(module, "BrainModel",
                         "A patient-specific brain model: the mechanical model (skull base fixed, exposed surface "
                         "loaded, skull contact), its surfaces, tissue classification and load report.")
    .def_readonly("model", &BrainModel::model)
    .def_property_readonly("brain_surface", [](const BrainModel & model) { return model.surfaces.brain; })
    .def_property_readonly("skull_surface", [](const BrainModel & model) { return model.surfaces.skull; })
    .def_property_readonly("tissue_classes",
                           [](const BrainModel & model) {
                             return ImageFromVolume(
                               itk::MakeBiomechanicalVolume<std::uint8_t>(model.tissueLabelImage.GetPointer()));
                           })
    .def_property_readonly("centroids", [](const BrainModel & model) { return model.classificationFit.centroids; })
    .def_property_readonly("csf_class",
                           [](const BrainModel & model) {
                             const nlohmann::json csf = CsfClassJson(model);
                             py::dict             out;
                             out["contrast"] = csf["contrast"].get<std::string>();
                             out["class"] = csf["class"].get<int>();
                             out["centroid"] = csf["centroid"].get<double>();
                             out["volume_ml"] = csf["volume_ml"].get<double>();
                             out["chosen"] = csf["chosen"].get<std::string>();
                             return out;
                           },
                           "The class that became the CSF: a dict of contrast ('t1' or 't2'), class (the tissue "
                           "label 1..K), centroid, volume_ml, and why it was chosen (chosen)")
    .def_property_readonly("brain_mask", [](const BrainModel & model) { return ImageFromVolume(model.brainMask); })
    .def_readonly("resected_volume", &BrainModel::resectedVolume, "mm^3 of brain the resection_mask removed (0: none)")
    .def_property_readonly("exposed_nodes", [](const BrainModel & model) { return ArrayFromIndices(model.exposedNodes); })
    .def_readonly("load", &BrainModel::load)
    .def_property_readonly("load_report", [](const BrainModel & model) { return LoadReportDict(model.loadReport); })
    .def_readonly("warnings", &BrainModel::warnings);

  module.def(
    "_build_brain_model",
    [](const py::object & image, const py::object & brainMask, const py::object & tumourMask,
       const std::optional<ContactSurface> & skullSurface, const py::object & surface, const py::object & points,
       const py::object & displacements, const py::dict & values, const py::object & progress) {
      const BrainShiftRegistrationSettings settings = RegistrationSettingsFrom(values);
      const auto                           preoperative = ItkImage(image, "image");
      const auto                           mask = ItkLabelImage(brainMask, "brain_mask");
      const auto                           tumour = ItkLabelImage(tumourMask, "tumour_mask");
      const bool measured = !surface.is_none() || !points.is_none() || !displacements.is_none();
      const IntraoperativeData intraoperative = IntraoperativeFrom(surface, points, displacements, py::none(),
                                                                   py::none(), MaxDistanceFrom(values));
      ProgressReporter reporter(progress);
      return RunWithoutGil(reporter, [&] {
        StageTimer timer(reporter.StageCallback());
        return TranslateItkErrors([&] {
          return BuildBrainModel(preoperative, mask, tumour, skullSurface.value_or(ContactSurface{}),
                                 measured ? &intraoperative : nullptr, settings.model, timer);
        });
      });
    },
    py::arg("image"), py::arg("brain_mask"), py::arg("tumour_mask"), py::arg("skull_surface"),
    py::arg("intraoperative_surface"), py::arg("sparse_points"), py::arg("sparse_displacements"), py::arg("settings"),
    py::arg("progress"));

  py::class_<UncertaintySettings>(module, "UncertaintySettings",
                                  "The uncertain inputs of update(uncertainty=N) and their distributions "
                                  "(docs/registration.md, Uncertainty).")
    .def(py::init<>())
    .def_readwrite("members", &UncertaintySettings::members)
    .def_readwrite("seed", &UncertaintySettings::seed)
    .def_readwrite("noise_sigma", &UncertaintySettings::noiseSigma, "mm per component; negative: the loads' RMS "
                                                                     "correspondence distance; 0: none")
    .def_readwrite("gravity_low", &UncertaintySettings::gravityLow)
    .def_readwrite("gravity_high", &UncertaintySettings::gravityHigh)
    .def_readwrite("youngs_modulus_spread", &UncertaintySettings::youngsModulusSpread)
    .def_readwrite("tissue_modulus_spread", &UncertaintySettings::tissueModulusSpread,
                   "log-sd of a factor per tissue class, on top of the common one (0: none)")
    .def_readwrite("poisson_low", &UncertaintySettings::poissonLow)
    .def_readwrite("poisson_high", &UncertaintySettings::poissonHigh)
    .def_readwrite("skull_gap_spread", &UncertaintySettings::skullGapSpread)
    .def_readwrite("exposed_radius_spread", &UncertaintySettings::exposedRadiusSpread)
    .def_readwrite("member_tolerance", &UncertaintySettings::memberTolerance)
    .def_readwrite("threads", &UncertaintySettings::threads);
}

// The one-call registration and its result.
void
BindRegistrationResult(py::module_ & module)
{
  py::class_<BrainShiftRegistrationResult>(module, "RegistrationResult", py::dynamic_attr(),
                                           "Everything `biomech register` writes, in memory.")
    .def_readonly("brain_model", &BrainShiftRegistrationResult::model)
    .def_readonly("solve", &BrainShiftRegistrationResult::solve)
    .def_property_readonly("gravity",
                           [](const BrainShiftRegistrationResult & result) {
                             return py::make_tuple(result.gravity.x(), result.gravity.y(), result.gravity.z());
                           },
                           "The solve's body acceleration (mm/s^2): the given gravity, or the fitted one.")
    .def_readonly("gravity_fit", &BrainShiftRegistrationResult::gravityFit,
                  "With gravity_fit_candidates: every size solved (mm/s^2) and its mutual information.")
    .def_property_readonly("transform",
                           [](const BrainShiftRegistrationResult & result) {
                             return PythonTransform{ result.transform.GetPointer() };
                           },
                           "Backward map: intraoperative point -> preoperative point.")
    .def_readonly("fit_max_residual", &BrainShiftRegistrationResult::fitMaxResidual)
    .def_readonly("fit_rms_residual", &BrainShiftRegistrationResult::fitRmsResidual)
    .def_property_readonly("warped_image",
                           [](const BrainShiftRegistrationResult & result) { return PythonImage(result.warpedImage.GetPointer()); })
    .def_property_readonly("warped_label_maps",
                           [](const BrainShiftRegistrationResult & result) {
                             py::list images;
                             for (const auto & labels : result.warpedLabelMaps)
                               images.append(PythonImage(labels.GetPointer()));
                             return images;
                           })
    .def_property_readonly("unregistered_on_intraoperative_grid",
                           [](const BrainShiftRegistrationResult & result) {
                             return PythonImage(result.unregisteredOnIntraoperativeGrid.GetPointer());
                           })
    .def_property_readonly("registered_on_intraoperative_grid",
                           [](const BrainShiftRegistrationResult & result) {
                             return PythonImage(result.registeredOnIntraoperativeGrid.GetPointer());
                           })
    .def_property_readonly("evaluation_mask",
                           [](const BrainShiftRegistrationResult & result) { return PythonImage(result.evaluationMask.GetPointer()); })
    .def_readonly("unregistered", &BrainShiftRegistrationResult::unregistered)
    .def_readonly("registered", &BrainShiftRegistrationResult::registered)
    .def_property_readonly("evaluated", &BrainShiftRegistrationResult::Evaluated)
    .def_property_readonly("stage_seconds", [](const BrainShiftRegistrationResult & result) { return StageSeconds(result.timer); })
    .def_readonly("warnings", &BrainShiftRegistrationResult::warnings)
    .def("table", &FormatRegistrationTable, "The table `biomech register` prints.");

  module.def(
    "_register",
    [](const py::object & image, const py::object & brainMask, const py::object & tumourMask,
       const std::optional<ContactSurface> & skullSurface, const std::vector<py::object> & labelMaps,
       const py::object & surface, const py::object & points, const py::object & displacements,
       const py::object & intraoperativeImage, const py::object & intraoperativeMask, const py::dict & values,
       const std::optional<UncertaintySettings> & uncertainty, const py::object & progress) {
      const BrainShiftRegistrationSettings settings = RegistrationSettingsFrom(values);
      BrainShiftRegistrationInputs         inputs;
      inputs.preoperativeImage = ItkImage(image, "preoperative_image");
      inputs.brainMask = ItkLabelImage(brainMask, "brain_mask");
      inputs.tumourMask = ItkLabelImage(tumourMask, "tumour_mask");
      inputs.skullSurface = skullSurface.value_or(ContactSurface{});
      for (std::size_t k = 0; k < labelMaps.size(); ++k)
      {
        inputs.labelMaps.push_back(ItkLabelImage(labelMaps[k], "label_maps[" + std::to_string(k) + "]"));
      }
      inputs.intraoperative = IntraoperativeFrom(surface, points, displacements, intraoperativeImage,
                                                 intraoperativeMask, MaxDistanceFrom(values));
      if (uncertainty)
      {
        CheckUncertaintySettings(*uncertainty);
      }
      ProgressReporter                           reporter(progress);
      std::optional<BrainShiftUncertaintyResult> ensemble;
      auto result = RunWithoutGil(reporter, [&] {
        return TranslateItkErrors([&] {
          BrainModel prepared; // the ensemble's model before the loads
          auto       registered = RegisterBrainShift(inputs, settings, reporter.StageCallback(), reporter.SolverCallback(),
                                                     uncertainty ? &prepared : nullptr);
          if (uncertainty)
          {
            ensemble = EstimateUncertaintyAfter(
              registered, prepared, { inputs.preoperativeImage, inputs.labelMaps, inputs.intraoperative, {} }, settings,
              *uncertainty);
          }
          return registered;
        });
      });
      return ResultWithEnsemble(std::move(result), settings, uncertainty, ensemble);
    },
    py::arg("preoperative_image"), py::arg("brain_mask"), py::arg("tumour_mask"), py::arg("skull_surface"),
    py::arg("label_maps"), py::arg("intraoperative_surface"), py::arg("sparse_points"), py::arg("sparse_displacements"),
    py::arg("intraoperative_image"), py::arg("intraoperative_mask"), py::arg("settings"), py::arg("uncertainty"),
    py::arg("progress"));
}

// The clinical workflow: model bundles, prepare and update.
void
BindModelBundles(py::module_ & module)
{
  py::class_<ModelBundle>(module, "ModelBundle",
                          "A brain model prepared before surgery (biomech prepare): the model, its surfaces, the "
                          "preoperative image and label maps and the settings; write() makes the bundle folder.")
    .def_readonly("brain_model", &ModelBundle::model)
    .def_property_readonly("manifest", [](const ModelBundle & bundle) { return JsonToDict(bundle.manifest); })
    .def_property_readonly("preoperative_image",
                           [](const ModelBundle & bundle) { return PythonImage(bundle.preoperativeImage.GetPointer()); })
    .def(
      "write",
      [](ModelBundle & bundle, const std::filesystem::path & folder) {
        bundle.manifest = TranslateItkErrors([&] { return WriteModelBundle(folder, bundle); });
      },
      py::arg("folder"), "Writes the bundle folder (manifest, model, images, surfaces); replaces a bundle there.");
  module.def(
    "read_model_bundle",
    [](const std::filesystem::path & folder) { return TranslateItkErrors([&] { return ReadModelBundle(folder); }); },
    py::arg("folder"), "Reads a bundle folder that biomech prepare (or ModelBundle.write) made; checks its checksums.");

  module.def(
    "_prepare",
    [](const py::object & image, const py::object & brainMask, const py::object & tumourMask,
       const std::optional<ContactSurface> & skullSurface, const std::vector<py::object> & labelMaps,
       const py::dict & values, const py::object & progress) {
      ModelBundle bundle;
      bundle.settings = RegistrationSettingsFrom(values);
      bundle.preoperativeImage = ItkImage(image, "image");
      const auto mask = ItkLabelImage(brainMask, "brain_mask");
      const auto tumour = ItkLabelImage(tumourMask, "tumour_mask");
      for (std::size_t k = 0; k < labelMaps.size(); ++k)
      {
        bundle.labelMaps.push_back(ItkLabelImage(labelMaps[k], "label_maps[" + std::to_string(k) + "]"));
        bundle.labelMapNames.push_back("labels-" + std::to_string(k) + ".nii.gz");
      }
      ProgressReporter reporter(progress);
      return RunWithoutGil(reporter, [&] {
        StageTimer timer(reporter.StageCallback());
        TranslateItkErrors([&] {
          CheckCraniotomyChoice(bundle.settings.model.craniotomyRadius, bundle.settings.model.craniotomyMask.IsNotNull());
          bundle.model = PrepareBrainModel(bundle.preoperativeImage, mask, tumour, skullSurface.value_or(ContactSurface{}),
                                           bundle.settings.model, timer, true);
          PrecomputeBrainModel(bundle.model, bundle.settings, timer);
        });
        bundle.manifest["prepare"] = { { "seconds", timer.Json() } };
        return bundle;
      });
    },
    py::arg("image"), py::arg("brain_mask"), py::arg("tumour_mask"), py::arg("skull_surface"), py::arg("label_maps"),
    py::arg("settings"), py::arg("progress"));

  module.def(
    "_update",
    [](const ModelBundle & bundle, const py::object & surface, const py::object & points,
       const py::object & displacements, const py::object & intraoperativeImage, const py::object & intraoperativeMask,
       const py::object & previous, const py::dict & values, const std::optional<UncertaintySettings> & uncertainty,
       const py::object & progress) {
      const BrainShiftRegistrationSettings settings = RegistrationSettingsFrom(values, bundle.settings);
      if (uncertainty)
      {
        CheckUncertaintySettings(*uncertainty);
      }
      BrainShiftUpdateInputs               inputs;
      inputs.preoperativeImage = bundle.preoperativeImage;
      inputs.labelMaps.assign(bundle.labelMaps.begin(), bundle.labelMaps.end());
      inputs.intraoperative = IntraoperativeFrom(surface, points, displacements, intraoperativeImage,
                                                 intraoperativeMask, MaxDistanceFrom(values));
      // An earlier update's result in memory, or its output folder (solution.bin).
      if (py::isinstance<BrainShiftRegistrationResult>(previous))
      {
        inputs.previous = WarmStartFrom(previous.cast<const BrainShiftRegistrationResult &>().solve);
      }
      else if (!previous.is_none())
      {
        inputs.previous = ReadUpdateSolution(py::str(previous).cast<std::string>(), bundle.manifest).start;
      }
      ProgressReporter                           reporter(progress);
      std::optional<BrainShiftUncertaintyResult> ensemble;
      auto result = RunWithoutGil(reporter, [&] {
        return TranslateItkErrors([&] {
          auto update = UpdateBrainShift(bundle.model, inputs, settings, reporter.StageCallback(), reporter.SolverCallback());
          if (uncertainty)
          {
            ensemble = EstimateUncertaintyAfter(update, bundle.model, inputs, settings, *uncertainty);
          }
          return update;
        });
      });
      return ResultWithEnsemble(std::move(result), settings, uncertainty, ensemble);
    },
    py::arg("bundle"), py::arg("intraoperative_surface"), py::arg("sparse_points"), py::arg("sparse_displacements"),
    py::arg("intraoperative_image"), py::arg("intraoperative_mask"), py::arg("previous"), py::arg("settings"),
    py::arg("uncertainty"), py::arg("progress"));
}

void
BindRegistration(py::module_ & module)
{
  BindBrainModel(module);
  BindRegistrationResult(module);
  BindModelBundles(module);
}

} // namespace

void
BindImages(py::module_ & module)
{
  BindFilesAndTransforms(module);
  BindFilters(module);
  BindRegistration(module);
  BindSyntheticScenes(module);
}

} // namespace bmr::python
