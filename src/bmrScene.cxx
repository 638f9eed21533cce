#include "bmrScene.h"

#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"
#include "bmrMeshless.h"

#include <nlohmann/json.hpp>
#include <omp.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <limits>
#include <optional>
#include <set>
#include <sstream>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bmr
{
namespace
{

std::string
JoinNames(const std::vector<std::string> & names)
{
  std::string joined;
  for (const auto & name : names)
  {
    joined += (joined.empty() ? "" : ", ") + name;
  }
  return joined.empty() ? "none" : joined;
}

/** A JSON value with its key path, so every error names where it is. */
class SceneValue
{
public:
  SceneValue(const json & value, std::string keyPath, std::string scenePath)
    : m_Value(value)
    , m_KeyPath(std::move(keyPath))
    , m_ScenePath(std::move(scenePath))
  {}

  const json &        Json() const { return m_Value; }
  const std::string & KeyPath() const { return m_KeyPath; }
  const std::string & ScenePath() const { return m_ScenePath; }

  [[noreturn]] void Fail(const std::string & problem) const
  {
    throw Error(m_ScenePath + ": " + (m_KeyPath.empty() ? std::string() : m_KeyPath + ": ") + problem);
  }

  bool IsObject() const { return m_Value.is_object(); }
  bool IsString() const { return m_Value.is_string(); }
  bool IsArray() const { return m_Value.is_array(); }

  void RequireObject() const
  {
    if (!m_Value.is_object())
    {
      Fail(std::string("expected an object {...}, got ") + m_Value.type_name());
    }
  }

  /** Rejects keys outside `allowed`: catches typos instead of ignoring them. */
  void AllowOnly(const std::vector<std::string> & allowed) const
  {
    RequireObject();
    for (const auto & item : m_Value.items())
    {
      if (std::find(allowed.begin(), allowed.end(), item.key()) == allowed.end())
      {
        Child(item.key()).Fail("unknown key '" + item.key() + "' (allowed here: " + JoinNames(allowed) + ")");
      }
    }
  }

  bool Has(const std::string & key) const { return m_Value.is_object() && m_Value.contains(key); }

  SceneValue Child(const std::string & key) const
  {
    static const json missing;
    const json & value = Has(key) ? m_Value.at(key) : missing;
    return SceneValue(value, m_KeyPath.empty() ? key : m_KeyPath + "." + key, m_ScenePath);
  }

  SceneValue Required(const std::string & key) const
  {
    RequireObject();
    if (!Has(key))
    {
      Fail("missing required key '" + key + "'");
    }
    return Child(key);
  }

  std::optional<SceneValue> Optional(const std::string & key) const
  {
    if (!Has(key))
    {
      return std::nullopt;
    }
    return Child(key);
  }

  std::size_t ArraySize() const
  {
    if (!m_Value.is_array())
    {
      Fail(std::string("expected an array [...], got ") + m_Value.type_name());
    }
    return m_Value.size();
  }

  SceneValue Element(std::size_t index) const
  {
    return SceneValue(m_Value.at(index), m_KeyPath + "[" + std::to_string(index) + "]", m_ScenePath);
  }

  double Number() const
  {
    if (!m_Value.is_number())
    {
      Fail(std::string("expected a number, got ") + m_Value.type_name());
    }
    const double value = m_Value.get<double>();
    if (!std::isfinite(value))
    {
      Fail("expected a finite number");
    }
    return value;
  }

  double PositiveNumber() const
  {
    const double value = Number();
    if (!(value > 0.0))
    {
      Fail("must be greater than 0, got " + m_Value.dump());
    }
    return value;
  }

  double NonNegativeNumber() const
  {
    const double value = Number();
    if (value < 0.0)
    {
      Fail("must not be negative, got " + m_Value.dump());
    }
    return value;
  }

  long long Integer() const
  {
    // Above 2^63 - 1 nlohmann keeps an unsigned integer, which get<long long> would wrap to a negative number.
    if (m_Value.is_number_unsigned() &&
        m_Value.get<unsigned long long>() > static_cast<unsigned long long>(std::numeric_limits<long long>::max()))
    {
      Fail("integer " + m_Value.dump() + " is too large");
    }
    if (m_Value.is_number_integer())
    {
      return m_Value.get<long long>();
    }
    if (m_Value.is_number_float())
    {
      const double value = m_Value.get<double>();
      if (std::isfinite(value) && value == std::round(value) && std::abs(value) < 9.0e15)
      {
        return static_cast<long long>(value);
      }
    }
    Fail(std::string("expected an integer, got ") + (m_Value.is_number() ? m_Value.dump() : m_Value.type_name()));
  }

  int IntegerInRange(long long minimum, long long maximum) const
  {
    const long long value = Integer();
    if (value < minimum || value > maximum)
    {
      Fail("must be between " + std::to_string(minimum) + " and " + std::to_string(maximum) + ", got " +
           std::to_string(value));
    }
    return static_cast<int>(value);
  }

  bool Boolean() const
  {
    if (!m_Value.is_boolean())
    {
      Fail(std::string("expected true or false, got ") + m_Value.type_name());
    }
    return m_Value.get<bool>();
  }

  std::string String() const
  {
    if (!m_Value.is_string())
    {
      Fail(std::string("expected a string, got ") + m_Value.type_name());
    }
    return m_Value.get<std::string>();
  }

  std::string NonEmptyString() const
  {
    std::string value = String();
    if (value.empty())
    {
      Fail("must not be empty");
    }
    return value;
  }

  /** One of `choices`, e.g. "hexahedra". */
  std::string Choice(const std::vector<std::string> & choices) const
  {
    const std::string value = String();
    if (std::find(choices.begin(), choices.end(), value) == choices.end())
    {
      Fail("'" + value + "' is not one of: " + JoinNames(choices));
    }
    return value;
  }

  void RequireArrayOfSize(std::size_t size) const
  {
    if (ArraySize() != size)
    {
      Fail("expected an array of " + std::to_string(size) + " values, got " + std::to_string(m_Value.size()));
    }
  }

  Vector3 Vector() const
  {
    RequireArrayOfSize(3);
    return Vector3(Element(0).Number(), Element(1).Number(), Element(2).Number());
  }

  Vector3 PositiveVector() const
  {
    RequireArrayOfSize(3);
    return Vector3(Element(0).PositiveNumber(), Element(1).PositiveNumber(), Element(2).PositiveNumber());
  }

  std::array<bool, 3> Components() const
  {
    RequireArrayOfSize(3);
    const std::array<bool, 3> components{ Element(0).Boolean(), Element(1).Boolean(), Element(2).Boolean() };
    if (!components[0] && !components[1] && !components[2])
    {
      Fail("at least one component must be true");
    }
    return components;
  }

private:
  const json & m_Value;
  std::string  m_KeyPath;
  std::string  m_ScenePath;
};

std::string
ResolvePath(const std::string & sceneFolder, const std::string & relativeOrAbsolute)
{
  const fs::path path(relativeOrAbsolute);
  if (path.is_absolute() || sceneFolder.empty())
  {
    return path.lexically_normal().string();
  }
  return (fs::path(sceneFolder) / path).lexically_normal().string();
}

GridCells
ParseGridCells(const SceneValue & value)
{
  const std::string name = value.Choice({ "hexahedra", "tetrahedra", "mixed" });
  if (name == "tetrahedra")
  {
    return GridCells::Tetrahedra;
  }
  return name == "mixed" ? GridCells::Mixed : GridCells::Hexahedra;
}

const char *
GridCellsName(GridCells cells)
{
  switch (cells)
  {
    case GridCells::Tetrahedra: return "tetrahedra";
    case GridCells::Mixed: return "mixed hexahedra and tetrahedra";
    default: return "hexahedra";
  }
}

LoadCurve
ParseCurve(const SceneValue & value)
{
  value.AllowOnly({ "shape", "ramp_time" });
  LoadCurve curve;
  if (const auto shape = value.Optional("shape"))
  {
    const std::string name = shape->Choice({ "smooth", "linear", "step" });
    curve.shape = name == "linear" ? LoadCurve::Shape::Linear
                                   : (name == "step" ? LoadCurve::Shape::Step : LoadCurve::Shape::Smooth);
  }
  if (const auto rampTime = value.Optional("ramp_time"))
  {
    curve.rampTime = rampTime->PositiveNumber();
  }
  return curve;
}

Material
ParseMaterial(const SceneValue & value, std::size_t index, std::optional<int> & label)
{
  value.AllowOnly({ "name", "label", "youngs_modulus", "poisson_ratio", "density" });
  Material material;
  material.name = value.Has("name") ? value.Child("name").NonEmptyString() : "material" + std::to_string(index);
  if (const auto labelValue = value.Optional("label"))
  {
    label = labelValue->IntegerInRange(std::numeric_limits<int>::min(), std::numeric_limits<int>::max());
  }
  material.youngsModulus = value.Required("youngs_modulus").PositiveNumber();
  const SceneValue poisson = value.Required("poisson_ratio");
  material.poissonRatio = poisson.Number();
  if (!(material.poissonRatio > -1.0 && material.poissonRatio < 0.5))
  {
    poisson.Fail("must lie in (-1, 0.5) for a compressible material, got " + poisson.Json().dump());
  }
  if (const auto density = value.Optional("density"))
  {
    material.density = density->PositiveNumber();
  }
  return material;
}

/** Sorted, unique node ids. */
std::vector<Index>
SortedUnique(std::vector<Index> ids)
{
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  return ids;
}

std::string
BoundsText(const Model & model)
{
  Vector3 lower = Vector3::Constant(std::numeric_limits<double>::max());
  Vector3 upper = Vector3::Constant(std::numeric_limits<double>::lowest());
  for (const auto & node : model.nodes)
  {
    lower = lower.cwiseMin(node);
    upper = upper.cwiseMax(node);
  }
  std::ostringstream text;
  text << "the mesh spans [" << lower.x() << ", " << upper.x() << "] x [" << lower.y() << ", " << upper.y() << "] x ["
       << lower.z() << ", " << upper.z() << "] mm";
  return text.str();
}

class SceneParser
{
public:
  SceneParser(const json & root, const std::string & scenePath)
    : m_Root(root, "", scenePath)
    , m_ScenePath(scenePath)
  {
    m_SceneFolder = fs::path(scenePath).parent_path().string();
  }

  Scene Parse()
  {
    m_Root.AllowOnly({ "description", "mesh", "material_array", "materials", "material_fields", "discretization",
                       "meshless",
                       "node_sets", "fixed", "prescribed_displacements", "gravity", "gravity_curve", "fluid_surface", "contact",
                       "tools", "solver", "output" });
    m_Scene.path = m_ScenePath;
    if (const auto description = m_Root.Optional("description"))
    {
      m_Scene.description = description->String();
    }
    ParseMaterials();
    ParseMesh();
    AssignMaterials();
    ParseNodeSets();
    ParseFixed();
    ParsePrescribedDisplacements();
    ParseGravity();
    ParseContact();
    ParseTools();
    ParseSolver();
    ParseOutput();
    ParseDiscretization();
    try
    {
      m_Scene.model.Validate();
    }
    catch (const Error & error)
    {
      throw Error(m_ScenePath + ": the model is not valid: " + error.what());
    }
    return std::move(m_Scene);
  }

private:
  Model & TheModel() { return m_Scene.model; }

  void ParseMaterials()
  {
    if (m_Root.Has("material_fields"))
    {
      // Per-cell properties come from the mesh file (AssignMaterials).
      for (const char * conflicting : { "materials", "material_array" })
      {
        if (m_Root.Has(conflicting))
        {
          m_Root.Child(conflicting).Fail("give either \"material_fields\" (properties per cell from the mesh file) or "
                                         "\"materials\", not both");
        }
      }
      if (!m_Root.Required("mesh").IsString())
      {
        m_Root.Child("material_fields")
          .Fail("applies only to a mesh read from a file (its cell-data arrays hold the properties)");
      }
      return;
    }
    if (!m_Root.Has("materials") && MaterialsComeWithIntegrationPoints())
    {
      return;
    }
    const SceneValue materials = m_Root.Required("materials");
    if (materials.ArraySize() == 0)
    {
      materials.Fail("at least one material is needed");
    }
    std::map<int, std::size_t> labelOwner;
    for (std::size_t index = 0; index < materials.ArraySize(); ++index)
    {
      const SceneValue   entry = materials.Element(index);
      std::optional<int> label;
      TheModel().materials.push_back(ParseMaterial(entry, index, label));
      m_MaterialLabels.push_back(label);
      if (label)
      {
        const auto [owner, inserted] = labelOwner.emplace(*label, index);
        if (!inserted)
        {
          entry.Child("label").Fail("label " + std::to_string(*label) + " is already used by materials[" +
                                    std::to_string(owner->second) + "]");
        }
      }
    }
  }

  void ParseMesh()
  {
    const SceneValue mesh = m_Root.Required("mesh");
    if (mesh.IsString())
    {
      const std::string labelArray =
        m_Root.Has("material_array") ? m_Root.Child("material_array").NonEmptyString() : "material";
      const std::string path = ResolvePath(m_SceneFolder, mesh.NonEmptyString());
      try
      {
        m_MeshData = ReadMesh(path, labelArray);
      }
      catch (const Error & error)
      {
        mesh.Fail(error.what());
      }
      if (m_Root.Has("material_array") && m_MeshData.cellLabels.empty())
      {
        std::vector<std::string> arrays;
        for (const auto & entry : m_MeshData.cellData)
        {
          arrays.push_back(entry.first);
        }
        m_Root.Child("material_array")
          .Fail("mesh '" + path + "' has no cell-data array '" + labelArray + "' (cell-data arrays: " +
                JoinNames(arrays) + ")");
      }
      const std::vector<Material> materials = std::move(TheModel().materials);
      TheModel() = std::move(m_MeshData.model);
      TheModel().materials = materials;
      m_Scene.meshSource = path;
      m_MeshFromFile = true;
      return;
    }

    if (!mesh.IsObject())
    {
      mesh.Fail(std::string("expected a file name or an object with \"generate\", got ") + mesh.Json().type_name());
    }
    if (m_Root.Has("material_array"))
    {
      m_Root.Child("material_array").Fail("applies only to a mesh read from a file; generated meshes use materials[0]");
    }
    const std::string shape = mesh.Required("generate").Choice({ "block", "ellipsoid" });
    const std::vector<Material> materials = TheModel().materials;
    const Material &            material = materials.front();
    std::ostringstream          source;
    source << std::setprecision(6);
    try
    {
      if (shape == "block")
      {
        mesh.AllowOnly({ "generate", "size", "divisions", "cells", "origin" });
        const Vector3    size = mesh.Required("size").PositiveVector();
        const SceneValue divisionsValue = mesh.Required("divisions");
        divisionsValue.RequireArrayOfSize(3);
        std::array<int, 3> divisions{};
        for (int axis = 0; axis < 3; ++axis)
        {
          divisions[axis] = divisionsValue.Element(axis).IntegerInRange(1, 100000);
        }
        const GridCells cells = mesh.Has("cells") ? ParseGridCells(mesh.Child("cells")) : GridCells::Hexahedra;
        const Vector3   origin = mesh.Has("origin") ? mesh.Child("origin").Vector() : Vector3::Zero();
        TheModel() = MakeBlockMesh(size, divisions, cells, material, origin);
        source << "generated block " << size.x() << " x " << size.y() << " x " << size.z() << " mm, " << divisions[0]
               << " x " << divisions[1] << " x " << divisions[2] << " cells, " << GridCellsName(cells);
      }
      else
      {
        mesh.AllowOnly({ "generate", "semi_axes", "spacing", "cells" });
        const Vector3   semiAxes = mesh.Required("semi_axes").PositiveVector();
        const double    spacing = mesh.Required("spacing").PositiveNumber();
        const GridCells cells = mesh.Has("cells") ? ParseGridCells(mesh.Child("cells")) : GridCells::Hexahedra;
        TheModel() = MakeEllipsoidMesh(semiAxes, spacing, cells, material);
        source << "generated ellipsoid, semi-axes " << semiAxes.x() << ", " << semiAxes.y() << ", " << semiAxes.z()
               << " mm, spacing " << spacing << " mm, " << GridCellsName(cells);
      }
    }
    catch (const Error & error)
    {
      mesh.Fail(error.what());
    }
    if (TheModel().cells.empty())
    {
      mesh.Fail("the generated mesh has no cells; use a smaller spacing");
    }
    TheModel().materials = materials;
    m_Scene.meshSource = source.str();
  }

  /** A meshless scene whose integration points come from a file with a material per point. */
  bool MaterialsComeWithIntegrationPoints() const
  {
    return m_Root.Has("meshless") && m_Root.Child("meshless").Has("integration_points");
  }

  /** Index of a material with these properties in the model, added when new:
   *  cells (or integration points) with equal properties share one entry. */
  Index MaterialIndex(Material material)
  {
    const auto key = std::make_tuple(material.youngsModulus, material.poissonRatio, material.density);
    const auto [position, inserted] = m_MaterialIndexOfProperties.emplace(key, static_cast<Index>(TheModel().materials.size()));
    if (inserted)
    {
      std::ostringstream name;
      name << "E" << material.youngsModulus << "_nu" << material.poissonRatio;
      material.name = name.str();
      TheModel().materials.push_back(material);
    }
    return position->second;
  }

  /** "material_fields": each cell's neo-Hookean properties from cell-data arrays of the mesh file. */
  void AssignMaterialFields()
  {
    const SceneValue fields = m_Root.Child("material_fields");
    fields.AllowOnly({ "youngs_modulus", "poisson_ratio", "density" });
    Model &           model = TheModel();
    const std::size_t cellCount = model.cells.size();
    auto              arrayOf = [&](const std::string & key) -> const std::vector<double> * {
      if (!fields.Has(key))
      {
        return nullptr;
      }
      const SceneValue  nameValue = fields.Child(key);
      const std::string name = nameValue.NonEmptyString();
      const auto        found = m_MeshData.cellData.find(name);
      if (found == m_MeshData.cellData.end() || found->second.components != 1 || found->second.Tuples() != cellCount)
      {
        std::vector<std::string> arrays;
        for (const auto & entry : m_MeshData.cellData)
        {
          arrays.push_back(entry.first);
        }
        nameValue.Fail("the mesh has no one-component cell-data array '" + name + "' (cell-data arrays: " +
                       JoinNames(arrays) + ")");
      }
      return &found->second.values;
    };
    const std::vector<double> * youngs = arrayOf("youngs_modulus");
    const std::vector<double> * poisson = arrayOf("poisson_ratio");
    const std::vector<double> * density = arrayOf("density");
    if (youngs == nullptr || poisson == nullptr)
    {
      fields.Fail("needs \"youngs_modulus\" and \"poisson_ratio\" (names of cell-data arrays); \"density\" is optional "
                  "(default 1000 kg/m^3)");
    }
    model.materials.clear();
    for (std::size_t cellId = 0; cellId < cellCount; ++cellId)
    {
      Material material;
      material.youngsModulus = (*youngs)[cellId];
      material.poissonRatio = (*poisson)[cellId];
      if (density != nullptr)
      {
        material.density = (*density)[cellId];
      }
      if (!(material.youngsModulus > 0.0 && material.poissonRatio > -1.0 && material.poissonRatio < 0.5 &&
            material.density > 0.0))
      {
        fields.Fail("cell " + std::to_string(cellId) + " has E = " + std::to_string(material.youngsModulus) +
                    " Pa, nu = " + std::to_string(material.poissonRatio) + ", density = " +
                    std::to_string(material.density) + "; need E > 0, -1 < nu < 0.5, density > 0");
      }
      model.cells[cellId].material = MaterialIndex(material);
    }
  }

  void AssignMaterials()
  {
    if (m_Root.Has("material_fields"))
    {
      AssignMaterialFields();
      return;
    }
    Model & model = TheModel();
    // One material without a label applies to every cell, whatever labels the
    // mesh carries (e.g. a mesh written by `biomech make-mesh`).
    const bool singleUnlabelled = m_MaterialLabels.size() == 1 && !m_MaterialLabels[0];
    if (!m_MeshFromFile || m_MeshData.cellLabels.empty() || singleUnlabelled)
    {
      for (auto & cell : model.cells)
      {
        cell.material = 0;
      }
      return;
    }
    const std::string labelArray =
      m_Root.Has("material_array") ? m_Root.Child("material_array").String() : std::string("material");
    const SceneValue   materials = m_Root.Child("materials");
    std::map<int, Index> materialOfLabel;
    for (std::size_t index = 0; index < m_MaterialLabels.size(); ++index)
    {
      if (!m_MaterialLabels[index])
      {
        materials.Element(index).Fail("missing key 'label': the mesh's cells carry material labels in cell-data array '" +
                                      labelArray + "', so every material needs the label it applies to");
      }
      materialOfLabel[*m_MaterialLabels[index]] = static_cast<Index>(index);
    }
    for (std::size_t cellId = 0; cellId < model.cells.size(); ++cellId)
    {
      const int  label = m_MeshData.cellLabels[cellId];
      const auto found = materialOfLabel.find(label);
      if (found == materialOfLabel.end())
      {
        std::vector<std::string> known;
        for (const auto & entry : materialOfLabel)
        {
          known.push_back(std::to_string(entry.first));
        }
        materials.Fail("cell " + std::to_string(cellId) + " has label " + std::to_string(label) + " in '" +
                       labelArray + "', but no material has label " + std::to_string(label) +
                       " (material labels: " + JoinNames(known) + ")");
      }
      model.cells[cellId].material = found->second;
    }
  }

  std::vector<Index> SelectNodes(const SceneValue & definition, const std::string & name)
  {
    static const std::vector<std::string> selectors{ "ids",
                                                     "point_data",
                                                     "nodes_in_box",
                                                     "surface_nodes_in_box",
                                                     "nodes_in_sphere",
                                                     "surface_nodes_in_sphere" };
    definition.AllowOnly(selectors);
    if (definition.Json().size() != 1)
    {
      definition.Fail("give exactly one of: " + JoinNames(selectors));
    }
    const Model &       model = TheModel();
    const std::string   selector = definition.Json().begin().key();
    const SceneValue    value = definition.Child(selector);
    std::vector<Index>  selected;

    if (selector == "ids")
    {
      for (std::size_t k = 0; k < value.ArraySize(); ++k)
      {
        const SceneValue id = value.Element(k);
        const long long  node = id.Integer();
        if (node < 0 || node >= static_cast<long long>(model.nodes.size()))
        {
          id.Fail("node " + std::to_string(node) + " does not exist (the mesh has nodes 0 to " +
                  std::to_string(model.nodes.size() - 1) + ")");
        }
        selected.push_back(static_cast<Index>(node));
      }
    }
    else if (selector == "point_data")
    {
      const std::string arrayName = value.NonEmptyString();
      const auto        array = m_MeshData.pointData.find(arrayName);
      if (array == m_MeshData.pointData.end())
      {
        std::vector<std::string> names;
        for (const auto & entry : m_MeshData.pointData)
        {
          names.push_back(entry.first);
        }
        value.Fail("the mesh has no point-data array '" + arrayName + "' (point-data arrays: " + JoinNames(names) +
                   ")" + (m_MeshFromFile ? "" : "; generated meshes have none, use their node sets instead"));
      }
      const DataArray & data = array->second;
      for (std::size_t node = 0; node < data.Tuples() && node < model.nodes.size(); ++node)
      {
        bool nonzero = false;
        for (int component = 0; component < data.components; ++component)
        {
          nonzero = nonzero || data.values[node * data.components + component] != 0.0;
        }
        if (nonzero)
        {
          selected.push_back(static_cast<Index>(node));
        }
      }
    }
    else
    {
      const bool         surfaceOnly = selector.rfind("surface_", 0) == 0;
      const bool         box = selector.find("box") != std::string::npos;
      std::vector<Index> candidates;
      if (surfaceOnly)
      {
        candidates = model.BoundaryNodes();
      }
      else
      {
        candidates.resize(model.nodes.size());
        for (std::size_t node = 0; node < model.nodes.size(); ++node)
        {
          candidates[node] = static_cast<Index>(node);
        }
      }
      if (box)
      {
        value.AllowOnly({ "min", "max" });
        const Vector3 lower = value.Required("min").Vector();
        const Vector3 upper = value.Required("max").Vector();
        if ((lower.array() > upper.array()).any())
        {
          value.Fail("'min' must not exceed 'max' in any component");
        }
        for (const Index node : candidates)
        {
          const Vector3 & x = model.nodes[node];
          if ((x.array() >= lower.array()).all() && (x.array() <= upper.array()).all())
          {
            selected.push_back(node);
          }
        }
      }
      else
      {
        value.AllowOnly({ "center", "centre", "radius" });
        if (value.Has("center") && value.Has("centre"))
        {
          value.Fail("give 'center' or 'centre', not both");
        }
        const Vector3 center = value.Required(value.Has("centre") ? "centre" : "center").Vector();
        const double  radius = value.Required("radius").PositiveNumber();
        for (const Index node : candidates)
        {
          if ((model.nodes[node] - center).norm() <= radius)
          {
            selected.push_back(node);
          }
        }
      }
    }

    selected = SortedUnique(std::move(selected));
    if (selected.empty())
    {
      definition.Fail("node set '" + name + "' selects no nodes; " + BoundsText(model));
    }
    return selected;
  }

  void ParseNodeSets()
  {
    const auto nodeSets = m_Root.Optional("node_sets");
    if (!nodeSets)
    {
      return;
    }
    nodeSets->RequireObject();
    for (const auto & item : nodeSets->Json().items())
    {
      const SceneValue definition = nodeSets->Child(item.key());
      if (item.key().empty())
      {
        definition.Fail("a node set needs a non-empty name");
      }
      if (TheModel().nodeSets.count(item.key()) != 0)
      {
        definition.Fail("node set '" + item.key() + "' already exists (the generated mesh defines it); choose another name");
      }
      TheModel().nodeSets[item.key()] = SelectNodes(definition, item.key());
    }
  }

  std::string NodeSetReference(const SceneValue & value)
  {
    const std::string name = value.NonEmptyString();
    if (TheModel().nodeSets.count(name) == 0)
    {
      std::vector<std::string> known;
      for (const auto & entry : TheModel().nodeSets)
      {
        known.push_back(entry.first);
      }
      value.Fail("no node set named '" + name + "' (node sets: " + JoinNames(known) + ")");
    }
    return name;
  }

  void ParseFixed()
  {
    const auto fixed = m_Root.Optional("fixed");
    if (!fixed)
    {
      return;
    }
    for (std::size_t index = 0; index < fixed->ArraySize(); ++index)
    {
      const SceneValue entry = fixed->Element(index);
      entry.AllowOnly({ "node_set", "components" });
      FixedConstraint constraint;
      constraint.nodeSet = NodeSetReference(entry.Required("node_set"));
      if (const auto components = entry.Optional("components"))
      {
        constraint.components = components->Components();
      }
      TheModel().fixedConstraints.push_back(constraint);
    }
  }

  void ReadDisplacementCsv(const SceneValue & value, PrescribedDisplacement & prescribed)
  {
    const std::string path = ResolvePath(m_SceneFolder, value.NonEmptyString());
    std::ifstream     stream(path);
    if (!stream)
    {
      value.Fail("cannot open displacement file '" + path + "'; check the path (relative to the scene file)");
    }
    const std::size_t nodeCount = TheModel().nodes.size();
    std::set<Index>   seen;
    std::string       line;
    int               lineNumber = 0;
    bool              firstDataLine = true;
    while (std::getline(stream, line))
    {
      ++lineNumber;
      const auto where = [&]() { return "'" + path + "' line " + std::to_string(lineNumber) + ": "; };
      line.erase(std::find_if(line.rbegin(), line.rend(), [](unsigned char c) { return !std::isspace(c); }).base(),
                 line.end());
      const auto firstChar = line.find_first_not_of(" \t");
      if (firstChar == std::string::npos || line[firstChar] == '#')
      {
        continue;
      }
      std::vector<std::string> fields;
      std::stringstream        lineStream(line);
      std::string              field;
      while (std::getline(lineStream, field, ','))
      {
        const auto begin = field.find_first_not_of(" \t");
        const auto end = field.find_last_not_of(" \t");
        fields.push_back(begin == std::string::npos ? "" : field.substr(begin, end - begin + 1));
      }
      if (fields.size() != 4)
      {
        value.Fail(where() + "expected 4 comma-separated values 'id,ux,uy,uz', got " + std::to_string(fields.size()));
      }
      double numbers[4];
      bool   numeric = true;
      for (int k = 0; k < 4; ++k)
      {
        char *       end = nullptr;
        const char * text = fields[k].c_str();
        numbers[k] = std::strtod(text, &end);
        numeric = numeric && !fields[k].empty() && *end == '\0' && std::isfinite(numbers[k]);
      }
      if (!numeric)
      {
        char * idEnd = nullptr;
        std::strtod(fields[0].c_str(), &idEnd);
        const bool idIsNumber = !fields[0].empty() && *idEnd == '\0';
        if (firstDataLine && !idIsNumber)
        {
          firstDataLine = false; // a header line such as "id,ux,uy,uz"
          continue;
        }
        value.Fail(where() + "expected numbers 'id,ux,uy,uz', got '" + line + "'");
      }
      firstDataLine = false;
      if (numbers[0] != std::round(numbers[0]) || numbers[0] < 0 || numbers[0] >= static_cast<double>(nodeCount))
      {
        std::ostringstream message;
        message << where() << "node " << fields[0] << " does not exist (the mesh has nodes 0 to " << nodeCount - 1
                << ")";
        value.Fail(message.str());
      }
      const Index node = static_cast<Index>(numbers[0]);
      if (!seen.insert(node).second)
      {
        value.Fail(where() + "node " + std::to_string(node) + " appears twice");
      }
      prescribed.nodes.push_back(node);
      prescribed.displacements.emplace_back(numbers[1], numbers[2], numbers[3]);
    }
    if (prescribed.nodes.empty())
    {
      value.Fail("displacement file '" + path + "' has no displacements (lines 'id,ux,uy,uz' in mm)");
    }
  }

  void ParsePrescribedDisplacements()
  {
    const auto list = m_Root.Optional("prescribed_displacements");
    if (!list)
    {
      return;
    }
    for (std::size_t index = 0; index < list->ArraySize(); ++index)
    {
      const SceneValue entry = list->Element(index);
      entry.AllowOnly({ "node_set", "displacement", "csv", "components", "curve" });
      PrescribedDisplacement prescribed;
      if (entry.Has("node_set") == entry.Has("csv"))
      {
        entry.Fail("give either 'node_set' with 'displacement', or 'csv'");
      }
      if (entry.Has("node_set"))
      {
        const std::string name = NodeSetReference(entry.Child("node_set"));
        const Vector3     displacement = entry.Required("displacement").Vector();
        prescribed.nodes = TheModel().nodeSets.at(name);
        prescribed.displacements.assign(prescribed.nodes.size(), displacement);
      }
      else
      {
        if (entry.Has("displacement"))
        {
          entry.Child("displacement").Fail("not allowed with 'csv' (the file gives each node's displacement)");
        }
        ReadDisplacementCsv(entry.Child("csv"), prescribed);
      }
      if (const auto components = entry.Optional("components"))
      {
        prescribed.components = components->Components();
      }
      if (const auto curve = entry.Optional("curve"))
      {
        prescribed.curve = ParseCurve(*curve);
      }
      TheModel().prescribedDisplacements.push_back(std::move(prescribed));
    }
  }

  void ParseGravity()
  {
    if (const auto gravity = m_Root.Optional("gravity"))
    {
      TheModel().bodyAcceleration = gravity->Vector();
    }
    if (const auto curve = m_Root.Optional("gravity_curve"))
    {
      if (!m_Root.Has("gravity"))
      {
        curve->Fail("needs 'gravity'");
      }
      TheModel().bodyForceCurve = ParseCurve(*curve);
    }
    if (const auto surface = m_Root.Optional("fluid_surface"))
    {
      if (!m_Root.Has("gravity"))
      {
        surface->Fail("needs 'gravity' (the CSF's surface is level under it)");
      }
      TheModel().fluidSurface = surface->Vector();
    }
  }

  void ParseContact()
  {
    const auto list = m_Root.Optional("contact");
    if (!list)
    {
      return;
    }
    for (std::size_t index = 0; index < list->ArraySize(); ++index)
    {
      const SceneValue entry = list->Element(index);
      entry.AllowOnly({ "name", "surface", "body_side", "flip_normals", "slave_node_set" });
      const SceneValue surfaceValue = entry.Required("surface");
      ContactSurface   surface;
      if (surfaceValue.IsString())
      {
        const std::string path = ResolvePath(m_SceneFolder, surfaceValue.NonEmptyString());
        try
        {
          surface = ReadSurface(path);
        }
        catch (const Error & error)
        {
          surfaceValue.Fail(error.what());
        }
      }
      else if (surfaceValue.IsObject())
      {
        surfaceValue.AllowOnly({ "generate", "semi_axes", "subdivisions", "center", "centre" });
        surfaceValue.Required("generate").Choice({ "ellipsoid" });
        if (surfaceValue.Has("center") && surfaceValue.Has("centre"))
        {
          surfaceValue.Fail("give 'center' or 'centre', not both");
        }
        const Vector3 semiAxes = surfaceValue.Required("semi_axes").PositiveVector();
        const int     subdivisions =
          surfaceValue.Has("subdivisions") ? surfaceValue.Child("subdivisions").IntegerInRange(0, 8) : 4;
        const std::string centreKey = surfaceValue.Has("centre") ? "centre" : "center";
        const Vector3 centre = surfaceValue.Has(centreKey) ? surfaceValue.Child(centreKey).Vector() : Vector3::Zero();
        try
        {
          surface = MakeEllipsoidSurface(semiAxes, subdivisions, centre);
        }
        catch (const Error & error)
        {
          surfaceValue.Fail(error.what());
        }
        surface.name = "ellipsoid";
      }
      else
      {
        surfaceValue.Fail(std::string("expected a file name or an object with \"generate\", got ") +
                          surfaceValue.Json().type_name());
      }
      surface.name = entry.Has("name") ? entry.Child("name").NonEmptyString()
                                       : "contact[" + std::to_string(index) + "] " + surface.name;
      if (const auto side = entry.Optional("body_side"))
      {
        surface.bodySide =
          side->Choice({ "inside", "outside" }) == "outside" ? ContactSurface::Side::Outside : ContactSurface::Side::Inside;
      }
      if (const auto flip = entry.Optional("flip_normals"))
      {
        surface.flipNormals = flip->Boolean();
      }
      if (const auto slaves = entry.Optional("slave_node_set"))
      {
        surface.slaveNodeSet = NodeSetReference(*slaves);
      }
      TheModel().contactSurfaces.push_back(std::move(surface));
    }
  }

  void ParseTools()
  {
    const auto list = m_Root.Optional("tools");
    if (!list)
    {
      return;
    }
    for (std::size_t index = 0; index < list->ArraySize(); ++index)
    {
      const SceneValue entry = list->Element(index);
      entry.AllowOnly(
        { "name", "shape", "radius", "length", "width", "surface", "trajectory", "slave_node_set", "stress_region" });
      RigidTool tool;
      tool.name = entry.Has("name") ? entry.Child("name").NonEmptyString() : "tool[" + std::to_string(index) + "]";
      const std::string shape = entry.Required("shape").Choice({ "probe", "spatula", "surface" });
      tool.shape = shape == "probe" ? RigidTool::Shape::Probe
                                    : (shape == "spatula" ? RigidTool::Shape::Spatula : RigidTool::Shape::Surface);
      if (tool.shape == RigidTool::Shape::Surface)
      {
        for (const char * key : { "radius", "length", "width" })
        {
          if (entry.Has(key))
          {
            entry.Child(key).Fail("a surface tool takes its shape from 'surface'");
          }
        }
        const SceneValue surfaceValue = entry.Required("surface");
        try
        {
          tool.surface = ReadSurface(ResolvePath(m_SceneFolder, surfaceValue.NonEmptyString()));
        }
        catch (const Error & error)
        {
          surfaceValue.Fail(error.what());
        }
      }
      else
      {
        if (entry.Has("surface"))
        {
          entry.Child("surface").Fail("only a tool of shape 'surface' takes a surface file");
        }
        tool.radius = entry.Required("radius").PositiveNumber();
        if (const auto length = entry.Optional("length"))
        {
          tool.length = length->NonNegativeNumber();
        }
        if (tool.shape == RigidTool::Shape::Spatula)
        {
          tool.width = entry.Required("width").PositiveNumber();
        }
        else if (entry.Has("width"))
        {
          entry.Child("width").Fail("only a spatula has a width");
        }
      }
      const SceneValue trajectory = entry.Required("trajectory");
      if (trajectory.ArraySize() == 0)
      {
        trajectory.Fail("needs at least one pose {\"time\": s, \"position\": [x, y, z]}");
      }
      for (std::size_t k = 0; k < trajectory.ArraySize(); ++k)
      {
        const SceneValue poseValue = trajectory.Element(k);
        poseValue.AllowOnly({ "time", "position", "rotation" });
        ToolPose pose;
        pose.time = poseValue.Required("time").NonNegativeNumber();
        pose.position = poseValue.Required("position").Vector();
        if (const auto rotation = poseValue.Optional("rotation"))
        {
          pose.rotation = rotation->Vector();
        }
        if (k > 0 && !(pose.time > tool.trajectory.back().time))
        {
          poseValue.Child("time").Fail("must be later than the previous pose's " +
                                       std::to_string(tool.trajectory.back().time) + " s");
        }
        tool.trajectory.push_back(pose);
      }
      if (const auto slaves = entry.Optional("slave_node_set"))
      {
        tool.slaveNodeSet = NodeSetReference(*slaves);
      }
      if (const auto region = entry.Optional("stress_region"))
      {
        region->AllowOnly({ "radius", "mu0", "alpha", "g", "tau", "poisson_ratio" });
        tool.stressRegionRadius = region->Required("radius").PositiveNumber();
        OgdenViscoelasticMaterial & material = tool.stressMaterial;
        if (const auto value = region->Optional("mu0"))
          material.mu0 = value->PositiveNumber();
        if (const auto value = region->Optional("alpha"))
          material.alpha = value->Number();
        if (const auto value = region->Optional("poisson_ratio"))
          material.poissonRatio = value->Number();
        if (region->Has("g") != region->Has("tau"))
        {
          region->Fail("give the Prony series as both 'g' and 'tau' (same length), or neither for Miller and Chinzei's");
        }
        if (region->Has("g"))
        {
          material.g.clear();
          material.tau.clear();
          const SceneValue g = region->Child("g"), tau = region->Child("tau");
          for (std::size_t k = 0; k < g.ArraySize(); ++k)
            material.g.push_back(g.Element(k).NonNegativeNumber());
          for (std::size_t k = 0; k < tau.ArraySize(); ++k)
            material.tau.push_back(tau.Element(k).PositiveNumber());
        }
        try
        {
          material.Validate();
        }
        catch (const Error & error)
        {
          region->Fail(error.what());
        }
      }
      TheModel().tools.push_back(std::move(tool));
    }
  }

  void ParseSolver()
  {
    const auto solver = m_Root.Optional("solver");
    if (!solver)
    {
      return;
    }
    solver->AllowOnly({ "integrator", "tetrahedron", "tolerance", "max_steps", "load_steps", "adapt_interval",
                        "time_step", "safety_factor", "end_time", "damping", "hourglass_coefficient", "threads",
                        "compute_stress", "output_interval" });
    SolverSettings & settings = m_Scene.settings;
    if (const auto value = solver->Optional("integrator"))
    {
      settings.integrator = value->Choice({ "dynamic_relaxation", "explicit_dynamics" }) == "explicit_dynamics"
                              ? Integrator::ExplicitDynamics
                              : Integrator::DynamicRelaxation;
    }
    if (const auto value = solver->Optional("tetrahedron"))
    {
      settings.tetrahedron = value->Choice({ "anp", "linear" }) == "linear" ? TetrahedronFormulation::Linear
                                                                             : TetrahedronFormulation::AverageNodalPressure;
    }
    if (const auto value = solver->Optional("tolerance"))
    {
      settings.tolerance = value->PositiveNumber();
    }
    if (const auto value = solver->Optional("max_steps"))
    {
      settings.maxSteps = value->IntegerInRange(1, std::numeric_limits<int>::max());
    }
    if (const auto value = solver->Optional("load_steps"))
    {
      settings.loadSteps = value->IntegerInRange(1, std::numeric_limits<int>::max());
    }
    if (const auto value = solver->Optional("adapt_interval"))
    {
      settings.adaptInterval = value->IntegerInRange(2, std::numeric_limits<int>::max());
    }
    if (const auto value = solver->Optional("time_step"))
    {
      settings.timeStep = value->NonNegativeNumber();
    }
    if (const auto value = solver->Optional("safety_factor"))
    {
      settings.timeStepSafetyFactor = value->PositiveNumber();
      if (settings.timeStepSafetyFactor > 1.0)
      {
        value->Fail("must not exceed 1 (the critical time step is the stability limit)");
      }
    }
    if (const auto value = solver->Optional("end_time"))
    {
      settings.endTime = value->PositiveNumber();
    }
    if (const auto value = solver->Optional("damping"))
    {
      settings.dampingCoefficient = value->NonNegativeNumber();
    }
    if (const auto value = solver->Optional("output_interval"))
    {
      settings.outputInterval = value->PositiveNumber();
    }
    if (const auto value = solver->Optional("hourglass_coefficient"))
    {
      settings.hourglassCoefficient = value->NonNegativeNumber();
      if (settings.hourglassCoefficient > 1.0)
      {
        value->Fail("must lie in [0, 1] (0.2 is the default)");
      }
    }
    if (const auto value = solver->Optional("threads"))
    {
      settings.threads = value->IntegerInRange(0, 4096);
    }
    if (const auto value = solver->Optional("compute_stress"))
    {
      settings.computeStress = value->Boolean();
    }
  }

  /** "discretization": "meshless" turns the mesh into the body of a meshless
   *  model: its nodes carry MLS shape functions, its cells only bound the body
   *  for the background integration grid. */
  void ParseDiscretization()
  {
    const auto discretization = m_Root.Optional("discretization");
    const bool meshless =
      discretization && discretization->Choice({ "finite_element", "meshless" }) == "meshless";
    const auto options = m_Root.Optional("meshless");
    if (!meshless && TheModel().cells.empty())
    {
      m_Root.Child("mesh").Fail("the mesh has no cells: finite elements need hexahedra or tetrahedra (a point cloud "
                                "needs \"discretization\": \"meshless\" with \"meshless\": {\"integration_points\": FILE})");
    }
    if (!meshless)
    {
      if (options)
      {
        options->Fail("meshless options need \"discretization\": \"meshless\"");
      }
      return;
    }
    if (m_Scene.settings.computeStress)
    {
      m_Root.Child("solver").Child("compute_stress").Fail(
        "the meshless model's stresses live at its integration points and are not written to the .vtu result; "
        "remove compute_stress (the C++ API returns them in SolveResult::cauchyStress)");
    }
    MlsSettings         shapeFunctions;
    IntegrationSettings integration;
    Model &             model = TheModel();
    if (options)
    {
      options->AllowOnly({ "basis", "dilatation", "quadratic_regularization", "essential_boundary", "integration",
                           "integration_points" });
      if (const auto value = options->Optional("basis"))
      {
        shapeFunctions.basis = value->Choice({ "linear", "modified_quadratic" }) == "linear"
                                 ? MlsBasis::Linear
                                 : MlsBasis::ModifiedQuadratic;
      }
      if (const auto value = options->Optional("dilatation"))
      {
        shapeFunctions.dilatation = value->PositiveNumber();
      }
      if (const auto value = options->Optional("quadratic_regularization"))
      {
        shapeFunctions.quadraticRegularization = value->PositiveNumber();
      }
      if (const auto value = options->Optional("essential_boundary"))
      {
        model.meshless.essentialBoundary = value->Choice({ "ebciem", "nodal" }) == "ebciem"
                                             ? EssentialBoundaryImposition::Ebciem
                                             : EssentialBoundaryImposition::Nodal;
      }
      if (const auto value = options->Optional("integration"))
      {
        value->AllowOnly({ "cell_size", "points_per_direction", "adaptive", "adaptive_tolerance", "max_levels" });
        if (const auto item = value->Optional("cell_size"))
        {
          integration.cellSize = item->NonNegativeNumber();
        }
        if (const auto item = value->Optional("points_per_direction"))
        {
          integration.pointsPerDirection = item->IntegerInRange(1, 3);
        }
        if (const auto item = value->Optional("adaptive"))
        {
          integration.adaptive = item->Boolean();
        }
        if (const auto item = value->Optional("adaptive_tolerance"))
        {
          integration.adaptiveTolerance = item->PositiveNumber();
        }
        if (const auto item = value->Optional("max_levels"))
        {
          integration.maxSubdivisionLevels = item->IntegerInRange(0, 6);
        }
      }
    }
    if (options && options->Has("integration_points"))
    {
      // Points, weights and per-point materials from a file (e.g. written by `biomech model`).
      const SceneValue file = options->Child("integration_points");
      if (options->Has("integration"))
      {
        file.Fail("give either \"integration_points\" (a file) or \"integration\" (settings to generate them), not both");
      }
      IntegrationPointData points;
      try
      {
        points = ReadIntegrationPoints(ResolvePath(m_SceneFolder, file.NonEmptyString()));
      }
      catch (const Error & error)
      {
        file.Fail(error.what());
      }
      model.meshless.shapeFunctions = shapeFunctions;
      model.meshless.integrationPoints = std::move(points.positions);
      model.meshless.integrationWeights = std::move(points.weights);
      model.meshless.integrationMaterials.resize(points.materials.size());
      for (std::size_t point = 0; point < points.materials.size(); ++point)
      {
        model.meshless.integrationMaterials[point] = MaterialIndex(points.materials[point]);
      }
      model.discretization = Discretization::Meshless;
      return;
    }
    try
    {
      MakeMeshlessFromCells(model, shapeFunctions, integration, m_Scene.settings.threads);
    }
    catch (const Error & error)
    {
      (options ? *options : *discretization).Fail(error.what());
    }
  }

  void ParseOutput()
  {
    const std::string stem = fs::path(m_ScenePath).stem().string();
    m_Scene.resultVtuFile = stem + "-result.vtu";
    m_Scene.reportFile = stem + "-report.json";
    const auto output = m_Root.Optional("output");
    if (!output)
    {
      return;
    }
    output->AllowOnly({ "vtu", "report" });
    if (const auto vtu = output->Optional("vtu"))
    {
      m_Scene.resultVtuFile = vtu->NonEmptyString();
      if (fs::path(m_Scene.resultVtuFile).extension() != ".vtu")
      {
        vtu->Fail("the result file name must end in .vtu, got '" + m_Scene.resultVtuFile + "'");
      }
    }
    if (const auto report = output->Optional("report"))
    {
      m_Scene.reportFile = report->NonEmptyString();
    }
    if (fs::path(m_Scene.reportFile).lexically_normal() == fs::path(m_Scene.resultVtuFile).lexically_normal())
    {
      output->Fail("'vtu' and 'report' name the same file");
    }
  }

  SceneValue                       m_Root;
  std::string                      m_ScenePath;
  std::string                      m_SceneFolder;
  Scene                            m_Scene;
  MeshData                         m_MeshData;
  bool                             m_MeshFromFile = false;
  std::map<std::tuple<double, double, double>, Index> m_MaterialIndexOfProperties;
  std::vector<std::optional<int>>  m_MaterialLabels;
};

std::string
FormatNumber(double value, int precision = 4)
{
  std::ostringstream text;
  text << std::setprecision(precision) << value;
  return text.str();
}

std::string
WithThousands(std::size_t value)
{
  std::string digits = std::to_string(value);
  for (int position = static_cast<int>(digits.size()) - 3; position > 0; position -= 3)
  {
    digits.insert(static_cast<std::size_t>(position), ",");
  }
  return digits;
}

} // namespace

Scene
ParseScene(const std::string & jsonText, const std::string & scenePath)
{
  json root;
  try
  {
    root = json::parse(jsonText);
  }
  catch (const json::exception & error) // parse_error, or out_of_range for a number such as 1e999
  {
    // nlohmann's text starts "[json.exception.parse_error.101] parse error at ...": keep what follows.
    std::string detail = error.what();
    if (const auto position = detail.find("] "); detail.rfind("[json.exception", 0) == 0 && position != std::string::npos)
    {
      detail.erase(0, position + 2);
    }
    throw Error(scenePath + ": not valid JSON: " + detail +
                " (NaN, Infinity and comments are not JSON; check the file is complete)");
  }
  if (!root.is_object())
  {
    throw Error(scenePath + ": a scene is a JSON object {...}, got " + std::string(root.type_name()));
  }
  return SceneParser(root, scenePath).Parse();
}

Scene
ReadScene(const std::string & path)
{
  std::error_code error;
  if (!fs::is_regular_file(path, error))
  {
    throw Error("scene file '" + path + "' does not exist or is not a file");
  }
  std::ifstream stream(path, std::ios::binary);
  if (!stream)
  {
    throw Error("scene file '" + path + "' cannot be opened for reading");
  }
  std::ostringstream text;
  text << stream.rdbuf();
  return ParseScene(text.str(), path);
}

ModelCounts
CountModel(const Model & model)
{
  ModelCounts counts;
  counts.nodes = model.nodes.size();
  counts.cells = model.cells.size();
  for (const auto & cell : model.cells)
  {
    (cell.type == CellType::Hexahedron ? counts.hexahedra : counts.tetrahedra) += 1;
  }
  counts.dofs = 3 * counts.nodes;
  counts.materials = model.materials.size();
  if (model.discretization == Discretization::Meshless)
  {
    counts.integrationPoints = model.meshless.integrationPoints.size();
  }
  return counts;
}

std::string
MakeReportJson(const Scene & scene, const SolveResult & result, const std::string & resultVtuPath)
{
  const ModelCounts counts = CountModel(scene.model);
  json              report;
  report["scene"] = scene.path;
  if (!scene.description.empty())
  {
    report["description"] = scene.description;
  }
  report["mesh"] = scene.meshSource;
  if (!resultVtuPath.empty())
  {
    report["result_vtu"] = resultVtuPath;
  }
  report["converged"] = result.converged;
  report["message"] = result.message;
  report["integrator"] =
    scene.settings.integrator == Integrator::ExplicitDynamics ? "explicit_dynamics" : "dynamic_relaxation";
  report["steps"] = result.steps;
  report["time_step"] = result.timeStep;
  report["critical_time_step"] = result.criticalTimeStep;
  report["wall_seconds"] = result.wallSeconds;
  report["estimated_error_mm"] = result.estimatedError;
  report["convergence_rate"] = result.convergenceRate;
  report["restarts"] = result.restarts;
  report["max_displacement_mm"] = result.maxDisplacement;
  report["strain_energy_J"] = result.strainEnergy;
  report["hourglass_energy_J"] = result.hourglassEnergy;
  report["kinetic_energy_J"] = result.kineticEnergy;
  report["contact_nodes"] = result.contactNodes;
  report["max_penetration_mm"] = result.maxPenetration;
  report["active_components"] = result.activeComponents;
  report["nodes"] = counts.nodes;
  report["cells"] = counts.cells;
  report["hexahedra"] = counts.hexahedra;
  report["tetrahedra"] = counts.tetrahedra;
  report["dofs"] = counts.dofs;
  report["materials"] = counts.materials;
  report["discretization"] = counts.integrationPoints > 0 ? "meshless" : "finite_element";
  report["integration_points"] = counts.integrationPoints;
  if (!result.tools.empty())
  {
    json tools = json::array();
    for (std::size_t k = 0; k < result.tools.size(); ++k)
    {
      const ToolHistory & history = result.tools[k];
      double              largest = 0.0;
      for (const Vector3 & force : history.force)
      {
        largest = std::max(largest, force.norm());
      }
      const Vector3 last = history.force.empty() ? Vector3::Zero() : history.force.back();
      const Vector3 moment = history.moment.empty() ? Vector3::Zero() : history.moment.back();
      tools.push_back({ { "name", history.name },
                        { "shape", k < scene.model.tools.size() ? ToolShapeName(scene.model.tools[k].shape) : "" },
                        { "final_force_N", { last.x(), last.y(), last.z() } },
                        { "final_moment_N_mm", { moment.x(), moment.y(), moment.z() } },
                        { "max_force_N", largest },
                        { "work_J", history.work },
                        { "records", history.time.size() } });
    }
    report["tools"] = tools;
  }
  report["threads"] = scene.settings.threads > 0 ? scene.settings.threads : omp_get_max_threads();
  return report.dump(2) + "\n";
}

std::string
FormatReportTable(const Scene & scene, const SolveResult & result)
{
  const ModelCounts  counts = CountModel(scene.model);
  const bool         explicitDynamics = scene.settings.integrator == Integrator::ExplicitDynamics;
  std::ostringstream table;
  const auto         row = [&table](const std::string & name, const std::string & value) {
    table << "  " << std::left << std::setw(18) << name << value << "\n";
  };

  table << "scene " << scene.path << "\n";
  if (!result.converged)
  {
    table << "  ****************************************************************\n"
          << "  *** NOT CONVERGED: the displacements are not a solution.     ***\n"
          << "  ****************************************************************\n";
  }
  row("result", result.converged ? "converged" : "NOT CONVERGED");
  if (!result.message.empty())
  {
    row("message", result.message);
  }
  row("mesh", scene.meshSource);
  const std::string materials =
    std::to_string(counts.materials) + (counts.materials == 1 ? " material" : " materials");
  if (counts.integrationPoints > 0)
  {
    row("model", "meshless: " + WithThousands(counts.nodes) + " nodes, " + WithThousands(counts.dofs) + " DOF, " +
                   WithThousands(counts.integrationPoints) + " integration points, " + materials);
  }
  else
  {
    row("model", WithThousands(counts.nodes) + " nodes, " + WithThousands(counts.dofs) + " DOF, " +
                   WithThousands(counts.cells) + " cells (" + WithThousands(counts.hexahedra) + " hexahedra, " +
                   WithThousands(counts.tetrahedra) + " tetrahedra), " + materials);
  }
  row("components", JoinNames(result.activeComponents));
  const std::string steps = WithThousands(static_cast<std::size_t>(std::max(result.steps, 0))) + " steps";
  if (explicitDynamics)
  {
    row("integrator", "explicit dynamics, " + steps + ", time step " + FormatNumber(result.timeStep) +
                        " s (critical " + FormatNumber(result.criticalTimeStep) + " s)");
  }
  else
  {
    // Dynamic relaxation steps in pseudo time with scaled masses: no physical time step to show.
    row("integrator", "dynamic relaxation, " + steps +
                        (result.restarts > 0 ? ", " + std::to_string(result.restarts) + " restart(s)" : std::string()));
  }
  if (!explicitDynamics)
  {
    row("estimated error", FormatNumber(result.estimatedError) + " mm (tolerance " +
                             FormatNumber(scene.settings.tolerance) + " mm, convergence rate " +
                             FormatNumber(result.convergenceRate, 6) + ")");
  }
  row("max displacement", FormatNumber(result.maxDisplacement) + " mm");
  std::string energies = "strain " + FormatNumber(result.strainEnergy) + " J";
  if (counts.hexahedra > 0)
  {
    energies += ", hourglass " + FormatNumber(result.hourglassEnergy) + " J";
  }
  if (explicitDynamics)
  {
    energies += ", kinetic " + FormatNumber(result.kineticEnergy) + " J";
  }
  row("energy", energies);
  if (!scene.model.contactSurfaces.empty())
  {
    row("contact", std::to_string(result.contactNodes) + " nodes in contact, max penetration " +
                     FormatNumber(result.maxPenetration) + " mm");
  }
  row("wall time", FormatNumber(result.wallSeconds) + " s");
  return table.str();
}

} // namespace bmr
