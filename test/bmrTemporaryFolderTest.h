// Test fixture with a fresh folder per test, removed afterwards.
#ifndef bmrTemporaryFolderTest_h
#define bmrTemporaryFolderTest_h

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <unistd.h>

namespace bmr
{
namespace test
{

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
