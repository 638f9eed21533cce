// Reading and writing meshes, surfaces and results in VTK formats.
// Lengths are read and written as they are in the file: mm.
#ifndef bmrMeshIO_h
#define bmrMeshIO_h

#include "bmrModel.h"
#include "bmrSolver.h"

#include <map>
#include <string>
#include <vector>

namespace bmr
{

/** A data array of a VTK file: `components` values per point or cell,
 *  stored point after point (values[i * components + c]). */
struct DataArray
{
  int                 components = 1;
  std::vector<double> values;

  std::size_t Tuples() const { return components > 0 ? values.size() / components : 0; }
};

/** A volume mesh as read from a file, before a scene assigns materials. */
struct MeshData
{
  /** Nodes (mm) and cells; every cell has material 0, Model::materials is empty. */
  Model model;
  /** Integer label per cell from the label array (empty when the file has none). */
  std::vector<int> cellLabels;
  /** Every point-data array of the file, by name (node sets may be given as a mask). */
  std::map<std::string, DataArray> pointData;
  /** Every cell-data array of the file, by name. */
  std::map<std::string, DataArray> cellData;
};

/** Reads a volume mesh from .vtu (XML) or .vtk (legacy) unstructured grid
 *  (a file without cells gives a point cloud, e.g. a meshless model's nodes).
 *  Supported cells: VTK_HEXAHEDRON (12) and VTK_TETRA (10); any other cell
 *  type is an error that names the cell. `labelArray` names the cell-data
 *  array of integer material labels; when the file has no such array,
 *  cellLabels stays empty. Throws bmr::Error naming the path on failure. */
MeshData
ReadMesh(const std::string & path, const std::string & labelArray = "material");

/** Writes the model's nodes and cells: .vtu (XML, compressed binary) or .vtk
 *  (legacy ASCII). Cell data "material" holds each cell's material index, and
 *  "youngs_modulus" (Pa), "poisson_ratio" and "density" (kg/m^3) its
 *  properties (a scene can read them back with "material_fields");
 *  every node set becomes an unsigned-char point-data mask with the set's
 *  name (1 = in the set), so a scene can select it with {"point_data": NAME}.
 *  Written to a temporary file first and then renamed: never half-written. */
void
WriteMesh(const std::string & path, const Model & model);

/** Writes a solve result as .vtu: point data "displacement" (mm) and
 *  "reaction_force" (N), cell data "material" (index) and, when computed,
 *  "cauchy_stress" (9 components, Pa, row after row). Written to a temporary
 *  file in the same folder and renamed, so nothing half-written remains. */
void
WriteResultVtu(const std::string & path, const Model & model, const SolveResult & result);

/** Reads a triangulated rigid surface from .stl, .obj, .vtp or .vtk (legacy
 *  polydata). Polygons and triangle strips are split into triangles;
 *  coincident points (STL repeats every vertex) are merged; triangles that
 *  collapse after merging are dropped. An empty surface is an error. */
ContactSurface
ReadSurface(const std::string & path);

/** Writes a triangulated surface as .vtp (XML), .stl (binary) or .vtk
 *  (legacy polydata), atomically. */
void
WriteSurface(const std::string & path, const ContactSurface & surface);

/** Integration points of a meshless model with a material per point, as a
 *  file holds them: positions (mm), weights (mm^3) and each point's
 *  neo-Hookean properties (Pa, -, kg/m^3). */
struct IntegrationPointData
{
  std::vector<Vector3>  positions;
  std::vector<double>   weights;
  std::vector<Material> materials;
};

/** Writes model.meshless's integration points as a .vtu of vertex cells with
 *  point data "weight", "youngs_modulus", "poisson_ratio" and "density",
 *  atomically. Throws bmr::Error for a model that is not meshless. */
void
WriteIntegrationPoints(const std::string & path, const Model & model);

/** Reads a file written by WriteIntegrationPoints (or any .vtu whose points
 *  carry those four arrays). Missing arrays, non-positive weights or
 *  properties out of range are errors naming the file, array and point. */
IntegrationPointData
ReadIntegrationPoints(const std::string & path);

/** Writes text to `path` through a temporary file in the same folder and a
 *  rename, so a reader sees either the old file or the complete new one. */
void
WriteTextFileAtomically(const std::string & path, const std::string & text);

} // namespace bmr

#endif
