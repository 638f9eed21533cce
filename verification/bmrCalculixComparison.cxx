// Comparing with CalculiX: nodes matched by position, displacement
// differences, and the indentation problem the verification tests and the
// benchmark solve with both (see bmrCalculix.h).
#include "bmrCalculix.h"

#include "bmrMeshGenerators.h"
#include "bmrUnits.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <unordered_map>

namespace bmr
{
namespace
{

struct GridKey
{
  long long x, y, z;
  bool operator==(const GridKey & other) const { return x == other.x && y == other.y && z == other.z; }
};

struct GridKeyHash
{
  std::size_t operator()(const GridKey & key) const
  {
    std::size_t h = static_cast<std::size_t>(key.x) * 73856093u;
    h ^= static_cast<std::size_t>(key.y) * 19349663u;
    h ^= static_cast<std::size_t>(key.z) * 83492791u;
    return h;
  }
};

} // namespace

std::vector<Index>
MatchNodes(const std::vector<Vector3> & points, const std::vector<Vector3> & nodes, double tolerance)
{
  const double cell = std::max(2.0 * tolerance, 1e-12);
  const auto   keyOf = [cell](const Vector3 & p) {
    return GridKey{ static_cast<long long>(std::floor(p.x() / cell)),
                    static_cast<long long>(std::floor(p.y() / cell)),
                    static_cast<long long>(std::floor(p.z() / cell)) };
  };
  std::unordered_map<GridKey, std::vector<Index>, GridKeyHash> grid;
  grid.reserve(nodes.size());
  for (Index i = 0; i < static_cast<Index>(nodes.size()); ++i)
  {
    grid[keyOf(nodes[i])].push_back(i);
  }
  std::vector<Index> match(points.size(), -1);
  for (std::size_t p = 0; p < points.size(); ++p)
  {
    const GridKey centre = keyOf(points[p]);
    double        best = tolerance;
    for (long long dx = -1; dx <= 1; ++dx)
    {
      for (long long dy = -1; dy <= 1; ++dy)
      {
        for (long long dz = -1; dz <= 1; ++dz)
        {
          const auto found = grid.find(GridKey{ centre.x + dx, centre.y + dy, centre.z + dz });
          if (found == grid.end())
          {
            continue;
          }
          for (const Index candidate : found->second)
          {
            const double distance = (nodes[candidate] - points[p]).norm();
            if (distance <= best)
            {
              best = distance;
              match[p] = candidate;
            }
          }
        }
      }
    }
  }
  return match;
}

DisplacementComparison
CompareDisplacements(const std::vector<Vector3> & nodes,
                     const std::vector<Vector3> & displacements,
                     const std::vector<Vector3> & referenceNodes,
                     const std::vector<Vector3> & referenceDisplacements,
                     double                       tolerance)
{
  if (nodes.size() != displacements.size() || referenceNodes.size() != referenceDisplacements.size())
  {
    throw Error("CompareDisplacements: node and displacement counts differ.");
  }
  const std::vector<Index> match = MatchNodes(nodes, referenceNodes, tolerance);
  DisplacementComparison   comparison;
  double                   sumSquares = 0.0;
  for (std::size_t i = 0; i < nodes.size(); ++i)
  {
    if (match[i] < 0)
    {
      std::ostringstream message;
      message << "CompareDisplacements: node " << i << " at (" << nodes[i].transpose()
              << ") mm is not a node of the reference mesh; use a reference mesh that refines this one.";
      throw Error(message.str());
    }
    const double error = (displacements[i] - referenceDisplacements[match[i]]).norm();
    sumSquares += error * error;
    if (error > comparison.maxError || comparison.maxNode < 0)
    {
      comparison.maxError = error;
      comparison.maxNode = static_cast<Index>(i);
    }
  }
  comparison.nodes = static_cast<int>(nodes.size());
  comparison.rmsError = nodes.empty() ? 0.0 : std::sqrt(sumSquares / static_cast<double>(nodes.size()));
  return comparison;
}

namespace
{

Model
MakeIndentation(const IndentationProblem & problem,
                const std::array<int, 3> & divisions,
                GridCells                  cells,
                bool                       quarter)
{
  const double  cx = 0.5 * problem.size.x();
  const double  cy = 0.5 * problem.size.y();
  const Vector3 origin = quarter ? Vector3(cx, cy, 0.0) : Vector3::Zero();
  const Vector3 size = quarter ? Vector3(0.5 * problem.size.x(), 0.5 * problem.size.y(), problem.size.z()) : problem.size;
  Model         model = MakeBlockMesh(size, divisions, cells, problem.material, origin);
  const double  eps = 1e-9 * problem.size.maxCoeff();

  std::vector<Index> bottom;
  std::vector<Index> patch;
  for (Index i = 0; i < static_cast<Index>(model.nodes.size()); ++i)
  {
    const Vector3 & p = model.nodes[i];
    if (std::abs(p.z()) <= eps)
    {
      bottom.push_back(i);
    }
    if (std::abs(p.z() - problem.size.z()) <= eps && std::abs(p.x() - cx) <= problem.patchHalfWidth + eps &&
        std::abs(p.y() - cy) <= problem.patchHalfWidth + eps)
    {
      patch.push_back(i);
    }
  }
  if (patch.empty())
  {
    throw Error("MakeIndentationModel: no top-face node lies in the indentation patch; refine the divisions or widen "
                "the patch.");
  }
  model.nodeSets["bottom"] = bottom;
  model.nodeSets["patch"] = patch;

  FixedConstraint fixed;
  fixed.nodeSet = "bottom";
  model.fixedConstraints.push_back(fixed);
  if (quarter)
  {
    model.fixedConstraints.push_back(FixedConstraint{ "xmin", { true, false, false } });
    model.fixedConstraints.push_back(FixedConstraint{ "ymin", { false, true, false } });
  }

  PrescribedDisplacement indent;
  indent.nodes = patch;
  indent.displacements.assign(patch.size(), Vector3(0.0, 0.0, -problem.depth));
  model.prescribedDisplacements.push_back(indent);
  return model;
}

} // namespace

Model
MakeIndentationModel(const IndentationProblem & problem, const std::array<int, 3> & divisions, GridCells cells)
{
  return MakeIndentation(problem, divisions, cells, false);
}

Model
MakeIndentationQuarterModel(const IndentationProblem & problem, const std::array<int, 3> & divisions, GridCells cells)
{
  return MakeIndentation(problem, divisions, cells, true);
}

std::vector<Vector3>
UnfoldQuarterDisplacements(const IndentationProblem &   problem,
                           const std::vector<Vector3> & quarterNodes,
                           const std::vector<Vector3> & quarterDisplacements,
                           const std::vector<Vector3> & points,
                           double                       tolerance)
{
  return UnfoldQuarterDisplacements(
    0.5 * problem.size.x(), 0.5 * problem.size.y(), quarterNodes, quarterDisplacements, points, tolerance);
}

std::vector<Vector3>
UnfoldQuarterDisplacements(double                       cx,
                           double                       cy,
                           const std::vector<Vector3> & quarterNodes,
                           const std::vector<Vector3> & quarterDisplacements,
                           const std::vector<Vector3> & points,
                           double                       tolerance)
{
  std::vector<Vector3> reflected(points.size());
  std::vector<Vector3> signs(points.size());
  for (std::size_t i = 0; i < points.size(); ++i)
  {
    const Vector3 & p = points[i];
    const bool      flipX = p.x() < cx;
    const bool      flipY = p.y() < cy;
    reflected[i] = Vector3(flipX ? 2.0 * cx - p.x() : p.x(), flipY ? 2.0 * cy - p.y() : p.y(), p.z());
    signs[i] = Vector3(flipX ? -1.0 : 1.0, flipY ? -1.0 : 1.0, 1.0);
  }
  const std::vector<Index> match = MatchNodes(reflected, quarterNodes, tolerance);
  std::vector<Vector3>     result(points.size());
  for (std::size_t i = 0; i < points.size(); ++i)
  {
    if (match[i] < 0)
    {
      std::ostringstream message;
      message << "UnfoldQuarterDisplacements: point (" << points[i].transpose()
              << ") mm reflects to no node of the quarter mesh; use a quarter mesh that refines the full one.";
      throw Error(message.str());
    }
    result[i] = quarterDisplacements[match[i]].cwiseProduct(signs[i]);
  }
  return result;
}

Model
MakeBrainSagModel(const BrainSagProblem & problem, double bodySpacing, int subdivisions, bool quarter)
{
  const Model full = MakeEllipsoidMesh(problem.semiAxes, bodySpacing, GridCells::Tetrahedra, problem.material, subdivisions);
  std::vector<char> onSurface(full.nodes.size(), 0);
  for (const Index node : full.NodeSet("surface"))
  {
    onSurface[node] = 1;
  }

  std::vector<char> keep(full.cells.size(), 1);
  for (std::size_t c = 0; c < full.cells.size() && quarter; ++c)
  {
    Vector3 centre = Vector3::Zero();
    for (int v = 0; v < 4; ++v)
    {
      centre += 0.25 * full.nodes[full.cells[c].nodes[v]];
    }
    keep[c] = centre.x() > 0.0 && centre.y() > 0.0;
  }
  std::vector<Index> newIndex;
  Model              model = KeepCells(full, keep, &newIndex);

  const Vector3        top(0.0, 0.0, problem.semiAxes.z());
  const double         onPlane = 1e-9 * bodySpacing;
  // The body grid's node planes lie a whole number of body spacings above its lowest node.
  double lowest = std::numeric_limits<double>::infinity();
  for (const Vector3 & p : full.nodes)
  {
    lowest = std::min(lowest, p.z());
  }
  const double baseZ = lowest + bodySpacing * std::round((problem.baseZ - lowest) / bodySpacing) + onPlane;
  const double         radius = problem.craniotomyRadius;
  std::vector<Index>   surface, base, craniotomy, symmetryX, symmetryY;
  std::vector<Vector3> sag;
  for (std::size_t old = 0; old < full.nodes.size(); ++old)
  {
    const Index node = newIndex[old];
    if (node < 0)
    {
      continue;
    }
    const Vector3 & p = model.nodes[node];
    if (quarter && std::abs(p.x()) < onPlane)
    {
      symmetryX.push_back(node);
    }
    if (quarter && std::abs(p.y()) < onPlane)
    {
      symmetryY.push_back(node);
    }
    if (!onSurface[old])
    {
      continue;
    }
    surface.push_back(node);
    const double r = (p - top).norm();
    if (p.z() <= baseZ)
    {
      base.push_back(node);
    }
    else if (r <= radius)
    {
      craniotomy.push_back(node);
      sag.emplace_back(0.0, 0.0, -problem.depth * (1.0 - (r / radius) * (r / radius)));
    }
  }
  if (quarter && (symmetryX.empty() || symmetryY.empty()))
  {
    std::ostringstream message;
    message << "MakeBrainSagModel: the grid of spacing " << bodySpacing / subdivisions
            << " mm has no node plane at x = 0 or y = 0, so it has no quarter model; choose a body spacing that "
               "divides the ellipsoid's box into an even number of cells along x and y, or an even subdivision.";
    throw Error(message.str());
  }
  if (craniotomy.empty() || base.empty())
  {
    throw Error("MakeBrainSagModel: no surface node lies in the craniotomy or below the base; refine the body spacing.");
  }
  model.nodeSets["surface"] = surface;
  model.nodeSets["base"] = base;
  model.nodeSets["craniotomy"] = craniotomy;
  model.fixedConstraints.push_back(FixedConstraint{ "base", { true, true, true } });
  if (quarter)
  {
    model.nodeSets["xmin"] = symmetryX;
    model.nodeSets["ymin"] = symmetryY;
    model.fixedConstraints.push_back(FixedConstraint{ "xmin", { true, false, false } });
    model.fixedConstraints.push_back(FixedConstraint{ "ymin", { false, true, false } });
  }
  PrescribedDisplacement push;
  push.nodes = craniotomy;
  push.displacements = sag;
  model.prescribedDisplacements.push_back(push);
  model.Validate();
  return model;
}

} // namespace bmr
