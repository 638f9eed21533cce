// `biomech simulate SCENE.json`: time-accurate explicit dynamics of a scene
// with moving tools, written as a time series: one .vtu per output frame
// collected in a .pvd (ParaView), the force and moment on every tool at every
// step as CSV, and the run report.
#include "bmrCommandSupport.h"
#include "bmrModelCommands.h"

#include "bmrMeshIO.h"
#include "bmrScene.h"
#include "bmrSolver.h"

#include <CLI/CLI.hpp>

#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;

namespace bmr
{
namespace app
{
namespace
{

struct SimulateOptions
{
  std::string        scenePath;
  std::string        outputDirectory = ".";
  std::optional<int> threads;
  bool               quiet = false;
};

/** The files of one run; removed together when the run fails, so that nothing half-written is left. */
struct SimulationFiles
{
  fs::path pvd, frames, csv, report;

  void Remove() const
  {
    std::error_code ignored;
    fs::remove(pvd, ignored);
    fs::remove_all(frames, ignored);
    fs::remove(csv, ignored);
    fs::remove(report, ignored);
  }
};

std::string
ToolForcesCsv(const SolveResult & result)
{
  std::ostringstream text;
  text << std::setprecision(10)
       << "time_s,tool,fx_N,fy_N,fz_N,mx_N_mm,my_N_mm,mz_N_mm,x_mm,y_mm,z_mm,contact_nodes\n";
  for (const ToolHistory & tool : result.tools)
  {
    for (std::size_t k = 0; k < tool.time.size(); ++k)
    {
      const Vector3 & f = tool.force[k];
      const Vector3 & m = tool.moment[k];
      const Vector3 & x = tool.position[k];
      text << tool.time[k] << "," << tool.name << "," << f.x() << "," << f.y() << "," << f.z() << "," << m.x() << ","
           << m.y() << "," << m.z() << "," << x.x() << "," << x.y() << "," << x.z() << "," << tool.contactNodes[k]
           << "\n";
    }
  }
  return text.str();
}

std::string
PvdCollection(const std::vector<std::pair<double, std::string>> & frames)
{
  std::ostringstream text;
  text << std::setprecision(12) << "<?xml version=\"1.0\"?>\n"
       << "<VTKFile type=\"Collection\" version=\"0.1\">\n  <Collection>\n";
  for (const auto & [time, file] : frames)
  {
    text << "    <DataSet timestep=\"" << time << "\" part=\"0\" file=\"" << file << "\"/>\n";
  }
  text << "  </Collection>\n</VTKFile>\n";
  return text.str();
}

int
RunSimulate(const SimulateOptions & options)
{
  Scene scene = ReadScene(options.scenePath);
  if (options.threads)
  {
    scene.settings.threads = *options.threads;
  }
  if (scene.settings.integrator != Integrator::ExplicitDynamics)
  {
    throw Error("'" + options.scenePath + "': simulate runs time-accurate explicit dynamics; set \"solver\": "
                "{\"integrator\": \"explicit_dynamics\", \"end_time\": ..., \"output_interval\": ...} (or use "
                "'biomech solve' for a steady state)");
  }
  if (scene.settings.outputInterval <= 0.0)
  {
    throw Error("'" + options.scenePath + "': give \"solver\": {\"output_interval\": SECONDS}, the time between "
                "the frames written (e.g. 0.0333 for 30 frames per second)");
  }

  const std::string stem = fs::path(scene.path).stem().string();
  const fs::path    folder(options.outputDirectory);
  SimulationFiles   files{ folder / (stem + ".pvd"), folder / (stem + "-frames"), folder / (stem + "-tool-forces.csv"),
                         folder / scene.reportFile };
  files.Remove(); // an earlier run's files must not pass for this run's
  CreateFolder(files.frames);

  std::vector<std::pair<double, std::string>> written;
  SolveResult                                 result;
  try
  {
    TerminalProgress progress(!options.quiet && ::isatty(STDERR_FILENO) != 0);
    Solver           solver(scene.model, scene.settings);
    SolveResult      frame;
    frame.reactionForces.assign(scene.model.nodes.size(), Vector3::Zero());
    result = solver.Solve([&progress](int step, double fraction, double) { progress.Update(step, fraction, 0.0); },
                          [&](const SolveFrame & state) {
                            std::ostringstream name;
                            name << stem << "-" << std::setw(5) << std::setfill('0') << written.size() << ".vtu";
                            frame.displacements = state.displacements;
                            WriteResultVtu((files.frames / name.str()).string(), scene.model, frame);
                            written.emplace_back(state.time, (fs::path(stem + "-frames") / name.str()).string());
                          });
    progress.Clear();
    WriteTextFileAtomically(files.pvd.string(), PvdCollection(written));
    WriteTextFileAtomically(files.csv.string(), ToolForcesCsv(result));
    WriteTextFileAtomically(files.report.string(), MakeReportJson(scene, result, files.pvd.string()));
  }
  catch (const SolveError & error)
  {
    files.Remove();
    throw Error(std::string("the simulation failed") +
                (error.Element() >= 0 ? " (element " + std::to_string(error.Element()) + ")" : std::string()) + ": " +
                error.what());
  }
  catch (...)
  {
    files.Remove();
    throw;
  }

  if (!options.quiet)
  {
    const double endTime = scene.settings.endTime;
    std::cout << FormatReportTable(scene, result);
    std::cout << std::setprecision(4) << "  simulated         " << endTime << " s in " << result.wallSeconds
              << " s wall: real-time factor " << endTime / result.wallSeconds << ", "
              << result.steps / result.wallSeconds << " steps/s\n";
    for (const ToolHistory & tool : result.tools)
    {
      double largest = 0.0;
      for (const Vector3 & force : tool.force)
      {
        largest = std::max(largest, force.norm());
      }
      std::cout << "  tool " << tool.name << ": largest force " << largest << " N, work " << tool.work << " J\n";
    }
    std::cout << "  frames            " << written.size() << " in " << files.pvd.string() << "\n"
              << "  tool forces       " << files.csv.string() << "\n"
              << "  report            " << files.report.string() << "\n";
  }
  return 0;
}

} // namespace

std::function<int()>
AddSimulateCommand(CLI::App & app)
{
  auto       options = std::make_shared<SimulateOptions>();
  CLI::App * command = app.add_subcommand(
    "simulate", "Time-accurate simulation of a scene with moving tools: frames (.pvd + .vtu), tool forces (.csv), "
                "report (.json)");
  command->add_option("scene", options->scenePath, "Scene file (JSON) with tools and explicit dynamics")->required();
  command->add_option("--output-dir,-d", options->outputDirectory, "Output folder")->capture_default_str();
  command->add_option("--threads", options->threads, "Worker threads (overrides the scene; 0: all)")
    ->check(CLI::Range(0, 4096));
  command->add_flag("--quiet,-q", options->quiet, "Print nothing but errors");
  return [command, options]() { return command->parsed() ? RunSimulate(*options) : -1; };
}

} // namespace app
} // namespace bmr
