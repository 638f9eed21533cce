// The worker-thread count of the core's OpenMP loops.
#ifndef bmrThreads_h
#define bmrThreads_h

#include <omp.h>

namespace bmr
{

/** `threads` when positive, else OpenMP's default (OMP_NUM_THREADS or all cores). */
inline int
ThreadCount(int threads)
{
  return threads > 0 ? threads : omp_get_max_threads();
}

} // namespace bmr

#endif
