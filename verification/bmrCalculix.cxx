// CalculiX harness: running ccx and reading its results (see bmrCalculix.h);
// the deck is written by bmrCalculixDeck.cxx.
#include "bmrCalculix.h"
#include "bmrCalculixContact.h"
#include "bmrCalculixStabilisation.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <sstream>

#include <sys/wait.h>
#include <unistd.h>

#ifndef BMR_CCX_EXECUTABLE
#  define BMR_CCX_EXECUTABLE "ccx"
#endif

namespace bmr
{
namespace
{

namespace fs = std::filesystem;

std::string
ShellQuote(const std::string & text)
{
  std::string quoted = "'";
  for (const char c : text)
  {
    if (c == '\'')
    {
      quoted += "'\\''";
    }
    else
    {
      quoted += c;
    }
  }
  return quoted + "'";
}

bool
IsExecutableFile(const fs::path & path)
{
  std::error_code error;
  return fs::is_regular_file(path, error) && ::access(path.c_str(), X_OK) == 0;
}

std::string
ReadFile(const fs::path & path)
{
  std::ifstream stream(path, std::ios::binary);
  std::ostringstream text;
  text << stream.rdbuf();
  return text.str();
}

std::string
Tail(const std::string & text, int lines)
{
  if (text.empty())
  {
    return text;
  }
  std::size_t position = text.size();
  int         count = 0;
  while (position > 0 && count <= lines)
  {
    position = text.rfind('\n', position - 1);
    if (position == std::string::npos)
    {
      return text;
    }
    ++count;
  }
  return text.substr(position + 1);
}

/** Fortran-style number: "1.234E-01", also "0.123456-100" (E dropped for
 *  three-digit exponents). */
bool
ParseNumber(const std::string & token, double & value)
{
  const char * begin = token.c_str();
  char *       end = nullptr;
  value = std::strtod(begin, &end);
  if (end != begin && *end == '\0')
  {
    return true;
  }
  const std::size_t sign = token.find_last_of("+-");
  if (sign == std::string::npos || sign == 0 || token[sign - 1] == 'E' || token[sign - 1] == 'e')
  {
    return false;
  }
  const std::string fixed = token.substr(0, sign) + "E" + token.substr(sign);
  begin = fixed.c_str();
  value = std::strtod(begin, &end);
  return end != begin && *end == '\0';
}

struct DatBlock
{
  double                               time = -1.0;
  std::vector<std::pair<long, Vector3>> rows;
};

/** The blocks of *NODE PRINT output whose header contains `header`, in the
 *  order written (a block's rows end at the first line that is not a row). */
std::vector<DatBlock>
DatBlocks(const std::string & text, const std::string & header)
{
  std::vector<DatBlock> blocks;
  std::istringstream    stream(text);
  std::string           line;
  bool                  inBlock = false;
  while (std::getline(stream, line))
  {
    if (line.find(header) != std::string::npos)
    {
      blocks.emplace_back();
      inBlock = true;
      const std::size_t at = line.rfind("time");
      if (at != std::string::npos)
      {
        std::istringstream timeStream(line.substr(at + 4));
        std::string        token;
        timeStream >> token;
        ParseNumber(token, blocks.back().time);
      }
      continue;
    }
    if (!inBlock)
    {
      continue;
    }
    std::istringstream fields(line);
    std::string        tokens[5];
    int                count = 0;
    while (count < 5 && fields >> tokens[count])
    {
      ++count;
    }
    double values[4];
    bool   numeric = count == 4;
    for (int i = 0; numeric && i < 4; ++i)
    {
      numeric = ParseNumber(tokens[i], values[i]);
    }
    if (numeric)
    {
      blocks.back().rows.emplace_back(static_cast<long>(values[0]), Vector3(values[1], values[2], values[3]));
    }
    else if (count > 0 || !blocks.back().rows.empty())
    {
      inBlock = false; // the blank line under the header keeps the block open
    }
  }
  return blocks;
}

/** The last non-empty block of DatBlocks. */
DatBlock
LastDatBlock(const std::string & text, const std::string & header)
{
  std::vector<DatBlock> blocks = DatBlocks(text, header);
  while (!blocks.empty() && blocks.back().rows.empty())
  {
    blocks.pop_back();
  }
  return blocks.empty() ? DatBlock{} : blocks.back();
}

} // namespace


std::string
FindCalculix(const std::string & executable)
{
  std::string name = executable;
  if (name.empty())
  {
    const char * fromEnvironment = std::getenv("BMR_CCX");
    name = (fromEnvironment && *fromEnvironment) ? fromEnvironment : BMR_CCX_EXECUTABLE;
  }
  if (name.find('/') != std::string::npos)
  {
    return IsExecutableFile(name) ? name : std::string{};
  }
  const char * path = std::getenv("PATH");
  std::string  directories = path ? path : "/usr/local/bin:/usr/bin:/bin";
  std::size_t  start = 0;
  while (start <= directories.size())
  {
    std::size_t end = directories.find(':', start);
    if (end == std::string::npos)
    {
      end = directories.size();
    }
    const std::string directory = directories.substr(start, end - start);
    const fs::path    candidate = fs::path(directory.empty() ? "." : directory) / name;
    if (IsExecutableFile(candidate))
    {
      return candidate.string();
    }
    start = end + 1;
  }
  return {};
}

Vector3
CalculixResult::TotalReactionForce(const std::vector<Index> & modelNodes) const
{
  std::vector<char> mask(mesh.modelNodes, 0);
  for (const Index node : modelNodes)
  {
    if (node >= 0 && node < mesh.modelNodes)
    {
      mask[node] = 1;
    }
  }
  const std::vector<char> meshMask = mesh.MeshNodeMask(mask);
  Vector3                 total = Vector3::Zero();
  for (std::size_t node = 0; node < meshReactionForces.size(); ++node)
  {
    if (meshMask[node])
    {
      total += meshReactionForces[node];
    }
  }
  return total;
}

namespace
{

/** CalculixSettings::gradualRelease with a stabilisation: the loading step
 *  alone, and the forces its springs (anchored at the reference state) exert
 *  on every mesh node, -k u, for the sprung components to take over. */
std::vector<Vector3>
LoadingSpringForces(const Model & model, const CalculixSettings & settings, double & seconds)
{
  CalculixSettings loading = settings;
  loading.gradualRelease = false;
  loading.holdOnly = true;
  loading.releaseForces.clear();
  loading.stabilisationExtrapolations = 0;
  loading.jobName = (settings.jobName.empty() ? std::string("bmr") : settings.jobName) + "-loading";
  const CalculixResult loaded = RunCalculix(model, loading);
  seconds = loaded.wallSeconds;
  std::vector<Vector3> forces(loaded.meshDisplacements.size());
  for (std::size_t node = 0; node < forces.size(); ++node)
  {
    forces[node] = -StabilisationStiffness(settings, 0) * loaded.meshDisplacements[node];
  }
  return forces;
}

/** CalculixSettings::stabilisationExtrapolations: the deck run again from
 *  its proximal sequence's extrapolated limit, the runs' counts summed. */
CalculixResult
RunExtrapolatedStabilisation(const Model & model, const CalculixSettings & settings)
{
  CalculixSettings run = settings;
  run.stabilisationExtrapolations = 0;
  const std::string job = settings.jobName.empty() ? std::string("bmr") : settings.jobName;
  CalculixResult    result = RunCalculix(model, run);
  for (int restart = 1; restart <= settings.stabilisationExtrapolations; ++restart)
  {
    if (result.stabilisationStepsBefore.size() < 2)
    {
      break; // fewer than two proximal steps finished: no contraction to measure
    }
    const std::vector<Vector3> & older = result.stabilisationStepsBefore[0];
    const std::vector<Vector3> & last = result.stabilisationStepsBefore[1];
    const std::vector<Vector3> & now = result.meshDisplacements;
    double                       along = 0.0;
    double                       squared = 0.0;
    for (Index node = 0; node < result.mesh.firstRigidNode; ++node)
    {
      along += (now[node] - last[node]).dot(last[node] - older[node]);
      squared += (last[node] - older[node]).squaredNorm();
    }
    const double ratio = squared > 0.0 ? std::min(along / squared, kMaxExtrapolationRatio) : 0.0;
    if (!(ratio > 0.0))
    {
      break; // the steps' motions do not shrink along one direction: nothing to extrapolate
    }
    CalculixResult::Extrapolation extrapolation;
    extrapolation.ratio = ratio;
    extrapolation.firstStep = result.stabilisationForces.size() + 1; // after the restart's loading step
    run.stabilisationAnchorStart.assign(now.size(), Vector3::Zero());
    for (Index node = 0; node < result.mesh.firstRigidNode; ++node)
    {
      const Vector3 shift = ratio / (1.0 - ratio) * (now[node] - last[node]);
      run.stabilisationAnchorStart[node] = now[node] + shift;
      extrapolation.largestShift = std::max(extrapolation.largestShift, shift.norm());
    }
    run.jobName = job + "-restart" + std::to_string(restart);
    CalculixResult next;
    try
    {
      next = RunCalculix(model, run);
    }
    catch (const Error & error)
    {
      // The run before stands: a proximal step is an equilibrium whatever
      // follows it.
      result.stabilisationStopped += std::string(result.stabilisationStopped.empty() ? "" : "\n") + "restart " +
                                     std::to_string(restart) + " from the extrapolated limit (contraction " +
                                     FormatDouble(ratio) + ") failed, so the result is the run before it: " +
                                     error.what();
      break;
    }
    next.wallSeconds += result.wallSeconds;
    next.increments += result.increments;
    next.iterations += result.iterations;
    next.stabilisationForces.insert(next.stabilisationForces.begin(), result.stabilisationForces.begin(),
                                    result.stabilisationForces.end());
    next.stabilisationStiffnesses.insert(next.stabilisationStiffnesses.begin(),
                                         result.stabilisationStiffnesses.begin(),
                                         result.stabilisationStiffnesses.end());
    next.stabilisationExtrapolations = result.stabilisationExtrapolations;
    next.stabilisationExtrapolations.push_back(extrapolation);
    if (!result.stabilisationStopped.empty())
    {
      next.stabilisationStopped = "before restart " + std::to_string(restart) + ": " + result.stabilisationStopped +
                                  (next.stabilisationStopped.empty() ? "" : "\n" + next.stabilisationStopped);
    }
    result = std::move(next);
  }
  return result;
}

} // namespace

CalculixResult
RunCalculix(const Model & model, const CalculixSettings & settings)
{
  if (settings.gradualRelease && settings.releaseForces.empty() && settings.stabilisationStiffness > 0.0 &&
      !settings.holdOnly)
  {
    // Before any restart: every run's loading step is the same, so its
    // springs' forces are computed once.
    CalculixSettings release = settings;
    double           loadingSeconds = 0.0;
    release.releaseForces = LoadingSpringForces(model, settings, loadingSeconds);
    release.gradualRelease = false;
    CalculixResult result = RunCalculix(model, release);
    result.holdRunSeconds = loadingSeconds;
    return result;
  }
  if (settings.stabilisationExtrapolations > 0)
  {
    return RunExtrapolatedStabilisation(model, settings);
  }
  if (settings.gradualRelease && !settings.startDisplacements.empty())
  {
    // The hold alone, for its reaction forces; then hold and gradual release.
    CalculixSettings hold = settings;
    hold.gradualRelease = false;
    hold.holdOnly = true;
    hold.releaseForces.clear();
    hold.jobName = (settings.jobName.empty() ? std::string("bmr") : settings.jobName) + "-hold";
    const CalculixResult held = RunCalculix(model, hold);
    CalculixSettings     release = settings;
    release.gradualRelease = false;
    release.holdOnly = false;
    release.releaseForces = held.meshReactionForces;
    CalculixResult result = RunCalculix(model, release);
    result.holdRunSeconds = held.wallSeconds;
    return result;
  }
  const std::string executable = FindCalculix(settings.executable);
  if (executable.empty())
  {
    throw Error("CalculiX: the executable '" +
                (settings.executable.empty() ? std::string(BMR_CCX_EXECUTABLE) : settings.executable) +
                "' was not found (PATH, $BMR_CCX); install Debian's calculix-ccx (scripts/install-dependencies.sh).");
  }
  model.Validate();

  CalculixResult result;
  result.mesh = MakeCalculixMesh(model, settings);

  // Job folder.
  fs::path   folder;
  const bool temporary = settings.workDirectory.empty();
  if (temporary)
  {
    std::string pattern = (fs::temp_directory_path() / "bmr-ccx-XXXXXX").string();
    if (!::mkdtemp(pattern.data()))
    {
      throw Error("CalculiX: could not create a temporary job folder under " + fs::temp_directory_path().string() +
                  ": " + std::strerror(errno));
    }
    folder = pattern;
  }
  else
  {
    folder = settings.workDirectory;
    std::error_code error;
    fs::create_directories(folder, error);
    if (error)
    {
      throw Error("CalculiX: could not create the job folder '" + folder.string() + "': " + error.message());
    }
  }
  const std::string job = settings.jobName.empty() ? "bmr" : settings.jobName;
  try
  {
    std::ofstream deck(folder / (job + ".inp"));
    if (!deck)
    {
      throw Error("CalculiX: could not write " + (folder / (job + ".inp")).string());
    }
    WriteCalculixDeck(deck, model, result.mesh, settings);
    if (!deck)
    {
      throw Error("CalculiX: writing " + (folder / (job + ".inp")).string() + " failed (disk full?)");
    }
  }
  catch (...)
  {
    if (temporary)
    {
      std::error_code ignored;
      fs::remove_all(folder, ignored);
    }
    throw;
  }
  // Remove results of an earlier run in a user-given folder.
  for (const char * extension : { ".dat", ".sta", ".frd", ".cvg" })
  {
    std::error_code ignored;
    fs::remove(folder / (job + extension), ignored);
  }

  std::ostringstream command;
  command << "cd " << ShellQuote(folder.string()) << " && ";
  if (settings.threads > 0)
  {
    command << "OMP_NUM_THREADS=" << settings.threads << " CCX_NPROC_EQUATION_SOLVER=" << settings.threads
            << " CCX_NPROC_RESULTS=" << settings.threads << " CCX_NPROC_STIFFNESS=" << settings.threads << " ";
  }
  command << ShellQuote(executable) << " -i " << ShellQuote(job) << " > " << ShellQuote(job + ".log") << " 2>&1";

  const auto start = std::chrono::steady_clock::now();
  const int  status = std::system(command.str().c_str());
  result.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  const std::string log = ReadFile(folder / (job + ".log"));
  const std::string dat = ReadFile(folder / (job + ".dat"));
  const std::string sta = ReadFile(folder / (job + ".sta"));
  const auto        fail = [&](const std::string & why) {
    std::ostringstream message;
    message << "CalculiX: " << why << " (job " << (folder / job).string() << ".inp";
    if (temporary && !settings.keepFiles)
    {
      std::error_code ignored;
      fs::remove_all(folder, ignored);
      message << ", removed; set CalculixSettings::keepFiles to keep it";
    }
    message << "). Last lines of its output:\n" << Tail(log, 25);
    throw Error(message.str());
  };

  const bool exitedNormally = status != -1 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
  if (status != -1 && WIFSIGNALED(status))
  {
    fail("ccx was killed by signal " + std::to_string(WTERMSIG(status)) + " (out of memory?)");
  }
  const DatBlock u = LastDatBlock(dat, "displacements (vx,vy,vz) for set NALL ");
  const DatBlock rf = LastDatBlock(dat, "forces (fx,fy,fz) for set NALL ");
  // The .dat gives the total time: each static step runs for 1.
  const bool   stabilised = settings.stabilisationStiffness > 0.0;
  const double endTime = settings.holdOnly                   ? 1.0
                         : stabilised                          ? 1.0 + settings.stabilisationSteps * settings.stabilisationStages
                         : settings.startDisplacements.empty() ? 1.0
                                                               : 2.0;
  const bool failed = !exitedNormally || log.find("*ERROR") != std::string::npos;
  // A proximal step that Newton does not finish (penalty contact that flips
  // between iterations) leaves the step before it as the result: an
  // equilibrium with springs whose force CalculixResult::stabilisationForces
  // states, like any other proximal step's.
  const bool stoppedInAProximalStep = failed && stabilised && !u.rows.empty() && u.time >= 2.0 - 1e-6;
  if (failed && !stoppedInAProximalStep)
  {
    fail("ccx failed (exit status " + std::to_string(status == -1 ? -1 : WEXITSTATUS(status)) + ")");
  }
  if (u.rows.empty() || (rf.rows.empty() && !stoppedInAProximalStep))
  {
    fail("no displacement or reaction force output in " + job + ".dat");
  }
  if (stoppedInAProximalStep)
  {
    // Proximal step g ends at time 1 + g: the last one finished is u.time - 1.
    result.stabilisationStopped = "CalculiX stopped in proximal step " + std::to_string(std::lround(u.time)) +
                                  " of " + std::to_string(std::lround(endTime - 1.0)) +
                                  "; the result is the step before. " + Tail(log, 3);
  }
  else if (std::abs(u.time - endTime) > 1e-6 || std::abs(rf.time - endTime) > 1e-6)
  {
    fail("the static step did not converge to its end (last output at time " + FormatDouble(u.time) + " of " +
         FormatDouble(endTime) + "); try a smaller initial increment or more increments");
  }
  const std::size_t meshNodes = result.mesh.nodes.size();
  result.meshDisplacements.assign(meshNodes, Vector3::Constant(std::numeric_limits<double>::quiet_NaN()));
  result.meshReactionForces.assign(meshNodes, Vector3::Zero());
  std::vector<char> seen(meshNodes, 0);
  for (const auto & row : u.rows)
  {
    if (row.first >= 1 && static_cast<std::size_t>(row.first) <= meshNodes)
    {
      result.meshDisplacements[row.first - 1] = row.second;
      seen[row.first - 1] = 1;
    }
  }
  if (!stoppedInAProximalStep) // the stopped step's reactions were not printed
  {
    for (const auto & row : rf.rows)
    {
      if (row.first >= 1 && static_cast<std::size_t>(row.first) <= meshNodes)
      {
        result.meshReactionForces[row.first - 1] = row.second;
      }
    }
  }
  for (std::size_t i = 0; i < meshNodes; ++i)
  {
    if (!seen[i] || !result.meshDisplacements[i].allFinite())
    {
      fail("node " + std::to_string(i + 1) + " has no finite displacement in " + job + ".dat");
    }
  }
  // The anchors' reactions are their springs' forces; one block per step end
  // (the free set's, printed too where CalculiX keeps earlier steps' requests,
  // carry residual-size forces).
  std::map<double, double> largestSpringForce;
  for (const DatBlock & block : DatBlocks(dat, "forces (fx,fy,fz) for set BMRANCHOR"))
  {
    double & largest = largestSpringForce[block.time];
    for (const auto & row : block.rows)
    {
      largest = std::max(largest, row.second.norm());
    }
  }
  for (const auto & step : largestSpringForce)
  {
    // Step end time t: the loading step ends at 1, proximal step g at 1 + g.
    const int proximalStep = static_cast<int>(std::lround(step.first)) - 1;
    const int stage = proximalStep == 0 ? 0 : (proximalStep - 1) / std::max(1, settings.stabilisationSteps);
    result.stabilisationForces.push_back(step.second);
    result.stabilisationStiffnesses.push_back(StabilisationStiffness(settings, stage));
  }
  result.displacements.assign(result.meshDisplacements.begin(),
                              result.meshDisplacements.begin() + result.mesh.modelNodes);
  if (stabilised)
  {
    // One NALL block per step end; the result is the last.
    std::map<double, const DatBlock *> stepEnds;
    const std::vector<DatBlock>        blocks = DatBlocks(dat, "displacements (vx,vy,vz) for set NALL ");
    for (const DatBlock & block : blocks)
    {
      if (!block.rows.empty() && block.time < u.time - 1e-6)
      {
        stepEnds[block.time] = &block;
      }
    }
    for (auto step = stepEnds.size() > 2 ? std::prev(stepEnds.end(), 2) : stepEnds.begin(); step != stepEnds.end();
         ++step)
    {
      std::vector<Vector3> & state = result.stabilisationStepsBefore.emplace_back(meshNodes, Vector3::Zero());
      for (const auto & row : step->second->rows)
      {
        if (row.first >= 1 && static_cast<std::size_t>(row.first) <= meshNodes)
        {
          state[row.first - 1] = row.second;
        }
      }
    }
  }

  // .sta: STEP INC ATT ITRS TOT-TIME STEP-TIME INC-TIME, one line per converged increment.
  std::istringstream staStream(sta);
  std::string        line;
  long               lastStep = 0;
  while (std::getline(staStream, line))
  {
    std::istringstream fields(line);
    long               step = 0, increment = 0, attempt = 0, iterations = 0;
    if (fields >> step >> increment >> attempt >> iterations)
    {
      if (step != lastStep)
      {
        lastStep = step;
        result.lastStepIncrements = result.lastStepIterations = 0;
      }
      ++result.increments;
      result.iterations += static_cast<int>(iterations);
      ++result.lastStepIncrements;
      result.lastStepIterations += static_cast<int>(iterations);
    }
  }

  if (temporary && !settings.keepFiles)
  {
    std::error_code ignored;
    fs::remove_all(folder, ignored);
  }
  else
  {
    result.workDirectory = folder.string();
  }
  return result;
}

} // namespace bmr
