#include "bmrModel.h"

#include "bmrShape.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace bmr
{

const char *
CellTypeName(CellType type)
{
  return type == CellType::Hexahedron ? "hexahedron" : "tetrahedron";
}

double
LoadCurve::Factor(double fraction) const
{
  const double s = std::clamp(fraction, 0.0, 1.0);
  switch (shape)
  {
    case Shape::Step:
      return 1.0;
    case Shape::Linear:
      return s;
    case Shape::Smooth:
      break;
  }
  // Quintic smoothstep: zero velocity and acceleration at both ends.
  return s * s * s * (10.0 + s * (-15.0 + 6.0 * s));
}

const std::vector<Index> &
Model::NodeSet(const std::string & name) const
{
  const auto found = nodeSets.find(name);
  if (found == nodeSets.end())
  {
    std::ostringstream message;
    message << "node set '" << name << "' does not exist; defined sets:";
    for (const auto & set : nodeSets)
    {
      message << " '" << set.first << "'";
    }
    if (nodeSets.empty())
    {
      message << " none";
    }
    message << ". Define it in the scene's node_sets or use one of these names.";
    throw Error(message.str());
  }
  return found->second;
}

double
CellVolume(const Model & model, Index cellIndex)
{
  const Cell & cell = model.cells[cellIndex];
  if (cell.type == CellType::Tetrahedron)
  {
    return TetrahedronVolume(model.nodes[cell.nodes[0]],
                             model.nodes[cell.nodes[1]],
                             model.nodes[cell.nodes[2]],
                             model.nodes[cell.nodes[3]]);
  }
  HexahedronCoordinates x;
  for (int a = 0; a < 8; ++a)
  {
    x.row(a) = model.nodes[cell.nodes[a]].transpose();
  }
  return HexahedronIntegrals(x).volume;
}

Model
KeepCells(const Model & model, const std::vector<char> & keep, std::vector<Index> * newIndexOfNode)
{
  Model kept;
  kept.materials = model.materials;
  std::vector<Index> newIndex(model.nodes.size(), -1);
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    if (!keep[c])
    {
      continue;
    }
    Cell cell = model.cells[c];
    for (int v = 0; v < NodesPerCell(cell.type); ++v)
    {
      Index & node = newIndex[cell.nodes[v]];
      if (node < 0)
      {
        node = static_cast<Index>(kept.nodes.size());
        kept.nodes.push_back(model.nodes[cell.nodes[v]]);
      }
      cell.nodes[v] = node;
    }
    kept.cells.push_back(cell);
  }
  if (newIndexOfNode)
  {
    *newIndexOfNode = std::move(newIndex);
  }
  return kept;
}

namespace
{

std::string
CellLabel(const Model & model, Index cellIndex)
{
  std::ostringstream label;
  label << CellTypeName(model.cells[cellIndex].type) << " cell " << cellIndex;
  return label.str();
}

void
CheckNodeIds(const Model & model, const std::vector<Index> & ids, const std::string & owner)
{
  const auto nodeCount = static_cast<Index>(model.nodes.size());
  for (const Index id : ids)
  {
    if (id < 0 || id >= nodeCount)
    {
      std::ostringstream message;
      message << owner << " refers to node " << id << ", but the mesh has nodes 0.." << nodeCount - 1
              << ". Fix the node ids.";
      throw Error(message.str());
    }
  }
}

void
CheckCell(const Model & model, Index cellIndex, double lengthScale)
{
  const Cell & cell = model.cells[cellIndex];
  if (cell.type != CellType::Hexahedron && cell.type != CellType::Tetrahedron)
  {
    throw Error(CellLabel(model, cellIndex) + " has an unknown cell type; supported: hexahedron, tetrahedron.");
  }
  const int  count = NodesPerCell(cell.type);
  const auto nodeCount = static_cast<Index>(model.nodes.size());
  for (int a = 0; a < count; ++a)
  {
    const Index node = cell.nodes[a];
    if (node < 0 || node >= nodeCount)
    {
      std::ostringstream message;
      message << CellLabel(model, cellIndex) << " refers to node " << node << ", but the mesh has nodes 0.."
              << nodeCount - 1 << ". The mesh file is inconsistent.";
      throw Error(message.str());
    }
    for (int b = 0; b < a; ++b)
    {
      if (cell.nodes[b] == node)
      {
        std::ostringstream message;
        message << CellLabel(model, cellIndex) << " is degenerate: node " << node
                << " appears twice. Remove or repair the cell.";
        throw Error(message.str());
      }
    }
  }
  if (cell.material < 0 || cell.material >= static_cast<Index>(model.materials.size()))
  {
    std::ostringstream message;
    message << CellLabel(model, cellIndex) << " has material index " << cell.material << ", but "
            << model.materials.size() << " material(s) are defined. Add the material or fix the cell labels.";
    throw Error(message.str());
  }

  // A cell is degenerate when it is flat: its volume a tiny fraction of the
  // cube of its own longest edge. (A fraction of the whole mesh's size instead
  // rejected well-shaped cells 0.1 mm across that CGAL places at voxel-scale
  // features of a 5.5 mm mesh of Colin27.) The mesh's length scale only
  // guards edges that are themselves negligible.
  double longestEdge = 0.0;
  for (int a = 0; a < count; ++a)
  {
    for (int b = 0; b < a; ++b)
    {
      longestEdge = std::max(longestEdge, (model.nodes[cell.nodes[a]] - model.nodes[cell.nodes[b]]).norm());
    }
  }
  const double edge = std::max(longestEdge, 1e-9 * lengthScale);
  const double degenerateVolume = 1e-9 * edge * edge * edge;
  double       worst = 0.0;
  if (cell.type == CellType::Tetrahedron)
  {
    worst = CellVolume(model, cellIndex);
  }
  else
  {
    // The trilinear map must be orientation-preserving at every corner, not just on average.
    HexahedronCoordinates x;
    for (int a = 0; a < 8; ++a)
    {
      x.row(a) = model.nodes[cell.nodes[a]].transpose();
    }
    worst = HexahedronMinimumCornerJacobian(x) / 8.0; // a corner Jacobian is an eighth of the volume scale
  }
  if (!std::isfinite(worst) || std::abs(worst) <= degenerateVolume)
  {
    throw Error(CellLabel(model, cellIndex) +
                " is degenerate (zero volume). Remove the cell or repair the mesh.");
  }
  if (worst < 0.0)
  {
    throw Error(CellLabel(model, cellIndex) +
                " is inverted (negative volume or corner Jacobian). Check its node ordering (VTK convention) "
                "or repair the mesh.");
  }
}

} // namespace

namespace
{

void
ValidateMeshless(const Model & model)
{
  const MeshlessDiscretization & meshless = model.meshless;
  const std::size_t              count = meshless.integrationPoints.size();
  if (count == 0)
  {
    throw Error("the meshless model has no integration points. Make them with bmr::MakeMeshlessFromCells or "
                "bmr::MakeIntegrationPoints (scene: \"discretization\": \"meshless\").");
  }
  if (meshless.integrationWeights.size() != count || meshless.integrationMaterials.size() != count)
  {
    throw Error("the meshless model has " + std::to_string(count) + " integration points but " +
                std::to_string(meshless.integrationWeights.size()) + " weights and " +
                std::to_string(meshless.integrationMaterials.size()) + " materials; give one of each per point.");
  }
  for (std::size_t p = 0; p < count; ++p)
  {
    const std::string label = "integration point " + std::to_string(p);
    if (!meshless.integrationPoints[p].allFinite())
    {
      throw Error(label + " has a non-finite coordinate.");
    }
    if (!(meshless.integrationWeights[p] > 0.0) || !std::isfinite(meshless.integrationWeights[p]))
    {
      throw Error(label + " has weight " + std::to_string(meshless.integrationWeights[p]) +
                  " mm^3; weights must be positive.");
    }
    const Index material = meshless.integrationMaterials[p];
    if (material < 0 || material >= static_cast<Index>(model.materials.size()))
    {
      throw Error(label + " refers to material " + std::to_string(material) + " but the model has " +
                  std::to_string(model.materials.size()) + " materials.");
    }
  }
  if (model.cells.empty())
  {
    for (const ContactSurface & surface : model.contactSurfaces)
    {
      if (surface.slaveNodeSet.empty())
      {
        throw Error("contact surface '" + surface.name + "': a meshless model without cells has no known "
                    "boundary; name the body's surface nodes in slave_node_set.");
      }
    }
  }
}


void
CheckMaterial(const Material & material, std::size_t m)
{
  const std::string label = "material " + std::to_string(m) + (material.name.empty() ? "" : " ('" + material.name + "')");
  if (!(material.youngsModulus > 0.0) || !std::isfinite(material.youngsModulus))
  {
    throw Error(label + " has Young's modulus " + std::to_string(material.youngsModulus) +
                " Pa; it must be positive.");
  }
  if (!(material.poissonRatio > -1.0 && material.poissonRatio < 0.5))
  {
    throw Error(label + " has Poisson's ratio " + std::to_string(material.poissonRatio) +
                "; it must lie in (-1, 0.5). Use 0.49 or 0.499 for nearly incompressible tissue.");
  }
  if (!(material.density > 0.0) || !std::isfinite(material.density))
  {
    throw Error(label + " has density " + std::to_string(material.density) + " kg/m^3; it must be positive.");
  }
  if (const std::string problem = MaterialLawProblem(material); !problem.empty())
  {
    throw Error(label + " " + problem + ".");
  }
}

void
CheckPrescribedDisplacement(const Model & model, const PrescribedDisplacement & load, std::size_t i)
{
  const std::string              label = "prescribed displacement " + std::to_string(i);
  if (load.nodes.size() != load.displacements.size())
  {
    throw Error(label + " has " + std::to_string(load.nodes.size()) + " nodes but " +
                std::to_string(load.displacements.size()) + " displacement vectors; give one per node.");
  }
  CheckNodeIds(model, load.nodes, label);
  for (std::size_t k = 0; k < load.displacements.size(); ++k)
  {
    if (!load.displacements[k].allFinite())
    {
      throw Error(label + " has a non-finite displacement at node " + std::to_string(load.nodes[k]) + ".");
    }
  }
  if (load.curve.shape != LoadCurve::Shape::Step && !(load.curve.rampTime > 0.0))
  {
    throw Error(label + " has a ramp time of " + std::to_string(load.curve.rampTime) + " s; it must be positive.");
  }
}

void
CheckContactSurface(const Model & model, const ContactSurface & surface)
{
  const std::string label = "contact surface '" + surface.name + "'";
  if (surface.vertices.empty() || surface.triangles.empty())
  {
    throw Error(label + " has no triangles. Give a triangulated surface (.stl, .vtk, .obj).");
  }
  for (std::size_t t = 0; t < surface.triangles.size(); ++t)
  {
    for (const Index v : surface.triangles[t])
    {
      if (v < 0 || v >= static_cast<Index>(surface.vertices.size()))
      {
        throw Error(label + " triangle " + std::to_string(t) + " refers to vertex " + std::to_string(v) +
                    ", which does not exist.");
      }
    }
  }
  if (!surface.slaveNodeSet.empty())
  {
    model.NodeSet(surface.slaveNodeSet);
  }
}

void
CheckTool(const Model & model, const RigidTool & tool)
{
  const std::string label = "tool '" + tool.name + "'";
  if (tool.trajectory.empty())
  {
    throw Error(label + " has no trajectory. Give at least one pose (time, position, rotation).");
  }
  for (std::size_t k = 0; k < tool.trajectory.size(); ++k)
  {
    const ToolPose & pose = tool.trajectory[k];
    if (!std::isfinite(pose.time) || !pose.position.allFinite() || !pose.rotation.allFinite())
    {
      throw Error(label + " pose " + std::to_string(k) + " is not finite.");
    }
    if (k > 0 && !(pose.time > tool.trajectory[k - 1].time))
    {
      throw Error(label + " pose " + std::to_string(k) + " at t = " + std::to_string(pose.time) +
                  " s does not come after the previous one: the trajectory's times must increase.");
    }
  }
  if (tool.shape == RigidTool::Shape::Surface)
  {
    if (tool.surface.vertices.empty() || tool.surface.triangles.empty())
    {
      throw Error(label + " has no surface. Give a closed triangulated surface in the tool's frame.");
    }
  }
  else
  {
    if (!(tool.radius > 0.0) || !std::isfinite(tool.radius))
    {
      throw Error(label + " has radius " + std::to_string(tool.radius) + " mm; it must be positive.");
    }
    if (!(tool.length >= 0.0) || !std::isfinite(tool.length))
    {
      throw Error(label + " has length " + std::to_string(tool.length) + " mm; it must be 0 or more.");
    }
    if (tool.shape == RigidTool::Shape::Spatula && (!(tool.width > 0.0) || !std::isfinite(tool.width)))
    {
      throw Error(label + " has width " + std::to_string(tool.width) + " mm; a spatula's must be positive.");
    }
  }
  if (!tool.slaveNodeSet.empty())
  {
    model.NodeSet(tool.slaveNodeSet);
  }
  if (!(tool.stressRegionRadius >= 0.0) || !std::isfinite(tool.stressRegionRadius))
  {
    throw Error(label + " has stress region radius " + std::to_string(tool.stressRegionRadius) +
                " mm; it must be 0 (none) or positive.");
  }
  if (tool.stressRegionRadius > 0.0)
  {
    try
    {
      tool.stressMaterial.Validate();
    }
    catch (const Error & error)
    {
      throw Error(label + " stress material: " + error.what());
    }
  }
}

} // namespace

void
Model::Validate() const
{
  const bool isMeshless = discretization == Discretization::Meshless;
  if (nodes.empty() || (cells.empty() && !isMeshless))
  {
    throw Error("the model has no nodes or no cells. Give a mesh with hexahedra or tetrahedra.");
  }
  Eigen::AlignedBox3d box;
  for (std::size_t i = 0; i < nodes.size(); ++i)
  {
    if (!nodes[i].allFinite())
    {
      throw Error("node " + std::to_string(i) + " has a non-finite coordinate. Repair the mesh.");
    }
    box.extend(nodes[i]);
  }
  if (materials.empty())
  {
    throw Error("no material is defined. Add at least one material.");
  }
  for (std::size_t m = 0; m < materials.size(); ++m)
  {
    CheckMaterial(materials[m], m);
  }
  const double lengthScale = std::max(box.diagonal().norm(), 1e-300);
  for (Index c = 0; c < static_cast<Index>(cells.size()); ++c)
  {
    CheckCell(*this, c, lengthScale);
  }
  if (isMeshless)
  {
    ValidateMeshless(*this);
  }
  // A node outside every cell has no mass and no stiffness: it cannot be solved for.
  // (Meshless nodes get mass from integration points; the solver checks that.)
  std::vector<char> used(nodes.size(), isMeshless ? 1 : 0);
  for (const Cell & cell : cells)
  {
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      used[cell.nodes[a]] = 1;
    }
  }
  const auto unused = std::find(used.begin(), used.end(), 0);
  if (unused != used.end())
  {
    throw Error("node " + std::to_string(unused - used.begin()) +
                " belongs to no cell. Remove unused points from the mesh (e.g. VTK's vtkCleanUnstructuredGrid).");
  }
  for (const auto & set : nodeSets)
  {
    CheckNodeIds(*this, set.second, "node set '" + set.first + "'");
  }
  for (std::size_t i = 0; i < fixedConstraints.size(); ++i)
  {
    NodeSet(fixedConstraints[i].nodeSet); // throws naming the missing set
  }
  for (std::size_t i = 0; i < prescribedDisplacements.size(); ++i)
  {
    CheckPrescribedDisplacement(*this, prescribedDisplacements[i], i);
  }
  if (!bodyAcceleration.allFinite())
  {
    throw Error("the body acceleration (gravity) is not finite.");
  }
  if (fluidSurface && (!fluidSurface->allFinite() || bodyAcceleration.isZero()))
  {
    throw Error(bodyAcceleration.isZero()
                  ? "a CSF fluid surface is given without gravity; give the body acceleration it is level under."
                  : "the CSF fluid surface point is not finite.");
  }
  for (const ContactSurface & surface : contactSurfaces)
  {
    CheckContactSurface(*this, surface);
  }
  for (const RigidTool & tool : tools)
  {
    CheckTool(*this, tool);
  }
}

const char *
ToolShapeName(RigidTool::Shape shape)
{
  switch (shape)
  {
    case RigidTool::Shape::Probe:
      return "probe";
    case RigidTool::Shape::Spatula:
      return "spatula";
    case RigidTool::Shape::Surface:
      return "surface";
  }
  return "unknown";
}

ToolPose
ToolPoseAt(const RigidTool & tool, double time)
{
  const std::vector<ToolPose> & poses = tool.trajectory;
  if (poses.empty())
  {
    throw Error("tool '" + tool.name + "' has no trajectory.");
  }
  if (time <= poses.front().time)
  {
    return ToolPose{ time, poses.front().position, poses.front().rotation };
  }
  if (time >= poses.back().time)
  {
    return ToolPose{ time, poses.back().position, poses.back().rotation };
  }
  const auto   next = std::upper_bound(poses.begin(), poses.end(), time,
                                     [](double t, const ToolPose & pose) { return t < pose.time; });
  const auto & a = *(next - 1);
  const auto & b = *next;
  const double s = (time - a.time) / (b.time - a.time);
  const auto   quaternion = [](const Vector3 & rotation) {
    const double angle = rotation.norm();
    return angle > 0.0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, rotation / angle)) : Eigen::Quaterniond::Identity();
  };
  const Eigen::AngleAxisd between(quaternion(a.rotation).slerp(s, quaternion(b.rotation)));
  return ToolPose{ time, (1.0 - s) * a.position + s * b.position, between.angle() * between.axis() };
}

namespace
{

using Face = std::array<Index, 4>; // triangle faces use -1 as 4th entry

// Outward faces in VTK ordering.
constexpr int kHexFaces[6][4] = { { 0, 3, 2, 1 }, { 4, 5, 6, 7 }, { 0, 1, 5, 4 },
                                  { 1, 2, 6, 5 }, { 2, 3, 7, 6 }, { 3, 0, 4, 7 } };
constexpr int kTetFaces[4][3] = { { 0, 2, 1 }, { 0, 1, 3 }, { 1, 2, 3 }, { 0, 3, 2 } };

Face
SortedKey(Face face, int count)
{
  std::sort(face.begin(), face.begin() + count);
  return face;
}

// Boundary faces in outward orientation. A hexahedron quad that meets two
// tetrahedron triangles (mixed meshes, either diagonal) is interior. Every
// cell face is listed under its sorted nodes and the list sorted, so that a
// face met once is on the boundary: about six times faster than a hash map of
// the faces (1.2 s for the 4.25 mm meshless cloud's tetrahedra of Colin27).
std::vector<Face>
BoundaryFaces(const Model & model)
{
  struct Entry
  {
    Face key;
    Face oriented;
  };
  std::vector<Entry> entries;
  entries.reserve(6 * model.cells.size());
  for (const Cell & cell : model.cells)
  {
    if (cell.type == CellType::Hexahedron)
    {
      for (const auto & f : kHexFaces)
      {
        const Face oriented{ cell.nodes[f[0]], cell.nodes[f[1]], cell.nodes[f[2]], cell.nodes[f[3]] };
        entries.push_back({ SortedKey(oriented, 4), oriented });
      }
    }
    else
    {
      for (const auto & f : kTetFaces)
      {
        const Face oriented{ cell.nodes[f[0]], cell.nodes[f[1]], cell.nodes[f[2]], -1 };
        entries.push_back({ SortedKey(oriented, 3), oriented });
      }
    }
  }
  std::sort(entries.begin(), entries.end(), [](const Entry & l, const Entry & r) { return l.key < r.key; });
  // The distinct faces, each with how often it occurs and one orientation.
  std::vector<Face> keys, oriented;
  std::vector<int>  counts;
  for (std::size_t first = 0; first < entries.size();)
  {
    std::size_t last = first + 1;
    while (last < entries.size() && entries[last].key == entries[first].key)
    {
      ++last;
    }
    keys.push_back(entries[first].key);
    oriented.push_back(entries[first].oriented);
    counts.push_back(static_cast<int>(last - first));
    first = last;
  }
  const auto find = [&keys](const Face & key) -> std::ptrdiff_t {
    const auto it = std::lower_bound(keys.begin(), keys.end(), key);
    return it != keys.end() && *it == key ? it - keys.begin() : -1;
  };
  auto triangleKey = [](Index a, Index b, Index c) { return SortedKey({ a, b, c, -1 }, 3); };
  for (std::size_t i = 0; i < keys.size(); ++i)
  {
    if (keys[i][3] < 0 || counts[i] != 1)
    {
      continue;
    }
    const Face & q = oriented[i];
    const Face   diagonals[2][2] = { { triangleKey(q[0], q[1], q[2]), triangleKey(q[0], q[2], q[3]) },
                                     { triangleKey(q[0], q[1], q[3]), triangleKey(q[1], q[2], q[3]) } };
    for (const auto & pair : diagonals)
    {
      const std::ptrdiff_t first = find(pair[0]);
      const std::ptrdiff_t second = find(pair[1]);
      if (first >= 0 && second >= 0 && counts[first] == 1 && counts[second] == 1)
      {
        counts[first] = counts[second] = counts[i] = 2;
        break;
      }
    }
  }
  std::vector<Face> boundary;
  for (std::size_t i = 0; i < keys.size(); ++i)
  {
    if (counts[i] == 1)
    {
      boundary.push_back(oriented[i]);
    }
  }
  std::sort(boundary.begin(), boundary.end()); // deterministic order
  return boundary;
}

} // namespace

std::vector<Index>
Model::BoundaryNodes() const
{
  std::vector<Index> nodesOnBoundary;
  for (const Face & face : BoundaryFaces(*this))
  {
    for (const Index i : face)
    {
      if (i >= 0)
      {
        nodesOnBoundary.push_back(i);
      }
    }
  }
  std::sort(nodesOnBoundary.begin(), nodesOnBoundary.end());
  nodesOnBoundary.erase(std::unique(nodesOnBoundary.begin(), nodesOnBoundary.end()), nodesOnBoundary.end());
  return nodesOnBoundary;
}

std::vector<std::array<Index, 3>>
Model::BoundaryTriangles() const
{
  std::vector<std::array<Index, 3>> triangles;
  for (const Face & face : BoundaryFaces(*this))
  {
    triangles.push_back({ face[0], face[1], face[2] });
    if (face[3] >= 0)
    {
      triangles.push_back({ face[0], face[2], face[3] });
    }
  }
  return triangles;
}

std::string
FormatPoint(const Vector3 & point)
{
  std::ostringstream text;
  text.precision(6);
  text << "(" << point.x() << ", " << point.y() << ", " << point.z() << ")";
  return text.str();
}

} // namespace bmr
