// The parallel schedule shared by the finite-element and meshless force
// models (bmrForceModel.h: ColouredSchedule): Morton-ordered blocks of work
// items, coloured so that blocks of one colour share no node.
#include "bmrForceModel.h"

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

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

ColouredSchedule
ScheduleByColour(const std::vector<Index> &   offsets,
                 const std::vector<Index> &   nodes,
                 const std::vector<Vector3> & centres,
                 const Eigen::AlignedBox3d &  box,
                 Index                        nodeCount,
                 Index                        blockSize)
{
  const Vector3 extent = box.sizes().cwiseMax(1e-300);
  auto          morton = [&](const Vector3 & centre) {
    const Vector3 unit = ((centre - box.min()).cwiseQuotient(extent)).cwiseMax(0.0).cwiseMin(1.0);
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
  };
  std::vector<std::pair<std::uint64_t, Index>> keyed;
  for (Index item = 0; item < static_cast<Index>(centres.size()); ++item)
  {
    keyed.emplace_back(morton(centres[item]), item);
  }
  std::stable_sort(keyed.begin(), keyed.end(), [](const auto & l, const auto & r) { return l.first < r.first; });

  // Greedy block colouring with a per-node bit mask of the colours touching it.
  const Index                             blockCount = (static_cast<Index>(keyed.size()) + blockSize - 1) / blockSize;
  std::vector<std::vector<Index>>         blocksOfColour;
  std::vector<std::vector<std::uint64_t>> used(nodeCount);
  for (Index b = 0; b < blockCount; ++b)
  {
    const Index                begin = b * blockSize;
    const Index                end = std::min<Index>(begin + blockSize, static_cast<Index>(keyed.size()));
    std::vector<std::uint64_t> taken;
    for (Index i = begin; i < end; ++i)
    {
      const Index item = keyed[i].second;
      for (Index k = offsets[item]; k < offsets[item + 1]; ++k)
      {
        const auto & mask = used[nodes[k]];
        taken.resize(std::max(taken.size(), mask.size()), 0);
        for (std::size_t w = 0; w < mask.size(); ++w)
        {
          taken[w] |= mask[w];
        }
      }
    }
    std::size_t colour = 0;
    while (colour / 64 < taken.size() && (taken[colour / 64] >> (colour % 64) & 1u))
    {
      ++colour;
    }
    for (Index i = begin; i < end; ++i)
    {
      const Index item = keyed[i].second;
      for (Index k = offsets[item]; k < offsets[item + 1]; ++k)
      {
        auto & mask = used[nodes[k]];
        mask.resize(std::max(mask.size(), colour / 64 + 1), 0);
        mask[colour / 64] |= std::uint64_t{ 1 } << (colour % 64);
      }
    }
    if (colour >= blocksOfColour.size())
    {
      blocksOfColour.resize(colour + 1);
    }
    blocksOfColour[colour].push_back(b);
  }

  ColouredSchedule schedule;
  schedule.blockOffsets.push_back(0);
  schedule.colourOffsets.push_back(0);
  for (const auto & blocks : blocksOfColour)
  {
    for (const Index b : blocks)
    {
      const Index begin = b * blockSize;
      const Index end = std::min<Index>(begin + blockSize, static_cast<Index>(keyed.size()));
      for (Index i = begin; i < end; ++i)
      {
        schedule.items.push_back(keyed[i].second);
      }
      schedule.blockOffsets.push_back(static_cast<Index>(schedule.items.size()));
    }
    schedule.colourOffsets.push_back(static_cast<Index>(schedule.blockOffsets.size()) - 1);
  }
  return schedule;
}

} // namespace bmr
