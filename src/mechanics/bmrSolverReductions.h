// Private to the solver: sums over the dofs in a fixed block partition, so
// that results do not depend on the number of threads.
#ifndef bmrSolverReductions_h
#define bmrSolverReductions_h

#include "bmrModel.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace bmr
{

// Fixed block partition: sums do not depend on the number of threads.
constexpr Index kReductionBlocks = 64;

template <typename Term>
inline double
DeterministicSum(Index count, int threads, const Term & term)
{
  double partial[kReductionBlocks];
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index b = 0; b < kReductionBlocks; ++b)
  {
    const Index begin = static_cast<Index>(static_cast<std::int64_t>(count) * b / kReductionBlocks);
    const Index end = static_cast<Index>(static_cast<std::int64_t>(count) * (b + 1) / kReductionBlocks);
    double      sum = 0.0;
    for (Index i = begin; i < end; ++i)
    {
      sum += term(i);
    }
    partial[b] = sum;
  }
  double total = 0.0;
  for (const double p : partial)
  {
    total += p;
  }
  return total;
}

// Size of one step's change of the displacements, in one pass over the dofs:
// largest and root-sum-square increment, and the first unconstrained dof whose
// increment is not finite or larger than `limit`.
struct IncrementStatistics
{
  double maxAbs = 0.0;
  double norm = 0.0;
  Index  firstBad = -1;
};

// `increment(d)` returns |du| of dof d (and may write the dof's new value):
// fixed blocks, so the sums do not depend on the number of threads.
template <typename Increment>
inline IncrementStatistics
MeasureIncrements(Index count, const std::vector<char> & constrained, double limit, int threads, const Increment & increment)
{
  double      maxima[kReductionBlocks], sums[kReductionBlocks];
  Index       bad[kReductionBlocks];
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index b = 0; b < kReductionBlocks; ++b)
  {
    const Index begin = static_cast<Index>(static_cast<std::int64_t>(count) * b / kReductionBlocks);
    const Index end = static_cast<Index>(static_cast<std::int64_t>(count) * (b + 1) / kReductionBlocks);
    double      largest = 0.0, sum = 0.0;
    Index       firstBad = -1;
    for (Index d = begin; d < end; ++d)
    {
      const double du = increment(d);
      // A prescribed jump is the user's load, not instability.
      if (!(du <= limit) && firstBad < 0 && !constrained[d])
      {
        firstBad = d;
      }
      largest = std::max(largest, du);
      sum += du * du;
    }
    maxima[b] = largest;
    sums[b] = sum;
    bad[b] = firstBad;
  }
  IncrementStatistics statistics;
  for (Index b = 0; b < kReductionBlocks; ++b)
  {
    statistics.maxAbs = std::max(statistics.maxAbs, maxima[b]);
    statistics.norm += sums[b];
    if (statistics.firstBad < 0)
    {
      statistics.firstBad = bad[b];
    }
  }
  statistics.norm = std::sqrt(statistics.norm);
  return statistics;
}

inline IncrementStatistics
MeasureIncrement(const std::vector<double> & next,
                 const std::vector<double> & current,
                 const std::vector<char> &   constrained,
                 double                      limit,
                 int                         threads)
{
  return MeasureIncrements(static_cast<Index>(next.size()), constrained, limit, threads,
                           [&](Index d) { return std::abs(next[d] - current[d]); });
}

} // namespace bmr

#endif
