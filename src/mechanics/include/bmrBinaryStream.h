// Binary files of the core's data: little-endian values in the order
// written, no padding, every count checked against the bytes left when read.
// The model bundle's model.bin, precomputation.bin and an update's
// solution.bin are written with these.
#ifndef bmrBinaryStream_h
#define bmrBinaryStream_h

#include "bmrModel.h"

#include <cstdint>
#include <cstring>
#include <string>
#include <type_traits>
#include <vector>

namespace bmr
{

/** Whether T is a std::vector (the members' dispatch below). */
template <typename T>
struct IsVector : std::false_type
{};
template <typename T, typename A>
struct IsVector<std::vector<T, A>> : std::true_type
{};

class BinaryWriter
{
public:
  template <typename T>
  void Value(const T & value)
  {
    static_assert(std::is_trivially_copyable_v<T>);
    m_Bytes.append(reinterpret_cast<const char *>(&value), sizeof(T));
  }
  void Text(const std::string & text)
  {
    Value<std::uint64_t>(text.size());
    m_Bytes.append(text);
  }
  template <typename T>
  void Values(const std::vector<T> & values)
  {
    static_assert(std::is_trivially_copyable_v<T>);
    Value<std::uint64_t>(values.size());
    m_Bytes.append(reinterpret_cast<const char *>(values.data()), values.size() * sizeof(T));
  }
  void Points(const std::vector<Vector3> & points)
  {
    Value<std::uint64_t>(points.size());
    for (const Vector3 & p : points)
    {
      Value(p.x());
      Value(p.y());
      Value(p.z());
    }
  }
  /** One member of a class that lists its members to a visitor (a value, a
   *  vector of values or points, or an object with VisitMembers). */
  template <typename T>
  void operator()(const T & member)
  {
    if constexpr (std::is_same_v<T, std::vector<Vector3>>)
    {
      Points(member);
    }
    else if constexpr (std::is_trivially_copyable_v<T>)
    {
      Value(member);
    }
    else if constexpr (IsVector<T>::value)
    {
      Values(member);
    }
    else
    {
      T::VisitMembers(member, *this);
    }
  }
  const std::string & Bytes() const { return m_Bytes; }

private:
  std::string m_Bytes;
};

class BinaryReader
{
public:
  /** `what`: the file in words; `advice`: what to do about a damaged file. */
  BinaryReader(std::string bytes, std::string what, std::string advice)
    : m_Bytes(std::move(bytes))
    , m_What(std::move(what))
    , m_Advice(std::move(advice))
  {}
  template <typename T>
  T Value()
  {
    static_assert(std::is_trivially_copyable_v<T>);
    T value;
    Need(sizeof(T));
    std::memcpy(&value, m_Bytes.data() + m_Offset, sizeof(T));
    m_Offset += sizeof(T);
    return value;
  }
  std::string Text()
  {
    const auto size = Count(1);
    std::string text = m_Bytes.substr(m_Offset, size);
    m_Offset += size;
    return text;
  }
  template <typename T>
  std::vector<T> Values()
  {
    static_assert(std::is_trivially_copyable_v<T>);
    const auto     size = Count(sizeof(T));
    std::vector<T> values(size);
    if (size > 0)
    {
      std::memcpy(values.data(), m_Bytes.data() + m_Offset, size * sizeof(T));
    }
    m_Offset += size * sizeof(T);
    return values;
  }
  std::vector<Vector3> Points()
  {
    const auto           size = Count(3 * sizeof(double));
    std::vector<Vector3> points(size);
    for (Vector3 & p : points)
    {
      p.x() = Value<double>();
      p.y() = Value<double>();
      p.z() = Value<double>();
    }
    return points;
  }
  /** The inverse of BinaryWriter::operator(). */
  template <typename T>
  void operator()(T & member)
  {
    if constexpr (std::is_same_v<T, std::vector<Vector3>>)
    {
      member = Points();
    }
    else if constexpr (std::is_trivially_copyable_v<T>)
    {
      member = Value<T>();
    }
    else if constexpr (IsVector<T>::value)
    {
      member = Values<typename T::value_type>();
    }
    else
    {
      T::VisitMembers(member, *this);
    }
  }
  bool AtEnd() const { return m_Offset == m_Bytes.size(); }
  [[noreturn]] void Fail(const std::string & why) const
  {
    throw Error(m_What + " is damaged (" + why + " at byte " + std::to_string(m_Offset) + "); " + m_Advice);
  }
  /** A count of items of at least `bytesEach` bytes each that the rest of the file can hold. */
  std::size_t Count(std::size_t bytesEach)
  {
    const auto count = Value<std::uint64_t>();
    if (bytesEach > 0 && count > (m_Bytes.size() - m_Offset) / bytesEach)
    {
      Fail("a count of " + std::to_string(count) + " beyond the file's end");
    }
    return static_cast<std::size_t>(count);
  }

private:
  void Need(std::size_t bytes) const
  {
    if (m_Bytes.size() - m_Offset < bytes)
    {
      Fail("the file ends early");
    }
  }

  std::string m_Bytes;
  std::string m_What;
  std::string m_Advice;
  std::size_t m_Offset = 0;
};

} // namespace bmr

#endif
