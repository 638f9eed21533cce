// CalculiX harness: the mesh given to CalculiX and its input deck (see bmrCalculix.h).
#include "bmrCalculix.h"
#include "bmrCalculixContact.h"
#include "bmrCalculixStabilisation.h"

#include "bmrUnits.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <limits>
#include <map>
#include <sstream>
#include <cstdint>
#include <unordered_map>

namespace bmr
{
namespace
{

// Local edges, in CalculiX mid-edge node order.
constexpr int kTetEdges[6][2] = { { 0, 1 }, { 1, 2 }, { 2, 0 }, { 0, 3 }, { 1, 3 }, { 2, 3 } };
constexpr int kHexEdges[12][2] = { { 0, 1 }, { 1, 2 }, { 2, 3 }, { 3, 0 }, { 4, 5 }, { 5, 6 },
                                   { 6, 7 }, { 7, 4 }, { 0, 4 }, { 1, 5 }, { 2, 6 }, { 3, 7 } };

int
ElementNodeCount(const std::string & type)
{
  // "C3D10", "C3D20R", "C3D8I", ...: the digits after "C3D".
  if (type.size() < 4 || type.compare(0, 3, "C3D") != 0)
  {
    return 0;
  }
  return std::atoi(type.c_str() + 3);
}

} // namespace

std::string
FormatDouble(double value)
{
  std::string text;
  for (int precision = 17; precision >= 6; --precision)
  {
    std::ostringstream stream;
    stream << std::setprecision(precision) << value;
    text = stream.str();
    if (text.size() <= 20)
    {
      break;
    }
  }
  // CalculiX reads a real without a point as no number in some cards (a
  // *SPRING stiffness of "3e-05" is "a card without data"; "3.e-05" is read).
  if (std::isfinite(value) && text.find('.') == std::string::npos)
  {
    const std::size_t exponent = text.find('e');
    text.insert(exponent == std::string::npos ? text.size() : exponent, ".");
  }
  return text;
}

std::vector<char>
CalculixMesh::MeshNodeMask(const std::vector<char> & modelMask) const
{
  std::vector<char> mask(nodes.size(), 0);
  std::copy(modelMask.begin(), modelMask.begin() + std::min<std::size_t>(modelMask.size(), modelNodes), mask.begin());
  for (std::size_t t = 0; t < boundaryTriangles.size(); ++t)
  {
    const auto & triangle = boundaryTriangles[t];
    if (modelMask[triangle[0]] && modelMask[triangle[1]] && modelMask[triangle[2]])
    {
      for (const Index mid : boundaryTriangleMidNodes[t])
      {
        if (mid >= 0)
        {
          mask[mid] = 1;
        }
      }
    }
  }
  return mask;
}

CalculixMesh
MakeCalculixMesh(const Model & model, const CalculixSettings & settings)
{
  const std::string tetType =
    !settings.tetrahedronType.empty() ? settings.tetrahedronType : (settings.quadratic ? "C3D10" : "C3D4");
  const std::string hexType =
    !settings.hexahedronType.empty() ? settings.hexahedronType : (settings.quadratic ? "C3D20R" : "C3D8");
  const int tetNodes = ElementNodeCount(tetType);
  const int hexNodes = ElementNodeCount(hexType);
  if (tetNodes != 4 && tetNodes != 10)
  {
    throw Error("CalculiX deck: tetrahedron element type '" + tetType +
                "' is not a 4- or 10-node C3D element; use C3D4 or C3D10.");
  }
  if (hexNodes != 8 && hexNodes != 20)
  {
    throw Error("CalculiX deck: hexahedron element type '" + hexType +
                "' is not an 8- or 20-node C3D element; use C3D8, C3D8I, C3D20 or C3D20R.");
  }

  bool hasTetrahedra = false, hasHexahedra = false;
  for (const Cell & cell : model.cells)
  {
    (cell.type == CellType::Tetrahedron ? hasTetrahedra : hasHexahedra) = true;
  }
  if (hasTetrahedra && hasHexahedra && (tetNodes == 10 || hexNodes == 20))
  {
    throw Error("CalculiX deck: the model mixes hexahedra and tetrahedra; quadratic elements would not conform "
                "where a hexahedron's face meets two tetrahedra. Use quadratic = false (C3D8 and C3D4), or a "
                "tetrahedral model for a quadratic reference.");
  }

  CalculixMesh mesh;
  mesh.nodes = model.nodes;
  mesh.modelNodes = static_cast<Index>(model.nodes.size());
  mesh.elementTypes.reserve(model.cells.size());
  mesh.elements.reserve(model.cells.size());

  std::unordered_map<std::uint64_t, Index> midEdge;
  const auto midEdgeNode = [&](Index a, Index b) {
    const Index         lo = std::min(a, b);
    const Index         hi = std::max(a, b);
    const std::uint64_t key = (static_cast<std::uint64_t>(lo) << 32) | static_cast<std::uint32_t>(hi);
    const auto          found = midEdge.find(key);
    if (found != midEdge.end())
    {
      return found->second;
    }
    const Index created = static_cast<Index>(mesh.nodes.size());
    mesh.nodes.push_back(0.5 * (model.nodes[lo] + model.nodes[hi]));
    mesh.edgeParents.push_back({ lo, hi });
    midEdge.emplace(key, created);
    return created;
  };

  for (const Cell & cell : model.cells)
  {
    const bool          tet = cell.type == CellType::Tetrahedron;
    const int           corners = NodesPerCell(cell.type);
    const int           total = tet ? tetNodes : hexNodes;
    std::vector<Index> element(cell.nodes.begin(), cell.nodes.begin() + corners);
    if (total > corners)
    {
      if (tet)
      {
        for (const auto & edge : kTetEdges)
        {
          element.push_back(midEdgeNode(cell.nodes[edge[0]], cell.nodes[edge[1]]));
        }
      }
      else
      {
        for (const auto & edge : kHexEdges)
        {
          element.push_back(midEdgeNode(cell.nodes[edge[0]], cell.nodes[edge[1]]));
        }
      }
    }
    mesh.elementTypes.push_back(tet ? tetType : hexType);
    mesh.elements.push_back(std::move(element));
  }

  mesh.boundaryTriangles = model.BoundaryTriangles();
  mesh.boundaryTriangleMidNodes.assign(mesh.boundaryTriangles.size(), { -1, -1, -1 });
  for (std::size_t t = 0; t < mesh.boundaryTriangles.size(); ++t)
  {
    for (int k = 0; k < 3; ++k)
    {
      const Index         a = mesh.boundaryTriangles[t][k];
      const Index         b = mesh.boundaryTriangles[t][(k + 1) % 3];
      const std::uint64_t key =
        (static_cast<std::uint64_t>(std::min(a, b)) << 32) | static_cast<std::uint32_t>(std::max(a, b));
      const auto found = midEdge.find(key);
      if (found != midEdge.end())
      {
        mesh.boundaryTriangleMidNodes[t][k] = found->second;
      }
    }
  }

  AddCalculixContactPairs(model, mesh);
  return mesh;
}

void
WriteCalculixDeck(std::ostream & stream, const Model & model, const CalculixMesh & mesh, const CalculixSettings & settings)
{
  if (mesh.elements.size() != model.cells.size() || mesh.modelNodes != static_cast<Index>(model.nodes.size()) ||
      mesh.contactPairs.size() != model.contactSurfaces.size())
  {
    throw Error("CalculiX deck: the CalculiX mesh was made for another model; call MakeCalculixMesh on this model.");
  }
  if (model.fluidSurface)
  {
    // CalculiX's GRAV load acts on whole elements; the solver's drainage acts on nodes.
    throw Error("CalculiX deck: the model has a CSF fluid surface (gravity on the drained part only), which the "
                "CalculiX deck does not express; remove the fluid surface to compare under full gravity.");
  }

  const bool continuation = !settings.startDisplacements.empty();
  if (continuation)
  {
    if (settings.startDisplacements.size() != model.nodes.size())
    {
      throw Error("CalculiX deck: CalculixSettings::startDisplacements has " +
                  std::to_string(settings.startDisplacements.size()) + " displacements for a model of " +
                  std::to_string(model.nodes.size()) + " nodes; give one per model node, or none.");
    }
    for (const Vector3 & start : settings.startDisplacements)
    {
      if (!start.allFinite())
      {
        throw Error("CalculiX deck: CalculixSettings::startDisplacements holds a displacement that is not finite; "
                    "give finite start displacements.");
      }
    }
  }
  const bool stabilised = settings.stabilisationStiffness > 0.0;
  if (!std::isfinite(settings.stabilisationStiffness) || settings.stabilisationStiffness < 0.0 ||
      settings.stabilisationSteps < 0 || (stabilised && settings.stabilisationSteps < 1) ||
      settings.stabilisationStages < 1 || !std::isfinite(settings.stabilisationSoftening) ||
      settings.stabilisationSoftening < 1.0)
  {
    throw Error("CalculiX deck: CalculixSettings::stabilisationStiffness " +
                FormatDouble(settings.stabilisationStiffness) + " N/mm, stabilisationSteps " +
                std::to_string(settings.stabilisationSteps) + ", stabilisationStages " +
                std::to_string(settings.stabilisationStages) + " and stabilisationSoftening " +
                FormatDouble(settings.stabilisationSoftening) +
                " are not a stabilisation: give a finite stiffness > 0, at least one step and one stage and a "
                "softening >= 1, or stiffness 0 (off).");
  }
  if (settings.stabilisationExtrapolations < 0 ||
      (settings.stabilisationExtrapolations > 0 && (!stabilised || settings.stabilisationSteps < 2)))
  {
    throw Error("CalculiX deck: CalculixSettings::stabilisationExtrapolations " +
                std::to_string(settings.stabilisationExtrapolations) +
                " needs a stabilisation with at least 2 proximal steps (the last two steps' motions give the "
                "contraction it extrapolates with); give stabilisationSteps >= 2, or no extrapolations.");
  }
  if (!settings.stabilisationAnchorStart.empty())
  {
    if (!stabilised || settings.stabilisationAnchorStart.size() != mesh.nodes.size())
    {
      throw Error("CalculiX deck: CalculixSettings::stabilisationAnchorStart has " +
                  std::to_string(settings.stabilisationAnchorStart.size()) + " displacements" +
                  (stabilised ? " for a CalculiX mesh of " + std::to_string(mesh.nodes.size()) + " nodes"
                              : " without a stabilisation") +
                  "; give one per mesh node with stabilisationStiffness > 0, or none.");
    }
    for (const Vector3 & start : settings.stabilisationAnchorStart)
    {
      if (!start.allFinite())
      {
        throw Error("CalculiX deck: CalculixSettings::stabilisationAnchorStart holds a displacement that is not "
                    "finite; give finite displacements.");
      }
    }
  }
  if (stabilised && continuation)
  {
    throw Error("CalculiX deck: CalculixSettings::stabilisationStiffness and startDisplacements are two ways into a "
                "hard contact problem; give one of them.");
  }
  if (!settings.releaseForces.empty() || settings.holdOnly)
  {
    if (!continuation && !stabilised)
    {
      throw Error("CalculiX deck: CalculixSettings::releaseForces and holdOnly need startDisplacements (the state "
                  "that is held and released) or a stabilisation (whose loading step's springs are released); give "
                  "one, or leave releaseForces empty and holdOnly false.");
    }
    if (!settings.releaseForces.empty() && settings.releaseForces.size() != mesh.nodes.size())
    {
      throw Error("CalculiX deck: CalculixSettings::releaseForces has " + std::to_string(settings.releaseForces.size()) +
                  " forces for a CalculiX mesh of " + std::to_string(mesh.nodes.size()) +
                  " nodes; give one per mesh node (CalculixResult::meshReactionForces of the hold), or none.");
    }
    for (const Vector3 & force : settings.releaseForces)
    {
      if (!force.allFinite())
      {
        throw Error("CalculiX deck: CalculixSettings::releaseForces holds a force that is not finite; give finite "
                    "forces.");
      }
    }
  }

  // Constraint per model node and component: constrained flag and value (mm).
  // Prescribed displacements override fixed constraints on the same component.
  const std::size_t   modelNodes = model.nodes.size();
  std::vector<char>   constrained(modelNodes * 3, 0);
  std::vector<double> value(modelNodes * 3, 0.0);
  for (const FixedConstraint & fixed : model.fixedConstraints)
  {
    for (const Index node : model.NodeSet(fixed.nodeSet))
    {
      for (int d = 0; d < 3; ++d)
      {
        if (fixed.components[d])
        {
          constrained[3 * node + d] = 1;
          value[3 * node + d] = 0.0;
        }
      }
    }
  }
  for (const PrescribedDisplacement & prescribed : model.prescribedDisplacements)
  {
    if (prescribed.nodes.size() != prescribed.displacements.size())
    {
      throw Error("CalculiX deck: a prescribed displacement has " + std::to_string(prescribed.nodes.size()) +
                  " nodes but " + std::to_string(prescribed.displacements.size()) +
                  " displacements; give one displacement per node.");
    }
    for (std::size_t i = 0; i < prescribed.nodes.size(); ++i)
    {
      const Index node = prescribed.nodes[i];
      if (node < 0 || static_cast<std::size_t>(node) >= modelNodes)
      {
        throw Error("CalculiX deck: prescribed displacement node " + std::to_string(node) + " does not exist.");
      }
      for (int d = 0; d < 3; ++d)
      {
        if (prescribed.components[d])
        {
          constrained[3 * node + d] = 1;
          value[3 * node + d] = prescribed.displacements[i][d];
        }
      }
    }
  }

  // What the continuation holds (and its release forces act on): the corner
  // nodes of the body's boundary, in the components the model leaves free.
  std::vector<char> boundary(modelNodes, 0);
  for (const auto & triangle : mesh.boundaryTriangles)
  {
    for (const Index node : triangle)
    {
      boundary[static_cast<std::size_t>(node)] = 1;
    }
  }
  const auto held = [&](std::size_t node, int d) { return boundary[node] && !constrained[3 * node + d]; };
  // Per component: the mesh nodes constrained (the model nodes constrained in
  // it, and the mid-edge nodes on boundary faces whose vertices all are).
  std::array<std::vector<char>, 3> meshConstrained;
  for (int d = 0; d < 3; ++d)
  {
    std::vector<char> modelMask(modelNodes, 0);
    for (std::size_t node = 0; node < modelNodes; ++node)
    {
      modelMask[node] = constrained[3 * node + d];
    }
    meshConstrained[d] = mesh.MeshNodeMask(modelMask);
  }
  // The stabilisation's springs: every node of the boundary faces, mid-edge
  // nodes too (on Colin27 a mid-edge node of a single 40 Pa tetrahedron took
  // Newton corrections of 4 mm), in the components left free.
  const std::vector<char>          boundaryMeshNode = mesh.MeshNodeMask(boundary);
  std::array<std::vector<char>, 3> sprung;
  for (int d = 0; d < 3; ++d)
  {
    sprung[d].assign(mesh.nodes.size(), 0);
    for (std::size_t node = 0; node < mesh.nodes.size(); ++node)
    {
      sprung[d][node] = boundaryMeshNode[node] && !meshConstrained[d][node];
    }
  }
  const CalculixAnchors anchors(mesh, sprung, settings);
  if (stabilised && anchors.Empty())
  {
    throw Error("CalculiX deck: CalculixSettings::stabilisationStiffness asks for springs on the body's boundary, "
                "but every boundary node is constrained in every component: nothing floats, so leave the "
                "stabilisation off (stiffness 0).");
  }

  stream << "** Written by BiomechanicalRegistration (bmrCalculix).\n"
         << "** Units: mm, N, s, tonne; stresses MPa.\n";
  stream << "*NODE, NSET=NALL\n";
  for (std::size_t i = 0; i < mesh.nodes.size(); ++i)
  {
    const Vector3 & p = mesh.nodes[i];
    stream << i + 1 << ", " << FormatDouble(p.x()) << ", " << FormatDouble(p.y()) << ", " << FormatDouble(p.z()) << "\n";
  }
  anchors.WriteNodes(stream);

  // Elements grouped by (material, type); one solid section per group.
  std::map<std::pair<Index, std::string>, std::vector<std::size_t>> groups;
  for (std::size_t e = 0; e < model.cells.size(); ++e)
  {
    groups[{ model.cells[e].material, mesh.elementTypes[e] }].push_back(e);
  }
  std::vector<std::pair<std::string, Index>> sections;
  for (const auto & group : groups)
  {
    const std::string name = "M" + std::to_string(group.first.first) + "_" + group.first.second;
    sections.emplace_back(name, group.first.first);
    stream << "*ELEMENT, TYPE=" << group.first.second << ", ELSET=" << name << "\n";
    for (const std::size_t e : group.second)
    {
      const auto & element = mesh.elements[e];
      stream << e + 1;
      for (std::size_t a = 0; a < element.size(); ++a)
      {
        // At most 16 entries per line in CalculiX input; continue with a trailing comma.
        stream << (a == 15 ? ",\n" : ", ") << element[a] + 1;
      }
      stream << "\n";
    }
  }

  const bool gravity = model.bodyAcceleration.norm() > 0.0;
  for (std::size_t m = 0; m < model.materials.size(); ++m)
  {
    const Material & material = model.materials[m];
    const double     mu = material.ShearModulus() * units::PascalToInternal;
    const double     kappa = material.BulkModulus() * units::PascalToInternal;
    if (!(mu > 0.0) || !(kappa > 0.0) || !std::isfinite(kappa))
    {
      throw Error("CalculiX deck: material '" + material.name + "' has E = " + FormatDouble(material.youngsModulus) +
                  " Pa, nu = " + FormatDouble(material.poissonRatio) +
                  "; the law's constants need E > 0 and -1 < nu < 0.5.");
    }
    if (const std::string problem = MaterialLawProblem(material); !problem.empty())
    {
      throw Error("CalculiX deck: material '" + material.name + "' " + problem + ".");
    }
    const MaterialLawDescription & law = DescribeMaterialLaw(material.law);
    stream << "*MATERIAL, NAME=MAT" << m << "\n"
           << "** " << material.name << ": " << law.name << ", E = " << FormatDouble(material.youngsModulus)
           << " Pa, nu = " << FormatDouble(material.poissonRatio)
           << (law.secondInvariant ? "; C10, C01 = (1 - s, s) mu/2" : "; C10 = mu/2")
           << ", D1 = 2/kappa (MPa)\n"
           << law.calculixKeyword << "\n";
    const std::vector<double> constants = CalculixMaterialConstants(material);
    for (std::size_t c = 0; c < constants.size(); ++c)
    {
      stream << (c == 0 ? "" : ", ") << FormatDouble(constants[c]);
    }
    stream << "\n";
    if (gravity)
    {
      stream << "*DENSITY\n" << FormatDouble(material.density * units::DensityToInternal) << "\n";
    }
  }
  for (const auto & section : sections)
  {
    if (section.second < 0 || static_cast<std::size_t>(section.second) >= model.materials.size())
    {
      throw Error("CalculiX deck: a cell refers to material " + std::to_string(section.second) + ", but the model has " +
                  std::to_string(model.materials.size()) + " materials.");
    }
    stream << "*SOLID SECTION, ELSET=" << section.first << ", MATERIAL=MAT" << section.second << "\n";
  }
  WriteCalculixContactPairs(stream, model, mesh, settings);
  if (!anchors.Empty())
  {
    // Numbered after the wedges.
    std::size_t element = model.cells.size();
    for (const auto & pair : mesh.contactPairs)
    {
      element += pair.masterWedges.size();
    }
    anchors.WriteSprings(stream, element);
  }

  // The constrained mesh nodes at their values; with `start` (the
  // continuation's first step) also the held nodes at the start state.
  const auto writeBoundary = [&](bool replace, const std::vector<Vector3> * start) {
    stream << (replace ? "*BOUNDARY, OP=NEW\n" : "*BOUNDARY\n");
    for (std::size_t node = 0; node < mesh.nodes.size(); ++node)
    {
      for (int d = 0; d < 3; ++d)
      {
        if (!meshConstrained[d][node])
        {
          continue;
        }
        double v = 0.0;
        if (static_cast<Index>(node) < mesh.modelNodes)
        {
          v = value[3 * node + d];
        }
        else
        {
          const auto & parents = mesh.edgeParents[node - mesh.modelNodes];
          v = 0.5 * (value[3 * parents[0] + d] + value[3 * parents[1] + d]);
        }
        stream << node + 1 << ", " << d + 1 << ", " << d + 1 << ", " << FormatDouble(v) << "\n";
      }
    }
    if (start)
    {
      for (std::size_t node = 0; node < modelNodes; ++node)
      {
        for (int d = 0; d < 3; ++d)
        {
          if (held(node, d))
          {
            stream << node + 1 << ", " << d + 1 << ", " << d + 1 << ", " << FormatDouble((*start)[node][d]) << "\n";
          }
        }
      }
    }
    for (std::size_t node = static_cast<std::size_t>(mesh.firstRigidNode); node < mesh.nodes.size(); ++node)
    {
      stream << node + 1 << ", 1, 3, 0\n"; // the rigid masters' wedges
    }
    anchors.WriteUnsprungHolds(stream);
  };
  const auto writeStepHeader = [&](double initialIncrement) {
    stream << "*STEP, NLGEOM, INC=" << settings.maximumIncrements << "\n"
           << "*STATIC" << (settings.solver.empty() ? std::string{} : ", SOLVER=" + settings.solver) << "\n"
           << FormatDouble(initialIncrement) << ", 1.0, " << FormatDouble(settings.minimumIncrement) << ", 1.0\n"
           << "*CONTROLS, PARAMETERS=FIELD\n"
           << FormatDouble(settings.residualTolerance) << ", " << FormatDouble(settings.correctionTolerance)
           << ", 0, 0, 0.02, 1e-5, 1e-3, 1e-8\n";
  };

  const char * releaseAmplitude = "BMRRELEASE";
  if (!settings.releaseForces.empty())
  {
    // The second step (total time 1 -> 2: the release, or the first proximal
    // step): the forces fall from their full values to zero, and stay there.
    stream << "*AMPLITUDE, NAME=" << releaseAmplitude << ", TIME=TOTAL TIME\n1., 1., 2., 0., 1.e6, 0.\n";
  }
  // The released components of the first `nodes` mesh nodes carry their
  // releaseForces, scaled by the release amplitude.
  const auto writeReleaseLoads = [&](std::size_t nodes, const auto & released) {
    stream << "*CLOAD, AMPLITUDE=" << releaseAmplitude << "\n";
    for (std::size_t node = 0; node < nodes; ++node)
    {
      for (int d = 0; d < 3; ++d)
      {
        if (released(node, d) && settings.releaseForces[node][d] != 0.0)
        {
          stream << node + 1 << ", " << d + 1 << ", " << FormatDouble(settings.releaseForces[node][d]) << "\n";
        }
      }
    }
  };
  // FREQUENCY beyond the increment limit: only the end of a step is printed.
  const int frequency = settings.maximumIncrements + 1;
  writeStepHeader(settings.initialIncrement);
  if (continuation)
  {
    // First step: the boundary's corner nodes held at the start state. Its
    // mid-edge nodes stay free: on a curved skull the mean of two corners'
    // positions can lie beyond it.
    writeBoundary(false, &settings.startDisplacements);
  }
  else
  {
    writeBoundary(false, nullptr);
  }
  if (stabilised)
  {
    anchors.WriteHold(stream, 0, 0, false);
  }

  if (gravity)
  {
    const double  magnitude = model.bodyAcceleration.norm(); // mm/s^2, consistent with t, N
    const Vector3 direction = model.bodyAcceleration / magnitude;
    stream << "*DLOAD\n";
    for (const auto & section : sections)
    {
      stream << section.first << ", GRAV, " << FormatDouble(magnitude) << ", " << FormatDouble(direction.x()) << ", "
             << FormatDouble(direction.y()) << ", " << FormatDouble(direction.z()) << "\n";
    }
  }

  if (continuation && !settings.holdOnly)
  {
    // The release: the model's own constraints only; loads carry over.
    stream << "*END STEP\n";
    writeStepHeader(settings.initialIncrement);
    writeBoundary(true, nullptr);
    if (!settings.releaseForces.empty())
    {
      writeReleaseLoads(modelNodes, held);
    }
  }
  if (stabilised && !settings.holdOnly)
  {
    // The proximal steps: each starts whole (it moves little once the first has
    // loaded the body), the set that followed the nodes frozen, the other freed
    // (OP=NEW); a new stage's springs start from where their anchors followed
    // the nodes to, the earlier stages' all freed.
    std::string fixedSet = CalculixAnchors::SetName(0, 0); // the loading step's
    for (int stage = 0; stage < anchors.Families(); ++stage)
    {
      for (int step = 1; step <= settings.stabilisationSteps; ++step)
      {
        // The nodes' state at every step's end: a later step that Newton does
        // not finish leaves this one as the result.
        stream << "*NODE PRINT, NSET=" << fixedSet << ", FREQUENCY=" << frequency << "\n"
               << "RF\n"
               << "*NODE PRINT, NSET=NALL, FREQUENCY=" << frequency << "\n"
               << "U\n"
               << "*END STEP\n";
        const bool placed = stage == 0 && step == 1 && !settings.stabilisationAnchorStart.empty();
        // A step whose anchors move (a restart's first) starts with the
        // loading step's increment: at once, on Colin27, the contact set grew
        // from 302 to 1,080 elements and Newton diverged.
        writeStepHeader(placed ? settings.initialIncrement : 1.0);
        writeBoundary(true, nullptr);
        const int set = stage == 0 ? step % 2 : (step - 1) % 2;
        if (placed)
        {
          // A restart: the first proximal step's anchors at the given state,
          // not where the loading step left them (a loading step with the
          // anchors moving stalled in penalty contact on the walled block).
          anchors.WriteHold(stream, stage, set, false, &settings.stabilisationAnchorStart);
        }
        else
        {
          anchors.WriteHold(stream, stage, set, true);
        }
        if (stage == 0 && step == 1 && !settings.releaseForces.empty())
        {
          // The loading step's springs, released here, handed over to loads
          // that fall to zero over the step: it starts in equilibrium.
          writeReleaseLoads(mesh.nodes.size(), [&](std::size_t node, int d) { return sprung[d][node] != 0; });
        }
        fixedSet = CalculixAnchors::SetName(stage, set);
      }
    }
    stream << "*NODE PRINT, NSET=" << fixedSet << ", FREQUENCY=" << frequency << "\n"
           << "RF\n";
  }
  stream << "*NODE PRINT, NSET=NALL, FREQUENCY=" << frequency << "\n"
         << "U\n"
         << "*NODE PRINT, NSET=NALL, FREQUENCY=" << frequency << "\n"
         << "RF\n"
         << "*END STEP\n";
}

} // namespace bmr
