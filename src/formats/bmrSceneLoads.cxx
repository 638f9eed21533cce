// The scene parser's sections after the model: constraints, prescribed
// displacements, gravity, contact, tools, solver settings and output names.
#include "bmrSceneParser.h"
#include "bmrSolverSettingsTable.h"

namespace bmr
{
namespace scene
{

void
SceneParser::ParseFixed()
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

void
SceneParser::ReadDisplacementCsv(const SceneValue & value, PrescribedDisplacement & prescribed)
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

void
SceneParser::ParsePrescribedDisplacements()
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

void
SceneParser::ParseGravity()
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

void
SceneParser::ParseContact()
{
  const auto list = m_Root.Optional("contact");
  if (!list)
  {
    return;
  }
  for (std::size_t index = 0; index < list->ArraySize(); ++index)
  {
    const SceneValue entry = list->Element(index);
    entry.AllowOnly({ "name", "surface", "body_side", "flip_normals", "slave_node_set", "offset" });
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
    if (const auto offset = entry.Optional("offset"))
    {
      surface.offset = offset->Number();
    }
    TheModel().contactSurfaces.push_back(std::move(surface));
  }
}

void
SceneParser::ParseTools()
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

void
SceneParser::ParseSolver()
{
  const auto solver = m_Root.Optional("solver");
  if (!solver)
  {
    return;
  }
  // The keys, their types and ranges are the solver settings' one table.
  std::vector<std::string> keys;
  for (const SolverSettingField & field : SolverSettingFields())
  {
    keys.push_back(field.name);
  }
  solver->AllowOnly(keys);
  SolverSettings & settings = m_Scene.settings;
  for (const SolverSettingField & field : SolverSettingFields())
  {
    const auto value = solver->Optional(field.name);
    if (!value)
    {
      continue;
    }
    double number = 0.0;
    switch (field.kind)
    {
      case SolverSettingField::Kind::Choice:
      {
        const std::string choice = value->Choice(field.choices);
        while (field.choices[static_cast<std::size_t>(number)] != choice)
        {
          number += 1.0;
        }
        break;
      }
      case SolverSettingField::Kind::Flag:
        number = value->Boolean() ? 1.0 : 0.0;
        break;
      case SolverSettingField::Kind::Integer:
        number = static_cast<double>(value->Integer());
        break;
      case SolverSettingField::Kind::Number:
        number = value->Number();
        break;
    }
    if (const std::string problem = field.Check(number); !problem.empty())
    {
      value->Fail(problem);
    }
    field.set(settings, number);
  }
}

void
SceneParser::ParseOutput()
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

} // namespace scene
} // namespace bmr
