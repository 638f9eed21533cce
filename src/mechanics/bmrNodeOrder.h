// Numbering nodes so that nodes close in space are close in memory (private to the core).
#ifndef bmrNodeOrder_h
#define bmrNodeOrder_h

#include "bmrModel.h"

#include <Eigen/Geometry>

#include <cstdint>
#include <vector>

namespace bmr
{

Eigen::AlignedBox3d
BoundingBox(const std::vector<Vector3> & points);

/** Morton (Z-order) code of a point in the frame of `box`, 10 bits per axis. */
std::uint64_t
MortonCode(const Vector3 & point, const Eigen::AlignedBox3d & box);

/** The nodes in Morton order: node n is given "slot" Slot(n). Meshes and
 *  clouds number their nodes in any order (CGAL's tetrahedra and the
 *  meshless cloud of Colin27 at random: about 120 mm between consecutive
 *  nodes at the 90th percentile), and then the nodes of one cell or one
 *  integration point are as many cache lines of u and f, arrays larger than
 *  L2 at 100,000 DOF. The meshless force kernel works in this numbering; the
 *  tetrahedral grids of images are numbered in it (docs/thread-scaling.md). */
class MortonNumbering
{
public:
  MortonNumbering() = default;
  explicit MortonNumbering(const std::vector<Vector3> & nodes);

  Index Slot(Index node) const { return m_SlotOfNode[node]; }
  Index Node(Index slot) const { return m_NodeOfSlot[slot]; }
  /** Per-node values (one per node) given in slot order, in node order. */
  std::vector<double> InNodeOrder(const std::vector<double> & valuesOfSlots) const;

  /** Whether it numbers `count` nodes one to one (a numbering read from a file). */
  bool IsPermutation(Index count) const
  {
    if (m_SlotOfNode.size() != static_cast<std::size_t>(count) || m_NodeOfSlot.size() != m_SlotOfNode.size())
    {
      return false;
    }
    for (Index n = 0; n < count; ++n)
    {
      const Index slot = m_SlotOfNode[n];
      if (slot < 0 || slot >= count || m_NodeOfSlot[slot] != n)
      {
        return false;
      }
    }
    return true;
  }

  /** Lists its members to `visit` (bmrBinaryStream.h). */
  template <typename Self, typename Visitor>
  static void VisitMembers(Self & self, Visitor & visit)
  {
    visit(self.m_SlotOfNode);
    visit(self.m_NodeOfSlot);
  }

private:
  std::vector<Index> m_SlotOfNode;
  std::vector<Index> m_NodeOfSlot;
};

} // namespace bmr

#endif
