#include "bmrModelBundle.h"

#include "bmrBinaryStream.h"
#include "bmrMeshIO.h"
#include "bmrScene.h"
#include "itkBiomechanicalImageConversion.h"
#include "itkBiomechanicalImageIO.h"
#include "itk_zlib.h"

#include <chrono>
#include <cstring>
#include <ctime>
#include <fstream>
#include <iterator>
#include <sstream>
#include <type_traits>
#include <unistd.h>

namespace bmr
{

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace
{

const char * const kFormatName = "biomechanical-registration model bundle";
const char         kModelMagic[8] = { 'B', 'M', 'R', 'M', 'O', 'D', 'E', 'L' };
const char         kSolutionMagic[8] = { 'B', 'M', 'R', 'S', 'O', 'L', 'V', 'E' };
constexpr int      kSolutionVersion = 1;
const char * const kPrepareAgain = "prepare the bundle again (biomech prepare)";

// model.bin: little-endian values in the order written, no padding (bmrBinaryStream.h).

void
WriteSurfaceBinary(BinaryWriter & out, const ContactSurface & surface)
{
  out.Text(surface.name);
  out.Points(surface.vertices);
  out.Values(surface.triangles);
  out.Value<std::uint8_t>(surface.bodySide == ContactSurface::Side::Inside ? 0 : 1);
  out.Value<std::uint8_t>(surface.flipNormals ? 1 : 0);
  out.Text(surface.slaveNodeSet);
}

ContactSurface
ReadSurfaceBinary(BinaryReader & in)
{
  ContactSurface surface;
  surface.name = in.Text();
  surface.vertices = in.Points();
  surface.triangles = in.Values<std::array<Index, 3>>();
  surface.bodySide = in.Value<std::uint8_t>() == 0 ? ContactSurface::Side::Inside : ContactSurface::Side::Outside;
  surface.flipNormals = in.Value<std::uint8_t>() != 0;
  surface.slaveNodeSet = in.Text();
  for (const auto & triangle : surface.triangles)
  {
    for (const Index vertex : triangle)
    {
      if (vertex < 0 || static_cast<std::size_t>(vertex) >= surface.vertices.size())
      {
        in.Fail("surface '" + surface.name + "' has a triangle with vertex " + std::to_string(vertex));
      }
    }
  }
  return surface;
}

void
WriteMaterials(BinaryWriter & out, const std::vector<Material> & materials)
{
  out.Value<std::uint64_t>(materials.size());
  for (const Material & material : materials)
  {
    out.Text(material.name);
    out.Value(material.youngsModulus);
    out.Value(material.poissonRatio);
    out.Value(material.density);
    out.Value(material.law);
    for (const MaterialParameter & parameter : MaterialParameters()) // a new one changes the format: a new version
    {
      out.Value(material.*parameter.value);
    }
  }
}

/** The inverse of WriteMaterials; `laws`: from version 3 on (before, every material is neo-Hookean). */
std::vector<Material>
ReadMaterials(BinaryReader & in, bool laws)
{
  std::vector<Material> materials(
    in.Count(8 + 3 * sizeof(double) + (laws ? sizeof(MaterialLaw) + MaterialParameters().size() * sizeof(double) : 0)));
  for (Material & material : materials)
  {
    material.name = in.Text();
    material.youngsModulus = in.Value<double>();
    material.poissonRatio = in.Value<double>();
    material.density = in.Value<double>();
    if (laws)
    {
      try
      {
        material.law = MaterialLawOfCode(in.Value<std::uint8_t>());
      }
      catch (const Error & error)
      {
        in.Fail("material '" + material.name + "': " + error.what());
      }
      for (const MaterialParameter & parameter : MaterialParameters())
      {
        material.*parameter.value = in.Value<double>();
      }
    }
  }
  return materials;
}

/** The prepared model and its surfaces; what the mechanics needs, bit for bit. */
std::string
ModelBytes(const BrainModel & brain)
{
  const Model & model = brain.pipelineModel->GetModel();
  if (!model.prescribedDisplacements.empty() || !model.contactSurfaces.empty() || !model.tools.empty())
  {
    throw Error("a model bundle holds a prepared model (no loads, contact or tools yet); give PrepareBrainModel's");
  }
  BinaryWriter out;
  for (const char c : kModelMagic)
  {
    out.Value(c);
  }
  out.Value<std::uint32_t>(kModelBundleVersion);
  out.Points(model.nodes);
  out.Value<std::uint64_t>(model.cells.size());
  for (const Cell & cell : model.cells)
  {
    out.Value(cell.type);
    out.Value(cell.nodes);
    out.Value(cell.material);
  }
  WriteMaterials(out, model.materials);
  out.Value<std::uint64_t>(model.nodeSets.size());
  for (const auto & [name, nodes] : model.nodeSets)
  {
    out.Text(name);
    out.Values(nodes);
  }
  out.Value<std::uint64_t>(model.fixedConstraints.size());
  for (const FixedConstraint & fixed : model.fixedConstraints)
  {
    out.Text(fixed.nodeSet);
    out.Value(fixed.components);
  }
  out.Value(model.discretization);
  const MeshlessDiscretization & meshless = model.meshless;
  out.Value(meshless.shapeFunctions.basis);
  out.Value(meshless.shapeFunctions.dilatation);
  out.Value(meshless.shapeFunctions.quadraticRegularization);
  out.Value(meshless.essentialBoundary);
  out.Points(meshless.integrationPoints);
  out.Values(meshless.integrationWeights);
  out.Values(meshless.integrationMaterials);
  WriteSurfaceBinary(out, brain.surfaces.brain);
  WriteSurfaceBinary(out, brain.surfaces.skull);
  WriteSurfaceBinary(out, brain.cortex);
  WriteMaterials(out, model.tissueMixture.classes); // version 4
  out.Values(model.tissueMixture.shares);
  return out.Bytes();
}

/** The inverse of ModelBytes: the model as the regions filter gave it, and the surfaces. */
void
ReadModelBytes(BinaryReader & in, BrainModel & brain)
{
  for (const char c : kModelMagic)
  {
    if (in.Value<char>() != c)
    {
      in.Fail("not a model file of this module");
    }
  }
  const auto version = in.Value<std::uint32_t>();
  if (version < kOldestModelBundleVersion || version > kModelBundleVersion)
  {
    in.Fail("format version " + std::to_string(version) + ", this module reads " +
            std::to_string(kOldestModelBundleVersion) + " to " + std::to_string(kModelBundleVersion));
  }
  const bool laws = version >= 3;
  Model model;
  model.nodes = in.Points();
  model.cells.resize(in.Count(sizeof(CellType) + sizeof(Cell::nodes) + sizeof(Index)));
  for (Cell & cell : model.cells)
  {
    cell.type = in.Value<CellType>();
    cell.nodes = in.Value<decltype(cell.nodes)>();
    cell.material = in.Value<Index>();
  }
  model.materials = ReadMaterials(in, laws);
  const std::size_t sets = in.Count(16);
  for (std::size_t k = 0; k < sets; ++k)
  {
    std::string name = in.Text();
    model.nodeSets[name] = in.Values<Index>();
  }
  model.fixedConstraints.resize(in.Count(8 + 3));
  for (FixedConstraint & fixed : model.fixedConstraints)
  {
    fixed.nodeSet = in.Text();
    fixed.components = in.Value<std::array<bool, 3>>();
  }
  model.discretization = in.Value<Discretization>();
  MeshlessDiscretization & meshless = model.meshless;
  meshless.shapeFunctions.basis = in.Value<MlsBasis>();
  meshless.shapeFunctions.dilatation = in.Value<double>();
  meshless.shapeFunctions.quadraticRegularization = in.Value<double>();
  meshless.essentialBoundary = in.Value<EssentialBoundaryImposition>();
  meshless.integrationPoints = in.Points();
  meshless.integrationWeights = in.Values<double>();
  meshless.integrationMaterials = in.Values<Index>();
  brain.surfaces.brain = ReadSurfaceBinary(in);
  brain.surfaces.skull = ReadSurfaceBinary(in);
  brain.cortex = ReadSurfaceBinary(in);
  if (version >= 4)
  {
    model.tissueMixture.classes = ReadMaterials(in, laws);
    model.tissueMixture.shares = in.Values<double>();
  }
  if (!in.AtEnd())
  {
    in.Fail("bytes after the model's end");
  }
  try
  {
    model.Validate();
  }
  catch (const Error & error)
  {
    in.Fail(std::string("its model does not validate: ") + error.what());
  }
  brain.pipelineModel = itk::BiomechanicalModelObject::New();
  brain.pipelineModel->SetModel(model);
  brain.model = std::move(model);
  if (const auto exposed = brain.model.nodeSets.find("exposed"); exposed != brain.model.nodeSets.end())
  {
    brain.exposedNodes = exposed->second;
  }
}

/** The whole file as bytes (empty when it cannot be read: the checksums have said so already). */
std::string
ReadTextFile(const std::string & path)
{
  std::ifstream input(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(input)), std::istreambuf_iterator<char>());
}

std::uint32_t
FileCrc32(const fs::path & path)
{
  std::ifstream     input(path, std::ios::binary);
  std::vector<char> buffer(1 << 20);
  uLong             crc = crc32(0L, Z_NULL, 0);
  while (input)
  {
    input.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    crc = crc32(crc, reinterpret_cast<const Bytef *>(buffer.data()), static_cast<uInt>(input.gcount()));
  }
  return static_cast<std::uint32_t>(crc);
}

json
GeometryJson(const itk::ImageBase<3> * image)
{
  json geometry;
  const auto & size = image->GetLargestPossibleRegion().GetSize();
  geometry["size"] = { size[0], size[1], size[2] };
  geometry["spacing"] = { image->GetSpacing()[0], image->GetSpacing()[1], image->GetSpacing()[2] };
  geometry["origin"] = { image->GetOrigin()[0], image->GetOrigin()[1], image->GetOrigin()[2] };
  json direction = json::array();
  for (unsigned r = 0; r < 3; ++r)
  {
    direction.push_back({ image->GetDirection()[r][0], image->GetDirection()[r][1], image->GetDirection()[r][2] });
  }
  geometry["direction"] = direction;
  return geometry;
}

/** Gives `image` the manifest's exact geometry (NIfTI keeps it in float32). */
template <typename TImage>
void
SetGeometry(TImage * image, const json & geometry, const std::string & what)
{
  const auto & size = image->GetLargestPossibleRegion().GetSize();
  for (unsigned d = 0; d < 3; ++d)
  {
    if (size[d] != geometry.at("size").at(d).get<std::size_t>())
    {
      throw Error("the model bundle's " + what + " has another size than its manifest says; prepare the bundle again");
    }
  }
  typename TImage::SpacingType   spacing;
  typename TImage::PointType     origin;
  typename TImage::DirectionType direction;
  for (unsigned r = 0; r < 3; ++r)
  {
    spacing[r] = geometry.at("spacing").at(r).get<double>();
    origin[r] = geometry.at("origin").at(r).get<double>();
    for (unsigned c = 0; c < 3; ++c)
    {
      direction[r][c] = geometry.at("direction").at(r).at(c).get<double>();
    }
  }
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->SetDirection(direction);
}

json
SurfaceCountsJson(const ContactSurface & surface)
{
  return { { "vertices", surface.vertices.size() }, { "triangles", surface.triangles.size() } };
}

std::string
UtcNow()
{
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  char              text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
  return text;
}

} // namespace

json
WriteModelBundle(const fs::path & folder, const ModelBundle & bundle)
{
  const BrainModel & brain = bundle.model;
  if (brain.pipelineModel.IsNull() || bundle.preoperativeImage.IsNull() || brain.tissueLabelImage.IsNull())
  {
    throw Error("the model bundle is incomplete: give a prepared model (PrepareBrainModel) and its preoperative image");
  }
  if (brain.cortex.triangles.empty())
  {
    throw Error("the prepared model has no cortex surface: prepare it with the cortex (PrepareBrainModel(..., true))");
  }
  if (!brain.pipelineModel->GetPrecomputation())
  {
    throw Error("the prepared model has no solver precomputation: make it (PrecomputeBrainModel) before writing the "
                "bundle");
  }
  // Written beside the target and renamed at the end: never a half-written bundle.
  fs::path target = fs::absolute(folder).lexically_normal();
  if (!target.has_filename())
  {
    target = target.parent_path(); // "plan/"
  }
  const fs::path partial = target.parent_path() / (target.filename().string() + ".partial-" + std::to_string(::getpid()));
  std::error_code ignored;
  fs::remove_all(partial, ignored);
  fs::create_directories(partial);
  json files = json::array();
  json manifest;
  const auto add = [&](const std::string & name, const std::string & role) {
    const fs::path path = partial / name;
    files.push_back({ { "name", name }, { "role", role }, { "bytes", fs::file_size(path) }, { "crc32", FileCrc32(path) } });
  };
  try
  {
    WriteTextFileAtomically((partial / "model.bin").string(), ModelBytes(brain));
    add("model.bin", "model");
    {
      BinaryWriter precomputation;
      brain.pipelineModel->GetPrecomputation()->Write(precomputation);
      WriteTextFileAtomically((partial / "precomputation.bin").string(), precomputation.Bytes());
    }
    add("precomputation.bin", "solver precomputation");
    itk::WriteBiomechanicalImage(bundle.preoperativeImage.GetPointer(), partial / "preoperative.nii.gz");
    add("preoperative.nii.gz", "preoperative image");
    itk::WriteBiomechanicalImage(
      itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(brain.brainMask).GetPointer(),
      partial / "brain-mask.nii.gz");
    add("brain-mask.nii.gz", "brain mask");
    itk::WriteBiomechanicalImage(brain.tissueLabelImage.GetPointer(), partial / "tissue-classes.nii.gz");
    add("tissue-classes.nii.gz", "tissue classes");
    for (std::size_t k = 0; k < bundle.labelMaps.size(); ++k)
    {
      const std::string name = "labels-" + std::to_string(k) + ".nii.gz";
      itk::WriteBiomechanicalImage(bundle.labelMaps[k].GetPointer(), partial / name);
      add(name, "label map");
    }
    // For viewers only: not read back.
    WriteMesh((partial / "model.vtu").string(), brain.model);
    add("model.vtu", "view");
    if (brain.model.discretization == Discretization::Meshless)
    {
      WriteIntegrationPoints((partial / "integration-points.vtu").string(), brain.model);
      add("integration-points.vtu", "view");
    }
    WriteSurface((partial / "brain.vtp").string(), brain.surfaces.brain);
    add("brain.vtp", "view");
    WriteSurface((partial / "skull.vtp").string(), brain.surfaces.skull);
    add("skull.vtp", "view");
    WriteSurface((partial / "cortex.vtp").string(), brain.cortex);
    add("cortex.vtp", "view");

    manifest = bundle.manifest.is_object() ? bundle.manifest : json::object();
    manifest["format"] = kFormatName;
    manifest["version"] = kModelBundleVersion;
    manifest["module_version"] = BMR_MODULE_VERSION;
    manifest["created_utc"] = UtcNow();
    manifest["preoperative_geometry"] = GeometryJson(bundle.preoperativeImage);
    json settings = json::object();
    for (const auto & field : RegistrationSettingFields())
    {
      settings[field.name] = field.Text(bundle.settings);
    }
    manifest["settings"] = settings;
    manifest["label_maps"] = bundle.labelMapNames;
    const ModelCounts counts = CountModel(brain.model);
    manifest["model"] = { { "grid", ImageGridKindName(bundle.settings.model.grid.kind) },
                          { "nodes", counts.nodes },
                          { "cells", counts.cells },
                          { "dofs", counts.dofs },
                          { "integration_points", counts.integrationPoints },
                          { "exposed_nodes", brain.exposedNodes.size() },
                          { "fixed_nodes", brain.model.NodeSet("skull_base").size() },
                          { "contact_nodes", brain.model.NodeSet("contact").size() },
                          { "mean_edge_length_mm", brain.gridQuality.meanEdgeLength },
                          { "volume_error", brain.gridQuality.volumeError },
                          { "resected_volume_mm3", brain.resectedVolume },
                          { "brain_surface", SurfaceCountsJson(brain.surfaces.brain) },
                          { "skull", SurfaceCountsJson(brain.surfaces.skull) },
                          { "cortex", SurfaceCountsJson(brain.cortex) } };
    manifest["classification"] = { { "centroids", brain.classificationFit.centroids },
                                   { "iterations", brain.classificationFit.iterations },
                                   { "converged", brain.classificationFit.converged },
                                   { "csf", CsfClassJson(brain) },
                                   { "csf_contrast_choice", static_cast<int>(brain.csfClass.contrast) },
                                   { "csf_class_index", brain.csfClass.csfClass },
                                   { "csf_volume_mm3", brain.csfVolume } };
    manifest["warnings"] = brain.warnings;
    manifest["files"] = files;
    WriteTextFileAtomically((partial / "manifest.json").string(), manifest.dump(2) + "\n");
  }
  catch (...)
  {
    fs::remove_all(partial, ignored);
    throw;
  }
  // Replace an earlier bundle only once the new one is complete.
  const fs::path previous = target.parent_path() / (target.filename().string() + ".previous-" + std::to_string(::getpid()));
  if (fs::exists(target))
  {
    if (!fs::exists(target / "manifest.json") && !fs::is_empty(target))
    {
      fs::remove_all(partial, ignored);
      throw Error("cannot write the model bundle '" + target.string() +
                  "': the folder exists and is not a model bundle; give a new folder");
    }
    fs::rename(target, previous);
  }
  fs::rename(partial, target);
  fs::remove_all(previous, ignored);
  return manifest;
}

ModelBundle
ReadModelBundle(const fs::path & folder)
{
  const std::string where = "model bundle '" + folder.string() + "'";
  if (!fs::is_directory(folder))
  {
    throw Error("cannot read the " + where + ": no such folder; make it with `biomech prepare`");
  }
  ModelBundle bundle;
  const fs::path manifestPath = folder / "manifest.json";
  if (!fs::is_regular_file(manifestPath))
  {
    throw Error("cannot read the " + where + ": it has no manifest.json (not a bundle, or not completely written); "
                "prepare it again");
  }
  try
  {
    bundle.manifest = json::parse(ReadTextFile(manifestPath.string()));
  }
  catch (const json::exception & error)
  {
    throw Error("cannot read the " + where + ": manifest.json does not parse (" + error.what() +
                "); prepare the bundle again");
  }
  const json & manifest = bundle.manifest;
  if (manifest.value("format", std::string()) != kFormatName)
  {
    throw Error("cannot read the " + where + ": manifest.json is not a model bundle's manifest");
  }
  if (const int version = manifest.value("version", -1);
      version < kOldestModelBundleVersion || version > kModelBundleVersion)
  {
    throw Error("cannot read the " + where + ": it is a bundle of format version " +
                std::to_string(manifest.value("version", -1)) + " (module " + manifest.value("module_version", "?") +
                "), this module (" + BMR_MODULE_VERSION + ") reads versions " + std::to_string(kOldestModelBundleVersion) +
                " to " + std::to_string(kModelBundleVersion) +
                "; prepare it again with this module");
  }
  try
  {
    for (const json & file : manifest.at("files"))
    {
      const std::string name = file.at("name").get<std::string>();
      const fs::path    path = folder / name;
      if (!fs::is_regular_file(path))
      {
        throw Error("cannot read the " + where + ": its " + name + " is missing; prepare the bundle again");
      }
      const auto bytes = fs::file_size(path);
      if (bytes != file.at("bytes").get<std::uintmax_t>())
      {
        throw Error("cannot read the " + where + ": its " + name + " has " + std::to_string(bytes) +
                    " bytes, the manifest says " + std::to_string(file.at("bytes").get<std::uintmax_t>()) +
                    " (truncated or replaced); prepare the bundle again");
      }
      if (FileCrc32(path) != file.at("crc32").get<std::uint32_t>())
      {
        throw Error("cannot read the " + where + ": its " + name +
                    " does not match the manifest's checksum (edited or damaged); prepare the bundle again");
      }
    }

    BrainModel & brain = bundle.model;
    BinaryReader model(ReadTextFile((folder / "model.bin").string()), "the " + where + "'s model.bin",
                       kPrepareAgain);
    ReadModelBytes(model, brain);
    {
      BinaryReader precomputation(ReadTextFile((folder / "precomputation.bin").string()),
                                  "the " + where + "'s precomputation.bin", kPrepareAgain);
      auto stored = std::make_shared<const SolverPrecomputation>(SolverPrecomputation::Read(precomputation));
      // Of this model (settings aside: an update may solve with others, and then makes its own).
      if (const std::string mismatch = stored->Mismatch(brain.pipelineModel->GetModel(), stored->Settings());
          !mismatch.empty())
      {
        throw Error("cannot read the " + where + ": its precomputation.bin does not belong to its model.bin (made " +
                    mismatch + "); " + kPrepareAgain);
      }
      brain.pipelineModel->SetPrecomputation(std::move(stored));
    }

    for (const auto & [name, text] : manifest.at("settings").items())
    {
      const auto * field = FindSettingField(RegistrationSettingFields(), name);
      if (field == nullptr)
      {
        throw Error("cannot read the " + where + ": its manifest has the unknown setting '" + name +
                    "'; prepare the bundle again with this module");
      }
      field->SetText(bundle.settings, text.get<std::string>());
    }
    const json & geometry = manifest.at("preoperative_geometry");
    bundle.preoperativeImage =
      itk::ReadBiomechanicalImage<RegistrationImage>((folder / "preoperative.nii.gz").string(), where + "'s image");
    SetGeometry(bundle.preoperativeImage.GetPointer(), geometry, "preoperative image");
    auto mask = itk::ReadBiomechanicalImage<RegistrationLabelImage>((folder / "brain-mask.nii.gz").string(),
                                                                     where + "'s brain mask");
    SetGeometry(mask.GetPointer(), geometry, "brain mask");
    brain.brainMask = itk::MakeBiomechanicalVolume<std::uint8_t>(mask.GetPointer());
    auto classes = itk::ReadBiomechanicalImage<RegistrationLabelImage>((folder / "tissue-classes.nii.gz").string(),
                                                                        where + "'s tissue classes");
    SetGeometry(classes.GetPointer(), geometry, "tissue classes");
    brain.tissueLabelImage = classes;
    bundle.labelMapNames = manifest.at("label_maps").get<std::vector<std::string>>();
    for (std::size_t k = 0; k < bundle.labelMapNames.size(); ++k)
    {
      auto labels = itk::ReadBiomechanicalImage<RegistrationLabelImage>(
        (folder / ("labels-" + std::to_string(k) + ".nii.gz")).string(), where + "'s label map");
      SetGeometry(labels.GetPointer(), geometry, "label map");
      bundle.labelMaps.push_back(labels);
    }
    const json & counts = manifest.at("model");
    brain.gridQuality.meanEdgeLength = counts.at("mean_edge_length_mm").get<double>();
    brain.gridQuality.volumeError = counts.at("volume_error").get<double>();
    brain.resectedVolume = counts.at("resected_volume_mm3").get<double>();
    const json & classification = manifest.at("classification");
    brain.classificationFit.centroids = classification.at("centroids").get<std::vector<double>>();
    brain.classificationFit.iterations = classification.at("iterations").get<int>();
    brain.classificationFit.converged = classification.at("converged").get<bool>();
    brain.csfClass.contrast = static_cast<TissueContrast>(classification.at("csf_contrast_choice").get<int>());
    brain.csfClass.csfClass = classification.at("csf_class_index").get<int>();
    brain.csfClass.reason = classification.at("csf").at("chosen").get<std::string>();
    brain.csfVolume = classification.at("csf_volume_mm3").get<double>();
    brain.warnings = manifest.at("warnings").get<std::vector<std::string>>();
  }
  catch (const json::exception & error)
  {
    throw Error("cannot read the " + where + ": its manifest lacks what this module needs (" +
                std::string(error.what()) + "); prepare the bundle again");
  }
  return bundle;
}

namespace
{

/** The bundle's model.bin checksum from its manifest (0 when absent). */
std::uint32_t
ModelChecksum(const json & manifest)
{
  for (const json & file : manifest.value("files", json::array()))
  {
    if (file.value("name", std::string()) == "model.bin")
    {
      return file.value("crc32", std::uint32_t{ 0 });
    }
  }
  return 0;
}

} // namespace

UpdateSolution
MakeUpdateSolution(const SolveResult & solve, const json & bundleManifest, int coldSteps)
{
  UpdateSolution solution;
  solution.start = WarmStartFrom(solve);
  solution.steps = solve.steps;
  solution.coldSteps = coldSteps;
  solution.modelChecksum = ModelChecksum(bundleManifest);
  solution.nodes = static_cast<Index>(solution.start.state.size());
  return solution;
}

void
WriteUpdateSolution(const fs::path & file, const UpdateSolution & solution)
{
  BinaryWriter out;
  for (const char c : kSolutionMagic)
  {
    out.Value(c);
  }
  out.Value<std::int32_t>(kSolutionVersion);
  out.Value<std::uint32_t>(solution.modelChecksum);
  out.Value<std::int32_t>(solution.nodes);
  out.Value<std::int32_t>(solution.steps);
  out.Value<std::int32_t>(solution.coldSteps);
  out.Points(solution.start.state);
  WriteTextFileAtomically(file.string(), out.Bytes());
}

UpdateSolution
ReadUpdateSolution(const fs::path & previous, const json & bundleManifest)
{
  const fs::path file = fs::is_directory(previous) ? previous / "solution.bin" : previous;
  const std::string what = "the previous update's solution '" + file.string() + "'";
  if (!fs::is_regular_file(file))
  {
    throw Error("cannot read " + what + ": no such file; give the output folder of an earlier `biomech update` of "
                "this bundle (--previous OUT)");
  }
  BinaryReader   in(ReadTextFile(file.string()), what, "solve without --previous, or give another update's folder");
  UpdateSolution solution;
  for (const char c : kSolutionMagic)
  {
    if (in.Value<char>() != c)
    {
      in.Fail("not a solution file");
    }
  }
  const auto version = in.Value<std::int32_t>();
  if (version != kSolutionVersion)
  {
    in.Fail("format version " + std::to_string(version) + ", this module reads " + std::to_string(kSolutionVersion));
  }
  solution.modelChecksum = in.Value<std::uint32_t>();
  solution.nodes = in.Value<std::int32_t>();
  solution.steps = in.Value<std::int32_t>();
  solution.coldSteps = in.Value<std::int32_t>();
  solution.start.state = in.Points();
  if (!in.AtEnd() || static_cast<Index>(solution.start.state.size()) != solution.nodes)
  {
    in.Fail("a size that does not match its header");
  }
  const std::uint32_t expected = ModelChecksum(bundleManifest);
  const Index         nodes = bundleManifest.value("model", json::object()).value("nodes", Index{ -1 });
  if (solution.modelChecksum != expected || solution.nodes != nodes)
  {
    throw Error("cannot use " + what + ": it solved another model (" + std::to_string(solution.nodes) +
                " nodes) than this bundle's (" + std::to_string(nodes) +
                " nodes, or the same count but another model.bin); give an update of this bundle, or none");
  }
  return solution;
}

} // namespace bmr
