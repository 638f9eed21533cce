// The one way the module writes a file: through a temporary file in the
// target's folder and a rename, so that a failed or interrupted write never
// leaves a half-written file under the target's name (nor the temporary).
#ifndef bmrAtomicWrite_h
#define bmrAtomicWrite_h

#include "bmrError.h"

#include <filesystem>
#include <string>
#include <system_error>
#include <unistd.h>

namespace bmr
{

/** Calls write(temporaryPath) and renames the finished file onto `path`.
 *  The temporary keeps the target's extension (ITK and VTK writers choose the
 *  format from it). `what` names the file in errors ("image", "transform",
 *  ...). Throws bmr::Error when the folder does not exist or the rename
 *  fails; an exception from `write` passes through; the temporary is removed
 *  in every failure. */
template <typename WriteFunction>
void
WriteAtomically(const std::filesystem::path & path, const std::string & what, WriteFunction && write)
{
  namespace fs = std::filesystem;
  const fs::path  folder = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::error_code error;
  if (!fs::is_directory(folder, error))
  {
    throw Error("cannot write " + what + " '" + path.string() + "': folder '" + folder.string() + "' does not exist");
  }
  const fs::path temporary = folder / (".tmp-" + std::to_string(::getpid()) + "-" + path.filename().string());
  try
  {
    write(temporary.string());
  }
  catch (...)
  {
    fs::remove(temporary, error);
    throw;
  }
  fs::rename(temporary, path, error);
  if (error)
  {
    const std::string reason = error.message();
    fs::remove(temporary, error);
    throw Error("cannot write " + what + " '" + path.string() + "': renaming the temporary file failed: " + reason);
  }
}

} // namespace bmr

#endif
