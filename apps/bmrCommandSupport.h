// Helpers shared by the `biomech` subcommands that read and write images:
// reading with a message that names the file, writing through a temporary
// file (nothing half-written is left as a result), output folders, and the
// per-step wall-time record of a command's report.
#ifndef bmrCommandSupport_h
#define bmrCommandSupport_h

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalImageIO.h"
#include "itkImageFileWriter.h"
#include "itkImageIOFactory.h"

#include "bmrBrainShiftRegistration.h"
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

/** Wall time of the steps of a command, for the report; when verbose, says on
 *  stderr what runs and how long it took. */
class StepTimer : public StageTimer
{
public:
  explicit StepTimer(bool verbose)
    : StageTimer(verbose ? StageCallback(PrintStage) : StageCallback())
  {}

  static void PrintStage(const std::string & name, double seconds)
  {
    if (seconds < 0.0)
    {
      std::fprintf(stderr, "  %-14s ...", name.c_str());
    }
    else
    {
      std::fprintf(stderr, " %.2f s\n", seconds);
    }
    std::fflush(stderr);
  }
};

/** One updating line on a terminal; silent when stderr is a file or pipe. */
class TerminalProgress
{
public:
  explicit TerminalProgress(bool enabled)
    : m_Enabled(enabled)
  {}

  ~TerminalProgress() { Clear(); }

  void Update(int step, double fraction, double estimatedError)
  {
    if (!m_Enabled)
    {
      return;
    }
    const auto now = std::chrono::steady_clock::now();
    if (m_Shown && now - m_LastUpdate < std::chrono::milliseconds(200))
    {
      return;
    }
    m_LastUpdate = now;
    m_Shown = true;
    if (fraction >= 0.0)
    {
      std::fprintf(stderr, "\r  step %d  %5.1f %% of end time\033[K", step, 100.0 * fraction);
    }
    else
    {
      std::fprintf(stderr, "\r  step %d  estimated error %.3g mm\033[K", step, estimatedError);
    }
    std::fflush(stderr);
  }

  void Clear()
  {
    if (m_Enabled && m_Shown)
    {
      std::fprintf(stderr, "\r\033[K");
      std::fflush(stderr);
      m_Shown = false;
    }
  }

private:
  bool                                  m_Enabled;
  bool                                  m_Shown = false;
  std::chrono::steady_clock::time_point m_LastUpdate;
};

/** Reads an image (a DICOM series too: its folder or one of its files,
 *  `series` choosing among several); a missing or unreadable file is an
 *  Error naming `what` and the path. */
template <typename TImage>
typename TImage::Pointer
ReadImage(const std::string & path, const std::string & what, const std::string & series = {})
{
  return itk::ReadBiomechanicalImage<TImage>(path, what, series);
}

/** What an image file holds, without reading its pixels. */
struct ImageFileInfo
{
  unsigned int         dimension = 0;
  itk::IOComponentEnum component = itk::IOComponentEnum::UNKNOWNCOMPONENTTYPE;
  unsigned int         components = 1;
};

inline ImageFileInfo
ReadImageFileInfo(const std::string & path, const std::string & what)
{
  std::error_code error;
  if (!std::filesystem::is_regular_file(path, error))
  {
    throw Error("cannot read " + what + " '" + path + "': no such file");
  }
  const auto io = itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::IOFileModeEnum::ReadMode);
  if (io.IsNull())
  {
    throw Error("cannot read " + what + " '" + path +
                "': not an image format biomech reads (.nii, .nii.gz, .nrrd, .mha, "
                ".mhd, .png)");
  }
  io->SetFileName(path);
  try
  {
    io->ReadImageInformation();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error("cannot read " + what + " '" + path + "': " + itk::PlainDescription(exception.GetDescription()));
  }
  return ImageFileInfo{ io->GetNumberOfDimensions(), io->GetComponentType(), io->GetNumberOfComponents() };
}

/** A mask file as an image of 0 and 1: every voxel > 0 is inside (so a
 *  brain-extracted image such as ch2bet.nii.gz works as a mask). */
inline RegistrationLabelImage::Pointer
ReadMaskImage(const std::string & path, const std::string & what)
{
  return ThresholdMask(ReadImage<RegistrationImage>(path, what));
}

/** Writes an ITK image through a temporary file in the same folder and a rename. */
template <typename TImage>
void
WriteImageAtomically(const TImage * image, const std::filesystem::path & path)
{
  itk::WriteBiomechanicalImage(image, path);
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
