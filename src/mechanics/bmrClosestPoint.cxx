#include "bmrClosestPoint.h"

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>

#include <algorithm>
#include <iterator>
#include <limits>

namespace bmr
{

namespace
{
using Kernel = CGAL::Simple_cartesian<double>;
using Point = Kernel::Point_3;
using Triangle = Kernel::Triangle_3;
using Primitive = CGAL::AABB_triangle_primitive<Kernel, std::vector<Triangle>::const_iterator>;
using AabbTraits = CGAL::AABB_traits<Kernel, Primitive>;
using AabbTree = CGAL::AABB_tree<AabbTraits>;

Point
ToPoint(const Vector3 & v)
{
  return { v.x(), v.y(), v.z() };
}
} // namespace

struct TriangleSurfaceTree::Impl
{
  std::vector<Triangle> triangles;  // the tree's primitives point into this
  std::vector<Index>    inputIndex; // input triangle of each primitive
  std::vector<Index>    primitiveOf; // primitive of each input triangle (-1: left out)
  AabbTree              tree;
};

TriangleSurfaceTree::TriangleSurfaceTree(const std::vector<Vector3> &              vertices,
                                         const std::vector<std::array<Index, 3>> & triangles,
                                         const std::string &                       surfaceName)
{
  auto impl = std::make_unique<Impl>();
  for (std::size_t t = 0; t < triangles.size(); ++t)
  {
    Vector3 p[3];
    for (int k = 0; k < 3; ++k)
    {
      const Index v = triangles[t][k];
      if (v < 0 || static_cast<std::size_t>(v) >= vertices.size())
      {
        throw Error(surfaceName + ": triangle " + std::to_string(t) + " refers to vertex " + std::to_string(v) +
                    ", which does not exist (" + std::to_string(vertices.size()) + " vertices)");
      }
      p[k] = vertices[v];
      if (!p[k].allFinite())
      {
        throw Error(surfaceName + ": vertex " + std::to_string(v) + " is not finite; fix the surface file");
      }
    }
    const bool kept = (p[1] - p[0]).cross(p[2] - p[0]).norm() > 0.0;
    if (kept)
    {
      impl->triangles.emplace_back(ToPoint(p[0]), ToPoint(p[1]), ToPoint(p[2]));
      impl->inputIndex.push_back(static_cast<Index>(t));
    }
    impl->primitiveOf.push_back(kept ? static_cast<Index>(impl->triangles.size()) - 1 : -1);
  }
  if (impl->triangles.empty())
  {
    throw Error(surfaceName + " has no triangle of non-zero area; give a triangulated surface");
  }
  impl->tree.insert(impl->triangles.begin(), impl->triangles.end());
  impl->tree.build();
  impl->tree.accelerate_distance_queries();
  m_Impl = std::move(impl);
  // CGAL 5.5 builds both structures above; one query makes sure that nothing
  // lazy is left for concurrent queries to race on in other versions.
  Closest(vertices[triangles[m_Impl->inputIndex.front()][0]]);
}

TriangleSurfaceTree::~TriangleSurfaceTree() = default;

template <typename TreeHit>
TriangleSurfaceTree::Hit
TriangleSurfaceTree::ToHit(const Vector3 & query, const TreeHit & hit) const
{
  const Point  q = ToPoint(query);
  const auto   primitive = static_cast<std::size_t>(hit.second - m_Impl->triangles.begin());
  // The kernel's squared distance, as AABB_tree::squared_distance computes it.
  const double squaredDistance = AabbTraits().squared_distance_object()(q, hit.first);
  return { Vector3(hit.first.x(), hit.first.y(), hit.first.z()), m_Impl->inputIndex[primitive], squaredDistance };
}

TriangleSurfaceTree::Hit
TriangleSurfaceTree::Closest(const Vector3 & query) const
{
  return ToHit(query, m_Impl->tree.closest_point_and_primitive(ToPoint(query)));
}

TriangleSurfaceTree::Hit
TriangleSurfaceTree::Closest(const Vector3 & query, const Hit & hint) const
{
  const Index primitive = hint.triangle >= 0 && static_cast<std::size_t>(hint.triangle) < m_Impl->primitiveOf.size()
                            ? m_Impl->primitiveOf[hint.triangle]
                            : -1;
  if (primitive < 0)
  {
    return Closest(query);
  }
  // The query's projection onto the hint's triangle is at least as close as the hint's own point.
  const auto triangle = m_Impl->triangles.begin() + primitive;
  const Point q = ToPoint(query);
  const AabbTree::Point_and_primitive_id start(Kernel::Construct_projected_point_3()(*triangle, q), triangle);
  return ToHit(query, m_Impl->tree.closest_point_and_primitive(q, start));
}

std::vector<Index>
TriangleSurfaceTree::TrianglesWithin(const Vector3 & query, double radius) const
{
  // The box around the ball finds every triangle the ball reaches, and a few
  // in its corners, which the exact distance leaves out.
  const Point                        q = ToPoint(query);
  const Kernel::Iso_cuboid_3         box(ToPoint(query - Vector3::Constant(radius)), ToPoint(query + Vector3::Constant(radius)));
  std::vector<Primitive::Id>         inBox;
  m_Impl->tree.all_intersected_primitives(box, std::back_inserter(inBox));
  const double                       squaredRadius = radius * radius * (1.0 + 1e-9);
  std::vector<Index>                 within;
  for (const Primitive::Id & id : inBox)
  {
    const Point closest = Kernel::Construct_projected_point_3()(*id, q);
    if (AabbTraits().squared_distance_object()(q, closest) <= squaredRadius)
    {
      within.push_back(m_Impl->inputIndex[static_cast<std::size_t>(id - m_Impl->triangles.begin())]);
    }
  }
  std::sort(within.begin(), within.end());
  return within;
}

TriangleSurfaceTree::Hit
TriangleSurfaceTree::ClosestAmong(const Vector3 & query, const std::vector<Index> & triangles) const
{
  const Point q = ToPoint(query);
  Hit         best{ Vector3::Zero(), -1, std::numeric_limits<double>::infinity() };
  for (const Index t : triangles)
  {
    const Index primitive = m_Impl->primitiveOf[static_cast<std::size_t>(t)];
    if (primitive < 0)
    {
      continue;
    }
    const Point  closest = Kernel::Construct_projected_point_3()(m_Impl->triangles[static_cast<std::size_t>(primitive)], q);
    const double squaredDistance = AabbTraits().squared_distance_object()(q, closest);
    if (squaredDistance < best.squaredDistance)
    {
      best = { Vector3(closest.x(), closest.y(), closest.z()), t, squaredDistance };
    }
  }
  if (best.triangle < 0)
  {
    throw Error("TriangleSurfaceTree::ClosestAmong: no triangle of non-zero area was given (internal error; please "
                "report it).");
  }
  return best;
}

} // namespace bmr
