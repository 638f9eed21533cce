// Helpers shared by the `biomech` subcommands that read and write images:
// reading with a message that names the file, writing through a temporary
// file (nothing half-written is left as a result), output folders, and the
// per-step wall-time record of a command's report.
#ifndef bmrCommandSupport_h
#define bmrCommandSupport_h

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"

#include "bmrModel.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <type_traits>
#include <unistd.h>
#include <utility>
#include <vector>

namespace bmr
{
namespace app
{

/** Wall time of the steps of a command, for the report and the printed table. */
class StepTimer
{
public:
  explicit StepTimer(bool verbose)
    : m_Verbose(verbose)
  {}

  /** Runs `step`, records its time and, when verbose, says what runs on stderr. */
  template <typename Step>
  auto Run(const std::string & name, Step && step)
  {
    if (m_Verbose)
    {
      std::fprintf(stderr, "  %-14s ...", name.c_str());
      std::fflush(stderr);
    }
    const auto start = std::chrono::steady_clock::now();
    auto       finish = [&] {
      const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      m_Seconds.emplace_back(name, seconds);
      if (m_Verbose)
      {
        std::fprintf(stderr, " %.2f s\n", seconds);
      }
    };
    if constexpr (std::is_void_v<decltype(step())>)
    {
      step();
      finish();
    }
    else
    {
      auto result = step();
      finish();
      return result;
    }
  }

  nlohmann::json Json() const
  {
    nlohmann::json times = nlohmann::json::object();
    double         total = 0.0;
    for (const auto & [name, seconds] : m_Seconds)
    {
      times[name] = seconds;
      total += seconds;
    }
    times["total"] = total;
    return times;
  }

private:
  bool                                        m_Verbose;
  std::vector<std::pair<std::string, double>> m_Seconds;
};

/** Reads an image; a missing or unreadable file is an Error naming `what` and the path. */
template <typename TImage>
typename TImage::Pointer
ReadImage(const std::string & path, const std::string & what)
{
  std::error_code error;
  if (!std::filesystem::is_regular_file(path, error))
  {
    throw Error("cannot read " + what + " '" + path + "': no such file");
  }
  auto reader = itk::ImageFileReader<TImage>::New();
  reader->SetFileName(path);
  try
  {
    reader->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error("cannot read " + what + " '" + path + "': " + exception.GetDescription());
  }
  return reader->GetOutput();
}

/** A temporary name in the folder of `path`, for writing and then renaming. */
inline std::filesystem::path
TemporaryPathFor(const std::filesystem::path & path)
{
  return path.parent_path() / (".tmp-" + std::to_string(::getpid()) + "-" + path.filename().string());
}

/** Renames a finished temporary file onto `path`; removes it and throws when that fails. */
inline void
MoveIntoPlace(const std::filesystem::path & temporary, const std::filesystem::path & path)
{
  std::error_code error;
  std::filesystem::rename(temporary, path, error);
  if (error)
  {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw Error("cannot write '" + path.string() + "': renaming the temporary file failed: " + error.message());
  }
}

/** Writes an ITK image through a temporary file in the same folder and a rename. */
template <typename TImage>
void
WriteImageAtomically(const TImage * image, const std::filesystem::path & path)
{
  const std::filesystem::path temporary = TemporaryPathFor(path);
  auto                        writer = itk::ImageFileWriter<TImage>::New();
  writer->SetInput(image);
  writer->SetFileName(temporary.string());
  writer->UseCompressionOn();
  try
  {
    writer->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw Error("cannot write image '" + path.string() + "': " + exception.GetDescription());
  }
  MoveIntoPlace(temporary, path);
}

/** Creates `folder` (and its parents); throws naming it when that fails. */
inline void
CreateFolder(const std::filesystem::path & folder)
{
  std::error_code error;
  std::filesystem::create_directories(folder, error);
  if (error || !std::filesystem::is_directory(folder))
  {
    throw Error("cannot create output folder '" + folder.string() + "'" + (error ? ": " + error.message() : ""));
  }
}

/** Creates the folder a file will be written to. */
inline void
CreateParentFolder(const std::filesystem::path & path)
{
  CreateFolder(path.has_parent_path() ? path.parent_path() : std::filesystem::path("."));
}

} // namespace app
} // namespace bmr

#endif
