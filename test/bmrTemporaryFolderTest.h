// Test fixture with a fresh folder per test, removed afterwards, and the
// error-message helpers of the file and scene tests.
#ifndef bmrTemporaryFolderTest_h
#define bmrTemporaryFolderTest_h

#include <gtest/gtest.h>

#include <algorithm>
#include "bmrModel.h"

#include <filesystem>
#include <functional>
#include <string>
#include <unistd.h>

#define EXPECT_CONTAINS(text, part) EXPECT_NE(std::string(text).find(part), std::string::npos) << "message: " << (text)

namespace bmr
{
namespace test
{

/** The message of the bmr::Error that `action` throws, or a note that it threw none. */
inline std::string
ErrorMessage(const std::function<void()> & action)
{
  try
  {
    action();
  }
  catch (const bmr::Error & error)
  {
    return error.what();
  }
  return "(no bmr::Error thrown)";
}

class TemporaryFolderTest : public ::testing::Test
{
protected:
  void SetUp() override
  {
    const auto * info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string  name = std::string(info->test_suite_name()) + "-" + info->name();
    std::replace(name.begin(), name.end(), '/', '_'); // parameterised test names
    m_Folder = std::filesystem::temp_directory_path() / ("bmr-" + name + "-" + std::to_string(::getpid()));
    std::filesystem::remove_all(m_Folder);
    std::filesystem::create_directories(m_Folder);
  }
  void TearDown() override { std::filesystem::remove_all(m_Folder); }

  std::filesystem::path m_Folder;
};

} // namespace test
} // namespace bmr

#endif
