// CalculiX harness: rigid contact surfaces as node-to-face penalty contact
// (see bmrCalculix.h): the masters' wedges, the slave faces and their nodes,
// and the deck's contact cards.
#include "bmrCalculixContact.h"

#include "bmrUnits.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <ostream>

namespace bmr
{
namespace
{

// Faces S1, S2, ... of CalculiX's tetrahedra and hexahedra (their corners).
constexpr int kTetFaces[4][3] = { { 0, 1, 2 }, { 0, 3, 1 }, { 1, 3, 2 }, { 2, 3, 0 } };
constexpr int kHexFaces[6][4] = { { 0, 1, 2, 3 }, { 4, 7, 6, 5 }, { 0, 4, 5, 1 },
                                  { 1, 5, 6, 2 }, { 2, 6, 7, 3 }, { 3, 7, 4, 0 } };

/** The corners of face `face` (1, 2, ...: CalculiX's S1, S2, ...) of a cell, in face order. */
std::vector<Index>
FaceCorners(const Cell & cell, int face)
{
  const bool         tet = cell.type == CellType::Tetrahedron;
  std::vector<Index> corners;
  for (int k = 0; k < (tet ? 3 : 4); ++k)
  {
    corners.push_back(cell.nodes[tet ? kTetFaces[face - 1][k] : kHexFaces[face - 1][k]]);
  }
  return corners;
}

/** The cells' faces on the body's boundary (met by one cell only) whose
 *  corners are all marked in `slave`: (cell, CalculiX face number). */
std::vector<std::pair<Index, int>>
SlaveFaces(const Model & model, const std::vector<char> & slave)
{
  std::map<std::vector<Index>, std::pair<int, std::pair<Index, int>>> faces; // sorted corners -> count, first face
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const Cell & cell = model.cells[c];
    for (int face = 1; face <= (cell.type == CellType::Tetrahedron ? 4 : 6); ++face)
    {
      std::vector<Index> key = FaceCorners(cell, face);
      std::sort(key.begin(), key.end());
      auto & entry = faces[key];
      if (entry.first++ == 0)
      {
        entry.second = { static_cast<Index>(c), face };
      }
    }
  }
  std::vector<std::pair<Index, int>> slaveFaces;
  for (const auto & [corners, entry] : faces)
  {
    const bool allSlave =
      std::all_of(corners.begin(), corners.end(), [&](Index node) { return slave[static_cast<std::size_t>(node)] != 0; });
    if (entry.first == 1 && allSlave)
    {
      slaveFaces.push_back(entry.second);
    }
  }
  std::sort(slaveFaces.begin(), slaveFaces.end());
  return slaveFaces;
}

/** The rigid master of a contact surface: a layer of wedges outside the body
 *  (see CalculixMesh::ContactPair), its nodes appended to `nodes`. */
std::vector<std::array<Index, 6>>
MasterWedges(const ContactSurface & surface, std::vector<Vector3> & nodes)
{
  std::vector<std::array<Index, 3>> triangles = surface.OutwardTriangles();
  if (surface.bodySide == ContactSurface::Side::Outside)
  {
    for (auto & c : triangles)
    {
      std::swap(c[1], c[2]); // normals away from the body
    }
  }
  // Each triangle extruded along its own normal, away from the body, by half
  // the mean edge: right prisms, never inverted (shared top nodes would
  // invert wedges in concave folds). They only carry the master faces, being fixed.
  double edgeSum = 0.0;
  for (const auto & c : triangles)
  {
    for (int k = 0; k < 3; ++k)
    {
      edgeSum += (surface.vertices[c[(k + 1) % 3]] - surface.vertices[c[k]]).norm();
    }
  }
  const double thickness = 0.5 * edgeSum / (3.0 * static_cast<double>(std::max<std::size_t>(triangles.size(), 1)));
  std::vector<Index> bottom(surface.vertices.size(), -1);
  std::vector<std::array<Index, 6>> wedges;
  for (std::size_t t = 0; t < triangles.size(); ++t)
  {
    const auto &  c = triangles[t];
    const Vector3 normal =
      (surface.vertices[c[1]] - surface.vertices[c[0]]).cross(surface.vertices[c[2]] - surface.vertices[c[0]]);
    if (!(normal.norm() > 0.0))
    {
      throw Error("CalculiX deck: contact surface '" + surface.name + "' has a degenerate triangle " +
                  std::to_string(t) + "; clean the surface (remove zero-area triangles).");
    }
    std::array<Index, 6> wedge{};
    for (int k = 0; k < 3; ++k)
    {
      const auto v = static_cast<std::size_t>(c[k]);
      if (bottom[v] < 0)
      {
        bottom[v] = static_cast<Index>(nodes.size());
        nodes.push_back(surface.vertices[v]);
      }
      wedge[k] = bottom[v];
      wedge[k + 3] = static_cast<Index>(nodes.size());
      nodes.push_back(surface.vertices[v] + thickness * normal.normalized());
    }
    wedges.push_back(wedge);
  }
  return wedges;
}

} // namespace

void
AddCalculixContactPairs(const Model & model, CalculixMesh & mesh)
{
  mesh.firstRigidNode = static_cast<Index>(mesh.nodes.size());
  for (const ContactSurface & surface : model.contactSurfaces)
  {
    std::vector<char> slave(model.nodes.size(), 0);
    for (const Index node : surface.slaveNodeSet.empty() ? model.BoundaryNodes() : model.NodeSet(surface.slaveNodeSet))
    {
      slave[static_cast<std::size_t>(node)] = 1;
    }
    CalculixMesh::ContactPair pair;
    pair.slaveFaces = SlaveFaces(model, slave);
    if (pair.slaveFaces.empty())
    {
      throw Error("CalculiX deck: contact surface '" + surface.name + "' has no slave face (no boundary face of the "
                  "body has all its corners in node set '" + surface.slaveNodeSet + "'); give a slave set of boundary nodes.");
    }
    // The slave faces' mean edge (the default penalty's length scale).
    double edgeSum = 0.0;
    int    edges = 0;
    for (const auto & [cell, face] : pair.slaveFaces)
    {
      const std::vector<Index> corners = FaceCorners(model.cells[static_cast<std::size_t>(cell)], face);
      for (std::size_t k = 0; k < corners.size(); ++k)
      {
        edgeSum += (model.nodes[corners[k]] - model.nodes[corners[(k + 1) % corners.size()]]).norm();
        ++edges;
      }
    }
    pair.slaveMeanEdge = edgeSum / edges;
    pair.masterWedges = MasterWedges(surface, mesh.nodes);
    mesh.contactPairs.push_back(std::move(pair));
  }
}

void
WriteCalculixContactPairs(std::ostream & stream, const Model & model, const CalculixMesh & mesh, const CalculixSettings & settings)
{
  if (mesh.contactPairs.empty())
  {
    return;
  }
  double stiffest = 0.0; // MPa
  for (const Material & material : model.materials)
  {
    stiffest = std::max(stiffest, material.youngsModulus * units::PascalToInternal);
  }
  stream << "*MATERIAL, NAME=RIGID\n"
         << "** the masters' wedges: all their nodes are fixed, so their stiffness does not matter\n"
         << "*ELASTIC\n1, 0.3\n";
  std::size_t element = model.cells.size();
  for (std::size_t c = 0; c < mesh.contactPairs.size(); ++c)
  {
    const CalculixMesh::ContactPair & pair = mesh.contactPairs[c];
    const std::string                 id = std::to_string(c + 1);
    const std::size_t                 firstWedge = element + 1;
    stream << "** contact surface '" << model.contactSurfaces[c].name << "'\n"
           << "*ELEMENT, TYPE=C3D6, ELSET=MASTER" << id << "\n";
    for (const auto & wedge : pair.masterWedges)
    {
      stream << ++element;
      for (const Index node : wedge)
      {
        stream << ", " << node + 1;
      }
      stream << "\n";
    }
    stream << "*SOLID SECTION, ELSET=MASTER" << id << ", MATERIAL=RIGID\n"
           << "*SURFACE, NAME=MASTERFACES" << id << ", TYPE=ELEMENT\n";
    for (std::size_t e = firstWedge; e <= element; ++e)
    {
      stream << e << ", S1\n";
    }
    // Element faces, not nodes: CalculiX gives each node of a face-based
    // slave its share of the faces' area (the force is pressure times that
    // area); a nodal slave surface of C3D10 corners held a block on a floor
    // with a penalty some 240 times too soft, one with the mid-edge nodes too
    // some 120 times too stiff (docs/registration.md).
    stream << "*SURFACE, NAME=SLAVE" << id << ", TYPE=ELEMENT\n";
    for (const auto & [cell, face] : pair.slaveFaces)
    {
      stream << cell + 1 << ", S" << face << "\n";
    }
    const double slope =
      settings.contactStiffness > 0.0 ? settings.contactStiffness : 10.0 * stiffest / pair.slaveMeanEdge;
    // No *FRICTION card: frictionless. The tension at large clearance is kept
    // negligible (1e-6 of the pressure at 1 mm overlap), and so is the
    // clearance over which it builds up (1 micrometre).
    stream << "*SURFACE INTERACTION, NAME=FRICTIONLESS" << id << "\n"
           << "*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR\n"
           << FormatDouble(slope) << ", " << FormatDouble(1e-6 * slope) << ", 0.001\n"
           << "*CONTACT PAIR, INTERACTION=FRICTIONLESS" << id << ", TYPE=NODE TO SURFACE"
           << (settings.smallSliding ? ", SMALL SLIDING" : "") << "\n"
           << "SLAVE" << id << ", MASTERFACES" << id << "\n";
  }
}

} // namespace bmr
