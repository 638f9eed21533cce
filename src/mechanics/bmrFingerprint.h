// A 64-bit FNV-1a fingerprint over 64-bit words: the precomputation's key of
// its model (SolverPrecomputation: stored in bundles, so its words must not
// change) and the contacts' key of their surfaces (RigidContact::SharedTree).
// Private to the core.
#ifndef bmrFingerprint_h
#define bmrFingerprint_h

#include "bmrModel.h"

#include <cstdint>
#include <cstring>
#include <type_traits>

namespace bmr
{

/** 64-bit FNV-1a over 64-bit words: each value of up to 8 bytes is one word. */
class Fingerprint
{
public:
  template <typename T>
  void Add(const T & value)
  {
    static_assert(std::is_trivially_copyable_v<T> && sizeof(T) <= sizeof(std::uint64_t));
    std::uint64_t word = 0;
    std::memcpy(&word, &value, sizeof(T));
    m_Hash = (m_Hash ^ word) * 1099511628211ull;
  }
  void Add(const Vector3 & point)
  {
    Add(point.x());
    Add(point.y());
    Add(point.z());
  }
  std::uint64_t Value() const { return m_Hash; }

private:
  std::uint64_t m_Hash = 14695981039346656037ull;
};

} // namespace bmr

#endif
