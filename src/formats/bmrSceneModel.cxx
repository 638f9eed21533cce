// The scene parser's model sections: materials, the mesh (file or generated),
// per-cell material fields, node sets and the discretization.
#include "bmrSceneParser.h"

namespace bmr
{
namespace scene
{

void
SceneParser::ParseMaterials()
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

void
SceneParser::ParseMesh()
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
bool
SceneParser::MaterialsComeWithIntegrationPoints() const
{
  return m_Root.Has("meshless") && m_Root.Child("meshless").Has("integration_points");
}

/** Index of a material with these properties in the model, added when new:
 *  cells (or integration points) with equal properties share one entry. */
Index
SceneParser::MaterialIndex(Material material)
{
  const auto [position, inserted] =
    m_MaterialIndexOfProperties.emplace(MaterialKey(material), static_cast<Index>(TheModel().materials.size()));
  if (inserted)
  {
    std::ostringstream name;
    name << "E" << material.youngsModulus << "_nu" << material.poissonRatio;
    if (material.law != MaterialLaw::NeoHookean)
    {
      name << "_" << DescribeMaterialLaw(material.law).name;
      for (const MaterialParameter & parameter : MaterialParameters())
      {
        name << material.*parameter.value;
      }
    }
    material.name = name.str();
    TheModel().materials.push_back(material);
  }
  return position->second;
}

/** "material_fields": each cell's properties from cell-data arrays of the
 *  mesh file; "law" (one for every cell) and its parameters (arrays, e.g.
 *  "second_invariant_share") as a material's. */
void
SceneParser::AssignMaterialFields()
{
  const SceneValue fields = m_Root.Child("material_fields");
  fields.AllowOnly(MaterialKeys({}));
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
  std::vector<const std::vector<double> *> parameters;
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    parameters.push_back(arrayOf(parameter.name));
  }
  Material                    lawOfEveryCell;
  if (fields.Has("law"))
  {
    lawOfEveryCell.law = ParseMaterialLawName(fields.Child("law"));
  }
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
    material.law = lawOfEveryCell.law;
    for (std::size_t k = 0; k < parameters.size(); ++k)
    {
      const MaterialParameter & parameter = MaterialParameters()[k];
      material.*parameter.value = parameters[k] != nullptr ? (*parameters[k])[cellId] : parameter.neutral;
    }
    if (const std::string problem = MaterialLawProblem(material); !problem.empty())
    {
      fields.Fail("cell " + std::to_string(cellId) + " " + problem);
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

void
SceneParser::AssignMaterials()
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

std::vector<Index>
SceneParser::SelectNodes(const SceneValue & definition, const std::string & name)
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

void
SceneParser::ParseNodeSets()
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

std::string
SceneParser::NodeSetReference(const SceneValue & value)
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

/** "discretization": "meshless" turns the mesh into the body of a meshless
 *  model: its nodes carry MLS shape functions, its cells only bound the body
 *  for the background integration grid. */
void
SceneParser::ParseDiscretization()
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
      value->AllowOnly({ "cell_size", "points_per_direction", "adaptive", "adaptive_tolerance", "max_levels",
                         "interior_points_per_direction", "interior_tolerance" });
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
      if (const auto item = value->Optional("interior_points_per_direction"))
      {
        integration.interiorPointsPerDirection = item->IntegerInRange(0, 3);
      }
      if (const auto item = value->Optional("interior_tolerance"))
      {
        integration.interiorTolerance = item->NonNegativeNumber();
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

} // namespace scene
} // namespace bmr
