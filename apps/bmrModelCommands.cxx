// The model commands of `biomech`: model, register and the single steps
// (classify, mask, grid, surfaces, loads). Over 800 lines on purpose: they
// share the option groups below, and another translation unit would compile
// these ITK headers once more in every build (slow on 2 cores).
#include "bmrModelCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBSplineTransform.h"
#include "itkBiomechanicalTransformIO.h"
#include "itkImageFileWriter.h"
#include "itkBiomechanicalImageConversion.h"

#include "bmrCommandSupport.h"
#include "bmrUncertaintyOptions.h"

#include "bmrBrainShiftUncertainty.h"
#include "bmrBrainSurfaces.h"
#include "bmrFuzzyCMeans.h"
#include "bmrImageGrids.h"
#include "bmrMaterialMapping.h"
#include "bmrMeshIO.h"
#include "bmrModelBundle.h"
#include "bmrScene.h"
#include "bmrSurfaceLoads.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <iostream>
#include <map>
#include <optional>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bmr
{
namespace app
{
namespace
{

using ImageType = itk::Image<float, 3>;
using MaskImageType = itk::Image<unsigned char, 3>;
using MembershipImageType = itk::VectorImage<float, 3>;

/** A mask file as a core volume (voxels > 0 inside); must lie on `grid` when given. */
LabelVolume
ReadMaskVolume(const std::string & path, const std::string & what, const ImageGeometry * grid)
{
  return MaskVolume(ReadMaskImage(path, what), what + " '" + path + "'", grid);
}

MembershipImageType::Pointer
MakeMembershipImage(const ScalarVolume & memberships)
{
  auto image = MembershipImageType::New();
  itk::ApplyBiomechanicalGeometry(memberships.geometry, image.GetPointer());
  image->SetNumberOfComponentsPerPixel(static_cast<unsigned int>(memberships.components));
  image->Allocate();
  std::copy(memberships.values.begin(), memberships.values.end(), image->GetBufferPointer());
  return image;
}

Vector3
ThreeValues(const std::vector<double> & values, const std::string & option)
{
  if (values.size() != 3)
  {
    throw Error(option + " needs 3 values (mm)");
  }
  return Vector3(values[0], values[1], values[2]);
}

/** "class 1 of 3 (t1 contrast), 183.256 mL": the summaries' line of the class that became the CSF. */
std::string
CsfClassText(const BrainModel & brain)
{
  std::ostringstream text;
  text << "class " << brain.csfClass.csfClass + 1 << " of " << brain.classificationFit.centroids.size() << " ("
       << TissueContrastName(brain.csfClass.contrast) << " contrast), " << brain.csfVolume / 1000.0 << " mL";
  return text.str();
}

void
PrintWarnings(const std::vector<std::string> & warnings)
{
  for (const std::string & warning : warnings)
  {
    std::cerr << "biomech: warning: " << warning << "\n";
  }
}

// ---------------------------------------------------------------------------
// Options shared by the subcommands.
// ---------------------------------------------------------------------------

struct RegionOptions
{
  std::vector<double> craniotomyCentre;
  double              craniotomyRadius = 0.0;
  std::string         craniotomyMask;

  void Add(CLI::App * command)
  {
    command->add_option("--craniotomy-centre", craniotomyCentre, "Centre X Y Z of the craniotomy (mm, physical space)")
      ->expected(3);
    command->add_option("--craniotomy-radius", craniotomyRadius, "Radius of the craniotomy (mm)");
    command->add_option("--craniotomy-mask", craniotomyMask, "Mask of the craniotomy region (instead of a sphere)");
  }

  bool HasCraniotomy() const { return !craniotomyCentre.empty() || !craniotomyMask.empty(); }

  /** The exposed surface nodes of the craniotomy (bmr::ExposedSurfaceNodes checks the region). */
  std::vector<Index> ExposedNodes(const Model & model, const std::vector<Index> & surface) const
  {
    LabelVolume      mask;
    CraniotomyRegion region = Sphere();
    if (!craniotomyMask.empty())
    {
      mask = ReadMaskVolume(craniotomyMask, "craniotomy mask", nullptr);
      region.mask = &mask;
    }
    return ExposedSurfaceNodes(model, surface, region);
  }

  /** The craniotomy of the one-call model builder (which checks the region). */
  void Apply(BrainModelSettings & settings) const
  {
    const CraniotomyRegion sphere = Sphere();
    settings.craniotomyCentre = sphere.centre;
    settings.craniotomyRadius = sphere.radius;
    if (!craniotomyMask.empty())
    {
      settings.craniotomyMask = ReadMaskImage(craniotomyMask, "craniotomy mask");
    }
  }

private:
  /** The sphere of --craniotomy-centre and --craniotomy-radius (radius 0 when no centre is given). */
  CraniotomyRegion Sphere() const
  {
    CraniotomyRegion region;
    if (!craniotomyCentre.empty())
    {
      if (!(craniotomyRadius > 0.0))
      {
        throw Error("--craniotomy-centre needs --craniotomy-radius > 0 (mm)");
      }
      region.centre = ThreeValues(craniotomyCentre, "--craniotomy-centre");
      region.radius = craniotomyRadius;
    }
    return region;
  }
};

struct MeasurementOptions
{
  std::string intraoperativeSurface;
  std::string sparseDisplacements;
  double      maxDistance = SurfaceLoadSettings{}.maxDistance;
  std::vector<double> matchAlong;

  std::optional<Vector3> MatchDirection() const
  {
    return matchAlong.empty() ? std::nullopt : std::optional<Vector3>(Vector3(matchAlong[0], matchAlong[1], matchAlong[2]));
  }

  void Add(CLI::App * command)
  {
    command->add_option("--match-along", matchAlong,
                        "Match the displaced surface (or the image's) along this direction X Y Z, e.g. gravity's, "
                        "instead of by closest points (register, model)")
      ->expected(3);
    command->add_option("--intraoperative-surface", intraoperativeSurface,
                        "Displaced exposed surface (.stl, .obj, .vtp, .vtk): closest-point correspondence");
    command->add_option("--sparse-displacements", sparseDisplacements,
                        "CSV with header x,y,z,ux,uy,uz (mm): displacements at points, interpolated over the exposed surface");
    command->add_option("--max-distance", maxDistance,
                        "Measurements farther than this from the model surface are rejected with a warning (mm)")
      ->capture_default_str();
  }

  bool Given() const { return !intraoperativeSurface.empty() || !sparseDisplacements.empty(); }

  /** The measurements for the one-call model builder; empty when none was given. */
  std::optional<IntraoperativeData> Data() const
  {
    if (!Given())
    {
      return std::nullopt;
    }
    if (!intraoperativeSurface.empty() && !sparseDisplacements.empty())
    {
      throw Error("give either --intraoperative-surface or --sparse-displacements, not both");
    }
    IntraoperativeData data;
    data.maxDistance = maxDistance;
    data.surfaceMatchDirection = MatchDirection();
    if (!intraoperativeSurface.empty())
    {
      data.surface = ReadSurface(intraoperativeSurface);
    }
    else
    {
      data.sparse = ReadSparseDisplacements(sparseDisplacements);
    }
    return data;
  }

  /** `modelSurface`: the body's surface for a point cloud (no cells); null for a mesh. */
  PrescribedDisplacement Displacements(const Model & model, const std::vector<Index> & exposed, LoadReport & report,
                                       const ContactSurface * modelSurface = nullptr) const
  {
    if (!intraoperativeSurface.empty() && !sparseDisplacements.empty())
    {
      throw Error("give either --intraoperative-surface or --sparse-displacements, not both");
    }
    SurfaceLoadSettings settings;
    settings.maxDistance = maxDistance;
    if (!intraoperativeSurface.empty())
    {
      return DisplacementsFromSurface(model, exposed, ReadSurface(intraoperativeSurface), settings, &report);
    }
    const SparseDisplacements sparse = ReadSparseDisplacements(sparseDisplacements);
    return DisplacementsFromSparsePoints(model, exposed, sparse.points, sparse.displacements, settings, &report,
                                         modelSurface);
  }
};

json
LoadReportJson(const LoadReport & report)
{
  return json{ { "used", report.usedPoints },
               { "rejected", report.rejectedPoints },
               { "max_correspondence_distance_mm", report.maxCorrespondenceDistance },
               { "rms_correspondence_distance_mm", report.rmsCorrespondenceDistance },
               { "warnings", report.warnings } };
}

std::string
DisplacementCsv(const PrescribedDisplacement & load)
{
  std::ostringstream text;
  text << std::setprecision(10) << "id,ux,uy,uz\n";
  for (std::size_t k = 0; k < load.nodes.size(); ++k)
  {
    const Vector3 & u = load.displacements[k];
    text << load.nodes[k] << "," << u.x() << "," << u.y() << "," << u.z() << "\n";
  }
  return text.str();
}

// ---------------------------------------------------------------------------
// The model pipeline: MRI (+ mask, tumour, craniotomy, measurements) -> scene.
// ---------------------------------------------------------------------------

/** Rows of the registration's settings table (bmr::RegistrationSettingFields)
 *  as options: --name-with-dashes, and --no-name for a flag whose default is
 *  true. The same names as Python's keywords and docs/registration.md. */
struct SettingOptions
{
  std::vector<std::string>            groups; // every row of these groups
  std::vector<std::string>            names;  // and these rows
  std::map<std::string, std::string>  values;
  std::map<std::string, bool>         flags;
  std::map<std::string, CLI::Option *> options;

  void Add(CLI::App * command)
  {
    const BrainShiftRegistrationSettings defaults;
    for (const RegistrationSettingField & row : RegistrationSettingFields())
    {
      if (std::find(groups.begin(), groups.end(), row.group) == groups.end() &&
          std::find(names.begin(), names.end(), row.name) == names.end())
      {
        continue;
      }
      std::string help = row.meaning + (row.unit.empty() ? "" : " (" + row.unit + ")");
      if (row.kind == SettingFieldBase::Kind::Flag)
      {
        const bool onByDefault = row.get(defaults) != 0.0;
        if (!onByDefault)
        {
          help[0] = static_cast<char>(std::toupper(static_cast<unsigned char>(help[0])));
        }
        options[row.name] = command->add_flag(onByDefault ? "--no-" + row.OptionName().substr(2) : row.OptionName(),
                                              flags[row.name], onByDefault ? "Turn off " + help : help);
        continue;
      }
      help[0] = static_cast<char>(std::toupper(static_cast<unsigned char>(help[0])));
      const char * type = row.kind == SettingFieldBase::Kind::Number    ? "FLOAT"
                          : row.kind == SettingFieldBase::Kind::Integer ? "INT"
                          : row.kind == SettingFieldBase::Kind::Choice  ? "CHOICE"
                                                                        : "TEXT";
      if (row.kind == SettingFieldBase::Kind::Choice)
      {
        help += ": " + row.Range();
      }
      options[row.name] =
        command->add_option(row.OptionName(), values[row.name], help)->type_name(type)->default_str(row.Text(defaults));
    }
  }

  /** The defaults with the given options set. */
  BrainShiftRegistrationSettings Resolved() const
  {
    BrainShiftRegistrationSettings settings;
    Apply(settings);
    return settings;
  }

  /** The given options set into `settings`; a bad value names its option. */
  void Apply(BrainShiftRegistrationSettings & settings) const
  {
    const BrainShiftRegistrationSettings defaults;
    for (const RegistrationSettingField & row : RegistrationSettingFields())
    {
      const auto option = options.find(row.name);
      if (option == options.end() || option->second->count() == 0)
      {
        continue;
      }
      try
      {
        if (row.kind == SettingFieldBase::Kind::Flag)
        {
          row.set(settings, row.get(defaults) != 0.0 ? 0.0 : 1.0);
        }
        else
        {
          row.SetText(settings, values.at(row.name));
        }
      }
      catch (const Error & error)
      {
        throw Error(option->second->get_name() + ": " + error.what());
      }
    }
  }
};


/** The preoperative side of a patient model, shared by `model` and `register`:
 *  the image and its masks, and every setting of bmr::BuildBrainModel. */
struct PatientModelOptions
{
  std::string         image;
  std::string         series;
  std::string         mask;
  std::string         tumourMask;
  std::string         resectionMask;
  std::string         skullSurface;
  SettingOptions      settings{ { "model" } };
  RegionOptions       regions;
  std::vector<double> gravity;
  double              csfDrainedDepth = 0.0;
  CLI::Option *       csfDrainedDepthOption = nullptr;

  /** `bodyLoads`: also --gravity and --csf-drained-depth (not `prepare`'s: they are the update's). */
  void Add(CLI::App * command, bool bodyLoads = true)
  {
    command->add_option("image", image,
                        "Preoperative MRI (.nii.gz, .nrrd, .mha, ..., or a DICOM series: its folder or one of its files)")
      ->required();
    command->add_option("--series", series,
                        "DICOM Series Instance UID of the preoperative image, when its folder holds several series "
                        "(default: the file's own series, else the one with most slices)");
    command->add_option("--mask", mask, "Brain mask on the image grid (voxels > 0); default: atlas skull stripping");
    command->add_option("--tumour-mask", tumourMask, "Tumour mask on the image grid (voxels > 0)");
    command->add_option("--resection-mask", resectionMask,
                        "Tissue removed by the surgery, e.g. the planned resection, on the image grid (voxels > 0): "
                        "fluid (the CSF class's material) fills it, so that the cavity's walls can sag");
    command->add_option("--skull-surface", skullSurface,
                        "Rigid skull surface (.stl, .obj, .vtp, .vtk) to use instead of the body dilated by --skull-gap");
    settings.Add(command);
    regions.Add(command);
    if (!bodyLoads)
    {
      return;
    }
    CLI::Option * gravityOption =
      command->add_option("--gravity", gravity, "Body acceleration X Y Z (mm/s^2), e.g. 0 0 -9810")->expected(3);
    csfDrainedDepthOption =
      command
        ->add_option("--csf-drained-depth", csfDrainedDepth,
                     "CSF drained to this depth (mm) below the brain's top along gravity: only the tissue above "
                     "the CSF's surface carries its weight (default: all of it)")
        ->check(CLI::NonNegativeNumber)
        ->needs(gravityOption);
  }

  /** The table's settings (the model's rows) and the craniotomy, gravity and CSF drainage. */
  BrainShiftRegistrationSettings RegistrationSettings() const
  {
    BrainShiftRegistrationSettings registration;
    settings.Apply(registration);
    BrainModelSettings & model = registration.model;
    regions.Apply(model);
    if (!gravity.empty())
    {
      model.gravity = ThreeValues(gravity, "--gravity");
    }
    if (csfDrainedDepthOption != nullptr && csfDrainedDepthOption->count() > 0)
    {
      model.csfDrainedDepth = csfDrainedDepth;
    }
    if (!resectionMask.empty())
    {
      model.resectionMask = ReadMaskImage(resectionMask, "resection mask");
    }
    return registration;
  }

  /** The settings of bmr::BuildBrainModel (reads the craniotomy and resection masks when they are given). */
  BrainModelSettings Settings() const { return RegistrationSettings().model; }

  /** The image, and the masks and skull surface that were given (null or empty otherwise). */
  struct Inputs
  {
    ImageType::Pointer     image;
    MaskImageType::Pointer brainMask;
    MaskImageType::Pointer tumourMask;
    ContactSurface         skullSurface;
  };

  Inputs Read() const
  {
    Inputs inputs;
    inputs.image = ReadImage<ImageType>(image, "preoperative image", series);
    if (!mask.empty())
    {
      inputs.brainMask = ReadMaskImage(mask, "brain mask");
    }
    if (!tumourMask.empty())
    {
      inputs.tumourMask = ReadMaskImage(tumourMask, "tumour mask");
    }
    if (!skullSurface.empty())
    {
      inputs.skullSurface = ReadSurface(skullSurface);
    }
    return inputs;
  }
};

struct ModelOptions
{
  PatientModelOptions patient;
  MeasurementOptions  measurements;
  std::string         outputDirectory = "model";
  bool                quiet = false;
};

// The scene `biomech solve` runs on the model's folder.
json
ModelScene(const BrainModel & brain, const BrainModelSettings & settings, const std::string & image)
{
  const Model &                  model = brain.model;
  const PrescribedDisplacement & load = brain.load;
  const std::vector<Index> &     exposed = brain.exposedNodes;
  const bool meshless = model.discretization == Discretization::Meshless;
  json       scene;
  std::ostringstream description;
  description << "Brain model of " << fs::path(image).filename().string() << " made by biomech model ("
              << ImageGridKindName(settings.grid.kind) << ", " << settings.grid.elementSize << " mm)";
  scene["description"] = description.str();
  scene["mesh"] = "model.vtu";
  if (meshless)
  {
    // A point cloud: each integration point carries its material.
    scene["discretization"] = "meshless";
    // The shape functions the grid's coverage was checked with.
    const MlsSettings & shapeFunctions = model.meshless.shapeFunctions;
    scene["meshless"] = { { "integration_points", "integration-points.vtu" },
                          { "dilatation", shapeFunctions.dilatation },
                          { "basis", shapeFunctions.basis == MlsBasis::Linear ? "linear" : "modified_quadratic" } };
  }
  else
  {
    scene["material_fields"] = { { "youngs_modulus", "youngs_modulus" },
                                 { "poisson_ratio", "poisson_ratio" },
                                 { "density", "density" } };
  }
  scene["node_sets"] = { { "skull_base", { { "point_data", "skull_base" } } } };
  scene["fixed"] = json::array({ { { "node_set", "skull_base" } } });
  if (!exposed.empty())
  {
    scene["node_sets"]["exposed"] = { { "point_data", "exposed" } };
  }
  if (!load.nodes.empty())
  {
    scene["prescribed_displacements"] = json::array({ { { "csv", "exposed-displacements.csv" } } });
  }
  if (!settings.gravity.isZero())
  {
    scene["gravity"] = { settings.gravity.x(), settings.gravity.y(), settings.gravity.z() };
  }
  if (model.fluidSurface)
  {
    scene["fluid_surface"] = { model.fluidSurface->x(), model.fluidSurface->y(), model.fluidSurface->z() };
  }
  if (!model.contactSurfaces.empty())
  {
    scene["node_sets"]["contact"] = { { "point_data", "contact" } };
    scene["contact"] = json::array(
      { { { "surface", "skull.vtp" }, { "name", "skull" }, { "body_side", "inside" }, { "slave_node_set", "contact" } } });
  }
  // 0.01 mm, as the brain-sized examples: far below the 0.1 mm a registration needs, and
  // reached by CGAL tetrahedra (slivers, soft CSF) that stall near 0.001 mm with contact.
  scene["solver"] = { { "integrator", "dynamic_relaxation" }, { "tolerance", 0.01 } };
  scene["output"] = { { "vtu", "brain-result.vtu" }, { "report", "brain-report.json" } };
  return scene;
}

int
RunModel(const ModelOptions & options)
{
  const fs::path outputDirectory(options.outputDirectory);
  StepTimer      timer(!options.quiet);
  json           report;
  const PatientModelOptions & patient = options.patient;
  const BrainModelSettings    settings = patient.Settings();
  report["image"] = patient.image;
  report["mask"] = patient.mask.empty() ? "atlas: " + settings.atlas.image : patient.mask;
  if (!patient.skullSurface.empty())
  {
    report["skull_surface"] = patient.skullSurface;
  }

  // Everything is computed before anything is written, so a failure leaves no partial model.
  const PatientModelOptions::Inputs inputs = timer.Run("read", [&] { return patient.Read(); });
  if (options.measurements.Given() && !patient.regions.HasCraniotomy())
  {
    throw Error("intraoperative measurements need the craniotomy region they belong to: give --craniotomy-centre "
                "and --craniotomy-radius, or --craniotomy-mask");
  }
  const std::optional<IntraoperativeData> measurements = options.measurements.Data();
  const BrainModel brain = BuildBrainModel(inputs.image, inputs.brainMask, inputs.tumourMask, inputs.skullSurface,
                                           measurements ? &*measurements : nullptr, settings, timer);
  const Model &                  model = brain.model;
  const std::vector<Index> &     exposed = brain.exposedNodes;
  const PrescribedDisplacement & load = brain.load;
  const BrainSurfaces &          surfaces = brain.surfaces;
  const std::vector<Index> &     surfaceNodes = model.NodeSet("surface");
  std::vector<std::string>       warnings = brain.warnings;
  report["classification"] = { { "classes", settings.classifier.classes },
                               { "centroids", brain.classificationFit.centroids },
                               { "iterations", brain.classificationFit.iterations },
                               { "converged", brain.classificationFit.converged } };
  if (measurements)
  {
    report["loads"] = LoadReportJson(brain.loadReport);
  }

  const json scene = ModelScene(brain, settings, patient.image);

  const ModelCounts counts = CountModel(model);
  report["grid"] = { { "kind", ImageGridKindName(settings.grid.kind) },
                     { "element_size_mm", settings.grid.elementSize },
                     { "nodes", counts.nodes },
                     { "cells", counts.cells },
                     { "dofs", counts.dofs },
                     { "integration_points", counts.integrationPoints },
                     { "volume_error", brain.gridQuality.volumeError },
                     { "min_scaled_jacobian", brain.gridQuality.minScaledJacobian },
                     { "min_dihedral_angle_deg", brain.gridQuality.minDihedralAngleDeg } };
  report["regions"] = { { "surface_nodes", surfaceNodes.size() },
                        { "exposed_nodes", exposed.size() },
                        { "skull_base_nodes", model.NodeSet("skull_base").size() } };
  report["skull_gap_mm"] = settings.skullGap;
  const Material csf = CsfClassMaterial(settings.materials);
  report["csf"] = { { "youngs_modulus_pa", csf.youngsModulus }, { "poisson_ratio", csf.poissonRatio } };
  report["csf"].update(CsfClassJson(brain));
  if (settings.csfDrainedDepth)
  {
    report["csf"]["drained_depth_mm"] = *settings.csfDrainedDepth;
  }
  if (settings.resectionMask.IsNotNull())
  {
    report["resected_volume_mm3"] = brain.resectedVolume;
  }
  report["warnings"] = warnings;

  timer.Run("write", [&] {
    CreateFolder(outputDirectory);
    // An earlier run's scene must not pass for this run's while its files are replaced.
    std::error_code ignored;
    fs::remove(outputDirectory / "scene.json", ignored);
    fs::remove(outputDirectory / "model-report.json", ignored);
    WriteMesh((outputDirectory / "model.vtu").string(), model);
    if (model.discretization == Discretization::Meshless)
    {
      WriteIntegrationPoints((outputDirectory / "integration-points.vtu").string(), model);
    }
    WriteSurface((outputDirectory / "brain-surface.vtp").string(), surfaces.brain);
    WriteSurface((outputDirectory / "skull.vtp").string(), surfaces.skull);
    if (!load.nodes.empty())
    {
      WriteTextFileAtomically((outputDirectory / "exposed-displacements.csv").string(), DisplacementCsv(load));
    }
    WriteImageAtomically(brain.membershipImage.GetPointer(), outputDirectory / "memberships.nii.gz");
    WriteImageAtomically(brain.tissueLabelImage.GetPointer(), outputDirectory / "tissue-labels.nii.gz");
    if (patient.mask.empty())
    {
      WriteImageAtomically(itk::MakeImageFromBiomechanicalVolume<MaskImageType>(brain.brainMask).GetPointer(),
                           outputDirectory / "brain-mask.nii.gz");
    }
    // Last: a folder whose writing failed part way has no scene to run.
    WriteTextFileAtomically((outputDirectory / "scene.json").string(), scene.dump(2) + "\n");
  });
  report["seconds"] = timer.Json();
  WriteTextFileAtomically((outputDirectory / "model-report.json").string(), report.dump(2) + "\n");

  PrintWarnings(warnings);
  if (!options.quiet)
  {
    std::cout << "model of " << patient.image << "\n"
              << "  grid              " << ImageGridKindName(settings.grid.kind) << ", " << counts.nodes
              << " nodes, " << counts.cells << " cells, " << counts.dofs << " DOF";
    if (counts.integrationPoints > 0)
    {
      std::cout << ", " << counts.integrationPoints << " integration points";
    }
    std::cout << "\n  volume error      " << 100.0 * brain.gridQuality.volumeError << " % of the mask\n"
              << "  exposed nodes     " << exposed.size() << ", fixed " << model.NodeSet("skull_base").size() << "\n"
              << "  CSF               " << CsfClassText(brain) << "\n"
              << "  time              " << report["seconds"]["total"].get<double>() << " s\n"
              << "  scene             " << (outputDirectory / "scene.json").string() << "\n";
  }
  return 0;
}

// ---------------------------------------------------------------------------
// The registration: model, solve, transform, warp, evaluation in one call.
// ---------------------------------------------------------------------------

/** The intraoperative data of `register` and `update`: measurements and an intraoperative image. */
struct IntraoperativeOptions
{
  MeasurementOptions measurements;
  std::string        image;
  std::string        series;
  std::string        mask;

  void Add(CLI::App * command)
  {
    measurements.Add(command);
    command->add_option("--intraoperative-image", image,
                        "Intraoperative image (a file, or a DICOM series' folder or file): evaluation (edge-based "
                        "Hausdorff), the gravity fit (--gravity-fit-candidates), and the exposed surface when no "
                        "surface or sparse displacements are given");
    command->add_option("--intraoperative-series", series,
                        "DICOM Series Instance UID of the intraoperative image, when its folder holds several");
    command->add_option("--intraoperative-mask", mask,
                        "Brain mask of the intraoperative image (default: atlas skull stripping when its "
                        "surface is needed; the registered preoperative mask for the evaluation)");
  }

  IntraoperativeData Read() const
  {
    IntraoperativeData data;
    if (const auto measured = measurements.Data())
    {
      data = *measured;
    }
    data.maxDistance = measurements.maxDistance;
    data.surfaceMatchDirection = measurements.MatchDirection();
    if (!image.empty())
    {
      data.image = ReadImage<ImageType>(image, "intraoperative image", series);
    }
    if (!mask.empty())
    {
      if (image.empty())
      {
        throw Error("--intraoperative-mask belongs to --intraoperative-image; give the image as well");
      }
      data.imageBrainMask = ReadMaskImage(mask, "intraoperative brain mask");
    }
    return data;
  }
};

struct RegisterOptions
{
  PatientModelOptions            patient;
  IntraoperativeOptions          intraoperative;
  std::vector<std::string>       labelMaps;
  std::string                    outputDirectory = "registration";
  SettingOptions                 settings{ { "solve", "fit", "evaluation" } };
  int                            overlays = 5;
  bool                           quiet = false;
  UncertaintyOptions             uncertainty;
};

/** "labels.nii.gz" -> "labels-warped.nii.gz". */
std::string
WarpedName(const std::string & path)
{
  std::string name = fs::path(path).filename().string();
  for (const char * extension : { ".nii.gz", ".nii", ".nrrd", ".mha", ".mhd" })
  {
    const std::string suffix(extension);
    if (name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0)
    {
      return name.substr(0, name.size() - suffix.size()) + "-warped.nii.gz";
    }
  }
  return name + "-warped.nii.gz";
}

/** Writes a registration's outputs into `outputDirectory` (the warped
 *  image and label maps, the transform, the model's result, with an
 *  intraoperative image its evaluation and overlays) and the report last, so
 *  that a folder without the report holds no finished result; prints the
 *  table. `report` holds what the caller adds, `moreSeconds` stages timed
 *  outside the registration ("seconds" gains them and "write"), `writeMore`
 *  writes the caller's files (adding them to "files"). Returns the
 *  exit status: 0 converged, 2 not converged. */
int
WriteRegistrationOutputs(const BrainShiftRegistrationResult & result, const BrainShiftRegistrationSettings & settings,
                         const fs::path & outputDirectory, const std::vector<std::string> & labelNames,
                         const RegistrationImage * intraoperative, int overlays, bool quiet, json report,
                         const json &                                                 moreSeconds = json::object(),
                         const std::function<void(const fs::path & folder, json & files)> & writeMore = {})
{
  const auto     written = std::chrono::steady_clock::now();
  const fs::path reportPath = outputDirectory / "registration-report.json";
  CreateFolder(outputDirectory);
  std::error_code ignored;
  fs::remove(reportPath, ignored);
  report.update(RegistrationReportJson(result, settings));
  json files = json::object();
  const auto write = [&](const std::string & key, const fs::path & path, const auto & writeFile) {
    writeFile(path);
    files[key] = path.string();
  };
  write("warped_image", outputDirectory / "warped.nii.gz",
        [&](const fs::path & path) { WriteImageAtomically(result.warpedImage.GetPointer(), path); });
  write("transform", outputDirectory / "transform.h5",
        [&](const fs::path & path) { itk::WriteBiomechanicalTransform(result.transform, path.string()); });
  write("model_result", outputDirectory / "model-result.vtu",
        [&](const fs::path & path) { WriteResultVtu(path.string(), result.model.model, result.solve); });
  for (std::size_t k = 0; k < result.warpedLabelMaps.size(); ++k)
  {
    write("warped_labels_" + std::to_string(k), outputDirectory / WarpedName(labelNames.at(k)),
          [&](const fs::path & path) { WriteImageAtomically(result.warpedLabelMaps[k].GetPointer(), path); });
  }
  if (result.Evaluated())
  {
    write("registered_on_intraoperative_grid", outputDirectory / "registered-on-intraoperative-grid.nii.gz",
          [&](const fs::path & path) { WriteImageAtomically(result.registeredOnIntraoperativeGrid.GetPointer(), path); });
    files["overlays"] = {
      { "unregistered", WriteEdgeOverlays(result.unregistered, intraoperative, (outputDirectory / "overlays").string(),
                                          "unregistered", overlays) },
      { "registered", WriteEdgeOverlays(result.registered, intraoperative, (outputDirectory / "overlays").string(),
                                        "registered", overlays) }
    };
  }
  if (writeMore)
  {
    writeMore(outputDirectory, files);
  }
  report["files"] = files;
  report["seconds"].update(moreSeconds);
  report["seconds"]["write"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - written).count();
  WriteTextFileAtomically(reportPath.string(), report.dump(2) + "\n");

  PrintWarnings(result.warnings);
  if (!quiet)
  {
    std::cout << FormatRegistrationTable(result) << "  output            " << outputDirectory.string() << "\n";
  }
  if (!result.solve.converged)
  {
    std::cerr << "biomech: the solve did NOT converge (" << result.solve.message
              << "); results written, the report says converged: false\n";
    return 2;
  }
  return 0;
}

/** Stage lines on a terminal and the solver's progress, for `register` and `update`. */
struct RegistrationProgress
{
  explicit RegistrationProgress(bool terminal)
    : terminal(terminal)
    , progress(terminal)
  {}

  StageCallback Stages()
  {
    if (!terminal)
    {
      return {};
    }
    return [this](const std::string & stage, double seconds) {
      progress.Clear();
      StepTimer::PrintStage(stage, seconds);
    };
  }
  ProgressCallback Steps()
  {
    return [this](int step, double fraction, double estimatedError) { progress.Update(step, fraction, estimatedError); };
  }

  bool             terminal;
  TerminalProgress progress;
};

int
RunRegister(const RegisterOptions & options)
{
  const PatientModelOptions::Inputs patient = options.patient.Read();
  BrainShiftRegistrationInputs      inputs;
  inputs.preoperativeImage = patient.image;
  inputs.brainMask = patient.brainMask;
  inputs.tumourMask = patient.tumourMask;
  inputs.skullSurface = patient.skullSurface;
  for (const std::string & path : options.labelMaps)
  {
    inputs.labelMaps.push_back(ReadImage<MaskImageType>(path, "label map"));
  }
  if (!options.patient.regions.HasCraniotomy())
  {
    throw Error("give the craniotomy: --craniotomy-centre X Y Z with --craniotomy-radius R, or --craniotomy-mask");
  }
  inputs.intraoperative = options.intraoperative.Read();

  BrainShiftRegistrationSettings settings = options.patient.RegistrationSettings();
  options.settings.Apply(settings);
  const UncertaintySettings uncertainty = options.uncertainty.Checked();

  BrainShiftRegistrationResult               result;
  std::optional<BrainShiftUncertaintyResult> ensemble;
  {
    RegistrationProgress progress(!options.quiet && ::isatty(STDERR_FILENO) != 0);
    BrainModel           prepared;
    result = RegisterBrainShift(inputs, settings, progress.Stages(), progress.Steps(),
                                uncertainty.members > 0 ? &prepared : nullptr);
    if (uncertainty.members > 0)
    {
      const BrainShiftUpdateInputs update{ inputs.preoperativeImage, inputs.labelMaps, inputs.intraoperative };
      ensemble = RunEnsemble(prepared, result, update, settings, uncertainty, options.labelMaps);
    }
  }
  json report = { { "preoperative_image", options.patient.image } };
  if (ensemble)
  {
    report["uncertainty"] = UncertaintyReportJson(*ensemble, uncertainty);
  }
  return WriteRegistrationOutputs(result, settings, options.outputDirectory, options.labelMaps,
                                  inputs.intraoperative.image, options.overlays, options.quiet, report, json::object(),
                                  [&](const fs::path & folder, json & files) {
                                    if (ensemble)
                                    {
                                      WriteEnsemble(*ensemble, inputs.preoperativeImage, folder, files);
                                    }
                                  });
}

// ---------------------------------------------------------------------------
// The two phases: `prepare` before surgery, `update` during it.
// ---------------------------------------------------------------------------

struct PrepareOptions
{
  PatientModelOptions      patient;
  std::vector<std::string> labelMaps;
  /** The solve's, fit's and evaluation's settings, stored as the updates' defaults. */
  SettingOptions           settings{ { "solve", "fit", "evaluation" } };
  std::string              output;
  bool                     quiet = false;
};

int
RunPrepare(const PrepareOptions & options)
{
  const auto                        started = std::chrono::steady_clock::now();
  const PatientModelOptions::Inputs patient = options.patient.Read();
  if (!options.patient.regions.HasCraniotomy())
  {
    throw Error("give the planned craniotomy: --craniotomy-centre X Y Z with --craniotomy-radius R, or "
                "--craniotomy-mask");
  }
  ModelBundle bundle;
  bundle.settings = options.patient.RegistrationSettings();
  options.settings.Apply(bundle.settings);
  bundle.preoperativeImage = patient.image;
  for (const std::string & path : options.labelMaps)
  {
    bundle.labelMaps.push_back(ReadImage<MaskImageType>(path, "label map"));
    bundle.labelMapNames.push_back(fs::path(path).filename().string());
  }
  RegistrationProgress progress(!options.quiet && ::isatty(STDERR_FILENO) != 0);
  StageTimer           timer(progress.Stages());
  bundle.model = PrepareBrainModel(patient.image, patient.brainMask, patient.tumourMask, patient.skullSurface,
                                   bundle.settings.model, timer, true);
  PrecomputeBrainModel(bundle.model, bundle.settings, timer);
  timer.Run("write", [&] {
    bundle.manifest["prepare"] = { { "preoperative_image", options.patient.image },
                                   { "seconds", timer.Json() },
                                   { "wall_seconds", std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count() } };
    WriteModelBundle(options.output, bundle);
  });
  PrintWarnings(bundle.model.warnings);
  if (!options.quiet)
  {
    const ModelCounts counts = CountModel(bundle.model.model);
    std::cout << "model bundle " << options.output << " of " << options.patient.image << "\n"
              << "  grid              " << ImageGridKindName(bundle.settings.model.grid.kind) << ", " << counts.nodes
              << " nodes, " << counts.cells << " cells, " << counts.dofs << " DOF";
    if (counts.integrationPoints > 0)
    {
      std::cout << ", " << counts.integrationPoints << " integration points";
    }
    std::cout << "\n  exposed nodes     " << bundle.model.exposedNodes.size() << ", fixed "
              << bundle.model.model.NodeSet("skull_base").size() << "\n"
              << "  CSF               " << CsfClassText(bundle.model) << "\n"
              << "  time              ";
    for (const auto & [stage, seconds] : timer.Stages())
    {
      std::cout << stage << " " << std::fixed << std::setprecision(2) << seconds << "  ";
    }
    std::cout << "| total " << timer.Json()["total"].get<double>() << " s\n";
  }
  return 0;
}

struct UpdateOptions
{
  std::string           bundle;
  IntraoperativeOptions intraoperative;
  std::vector<double>   gravity;
  double                csfDrainedDepth = 0.0;
  CLI::Option *         csfDrainedDepthOption = nullptr;
  SettingOptions        settings{ { "solve", "fit", "evaluation" } };
  std::string           previous; // an earlier update's folder: warm start
  int                   overlays = 5;
  std::string           outputDirectory = "update";
  bool                  quiet = false;
  UncertaintyOptions    uncertainty;
};

/** Intraoperative measurements must lie on the bundle's preoperative image: a
 *  point outside it is from another patient, scan or coordinate frame. */
void
CheckMeasurementsInside(const IntraoperativeData & data, const RegistrationImage * image, const std::string & bundle)
{
  const ImageGeometry geometry = itk::MakeBiomechanicalGeometry(image);
  const auto          outside = [&](const Vector3 & point) {
    const Vector3 index = geometry.PointToIndex(point);
    for (int d = 0; d < 3; ++d)
    {
      if (index[d] < -0.5 || index[d] > geometry.size[d] - 0.5)
      {
        return true;
      }
    }
    return false;
  };
  const std::vector<Vector3> & points = data.sparse.points.empty() ? data.surface.vertices : data.sparse.points;
  const auto first = std::find_if(points.begin(), points.end(), outside);
  if (first != points.end())
  {
    std::ostringstream message;
    message << "the intraoperative " << (data.sparse.points.empty() ? "surface's vertex " : "point ") << first - points.begin()
            << " (" << first->transpose() << " mm) lies outside the preoperative image of the model bundle '" << bundle
            << "' (" << geometry.Describe() << "): the measurements are in another coordinate frame or of another "
            << "patient; give them in the preoperative image's physical space";
    throw Error(message.str());
  }
}

int
RunUpdate(const UpdateOptions & options)
{
  const auto                started = std::chrono::steady_clock::now();
  const UncertaintySettings uncertainty = options.uncertainty.Checked();
  ModelBundle               bundle = ReadModelBundle(options.bundle);
  const double readSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  BrainShiftRegistrationSettings settings = bundle.settings;
  options.settings.Apply(settings);
  if (!options.gravity.empty())
  {
    settings.model.gravity = ThreeValues(options.gravity, "--gravity");
  }
  if (options.csfDrainedDepthOption->count() > 0)
  {
    settings.model.csfDrainedDepth = options.csfDrainedDepth;
  }
  BrainShiftUpdateInputs inputs;
  inputs.preoperativeImage = bundle.preoperativeImage;
  inputs.labelMaps.assign(bundle.labelMaps.begin(), bundle.labelMaps.end());
  inputs.intraoperative = options.intraoperative.Read();
  CheckMeasurementsInside(inputs.intraoperative, bundle.preoperativeImage, options.bundle);
  std::optional<UpdateSolution> previous;
  if (!options.previous.empty())
  {
    previous = ReadUpdateSolution(options.previous, bundle.manifest);
    inputs.previous = previous->start;
  }

  BrainShiftRegistrationResult result;
  // The ensemble loads the model as prepared, before the update's loads.
  const std::optional<BrainModel> prepared =
    uncertainty.members > 0 ? std::optional<BrainModel>(bundle.model) : std::nullopt;
  std::optional<BrainShiftUncertaintyResult> ensemble;
  {
    RegistrationProgress progress(!options.quiet && ::isatty(STDERR_FILENO) != 0);
    result = UpdateBrainShift(std::move(bundle.model), inputs, settings, progress.Stages(), progress.Steps());
    if (prepared)
    {
      ensemble = RunEnsemble(*prepared, result, inputs, settings, uncertainty, bundle.labelMapNames);
    }
  }
  json report = { { "bundle", options.bundle },
                  { "preoperative_image",
                    bundle.manifest.value("prepare", json::object()).value("preoperative_image", std::string()) } };
  report["stages"] = json::array();
  for (const auto & stage : result.timer.Stages())
  {
    report["stages"].push_back(stage.first);
  }
  // A warm start's saving is said against the cold solve at the head of the
  // surgery's chain of updates (of other data: a cold solve of these data
  // was not run).
  const int coldSteps = previous ? previous->coldSteps : result.solve.steps;
  if (previous)
  {
    report["warm_start"] = { { "previous", options.previous },
                             { "previous_steps", previous->steps },
                             { "cold_steps_of_first_update", coldSteps },
                             { "steps", result.solve.steps },
                             { "steps_saved", coldSteps - result.solve.steps },
                             { "fraction_of_cold_steps",
                               coldSteps > 0 ? static_cast<double>(result.solve.steps) / coldSteps : 0.0 } };
  }
  const UpdateSolution solution = MakeUpdateSolution(result.solve, bundle.manifest, coldSteps);
  if (ensemble)
  {
    report["uncertainty"] = UncertaintyReportJson(*ensemble, uncertainty);
  }
  const auto writeSolution = [&](const fs::path & folder, json & files) {
    WriteUpdateSolution(folder / "solution.bin", solution);
    files["solution"] = (folder / "solution.bin").string();
    if (ensemble)
    {
      WriteEnsemble(*ensemble, inputs.preoperativeImage, folder, files);
    }
  };
  const int status = WriteRegistrationOutputs(result, settings, options.outputDirectory, bundle.labelMapNames,
                                              inputs.intraoperative.image, options.overlays, true, report,
                                              { { "read-bundle", readSeconds } }, writeSolution);
  // The whole update, from reading the bundle to the last file written.
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  if (!options.quiet)
  {
    std::cout << FormatRegistrationTable(result) << "  bundle read       " << std::fixed << std::setprecision(2)
              << readSeconds << " s; update " << wall << " s from reading the bundle to the last file written\n";
    if (previous)
    {
      std::cout << "  warm start        from " << options.previous << ": " << result.solve.steps << " steps, "
                << coldSteps - result.solve.steps << " fewer than the first update's cold solve (" << coldSteps
                << ")\n";
    }
    std::cout << "  output            " << options.outputDirectory << "\n";
  }
  return status;
}

// ---------------------------------------------------------------------------
// The single steps, each on its own.
// ---------------------------------------------------------------------------

struct StepOptions
{
  std::string        input;
  std::string        mask;
  std::string        output;
  SettingOptions     classifySettings{ {}, { "classes", "fuzziness", "classifier_tolerance", "classifier_max_iterations" } };
  SettingOptions     maskSettings{ {}, { "atlas", "atlas_mask", "affine_only" } };
  SettingOptions     gridSettings{ {}, { "grid", "element_size", "threads" } };
  SettingOptions     surfaceSettings{ {}, { "skull_gap" } };
  std::string        integrationPointsOutput;
  std::string        memberships;
  std::string        tumourMask;
  RegionOptions      regions;
  MeasurementOptions measurements;
  std::string        skullOutput;
  std::string        modelSurface;
};

int
RunClassify(const StepOptions & options)
{
  const ImageType::Pointer image = ReadImage<ImageType>(options.input, "image");
  const ScalarVolume       intensities = itk::MakeBiomechanicalVolume<float>(image.GetPointer());
  LabelVolume              mask;
  if (!options.mask.empty())
  {
    mask = ReadMaskVolume(options.mask, "brain mask", &intensities.geometry);
  }
  std::vector<std::string>   warnings;
  const TissueClassification result = ClassifyTissue(intensities, options.mask.empty() ? nullptr : &mask,
                                                     options.classifySettings.Resolved().model.classifier, {}, &warnings);
  const fs::path prefix(options.output);
  CreateFolder(prefix.has_parent_path() ? prefix.parent_path() : fs::path("."));
  WriteImageAtomically(MakeMembershipImage(result.memberships).GetPointer(), prefix.string() + "-memberships.nii.gz");
  WriteImageAtomically(itk::MakeImageFromBiomechanicalVolume<MaskImageType>(result.labels).GetPointer(),
                       prefix.string() + "-labels.nii.gz");
  PrintWarnings(warnings);
  std::cout << "classes " << result.fit.centroids.size() << ", centroids";
  for (const double centroid : result.fit.centroids)
  {
    std::cout << " " << centroid;
  }
  std::cout << ", " << result.fit.iterations << " iterations" << (result.fit.converged ? "" : " (NOT CONVERGED)")
            << "\nwrote " << prefix.string() << "-memberships.nii.gz and " << prefix.string() << "-labels.nii.gz\n";
  return 0;
}

int
RunMask(const StepOptions & options)
{
  const MaskImageType::Pointer mask = AtlasBrainMask(ReadImage<ImageType>(options.input, "image"), options.maskSettings.Resolved().model.atlas);
  const fs::path               output(options.output);
  CreateFolder(output.has_parent_path() ? output.parent_path() : fs::path("."));
  WriteImageAtomically(mask.GetPointer(), output);
  std::cout << "wrote " << output.string() << "\n";
  return 0;
}

int
RunGrid(const StepOptions & options)
{
  const ImageType::Pointer image = ReadImage<ImageType>(options.input, "label image");
  LabelVolume              labels = itk::MakeBiomechanicalVolume<std::uint8_t>(image.GetPointer());
  std::vector<std::string> warnings;
  const BrainShiftRegistrationSettings settings = options.gridSettings.Resolved();
  ImageGridSettings                    gridSettings = settings.model.grid;
  gridSettings.threads = settings.model.threads;
  ImageGrid grid = MakeGridFromLabels(labels, gridSettings, &warnings);
  if (!options.memberships.empty())
  {
    const auto         membershipImage = ReadImage<MembershipImageType>(options.memberships, "memberships");
    const ScalarVolume memberships = itk::MakeBiomechanicalVolume<float>(membershipImage.GetPointer());
    LabelVolume        tumour;
    if (!options.tumourMask.empty())
    {
      tumour = ReadMaskVolume(options.tumourMask, "tumour mask", &memberships.geometry);
    }
    MapMaterialsFromMemberships(grid.model, memberships, MaterialMappingSettings{},
                                tumour.values.empty() ? nullptr : &tumour);
  }
  const bool meshless = grid.model.discretization == Discretization::Meshless;
  if (meshless && options.integrationPointsOutput.empty())
  {
    throw Error("a meshless grid needs --integration-points FILE.vtu for its integration points");
  }
  const fs::path output(options.output);
  CreateFolder(output.has_parent_path() ? output.parent_path() : fs::path("."));
  WriteMesh(output.string(), grid.model);
  if (meshless)
  {
    WriteIntegrationPoints(options.integrationPointsOutput, grid.model);
  }
  PrintWarnings(warnings);
  std::cout << FormatGridQuality(grid.quality) << "wrote " << output.string() << "\n";
  return 0;
}

int
RunSurfaces(const StepOptions & options)
{
  const LabelVolume   mask = ReadMaskVolume(options.input, "brain mask", nullptr);
  std::vector<std::string> warnings;
  const BrainModelSettings model = options.surfaceSettings.Resolved().model;
  const double             skullGap = model.skullGap;
  const BrainSurfaces      surfaces = BrainSurfacesOfMask(mask, skullGap, warnings, true, model.skullClosing);
  PrintWarnings(warnings);
  for (const fs::path path : { fs::path(options.output), fs::path(options.skullOutput) })
  {
    CreateFolder(path.has_parent_path() ? path.parent_path() : fs::path("."));
  }
  WriteSurface(options.output, surfaces.brain);
  WriteSurface(options.skullOutput, surfaces.skull);
  std::cout << "brain surface " << surfaces.brain.triangles.size() << " triangles, enclosed volume "
            << EnclosedVolume(surfaces.brain) / 1000.0 << " ml -> " << options.output << "\n"
            << "skull surface " << surfaces.skull.triangles.size() << " triangles (gap " << skullGap
            << " mm) -> " << options.skullOutput << "\n";
  return 0;
}

int
RunLoads(const StepOptions & options)
{
  MeshData mesh = ReadMesh(options.input);
  Model &  model = mesh.model;
  if (!options.regions.HasCraniotomy())
  {
    throw Error("give the craniotomy region: --craniotomy-centre X Y Z with --craniotomy-radius R, or --craniotomy-mask");
  }
  if (!options.measurements.Given())
  {
    throw Error("give the measurements: --intraoperative-surface FILE or --sparse-displacements CSV");
  }
  // A meshless cloud has no cells: its boundary nodes are the mesh file's "surface" set.
  const auto                   surfaceMask = mesh.pointData.find("surface");
  std::vector<Index>           surface;
  if (surfaceMask != mesh.pointData.end() && surfaceMask->second.components == 1)
  {
    for (std::size_t node = 0; node < surfaceMask->second.values.size(); ++node)
    {
      if (surfaceMask->second.values[node] != 0.0)
      {
        surface.push_back(static_cast<Index>(node));
      }
    }
  }
  else
  {
    surface = model.BoundaryNodes();
  }
  const std::vector<Index>     exposed = options.regions.ExposedNodes(model, surface);
  LoadReport                   report;
  ContactSurface               modelSurface;
  if (!options.modelSurface.empty())
  {
    modelSurface = ReadSurface(options.modelSurface);
  }
  const PrescribedDisplacement load =
    options.measurements.Displacements(model, exposed, report, options.modelSurface.empty() ? nullptr : &modelSurface);
  const fs::path               output(options.output);
  CreateFolder(output.has_parent_path() ? output.parent_path() : fs::path("."));
  WriteTextFileAtomically(output.string(), DisplacementCsv(load));
  PrintWarnings(report.warnings);
  std::cout << exposed.size() << " exposed nodes, " << load.nodes.size() << " loaded, " << report.rejectedPoints
            << " rejected; correspondence distance max " << report.maxCorrespondenceDistance << " mm, rms "
            << report.rmsCorrespondenceDistance << " mm\nwrote " << output.string() << "\n";
  return 0;
}

} // namespace

std::function<int()>
AddModelCommands(CLI::App & app)
{
  // Warnings reach the user through the reports and "biomech: warning:" lines, not ITK's raw output.
  itk::Object::GlobalWarningDisplayOff();

  auto step = std::make_shared<StepOptions>();

  CLI::App * classify = app.add_subcommand("classify", "Fuzzy c-means tissue classification of an MRI inside a mask");
  classify->add_option("image", step->input, "MRI image")->required();
  classify->add_option("--mask", step->mask, "Brain mask on the image grid (voxels > 0)");
  classify->add_option("-o,--output", step->output, "Output prefix: PREFIX-memberships.nii.gz, PREFIX-labels.nii.gz")
    ->required();
  step->classifySettings.Add(classify);

  CLI::App * mask = app.add_subcommand("mask", "Brain mask by atlas registration (Colin27 by default)");
  mask->add_option("image", step->input, "T1 MRI image")->required();
  mask->add_option("-o,--output", step->output, "Output mask (.nii.gz)")->required();
  step->maskSettings.Add(mask);

  CLI::App * gridCommand = app.add_subcommand("grid", "Hexahedral, tetrahedral, mixed or meshless grid from a mask or label image");
  gridCommand->add_option("labels", step->input, "Mask or label image (0 = outside)")->required();
  gridCommand->add_option("-o,--output", step->output, "Output mesh (.vtu or .vtk)")->required();
  step->gridSettings.Add(gridCommand);
  gridCommand->add_option("--integration-points", step->integrationPointsOutput, "Meshless: output integration points (.vtu)");
  gridCommand->add_option("--memberships", step->memberships, "Memberships from 'classify': map materials to the cells");
  gridCommand->add_option("--tumour-mask", step->tumourMask, "Tumour mask on the memberships' grid");

  CLI::App * surfaces = app.add_subcommand("surfaces", "Brain surface and rigid skull surface from a brain mask");
  surfaces->add_option("mask", step->input, "Brain mask (voxels > 0)")->required();
  surfaces->add_option("-o,--output", step->output, "Brain surface (.vtp, .stl, .vtk)")->required();
  surfaces->add_option("--skull-output", step->skullOutput, "Skull surface (.vtp, .stl, .vtk)")->required();
  step->surfaceSettings.Add(surfaces);

  CLI::App * loads = app.add_subcommand("loads", "Displacements of the exposed surface nodes from intraoperative measurements");
  loads->add_option("mesh", step->input, "Model mesh (.vtu, .vtk)")->required();
  loads->add_option("-o,--output", step->output, "Output CSV id,ux,uy,uz for a scene's prescribed_displacements")
    ->required();
  step->regions.Add(loads);
  step->measurements.Add(loads);
  loads->add_option("--model-surface", step->modelSurface,
                    "Surface of the body, for a meshless point cloud (no cells), e.g. from 'surfaces'");

  auto options = std::make_shared<ModelOptions>();
  CLI::App * model = app.add_subcommand(
    "model", "From an MRI (+ mask, tumour mask, craniotomy, intraoperative measurements) to a scene for 'solve'");
  options->patient.Add(model);
  options->measurements.Add(model);
  model->add_option("-o,--output-dir", options->outputDirectory, "Folder for the scene and its files")
    ->capture_default_str();
  model->add_flag("--quiet,-q", options->quiet, "Print nothing but warnings and errors");

  auto registration = std::make_shared<RegisterOptions>();
  CLI::App * registerCommand = app.add_subcommand(
    "register", "Brain-shift registration in one call: model, solve, transform, warped image (+ labels), evaluation, "
                "report. Exit 0 converged, 2 not converged (results written), 1 error");
  registration->patient.Add(registerCommand);
  registerCommand->add_option("--labels", registration->labelMaps,
                              "Label maps on the image grid to warp (nearest neighbour); repeat for several");
  registration->intraoperative.Add(registerCommand);
  registration->settings.Add(registerCommand);
  registration->uncertainty.Add(registerCommand);
  registerCommand->add_option("--overlays", registration->overlays, "Edge-overlay PNGs per evaluation (0: none)")
    ->capture_default_str();
  registerCommand->add_option("-o,--output-dir", registration->outputDirectory, "Output folder")->capture_default_str();
  registerCommand->add_flag("--quiet,-q", registration->quiet, "Print nothing but warnings and errors");

  auto       prepare = std::make_shared<PrepareOptions>();
  CLI::App * prepareCommand = app.add_subcommand(
    "prepare", "Before surgery: skull stripping, classification, grid, materials, surfaces and regions of the "
               "preoperative MRI, written as a model bundle (a folder) for `update`");
  prepare->patient.Add(prepareCommand, false);
  prepareCommand->add_option("--labels", prepare->labelMaps,
                             "Label maps on the image grid that each update warps (nearest neighbour); repeat for several");
  prepare->settings.Add(prepareCommand);
  prepareCommand->add_option("-o,--output", prepare->output, "The model bundle's folder")->required();
  prepareCommand->add_flag("--quiet,-q", prepare->quiet, "Print nothing but warnings and errors");

  auto       update = std::make_shared<UpdateOptions>();
  CLI::App * updateCommand = app.add_subcommand(
    "update", "During surgery: loads from the intraoperative data, solve, transform, warped image (+ labels), "
              "evaluation, report, on a model bundle from `prepare`. Exit 0 converged, 2 not converged (results "
              "written), 1 error");
  updateCommand->add_option("bundle", update->bundle, "Model bundle (folder) written by `biomech prepare`")->required();
  update->intraoperative.Add(updateCommand);
  CLI::Option * updateGravity =
    updateCommand->add_option("--gravity", update->gravity, "Body acceleration X Y Z (mm/s^2), e.g. 0 0 -9810")
      ->expected(3);
  update->csfDrainedDepthOption =
    updateCommand
      ->add_option("--csf-drained-depth", update->csfDrainedDepth,
                   "CSF drained to this depth (mm) below the brain's top along gravity (default: all of it)")
      ->check(CLI::NonNegativeNumber)
      ->needs(updateGravity);
  update->settings.Add(updateCommand);
  updateCommand->add_option("--previous", update->previous,
                            "A later update of the same surgery: start the solve from this earlier update's output "
                            "folder (its solution.bin); the result is the cold solve's within the tolerance");
  update->uncertainty.Add(updateCommand);
  updateCommand->add_option("--overlays", update->overlays, "Edge-overlay PNGs per evaluation (0: none)")
    ->capture_default_str();
  updateCommand->add_option("-o,--output-dir", update->outputDirectory, "Output folder")->capture_default_str();
  updateCommand->add_flag("--quiet,-q", update->quiet, "Print nothing but warnings and errors");

  return [=]() -> int {
    if (prepareCommand->parsed())
    {
      return RunPrepare(*prepare);
    }
    if (updateCommand->parsed())
    {
      return RunUpdate(*update);
    }
    if (registerCommand->parsed())
    {
      return RunRegister(*registration);
    }
    if (model->parsed())
    {
      return RunModel(*options);
    }
    if (classify->parsed())
    {
      return RunClassify(*step);
    }
    if (mask->parsed())
    {
      return RunMask(*step);
    }
    if (gridCommand->parsed())
    {
      return RunGrid(*step);
    }
    if (surfaces->parsed())
    {
      return RunSurfaces(*step);
    }
    if (loads->parsed())
    {
      return RunLoads(*step);
    }
    return -1;
  };
}

BrainShiftUncertaintyResult
RunEnsemble(const BrainModel & prepared, BrainShiftRegistrationResult & result, const BrainShiftUpdateInputs & inputs,
            const BrainShiftRegistrationSettings & settings, const UncertaintySettings & uncertainty,
            const std::vector<std::string> & labelNames)
{
  BrainShiftUncertaintyResult ensemble = EstimateUncertaintyAfter(result, prepared, inputs, settings, uncertainty);
  for (auto & region : ensemble.regions)
  {
    if (region.labelMap >= 0)
    {
      region.name = fs::path(labelNames.at(static_cast<std::size_t>(region.labelMap))).filename().string();
    }
  }
  return ensemble;
}

void
WriteEnsemble(const BrainShiftUncertaintyResult & ensemble, const RegistrationImage * preoperative,
              const fs::path & folder, json & files)
{
  WriteImageAtomically(ensemble.uncertaintyImage.GetPointer(), folder / "displacement-uncertainty.nii.gz");
  files["displacement_uncertainty"] = (folder / "displacement-uncertainty.nii.gz").string();
  itk::WriteBiomechanicalTransform(ensemble.meanTransform, (folder / "mean-transform.h5").string());
  files["mean_transform"] = (folder / "mean-transform.h5").string();
  WriteUncertaintyOverlay(ensemble, preoperative, (folder / "uncertainty-overlay.png").string());
  files["uncertainty_overlay"] = (folder / "uncertainty-overlay.png").string();
}

} // namespace app
} // namespace bmr
