// Reading and writing the module's transforms with ITK's transform IO, so
// that 3D Slicer and other ITK programs read them: HDF5 (.h5, .hdf5) or the
// legacy text format (.tfm, .txt). Writing goes through a temporary file in
// the same folder and a rename, so a failed write never leaves a file that
// passes for a result.
#ifndef itkBiomechanicalTransformIO_h
#define itkBiomechanicalTransformIO_h

#include "itkBiomechanicalImageIO.h"
#include "itkTransformBase.h"
#include "itkTransformFileReader.h"
#include "itkTransformFileWriter.h"

#include <cstdio>
#include <filesystem>
#include <string>
#include <unistd.h>

namespace itk
{

/** Writes one transform (double precision) to `path` (.h5, .hdf5, .tfm or
 * .txt). Throws ExceptionObject naming the file when the extension is not one
 * of these or the write fails; no file is left behind then. */
inline void
WriteBiomechanicalTransform(const TransformBaseTemplate<double> * transform, const std::string & path)
{
  const std::filesystem::path target(path);
  const std::string           extension = target.extension().string();
  if (extension != ".h5" && extension != ".hdf5" && extension != ".tfm" && extension != ".txt")
  {
    itkGenericExceptionMacro("cannot write transform '" << path << "': the extension must be .h5 or .hdf5 (HDF5) or "
                                                        << ".tfm or .txt (ITK text)");
  }
  try
  {
    bmr::WriteAtomically(target, "transform", [&](const std::string & temporary) {
      auto writer = TransformFileWriterTemplate<double>::New();
      writer->SetInput(transform);
      writer->SetFileName(temporary);
      writer->Update();
    });
  }
  catch (const ExceptionObject & exception)
  {
    itkGenericExceptionMacro("cannot write transform '" << path << "': " << exception.GetDescription());
  }
  catch (const bmr::Error & error)
  {
    itkGenericExceptionMacro(<< error.what());
  }
}

/** Reads the single transform stored in `path`. Throws ExceptionObject naming
 * the file when it is missing, unreadable or holds no or several transforms
 * (a composite transform counts as one). */
inline TransformBaseTemplate<double>::Pointer
ReadBiomechanicalTransform(const std::string & path)
{
  std::error_code error;
  if (!std::filesystem::is_regular_file(path, error))
  {
    itkGenericExceptionMacro("cannot read transform '" << path << "': no such file");
  }
  auto reader = TransformFileReaderTemplate<double>::New();
  reader->SetFileName(path);
  std::string failure;
  try
  {
    reader->Update();
  }
  catch (const ExceptionObject & exception)
  {
    failure = PlainDescription(exception.GetDescription());
  }
  catch (const std::exception &)
  {
    // ITK's text transform reader throws std::out_of_range on some malformed lines.
    failure = "the file is damaged or not an ITK transform file (.h5, .hdf5, .tfm, .txt)";
  }
  if (!failure.empty())
  {
    // Constructed directly: itkGenericExceptionMacro would prefix "ITK ERROR: " to the description.
    throw ExceptionObject(__FILE__, __LINE__, "cannot read transform '" + path + "': " + failure, ITK_LOCATION);
  }
  const auto * list = reader->GetTransformList();
  if (list->size() != 1)
  {
    itkGenericExceptionMacro("cannot read transform '" << path << "': it holds " << list->size()
                                                       << " transforms; expected exactly one");
  }
  return list->front();
}

} // namespace itk

#endif
