// Test fixture with a fresh folder per test, removed afterwards, and the
// error-message helpers of the file and scene tests.
#ifndef bmrTemporaryFolderTest_h
#define bmrTemporaryFolderTest_h

#include <gtest/gtest.h>

#include <algorithm>
#include "bmrModel.h"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>
#include <sys/wait.h>
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

inline std::string
ReadText(const std::filesystem::path & path)
{
  std::ifstream stream(path);
  return std::string((std::istreambuf_iterator<char>(stream)), std::istreambuf_iterator<char>());
}

/** Exit status and output of a run of the biomech command-line tool. */
struct CommandResult
{
  int         exitCode = -1;
  std::string out;
  std::string err;
};

/** Runs `biomech ARGUMENTS` (arguments already quoted for the shell), with
 *  its output captured through files in `folder`. */
inline CommandResult
RunBiomech(const std::filesystem::path & folder, const std::string & arguments)
{
  const std::filesystem::path outPath = folder / "stdout.txt";
  const std::filesystem::path errPath = folder / "stderr.txt";
  const std::string command = std::string("'") + BMR_BIOMECH_EXECUTABLE + "' " + arguments + " > '" +
                              outPath.string() + "' 2> '" + errPath.string() + "' < /dev/null";
  const int     status = std::system(command.c_str());
  CommandResult result;
  result.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  result.out = ReadText(outPath);
  result.err = ReadText(errPath);
  std::filesystem::remove(outPath);
  std::filesystem::remove(errPath);
  return result;
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
