// Reading images with a message that names the file, and writing them
// through a temporary file and a rename (nothing half-written is left as a
// result); shared by the command-line tool and the registration pipeline.
#ifndef itkBiomechanicalImageIO_h
#define itkBiomechanicalImageIO_h

// ITK first: its bundled Eigen must be seen before the system Eigen the core includes.
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"

#include "bmrAtomicWrite.h"
#include "bmrModel.h"

#include <filesystem>
#include <iostream>
#include <regex>
#include <sstream>
#include <string>
#include <unistd.h>

namespace itk
{

/** An ITK exception's description as one plain line for a user: without the
 *  "ITK ERROR: Class(0x...): " prefixes, and ITK's several-line list of the IO
 *  classes it tried replaced by what it means. */
inline std::string
PlainDescription(const std::string & description)
{
  if (description.find("Could not create") != std::string::npos && description.find("IO") != std::string::npos &&
      description.find("Tried to create") != std::string::npos)
  {
    return "no ITK reader recognises the file: it is not in a supported format, or its extension does not match "
           "its content";
  }
  std::string text = std::regex_replace(description, std::regex("ITK ERROR: "), "");
  text = std::regex_replace(text, std::regex("[A-Za-z_:<>]+\\(0x[0-9a-fA-F]+\\): "), "");
  text = std::regex_replace(text, std::regex("\\s+"), " ");
  const auto first = text.find_first_not_of(' ');
  const auto last = text.find_last_not_of(' ');
  return first == std::string::npos ? std::string() : text.substr(first, last - first + 1);
}

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
  // MetaIO reports a file shorter than its header on std::cerr and reads on
  // (ITK 5.2): catch that text, so a truncated image is an error, not garbage.
  std::ostringstream   libraryOutput;
  std::streambuf *     console = std::cerr.rdbuf(libraryOutput.rdbuf());
  std::string          failure;
  try
  {
    reader->Update();
  }
  catch (const ExceptionObject & exception)
  {
    failure = PlainDescription(exception.GetDescription());
  }
  catch (const std::exception & exception)
  {
    failure = "the file is damaged or not an image in a supported format";
  }
  std::cerr.rdbuf(console);
  if (libraryOutput.str().find("not read completely") != std::string::npos)
  {
    failure = "the file holds fewer voxels than its header says (truncated?); write it again";
  }
  else if (failure.empty())
  {
    std::cerr << libraryOutput.str();
  }
  if (!failure.empty())
  {
    throw bmr::Error("cannot read " + what + " '" + path + "': " + failure);
  }
  return reader->GetOutput();
}

/** Writes an ITK image (compressed) through a temporary file in the same
 *  folder and a rename (bmr::WriteAtomically). Throws bmr::Error naming it. */
template <typename TImage>
void
WriteBiomechanicalImage(const TImage * image, const std::filesystem::path & path)
{
  bmr::WriteAtomically(path, "image", [&](const std::string & temporary) {
    auto writer = ImageFileWriter<TImage>::New();
    writer->SetInput(image);
    writer->SetFileName(temporary);
    writer->UseCompressionOn();
    try
    {
      writer->Update();
    }
    catch (const ExceptionObject & exception)
    {
      throw bmr::Error("cannot write image '" + path.string() + "': " + PlainDescription(exception.GetDescription()));
    }
  });
}

} // namespace itk

#endif
