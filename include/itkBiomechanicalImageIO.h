// Reading images with a message that names the file, and writing them
// through a temporary file and a rename (nothing half-written is left as a
// result); shared by the command-line tool and the registration pipeline.
#ifndef itkBiomechanicalImageIO_h
#define itkBiomechanicalImageIO_h

// ITK first: its bundled Eigen must be seen before the system Eigen the core includes.
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"

#include "bmrModel.h"

#include <filesystem>
#include <string>
#include <unistd.h>

namespace itk
{

/** Reads an image; a missing or unreadable file is a bmr::Error naming `what` and the path. */
template <typename TImage>
typename TImage::Pointer
ReadBiomechanicalImage(const std::string & path, const std::string & what)
{
  std::error_code error;
  if (!std::filesystem::is_regular_file(path, error))
  {
    throw bmr::Error("cannot read " + what + " '" + path + "': no such file");
  }
  auto reader = ImageFileReader<TImage>::New();
  reader->SetFileName(path);
  try
  {
    reader->Update();
  }
  catch (const ExceptionObject & exception)
  {
    throw bmr::Error("cannot read " + what + " '" + path + "': " + exception.GetDescription());
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
    throw bmr::Error("cannot write '" + path.string() + "': renaming the temporary file failed: " + error.message());
  }
}

/** Writes an ITK image through a temporary file in the same folder and a rename. */
template <typename TImage>
void
WriteBiomechanicalImage(const TImage * image, const std::filesystem::path & path)
{
  const std::filesystem::path temporary = TemporaryPathFor(path);
  auto                        writer = ImageFileWriter<TImage>::New();
  writer->SetInput(image);
  writer->SetFileName(temporary.string());
  writer->UseCompressionOn();
  try
  {
    writer->Update();
  }
  catch (const ExceptionObject & exception)
  {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw bmr::Error("cannot write image '" + path.string() + "': " + exception.GetDescription());
  }
  MoveIntoPlace(temporary, path);
}

} // namespace itk

#endif
