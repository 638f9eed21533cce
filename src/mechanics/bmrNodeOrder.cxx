#include "bmrNodeOrder.h"

#include <algorithm>
#include <utility>

namespace bmr
{

Eigen::AlignedBox3d
BoundingBox(const std::vector<Vector3> & points)
{
  Eigen::AlignedBox3d box;
  for (const Vector3 & x : points)
  {
    box.extend(x);
  }
  return box;
}

std::uint64_t
MortonCode(const Vector3 & point, const Eigen::AlignedBox3d & box)
{
  const Vector3 extent = box.sizes().cwiseMax(1e-300);
  const Vector3 unit = ((point - box.min()).cwiseQuotient(extent)).cwiseMax(0.0).cwiseMin(1.0);
  std::uint64_t code = 0;
  for (int bit = 9; bit >= 0; --bit)
  {
    for (int axis = 0; axis < 3; ++axis)
    {
      const auto q = static_cast<std::uint64_t>(unit[axis] * 1023.0);
      code = (code << 1) | ((q >> bit) & 1u);
    }
  }
  return code;
}

MortonNumbering::MortonNumbering(const std::vector<Vector3> & nodes)
  : m_SlotOfNode(nodes.size())
  , m_NodeOfSlot(nodes.size())
{
  const Eigen::AlignedBox3d                    box = BoundingBox(nodes);
  std::vector<std::pair<std::uint64_t, Index>> keyed;
  keyed.reserve(nodes.size());
  for (Index n = 0; n < static_cast<Index>(nodes.size()); ++n)
  {
    keyed.emplace_back(MortonCode(nodes[n], box), n);
  }
  std::stable_sort(keyed.begin(), keyed.end(), [](const auto & l, const auto & r) { return l.first < r.first; });
  for (Index slot = 0; slot < static_cast<Index>(keyed.size()); ++slot)
  {
    m_NodeOfSlot[slot] = keyed[slot].second;
    m_SlotOfNode[keyed[slot].second] = slot;
  }
}

std::vector<double>
MortonNumbering::InNodeOrder(const std::vector<double> & valuesOfSlots) const
{
  std::vector<double> values(valuesOfSlots.size());
  for (std::size_t slot = 0; slot < valuesOfSlots.size(); ++slot)
  {
    values[m_NodeOfSlot[slot]] = valuesOfSlots[slot];
  }
  return values;
}

} // namespace bmr
