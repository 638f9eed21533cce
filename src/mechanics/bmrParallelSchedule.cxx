// The parallel schedule shared by the finite-element and meshless force
// models (bmrForceModel.h: ColouredSchedule): Morton-ordered blocks of work
// items, coloured so that blocks of one colour share no node.
#include "bmrForceModel.h"
#include "bmrNodeOrder.h"

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <utility>
#include <vector>

namespace bmr
{

ColouredSchedule
ScheduleBySlabs(const std::vector<Index> &   offsets,
                const std::vector<Index> &   nodes,
                const std::vector<Vector3> & centres,
                const Eigen::AlignedBox3d &  box,
                Index                        nodeCount,
                Index                        slabsPerColour)
{
  const Index count = static_cast<Index>(centres.size());
  int         axis = 0;
  box.sizes().maxCoeff(&axis);
  std::vector<Index> order(count);
  std::iota(order.begin(), order.end(), Index{ 0 });
  std::stable_sort(order.begin(), order.end(), [&](Index l, Index r) { return centres[l][axis] < centres[r][axis]; });

  std::vector<Index> slabOf(count);
  std::vector<Index> lowest(nodeCount), highest(nodeCount);
  for (Index slabs = 2 * slabsPerColour; slabs >= 4; slabs /= 2)
  {
    // Equal item counts per slab, cut along the longest axis.
    for (Index position = 0; position < count; ++position)
    {
      slabOf[order[position]] = static_cast<Index>(static_cast<std::int64_t>(position) * slabs / count);
    }
    std::fill(lowest.begin(), lowest.end(), slabs);
    std::fill(highest.begin(), highest.end(), Index{ -1 });
    for (Index item = 0; item < count; ++item)
    {
      for (Index k = offsets[item]; k < offsets[item + 1]; ++k)
      {
        lowest[nodes[k]] = std::min(lowest[nodes[k]], slabOf[item]);
        highest[nodes[k]] = std::max(highest[nodes[k]], slabOf[item]);
      }
    }
    bool valid = true;
    for (Index n = 0; n < nodeCount && valid; ++n)
    {
      valid = highest[n] - lowest[n] <= 1;
    }
    if (!valid)
    {
      continue; // a slab thinner than an item: fewer, thicker slabs
    }
    std::vector<std::vector<std::pair<std::uint64_t, Index>>> itemsOfSlab(slabs);
    for (Index item = 0; item < count; ++item)
    {
      itemsOfSlab[slabOf[item]].emplace_back(MortonCode(centres[item], box), item);
    }
    ColouredSchedule schedule;
    schedule.blockOffsets.push_back(0);
    schedule.colourOffsets.push_back(0);
    for (Index parity = 0; parity < 2; ++parity)
    {
      for (Index slab = parity; slab < slabs; slab += 2)
      {
        auto & keyed = itemsOfSlab[slab];
        std::stable_sort(keyed.begin(), keyed.end(), [](const auto & l, const auto & r) { return l.first < r.first; });
        for (const auto & entry : keyed)
        {
          schedule.items.push_back(entry.second);
        }
        schedule.blockOffsets.push_back(static_cast<Index>(schedule.items.size()));
      }
      schedule.colourOffsets.push_back(static_cast<Index>(schedule.blockOffsets.size()) - 1);
    }
    return schedule;
  }
  return {};
}

ColouredSchedule
ScheduleByColour(const std::vector<Index> &   offsets,
                 const std::vector<Index> &   nodes,
                 const std::vector<Vector3> & centres,
                 const Eigen::AlignedBox3d &  box,
                 Index                        nodeCount,
                 Index                        blockSize)
{
  std::vector<std::pair<std::uint64_t, Index>> keyed;
  for (Index item = 0; item < static_cast<Index>(centres.size()); ++item)
  {
    keyed.emplace_back(MortonCode(centres[item], box), item);
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

ColouredSchedule
ScheduleWork(const std::vector<Index> &   offsets,
             const std::vector<Index> &   nodes,
             const std::vector<Vector3> & centres,
             const Eigen::AlignedBox3d &  box,
             Index                        nodeCount,
             Index                        blockSize)
{
  ColouredSchedule schedule = ScheduleBySlabs(offsets, nodes, centres, box, nodeCount, kSlabsPerColour);
  return schedule.items.empty() ? ScheduleByColour(offsets, nodes, centres, box, nodeCount, blockSize) : schedule;
}

} // namespace bmr
