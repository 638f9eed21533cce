// Frictionless rigid contact with separation (Joldes et al., MICCAI 2009):
// after each step, slave nodes that crossed the rigid master surface are moved
// to its closest point. No penalty parameters. Private to the core.
#ifndef bmrContact_h
#define bmrContact_h

#include "bmrClosestPoint.h"
#include "bmrModel.h"

#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

namespace bmr
{

class RigidContact
{
public:
  /** Builds the AABB tree and pseudo-normals, or shares those of a contact
   *  alive with the same surface (vertices, triangles, orientation and body
   *  side: an ensemble's members) or of the last contact made (a gravity
   *  fit's solves, one after another). Closed surfaces
   *  are oriented outward; open ones keep their orientation (normals point
   *  outside). */
  RigidContact(const ContactSurface & surface, std::vector<Index> slaveNodes, const std::vector<Vector3> & reference);
  ~RigidContact();
  RigidContact(const RigidContact &) = delete;
  RigidContact & operator=(const RigidContact &) = delete;

  /** Moves penetrating slave nodes (u: 3 per node, mm) onto the surface (at
   *  its offset, ContactSurface::offset) and marks them in `inContact`. Components flagged in `dofConstrained` (3 per
   *  node) keep their value; the node moves in its free components only.
   *  `corrections` (when given): per slave node, the displacement the
   *  projection added (zero for nodes it left alone). `normals` (when given):
   *  per projected slave node, the surface's interpolated unit normal at its
   *  closest point (the vertices' pseudo-normals interpolated there: it
   *  changes continuously across edges), towards the body's side (model
   *  frame; zero for nodes left alone).
   *  `clearances` (when given): per slave node, a lower bound of its
   *  distance to the surface's offset on the body's side (0 for nodes projected or
   *  held in every component): while the pose stays, a node that moves less
   *  than that cannot cross the surface. */
  void Enforce(double * u, const std::vector<char> & dofConstrained, std::vector<char> & inContact, int threads,
               std::vector<Vector3> * corrections = nullptr, std::vector<Vector3> * normals = nullptr,
               std::vector<double> * clearances = nullptr);

  /** Places the surface: a point p of the surface's own frame is at
   *  rotation p + translation (a moving tool); identity by default. */
  void SetPose(const Eigen::Matrix3d & rotation, const Vector3 & translation);

  /** Signed distance (mm) of a point (model frame) to the surface itself (not
   *  its offset), positive on the body's side. */
  double SignedDistance(const Vector3 & point) const;

  /** Slave nodes beyond the surface's offset by more than `tolerance` (mm) at
   *  displacements u: how many, the deepest and how deep. */
  struct Penetrations
  {
    int    count = 0;
    Index  deepestNode = -1;
    double depth = 0.0; // mm; 0 when none
  };
  Penetrations FindPenetrations(const double * u, double tolerance = 0.0) const;

  /** Largest penetration (mm) of any slave node at displacements u. */
  double MaxPenetration(const double * u) const { return FindPenetrations(u).depth; }

  bool IsClosed() const;
  /** Whether the two contacts share one tree (SharedTree: equal surfaces). */
  bool SharesTreeWith(const RigidContact & other) const { return m_Tree == other.m_Tree; }
  /** Trees built so far in this process (the others were shared). */
  static std::uint64_t TreesBuilt() { return s_TreesBuilt.load(); }
  const std::vector<Index> & SlaveNodes() const { return m_SlaveNodes; }

private:
  struct Tree;
  /** The tree of `surface`: a live contact's when one has the same surface, else a new one. */
  static std::shared_ptr<const Tree> SharedTree(const ContactSurface & surface);
  std::shared_ptr<const Tree> m_Tree; // immutable, shared
  static std::atomic<std::uint64_t> s_TreesBuilt;
  std::vector<Index>     m_SlaveNodes;
  double                 m_Offset = 0.0;  // ContactSurface::offset (mm)
  std::vector<Vector3>   m_Reference;     // reference positions of slave nodes
  Eigen::Matrix3d        m_Rotation = Eigen::Matrix3d::Identity();
  Vector3                m_Translation = Vector3::Zero();
  std::vector<Vector3>   m_LastQueried;   // position at the last exact query, in the surface's frame
  std::vector<double>    m_SafeDistance;  // distance to the surface at that query (allowed side), else 0
  std::vector<TriangleSurfaceTree::Hit> m_LastHit; // closest point of the last query (surface frame; triangle -1: none yet)
  /** The triangles that hold a slave's closest point while it stays within
   *  m_CandidateReach of `centre` (surface frame; none yet: empty). */
  struct Candidates
  {
    Vector3            centre = Vector3::Zero();
    std::vector<Index> triangles;
  };
  std::vector<Candidates> m_Candidates;
  double                  m_CandidateReach = 0.0; // mm
  /** The closest point of slave i at x (surface frame): from its candidates while it stays near them, else from the tree. */
  TriangleSurfaceTree::Hit ClosestOfSlave(Index i, const Vector3 & x);
};

} // namespace bmr

#endif
