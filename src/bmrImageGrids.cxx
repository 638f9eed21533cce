// Grids from a mask or label image: regular hexahedra, CGAL Mesh_3
// tetrahedra, mixed hexahedra + snapped tetrahedra, meshless point clouds.
// CGAL's Mesh_3 is expensive to compile, so all of it stays in this file.
#include "bmrImageGrids.h"

#include "bmrShape.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Image_3.h>
#include <CGAL/ImageIO.h>
#include <CGAL/Labeled_mesh_domain_3.h>
#include <CGAL/Mesh_complex_3_in_triangulation_3.h>
#include <CGAL/Mesh_criteria_3.h>
#include <CGAL/Mesh_triangulation_3.h>
#include <CGAL/Random.h>
#include <CGAL/make_mesh_3.h>

#include <Eigen/Dense>

#include <algorithm>
#include <numeric>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <iomanip>
#include <limits>
#include <map>
#include <queue>
#include <sstream>
#include <unordered_map>
#include <utility>

namespace bmr
{
namespace
{

constexpr double kPi = 3.14159265358979323846;

std::string
Number(double value)
{
  std::ostringstream text;
  text << std::setprecision(4) << value;
  return text.str();
}

/** The body's voxels, their bounding box and the checks common to every grid kind. */
struct Body
{
  const LabelVolume * labels = nullptr;
  std::array<int, 3>  lower{}, upper{}; // inclusive voxel index box of the tissue voxels
  std::size_t         voxels = 0;
  double              maskVolume = 0.0;
  bool                flipped = false; // det(direction) < 0: cells need a mirrored node order

  bool Inside(int i, int j, int k) const { return labels->At(i, j, k) > 0; }
  const ImageGeometry & Geometry() const { return labels->geometry; }
  /** Grid frame: mm along the image axes from voxel 0's centre (= CGAL's frame). */
  Vector3 ToPhysical(const Vector3 & g) const
  {
    const ImageGeometry & geometry = Geometry();
    return geometry.origin + geometry.direction * g;
  }
  /** 1 inside, 0 outside, trilinear between voxel centres (0 beyond the image). */
  double MaskValue(const Vector3 & g) const
  {
    const ImageGeometry & geometry = Geometry();
    const Vector3         index = g.cwiseQuotient(geometry.spacing);
    std::array<int, 3>    base{};
    std::array<double, 3> t{};
    for (int d = 0; d < 3; ++d)
    {
      const double floorIndex = std::floor(index[d]);
      base[d] = static_cast<int>(floorIndex);
      t[d] = index[d] - floorIndex;
    }
    double value = 0.0;
    for (int c = 0; c < 8; ++c)
    {
      const int i = base[0] + HexahedronCornerOffsets[c][0], j = base[1] + HexahedronCornerOffsets[c][1], k = base[2] + HexahedronCornerOffsets[c][2];
      if (i < 0 || j < 0 || k < 0 || i >= geometry.size[0] || j >= geometry.size[1] || k >= geometry.size[2] ||
          !Inside(i, j, k))
      {
        continue;
      }
      value += (HexahedronCornerOffsets[c][0] ? t[0] : 1.0 - t[0]) * (HexahedronCornerOffsets[c][1] ? t[1] : 1.0 - t[1]) *
               (HexahedronCornerOffsets[c][2] ? t[2] : 1.0 - t[2]);
    }
    return value;
  }
  bool NearestVoxelInside(const Vector3 & g) const
  {
    const ImageGeometry & geometry = Geometry();
    std::array<int, 3>    index{};
    for (int d = 0; d < 3; ++d)
    {
      index[d] = static_cast<int>(std::lround(g[d] / geometry.spacing[d]));
      if (index[d] < 0 || index[d] >= geometry.size[d])
      {
        return false;
      }
    }
    return Inside(index[0], index[1], index[2]);
  }
};

Body
CheckInput(const LabelVolume & labels, const ImageGridSettings & settings)
{
  const ImageGeometry & geometry = labels.geometry;
  if (labels.components != 1)
  {
    throw Error("MakeGridFromLabels: the label volume has " + std::to_string(labels.components) +
                " components per voxel; give a scalar mask or label image (1 component, 0 = outside).");
  }
  if (geometry.size[0] <= 0 || geometry.size[1] <= 0 || geometry.size[2] <= 0 ||
      labels.values.size() != geometry.VoxelCount())
  {
    throw Error("MakeGridFromLabels: the label volume is empty or its " + std::to_string(labels.values.size()) +
                " values do not fill its grid of " + geometry.Describe() + "; give a 3D mask or label image.");
  }
  for (int d = 0; d < 3; ++d)
  {
    if (!(geometry.spacing[d] > 0.0) || !std::isfinite(geometry.spacing[d]))
    {
      throw Error("MakeGridFromLabels: the label image has a non-positive voxel spacing (" + geometry.Describe() +
                  "); fix the image header.");
    }
  }
  Body body;
  body.labels = &labels;
  body.lower = { geometry.size[0], geometry.size[1], geometry.size[2] };
  body.upper = { -1, -1, -1 };
  for (int k = 0; k < geometry.size[2]; ++k)
  {
    for (int j = 0; j < geometry.size[1]; ++j)
    {
      for (int i = 0; i < geometry.size[0]; ++i)
      {
        if (labels.values[geometry.Offset(i, j, k)] > 0)
        {
          ++body.voxels;
          const int index[3] = { i, j, k };
          for (int d = 0; d < 3; ++d)
          {
            body.lower[d] = std::min(body.lower[d], index[d]);
            body.upper[d] = std::max(body.upper[d], index[d]);
          }
        }
      }
    }
  }
  if (body.voxels == 0)
  {
    throw Error("MakeGridFromLabels: the mask is empty (every voxel is background 0) on " + geometry.Describe() +
                "; give a mask or label image with tissue labels > 0.");
  }
  body.maskVolume = static_cast<double>(body.voxels) * geometry.VoxelVolume();
  body.flipped = geometry.direction.determinant() < 0.0;

  const double smallestSpacing = geometry.spacing.minCoeff();
  const double h = settings.elementSize;
  if (!std::isfinite(h) || h < smallestSpacing * (1.0 - 1e-9))
  {
    throw Error("MakeGridFromLabels: element size " + Number(h) +
                " mm is smaller than the voxel spacing; the smallest allowed element size is " +
                Number(smallestSpacing) + " mm (the smallest voxel spacing of " + geometry.Describe() + ").");
  }
  Vector3 extent;
  for (int d = 0; d < 3; ++d)
  {
    extent[d] = (body.upper[d] - body.lower[d] + 1) * geometry.spacing[d];
  }
  if (extent.minCoeff() < 2.0 * h)
  {
    throw Error("MakeGridFromLabels: element size " + Number(h) + " mm is too large for the body, whose extent is " +
                Number(extent[0]) + " x " + Number(extent[1]) + " x " + Number(extent[2]) +
                " mm along the image axes: it must be at least 2 elements across. Use an element size of at most " +
                Number(0.5 * extent.minCoeff()) + " mm.");
  }
  return body;
}

Material
Parenchyma()
{
  Material material;
  material.name = "parenchyma";
  material.youngsModulus = 3000.0;
  material.poissonRatio = 0.49;
  material.density = 1000.0;
  return material;
}

void
AddStandardNodeSets(Model & model)
{
  auto & all = model.nodeSets["all"];
  all.resize(model.nodes.size());
  for (std::size_t n = 0; n < all.size(); ++n)
  {
    all[n] = static_cast<Index>(n);
  }
  if (!model.cells.empty())
  {
    model.nodeSets["surface"] = model.BoundaryNodes();
  }
}

// ----------------------------------------------------------------------------
// Regular grid of cubes conforming to the mask

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

// ----------------------------------------------------------------------------
// CGAL Mesh_3 on the labelled image

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using MeshDomain = CGAL::Labeled_mesh_domain_3<Kernel>;
using Triangulation = CGAL::Mesh_triangulation_3<MeshDomain, CGAL::Default, CGAL::Sequential_tag>::type;
using Complex = CGAL::Mesh_complex_3_in_triangulation_3<Triangulation>;
using Criteria = CGAL::Mesh_criteria_3<Triangulation>;

double
DerivedFacetDistance(const ImageGridSettings & settings)
{
  return settings.facetDistance > 0.0 ? settings.facetDistance : settings.elementSize / 8.0;
}

/** Keeps the largest set of tetrahedra connected through shared faces (CGAL
 *  can leave small pieces where the mask narrows below the element size;
 *  loose pieces would be unconstrained bodies) and drops unused nodes. */
void
KeepLargestFaceConnectedTetrahedra(ImageGrid & grid, std::vector<std::string> * warnings)
{
  Model &          model = grid.model;
  const std::size_t cellCount = model.cells.size();
  // Union-find over cells sharing a face; faces found by sorting their node triples.
  std::vector<std::size_t> parent(cellCount);
  std::iota(parent.begin(), parent.end(), std::size_t{ 0 });
  auto root = [&](std::size_t c) {
    while (parent[c] != c)
    {
      parent[c] = parent[parent[c]];
      c = parent[c];
    }
    return c;
  };
  std::vector<std::pair<std::array<Index, 3>, std::size_t>> faces;
  faces.reserve(4 * cellCount);
  for (std::size_t c = 0; c < cellCount; ++c)
  {
    const auto & n = model.cells[c].nodes;
    for (int omitted = 0; omitted < 4; ++omitted)
    {
      std::array<Index, 3> face{};
      for (int v = 0, f = 0; v < 4; ++v)
      {
        if (v != omitted)
        {
          face[f++] = n[v];
        }
      }
      std::sort(face.begin(), face.end());
      faces.emplace_back(face, c);
    }
  }
  std::sort(faces.begin(), faces.end());
  for (std::size_t f = 1; f < faces.size(); ++f)
  {
    if (faces[f].first == faces[f - 1].first)
    {
      parent[root(faces[f].second)] = root(faces[f - 1].second);
    }
  }
  std::map<std::size_t, std::size_t> sizeOfRoot;
  for (std::size_t c = 0; c < cellCount; ++c)
  {
    ++sizeOfRoot[root(c)];
  }
  if (sizeOfRoot.size() <= 1)
  {
    return;
  }
  const auto largest = std::max_element(sizeOfRoot.begin(), sizeOfRoot.end(), [](const auto & a, const auto & b) {
                         return a.second < b.second;
                       })->first;
  Model              kept;
  kept.materials = model.materials;
  std::vector<int>   keptLabels;
  std::vector<Index> newIndex(model.nodes.size(), -1);
  for (std::size_t c = 0; c < cellCount; ++c)
  {
    if (root(c) != largest)
    {
      continue;
    }
    Cell cell = model.cells[c];
    for (int v = 0; v < 4; ++v)
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
    keptLabels.push_back(grid.cellLabels[c]);
  }
  if (warnings)
  {
    warnings->push_back("grid: the tetrahedral mesh has " + std::to_string(sizeOfRoot.size()) +
                        " face-connected parts; kept the largest (" + std::to_string(kept.cells.size()) +
                        " tetrahedra), dropped " + std::to_string(cellCount - kept.cells.size()) +
                        " tetrahedra in the others (where the mask narrows below the element size)");
  }
  model = std::move(kept);
  grid.cellLabels = std::move(keptLabels);
}

ImageGrid
MakeTetrahedralGrid(const Body & body, const ImageGridSettings & settings, std::vector<std::string> * warnings)
{
  const ImageGeometry & geometry = body.Geometry();
  if (!(settings.facetAngle > 0.0 && settings.facetAngle <= 30.0))
  {
    throw Error("MakeGridFromLabels: facet angle " + Number(settings.facetAngle) +
                " degrees is out of range; CGAL guarantees termination for (0, 30] degrees.");
  }
  if (!(settings.cellRadiusEdgeRatio >= 2.0))
  {
    throw Error("MakeGridFromLabels: cell radius-edge ratio " + Number(settings.cellRadiusEdgeRatio) +
                " must be at least 2 (CGAL's refinement does not terminate below).");
  }
  if (!(settings.facetDistance >= 0.0) || !std::isfinite(settings.facetDistance))
  {
    throw Error("MakeGridFromLabels: facet distance " + Number(settings.facetDistance) +
                " mm must be >= 0 (0: elementSize / 8).");
  }
  // CGAL's image descriptor over a copy of the voxels (x fastest, as in ITK).
  _image * image = ::_createImage(static_cast<std::size_t>(geometry.size[0]), static_cast<std::size_t>(geometry.size[1]),
                                  static_cast<std::size_t>(geometry.size[2]), 1, geometry.spacing[0],
                                  geometry.spacing[1], geometry.spacing[2], 1, WK_FIXED, SGN_UNSIGNED);
  if (image == nullptr)
  {
    throw Error("MakeGridFromLabels: could not allocate CGAL's copy of the label image (" + geometry.Describe() + ").");
  }
  std::memcpy(image->data, body.labels->values.data(), body.labels->values.size());
  image->tx = image->ty = image->tz = 0.0f;
  CGAL::Image_3 cgalImage(image); // owns the descriptor from here

  // CGAL draws random numbers (initial points, perturbation): seed them.
  CGAL::get_default_random() = CGAL::Random(static_cast<unsigned int>(settings.seed));
  CGAL::Random domainRandom(static_cast<unsigned int>(settings.seed));
  namespace params = CGAL::parameters;
  MeshDomain domain = MeshDomain::create_labeled_image_mesh_domain(cgalImage, params::p_rng = &domainRandom);
  const double h = settings.elementSize;
  Criteria     criteria(params::facet_angle = settings.facetAngle, params::facet_size = h / std::sqrt(3.0),
                    params::facet_distance = DerivedFacetDistance(settings),
                    params::cell_radius_edge_ratio = settings.cellRadiusEdgeRatio,
                    params::cell_size = h * std::sqrt(6.0) / 4.0);
  Complex complex;
  // No time limits: a time-limited optimisation would depend on the machine's speed.
  if (settings.optimise)
  {
    complex = CGAL::make_mesh_3<Complex>(domain, criteria, params::no_lloyd(), params::no_odt(),
                                         params::perturb(params::time_limit = 0, params::sliver_bound = 10.0),
                                         params::exude(params::time_limit = 0, params::sliver_bound = 15.0));
  }
  else
  {
    complex = CGAL::make_mesh_3<Complex>(domain, criteria, params::no_lloyd(), params::no_odt(),
                                         params::no_perturb(),
                                         params::no_exude());
  }

  ImageGrid result;
  Model &   model = result.model;
  model.materials.push_back(Parenchyma());
  std::map<Triangulation::Vertex_handle, Index> nodeOf;
  for (auto cell = complex.cells_in_complex_begin(); cell != complex.cells_in_complex_end(); ++cell)
  {
    Cell element;
    element.type = CellType::Tetrahedron;
    element.nodes.fill(0);
    for (int v = 0; v < 4; ++v)
    {
      const auto vertex = cell->vertex(v);
      auto       found = nodeOf.find(vertex);
      if (found == nodeOf.end())
      {
        const auto & point = vertex->point().point();
        found = nodeOf.emplace(vertex, static_cast<Index>(model.nodes.size())).first;
        model.nodes.push_back(body.ToPhysical(Vector3(point.x(), point.y(), point.z())));
      }
      element.nodes[v] = found->second;
    }
    if (TetrahedronVolume(model.nodes[element.nodes[0]], model.nodes[element.nodes[1]], model.nodes[element.nodes[2]],
                  model.nodes[element.nodes[3]]) < 0.0)
    {
      std::swap(element.nodes[1], element.nodes[2]);
    }
    model.cells.push_back(element);
    result.cellLabels.push_back(static_cast<int>(complex.subdomain_index(cell)));
  }
  if (model.cells.empty())
  {
    throw Error("MakeGridFromLabels: CGAL's mesh generator produced no tetrahedra for the mask (" +
                geometry.Describe() + ", " + std::to_string(body.voxels) +
                " tissue voxels); use a smaller element size or check the mask.");
  }
  KeepLargestFaceConnectedTetrahedra(result, warnings);
  return result;
}

// ----------------------------------------------------------------------------
// Meshless point cloud

ImageGrid
MakeMeshlessGrid(const Body & body, const ImageGridSettings & settings, std::vector<std::string> * warnings)
{
  const double h = settings.elementSize;
  // The body's surface: the boundary of the tetrahedral mesh of the same size.
  const ImageGrid              tetrahedra = MakeTetrahedralGrid(body, settings, warnings);
  std::vector<Vector3> surfaceNodes;
  for (const Index n : tetrahedra.model.BoundaryNodes())
    surfaceNodes.push_back(tetrahedra.model.nodes[n]);
  // The region is the union of the tetrahedra (point location only), which
  // does not need the surface to be a 2-manifold.
  const BodyRegion region = BodyRegion::FromCells(tetrahedra.model);

  // Interior nodes: the regular grid inside the body, away from the surface
  // nodes (a bucket grid of cell h finds the near ones: one fixed-radius query
  // per grid point, simpler here than a k-d tree).
  const ImageGeometry & geometry = body.Geometry();
  auto bucketOf = [h](const Vector3 & x) {
    return std::array<long, 3>{ static_cast<long>(std::floor(x[0] / h)), static_cast<long>(std::floor(x[1] / h)),
                                static_cast<long>(std::floor(x[2] / h)) };
  };
  struct BucketHash
  {
    std::size_t operator()(const std::array<long, 3> & k) const
    {
      return static_cast<std::size_t>(k[0] * 73856093L ^ k[1] * 19349663L ^ k[2] * 83492791L);
    }
  };
  std::unordered_map<std::array<long, 3>, std::vector<Index>, BucketHash> buckets;
  for (std::size_t n = 0; n < surfaceNodes.size(); ++n)
    buckets[bucketOf(surfaceNodes[n])].push_back(static_cast<Index>(n));
  const double clearance = 0.5 * h;
  auto         nearSurface = [&](const Vector3 & x) {
    const auto key = bucketOf(x);
    for (long dz = -1; dz <= 1; ++dz)
      for (long dy = -1; dy <= 1; ++dy)
        for (long dx = -1; dx <= 1; ++dx)
        {
          auto it = buckets.find({ key[0] + dx, key[1] + dy, key[2] + dz });
          if (it == buckets.end())
            continue;
          for (Index n : it->second)
            if ((surfaceNodes[n] - x).squaredNorm() < clearance * clearance)
              return true;
        }
    return false;
  };
  ImageGrid result;
  Model &   model = result.model;
  model.materials.push_back(Parenchyma());
  model.nodes = surfaceNodes;
  std::array<int, 3> count{};
  Vector3            start;
  for (int d = 0; d < 3; ++d)
  {
    const double lo = (body.lower[d] - 0.5) * geometry.spacing[d];
    const double hi = (body.upper[d] + 0.5) * geometry.spacing[d];
    count[d] = static_cast<int>(std::ceil((hi - lo) / h));
    start[d] = 0.5 * (lo + hi) - 0.5 * (count[d] - 1) * h;
  }
  for (int c = 0; c < count[2]; ++c)
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a)
      {
        const Vector3 g = start + h * Vector3(a, b, c);
        if (!body.NearestVoxelInside(g))
          continue;
        const Vector3 x = body.ToPhysical(g);
        if (!region.Contains(x) || nearSurface(x))
          continue;
        model.nodes.push_back(x);
      }
  AddStandardNodeSets(model);
  auto & surface = model.nodeSets["surface"];
  surface.resize(surfaceNodes.size());
  for (std::size_t n = 0; n < surfaceNodes.size(); ++n)
    surface[n] = static_cast<Index>(n);

  const MlsSettings & mlsSettings = settings.meshlessShapeFunctions;
  try
  {
    const MovingLeastSquares mls(model.nodes, mlsSettings);
    IntegrationPoints        points = MakeIntegrationPoints(region, mls, settings.meshlessIntegration, settings.threads);
    if (points.positions.empty())
    {
      throw Error("no integration point lies inside the body");
    }
    // The supports the solver will use: widened where the points are sparser than the nodes.
    const MovingLeastSquares covered(model.nodes, mlsSettings, points.positions);
    const ShapeFunctionTable table = covered.Evaluate(points.positions, false, settings.threads, "integration point");
    double minimum = std::numeric_limits<double>::max(), sum = 0.0;
    for (Index p = 0; p < table.PointCount(); ++p)
    {
      const double neighbours = table.offsets[p + 1] - table.offsets[p];
      minimum = std::min(minimum, neighbours);
      sum += neighbours;
    }
    result.quality.minNeighboursPerPoint = minimum;
    result.quality.meanNeighboursPerPoint = sum / table.PointCount();
    double spacing = 0.0;
    for (Index n = 0; n < mls.NodeCount(); ++n)
      spacing += mls.NodalSpacing(n);
    result.quality.meanEdgeLength = spacing / mls.NodeCount();
    model.meshless.shapeFunctions = mlsSettings;
    model.meshless.integrationPoints = std::move(points.positions);
    model.meshless.integrationWeights = std::move(points.weights);
    model.meshless.integrationMaterials = std::move(points.materials);
    model.discretization = Discretization::Meshless;
  }
  catch (const Error & error)
  {
    throw Error(std::string("MakeGridFromLabels: the meshless point cloud of spacing ") + Number(h) +
                " mm does not cover the body: " + error.what() +
                " Increase meshlessShapeFunctions.dilatation (now " + Number(mlsSettings.dilatation) +
                ") or use a smaller element size.");
  }
  // The tetrahedra stay with the grid as the body's description (surfaces, rasterisation).
  result.meshlessBody = tetrahedra.model;
  return result;
}

// ----------------------------------------------------------------------------
// Quality

/** Smallest corner Jacobian with unit edge vectors (1 for a cube). */
double
HexScaledJacobian(const Model & model, const Cell & cell)
{
  static const int neighbours[8][3] = { { 1, 3, 4 }, { 2, 0, 5 }, { 3, 1, 6 }, { 0, 2, 7 },
                                        { 7, 5, 0 }, { 4, 6, 1 }, { 5, 7, 2 }, { 6, 4, 3 } };
  double minimum = std::numeric_limits<double>::max();
  for (int c = 0; c < 8; ++c)
  {
    const Vector3 & p = model.nodes[cell.nodes[c]];
    const Vector3   a = (model.nodes[cell.nodes[neighbours[c][0]]] - p).normalized();
    const Vector3   b = (model.nodes[cell.nodes[neighbours[c][1]]] - p).normalized();
    const Vector3   d = (model.nodes[cell.nodes[neighbours[c][2]]] - p).normalized();
    minimum = std::min(minimum, a.cross(b).dot(d));
  }
  return minimum;
}

} // namespace

const char *
ImageGridKindName(ImageGridKind kind)
{
  switch (kind)
  {
    case ImageGridKind::Hexahedra:
      return "hexahedra";
    case ImageGridKind::Tetrahedra:
      return "tetrahedra";
    case ImageGridKind::Mixed:
      return "mixed";
    case ImageGridKind::Meshless:
      return "meshless";
  }
  return "unknown";
}

ImageGridKind
ParseImageGridKind(const std::string & name)
{
  if (name == "hexahedra" || name == "hex" || name == "hexahedron")
    return ImageGridKind::Hexahedra;
  if (name == "tetrahedra" || name == "tet" || name == "tetrahedron")
    return ImageGridKind::Tetrahedra;
  if (name == "mixed")
    return ImageGridKind::Mixed;
  if (name == "meshless")
    return ImageGridKind::Meshless;
  throw Error("unknown grid kind '" + name + "': use hexahedra, tetrahedra, mixed or meshless.");
}

GridQuality
MeasureGridQuality(const Model & model)
{
  GridQuality quality;
  quality.nodes = model.nodes.size();
  quality.cells = model.cells.size();
  double      jacobianSum = 0.0, edgeSum = 0.0;
  std::size_t edgeCount = 0;
  quality.minScaledJacobian = model.cells.empty() ? 0.0 : std::numeric_limits<double>::max();
  double minDihedral = std::numeric_limits<double>::max(), maxDihedral = 0.0;
  static const int tetEdges[6][2] = { { 0, 1 }, { 0, 2 }, { 0, 3 }, { 1, 2 }, { 1, 3 }, { 2, 3 } };
  static const int hexEdges[12][2] = { { 0, 1 }, { 1, 2 }, { 2, 3 }, { 3, 0 }, { 4, 5 }, { 5, 6 },
                                       { 6, 7 }, { 7, 4 }, { 0, 4 }, { 1, 5 }, { 2, 6 }, { 3, 7 } };
  for (std::size_t e = 0; e < model.cells.size(); ++e)
  {
    const Cell & cell = model.cells[e];
    quality.meshVolume += CellVolume(model, static_cast<Index>(e));
    double shortest = std::numeric_limits<double>::max(), longest = 0.0;
    auto   edge = [&](int a, int b) {
      const double length = (model.nodes[cell.nodes[a]] - model.nodes[cell.nodes[b]]).norm();
      shortest = std::min(shortest, length);
      longest = std::max(longest, length);
      edgeSum += length;
      ++edgeCount;
    };
    double scaled = 0.0;
    if (cell.type == CellType::Hexahedron)
    {
      ++quality.hexahedra;
      for (const auto & ed : hexEdges)
        edge(ed[0], ed[1]);
      scaled = HexScaledJacobian(model, cell);
    }
    else
    {
      ++quality.tetrahedra;
      for (const auto & ed : tetEdges)
        edge(ed[0], ed[1]);
      const Vector3 * x[4] = { &model.nodes[cell.nodes[0]], &model.nodes[cell.nodes[1]], &model.nodes[cell.nodes[2]],
                               &model.nodes[cell.nodes[3]] };
      const double six = 6.0 * TetrahedronVolume(*x[0], *x[1], *x[2], *x[3]);
      scaled = std::numeric_limits<double>::max();
      for (int c = 0; c < 4; ++c)
      {
        double lengths = std::sqrt(2.0);
        for (int o = 1; o < 4; ++o)
          lengths /= (*x[(c + o) % 4] - *x[c]).norm();
        scaled = std::min(scaled, six * lengths);
      }
      // Dihedral angles from the outward face normals: angle = pi - angle(n_k, n_l).
      Vector3 normals[4];
      for (int k = 0; k < 4; ++k)
      {
        const Vector3 & a = *x[(k + 1) % 4];
        const Vector3 & b = *x[(k + 2) % 4];
        const Vector3 & c = *x[(k + 3) % 4];
        Vector3         n = (b - a).cross(c - a);
        if (n.dot(*x[k] - a) > 0.0)
          n = -n;
        normals[k] = n.normalized();
      }
      for (int k = 0; k < 4; ++k)
        for (int l = k + 1; l < 4; ++l)
        {
          const double angle = 180.0 - std::acos(std::clamp(normals[k].dot(normals[l]), -1.0, 1.0)) * 180.0 / kPi;
          minDihedral = std::min(minDihedral, angle);
          maxDihedral = std::max(maxDihedral, angle);
        }
    }
    quality.minScaledJacobian = std::min(quality.minScaledJacobian, scaled);
    jacobianSum += scaled;
    quality.maxAspectRatio = std::max(quality.maxAspectRatio, longest / shortest);
  }
  if (!model.cells.empty())
  {
    quality.meanScaledJacobian = jacobianSum / model.cells.size();
    quality.meanEdgeLength = edgeSum / edgeCount;
  }
  if (quality.tetrahedra > 0)
  {
    quality.minDihedralAngleDeg = minDihedral;
    quality.maxDihedralAngleDeg = maxDihedral;
  }
  return quality;
}

/** The largest face-connected (6-connected) part of the tissue voxels: specks
 *  of a skull-stripped mask would otherwise become loose, unloaded pieces of
 *  the model. Labels inside the part are kept. */
LabelVolume
LargestConnectedTissue(const LabelVolume & labels, std::vector<std::string> & warnings)
{
  const ImageGeometry & geometry = labels.geometry;
  const std::size_t     voxels = geometry.VoxelCount();
  if (labels.components != 1 || labels.values.size() != voxels)
  {
    return labels; // CheckInput names the problem
  }
  std::vector<std::int32_t> component(voxels, -1);
  std::vector<std::size_t>  sizes;
  std::vector<std::size_t>  stack;
  const std::size_t         strideY = static_cast<std::size_t>(geometry.size[0]);
  const std::size_t         strideZ = strideY * static_cast<std::size_t>(geometry.size[1]);
  for (std::size_t seed = 0; seed < voxels; ++seed)
  {
    if (labels.values[seed] == 0 || component[seed] >= 0)
    {
      continue;
    }
    const auto  id = static_cast<std::int32_t>(sizes.size());
    std::size_t size = 0;
    component[seed] = id;
    stack.push_back(seed);
    while (!stack.empty())
    {
      const std::size_t voxel = stack.back();
      stack.pop_back();
      ++size;
      const int i = static_cast<int>(voxel % strideY);
      const int j = static_cast<int>((voxel / strideY) % geometry.size[1]);
      const int k = static_cast<int>(voxel / strideZ);
      const std::pair<bool, std::size_t> neighbours[6] = {
        { i > 0, voxel - 1 },       { i + 1 < geometry.size[0], voxel + 1 },
        { j > 0, voxel - strideY }, { j + 1 < geometry.size[1], voxel + strideY },
        { k > 0, voxel - strideZ }, { k + 1 < geometry.size[2], voxel + strideZ }
      };
      for (const auto & [exists, neighbour] : neighbours)
      {
        if (exists && labels.values[neighbour] != 0 && component[neighbour] < 0)
        {
          component[neighbour] = id;
          stack.push_back(neighbour);
        }
      }
    }
    sizes.push_back(size);
  }
  if (sizes.size() <= 1)
  {
    return labels;
  }
  const auto  largest = static_cast<std::int32_t>(std::max_element(sizes.begin(), sizes.end()) - sizes.begin());
  LabelVolume kept = labels;
  for (std::size_t voxel = 0; voxel < voxels; ++voxel)
  {
    if (component[voxel] != largest)
    {
      kept.values[voxel] = 0;
    }
  }
  warnings.push_back("grid: the mask has " + std::to_string(sizes.size()) + " separate parts; kept the largest (" +
                     std::to_string(sizes[largest]) + " voxels), dropped " +
                     std::to_string(std::accumulate(sizes.begin(), sizes.end(), std::size_t{ 0 }) - sizes[largest]) +
                     " voxels in the others (they would be loose pieces of the model)");
  return kept;
}

ImageGrid
MakeGridFromLabels(const LabelVolume & inputLabels, const ImageGridSettings & settings, std::vector<std::string> * warnings)
{
  const auto  started = std::chrono::steady_clock::now();
  std::vector<std::string> localWarnings;
  const LabelVolume labels = LargestConnectedTissue(inputLabels, localWarnings);
  const Body  body = CheckInput(labels, settings);
  ImageGrid   result;
  switch (settings.kind)
  {
    case ImageGridKind::Hexahedra:
    case ImageGridKind::Mixed:
    {
      const bool         mixed = settings.kind == ImageGridKind::Mixed;
      const CubeGrid     grid = MakeCubeGrid(body, settings.elementSize, &localWarnings);
      std::vector<char>  onSurface;
      std::vector<Index> pointToNode;
      result = MakeGridCells(body, grid, mixed, &onSurface, &pointToNode);
      if (mixed)
        SnapSurfaceNodes(body, grid, onSurface, pointToNode, result.model);
      AddStandardNodeSets(result.model);
      break;
    }
    case ImageGridKind::Tetrahedra:
      result = MakeTetrahedralGrid(body, settings, &localWarnings);
      AddStandardNodeSets(result.model);
      break;
    case ImageGridKind::Meshless:
      result = MakeMeshlessGrid(body, settings, &localWarnings);
      break;
  }
  result.model.Validate();

  if (settings.kind == ImageGridKind::Meshless)
  {
    GridQuality & quality = result.quality;
    quality.nodes = result.model.nodes.size();
    quality.integrationPoints = result.model.meshless.integrationPoints.size();
    quality.meshVolume = 0.0;
    for (double w : result.model.meshless.integrationWeights)
      quality.meshVolume += w;
  }
  else
  {
    result.quality = MeasureGridQuality(result.model);
  }
  result.quality.maskVolume = body.maskVolume;
  result.quality.volumeError = (result.quality.meshVolume - body.maskVolume) / body.maskVolume;
  result.quality.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  if (warnings)
    warnings->insert(warnings->end(), localWarnings.begin(), localWarnings.end());
  return result;
}

std::string
FormatGridQuality(const GridQuality & q)
{
  std::ostringstream text;
  text << std::setprecision(4);
  text << "grid: " << q.nodes << " nodes (" << 3 * q.nodes << " DOF), " << q.cells << " cells (" << q.hexahedra
       << " hexahedra, " << q.tetrahedra << " tetrahedra)";
  if (q.integrationPoints > 0)
    text << ", " << q.integrationPoints << " integration points";
  text << ", " << q.seconds << " s\n";
  text << "volume: mesh " << q.meshVolume / 1000.0 << " mL, mask " << q.maskVolume / 1000.0 << " mL, error "
       << 100.0 * q.volumeError << " %\n";
  if (q.cells > 0)
  {
    text << "quality: scaled Jacobian min " << q.minScaledJacobian << " mean " << q.meanScaledJacobian
         << ", max aspect ratio " << q.maxAspectRatio << ", mean edge " << q.meanEdgeLength << " mm";
    if (q.tetrahedra > 0)
      text << ", dihedral angles " << q.minDihedralAngleDeg << " .. " << q.maxDihedralAngleDeg << " deg";
    text << "\n";
  }
  if (q.integrationPoints > 0)
  {
    text << "meshless: MLS neighbours per integration point min " << q.minNeighboursPerPoint << " mean "
         << q.meanNeighboursPerPoint << ", mean nodal spacing " << q.meanEdgeLength << " mm\n";
  }
  return text.str();
}

LabelVolume
RasterizeCells(const Model & model, const ImageGeometry & grid)
{
  if (model.cells.empty())
  {
    throw Error("RasterizeCells: the model has no cells (a meshless model's body is its mask)");
  }
  LabelVolume volume;
  volume.geometry = grid;
  volume.values.assign(grid.VoxelCount(), 0);
  const auto cellCount = static_cast<std::int64_t>(model.cells.size());
#pragma omp parallel for schedule(dynamic, 64)
  for (std::int64_t cellId = 0; cellId < cellCount; ++cellId)
  {
    const Cell & cell = model.cells[cellId];
    const int    tetCount = cell.type == CellType::Hexahedron ? 6 : 1;
    for (int t = 0; t < tetCount; ++t)
    {
      // Vertices in continuous index space, where voxel centres are integers.
      Eigen::Matrix<double, 3, 4> corners;
      for (int q = 0; q < 4; ++q)
      {
        const Index node = cell.type == CellType::Hexahedron ? cell.nodes[KuhnTetrahedra[t][q]] : cell.nodes[q];
        corners.col(q) = grid.PointToIndex(model.nodes[node]);
      }
      Eigen::Matrix3d edges;
      edges << corners.col(1) - corners.col(0), corners.col(2) - corners.col(0), corners.col(3) - corners.col(0);
      const Eigen::Matrix3d toBarycentric = edges.inverse();
      const Vector3         lower = corners.rowwise().minCoeff();
      const Vector3         upper = corners.rowwise().maxCoeff();
      // Voxel centres on a cell's face (7 mm cells on 1 mm voxels put many
      // there) must count whatever the image's placement: an image file's
      // geometry in single precision (NIfTI) moves the nodes by 1e-5 voxel
      // 1 m from the origin, and a 1e-9 tolerance let that decide (a
      // registration 0.65 mm different, docs/model-building.md).
      constexpr double      kOnFace = 1e-3; // voxels, in the bounds; barycentric, in the test
      int                   first[3], last[3];
      for (int d = 0; d < 3; ++d)
      {
        first[d] = std::max(0, static_cast<int>(std::ceil(lower[d] - kOnFace)));
        last[d] = std::min(grid.size[d] - 1, static_cast<int>(std::floor(upper[d] + kOnFace)));
      }
      for (int k = first[2]; k <= last[2]; ++k)
      {
        for (int j = first[1]; j <= last[1]; ++j)
        {
          for (int i = first[0]; i <= last[0]; ++i)
          {
            const Vector3 local = toBarycentric * (Vector3(i, j, k) - corners.col(0));
            // Inclusive: a voxel centre on a face shared by two cells counts for the body.
            if (local.minCoeff() >= -kOnFace && local.sum() <= 1.0 + kOnFace)
            {
              std::uint8_t & value = volume.values[grid.Offset(i, j, k)];
#pragma omp atomic write
              value = 1;
            }
          }
        }
      }
    }
  }
  return volume;
}

} // namespace bmr
