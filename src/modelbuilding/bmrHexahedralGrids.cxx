// Regular hexahedral grids conforming to a mask, and mixed grids (boundary
// cubes split into tetrahedra with snapped surface nodes).
#include "bmrImageGridBody.h"

namespace bmr
{
namespace grids
{
namespace
{

struct CubeGrid
{
  double                h = 0.0;
  std::array<int, 3>    n{};     // cubes per axis
  Vector3               start;   // grid frame position of grid point (0, 0, 0)
  std::vector<double>   fraction; // inside volume fraction per cube
  std::vector<int>      label;    // majority label per cube
  std::vector<char>     keep;

  std::size_t Cube(int a, int b, int c) const
  {
    return static_cast<std::size_t>(a) + static_cast<std::size_t>(n[0]) * (static_cast<std::size_t>(b) + n[1] * static_cast<std::size_t>(c));
  }
  std::size_t Point(int a, int b, int c) const
  {
    return static_cast<std::size_t>(a) +
           static_cast<std::size_t>(n[0] + 1) * (static_cast<std::size_t>(b) + (n[1] + 1) * static_cast<std::size_t>(c));
  }
  std::size_t PointCount() const { return static_cast<std::size_t>(n[0] + 1) * (n[1] + 1) * (n[2] + 1); }
  bool Kept(int a, int b, int c) const
  {
    if (a < 0 || b < 0 || c < 0 || a >= n[0] || b >= n[1] || c >= n[2])
    {
      return false;
    }
    return keep[Cube(a, b, c)] != 0;
  }
  Vector3 PointPosition(int a, int b, int c) const { return start + h * Vector3(a, b, c); }
};

/** Voxels overlapping the interval [lo, hi] (grid frame) along one axis and the overlap lengths. */
std::vector<std::pair<int, double>>
Overlaps(double lo, double hi, double spacing, int size)
{
  std::vector<std::pair<int, double>> result;
  const int first = std::max(0, static_cast<int>(std::floor(lo / spacing + 0.5)));
  const int last = std::min(size - 1, static_cast<int>(std::floor(hi / spacing + 0.5)));
  for (int i = first; i <= last; ++i)
  {
    const double overlap = std::min(hi, (i + 0.5) * spacing) - std::max(lo, (i - 0.5) * spacing);
    if (overlap > 0.0)
    {
      result.emplace_back(i, overlap);
    }
  }
  return result;
}

/** Makes the kept cubes well-composed (no two cubes meet at only an edge or a
 *  vertex with the cubes around it missing, no such pinch of the outside
 *  either) by adding, for each offending configuration, the missing cube with
 *  the largest inside fraction. Returns the number of cubes added. */
std::size_t
RemoveNonManifoldContacts(CubeGrid & grid)
{
  std::size_t added = 0;
  auto        add = [&](std::size_t first, std::size_t second) {
    grid.keep[grid.fraction[first] >= grid.fraction[second] ? first : second] = 1;
    ++added;
  };
  for (int iteration = 0; iteration < 100; ++iteration)
  {
    const std::size_t before = added;
    // Edge configurations: the 4 cubes around a grid edge, kept diagonally.
    for (int axis = 0; axis < 3; ++axis)
    {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      std::array<int, 3> p{};
      for (p[2] = 0; p[2] < grid.n[2]; ++p[2])
        for (p[1] = 0; p[1] < grid.n[1]; ++p[1])
          for (p[0] = 0; p[0] < grid.n[0]; ++p[0])
          {
            if (p[u] + 1 >= grid.n[u] || p[v] + 1 >= grid.n[v])
              continue;
            auto at = [&](int du, int dv) {
              std::array<int, 3> q = p;
              q[u] += du;
              q[v] += dv;
              return grid.Cube(q[0], q[1], q[2]);
            };
            const std::size_t c00 = at(0, 0), c11 = at(1, 1), c10 = at(1, 0), c01 = at(0, 1);
            if (grid.keep[c00] == grid.keep[c11] && grid.keep[c10] == grid.keep[c01] &&
                grid.keep[c00] != grid.keep[c10])
            {
              if (grid.keep[c00])
                add(c10, c01);
              else
                add(c00, c11);
            }
          }
    }
    // Vertex configurations: in a 2x2x2 block, two antipodal cubes alone (kept or missing).
    for (int c = 0; c + 1 < grid.n[2]; ++c)
      for (int b = 0; b + 1 < grid.n[1]; ++b)
        for (int a = 0; a + 1 < grid.n[0]; ++a)
        {
          std::array<std::size_t, 8> cube{};
          int                        kept = 0;
          for (int q = 0; q < 8; ++q)
          {
            cube[q] = grid.Cube(a + HexahedronCornerOffsets[q][0], b + HexahedronCornerOffsets[q][1], c + HexahedronCornerOffsets[q][2]);
            kept += grid.keep[cube[q]] ? 1 : 0;
          }
          if (kept != 2 && kept != 6)
            continue;
          const char minority = kept == 2 ? 1 : 0;
          // Antipodal pairs in VTK corner order: 0-6, 1-7, 2-4, 3-5.
          const int antipode[8] = { 6, 7, 4, 5, 2, 3, 0, 1 };
          int       first = -1;
          for (int q = 0; q < 8; ++q)
          {
            if (grid.keep[cube[q]] == minority)
            {
              first = q;
              break;
            }
          }
          if (grid.keep[cube[antipode[first]]] != minority)
            continue;
          if (minority == 0)
          {
            add(cube[first], cube[antipode[first]]);
          }
          else
          {
            std::size_t best = cube[first == 0 ? 1 : 0];
            bool        found = false;
            for (int q = 0; q < 8; ++q)
            {
              if (q == first || q == antipode[first])
                continue;
              if (!found || grid.fraction[cube[q]] > grid.fraction[best])
              {
                best = cube[q];
                found = true;
              }
            }
            grid.keep[best] = 1;
            ++added;
          }
        }
    if (added == before)
      break;
  }
  return added;
}

/** Keeps only the largest face-connected component; returns the cubes dropped. */
std::size_t
KeepLargestComponent(CubeGrid & grid)
{
  std::vector<int> component(grid.keep.size(), -1);
  std::vector<std::size_t> sizes;
  for (int c = 0; c < grid.n[2]; ++c)
    for (int b = 0; b < grid.n[1]; ++b)
      for (int a = 0; a < grid.n[0]; ++a)
      {
        const std::size_t seed = grid.Cube(a, b, c);
        if (!grid.keep[seed] || component[seed] >= 0)
          continue;
        const int id = static_cast<int>(sizes.size());
        std::size_t count = 0;
        std::queue<std::array<int, 3>> queue;
        queue.push({ a, b, c });
        component[seed] = id;
        while (!queue.empty())
        {
          const auto p = queue.front();
          queue.pop();
          ++count;
          const int steps[6][3] = { { 1, 0, 0 }, { -1, 0, 0 }, { 0, 1, 0 }, { 0, -1, 0 }, { 0, 0, 1 }, { 0, 0, -1 } };
          for (const auto & s : steps)
          {
            const int x = p[0] + s[0], y = p[1] + s[1], z = p[2] + s[2];
            if (!grid.Kept(x, y, z))
              continue;
            const std::size_t q = grid.Cube(x, y, z);
            if (component[q] < 0)
            {
              component[q] = id;
              queue.push({ x, y, z });
            }
          }
        }
        sizes.push_back(count);
      }
  if (sizes.size() <= 1)
    return 0;
  const int   largest = static_cast<int>(std::max_element(sizes.begin(), sizes.end()) - sizes.begin());
  std::size_t dropped = 0;
  for (std::size_t q = 0; q < grid.keep.size(); ++q)
  {
    if (grid.keep[q] && component[q] != largest)
    {
      grid.keep[q] = 0;
      ++dropped;
    }
  }
  return dropped;
}

CubeGrid
MakeCubeGrid(const Body & body, double h, std::vector<std::string> * warnings)
{
  const ImageGeometry & geometry = body.Geometry();
  CubeGrid              grid;
  grid.h = h;
  for (int d = 0; d < 3; ++d)
  {
    const double lo = (body.lower[d] - 0.5) * geometry.spacing[d];
    const double hi = (body.upper[d] + 0.5) * geometry.spacing[d];
    const int    cubes = static_cast<int>(std::ceil((hi - lo) / h - 1e-9));
    // Two empty layers around the body's box keep every 2x2x2 block inside the grid.
    grid.n[d] = cubes + 4;
    grid.start[d] = 0.5 * (lo + hi) - 0.5 * grid.n[d] * h;
  }
  const std::size_t cubeCount = static_cast<std::size_t>(grid.n[0]) * grid.n[1] * grid.n[2];
  grid.fraction.assign(cubeCount, 0.0);
  grid.label.assign(cubeCount, 0);
  grid.keep.assign(cubeCount, 0);

  // Overlap of each cube with the voxels along each axis (separable).
  std::array<std::vector<std::vector<std::pair<int, double>>>, 3> overlaps;
  for (int d = 0; d < 3; ++d)
  {
    overlaps[d].resize(grid.n[d]);
    for (int a = 0; a < grid.n[d]; ++a)
    {
      const double lo = grid.start[d] + a * h;
      overlaps[d][a] = Overlaps(lo, lo + h, geometry.spacing[d], geometry.size[d]);
    }
  }
  const double cubeVolume = h * h * h;
  // The fraction is the exact volume of the nearest-voxel mask inside the
  // cube (what supersampling converges to). Cubes are independent: the result
  // does not depend on the thread count.
#pragma omp parallel for schedule(dynamic, 1)
  for (int c = 0; c < grid.n[2]; ++c)
  {
    std::vector<std::pair<int, double>> labelVolumes;
    for (int b = 0; b < grid.n[1]; ++b)
    {
      for (int a = 0; a < grid.n[0]; ++a)
      {
        labelVolumes.clear();
        double inside = 0.0;
        for (const auto & z : overlaps[2][c])
          for (const auto & y : overlaps[1][b])
            for (const auto & x : overlaps[0][a])
            {
              const int value = body.labels->At(x.first, y.first, z.first);
              if (value == 0)
                continue;
              const double volume = x.second * y.second * z.second;
              inside += volume;
              auto it = std::find_if(labelVolumes.begin(), labelVolumes.end(),
                                     [value](const std::pair<int, double> & e) { return e.first == value; });
              if (it == labelVolumes.end())
                labelVolumes.emplace_back(value, volume);
              else
                it->second += volume;
            }
        const std::size_t q = grid.Cube(a, b, c);
        grid.fraction[q] = inside / cubeVolume;
        int    best = 0;
        double bestVolume = -1.0;
        for (const auto & e : labelVolumes)
        {
          if (e.second > bestVolume || (e.second == bestVolume && e.first < best))
          {
            best = e.first;
            bestVolume = e.second;
          }
        }
        grid.label[q] = best;
      }
    }
  }
  // Threshold on the inside fraction: 0.5 loses volume on a convex surface
  // (its cut cubes are mostly less than half inside), so keep the cubes with
  // the largest fractions until their volume matches the mask's, with the
  // threshold held within [0.35, 0.65] so that no mostly-outside cube is kept.
  {
    std::vector<double> sorted;
    for (double f : grid.fraction)
      if (f > 0.0)
        sorted.push_back(f);
    std::sort(sorted.begin(), sorted.end(), std::greater<double>());
    const auto   wanted = static_cast<std::size_t>(std::llround(body.maskVolume / cubeVolume));
    double       threshold = wanted == 0 ? 0.5 : sorted[std::min(wanted, sorted.size()) - 1];
    threshold = std::clamp(threshold, 0.35, 0.65);
    for (std::size_t q = 0; q < grid.keep.size(); ++q)
      grid.keep[q] = grid.fraction[q] >= threshold ? 1 : 0;
  }
  std::size_t kept = 0;
  for (char k : grid.keep)
    kept += k ? 1 : 0;
  if (kept == 0)
  {
    throw Error("MakeGridFromLabels: no grid cube of " + Number(h) +
                " mm is at least half inside the mask (the body is too thin for this element size); use a smaller "
                "element size.");
  }
  const std::size_t added = RemoveNonManifoldContacts(grid);
  const std::size_t dropped = KeepLargestComponent(grid);
  for (std::size_t q = 0; q < grid.keep.size(); ++q)
  {
    // A cube added for manifoldness that lies wholly outside takes its neighbours' label.
    if (grid.keep[q] && grid.label[q] == 0)
      grid.label[q] = 1;
  }
  if (warnings && added > 0)
  {
    warnings->push_back("grid: added " + std::to_string(added) +
                        " cube(s) less than half inside the mask where cubes met only at an edge or a vertex "
                        "(non-manifold contact).");
  }
  if (warnings && dropped > 0)
  {
    warnings->push_back("grid: dropped " + std::to_string(dropped) +
                        " cube(s) not face-connected to the largest part of the body (islands of the mask); "
                        "clean the mask if they matter.");
  }
  return grid;
}

/** Hexahedra (or, for boundary cubes of a mixed grid, Kuhn tetrahedra) from the kept cubes. */
ImageGrid
MakeGridCells(const Body & body, const CubeGrid & grid, bool mixed, std::vector<char> * surfacePoint,
              std::vector<Index> * pointToNode)
{
  // Grid points used by kept cubes, numbered in grid order.
  std::vector<Index> node(grid.PointCount(), -1);
  std::vector<char>  onSurface(grid.PointCount(), 0);
  for (int c = 0; c <= grid.n[2]; ++c)
    for (int b = 0; b <= grid.n[1]; ++b)
      for (int a = 0; a <= grid.n[0]; ++a)
      {
        int kept = 0;
        for (int q = 0; q < 8; ++q)
          kept += grid.Kept(a - HexahedronCornerOffsets[q][0], b - HexahedronCornerOffsets[q][1], c - HexahedronCornerOffsets[q][2]) ? 1 : 0;
        if (kept > 0)
          node[grid.Point(a, b, c)] = 0;
        if (kept > 0 && kept < 8)
          onSurface[grid.Point(a, b, c)] = 1;
      }
  ImageGrid result;
  Model &   model = result.model;
  model.materials.push_back(Parenchyma());
  for (int c = 0; c <= grid.n[2]; ++c)
    for (int b = 0; b <= grid.n[1]; ++b)
      for (int a = 0; a <= grid.n[0]; ++a)
      {
        Index & id = node[grid.Point(a, b, c)];
        if (id < 0)
          continue;
        id = static_cast<Index>(model.nodes.size());
        model.nodes.push_back(body.ToPhysical(grid.PointPosition(a, b, c)));
      }
  // A mirroring direction matrix turns the grid's cubes inside out: mirror the node order back.
  const int hexOrder[8] = { 0, 1, 2, 3, 4, 5, 6, 7 };
  const int hexMirrored[8] = { 4, 5, 6, 7, 0, 1, 2, 3 };
  const int * order = body.flipped ? hexMirrored : hexOrder;
  for (int c = 0; c < grid.n[2]; ++c)
    for (int b = 0; b < grid.n[1]; ++b)
      for (int a = 0; a < grid.n[0]; ++a)
      {
        const std::size_t q = grid.Cube(a, b, c);
        if (!grid.keep[q])
          continue;
        std::array<Index, 8> corners{};
        bool                 touchesSurface = false;
        for (int v = 0; v < 8; ++v)
        {
          const std::size_t p = grid.Point(a + HexahedronCornerOffsets[v][0], b + HexahedronCornerOffsets[v][1], c + HexahedronCornerOffsets[v][2]);
          corners[v] = node[p];
          touchesSurface = touchesSurface || onSurface[p];
        }
        if (mixed && touchesSurface)
        {
          for (const auto & tet : KuhnTetrahedra)
          {
            Cell cell;
            cell.type = CellType::Tetrahedron;
            cell.nodes.fill(0);
            for (int v = 0; v < 4; ++v)
              cell.nodes[v] = corners[tet[v]];
            if (body.flipped)
              std::swap(cell.nodes[1], cell.nodes[2]);
            model.cells.push_back(cell);
            result.cellLabels.push_back(grid.label[q]);
          }
        }
        else
        {
          Cell cell;
          cell.type = CellType::Hexahedron;
          for (int v = 0; v < 8; ++v)
            cell.nodes[v] = corners[order[v]];
          model.cells.push_back(cell);
          result.cellLabels.push_back(grid.label[q]);
        }
      }
  if (surfacePoint)
    *surfacePoint = std::move(onSurface);
  if (pointToNode)
    *pointToNode = std::move(node);
  return result;
}

/** Moves the surface nodes of a mixed grid (all of them in tetrahedra) along
 *  the surface normal to the 0.5 level of the mask. Sequential, so the result
 *  is deterministic; every move keeps the attached tetrahedra valid. */
void
SnapSurfaceNodes(const Body & body, const CubeGrid & grid, const std::vector<char> & onSurface,
                 const std::vector<Index> & pointToNode, Model & model)
{
  const double h = grid.h;
  // Outward normals in the grid frame from the faces between kept and missing cubes.
  std::vector<Vector3> normal(model.nodes.size(), Vector3::Zero());
  for (int c = 0; c < grid.n[2]; ++c)
    for (int b = 0; b < grid.n[1]; ++b)
      for (int a = 0; a < grid.n[0]; ++a)
      {
        if (!grid.Kept(a, b, c))
          continue;
        for (int d = 0; d < 3; ++d)
          for (int side = 0; side < 2; ++side)
          {
            std::array<int, 3> neighbour{ a, b, c };
            neighbour[d] += side ? 1 : -1;
            if (grid.Kept(neighbour[0], neighbour[1], neighbour[2]))
              continue;
            Vector3 outward = Vector3::Zero();
            outward[d] = side ? 1.0 : -1.0;
            // The 4 grid points of this face.
            for (int u = 0; u < 2; ++u)
              for (int v = 0; v < 2; ++v)
              {
                std::array<int, 3> p{ a, b, c };
                p[d] += side;
                p[(d + 1) % 3] += u;
                p[(d + 2) % 3] += v;
                const Index id = pointToNode[grid.Point(p[0], p[1], p[2])];
                normal[id] += outward;
              }
          }
      }
  // Tetrahedra attached to each node.
  std::vector<std::vector<Index>> cellsOfNode(model.nodes.size());
  for (std::size_t e = 0; e < model.cells.size(); ++e)
  {
    const Cell & cell = model.cells[e];
    if (cell.type != CellType::Tetrahedron)
      continue;
    for (int v = 0; v < 4; ++v)
      cellsOfNode[cell.nodes[v]].push_back(static_cast<Index>(e));
  }
  const double minimumVolume = 0.15 * h * h * h / 6.0; // a Kuhn tetrahedron has h^3 / 6
  const double maximumMove = 0.4 * h;
  const double step = 0.25 * body.Geometry().spacing.minCoeff();
  auto acceptable = [&](Index id) {
    for (Index e : cellsOfNode[id])
    {
      const Cell & cell = model.cells[e];
      if (TetrahedronVolume(model.nodes[cell.nodes[0]], model.nodes[cell.nodes[1]], model.nodes[cell.nodes[2]],
                    model.nodes[cell.nodes[3]]) < minimumVolume)
        return false;
    }
    return true;
  };
  for (int c = 0; c <= grid.n[2]; ++c)
    for (int b = 0; b <= grid.n[1]; ++b)
      for (int a = 0; a <= grid.n[0]; ++a)
      {
        const std::size_t p = grid.Point(a, b, c);
        if (!onSurface[p])
          continue;
        const Index id = pointToNode[p];
        if (normal[id].squaredNorm() == 0.0)
          continue;
        const Vector3 n = normal[id].normalized();
        const Vector3 g = grid.PointPosition(a, b, c);
        const double  f0 = body.MaskValue(g) - 0.5;
        if (f0 == 0.0)
          continue;
        // Search outward when inside, inward when outside, for the 0.5 level.
        const double sign = f0 > 0.0 ? 1.0 : -1.0;
        double       previousT = 0.0, previousF = f0, target = std::numeric_limits<double>::quiet_NaN();
        for (double t = step; t <= maximumMove + 1e-12; t += step)
        {
          const double f = body.MaskValue(g + sign * t * n) - 0.5;
          if ((f > 0.0) != (previousF > 0.0) || f == 0.0)
          {
            target = previousT + (t - previousT) * previousF / (previousF - f);
            break;
          }
          previousT = t;
          previousF = f;
        }
        if (!std::isfinite(target))
          continue;
        const Vector3 original = model.nodes[id];
        double        move = target;
        for (int attempt = 0; attempt < 4; ++attempt, move *= 0.5)
        {
          model.nodes[id] = body.ToPhysical(g + sign * move * n);
          if (acceptable(id))
            break;
          model.nodes[id] = original;
        }
      }
}

} // namespace

ImageGrid
MakeHexahedralGrid(const Body & body, double h, bool mixed, std::vector<std::string> * warnings)
{
  const CubeGrid     grid = MakeCubeGrid(body, h, warnings);
  std::vector<char>  onSurface;
  std::vector<Index> pointToNode;
  ImageGrid          result = MakeGridCells(body, grid, mixed, &onSurface, &pointToNode);
  if (mixed)
    SnapSurfaceNodes(body, grid, onSurface, pointToNode, result.model);
  AddStandardNodeSets(result.model);
  return result;
}

} // namespace grids
} // namespace bmr
