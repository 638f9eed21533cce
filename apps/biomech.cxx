// biomech: command-line tool of the BiomechanicalRegistration module.
//
//   biomech solve SCENE.json [--output-dir DIR] [--threads N] [--quiet]
//   biomech make-mesh --shape block --size X Y Z --divisions I J K -o mesh.vtu
//   biomech model IMAGE [--mask M] [--craniotomy-centre X Y Z --craniotomy-radius R]
//                 [--intraoperative-surface S | --sparse-displacements CSV] -o DIR
//   biomech classify | mask | grid | surfaces | loads   (the model's steps one at a time)
//   biomech register IMAGE --mask M --craniotomy-centre X Y Z --craniotomy-radius R
//                 (--intraoperative-surface S | --sparse-displacements CSV | --intraoperative-image I) -o DIR
//   biomech fit-transform | warp | evaluate | bspline-register   (transform, warp, accuracy, baseline)
//   biomech demo [-o DIR]   (registration against a known answer, with the B-spline baseline)
//   biomech electrodes CT MRI [--mask M] [--contacts N] -o DIR   (contacts from an intraoperative CT)
//   biomech simulate SCENE.json [-d DIR]   (moving tools in time: .pvd frames, tool forces .csv)
//
// Exit status: 0 success (solve converged), 2 solve finished but did not
// converge (results written, report says so), 1 any error (nothing written).
#include "bmrCommandSupport.h"
// ITK-based headers before the core ones: ITK's bundled Eigen must come first.
#include "bmrBrainShiftRegistration.h"

#include "bmrMeshGenerators.h"
#include "bmrImageCommands.h"
#include "bmrModelCommands.h"
#include "bmrMeshIO.h"
#include "bmrScene.h"
#include "bmrSolver.h"
#include "bmrSolverSettingsTable.h"

#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <new>
#include <optional>
#include <unistd.h>

namespace fs = std::filesystem;

namespace
{

constexpr int ExitSuccess = 0;
constexpr int ExitError = 1;
constexpr int ExitNotConverged = 2;

struct SolveOptions
{
  std::string         scenePath;
  std::string         outputDirectory = ".";
  std::optional<int>  threads;
  std::vector<std::string> overrides; // --set NAME=VALUE
  bool                quiet = false;
};

struct MakeMeshOptions
{
  std::string         shape;
  std::vector<double> size;
  std::vector<int>    divisions;
  std::vector<double> semiAxes;
  double              spacing = 0.0;
  std::vector<double> origin;
  std::string         cells = "hexahedra";
  std::string         outputPath;
};

void
RemoveIfExists(const fs::path & path)
{
  std::error_code ignored;
  fs::remove(path, ignored);
}

/** A settings table: one setting per entry (name = default unit (allowed), meaning), or the docs' Markdown. */
template <typename TSettings>
int
PrintSettings(const std::vector<bmr::SettingField<TSettings>> & fields, const TSettings & defaults, bool markdown)
{
  if (markdown)
  {
    std::cout << bmr::SettingsMarkdown(fields, defaults);
    return ExitSuccess;
  }
  for (const auto & field : fields)
  {
    std::cout << field.name << " = " << field.Text(defaults) << (field.unit.empty() ? "" : " " + field.unit);
    const std::string range = field.Range();
    std::cout << (range.empty() ? "" : "  (" + range + ")") << "\n    " << field.meaning << "\n";
  }
  return ExitSuccess;
}

int
RunSolve(const SolveOptions & options)
{
  bmr::Scene scene = bmr::ReadScene(options.scenePath);
  if (options.threads)
  {
    bmr::SetSolverSetting(scene.settings, "threads", std::to_string(*options.threads));
  }
  for (const std::string & assignment : options.overrides)
  {
    const auto equals = assignment.find('=');
    if (equals == std::string::npos || equals == 0)
    {
      throw bmr::Error("--set needs NAME=VALUE (a key of the scene's \"solver\" object), got '" + assignment + "'");
    }
    bmr::SetSolverSetting(scene.settings, assignment.substr(0, equals), assignment.substr(equals + 1));
  }

  const fs::path outputDirectory(options.outputDirectory);
  const fs::path vtuPath = outputDirectory / scene.resultVtuFile;
  const fs::path reportPath = outputDirectory / scene.reportFile;
  // A result left from an earlier run must not pass for this run's result.
  RemoveIfExists(vtuPath);
  RemoveIfExists(reportPath);
  bmr::app::CreateParentFolder(vtuPath);
  bmr::app::CreateParentFolder(reportPath);

  bmr::SolveResult result;
  {
    bmr::app::TerminalProgress progress(!options.quiet && ::isatty(STDERR_FILENO) != 0);
    bmr::Solver      solver(scene.model, scene.settings);
    try
    {
      result = solver.Solve([&progress](int step, double fraction, double estimatedError) {
        progress.Update(step, fraction, estimatedError);
      });
    }
    catch (const bmr::SolveError & error)
    {
      progress.Clear();
      // The solver's message names the step and the cell; add the cell index in a fixed form for scripts.
      throw bmr::Error(std::string("the solve failed") +
                       (error.Element() >= 0 ? " (element " + std::to_string(error.Element()) + ")" : std::string()) +
                       ": " + error.what());
    }
  }

  try
  {
    bmr::WriteResultVtu(vtuPath.string(), scene.model, result);
    bmr::WriteTextFileAtomically(reportPath.string(), bmr::MakeReportJson(scene, result, vtuPath.string()));
  }
  catch (...)
  {
    // Both files or neither: a result without its report could pass for converged.
    RemoveIfExists(vtuPath);
    RemoveIfExists(reportPath);
    throw;
  }

  if (!options.quiet)
  {
    std::cout << bmr::FormatReportTable(scene, result);
    std::cout << "  result            " << vtuPath.string() << "\n";
    std::cout << "  report            " << reportPath.string() << "\n";
  }
  if (!result.converged)
  {
    std::cerr << "biomech: " << (result.message.empty() ? "NOT CONVERGED" : result.message)
              << " (results written, report says converged: false)\n";
    return ExitNotConverged;
  }
  return ExitSuccess;
}

bmr::Vector3
ThreeValues(const std::vector<double> & values, const std::string & option)
{
  if (values.size() != 3)
  {
    throw bmr::Error(option + " needs 3 values");
  }
  return bmr::Vector3(values[0], values[1], values[2]);
}

int
RunMakeMesh(const MakeMeshOptions & options)
{
  const bmr::GridCells cells = options.cells == "tetrahedra"
                                 ? bmr::GridCells::Tetrahedra
                                 : (options.cells == "mixed" ? bmr::GridCells::Mixed : bmr::GridCells::Hexahedra);
  bmr::Model model;
  if (options.shape == "block")
  {
    if (options.size.empty() || options.divisions.empty() || !options.semiAxes.empty() || options.spacing != 0.0)
    {
      throw bmr::Error("--shape block needs --size X Y Z and --divisions I J K (and no --semi-axes or --spacing)");
    }
    const bmr::Vector3 size = ThreeValues(options.size, "--size");
    if ((size.array() <= 0.0).any())
    {
      throw bmr::Error("--size values must be greater than 0 (mm)");
    }
    if (options.divisions.size() != 3 || *std::min_element(options.divisions.begin(), options.divisions.end()) < 1)
    {
      throw bmr::Error("--divisions needs 3 integers of at least 1");
    }
    const bmr::Vector3 origin = options.origin.empty() ? bmr::Vector3::Zero() : ThreeValues(options.origin, "--origin");
    model = bmr::MakeBlockMesh(size, { options.divisions[0], options.divisions[1], options.divisions[2] }, cells,
                               bmr::Material{}, origin);
  }
  else
  {
    if (options.semiAxes.empty() || options.spacing <= 0.0 || !options.size.empty() || !options.divisions.empty() ||
        !options.origin.empty())
    {
      throw bmr::Error("--shape ellipsoid needs --semi-axes X Y Z and --spacing H > 0 (and no --size, --divisions or --origin)");
    }
    const bmr::Vector3 semiAxes = ThreeValues(options.semiAxes, "--semi-axes");
    if ((semiAxes.array() <= 0.0).any())
    {
      throw bmr::Error("--semi-axes values must be greater than 0 (mm)");
    }
    model = bmr::MakeEllipsoidMesh(semiAxes, options.spacing, cells);
  }
  bmr::WriteMesh(options.outputPath, model);
  const bmr::ModelCounts counts = bmr::CountModel(model);
  std::cout << "wrote " << options.outputPath << ": " << counts.nodes << " nodes, " << counts.cells << " cells ("
            << counts.hexahedra << " hexahedra, " << counts.tetrahedra << " tetrahedra), node sets:";
  for (const auto & entry : model.nodeSets)
  {
    std::cout << " " << entry.first;
  }
  std::cout << "\n";
  return ExitSuccess;
}

} // namespace

int
main(int argc, char ** argv)
{
  CLI::App app{ "biomech: nonlinear biomechanical model solver (TLED: Total Lagrangian explicit dynamics)\n"
                "Units: mm, Pa, kg/m^3, s. Scene format: docs/scene-format.md",
                "biomech" };
  app.require_subcommand(1);

  SolveOptions solveOptions;
  CLI::App *   solve = app.add_subcommand(
    "solve", "Solve a scene; write the result .vtu and a report .json. Exit 0 converged, 2 not converged, 1 error");
  solve->add_option("scene", solveOptions.scenePath, "Scene file (JSON)")->required();
  solve->add_option("--output-dir,-d", solveOptions.outputDirectory, "Folder for the result and the report")
    ->capture_default_str();
  solve->add_option("--threads", solveOptions.threads,
                    "Worker threads (overrides the scene; 0 = OpenMP's default, OMP_NUM_THREADS or all cores)")
    ->check(CLI::Range(0, 4096));
  solve->add_option("--set", solveOptions.overrides,
                    "Override a solver setting of the scene: NAME=VALUE, e.g. tolerance=0.01 (the keys: "
                    "biomech settings); may be repeated");
  solve->add_flag("--quiet,-q", solveOptions.quiet, "Print nothing but errors");

  bool       settingsMarkdown = false, registrationSettings = false;
  CLI::App * settings = app.add_subcommand(
    "settings", "List the solver settings (the scene's \"solver\" keys, Python's SolverSettings, solve --set) or "
                "the registration's (register/model options, Python's register() keywords)");
  settings->add_flag("--registration", registrationSettings, "The registration's settings (docs/registration.md)");
  settings->add_flag("--markdown", settingsMarkdown, "Print the Markdown table of the docs");

  MakeMeshOptions makeMeshOptions;
  CLI::App *      makeMesh = app.add_subcommand("make-mesh", "Generate a block or ellipsoid mesh and write it (.vtu or .vtk)");
  makeMesh->add_option("--shape", makeMeshOptions.shape, "block or ellipsoid")
    ->required()
    ->check(CLI::IsMember({ "block", "ellipsoid" }));
  makeMesh->add_option("--size", makeMeshOptions.size, "Block size X Y Z (mm)")->expected(3);
  makeMesh->add_option("--divisions", makeMeshOptions.divisions, "Block cells along X Y Z")->expected(3);
  makeMesh->add_option("--origin", makeMeshOptions.origin, "Block corner X Y Z (mm), default 0 0 0")->expected(3);
  makeMesh->add_option("--semi-axes", makeMeshOptions.semiAxes, "Ellipsoid semi-axes X Y Z (mm)")->expected(3);
  makeMesh->add_option("--spacing", makeMeshOptions.spacing, "Ellipsoid grid spacing (mm)");
  makeMesh->add_option("--cells", makeMeshOptions.cells, "hexahedra, tetrahedra or mixed")
    ->check(CLI::IsMember({ "hexahedra", "tetrahedra", "mixed" }))
    ->capture_default_str();
  makeMesh->add_option("-o,--output", makeMeshOptions.outputPath, "Output mesh (.vtu or .vtk)")->required();

  const std::vector<std::function<int()>> runOtherCommands = { bmr::app::AddModelCommands(app),
                                                                bmr::app::AddTransformCommands(app),
                                                                bmr::app::AddEvaluateCommand(app),
                                                                bmr::app::AddBSplineRegisterCommand(app),
                                                                bmr::app::AddDemoCommand(app),
                                                                bmr::app::AddElectrodesCommand(app),
                                                                bmr::app::AddSimulateCommand(app) };

  try
  {
    app.parse(argc, argv);
  }
  catch (const CLI::ParseError & error)
  {
    if (error.get_exit_code() == 0) // --help
    {
      return app.exit(error);
    }
    std::cerr << "biomech: error: " << error.what() << "\n"
              << "run 'biomech --help' or 'biomech SUBCOMMAND --help' for usage\n";
    return ExitError;
  }

  try
  {
    if (solve->parsed())
    {
      return RunSolve(solveOptions);
    }
    if (makeMesh->parsed())
    {
      return RunMakeMesh(makeMeshOptions);
    }
    if (settings->parsed())
    {
      return registrationSettings ? PrintSettings(bmr::RegistrationSettingFields(), bmr::BrainShiftRegistrationSettings{},
                                                  settingsMarkdown)
                                  : PrintSettings(bmr::SolverSettingFields(), bmr::SolverSettings{}, settingsMarkdown);
    }
    for (const auto & run : runOtherCommands)
    {
      if (const int status = run(); status >= 0)
      {
        return status;
      }
    }
    throw bmr::Error("no subcommand ran");
  }
  catch (const std::bad_alloc &)
  {
    std::cerr << "biomech: error: out of memory: the model or image is too large for this machine's memory; "
                 "use a coarser mesh or a smaller image\n";
    return ExitError;
  }
  catch (const std::exception & error)
  {
    std::cerr << "biomech: error: " << error.what() << "\n";
    return ExitError;
  }
}
