// Structured meshes for verification, benchmarks and the brain-sized demo:
// blocks, ellipsoids on a regular grid, and closed ellipsoid surfaces.
#include "bmrMeshGenerators.h"

#include "bmrShape.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <sstream>
#include <utility>

namespace bmr
{
namespace
{

/** Throws when a grid of cellsX x cellsY x cellsZ cells (doubles: they may be
 *  huge or not finite) has more nodes or cells than a 32-bit Index numbers
 *  (3 DOF per node), before anything is allocated for it. */
void
RequireIndexableGrid(const char * generator, double cellsX, double cellsY, double cellsZ)
{
  const double nodes = (cellsX + 1.0) * (cellsY + 1.0) * (cellsZ + 1.0);
  const double cells = 6.0 * cellsX * cellsY * cellsZ; // tetrahedra: 6 per grid cell
  const double limit = static_cast<double>(std::numeric_limits<Index>::max());
  if (!(3.0 * nodes <= limit && cells <= limit))
  {
    std::ostringstream message;
    message << generator << ": a grid of " << cellsX << " x " << cellsY << " x " << cellsZ << " cells has " << nodes
            << " nodes, more than the " << static_cast<long long>(limit / 3.0)
            << " a model can number; use fewer divisions or a coarser spacing";
    throw Error(message.str());
  }
}


/** Adds the cells of one grid cell whose 8 corner node ids (VTK order) are given. */
void
AddGridCell(Model & model, const std::array<Index, 8> & corners, bool hexahedron)
{
  if (hexahedron)
  {
    Cell cell;
    cell.type = CellType::Hexahedron;
    cell.nodes = corners;
    cell.material = 0;
    model.cells.push_back(cell);
    return;
  }
  for (const auto & tet : KuhnTetrahedra)
  {
    Cell cell;
    cell.type = CellType::Tetrahedron;
    cell.nodes.fill(0);
    for (int n = 0; n < 4; ++n)
    {
      cell.nodes[n] = corners[tet[n]];
    }
    cell.material = 0;
    model.cells.push_back(cell);
  }
}

/** Determinants of the trilinear map's Jacobian at the 8 corners of a hexahedron
 *  (all positive for a valid, non-inverted cell). */
double
MinCornerJacobian(const Model & model, const Cell & cell)
{
  // Neighbours of each corner along the local +xi, +eta, +zeta directions (or
  // their negatives), in an order that gives a right-handed frame for a cube.
  static const int neighbours[8][3] = { { 1, 3, 4 }, { 2, 0, 5 }, { 3, 1, 6 }, { 0, 2, 7 },
                                        { 7, 5, 0 }, { 4, 6, 1 }, { 5, 7, 2 }, { 6, 4, 3 } };
  double minimum = std::numeric_limits<double>::max();
  for (int c = 0; c < 8; ++c)
  {
    const Vector3 & p = model.nodes[cell.nodes[c]];
    const Vector3   a = model.nodes[cell.nodes[neighbours[c][0]]] - p;
    const Vector3   b = model.nodes[cell.nodes[neighbours[c][1]]] - p;
    const Vector3   d = model.nodes[cell.nodes[neighbours[c][2]]] - p;
    minimum = std::min(minimum, a.cross(b).dot(d));
  }
  return minimum;
}

bool
CellIsValid(const Model & model, const Cell & cell, double minTetVolume, double minCornerJacobian)
{
  if (cell.type == CellType::Hexahedron)
  {
    return MinCornerJacobian(model, cell) > minCornerJacobian;
  }
  return TetrahedronVolume(model.nodes[cell.nodes[0]], model.nodes[cell.nodes[1]], model.nodes[cell.nodes[2]],
                   model.nodes[cell.nodes[3]]) > minTetVolume;
}

} // namespace

Model
MakeBlockMesh(const Vector3 & size, const std::array<int, 3> & divisions, GridCells cells, const Material & material,
              const Vector3 & origin)
{
  for (int d = 0; d < 3; ++d)
  {
    if (divisions[d] < 1)
    {
      std::ostringstream message;
      message << "MakeBlockMesh: divisions[" << d << "] = " << divisions[d] << " must be at least 1";
      throw Error(message.str());
    }
    if (!(size[d] > 0.0))
    {
      std::ostringstream message;
      message << "MakeBlockMesh: size[" << d << "] = " << size[d] << " mm must be positive";
      throw Error(message.str());
    }
  }
  RequireIndexableGrid("MakeBlockMesh", divisions[0], divisions[1], divisions[2]);
  const int nx = divisions[0], ny = divisions[1], nz = divisions[2];
  Model     model;
  model.materials.push_back(material);

  auto nodeId = [&](int i, int j, int k) { return static_cast<Index>(i + (nx + 1) * (j + (ny + 1) * k)); };
  model.nodes.resize(static_cast<std::size_t>(nx + 1) * (ny + 1) * (nz + 1));
  for (int k = 0; k <= nz; ++k)
  {
    for (int j = 0; j <= ny; ++j)
    {
      for (int i = 0; i <= nx; ++i)
      {
        // Exact end coordinates (no accumulated rounding) on the far faces.
        const Vector3 fraction(double(i) / nx, double(j) / ny, double(k) / nz);
        model.nodes[nodeId(i, j, k)] = origin + size.cwiseProduct(fraction);
      }
    }
  }

  const double xSplit = origin.x() + 0.5 * size.x();
  for (int k = 0; k < nz; ++k)
  {
    for (int j = 0; j < ny; ++j)
    {
      for (int i = 0; i < nx; ++i)
      {
        std::array<Index, 8> corners{};
        for (int c = 0; c < 8; ++c)
        {
          corners[c] = nodeId(i + HexahedronCornerOffsets[c][0], j + HexahedronCornerOffsets[c][1], k + HexahedronCornerOffsets[c][2]);
        }
        bool hexahedron = cells == GridCells::Hexahedra;
        if (cells == GridCells::Mixed)
        {
          const double centreX = origin.x() + size.x() * (i + 0.5) / nx;
          hexahedron = centreX < xSplit;
        }
        AddGridCell(model, corners, hexahedron);
      }
    }
  }

  auto & all = model.nodeSets["all"];
  all.resize(model.nodes.size());
  for (std::size_t n = 0; n < all.size(); ++n)
  {
    all[n] = static_cast<Index>(n);
  }
  auto & xmin = model.nodeSets["xmin"];
  auto & xmax = model.nodeSets["xmax"];
  auto & ymin = model.nodeSets["ymin"];
  auto & ymax = model.nodeSets["ymax"];
  auto & zmin = model.nodeSets["zmin"];
  auto & zmax = model.nodeSets["zmax"];
  for (int k = 0; k <= nz; ++k)
  {
    for (int j = 0; j <= ny; ++j)
    {
      for (int i = 0; i <= nx; ++i)
      {
        const Index n = nodeId(i, j, k);
        if (i == 0)
          xmin.push_back(n);
        if (i == nx)
          xmax.push_back(n);
        if (j == 0)
          ymin.push_back(n);
        if (j == ny)
          ymax.push_back(n);
        if (k == 0)
          zmin.push_back(n);
        if (k == nz)
          zmax.push_back(n);
      }
    }
  }
  return model;
}

void
DistortInteriorNodes(Model & model, double fraction, std::uint32_t seed)
{
  if (model.nodes.empty() || fraction == 0.0)
  {
    return;
  }
  if (!(fraction > 0.0) || !std::isfinite(fraction))
  {
    std::ostringstream message;
    message << "DistortInteriorNodes: fraction " << fraction << " must be a non-negative finite number";
    throw Error(message.str());
  }

  // Bounding box and smallest grid spacing (the shortest extent, along its
  // dominant axis, of any cell edge: the axis-aligned edges of a grid cell).
  Vector3 lower = model.nodes[0], upper = model.nodes[0];
  for (const auto & p : model.nodes)
  {
    lower = lower.cwiseMin(p);
    upper = upper.cwiseMax(p);
  }
  double spacing = std::numeric_limits<double>::max();
  for (const auto & cell : model.cells)
  {
    const int count = NodesPerCell(cell.type);
    for (int a = 0; a < count; ++a)
    {
      for (int b = a + 1; b < count; ++b)
      {
        const double extent = (model.nodes[cell.nodes[a]] - model.nodes[cell.nodes[b]]).cwiseAbs().maxCoeff();
        if (extent > 0.0)
        {
          spacing = std::min(spacing, extent);
        }
      }
    }
  }
  if (spacing == std::numeric_limits<double>::max())
  {
    return;
  }
  const double tolerance = 1e-9 * (upper - lower).norm();

  std::vector<bool> movable(model.nodes.size(), true);
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    const Vector3 & p = model.nodes[n];
    for (int d = 0; d < 3; ++d)
    {
      if (std::abs(p[d] - lower[d]) <= tolerance || std::abs(p[d] - upper[d]) <= tolerance)
      {
        movable[n] = false;
      }
    }
  }
  // Meshes that name their surface (ellipsoids) keep it too.
  const auto surface = model.nodeSets.find("surface");
  if (surface != model.nodeSets.end())
  {
    for (Index n : surface->second)
    {
      if (n >= 0 && static_cast<std::size_t>(n) < movable.size())
      {
        movable[n] = false;
      }
    }
  }

  // std::mt19937's output sequence is fixed by the standard; the mapping to
  // [-1, 1] is done here so the result does not depend on the library.
  std::mt19937         generator(seed);
  std::vector<Vector3> offsets(model.nodes.size(), Vector3::Zero());
  const double         amplitude = fraction * spacing;
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    Vector3 r;
    for (int d = 0; d < 3; ++d)
    {
      r[d] = 2.0 * (static_cast<double>(generator()) / 4294967295.0) - 1.0;
    }
    if (movable[n])
    {
      offsets[n] = amplitude * r;
    }
  }

  // Apply, then halve the offsets of the nodes of any cell that became badly
  // shaped (rare worst cases of large fractions) until every cell is valid.
  const std::vector<Vector3> original = model.nodes;
  const double               minTetVolume = 1e-3 * spacing * spacing * spacing / 6.0;
  const double               minJacobian = 1e-3 * spacing * spacing * spacing;
  for (int attempt = 0; attempt < 30; ++attempt)
  {
    for (std::size_t n = 0; n < model.nodes.size(); ++n)
    {
      model.nodes[n] = original[n] + offsets[n];
    }
    bool allValid = true;
    for (const auto & cell : model.cells)
    {
      if (!CellIsValid(model, cell, minTetVolume, minJacobian))
      {
        allValid = false;
        for (int a = 0; a < NodesPerCell(cell.type); ++a)
        {
          offsets[cell.nodes[a]] *= 0.5;
        }
      }
    }
    if (allValid)
    {
      return;
    }
  }
  model.nodes = original; // could not distort safely: leave the mesh as it was
}

Model
MakeEllipsoidMesh(const Vector3 & semiAxes, double spacing, GridCells cells, const Material & material, int subdivisions)
{
  if (!(spacing > 0.0) || !(semiAxes.minCoeff() > 0.0) || subdivisions < 1)
  {
    std::ostringstream message;
    message << "MakeEllipsoidMesh: semi-axes (" << semiAxes.transpose() << ") mm, spacing " << spacing
            << " mm and subdivisions " << subdivisions << " must be positive";
    throw Error(message.str());
  }
  // Grid symmetric about the origin that covers the ellipsoid; the body is
  // decided on the grid of `spacing`, the cells are `subdivisions` finer.
  const Vector3 gridCells = (2.0 * semiAxes / spacing).array().ceil().max(1.0).matrix() * subdivisions;
  RequireIndexableGrid("MakeEllipsoidMesh", gridCells[0], gridCells[1], gridCells[2]);
  const double       h = spacing / subdivisions;
  std::array<int, 3> n{};
  Vector3            lower;
  for (int d = 0; d < 3; ++d)
  {
    n[d] = static_cast<int>(gridCells[d]);
    lower[d] = -0.5 * n[d] * h;
  }
  auto inside = [&](int i, int j, int k) {
    if (i < 0 || j < 0 || k < 0 || i >= n[0] || j >= n[1] || k >= n[2])
      return false;
    const Vector3 centre =
      lower + spacing * Vector3(i / subdivisions + 0.5, j / subdivisions + 0.5, k / subdivisions + 0.5);
    return centre.cwiseQuotient(semiAxes).squaredNorm() < 1.0;
  };

  Model model;
  model.materials.push_back(material);
  const std::size_t    gridNodes = static_cast<std::size_t>(n[0] + 1) * (n[1] + 1) * (n[2] + 1);
  std::vector<Index>   nodeOfGrid(gridNodes, -1);
  auto                 gridId = [&](int i, int j, int k) {
    return static_cast<std::size_t>(i) + static_cast<std::size_t>(n[0] + 1) * (j + static_cast<std::size_t>(n[1] + 1) * k);
  };
  std::vector<std::array<int, 3>> gridOfNode;
  auto                            node = [&](int i, int j, int k) {
    Index & id = nodeOfGrid[gridId(i, j, k)];
    if (id < 0)
    {
      id = static_cast<Index>(model.nodes.size());
      model.nodes.push_back(lower + h * Vector3(i, j, k));
      gridOfNode.push_back({ i, j, k });
    }
    return id;
  };

  for (int k = 0; k < n[2]; ++k)
  {
    for (int j = 0; j < n[1]; ++j)
    {
      for (int i = 0; i < n[0]; ++i)
      {
        if (!inside(i, j, k))
          continue;
        std::array<Index, 8> corners{};
        for (int c = 0; c < 8; ++c)
        {
          corners[c] = node(i + HexahedronCornerOffsets[c][0], j + HexahedronCornerOffsets[c][1], k + HexahedronCornerOffsets[c][2]);
        }
        bool hexahedron = cells == GridCells::Hexahedra;
        if (cells == GridCells::Mixed)
        {
          hexahedron = (lower.x() + h * (i + 0.5)) < 0.0;
        }
        AddGridCell(model, corners, hexahedron);
      }
    }
  }
  if (model.cells.empty())
  {
    std::ostringstream message;
    message << "MakeEllipsoidMesh: spacing " << spacing << " mm is too coarse for semi-axes ("
            << semiAxes.transpose() << ") mm: no grid cell centre lies inside";
    throw Error(message.str());
  }

  // A node is on the surface when one of the 8 grid cells around it is outside
  // (the cube-adjacency graph is connected, so it then lies on a boundary face).
  auto & surface = model.nodeSets["surface"];
  auto & all = model.nodeSets["all"];
  for (std::size_t id = 0; id < model.nodes.size(); ++id)
  {
    all.push_back(static_cast<Index>(id));
    const auto & g = gridOfNode[id];
    bool         onSurface = false;
    for (int c = 0; c < 8 && !onSurface; ++c)
    {
      onSurface = !inside(g[0] - HexahedronCornerOffsets[c][0], g[1] - HexahedronCornerOffsets[c][1], g[2] - HexahedronCornerOffsets[c][2]);
    }
    if (onSurface)
    {
      surface.push_back(static_cast<Index>(id));
    }
  }
  return model;
}

ContactSurface
MakeEllipsoidSurface(const Vector3 & semiAxes, int subdivisions, const Vector3 & centre)
{
  if (subdivisions < 0 || subdivisions > 8)
  {
    std::ostringstream message;
    message << "MakeEllipsoidSurface: subdivisions = " << subdivisions << " must be in [0, 8]";
    throw Error(message.str());
  }
  if (!(semiAxes.minCoeff() > 0.0))
  {
    std::ostringstream message;
    message << "MakeEllipsoidSurface: semi-axes (" << semiAxes.transpose() << ") mm must be positive";
    throw Error(message.str());
  }
  const double         t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vector3> vertices = { { -1, t, 0 }, { 1, t, 0 },  { -1, -t, 0 }, { 1, -t, 0 },
                                    { 0, -1, t }, { 0, 1, t },  { 0, -1, -t }, { 0, 1, -t },
                                    { t, 0, -1 }, { t, 0, 1 },  { -t, 0, -1 }, { -t, 0, 1 } };
  for (auto & v : vertices)
  {
    v.normalize();
  }
  std::vector<std::array<Index, 3>> triangles = { { 0, 11, 5 }, { 0, 5, 1 },  { 0, 1, 7 },   { 0, 7, 10 }, { 0, 10, 11 },
                                                  { 1, 5, 9 },  { 5, 11, 4 }, { 11, 10, 2 }, { 10, 7, 6 }, { 7, 1, 8 },
                                                  { 3, 9, 4 },  { 3, 4, 2 },  { 3, 2, 6 },   { 3, 6, 8 },  { 3, 8, 9 },
                                                  { 4, 9, 5 },  { 2, 4, 11 }, { 6, 2, 10 },  { 8, 6, 7 },  { 9, 8, 1 } };
  for (int level = 0; level < subdivisions; ++level)
  {
    std::map<std::pair<Index, Index>, Index> midpoints;
    auto                                     midpoint = [&](Index a, Index b) {
      const auto key = std::make_pair(std::min(a, b), std::max(a, b));
      const auto found = midpoints.find(key);
      if (found != midpoints.end())
        return found->second;
      const Index id = static_cast<Index>(vertices.size());
      vertices.push_back((vertices[a] + vertices[b]).normalized());
      midpoints.emplace(key, id);
      return id;
    };
    std::vector<std::array<Index, 3>> refined;
    refined.reserve(triangles.size() * 4);
    for (const auto & tri : triangles)
    {
      const Index ab = midpoint(tri[0], tri[1]);
      const Index bc = midpoint(tri[1], tri[2]);
      const Index ca = midpoint(tri[2], tri[0]);
      refined.push_back({ tri[0], ab, ca });
      refined.push_back({ tri[1], bc, ab });
      refined.push_back({ tri[2], ca, bc });
      refined.push_back({ ab, bc, ca });
    }
    triangles.swap(refined);
  }
  // Outward orientation on the unit sphere (kept by the positive scaling).
  for (auto & tri : triangles)
  {
    const Vector3 & a = vertices[tri[0]];
    const Vector3 & b = vertices[tri[1]];
    const Vector3 & c = vertices[tri[2]];
    if ((b - a).cross(c - a).dot(a + b + c) < 0.0)
    {
      std::swap(tri[1], tri[2]);
    }
  }
  ContactSurface surface;
  surface.name = "ellipsoid";
  surface.vertices.reserve(vertices.size());
  for (const auto & v : vertices)
  {
    surface.vertices.push_back(centre + v.cwiseProduct(semiAxes));
  }
  surface.triangles = std::move(triangles);
  surface.bodySide = ContactSurface::Side::Inside;
  return surface;
}

} // namespace bmr
