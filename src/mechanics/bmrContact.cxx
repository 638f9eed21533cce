#include "bmrContact.h"
#include "bmrClosestPoint.h"
#include "bmrFingerprint.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <atomic>
#include <mutex>
#include <utility>

namespace bmr
{

namespace
{
constexpr int kProjectionPasses = 4;
// A contact offset's projection (RigidContact::Tree::Target): its passes, and
// how close to the offset (a share of it) the projected node lands.
constexpr int    kOffsetPasses = 8;
constexpr double kOffsetTolerance = 1e-6;

/** The least distance (mm, on the body's side) a slave may keep from a surface with this contact offset unprojected. */
double
AllowedDistance(double offset)
{
  return offset - kOffsetTolerance * std::abs(offset);
}
} // namespace

struct RigidContact::Tree
{
  // What it was made from (SharedTree compares it).
  std::vector<std::array<Index, 3>>          triangles; // as given
  bool                                       flipNormals = false;
  ContactSurface::Side                       bodySide = ContactSurface::Side::Inside;

  std::vector<Vector3>                       vertices;
  std::vector<std::array<Index, 3>>          corners; // after the orientation flip
  std::vector<Vector3>                       faceNormals;
  std::vector<Vector3>                       vertexNormals; // angle-weighted pseudo-normals, unit length
  std::vector<std::array<Vector3, 3>>        edgeNormals; // per triangle, of its edge from corner k to k + 1: sum of the adjacent face normals
  std::unique_ptr<TriangleSurfaceTree>       surface; // over `corners`: none is degenerate, so none is left out
  bool                                       closed = false;
  double                                     sideSign = -1.0; // -1: body inside, +1: body outside

  // Signed distance of x to the surface (positive outside) from its closest
  // point `hit`, which goes to `closest`. `smoothNormal` (when asked, and
  // set only where x lies closer than `offset` to the surface on the body's
  // side, or beyond it): the unit
  // outward normal of the surface made smooth, the vertices' pseudo-normals
  // interpolated at the closest point; it changes continuously as the
  // closest point crosses an edge, where the facets' normals jump.
  double SignedDistance(const Vector3 & x, const TriangleSurfaceTree::Hit & hit, Vector3 & closest,
                        Vector3 * smoothNormal = nullptr, double offset = 0.0) const
  {
    const auto   t = static_cast<std::size_t>(hit.triangle);
    const auto & c = corners[t];
    closest = hit.point;
    // Barycentric coordinates of the closest point tell whether it lies on a
    // vertex, an edge or inside the face; each has its own pseudo-normal, which
    // makes the sign correct everywhere (Baerentzen and Aanaes).
    const Vector3 a = vertices[c[0]];
    const Vector3 v0 = vertices[c[1]] - a;
    const Vector3 v1 = vertices[c[2]] - a;
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
      // Corners (0, 1) are edge 0, (1, 2) edge 1, (0, 2) edge 2.
      normal = edgeNormals[t][nonzero[0] == 0 && nonzero[1] == 2 ? 2 : nonzero[0]];
    }
    // The pseudo-normal gives the side only: edge and vertex pseudo-normals
    // are sums of face normals, not unit vectors.
    const double distance = (x - closest).dot(normal) < 0.0 ? -(x - closest).norm() : (x - closest).norm();
    if (smoothNormal != nullptr && sideSign * distance < offset)
    {
      // Only there: most queries find the node on the body's side.
      Vector3 sum = Vector3::Zero();
      for (int k = 0; k < 3; ++k)
      {
        sum += std::clamp(weights[k], 0.0, 1.0) * vertexNormals[c[k]];
      }
      *smoothNormal = sum.norm() > 0.0 ? Vector3(sum.normalized()) : faceNormals[t];
    }
    return distance;
  }

  double SignedDistance(const Vector3 & x, Vector3 & closest) const
  {
    return SignedDistance(x, surface->Closest(x), closest);
  }

  // Where a node at x (signed distance `bodySide` on the body's side,
  // closest point `closest`, the smooth outward normal there `smooth`) that
  // came closer than `offset` goes: the closest point of the level set of the
  // surface's distance at the offset, the constraint whose projection is
  // normal to it (a projection along any other direction pushes the node
  // along the surface every step, and it never settles). From the node's
  // closest point along the line to the node where that line is steady (the
  // node at least half the offset from the surface, on the offset's side),
  // else along the smooth normal first; then again from there while the
  // point is closer than the offset to another part of the surface (a valley
  // between faces), up to kOffsetPasses times.
  Vector3 Target(const Vector3 & x, const Vector3 & closest, double bodySide, const Vector3 & smooth,
                 double offset) const
  {
    if (offset == 0.0)
    {
      return closest;
    }
    const auto along = [&](const Vector3 & point, const Vector3 & near, double side, const Vector3 & normal) {
      const double length = (point - near).norm();
      const bool   steady = length >= 0.5 * std::abs(offset) && (side >= 0.0) == (offset > 0.0);
      return Vector3(near + offset * (steady ? Vector3((side >= 0.0 ? 1.0 : -1.0) / length * (point - near))
                                             : Vector3(sideSign * normal)));
    };
    Vector3 target = along(x, closest, bodySide, smooth);
    for (int pass = 0; pass < kOffsetPasses; ++pass)
    {
      Vector3      near, normal;
      const double side = sideSign * SignedDistance(target, surface->Closest(target), near, &normal, offset);
      if (std::abs(side - offset) <= kOffsetTolerance * std::abs(offset))
      {
        break;
      }
      target = along(target, near, side, normal);
    }
    return target;
  }
};

namespace
{
// How far (in mean edge lengths of the surface) a slave may move before its
// candidate triangles are searched again. Colin27's 7 mm tetrahedra with
// fitted gravity against the undecimated skull (frontal-15mm, 2 threads, one
// run each on a noisy host): the job took 46-51 s with every query from the
// tree, 32.6 / 33.5 / 35.2 s at 0.05 / 0.1 / 0.2, 65 s at 1 (too many
// candidates to project); the tree's traversal fell from 17 % of the samples
// to 2 % at 0.1.
constexpr double kCandidateReach = 0.1;

/** Edge e = 3 t + k of a triangle list (from corner k to corner k + 1), keyed
 *  by its end points (the smaller first, packed in one key); sorted by key,
 *  then by number, the edges shared by triangles lie next to each other. */
struct SurfaceEdge
{
  std::uint64_t ends;
  std::size_t   number;
  bool          operator<(const SurfaceEdge & other) const
  {
    return ends != other.ends ? ends < other.ends : number < other.number;
  }
};

std::vector<SurfaceEdge>
SortedEdges(const std::vector<std::array<Index, 3>> & triangles)
{
  std::vector<SurfaceEdge> edges(3 * triangles.size());
  for (std::size_t e = 0; e < edges.size(); ++e)
  {
    const auto & c = triangles[e / 3];
    const auto   a = static_cast<std::uint32_t>(c[e % 3]), b = static_cast<std::uint32_t>(c[(e % 3 + 1) % 3]);
    edges[e] = { (std::uint64_t{ std::min(a, b) } << 32) | std::max(a, b), e };
  }
  std::sort(edges.begin(), edges.end());
  return edges;
}
} // namespace

double
ContactSurface::MeanEdgeLength() const
{
  double      sum = 0.0;
  std::size_t count = 0;
  for (const auto & t : triangles)
  {
    for (int k = 0; k < 3; ++k)
    {
      sum += (vertices[t[k]] - vertices[t[(k + 1) % 3]]).norm();
      ++count;
    }
  }
  return count > 0 ? sum / static_cast<double>(count) : 0.0;
}

std::vector<std::array<Index, 3>>
ContactSurface::OutwardTriangles(bool * closedOut) const
{
  const std::vector<SurfaceEdge> edges = SortedEdges(triangles);
  const auto fromCorner = [&](const SurfaceEdge & edge) { return triangles[edge.number / 3][edge.number % 3]; };
  bool closed = true;
  bool oriented = true;
  for (std::size_t first = 0, last = 0; first < edges.size(); first = last)
  {
    while (last < edges.size() && edges[last].ends == edges[first].ends)
    {
      ++last;
    }
    closed = closed && last - first == 2;
    // Consistently oriented: the two triangles run along their shared edge in opposite directions.
    oriented = oriented && (last - first != 2 || fromCorner(edges[first]) != fromCorner(edges[first + 1]));
  }
  if (closed && !oriented)
  {
    throw Error("contact surface '" + name + "' is closed but its triangles are not consistently oriented. Repair the surface.");
  }
  bool flip = flipNormals;
  if (closed)
  {
    double signedVolume = 0.0;
    for (const auto & c : triangles)
    {
      signedVolume += vertices[c[0]].dot(vertices[c[1]].cross(vertices[c[2]]));
    }
    flip = signedVolume < 0.0; // orient outward
  }
  std::vector<std::array<Index, 3>> outward = triangles;
  if (flip)
  {
    for (auto & c : outward)
    {
      std::swap(c[1], c[2]);
    }
  }
  if (closedOut != nullptr)
  {
    *closedOut = closed;
  }
  return outward;
}

namespace
{
/** A fingerprint of a surface's vertices, triangles, orientation and body side. */
std::uint64_t
SurfaceKey(const ContactSurface & surface)
{
  Fingerprint key;
  for (const Vector3 & vertex : surface.vertices)
  {
    key.Add(vertex);
  }
  for (const auto & triangle : surface.triangles)
  {
    for (const Index vertex : triangle)
    {
      key.Add(vertex);
    }
  }
  key.Add(surface.flipNormals);
  key.Add(surface.bodySide);
  return key.Value();
}
} // namespace

std::atomic<std::uint64_t> RigidContact::s_TreesBuilt{ 0 };

std::shared_ptr<const RigidContact::Tree>
RigidContact::SharedTree(const ContactSurface & surface)
{
  // The trees of the contacts alive, by their surfaces' keys: a tree is the
  // costly part of a contact (Colin27's skull, 262k triangles: its edges
  // sorted, its normals, CGAL's AABB and k-d trees) and depends on the
  // surface alone. Weak: a tree lives as long as a contact uses it, and the
  // last one used a while longer, for the next solve of the same surface
  // (a gravity fit's sizes, solved one after another).
  static std::mutex                                                    mutex;
  static std::vector<std::pair<std::uint64_t, std::weak_ptr<const Tree>>> trees;
  static std::shared_ptr<const Tree>                                   lastUsed;
  const std::uint64_t key = SurfaceKey(surface);
  const auto          same = [&](const Tree & tree) {
    return tree.flipNormals == surface.flipNormals && tree.bodySide == surface.bodySide &&
           tree.triangles == surface.triangles && tree.vertices == surface.vertices;
  };
  {
    const std::lock_guard<std::mutex> lock(mutex);
    trees.erase(std::remove_if(trees.begin(), trees.end(), [](const auto & entry) { return entry.second.expired(); }),
                trees.end());
    for (const auto & [entryKey, entry] : trees)
    {
      if (const auto tree = entry.lock(); entryKey == key && tree && same(*tree))
      {
        lastUsed = tree;
        return tree;
      }
    }
  }

  // Built outside the lock (two contacts may build the same tree at once; both are right).
  auto   made = std::make_shared<Tree>();
  Tree & tree = *made;
  tree.triangles = surface.triangles;
  tree.flipNormals = surface.flipNormals;
  tree.bodySide = surface.bodySide;
  tree.corners = surface.OutwardTriangles(&tree.closed);
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
    for (int k = 0; k < 3; ++k)
    {
      const Vector3 e1 = (p[(k + 1) % 3] - p[k]).normalized();
      const Vector3 e2 = (p[(k + 2) % 3] - p[k]).normalized();
      tree.vertexNormals[c[k]] += std::acos(std::clamp(e1.dot(e2), -1.0, 1.0)) * normal;
    }
  }
  // Unit length: the side test needs only their direction, the smooth normal interpolates them.
  for (Vector3 & normal : tree.vertexNormals)
  {
    if (normal.norm() > 0.0)
    {
      normal.normalize();
    }
  }
  // An edge's pseudo-normal sums the normals of the triangles that share it, in triangle order.
  const std::vector<SurfaceEdge> edges = SortedEdges(tree.corners);
  tree.edgeNormals.resize(tree.corners.size());
  for (std::size_t first = 0, last = 0; first < edges.size(); first = last)
  {
    Vector3 sum = Vector3::Zero();
    for (last = first; last < edges.size() && edges[last].ends == edges[first].ends; ++last)
    {
      sum += tree.faceNormals[edges[last].number / 3];
    }
    for (std::size_t e = first; e < last; ++e)
    {
      tree.edgeNormals[edges[e].number / 3][edges[e].number % 3] = sum;
    }
  }
  tree.vertices = surface.vertices;
  tree.surface =
    std::make_unique<TriangleSurfaceTree>(tree.vertices, tree.corners, "contact surface '" + surface.name + "'");
  const std::lock_guard<std::mutex> lock(mutex);
  trees.emplace_back(key, made);
  lastUsed = made;
  ++s_TreesBuilt;
  return made;
}

RigidContact::RigidContact(const ContactSurface & surface, std::vector<Index> slaveNodes, const std::vector<Vector3> & reference)
  : m_SlaveNodes(std::move(slaveNodes))
{
  if (!std::isfinite(surface.offset))
  {
    throw Error("contact surface '" + surface.name + "': the offset is not a finite number; give it in mm (0: none)");
  }
  m_Offset = surface.offset;
  m_Tree = SharedTree(surface);

  for (const Index node : m_SlaveNodes)
  {
    m_Reference.push_back(reference[node]);
  }
  m_LastQueried = m_Reference;
  m_SafeDistance.assign(m_SlaveNodes.size(), 0.0);
  m_LastHit.assign(m_SlaveNodes.size(), TriangleSurfaceTree::Hit{ Vector3::Zero(), -1, 0.0 });
  m_Candidates.resize(m_SlaveNodes.size());
  m_CandidateReach = kCandidateReach * surface.MeanEdgeLength();
}

TriangleSurfaceTree::Hit
RigidContact::ClosestOfSlave(Index i, const Vector3 & x)
{
  // Every triangle within d + 2 r of the centre, d its distance there, holds
  // the closest point of any x within r of the centre: that point is at most
  // d + r from x, so at most d + 2 r from the centre.
  Candidates &                 candidates = m_Candidates[static_cast<std::size_t>(i)];
  TriangleSurfaceTree::Hit &   last = m_LastHit[static_cast<std::size_t>(i)];
  const TriangleSurfaceTree &  surface = *m_Tree->surface;
  if (!candidates.triangles.empty() && (x - candidates.centre).norm() <= m_CandidateReach)
  {
    last = surface.ClosestAmong(x, candidates.triangles);
    return last;
  }
  last = last.triangle >= 0 ? surface.Closest(x, last) : surface.Closest(x);
  candidates.centre = x;
  candidates.triangles = surface.TrianglesWithin(x, std::sqrt(last.squaredDistance) + 2.0 * m_CandidateReach);
  return last;
}

RigidContact::~RigidContact() = default;

bool
RigidContact::IsClosed() const
{
  return m_Tree->closed;
}

void
RigidContact::SetPose(const Eigen::Matrix3d & rotation, const Vector3 & translation)
{
  m_Rotation = rotation;
  m_Translation = translation;
}

void
RigidContact::Enforce(double * u, const std::vector<char> & dofConstrained, std::vector<char> & inContact, int threads,
                      std::vector<Vector3> * corrections, std::vector<Vector3> * normals,
                      std::vector<double> * clearances)
{
  const Tree & tree = *m_Tree;
  const auto   count = static_cast<Index>(m_SlaveNodes.size());
  if (corrections != nullptr)
  {
    corrections->assign(m_SlaveNodes.size(), Vector3::Zero());
  }
  if (normals != nullptr)
  {
    normals->assign(m_SlaveNodes.size(), Vector3::Zero());
  }
  if (clearances != nullptr)
  {
    clearances->assign(m_SlaveNodes.size(), 0.0);
  }
  // Distances are measured in the surface's own frame, where they do not
  // change when the surface moves rigidly: the query cache stays valid.
  const auto toSurface = [&](const Vector3 & x) -> Vector3 { return m_Rotation.transpose() * (x - m_Translation); };
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
    const Vector3 x = toSurface(m_Reference[i] + Vector3(un[0], un[1], un[2]));
    // A node that was at distance d on the allowed side cannot have crossed the
    // surface while it stays within d of that position: no query needed.
    const double moved = (x - m_LastQueried[i]).norm();
    if (moved < m_SafeDistance[i])
    {
      if (clearances != nullptr)
      {
        (*clearances)[static_cast<std::size_t>(i)] = m_SafeDistance[i] - moved;
      }
      continue;
    }
    Vector3      closest, smooth;
    const auto   hit = ClosestOfSlave(i, x);
    const double bodySide =
      tree.sideSign * tree.SignedDistance(x, hit, closest, normals || m_Offset != 0.0 ? &smooth : nullptr, m_Offset);
    if (bodySide >= AllowedDistance(m_Offset))
    {
      m_LastQueried[i] = x;
      m_SafeDistance[i] = std::max(0.0, bodySide - m_Offset); // at offset 0: |x - closest|
      if (clearances != nullptr)
      {
        (*clearances)[static_cast<std::size_t>(i)] = m_SafeDistance[i];
      }
      continue;
    }
    if (normals != nullptr)
    {
      (*normals)[static_cast<std::size_t>(i)] = m_Rotation * (tree.sideSign * smooth);
    }
    // Project onto the surface (its offset); a node held in some components (a
    // symmetry plane) moves in the others only: alternate projection and
    // restoring the held components, which converges for the locally convex surface.
    const Vector3 held0(un[0], un[1], un[2]);
    Vector3       position = x;
    Vector3       target = tree.Target(x, closest, bodySide, smooth, m_Offset);
    for (int pass = 0; pass < kProjectionPasses; ++pass)
    {
      Vector3 displacement = m_Rotation * target + m_Translation - m_Reference[i];
      for (int k = 0; k < 3; ++k)
      {
        if (held[k])
        {
          displacement[k] = held0[k];
        }
      }
      position = m_Reference[i] + displacement;
      if (!(held[0] || held[1] || held[2]))
      {
        break;
      }
      const Vector3 at = toSurface(position);
      const auto    next = tree.surface->Closest(at);
      const double  side = tree.sideSign * tree.SignedDistance(at, next, closest, &smooth, m_Offset);
      if (side >= AllowedDistance(m_Offset))
      {
        break;
      }
      target = tree.Target(at, closest, side, smooth, m_Offset);
    }
    const Vector3 projected = position - m_Reference[i];
    if (corrections != nullptr)
    {
      (*corrections)[static_cast<std::size_t>(i)] = projected - held0;
    }
    un[0] = projected.x();
    un[1] = projected.y();
    un[2] = projected.z();
    inContact[node] = 1;
    m_SafeDistance[i] = 0.0;
  }
}

double
RigidContact::SignedDistance(const Vector3 & point) const
{
  Vector3 closest;
  return m_Tree->sideSign * m_Tree->SignedDistance(m_Rotation.transpose() * (point - m_Translation), closest);
}

RigidContact::Penetrations
RigidContact::FindPenetrations(const double * u, double tolerance) const
{
  Penetrations found;
  for (std::size_t i = 0; i < m_SlaveNodes.size(); ++i)
  {
    const double * un = u + 3 * static_cast<std::size_t>(m_SlaveNodes[i]);
    Vector3        closest;
    const Vector3  x = m_Rotation.transpose() * (m_Reference[i] + Vector3(un[0], un[1], un[2]) - m_Translation);
    const double   bodySide = m_Tree->sideSign * m_Tree->SignedDistance(x, closest);
    const double   depth = AllowedDistance(m_Offset) - bodySide;
    if (depth > tolerance)
    {
      ++found.count;
      if (depth > found.depth)
      {
        found.depth = depth;
        found.deepestNode = m_SlaveNodes[i];
      }
    }
  }
  return found;
}

} // namespace bmr
