// Closest points on a triangulated surface: the core's one CGAL AABB tree
// (Simple_cartesian<double>), used by rigid contact, surface loads and the
// brain/skull surfaces. CGAL stays in bmrClosestPoint.cxx (pimpl), so its
// templates are compiled once. Private to the core.
#ifndef bmrClosestPoint_h
#define bmrClosestPoint_h

#include "bmrModel.h"

#include <array>
#include <memory>
#include <string>
#include <vector>

namespace bmr
{

class TriangleSurfaceTree
{
public:
  struct Hit
  {
    Vector3 point;           // closest point of the surface (mm)
    Index   triangle;        // its triangle: an index into the constructor's `triangles`
    double  squaredDistance; // from the query to `point` (mm^2)
  };

  /** Builds the tree over `triangles` (vertex index triples into `vertices`,
   *  mm). Zero-area triangles are left out: they add no points and CGAL's
   *  projection onto them is ill-defined. Throws bmr::Error, starting with
   *  `surfaceName`, if a triangle refers to a missing vertex, a vertex it uses
   *  is not finite, or no triangle has non-zero area. */
  TriangleSurfaceTree(const std::vector<Vector3> &              vertices,
                      const std::vector<std::array<Index, 3>> & triangles,
                      const std::string &                       surfaceName);
  ~TriangleSurfaceTree();
  TriangleSurfaceTree(const TriangleSurfaceTree &) = delete;
  TriangleSurfaceTree & operator=(const TriangleSurfaceTree &) = delete;

  /** Closest point of the surface to `query` (mm). Safe for concurrent
   *  queries: every search structure is built by the constructor. */
  Hit Closest(const Vector3 & query) const;

  /** The same closest point, searched from a hit of a nearby earlier query
   *  (CGAL's hint): the query's projection onto the hint's triangle bounds
   *  the search from the start, so a query near the hint's visits a few
   *  boxes instead of first searching the tree's k-d tree of sample points
   *  (Colin27's `register` solve with skull contact: 1.20-1.26 s with the
   *  hint's own point as the bound, 0.96-0.98 s with the projection). Where
   *  two triangles are equally close the triangle may differ from
   *  Closest(query)'s; the distance does not, beyond rounding. */
  Hit Closest(const Vector3 & query, const Hit & hint) const;

  /** The triangles (the constructor's indices, ascending) that come within
   *  `radius` (mm) of `query`, give or take rounding; zero-area ones are left
   *  out as in Closest. */
  std::vector<Index> TrianglesWithin(const Vector3 & query, double radius) const;

  /** The closest point of `query` on `triangles` (the constructor's indices,
   *  not empty) alone, projected as Closest projects: where the closest
   *  triangle of the whole surface is among them, the same hit (on a tie,
   *  possibly the other triangle). */
  Hit ClosestAmong(const Vector3 & query, const std::vector<Index> & triangles) const;

private:
  struct Impl;
  template <typename TreeHit>
  Hit ToHit(const Vector3 & query, const TreeHit & hit) const;
  std::unique_ptr<const Impl> m_Impl;
};

} // namespace bmr

#endif
