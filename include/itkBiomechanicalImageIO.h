// Reading images with a message that names the file (a DICOM series too,
// given as its folder or one of its files), and writing them through a
// temporary file and a rename (nothing half-written is left as a result);
// shared by the command-line tool, the registration pipeline and Python.
#ifndef itkBiomechanicalImageIO_h
#define itkBiomechanicalImageIO_h

// ITK first: its bundled Eigen must be seen before the system Eigen the core includes.
#include "itkGDCMImageIO.h"
#include "itkGDCMSeriesFileNames.h"
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"
#include "itkImageSeriesReader.h"
#include "itk_zlib.h"

#include "bmrAtomicWrite.h"
#include "bmrModel.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <regex>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

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

/** The DICOM series an image path stands for: a folder, or one file of a
 *  series (its neighbours in the same folder with the same series are read
 *  with it). `files` in slice order (GDCM's sort by image position). */
struct BiomechanicalDicomSeries
{
  std::string              uid;          // GDCM's series identifier (the Series Instance UID, then details)
  std::vector<std::string> files;
  std::size_t              seriesInFolder = 0;
};

/** True when `path` is a folder, or a file that GDCM reads as DICOM. */
inline bool
IsBiomechanicalDicomPath(const std::string & path)
{
  std::error_code error;
  if (std::filesystem::is_directory(path, error))
  {
    return true;
  }
  auto io = GDCMImageIO::New();
  return std::filesystem::is_regular_file(path, error) && io->CanReadFile(path.c_str());
}

/** Chooses the series of `path` (IsBiomechanicalDicomPath): the one named by
 *  `seriesUid` (its Series Instance UID, or GDCM's identifier), else the
 *  file's own series, else the folder's series with most slices. Throws
 *  bmr::Error naming `what` when the folder holds no image series or the
 *  named one. Series are told apart by GDCM's series details (orientation,
 *  size...), so a localiser in the same Series Instance UID is not mixed in. */
inline BiomechanicalDicomSeries
ChooseBiomechanicalDicomSeries(const std::string & path, const std::string & what, const std::string & seriesUid = {})
{
  std::error_code       error;
  const bool            folder = std::filesystem::is_directory(path, error);
  const std::string     directory = folder ? path : std::filesystem::path(path).parent_path().string();
  std::string           wanted = seriesUid;
  if (!folder && wanted.empty())
  {
    auto io = GDCMImageIO::New();
    io->SetFileName(path);
    try
    {
      io->ReadImageInformation();
    }
    catch (const ExceptionObject & exception)
    {
      throw bmr::Error("cannot read " + what + " '" + path + "': " + PlainDescription(exception.GetDescription()));
    }
    io->GetValueFromTag("0020|000e", wanted);
    while (!wanted.empty() && (wanted.back() == ' ' || wanted.back() == '\0'))
    {
      wanted.pop_back();
    }
  }
  auto names = GDCMSeriesFileNames::New();
  names->SetUseSeriesDetails(true);
  names->SetGlobalWarningDisplay(false);
  names->SetDirectory(directory.empty() ? std::string(".") : directory);
  const std::vector<std::string> uids = names->GetSeriesUIDs();
  if (uids.empty())
  {
    throw bmr::Error("cannot read " + what + " '" + path + "': the folder '" + directory +
                     "' holds no DICOM image series; give the folder of the series (or one of its files), or an "
                     "image file (NIfTI, NRRD, MetaImage)");
  }
  BiomechanicalDicomSeries chosen;
  chosen.seriesInFolder = uids.size();
  for (const std::string & uid : uids)
  {
    // GDCM's identifier is the Series Instance UID followed by the details.
    if (!wanted.empty() && uid.rfind(wanted, 0) != 0)
    {
      continue;
    }
    std::vector<std::string> files = names->GetFileNames(uid);
    const bool holdsFile = folder || std::any_of(files.begin(), files.end(), [&](const std::string & file) {
                             return std::filesystem::equivalent(file, path, error);
                           });
    if (holdsFile && files.size() > chosen.files.size())
    {
      chosen.uid = uid;
      chosen.files = std::move(files);
    }
  }
  if (chosen.files.empty())
  {
    std::ostringstream message;
    message << "cannot read " << what << " '" << path << "': the folder holds no DICOM series '" << wanted
            << "'; its series are:";
    for (const std::string & uid : uids)
    {
      message << " " << uid << " (" << names->GetFileNames(uid).size() << " files)";
    }
    message << ". Choose one with --series UID";
    throw bmr::Error(message.str());
  }
  return chosen;
}

/** Reads a DICOM series (ChooseBiomechanicalDicomSeries) with ITK's GDCM
 *  series reader: the scanner geometry kept (origin and direction cosines of
 *  the first slice, the slice spacing from the slices' positions). When the
 *  folder holds several series, says on std::clog which was read. */
template <typename TImage>
typename TImage::Pointer
ReadBiomechanicalDicomSeries(const std::string & path, const std::string & what, const std::string & seriesUid = {})
{
  const BiomechanicalDicomSeries series = ChooseBiomechanicalDicomSeries(path, what, seriesUid);
  if (series.seriesInFolder > 1)
  {
    std::clog << what << ": read DICOM series " << series.uid << " (" << series.files.size() << " slices), one of the "
              << series.seriesInFolder << " series in the folder" << (seriesUid.empty() ? " (the one with most slices or of the file given; choose another with --series UID)" : "") << "\n";
  }
  auto reader = ImageSeriesReader<TImage>::New();
  reader->SetImageIO(GDCMImageIO::New());
  reader->SetFileNames(series.files);
  try
  {
    reader->Update();
  }
  catch (const ExceptionObject & exception)
  {
    throw bmr::Error("cannot read " + what + " '" + path + "' (DICOM series " + series.uid + "): " +
                     PlainDescription(exception.GetDescription()));
  }
  return reader->GetOutput();
}

/** Reads an image; a missing or unreadable file is a bmr::Error naming `what`
 *  and the path. A folder, or a DICOM file, is read as a DICOM series
 *  (ReadBiomechanicalDicomSeries; `seriesUid` chooses among several). */
template <typename TImage>
typename TImage::Pointer
ReadBiomechanicalImage(const std::string & path, const std::string & what, const std::string & seriesUid = {})
{
  std::error_code error;
  if (std::filesystem::is_directory(path, error))
  {
    return ReadBiomechanicalDicomSeries<TImage>(path, what, seriesUid);
  }
  if (!std::filesystem::is_regular_file(path, error))
  {
    throw bmr::Error("cannot read " + what + " '" + path + "': no such file");
  }
  if (IsBiomechanicalDicomPath(path))
  {
    return ReadBiomechanicalDicomSeries<TImage>(path, what, seriesUid);
  }
  if (!seriesUid.empty())
  {
    throw bmr::Error("cannot read " + what + " '" + path + "': a series (" + seriesUid +
                     ") is chosen, but the file is not DICOM; give the series' folder or leave out --series");
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

/** Copies the file `source` gzip-compressed at zlib level `level` (1:
 *  fastest ... 9: smallest) to `target`. Throws bmr::Error naming both. */
inline void
GzipBiomechanicalFile(const std::string & source, const std::string & target, int level)
{
  std::ifstream input(source, std::ios::binary);
  gzFile        output = gzopen(target.c_str(), ("wb" + std::to_string(level)).c_str());
  if (!input || output == nullptr)
  {
    if (output != nullptr)
    {
      gzclose(output);
    }
    throw bmr::Error("cannot compress '" + source + "' into '" + target + "': " +
                     (input ? "the target cannot be opened" : "the source cannot be read"));
  }
  std::vector<char> buffer(1 << 20);
  bool              written = true;
  while (written && input)
  {
    input.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    const auto count = static_cast<unsigned>(input.gcount());
    written = count == 0 || gzwrite(output, buffer.data(), count) == static_cast<int>(count);
  }
  const bool closed = gzclose(output) == Z_OK;
  if (!written || !closed || input.bad())
  {
    throw bmr::Error("cannot compress '" + source + "' into '" + target + "': writing failed (disk full?)");
  }
}

/** Writes an ITK image (compressed) through a temporary file in the same
 *  folder and a rename (bmr::WriteAtomically). Throws bmr::Error naming it.
 *  A .nii.gz is written uncompressed, then gzip-compressed at zlib's fastest
 *  level: ITK 5.2's NIfTI writer compresses at zlib's default level and lets
 *  no caller change it, which took about 1 s of `biomech model` for Colin27's
 *  85 MB of memberships (level 1: 0.26 s instead of 1.08 s for a file a fifth
 *  larger); readers see an ordinary .nii.gz. */
template <typename TImage>
void
WriteBiomechanicalImage(const TImage * image, const std::filesystem::path & path)
{
  const std::string name = path.filename().string();
  const bool        niftiGz = name.size() > 7 && name.compare(name.size() - 7, 7, ".nii.gz") == 0;
  bmr::WriteAtomically(path, "image", [&](const std::string & temporary) {
    const std::string uncompressed = niftiGz ? temporary.substr(0, temporary.size() - 3) : temporary;
    // WriteAtomically removes its temporary after a failure; the uncompressed file is ours.
    const auto removeUncompressed = [&] {
      std::error_code ignored;
      if (niftiGz)
      {
        std::filesystem::remove(uncompressed, ignored);
      }
    };
    auto writer = ImageFileWriter<TImage>::New();
    writer->SetInput(image);
    writer->SetFileName(uncompressed);
    writer->SetUseCompression(!niftiGz);
    try
    {
      writer->Update();
      if (niftiGz)
      {
        GzipBiomechanicalFile(uncompressed, temporary, 1);
        std::filesystem::remove(uncompressed);
      }
    }
    catch (const ExceptionObject & exception)
    {
      removeUncompressed();
      throw bmr::Error("cannot write image '" + path.string() + "': " + PlainDescription(exception.GetDescription()));
    }
    catch (...)
    {
      removeUncompressed();
      throw;
    }
  });
}

} // namespace itk

#endif
