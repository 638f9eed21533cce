// Scenes: a JSON file that names a mesh, materials, node sets, constraints,
// loads, contact surfaces, solver settings and outputs (docs/scene-format.md),
// and the run report written after a solve.
#ifndef bmrScene_h
#define bmrScene_h

#include "bmrModel.h"
#include "bmrSolver.h"

#include <string>

namespace bmr
{

/** A parsed scene: the model and settings ready for bmr::Solver. */
struct Scene
{
  std::string    path;        // the scene file (as given)
  std::string    description; // optional "description" of the scene
  std::string    meshSource;  // mesh file path, or what was generated
  Model          model;       // user units: mm, Pa, kg/m^3, s
  SolverSettings settings;
  std::string    resultVtuFile; // relative to the output folder unless absolute
  std::string    reportFile;    // relative to the output folder unless absolute
};

/** Reads and parses a scene file; relative paths inside it are relative to
 *  the scene file's folder. Throws bmr::Error naming the file and the key
 *  path (e.g. "prescribed_displacements[1].node_set") of the first problem:
 *  unknown key, wrong type, missing required key, value out of range,
 *  unknown node set, empty node set, nonexistent node id or material label. */
Scene
ReadScene(const std::string & path);

/** Parses scene JSON text as if it were the file `scenePath` (used for
 *  messages, for relative paths and for the default output names). */
Scene
ParseScene(const std::string & jsonText, const std::string & scenePath);

/** Sizes of a model, for reports. */
struct ModelCounts
{
  std::size_t nodes = 0;
  std::size_t cells = 0;
  std::size_t hexahedra = 0;
  std::size_t tetrahedra = 0;
  std::size_t dofs = 0; // 3 per node
  std::size_t materials = 0;
  std::size_t integrationPoints = 0; // meshless models only
};

ModelCounts
CountModel(const Model & model);

/** The run report as JSON text (keys in docs/scene-format.md). */
std::string
MakeReportJson(const Scene & scene, const SolveResult & result, const std::string & resultVtuPath = "");

/** The solve's wall time by part (SolveResult::parts and the rest, s) and
 *  its contact sweeps, as the JSON object the reports carry under "parts". */
std::string
MakeSolvePartsJson(const SolveResult & result);

/** A short human-readable summary of the run; says NOT CONVERGED loudly. */
std::string
FormatReportTable(const Scene & scene, const SolveResult & result);

} // namespace bmr

#endif
