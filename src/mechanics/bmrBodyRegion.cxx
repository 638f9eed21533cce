// The body region of a meshless (MTLED) discretization, where its integration
// points may lie (bmrMeshlessIntegration.cxx): the union of a model's cells
// (bucket grid over the cells' boxes, barycentric inside test) or the inside
// of a closed triangulated surface (CGAL ray parity).
#include "bmrMeshless.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Side_of_triangle_mesh.h>
#include <CGAL/Surface_mesh.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <sstream>

namespace bmr
{

namespace
{
// Barycentric slack of the inside test: points on a shared face or on the
// boundary are found despite rounding (dimensionless, relative to the cell).
constexpr double kBarycentricTolerance = 1e-10;
// A tetrahedron with |6 V| below this fraction of its longest edge cubed is
// degenerate and contains nothing.
constexpr double kDegenerateTetrahedron = 1e-14;

/** Kuhn split of a hexahedron (VTK corner numbering) around its diagonal 0-6:
 *  every face is split along the diagonal through its lowest corner, the same
 *  split MakeBlockMesh uses for tetrahedra, so neighbouring cells agree. */
constexpr int kHexahedronTetrahedra[6][4] = { { 0, 1, 2, 6 }, { 0, 1, 5, 6 }, { 0, 3, 2, 6 },
                                              { 0, 3, 7, 6 }, { 0, 4, 5, 6 }, { 0, 4, 7, 6 } };

/** Affine map from a point to the last three barycentric coordinates. */
struct TetrahedronMap
{
  Vector3         origin;
  Eigen::Matrix3d inverse;
};

// ---------------------------------------------------------------------------
// Point location in the union of cells: uniform bucket grid over cell boxes.
// ---------------------------------------------------------------------------
class CellLocator
{
public:
  explicit CellLocator(const Model & model)
  {
    const Index cellCount = static_cast<Index>(model.cells.size());
    const Index nodeCount = static_cast<Index>(model.nodes.size());
    m_Materials.resize(cellCount);
    m_CellBoxes.resize(cellCount);
    m_TetrahedronBegin.assign(cellCount + 1, 0);
    double meanExtent = 0.0;
    for (Index c = 0; c < cellCount; ++c)
    {
      const Cell & cell = model.cells[c];
      if (cell.type != CellType::Hexahedron && cell.type != CellType::Tetrahedron)
      {
        std::ostringstream message;
        message << "BodyRegion::FromCells: cell " << c
                << " has an unknown cell type; supported: hexahedron, tetrahedron.";
        throw Error(message.str());
      }
      Eigen::AlignedBox3d box;
      for (int k = 0; k < NodesPerCell(cell.type); ++k)
      {
        const Index node = cell.nodes[k];
        if (node < 0 || node >= nodeCount)
        {
          std::ostringstream message;
          message << "BodyRegion::FromCells: cell " << c << " refers to node " << node << " but the model has "
                  << nodeCount << " nodes. Fix the cell's node ids.";
          throw Error(message.str());
        }
        box.extend(model.nodes[node]);
      }
      m_Bounds.extend(box);
      const double extent = box.sizes().maxCoeff();
      meanExtent += extent;
      // Expanded so that the box test never rejects what the barycentric test accepts.
      const Vector3 slack = Vector3::Constant(1e-9 * extent);
      m_CellBoxes[c] = Eigen::AlignedBox3d(box.min() - slack, box.max() + slack);
      m_Materials[c] = cell.material;

      auto addTetrahedron = [&](Index a, Index b, Index d, Index e) {
        const Vector3 & x0 = model.nodes[a];
        Eigen::Matrix3d edges;
        edges.col(0) = model.nodes[b] - x0;
        edges.col(1) = model.nodes[d] - x0;
        edges.col(2) = model.nodes[e] - x0;
        const double longest = std::max({ edges.col(0).norm(), edges.col(1).norm(), edges.col(2).norm(),
                                          (edges.col(1) - edges.col(0)).norm(), (edges.col(2) - edges.col(0)).norm(),
                                          (edges.col(2) - edges.col(1)).norm() });
        const double determinant = edges.determinant();
        if (!(std::abs(determinant) > kDegenerateTetrahedron * longest * longest * longest))
        {
          return; // flat: no volume to contain anything
        }
        m_Tetrahedra.push_back({ x0, edges.inverse() });
      };
      if (cell.type == CellType::Tetrahedron)
      {
        addTetrahedron(cell.nodes[0], cell.nodes[1], cell.nodes[2], cell.nodes[3]);
      }
      else
      {
        for (const auto & t : kHexahedronTetrahedra)
        {
          addTetrahedron(cell.nodes[t[0]], cell.nodes[t[1]], cell.nodes[t[2]], cell.nodes[t[3]]);
        }
      }
      m_TetrahedronBegin[c + 1] = static_cast<Index>(m_Tetrahedra.size());
    }
    meanExtent /= std::max<Index>(cellCount, 1);
    BuildBuckets(meanExtent);
  }

  const Eigen::AlignedBox3d & Bounds() const { return m_Bounds; }

  /** Smallest index of a cell containing x, -1 if none. Buckets list cells in
   *  ascending order, so the first hit is the smallest. */
  Index FindCell(const Vector3 & x) const
  {
    if (!m_SearchBox.contains(x))
    {
      return -1;
    }
    const Index bucket = BucketOf(x);
    for (Index e = m_BucketBegin[bucket]; e < m_BucketBegin[bucket + 1]; ++e)
    {
      const Index c = m_BucketCells[e];
      if (!m_CellBoxes[c].contains(x))
      {
        continue;
      }
      for (Index t = m_TetrahedronBegin[c]; t < m_TetrahedronBegin[c + 1]; ++t)
      {
        const Vector3 lambda = m_Tetrahedra[t].inverse * (x - m_Tetrahedra[t].origin);
        if (lambda.minCoeff() >= -kBarycentricTolerance && lambda.sum() <= 1.0 + kBarycentricTolerance)
        {
          return c;
        }
      }
    }
    return -1;
  }

  Index Material(Index cell) const { return m_Materials[cell]; }

private:
  void BuildBuckets(double meanExtent)
  {
    const Index cellCount = static_cast<Index>(m_CellBoxes.size());
    const Vector3 slack = Vector3::Constant(1e-9 * m_Bounds.sizes().maxCoeff());
    m_SearchBox = Eigen::AlignedBox3d(m_Bounds.min() - slack, m_Bounds.max() + slack);
    // Buckets about as large as a cell: a cell overlaps ~8 buckets and a bucket
    // holds ~8 cells. Capped so a few huge cells cannot blow up memory.
    const Vector3 extent = m_SearchBox.sizes();
    double        size = std::max(meanExtent, 1e-12 * extent.maxCoeff());
    if (!(size > 0.0))
    {
      size = 1.0;
    }
    auto dimensions = [&](double s) {
      std::array<double, 3> d{};
      for (int a = 0; a < 3; ++a)
      {
        d[a] = std::max(1.0, std::ceil(extent[a] / s));
      }
      return d;
    };
    const double maxBuckets = 8.0 * std::max<Index>(cellCount, 1) + 64.0;
    auto         d = dimensions(size);
    while (d[0] * d[1] * d[2] > maxBuckets)
    {
      size *= 1.25;
      d = dimensions(size);
    }
    for (int a = 0; a < 3; ++a)
    {
      m_Dimensions[a] = static_cast<Index>(d[a]);
      m_InverseBucketSize[a] = m_Dimensions[a] / std::max(extent[a], std::numeric_limits<double>::min());
    }
    const Index bucketCount = m_Dimensions[0] * m_Dimensions[1] * m_Dimensions[2];

    // Two passes (count, fill) in cell order keep each bucket's list ascending.
    m_BucketBegin.assign(bucketCount + 1, 0);
    auto forEachBucket = [&](Index c, auto && visit) {
      const std::array<Index, 3> lo = Coordinates(m_CellBoxes[c].min());
      const std::array<Index, 3> hi = Coordinates(m_CellBoxes[c].max());
      for (Index k = lo[2]; k <= hi[2]; ++k)
        for (Index j = lo[1]; j <= hi[1]; ++j)
          for (Index i = lo[0]; i <= hi[0]; ++i)
            visit(i + m_Dimensions[0] * (j + m_Dimensions[1] * k));
    };
    for (Index c = 0; c < cellCount; ++c)
    {
      forEachBucket(c, [&](Index b) { ++m_BucketBegin[b + 1]; });
    }
    for (Index b = 0; b < bucketCount; ++b)
    {
      m_BucketBegin[b + 1] += m_BucketBegin[b];
    }
    m_BucketCells.resize(m_BucketBegin[bucketCount]);
    std::vector<Index> fill(m_BucketBegin.begin(), m_BucketBegin.end() - 1);
    for (Index c = 0; c < cellCount; ++c)
    {
      forEachBucket(c, [&](Index b) { m_BucketCells[fill[b]++] = c; });
    }
  }

  std::array<Index, 3> Coordinates(const Vector3 & x) const
  {
    std::array<Index, 3> ijk{};
    for (int a = 0; a < 3; ++a)
    {
      const double u = std::floor((x[a] - m_SearchBox.min()[a]) * m_InverseBucketSize[a]);
      ijk[a] = static_cast<Index>(std::clamp(u, 0.0, static_cast<double>(m_Dimensions[a] - 1)));
    }
    return ijk;
  }

  Index BucketOf(const Vector3 & x) const
  {
    const std::array<Index, 3> ijk = Coordinates(x);
    return ijk[0] + m_Dimensions[0] * (ijk[1] + m_Dimensions[1] * ijk[2]);
  }

  std::vector<Index>               m_Materials;
  std::vector<Eigen::AlignedBox3d> m_CellBoxes;
  std::vector<Index>               m_TetrahedronBegin;
  std::vector<TetrahedronMap>      m_Tetrahedra;
  Eigen::AlignedBox3d              m_Bounds;
  Eigen::AlignedBox3d              m_SearchBox;
  std::array<Index, 3>             m_Dimensions{ 1, 1, 1 };
  Vector3                          m_InverseBucketSize = Vector3::Ones();
  std::vector<Index>               m_BucketBegin;
  std::vector<Index>               m_BucketCells;
};

// ---------------------------------------------------------------------------
// Inside of a closed triangulated surface: CGAL ray parity with exact predicates.
// ---------------------------------------------------------------------------
using SurfaceKernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using SurfaceMesh = CGAL::Surface_mesh<SurfaceKernel::Point_3>;
using SideOfSurface = CGAL::Side_of_triangle_mesh<SurfaceMesh, SurfaceKernel>;

class SurfaceLocator
{
public:
  SurfaceLocator(const std::vector<Vector3> & vertices, const std::vector<std::array<Index, 3>> & triangles)
  {
    if (triangles.empty())
    {
      throw Error("BodyRegion::FromSurface: the surface has no triangles. Give a closed triangulated surface.");
    }
    const Index vertexCount = static_cast<Index>(vertices.size());
    std::map<std::pair<Index, Index>, int> edgeUse;
    std::map<std::pair<Index, Index>, int> directedUse;
    for (std::size_t t = 0; t < triangles.size(); ++t)
    {
      const auto & c = triangles[t];
      for (int k = 0; k < 3; ++k)
      {
        if (c[k] < 0 || c[k] >= vertexCount)
        {
          std::ostringstream message;
          message << "BodyRegion::FromSurface: triangle " << t << " refers to vertex " << c[k]
                  << " but the surface has " << vertexCount << " vertices. Fix the triangle's vertex ids.";
          throw Error(message.str());
        }
        if (!vertices[c[k]].allFinite())
        {
          std::ostringstream message;
          message << "BodyRegion::FromSurface: vertex " << c[k] << " has a non-finite coordinate.";
          throw Error(message.str());
        }
      }
      if (c[0] == c[1] || c[1] == c[2] || c[2] == c[0])
      {
        std::ostringstream message;
        message << "BodyRegion::FromSurface: triangle " << t << " repeats a vertex (" << c[0] << ", " << c[1] << ", "
                << c[2] << "). Remove degenerate triangles.";
        throw Error(message.str());
      }
      for (int k = 0; k < 3; ++k)
      {
        ++edgeUse[std::minmax(c[k], c[(k + 1) % 3])];
        ++directedUse[{ c[k], c[(k + 1) % 3] }];
        m_Bounds.extend(vertices[c[k]]);
      }
    }
    std::size_t boundaryEdges = 0;
    for (const auto & [edge, count] : edgeUse)
    {
      if (count == 1)
      {
        ++boundaryEdges;
      }
      else if (count > 2)
      {
        std::ostringstream message;
        message << "BodyRegion::FromSurface: edge (" << edge.first << ", " << edge.second << ") is shared by " << count
                << " triangles; the surface must be a closed 2-manifold. Repair the surface.";
        throw Error(message.str());
      }
    }
    if (boundaryEdges > 0)
    {
      const auto first = std::find_if(edgeUse.begin(), edgeUse.end(), [](const auto & e) { return e.second == 1; });
      std::ostringstream message;
      message << "BodyRegion::FromSurface: the surface is not closed: " << boundaryEdges
              << " boundary edges (used by one triangle only), e.g. (" << first->first.first << ", "
              << first->first.second << "). Close its holes so that it bounds a volume.";
      throw Error(message.str());
    }
    for (const auto & [edge, count] : directedUse)
    {
      if (count != 1)
      {
        std::ostringstream message;
        message << "BodyRegion::FromSurface: the triangles are not consistently oriented (edge " << edge.first << " -> "
                << edge.second << " is used twice in the same direction). Orient all triangles the same way.";
        throw Error(message.str());
      }
    }

    m_Mesh = std::make_unique<SurfaceMesh>();
    std::vector<SurfaceMesh::Vertex_index> handles(vertices.size());
    for (std::size_t v = 0; v < vertices.size(); ++v)
    {
      handles[v] = m_Mesh->add_vertex(SurfaceKernel::Point_3(vertices[v].x(), vertices[v].y(), vertices[v].z()));
    }
    for (std::size_t t = 0; t < triangles.size(); ++t)
    {
      const auto & c = triangles[t];
      if (m_Mesh->add_face(handles[c[0]], handles[c[1]], handles[c[2]]) == SurfaceMesh::null_face())
      {
        std::ostringstream message;
        message << "BodyRegion::FromSurface: triangle " << t
                << " makes the surface non-manifold (e.g. two sheets meet at a vertex). Repair the surface.";
        throw Error(message.str());
      }
    }
    m_Side = std::make_unique<SideOfSurface>(*m_Mesh);
    // The AABB tree is built lazily on the first query: build it now so that
    // later (concurrent) queries only read.
    (*m_Side)(SurfaceKernel::Point_3(vertices[triangles[0][0]].x(), vertices[triangles[0][0]].y(),
                                     vertices[triangles[0][0]].z()));
  }

  const Eigen::AlignedBox3d & Bounds() const { return m_Bounds; }

  bool Contains(const Vector3 & x) const
  {
    if (!m_Bounds.contains(x))
    {
      return false;
    }
    return (*m_Side)(SurfaceKernel::Point_3(x.x(), x.y(), x.z())) != CGAL::ON_UNBOUNDED_SIDE;
  }

private:
  std::unique_ptr<SurfaceMesh>   m_Mesh;
  std::unique_ptr<SideOfSurface> m_Side;
  Eigen::AlignedBox3d            m_Bounds;
};

} // namespace

// ---------------------------------------------------------------------------
// BodyRegion
// ---------------------------------------------------------------------------
struct BodyRegion::Impl
{
  std::unique_ptr<CellLocator>    cells;   // FromCells
  std::unique_ptr<SurfaceLocator> surface; // FromSurface
  Index                           surfaceMaterial = 0;
};

BodyRegion::BodyRegion(std::unique_ptr<Impl> impl)
  : m_Impl(std::move(impl))
{}
BodyRegion::BodyRegion(BodyRegion &&) noexcept = default;
BodyRegion & BodyRegion::operator=(BodyRegion &&) noexcept = default;
BodyRegion::~BodyRegion() = default;

BodyRegion
BodyRegion::FromCells(const Model & model)
{
  if (model.cells.empty())
  {
    throw Error("BodyRegion::FromCells: the model has no cells, so it describes no body. Add the cells of the body "
                "(hexahedra or tetrahedra) or use BodyRegion::FromSurface.");
  }
  auto impl = std::make_unique<Impl>();
  impl->cells = std::make_unique<CellLocator>(model);
  return BodyRegion(std::move(impl));
}

BodyRegion
BodyRegion::FromSurface(const std::vector<Vector3> &              vertices,
                        const std::vector<std::array<Index, 3>> & triangles,
                        Index                                     material)
{
  auto impl = std::make_unique<Impl>();
  impl->surface = std::make_unique<SurfaceLocator>(vertices, triangles);
  impl->surfaceMaterial = material;
  return BodyRegion(std::move(impl));
}

bool
BodyRegion::Contains(const Vector3 & x) const
{
  if (m_Impl->cells)
  {
    return m_Impl->cells->FindCell(x) >= 0;
  }
  return m_Impl->surface->Contains(x);
}

Index
BodyRegion::MaterialAt(const Vector3 & x) const
{
  if (m_Impl->cells)
  {
    const Index cell = m_Impl->cells->FindCell(x);
    return cell >= 0 ? m_Impl->cells->Material(cell) : -1;
  }
  return m_Impl->surface->Contains(x) ? m_Impl->surfaceMaterial : -1;
}

Eigen::AlignedBox3d
BodyRegion::Bounds() const
{
  return m_Impl->cells ? m_Impl->cells->Bounds() : m_Impl->surface->Bounds();
}

} // namespace bmr
