// The intensity-registration peers (bmrElastixPeer.h).
#include "bmrElastixPeer.h"

#include "itkCastImageFilter.h"

#include "bmrCommandSupport.h"
#include "bmrMeshIO.h"

#include <cerrno>
#include <cmath>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <fstream>
#include <regex>
#include <sstream>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

extern char ** environ;

namespace fs = std::filesystem;

namespace bmr
{
namespace app
{
namespace
{

using DisplacementField = itk::DisplacementFieldTransform<double, 3>::DisplacementFieldType;

/** A displacement field image (3-vectors of floats or doubles), in double precision. */
DisplacementField::Pointer
ReadDisplacementField(const std::string & path, const std::string & what)
{
  auto cast = itk::CastImageFilter<itk::Image<itk::Vector<float, 3>, 3>, DisplacementField>::New();
  cast->SetInput(ReadImage<itk::Image<itk::Vector<float, 3>, 3>>(path, what));
  cast->Update();
  return cast->GetOutput();
}

itk::DisplacementFieldTransform<double, 3>::Pointer
FieldTransform(DisplacementField * field)
{
  auto transform = itk::DisplacementFieldTransform<double, 3>::New();
  transform->SetDisplacementField(field);
  return transform;
}

/** Runs `arguments` (arguments[0] found on PATH), its output into `log`;
 *  throws Error naming the program, its exit and the log's last lines. */
void
RunProgram(const std::vector<std::string> & arguments, const fs::path & log, const std::string & install)
{
  std::vector<char *> argv;
  for (const std::string & argument : arguments)
  {
    argv.push_back(const_cast<char *>(argument.c_str()));
  }
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
  pid_t     child = 0;
  const int spawned = posix_spawnp(&child, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (spawned != 0)
  {
    throw Error("cannot run " + arguments[0] + " (" + std::strerror(spawned) + "); " + install);
  }
  int status = 0;
  while (::waitpid(child, &status, 0) < 0 && errno == EINTR)
  {
  }
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
  {
    std::ifstream           file(log);
    std::deque<std::string> tail;
    for (std::string line; std::getline(file, line);)
    {
      if (line.find_first_not_of(" \t\r") == std::string::npos)
      {
        continue;
      }
      tail.push_back(line);
      if (tail.size() > 8)
      {
        tail.pop_front();
      }
    }
    std::string last; // one line, as every error of biomech
    for (const std::string & line : tail)
    {
      last += (last.empty() ? " " : " | ") + line;
    }
    throw Error(arguments[0] + " failed (" +
                (WIFEXITED(status) ? "exit status " + std::to_string(WEXITSTATUS(status))
                                   : "signal " + std::to_string(WTERMSIG(status))) +
                "); its log " + log.string() + " ends:" + last);
  }
}

} // namespace

bool
OnPath(const std::string & program)
{
  const char *      path = std::getenv("PATH");
  std::stringstream folders(path != nullptr ? path : "");
  for (std::string folder; std::getline(folders, folder, ':');)
  {
    if (!folder.empty() && ::access((fs::path(folder) / program).c_str(), X_OK) == 0)
    {
      return true;
    }
  }
  return false;
}

std::vector<std::string>
DefaultElastixParameters()
{
  std::error_code  ignored;
  const fs::path   executable = fs::read_symlink("/proc/self/exe", ignored);
  for (const fs::path & folder : { executable.parent_path().parent_path() / "share" / "BiomechanicalRegistration" / "elastix",
                                   fs::path(BMR_ELASTIX_PARAMETERS_DIR) })
  {
    if (fs::exists(folder / "affine.txt") && fs::exists(folder / "bspline.txt"))
    {
      return { (folder / "affine.txt").string(), (folder / "bspline.txt").string() };
    }
  }
  throw Error("the elastix parameter files (affine.txt, bspline.txt) are not installed; give them with "
              "--elastix-parameters");
}

IntensityPeer
RegisterWithElastix(const fs::path & fixed, const fs::path & moving, const fs::path & fixedMask,
                    const std::vector<std::string> & parameterFiles, const RegistrationImage * preoperativeGrid,
                    const fs::path & folder, int threads)
{
  const std::string install = "install Debian's elastix (scripts/install-dependencies.sh) or leave out --elastix";
  std::error_code   ignored;
  fs::remove_all(folder, ignored);
  CreateFolder(folder);
  // Absolute: the last stage's parameters name the first's file by this folder.
  const fs::path out = fs::absolute(folder);
  std::vector<std::string> elastix{ "elastix", "-f", fixed.string(), "-m", moving.string(), "-fMask",
                                    fixedMask.string(), "-out", out.string() };
  for (const std::string & file : parameterFiles)
  {
    if (!fs::exists(file))
    {
      throw Error("elastix parameter file " + file + " does not exist");
    }
    elastix.insert(elastix.end(), { "-p", file });
  }
  std::vector<std::string> threading;
  if (threads > 0)
  {
    threading = { "-threads", std::to_string(threads) };
  }
  elastix.insert(elastix.end(), threading.begin(), threading.end());
  IntensityPeer peer;
  auto        start = std::chrono::steady_clock::now();
  RunProgram(elastix, out / "elastix-output.txt", install);
  peer.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  // The last stage's parameters hold the chain; a copy with the preoperative
  // grid's origin, size and spacing gives the field there (same directions).
  const fs::path transform = out / ("TransformParameters." + std::to_string(parameterFiles.size() - 1) + ".txt");
  std::ifstream  in(transform);
  std::string    text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto     vector3 = [](const auto & values) {
    std::ostringstream line;
    line.precision(17);
    line << values[0] << " " << values[1] << " " << values[2];
    return line.str();
  };
  text = std::regex_replace(text, std::regex(R"(\(Size [^)]*\))"),
                            "(Size " + vector3(preoperativeGrid->GetLargestPossibleRegion().GetSize()) + ")");
  text = std::regex_replace(text, std::regex(R"(\(Spacing [^)]*\))"), "(Spacing " + vector3(preoperativeGrid->GetSpacing()) + ")");
  text = std::regex_replace(text, std::regex(R"(\(Origin [^)]*\))"), "(Origin " + vector3(preoperativeGrid->GetOrigin()) + ")");
  const fs::path onPreoperativeGrid = out / "TransformParameters.preoperative-grid.txt";
  WriteTextFileAtomically(onPreoperativeGrid.string(), text);

  start = std::chrono::steady_clock::now();
  const auto transformix = [&](std::vector<std::string> command, const fs::path & output) {
    CreateFolder(output);
    command.insert(command.end(), { "-out", output.string() });
    command.insert(command.end(), threading.begin(), threading.end());
    RunProgram(command, output / "transformix-output.txt", install);
  };
  transformix({ "transformix", "-in", moving.string(), "-tp", transform.string() }, out / "warped");
  transformix({ "transformix", "-def", "all", "-tp", onPreoperativeGrid.string() }, out / "field");
  peer.outputSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  peer.warpedOnFixedGrid = ReadImage<RegistrationImage>((out / "warped" / "result.nii").string(), "elastix's warped image");
  peer.transform = FieldTransform(
    ReadDisplacementField((out / "field" / "deformationField.nii").string(), "elastix's deformation field"));
  // 85 MB on Colin27's grid; the transform parameter files make it again.
  fs::remove(out / "field" / "deformationField.nii", ignored);
  return peer;
}

IntensityPeer
ReadIntensityPeer(const std::string & fieldPath, const std::string & warpedPath, const RegistrationImage * preoperativeGrid,
                  const RegistrationImage * intraoperativeGrid)
{
  // ITK would read a scalar image as a field with three equal components: refuse it.
  const ImageFileInfo info = ReadImageFileInfo(fieldPath, "the peer's displacement field");
  if (info.dimension != 3 || info.components != 3)
  {
    throw Error("the peer's displacement field " + fieldPath + " has " + std::to_string(info.dimension) +
                " dimensions and " + std::to_string(info.components) + " components per voxel; give a 3D image of "
                "3-vectors (e.g. transformix's deformationField, ANTs' composed warp)");
  }
  const DisplacementField::Pointer field = ReadDisplacementField(fieldPath, "the peer's displacement field");
  // Grids compared to the precision NIfTI stores them with (single precision).
  const auto onGrid = [](const auto * image, const RegistrationImage * grid) {
    if (image->GetLargestPossibleRegion() != grid->GetLargestPossibleRegion())
    {
      return false;
    }
    for (unsigned int axis = 0; axis < 3; ++axis)
    {
      if (std::abs(image->GetSpacing()[axis] - grid->GetSpacing()[axis]) > 1e-4 ||
          std::abs(image->GetOrigin()[axis] - grid->GetOrigin()[axis]) > 1e-3)
      {
        return false;
      }
    }
    return true;
  };
  if (!onGrid(field.GetPointer(), preoperativeGrid))
  {
    throw Error("the peer's displacement field " + fieldPath + " is not on the preoperative image's grid (size, spacing, "
                "origin): compute it there (the study measures errors over the whole brain)");
  }
  IntensityPeer peer;
  peer.warpedOnFixedGrid = ReadImage<RegistrationImage>(warpedPath, "the peer's warped image");
  if (!onGrid(peer.warpedOnFixedGrid.GetPointer(), intraoperativeGrid))
  {
    throw Error("the peer's warped image " + warpedPath + " is not on the intraoperative image's grid (size, spacing, "
                "origin): resample the preoperative image onto intraoperative.nii.gz");
  }
  // The same grids, read back from single-precision NIfTI: take the exact geometry.
  field->CopyInformation(preoperativeGrid);
  peer.warpedOnFixedGrid->CopyInformation(intraoperativeGrid);
  peer.transform = FieldTransform(field);
  return peer;
}

} // namespace app
} // namespace bmr
