#include "bmrModelCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkAtlasBrainMaskImageFilter.h"
#include "itkBiomechanicalImageConversion.h"
#include "itkBrainSurfaceMeshSource.h"

#include "bmrCommandSupport.h"

#include "bmrBrainSurfaces.h"
#include "bmrFuzzyCMeans.h"
#include "bmrImageGrids.h"
#include "bmrMaterialMapping.h"
#include "bmrMeshIO.h"
#include "bmrScene.h"
#include "bmrSurfaceLoads.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <iostream>
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

const char * const DefaultAtlas = "/usr/share/mricron/templates/ch2.nii.gz";
const char * const DefaultAtlasMask = "/usr/share/mricron/templates/ch2bet.nii.gz";

/** A mask file as a core volume: every voxel > 0 is inside (so a brain-extracted
 *  image such as ch2bet.nii.gz works as a mask). Must lie on `grid` when given. */
LabelVolume
ReadMaskVolume(const std::string & path, const std::string & what, const ImageGeometry * grid)
{
  const ImageType::Pointer image = ReadImage<ImageType>(path, what);
  LabelVolume              mask;
  mask.geometry = itk::MakeBiomechanicalGeometry(image.GetPointer());
  const ScalarVolume values = itk::MakeBiomechanicalVolume<float>(image.GetPointer());
  mask.values.resize(values.values.size());
  for (std::size_t voxel = 0; voxel < values.values.size(); ++voxel)
  {
    mask.values[voxel] = values.values[voxel] > 0.0f ? 1 : 0;
  }
  if (grid != nullptr && !mask.geometry.SameGridAs(*grid))
  {
    throw Error(what + " '" + path + "' is not on the image grid: it has " + mask.geometry.Describe() +
                ", the image has " + grid->Describe() + "; resample it onto the image (nearest neighbour) first");
  }
  return mask;
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

struct ClassifierOptions
{
  // 3, not the classifier's 2: on a T1 image two classes split grey from white
  // matter, and the darker class (grey matter) would get the CSF material.
  int    classes = 3;
  double fuzziness = 2.0;
  double tolerance = 1e-5;
  int    maxIterations = 300;

  void Add(CLI::App * command)
  {
    command->add_option("--classes", classes, "Tissue classes (2: CSF and parenchyma; 3: CSF, grey, white)")
      ->check(CLI::Range(2, 16))
      ->capture_default_str();
    command->add_option("--fuzziness", fuzziness, "Fuzzy c-means exponent m > 1")->capture_default_str();
    command->add_option("--tolerance", tolerance, "Largest centroid change, relative to the intensity range")
      ->capture_default_str();
    command->add_option("--max-iterations", maxIterations, "Fuzzy c-means iteration limit")->capture_default_str();
  }

  FuzzyCMeansSettings Settings() const
  {
    FuzzyCMeansSettings settings;
    settings.classes = classes;
    settings.fuzziness = fuzziness;
    settings.tolerance = tolerance;
    settings.maxIterations = maxIterations;
    return settings;
  }
};

struct AtlasOptions
{
  std::string atlas = DefaultAtlas;
  std::string atlasMask = DefaultAtlasMask;
  bool        affineOnly = false;

  void Add(CLI::App * command)
  {
    command->add_option("--atlas", atlas, "Atlas T1 image for skull stripping")->capture_default_str();
    command->add_option("--atlas-mask", atlasMask, "Atlas brain mask (voxels > 0 are brain)")->capture_default_str();
    command->add_flag("--affine-only", affineOnly, "Skip the B-spline stage of the atlas registration");
  }

  /** The brain mask of `image` by atlas registration (itk::AtlasBrainMaskImageFilter). */
  MaskImageType::Pointer BrainMask(const ImageType::Pointer & image) const
  {
    auto filter = itk::AtlasBrainMaskImageFilter<ImageType>::New();
    filter->SetInput(image);
    filter->SetAtlasImage(ReadImage<ImageType>(atlas, "atlas"));
    filter->SetAtlasMaskImage(ReadImage<ImageType>(atlasMask, "atlas mask"));
    filter->SetUseBSplineStage(!affineOnly);
    try
    {
      filter->Update();
    }
    catch (const itk::ExceptionObject & exception)
    {
      throw Error(std::string("skull stripping failed: ") + exception.GetDescription());
    }
    return filter->GetOutput();
  }
};

struct GridOptions
{
  std::string kind = "hexahedra";
  double      elementSize = 5.0;

  void Add(CLI::App * command)
  {
    command->add_option("--grid", kind, "hexahedra, tetrahedra, mixed or meshless")
      ->check(CLI::IsMember({ "hexahedra", "tetrahedra", "mixed", "meshless", "hex", "tet" }))
      ->capture_default_str();
    command->add_option("--element-size", elementSize, "Element edge or meshless nodal spacing (mm)")
      ->capture_default_str();
  }

  ImageGridSettings Settings(int threads) const
  {
    ImageGridSettings settings;
    settings.kind = ParseImageGridKind(kind);
    settings.elementSize = elementSize;
    settings.threads = threads;
    return settings;
  }
};

struct RegionOptions
{
  std::vector<double> craniotomyCentre;
  double              craniotomyRadius = 0.0;
  std::string         craniotomyMask;
  double              skullBaseHeight = SkullBaseSettings{}.height;

  void Add(CLI::App * command)
  {
    command->add_option("--craniotomy-centre", craniotomyCentre, "Centre X Y Z of the craniotomy (mm, physical space)")
      ->expected(3);
    command->add_option("--craniotomy-radius", craniotomyRadius, "Radius of the craniotomy (mm)");
    command->add_option("--craniotomy-mask", craniotomyMask, "Mask of the craniotomy region (instead of a sphere)");
    command->add_option("--skull-base-height", skullBaseHeight,
                        "Fixed band above the most inferior surface node (mm): skull base and brain stem")
      ->capture_default_str();
  }

  bool HasCraniotomy() const { return !craniotomyCentre.empty() || !craniotomyMask.empty(); }

  std::vector<Index> ExposedNodes(const Model & model, const std::vector<Index> & surface) const
  {
    if (!craniotomyCentre.empty() && !craniotomyMask.empty())
    {
      throw Error("give the craniotomy either as a sphere (--craniotomy-centre, --craniotomy-radius) or as "
                  "--craniotomy-mask, not both");
    }
    if (!craniotomyMask.empty())
    {
      const LabelVolume region = ReadMaskVolume(craniotomyMask, "craniotomy mask", nullptr);
      const auto        nodes = SurfaceNodesInMask(model, surface, region);
      if (nodes.empty())
      {
        throw Error("the craniotomy mask '" + craniotomyMask + "' selects no node of the brain surface; "
                    "it must overlap the brain's boundary");
      }
      return nodes;
    }
    if (craniotomyRadius <= 0.0)
    {
      throw Error("--craniotomy-centre needs --craniotomy-radius > 0 (mm)");
    }
    return SurfaceNodesInSphere(model, surface, ThreeValues(craniotomyCentre, "--craniotomy-centre"), craniotomyRadius);
  }

  std::vector<Index> FixedNodes(const Model & model, const std::vector<Index> & surface) const
  {
    SkullBaseSettings settings;
    settings.height = skullBaseHeight;
    return SkullBaseNodes(model, surface, settings);
  }
};

struct MeasurementOptions
{
  std::string intraoperativeSurface;
  std::string sparseDisplacements;
  double      maxDistance = SurfaceLoadSettings{}.maxDistance;

  void Add(CLI::App * command)
  {
    command->add_option("--intraoperative-surface", intraoperativeSurface,
                        "Displaced exposed surface (.stl, .obj, .vtp, .vtk): closest-point correspondence");
    command->add_option("--sparse-displacements", sparseDisplacements,
                        "CSV with header x,y,z,ux,uy,uz (mm): displacements at points, interpolated over the exposed surface");
    command->add_option("--max-distance", maxDistance,
                        "Measurements farther than this from the model surface are rejected with a warning (mm)")
      ->capture_default_str();
  }

  bool Given() const { return !intraoperativeSurface.empty() || !sparseDisplacements.empty(); }

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

/** The brain and skull surfaces of a mask image (signed distance, isosurfaces). */
BrainSurfaces
MakeSurfaces(const LabelVolume & mask, double skullGap, std::vector<std::string> & warnings)
{
  auto source = itk::BrainSurfaceMeshSource<MaskImageType>::New();
  auto image = itk::MakeImageFromBiomechanicalVolume<MaskImageType>(mask);
  source->SetInput(image);
  source->SetSkullGap(skullGap);
  try
  {
    source->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(exception.GetDescription());
  }
  warnings.insert(warnings.end(), source->GetWarnings().begin(), source->GetWarnings().end());
  return BrainSurfaces{ source->GetBrainSurface(), source->GetSkullSurface() };
}

// ---------------------------------------------------------------------------
// The model pipeline: MRI (+ mask, tumour, craniotomy, measurements) -> scene.
// ---------------------------------------------------------------------------

struct ModelOptions
{
  std::string        image;
  std::string        mask;
  std::string        tumourMask;
  std::string        outputDirectory = "model";
  AtlasOptions       atlas;
  ClassifierOptions  classifier;
  GridOptions        grid;
  RegionOptions      regions;
  MeasurementOptions measurements;
  double             skullGap = BrainSurfaceSettings{}.skullGap;
  std::string        skullSurface;
  bool               noContact = false;
  std::vector<double> gravity;
  int                threads = 0;
  bool               quiet = false;
};

int
RunModel(const ModelOptions & options)
{
  const fs::path outputDirectory(options.outputDirectory);
  StepTimer      timer(!options.quiet);
  json           report;
  std::vector<std::string> warnings;
  report["image"] = options.image;

  // Everything is computed before anything is written, so a failure leaves no partial model.
  const ImageType::Pointer image = timer.Run("read", [&] { return ReadImage<ImageType>(options.image, "image"); });
  const ScalarVolume       intensities = itk::MakeBiomechanicalVolume<float>(image.GetPointer());

  LabelVolume mask;
  if (!options.mask.empty())
  {
    mask = ReadMaskVolume(options.mask, "brain mask", &intensities.geometry);
    report["mask"] = options.mask;
  }
  else
  {
    mask = timer.Run("skull-strip", [&] {
      return itk::MakeBiomechanicalVolume<std::uint8_t>(options.atlas.BrainMask(image).GetPointer());
    });
    report["mask"] = "atlas: " + options.atlas.atlas;
  }

  LabelVolume tumour;
  if (!options.tumourMask.empty())
  {
    tumour = ReadMaskVolume(options.tumourMask, "tumour mask", &intensities.geometry);
  }

  const TissueClassification classification = timer.Run("classify", [&] {
    return ClassifyTissue(intensities, &mask, options.classifier.Settings(), {}, &warnings);
  });
  report["classification"] = { { "classes", options.classifier.classes },
                               { "centroids", classification.fit.centroids },
                               { "iterations", classification.fit.iterations },
                               { "converged", classification.fit.converged } };

  // The tumour is a second label, so that tetrahedral meshes conform to its boundary.
  LabelVolume labels = mask;
  if (!tumour.values.empty())
  {
    for (std::size_t voxel = 0; voxel < labels.values.size(); ++voxel)
    {
      if (tumour.values[voxel] != 0)
      {
        labels.values[voxel] = 2;
      }
    }
  }
  ImageGrid grid = timer.Run("grid", [&] { return MakeGridFromLabels(labels, options.grid.Settings(options.threads), &warnings); });
  Model &   model = grid.model;

  timer.Run("materials", [&] {
    MaterialMappingSettings settings;
    MapMaterialsFromMemberships(model, classification.memberships, settings, tumour.values.empty() ? nullptr : &tumour,
                                &warnings);
  });

  // The skull is the boundary of the body dilated by the gap, and the body is
  // the model's cells (for a point cloud, the tetrahedra its integration points
  // cover), not the mask: the corners of a staircase hexahedral grid stick out
  // of the mask by up to half a cell, and a meshless cloud's surface nodes
  // partly lie outside a skull made from the mask (an integration point
  // inverted at step 2 under 0.1 g).
  BrainSurfaces surfaces = timer.Run("surfaces", [&] {
    const Model & body = model.cells.empty() ? grid.meshlessBody : model;
    return MakeSurfaces(RasterizeCells(body, mask.geometry), options.skullGap, warnings);
  });
  if (!options.skullSurface.empty())
  {
    // The user's skull (e.g. segmented from CT) replaces the dilated body as the contact master.
    const std::string name = surfaces.skull.name;
    surfaces.skull = ReadSurface(options.skullSurface);
    surfaces.skull.name = name;
    surfaces.skull.bodySide = ContactSurface::Side::Inside;
    report["skull_surface"] = options.skullSurface;
  }

  const std::vector<Index> & surfaceNodes = model.NodeSet("surface");
  model.nodeSets["skull_base"] = options.regions.FixedNodes(model, surfaceNodes);
  std::vector<Index> exposed;
  if (options.regions.HasCraniotomy())
  {
    exposed = options.regions.ExposedNodes(model, surfaceNodes);
    model.nodeSets["exposed"] = exposed;
  }
  else if (options.measurements.Given())
  {
    throw Error("intraoperative measurements need the craniotomy region they belong to: give --craniotomy-centre "
                "and --craniotomy-radius, or --craniotomy-mask");
  }

  LoadReport             loadReport;
  PrescribedDisplacement load;
  if (options.measurements.Given())
  {
    load = timer.Run("loads", [&] {
      return options.measurements.Displacements(model, exposed, loadReport,
                                                model.cells.empty() ? &surfaces.brain : nullptr);
    });
    warnings.insert(warnings.end(), loadReport.warnings.begin(), loadReport.warnings.end());
    report["loads"] = LoadReportJson(loadReport);
  }

  // Contact: every surface node that is neither fixed nor loaded may touch the skull.
  if (!options.noContact)
  {
    std::vector<char> constrained(model.nodes.size(), 0);
    for (const Index node : model.nodeSets["skull_base"])
    {
      constrained[node] = 1;
    }
    for (const Index node : load.nodes)
    {
      constrained[node] = 1;
    }
    std::vector<Index> contactNodes;
    for (const Index node : surfaceNodes)
    {
      if (!constrained[node])
      {
        contactNodes.push_back(node);
      }
    }
    model.nodeSets["contact"] = contactNodes;
  }

  // The scene `biomech solve` runs.
  const bool meshless = model.discretization == Discretization::Meshless;
  json       scene;
  std::ostringstream description;
  description << "Brain model of " << fs::path(options.image).filename().string() << " made by biomech model ("
              << ImageGridKindName(options.grid.Settings(0).kind) << ", " << options.grid.elementSize << " mm)";
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
  if (!options.gravity.empty())
  {
    const Vector3 gravity = ThreeValues(options.gravity, "--gravity");
    scene["gravity"] = { gravity.x(), gravity.y(), gravity.z() };
  }
  if (!options.noContact && !model.nodeSets["contact"].empty())
  {
    scene["node_sets"]["contact"] = { { "point_data", "contact" } };
    scene["contact"] = json::array(
      { { { "surface", "skull.vtp" }, { "name", "skull" }, { "body_side", "inside" }, { "slave_node_set", "contact" } } });
  }
  if (load.nodes.empty() && options.gravity.empty())
  {
    warnings.push_back("the scene has no load (no intraoperative measurements and no --gravity): its solution is zero");
  }
  // 0.01 mm, as the brain-sized examples: far below the 0.1 mm a registration needs, and
  // reached by CGAL tetrahedra (slivers, soft CSF) that stall near 0.001 mm with contact.
  scene["solver"] = { { "integrator", "dynamic_relaxation" }, { "tolerance", 0.01 } };
  scene["output"] = { { "vtu", "brain-result.vtu" }, { "report", "brain-report.json" } };

  const ModelCounts counts = CountModel(model);
  report["grid"] = { { "kind", ImageGridKindName(options.grid.Settings(0).kind) },
                     { "element_size_mm", options.grid.elementSize },
                     { "nodes", counts.nodes },
                     { "cells", counts.cells },
                     { "dofs", counts.dofs },
                     { "integration_points", counts.integrationPoints },
                     { "volume_error", grid.quality.volumeError },
                     { "min_scaled_jacobian", grid.quality.minScaledJacobian },
                     { "min_dihedral_angle_deg", grid.quality.minDihedralAngleDeg } };
  report["regions"] = { { "surface_nodes", surfaceNodes.size() },
                        { "exposed_nodes", exposed.size() },
                        { "skull_base_nodes", model.nodeSets["skull_base"].size() } };
  report["skull_gap_mm"] = options.skullGap;
  report["warnings"] = warnings;

  timer.Run("write", [&] {
    CreateFolder(outputDirectory);
    // An earlier run's scene must not pass for this run's while its files are replaced.
    std::error_code ignored;
    fs::remove(outputDirectory / "scene.json", ignored);
    fs::remove(outputDirectory / "model-report.json", ignored);
    WriteMesh((outputDirectory / "model.vtu").string(), model);
    if (meshless)
    {
      WriteIntegrationPoints((outputDirectory / "integration-points.vtu").string(), model);
    }
    WriteSurface((outputDirectory / "brain-surface.vtp").string(), surfaces.brain);
    WriteSurface((outputDirectory / "skull.vtp").string(), surfaces.skull);
    if (!load.nodes.empty())
    {
      WriteTextFileAtomically((outputDirectory / "exposed-displacements.csv").string(), DisplacementCsv(load));
    }
    WriteImageAtomically(MakeMembershipImage(classification.memberships).GetPointer(),
                         outputDirectory / "memberships.nii.gz");
    WriteImageAtomically(itk::MakeImageFromBiomechanicalVolume<MaskImageType>(classification.labels).GetPointer(),
                         outputDirectory / "tissue-labels.nii.gz");
    if (options.mask.empty())
    {
      WriteImageAtomically(itk::MakeImageFromBiomechanicalVolume<MaskImageType>(mask).GetPointer(),
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
    std::cout << "model of " << options.image << "\n"
              << "  grid              " << ImageGridKindName(options.grid.Settings(0).kind) << ", " << counts.nodes
              << " nodes, " << counts.cells << " cells, " << counts.dofs << " DOF";
    if (counts.integrationPoints > 0)
    {
      std::cout << ", " << counts.integrationPoints << " integration points";
    }
    std::cout << "\n  volume error      " << 100.0 * grid.quality.volumeError << " % of the mask\n"
              << "  exposed nodes     " << exposed.size() << ", fixed " << model.nodeSets["skull_base"].size() << "\n"
              << "  time              " << report["seconds"]["total"].get<double>() << " s\n"
              << "  scene             " << (outputDirectory / "scene.json").string() << "\n";
  }
  return 0;
}

// ---------------------------------------------------------------------------
// The single steps, each on its own.
// ---------------------------------------------------------------------------

struct StepOptions
{
  std::string        input;
  std::string        mask;
  std::string        output;
  ClassifierOptions  classifier;
  AtlasOptions       atlas;
  GridOptions        grid;
  std::string        integrationPointsOutput;
  std::string        memberships;
  std::string        tumourMask;
  RegionOptions      regions;
  MeasurementOptions measurements;
  double             skullGap = BrainSurfaceSettings{}.skullGap;
  std::string        skullOutput;
  std::string        modelSurface;
  int                threads = 0;
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
                                                     options.classifier.Settings(), {}, &warnings);
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
  const MaskImageType::Pointer mask = options.atlas.BrainMask(ReadImage<ImageType>(options.input, "image"));
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
  ImageGrid                grid = MakeGridFromLabels(labels, options.grid.Settings(options.threads), &warnings);
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
  const BrainSurfaces      surfaces = MakeSurfaces(mask, options.skullGap, warnings);
  PrintWarnings(warnings);
  for (const fs::path path : { fs::path(options.output), fs::path(options.skullOutput) })
  {
    CreateFolder(path.has_parent_path() ? path.parent_path() : fs::path("."));
  }
  WriteSurface(options.output, surfaces.brain);
  WriteSurface(options.skullOutput, surfaces.skull);
  std::cout << "brain surface " << surfaces.brain.triangles.size() << " triangles, enclosed volume "
            << EnclosedVolume(surfaces.brain) / 1000.0 << " ml -> " << options.output << "\n"
            << "skull surface " << surfaces.skull.triangles.size() << " triangles (gap " << options.skullGap
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
  step->classifier.Add(classify);

  CLI::App * mask = app.add_subcommand("mask", "Brain mask by atlas registration (Colin27 by default)");
  mask->add_option("image", step->input, "T1 MRI image")->required();
  mask->add_option("-o,--output", step->output, "Output mask (.nii.gz)")->required();
  step->atlas.Add(mask);

  CLI::App * gridCommand = app.add_subcommand("grid", "Hexahedral, tetrahedral, mixed or meshless grid from a mask or label image");
  gridCommand->add_option("labels", step->input, "Mask or label image (0 = outside)")->required();
  gridCommand->add_option("-o,--output", step->output, "Output mesh (.vtu or .vtk)")->required();
  step->grid.Add(gridCommand);
  gridCommand->add_option("--integration-points", step->integrationPointsOutput, "Meshless: output integration points (.vtu)");
  gridCommand->add_option("--memberships", step->memberships, "Memberships from 'classify': map materials to the cells");
  gridCommand->add_option("--tumour-mask", step->tumourMask, "Tumour mask on the memberships' grid");
  gridCommand->add_option("--threads", step->threads, "Worker threads (0: all)")->check(CLI::Range(0, 4096));

  CLI::App * surfaces = app.add_subcommand("surfaces", "Brain surface and rigid skull surface from a brain mask");
  surfaces->add_option("mask", step->input, "Brain mask (voxels > 0)")->required();
  surfaces->add_option("-o,--output", step->output, "Brain surface (.vtp, .stl, .vtk)")->required();
  surfaces->add_option("--skull-output", step->skullOutput, "Skull surface (.vtp, .stl, .vtk)")->required();
  surfaces->add_option("--skull-gap", step->skullGap, "Gap between brain and skull (mm)")->capture_default_str();

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
  model->add_option("image", options->image, "Preoperative T1 MRI (.nii.gz, .nrrd, .mha, ...)")->required();
  model->add_option("--mask", options->mask, "Brain mask on the image grid (voxels > 0); default: atlas skull stripping");
  model->add_option("--tumour-mask", options->tumourMask, "Tumour mask on the image grid (voxels > 0)");
  model->add_option("-o,--output-dir", options->outputDirectory, "Folder for the scene and its files")
    ->capture_default_str();
  options->atlas.Add(model);
  options->classifier.Add(model);
  options->grid.Add(model);
  options->regions.Add(model);
  options->measurements.Add(model);
  model->add_option("--skull-gap", options->skullGap, "Gap between the brain surface and the rigid skull (mm)")
    ->capture_default_str();
  model->add_option("--skull-surface", options->skullSurface,
                    "Rigid skull surface (.stl, .obj, .vtp, .vtk) to use instead of the body dilated by --skull-gap");
  model->add_flag("--no-contact", options->noContact, "No brain-skull contact");
  model->add_option("--gravity", options->gravity, "Body acceleration X Y Z (mm/s^2), e.g. 0 0 -9810")->expected(3);
  model->add_option("--threads", options->threads, "Worker threads (0: all)")->check(CLI::Range(0, 4096));
  model->add_flag("--quiet,-q", options->quiet, "Print nothing but warnings and errors");

  return [=]() -> int {
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

} // namespace app
} // namespace bmr
