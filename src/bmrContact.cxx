#include "bmrContact.h"

#include <Eigen/Geometry>

#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Simple_cartesian.h>

#include <algorithm>
#include <cmath>
#include <map>

namespace bmr
{

namespace
{
constexpr int kProjectionPasses = 4;

using Kernel = CGAL::Simple_cartesian<double>;
using Point = Kernel::Point_3;
using Triangle = Kernel::Triangle_3;
using TriangleIterator = std::vector<Triangle>::const_iterator;
using Primitive = CGAL::AABB_triangle_primitive<Kernel, TriangleIterator>;
using AabbTree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, Primitive>>;

Vector3
ToVector(const Point & p)
{
  return { p.x(), p.y(), p.z() };
}
} // namespace

struct RigidContact::Tree
{
  std::vector<Triangle>             triangles;
  std::vector<std::array<Index, 3>> corners;
  std::vector<Vector3>              faceNormals;
  std::vector<Vector3>              vertexNormals; // angle-weighted pseudo-normals
  std::map<std::pair<Index, Index>, Vector3> edgeNormals;
  AabbTree                          tree;
  bool                              closed = false;
  double                            sideSign = -1.0; // -1: body inside, +1: body outside

  // Signed distance of x to the surface (positive outside) and the closest point.
  double SignedDistance(const Vector3 & x, Vector3 & closest) const
  {
    const auto   hit = tree.closest_point_and_primitive(Point(x.x(), x.y(), x.z()));
    const auto   t = static_cast<std::size_t>(hit.second - triangles.begin());
    const auto & c = corners[t];
    closest = ToVector(hit.first);
    // Barycentric coordinates of the closest point tell whether it lies on a
    // vertex, an edge or inside the face; each has its own pseudo-normal, which
    // makes the sign correct everywhere (Baerentzen and Aanaes).
    const Vector3 a = ToVector(triangles[t].vertex(0));
    const Vector3 v0 = ToVector(triangles[t].vertex(1)) - a;
    const Vector3 v1 = ToVector(triangles[t].vertex(2)) - a;
    const Vector3 v2 = closest - a;
    const double  d00 = v0.dot(v0), d01 = v0.dot(v1), d11 = v1.dot(v1), d20 = v2.dot(v0), d21 = v2.dot(v1);
    const double  denominator = d00 * d11 - d01 * d01;
    const double  w1 = (d11 * d20 - d01 * d21) / denominator;
    const double  w2 = (d00 * d21 - d01 * d20) / denominator;
    const double  weights[3] = { 1.0 - w1 - w2, w1, w2 };
    constexpr double tiny = 1e-9;
    int              nonzero[3];
    int              count = 0;
    for (int k = 0; k < 3; ++k)
    {
      if (weights[k] > tiny)
      {
        nonzero[count++] = k;
      }
    }
    Vector3 normal = faceNormals[t];
    if (count == 1)
    {
      normal = vertexNormals[c[nonzero[0]]];
    }
    else if (count == 2)
    {
      const auto edge = edgeNormals.find(std::minmax(c[nonzero[0]], c[nonzero[1]]));
      if (edge != edgeNormals.end())
      {
        normal = edge->second;
      }
    }
    return (x - closest).dot(normal);
  }
};

RigidContact::RigidContact(const ContactSurface & surface, std::vector<Index> slaveNodes, const std::vector<Vector3> & reference)
  : m_Tree(std::make_unique<Tree>())
  , m_SlaveNodes(std::move(slaveNodes))
{
  Tree & tree = *m_Tree;
  tree.corners = surface.triangles;

  // Closed means every edge is shared by exactly two triangles.
  std::map<std::pair<Index, Index>, int> edgeUse;
  std::map<std::pair<Index, Index>, int> directedUse;
  for (const auto & c : tree.corners)
  {
    for (int k = 0; k < 3; ++k)
    {
      ++edgeUse[std::minmax(c[k], c[(k + 1) % 3])];
      ++directedUse[{ c[k], c[(k + 1) % 3] }];
    }
  }
  tree.closed = std::all_of(edgeUse.begin(), edgeUse.end(), [](const auto & e) { return e.second == 2; });
  bool flip = surface.flipNormals;
  if (tree.closed)
  {
    if (std::any_of(directedUse.begin(), directedUse.end(), [](const auto & e) { return e.second != 1; }))
    {
      throw Error("contact surface '" + surface.name +
                  "' is closed but its triangles are not consistently oriented. Repair the surface.");
    }
    double signedVolume = 0.0;
    for (const auto & c : tree.corners)
    {
      signedVolume += surface.vertices[c[0]].dot(surface.vertices[c[1]].cross(surface.vertices[c[2]]));
    }
    flip = signedVolume < 0.0; // orient outward
  }
  if (flip)
  {
    for (auto & c : tree.corners)
    {
      std::swap(c[1], c[2]);
    }
  }
  tree.sideSign = surface.bodySide == ContactSurface::Side::Inside ? -1.0 : 1.0;

  tree.vertexNormals.assign(surface.vertices.size(), Vector3::Zero());
  for (std::size_t t = 0; t < tree.corners.size(); ++t)
  {
    const auto &  c = tree.corners[t];
    const Vector3 p[3] = { surface.vertices[c[0]], surface.vertices[c[1]], surface.vertices[c[2]] };
    Vector3       normal = (p[1] - p[0]).cross(p[2] - p[0]);
    if (!(normal.norm() > 0.0))
    {
      throw Error("contact surface '" + surface.name + "' has a degenerate triangle " + std::to_string(t) +
                  ". Clean the surface (remove zero-area triangles).");
    }
    normal.normalize();
    tree.faceNormals.push_back(normal);
    tree.triangles.emplace_back(Point(p[0].x(), p[0].y(), p[0].z()), Point(p[1].x(), p[1].y(), p[1].z()),
                                Point(p[2].x(), p[2].y(), p[2].z()));
    for (int k = 0; k < 3; ++k)
    {
      const Vector3 e1 = (p[(k + 1) % 3] - p[k]).normalized();
      const Vector3 e2 = (p[(k + 2) % 3] - p[k]).normalized();
      tree.vertexNormals[c[k]] += std::acos(std::clamp(e1.dot(e2), -1.0, 1.0)) * normal;
      // try_emplace with an explicit zero: Eigen's default constructor leaves values uninitialised.
      tree.edgeNormals.try_emplace(std::minmax(c[k], c[(k + 1) % 3]), Vector3::Zero()).first->second += normal;
    }
  }
  tree.tree.insert(tree.triangles.begin(), tree.triangles.end());
  tree.tree.build();
  tree.tree.accelerate_distance_queries();
  Vector3 unused;
  tree.SignedDistance(surface.vertices.front(), unused); // builds lazy search structures before threads query

  for (const Index node : m_SlaveNodes)
  {
    m_Reference.push_back(reference[node]);
  }
  m_LastQueried = m_Reference;
  m_SafeDistance.assign(m_SlaveNodes.size(), 0.0);
}

RigidContact::~RigidContact() = default;

bool
RigidContact::IsClosed() const
{
  return m_Tree->closed;
}

void
RigidContact::Enforce(double * u, const std::vector<char> & dofConstrained, std::vector<char> & inContact, int threads)
{
  const Tree & tree = *m_Tree;
  const auto   count = static_cast<Index>(m_SlaveNodes.size());
#pragma omp parallel for num_threads(threads) schedule(dynamic, 256)
  for (Index i = 0; i < count; ++i)
  {
    const Index  node = m_SlaveNodes[i];
    const char * held = &dofConstrained[3 * static_cast<std::size_t>(node)];
    if (held[0] && held[1] && held[2])
    {
      continue;
    }
    double *      un = u + 3 * static_cast<std::size_t>(node);
    const Vector3 x = m_Reference[i] + Vector3(un[0], un[1], un[2]);
    // A node that was at distance d on the allowed side cannot have crossed the
    // surface while it stays within d of that position: no query needed.
    if ((x - m_LastQueried[i]).norm() < m_SafeDistance[i])
    {
      continue;
    }
    Vector3 closest;
    if (tree.sideSign * tree.SignedDistance(x, closest) >= 0.0)
    {
      m_LastQueried[i] = x;
      m_SafeDistance[i] = (x - closest).norm();
      continue;
    }
    // Project onto the surface; a node held in some components (a symmetry
    // plane) moves in the others only: alternate projection and restoring the
    // held components, which converges for the locally convex surface.
    const Vector3 held0(un[0], un[1], un[2]);
    Vector3       position = x;
    for (int pass = 0; pass < kProjectionPasses; ++pass)
    {
      Vector3 displacement = closest - m_Reference[i];
      for (int k = 0; k < 3; ++k)
      {
        if (held[k])
        {
          displacement[k] = held0[k];
        }
      }
      position = m_Reference[i] + displacement;
      if (!(held[0] || held[1] || held[2]) || tree.sideSign * tree.SignedDistance(position, closest) >= 0.0)
      {
        break;
      }
    }
    const Vector3 projected = position - m_Reference[i];
    un[0] = projected.x();
    un[1] = projected.y();
    un[2] = projected.z();
    inContact[node] = 1;
    m_SafeDistance[i] = 0.0;
  }
}

double
RigidContact::MaxPenetration(const double * u) const
{
  double deepest = 0.0;
  for (std::size_t i = 0; i < m_SlaveNodes.size(); ++i)
  {
    const double * un = u + 3 * static_cast<std::size_t>(m_SlaveNodes[i]);
    Vector3        closest;
    const double   s = m_Tree->sideSign * m_Tree->SignedDistance(m_Reference[i] + Vector3(un[0], un[1], un[2]), closest);
    deepest = std::max(deepest, -s);
  }
  return deepest;
}

} // namespace bmr
