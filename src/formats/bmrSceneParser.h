// The scene parser's parts (internal to the core library): SceneValue, a
// JSON value that names its key path in every error, the small parsers they
// share, and SceneParser, whose sections are defined by topic in
// bmrSceneModel.cxx (materials, mesh, node sets, discretization),
// bmrSceneLoads.cxx (constraints, loads, contact, tools, solver, output) and
// bmrScene.cxx (the whole scene, the report).
#ifndef bmrSceneParser_h
#define bmrSceneParser_h

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

namespace bmr
{
namespace scene
{

namespace fs = std::filesystem;
using json = nlohmann::json;

inline std::string
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
      Fail(m_Value.dump() + " is not one of: " + JoinNames(choices)); // dump: quoted, control characters escaped
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

inline std::string
ResolvePath(const std::string & sceneFolder, const std::string & relativeOrAbsolute)
{
  const fs::path path(relativeOrAbsolute);
  if (path.is_absolute() || sceneFolder.empty())
  {
    return path.lexically_normal().string();
  }
  return (fs::path(sceneFolder) / path).lexically_normal().string();
}

inline GridCells
ParseGridCells(const SceneValue & value)
{
  const std::string name = value.Choice({ "hexahedra", "tetrahedra", "mixed" });
  if (name == "tetrahedra")
  {
    return GridCells::Tetrahedra;
  }
  return name == "mixed" ? GridCells::Mixed : GridCells::Hexahedra;
}

inline const char *
GridCellsName(GridCells cells)
{
  switch (cells)
  {
    case GridCells::Tetrahedra: return "tetrahedra";
    case GridCells::Mixed: return "mixed hexahedra and tetrahedra";
    default: return "hexahedra";
  }
}

inline LoadCurve
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

/** One of bmrMaterialLaw.h's names, e.g. "mooney-rivlin". */
inline MaterialLaw
ParseMaterialLawName(const SceneValue & value)
{
  return MaterialLawNamed(value.Choice(MaterialLawNameList()));
}

/** The keys of a scene material, or of "material_fields": the three
 *  moduli's, "law" and every law parameter's (MaterialParameters()). */
inline std::vector<std::string>
MaterialKeys(std::vector<std::string> keys)
{
  keys.insert(keys.end(), { "youngs_modulus", "poisson_ratio", "density", "law" });
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    keys.emplace_back(parameter.name);
  }
  return keys;
}

/** "law" (bmrMaterialLaw.h's names; default neo-hookean) and its parameters
 *  (MaterialParameters(): Mooney-Rivlin's "second_invariant_share"). */
inline void
ParseMaterialLaw(const SceneValue & value, Material & material)
{
  if (const auto law = value.Optional("law"))
  {
    material.law = ParseMaterialLawName(*law);
  }
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    if (const auto number = value.Optional(parameter.name))
    {
      material.*parameter.value = number->Number();
    }
  }
  if (const std::string problem = MaterialLawProblem(material); !problem.empty())
  {
    value.Fail(problem);
  }
}

inline Material
ParseMaterial(const SceneValue & value, std::size_t index, std::optional<int> & label)
{
  value.AllowOnly(MaterialKeys({ "name", "label" }));
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
  ParseMaterialLaw(value, material);
  return material;
}

/** Sorted, unique node ids. */
inline std::vector<Index>
SortedUnique(std::vector<Index> ids)
{
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  return ids;
}

inline std::string
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

  Scene Parse();

private:
  Model & TheModel() { return m_Scene.model; }

  void ParseMaterials();

  void ParseMesh();

  /** A meshless scene whose integration points come from a file with a material per point. */
  bool MaterialsComeWithIntegrationPoints() const;

  /** Index of a material with these properties in the model, added when new:
   *  cells (or integration points) with equal properties share one entry. */
  Index MaterialIndex(Material material);

  /** "material_fields": each cell's neo-Hookean properties from cell-data arrays of the mesh file. */
  void AssignMaterialFields();

  void AssignMaterials();

  std::vector<Index> SelectNodes(const SceneValue & definition, const std::string & name);

  void ParseNodeSets();

  std::string NodeSetReference(const SceneValue & value);

  void ParseFixed();

  void ReadDisplacementCsv(const SceneValue & value, PrescribedDisplacement & prescribed);

  void ParsePrescribedDisplacements();

  void ParseGravity();

  void ParseContact();

  void ParseTools();

  void ParseSolver();

  /** "discretization": "meshless" turns the mesh into the body of a meshless
   *  model: its nodes carry MLS shape functions, its cells only bound the body
   *  for the background integration grid. */
  void ParseDiscretization();

  void ParseOutput();

  SceneValue                       m_Root;
  std::string                      m_ScenePath;
  std::string                      m_SceneFolder;
  Scene                            m_Scene;
  MeshData                         m_MeshData;
  bool                             m_MeshFromFile = false;
  std::map<std::vector<double>, Index> m_MaterialIndexOfProperties; // by MaterialKey
  std::vector<std::optional<int>>  m_MaterialLabels;
};

} // namespace scene
} // namespace bmr

#endif
