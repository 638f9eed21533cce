#include "bmrSceneParser.h"

#include <iomanip>

namespace bmr
{
namespace scene
{

Scene
SceneParser::Parse()
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

} // namespace scene

using scene::json;
using scene::JoinNames;
namespace fs = std::filesystem;

namespace
{

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
  return scene::SceneParser(root, scenePath).Parse();
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
MakeSolvePartsJson(const SolveResult & result)
{
  const SolvePartSeconds & parts = result.parts;
  json                     seconds;
  seconds["internal_forces_s"] = parts.internalForces;
  seconds["essential_boundary_s"] = parts.essentialBoundary;
  seconds["contact_s"] = parts.contact;
  seconds["rest_s"] = result.wallSeconds - parts.internalForces - parts.essentialBoundary - parts.contact;
  seconds["contact_sweeps"] = parts.contactSweeps;
  seconds["force_table_bytes"] = parts.forceTableBytes;
  return seconds.dump();
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
  report["parts"] = json::parse(MakeSolvePartsJson(result));
  report["estimated_error_mm"] = result.estimatedError;
  report["convergence_rate"] = result.convergenceRate;
  report["lowest_eigenvalue"] = result.lowestEigenvalue;
  report["restarts"] = result.restarts;
  report["max_displacement_mm"] = result.maxDisplacement;
  report["strain_energy_J"] = result.strainEnergy;
  report["hourglass_energy_J"] = result.hourglassEnergy;
  report["kinetic_energy_J"] = result.kineticEnergy;
  report["contact_nodes"] = result.contactNodes;
  report["max_penetration_mm"] = result.maxPenetration;
  report["active_components"] = result.activeComponents;
  report["warnings"] = result.warnings;
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
  for (const std::string & warning : result.warnings)
  {
    row("warning", warning);
  }
  return table.str();
}

} // namespace bmr
