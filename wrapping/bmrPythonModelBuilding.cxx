// Python bindings of files (meshes, surfaces, scenes), model building from
// images (tissue classification, grids, surfaces) and loads.
#include "bmrPythonSupport.h"

#include "bmrBrainSurfaces.h"
#include "bmrFuzzyCMeans.h"
#include "bmrImageGrids.h"
#include "bmrMaterialMapping.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"
#include "bmrScene.h"
#include "bmrSurfaceLoads.h"

#include <Python.h>
#include <pybind11/eigen.h>
#include <pybind11/functional.h>

#include <cmath>
#include <cstring>
#include <sstream>

namespace bmr::python
{

namespace
{

py::dict
GridQualityDict(const GridQuality & quality)
{
  py::dict result;
  result["cells"] = quality.cells;
  result["hexahedra"] = quality.hexahedra;
  result["tetrahedra"] = quality.tetrahedra;
  result["nodes"] = quality.nodes;
  result["mesh_volume_mm3"] = quality.meshVolume;
  result["mask_volume_mm3"] = quality.maskVolume;
  result["volume_error"] = quality.volumeError;
  result["min_scaled_jacobian"] = quality.minScaledJacobian;
  result["mean_scaled_jacobian"] = quality.meanScaledJacobian;
  result["min_dihedral_angle_deg"] = quality.minDihedralAngleDeg;
  result["max_dihedral_angle_deg"] = quality.maxDihedralAngleDeg;
  result["max_aspect_ratio"] = quality.maxAspectRatio;
  result["mean_edge_length_mm"] = quality.meanEdgeLength;
  result["integration_points"] = quality.integrationPoints;
  result["min_neighbours_per_point"] = quality.minNeighboursPerPoint;
  result["mean_neighbours_per_point"] = quality.meanNeighboursPerPoint;
  result["seconds"] = quality.seconds;
  return result;
}

py::dict
DataArrays(const std::map<std::string, DataArray> & arrays)
{
  py::dict result;
  for (const auto & [name, data] : arrays)
  {
    py::array_t<double> array(data.components == 1
                                ? std::vector<py::ssize_t>{ static_cast<py::ssize_t>(data.Tuples()) }
                                : std::vector<py::ssize_t>{ static_cast<py::ssize_t>(data.Tuples()), data.components });
    if (!data.values.empty())
    {
      std::memcpy(array.mutable_data(), data.values.data(), data.values.size() * sizeof(double));
    }
    result[py::str(name)] = array;
  }
  return result;
}

std::vector<Index>
SurfaceNodesOrBoundary(const Model & model, const py::object & surfaceNodes)
{
  return surfaceNodes.is_none() ? model.BoundaryNodes() : IndicesFromArray(surfaceNodes, "surface_nodes");
}

GridCells
ParseGridCells(const std::string & name)
{
  if (name == "hexahedra")
    return GridCells::Hexahedra;
  if (name == "tetrahedra")
    return GridCells::Tetrahedra;
  if (name == "mixed")
    return GridCells::Mixed;
  throw py::value_error("cells must be 'hexahedra', 'tetrahedra' or 'mixed', not '" + name + "'");
}

} // namespace

void
BindFiles(py::module_ & module)
{
  module.def(
    "read_mesh",
    [](const std::filesystem::path & pathArgument, const std::string & labelArray) {
      const std::string path = pathArgument.string();
      MeshData mesh = ReadMesh(path, labelArray);
      py::dict result;
      result["model"] = std::move(mesh.model);
      result["cell_labels"] = py::array_t<int>(static_cast<py::ssize_t>(mesh.cellLabels.size()), mesh.cellLabels.data());
      result["point_data"] = DataArrays(mesh.pointData);
      result["cell_data"] = DataArrays(mesh.cellData);
      return result;
    },
    py::arg("path"), py::arg("label_array") = "material",
    "Reads a .vtu or .vtk volume mesh: a dict with 'model', 'cell_labels', 'point_data' and 'cell_data' (arrays by name).");
  module.def("write_mesh", [](const std::filesystem::path & path, const Model & model) { WriteMesh(path.string(), model); },
             py::arg("path"), py::arg("model"), "Writes nodes, cells, materials and node sets (.vtu or .vtk), atomically.");
  module.def(
    "write_result", [](const std::filesystem::path & pathArgument, const Model & model, const SolveResult & result) {
      const std::string path = pathArgument.string();
      if (result.displacements.size() != model.nodes.size())
      {
        throw py::value_error("the result has " + std::to_string(result.displacements.size()) +
                              " displacements but the model has " + std::to_string(model.nodes.size()) +
                              " nodes: write a result with the model it was solved on");
      }
      WriteResultVtu(path, model, result);
    },
    py::arg("path"), py::arg("model"), py::arg("result"),
    "Writes a solve result as .vtu (point data 'displacement', 'reaction_force'), as `biomech solve` does.");
  module.def("read_surface", [](const std::filesystem::path & path) { return ReadSurface(path.string()); }, py::arg("path"), "Reads a triangulated surface (.stl, .obj, .vtp, .vtk).");
  module.def(
    "write_surface",
    [](const std::filesystem::path & path, const ContactSurface & surface) { WriteSurface(path.string(), surface); },
             py::arg("path"), py::arg("surface"), "Writes a surface (.vtp, .stl, .vtk), atomically.");
  module.def(
    "read_sparse_displacements",
    [](const std::filesystem::path & pathArgument) {
      const std::string path = pathArgument.string();
      const SparseDisplacements sparse = ReadSparseDisplacements(path);
      return py::make_tuple(ArrayFromPoints(sparse.points), ArrayFromPoints(sparse.displacements));
    },
    py::arg("path"), "Reads a CSV x,y,z,ux,uy,uz (mm): (points, displacements) as (N, 3) arrays.");

  module.def(
    "make_block_mesh",
    [](const py::object & size, const std::array<int, 3> & divisions, const std::string & cells,
       const Material & material, const py::object & origin) {
      for (int d = 0; d < 3; ++d)
      {
        if (divisions[static_cast<std::size_t>(d)] < 1)
        {
          throw py::value_error("divisions must be at least 1 along every axis");
        }
      }
      const Vector3 extent = VectorFromObject(size, "size");
      if ((extent.array() <= 0.0).any())
      {
        throw py::value_error("size must be positive along every axis (mm)");
      }
      return MakeBlockMesh(extent, divisions, ParseGridCells(cells), material, VectorFromObject(origin, "origin"));
    },
    py::arg("size"), py::arg("divisions"), py::arg("cells") = "hexahedra", py::arg("material") = Material{},
    py::arg("origin") = py::make_tuple(0.0, 0.0, 0.0),
    "Box [origin, origin + size] (mm) meshed with divisions cells per axis; node sets xmin..zmax and all.");
  module.def(
    "make_ellipsoid_surface",
    [](const py::object & semiAxes, int subdivisions, const py::object & centre) {
      if (subdivisions < 0 || subdivisions > 8)
      {
        throw py::value_error("subdivisions must be within 0..8");
      }
      return MakeEllipsoidSurface(VectorFromObject(semiAxes, "semi_axes"), subdivisions, VectorFromObject(centre, "centre"));
    },
    py::arg("semi_axes"), py::arg("subdivisions") = 3, py::arg("centre") = py::make_tuple(0.0, 0.0, 0.0));
}

// Tissue classification and grids.
void
BindClassificationAndGrids(py::module_ & module)
{
  py::class_<TissueClassification>(module, "TissueClassification")
    .def_property_readonly("centroids", [](const TissueClassification & result) { return result.fit.centroids; })
    .def_property_readonly("iterations", [](const TissueClassification & result) { return result.fit.iterations; })
    .def_property_readonly("converged", [](const TissueClassification & result) { return result.fit.converged; })
    .def_property_readonly("memberships", [](const TissueClassification & result) { return ImageFromVolume(result.memberships); },
                           "Image of float32 memberships, array [z, y, x, class] (ascending centroid); 0 outside the mask.")
    .def_property_readonly("labels", [](const TissueClassification & result) { return ImageFromVolume(result.labels); },
                           "uint8 Image: 1..K, the class of largest membership; 0 outside the mask.");

  module.def(
    "classify_tissue",
    [](const py::object & image, const py::object & mask, int classes, double fuzziness, double tolerance,
       int maxIterations, int threads, const py::object & progress) {
      const ScalarVolume intensities = ScalarVolumeFromImage(image, "image");
      LabelVolume        maskVolume;
      if (!mask.is_none())
      {
        maskVolume = LabelVolumeFromImage(mask, "mask");
      }
      FuzzyCMeansSettings settings;
      settings.classes = classes;
      settings.fuzziness = fuzziness;
      settings.tolerance = tolerance;
      settings.maxIterations = maxIterations;
      settings.threads = threads;
      ProgressReporter         reporter(progress);
      std::vector<std::string> warnings;
      TissueClassification     result = RunWithoutGil(reporter, [&] {
        return ClassifyTissue(intensities, mask.is_none() ? nullptr : &maskVolume, settings,
                              [&](double fraction) { reporter.Report("classify", fraction); }, &warnings);
      });
      WarnInPython(warnings);
      return result;
    },
    py::arg("image"), py::arg("mask") = py::none(), py::kw_only(), py::arg("classes") = FuzzyCMeansSettings{}.classes,
    py::arg("fuzziness") = FuzzyCMeansSettings{}.fuzziness, py::arg("tolerance") = FuzzyCMeansSettings{}.tolerance,
    py::arg("max_iterations") = FuzzyCMeansSettings{}.maxIterations, py::arg("threads") = 0,
    py::arg("progress") = py::none(),
    "Fuzzy c-means tissue classification inside the mask (itk::FuzzyCMeansClassifierImageFilter's method).");

  py::class_<ImageGrid>(module, "ImageGrid")
    .def_readonly("model", &ImageGrid::model)
    .def_property_readonly("cell_labels", [](const ImageGrid & grid) {
      return py::array_t<int>(static_cast<py::ssize_t>(grid.cellLabels.size()), grid.cellLabels.data());
    })
    .def_property_readonly("quality", [](const ImageGrid & grid) { return GridQualityDict(grid.quality); })
    .def_readonly("meshless_body", &ImageGrid::meshlessBody);

  module.def(
    "make_grid",
    [](const py::object & labels, const std::string & kind, double elementSize, double facetAngle, double facetDistance,
       double cellRadiusEdgeRatio, bool optimise, std::uint32_t seed, int threads) {
      const LabelVolume volume = LabelVolumeFromImage(labels, "labels");
      ImageGridSettings settings;
      settings.kind = ParseImageGridKind(kind);
      settings.elementSize = elementSize;
      settings.facetAngle = facetAngle;
      settings.facetDistance = facetDistance;
      settings.cellRadiusEdgeRatio = cellRadiusEdgeRatio;
      settings.optimise = optimise;
      settings.seed = seed;
      settings.threads = threads;
      std::vector<std::string> warnings;
      ImageGrid                grid;
      {
        py::gil_scoped_release release;
        grid = MakeGridFromLabels(volume, settings, &warnings);
      }
      WarnInPython(warnings);
      return grid;
    },
    py::arg("labels"), py::kw_only(), py::arg("kind") = "hexahedra", py::arg("element_size") = ImageGridSettings{}.elementSize,
    py::arg("facet_angle") = ImageGridSettings{}.facetAngle, py::arg("facet_distance") = ImageGridSettings{}.facetDistance,
    py::arg("cell_radius_edge_ratio") = ImageGridSettings{}.cellRadiusEdgeRatio,
    py::arg("optimise") = ImageGridSettings{}.optimise, py::arg("seed") = ImageGridSettings{}.seed, py::arg("threads") = 0,
    "Computational grid of a mask or label image (itk::BiomechanicalGridImageFilter's method): 'hexahedra', "
    "'tetrahedra', 'mixed' or 'meshless'.");
}

// Regions of a grid (surface, exposed, skull base) and the material mapping.
void
BindRegionsAndMaterials(py::module_ & module)
{
  module.def(
    "surface_nodes_in_sphere",
    [](const Model & model, const py::object & centre, double radius, const py::object & surfaceNodes) {
      return ArrayFromIndices(
        SurfaceNodesInSphere(model, SurfaceNodesOrBoundary(model, surfaceNodes), VectorFromObject(centre, "centre"), radius));
    },
    py::arg("model"), py::arg("centre"), py::arg("radius"), py::arg("surface_nodes") = py::none(),
    "Boundary nodes (or of surface_nodes) within radius mm of centre: e.g. the craniotomy.");
  module.def(
    "surface_nodes_in_mask",
    [](const Model & model, const py::object & mask, double tolerance, const py::object & surfaceNodes) {
      const LabelVolume region = LabelVolumeFromImage(mask, "mask");
      return ArrayFromIndices(SurfaceNodesInMask(model, SurfaceNodesOrBoundary(model, surfaceNodes), region, tolerance));
    },
    py::arg("model"), py::arg("mask"), py::arg("tolerance") = -1.0, py::arg("surface_nodes") = py::none());
  module.def(
    "skull_base_nodes",
    [](const Model & model, double height, const py::object & superior, const py::object & surfaceNodes) {
      SkullBaseSettings settings;
      settings.height = height;
      settings.superior = VectorFromObject(superior, "superior");
      return ArrayFromIndices(SkullBaseNodes(model, SurfaceNodesOrBoundary(model, surfaceNodes), settings));
    },
    py::arg("model"), py::arg("height") = SkullBaseSettings{}.height, py::arg("superior") = py::make_tuple(0.0, 0.0, 1.0),
    py::arg("surface_nodes") = py::none(), "Boundary nodes within height mm of the lowest one along superior.");
  module.def(
    "model_regions",
    [](Model model, const py::object & centre, double radius, const py::object & mask, double skullBaseHeight,
       const py::object & superior, bool contact, const py::object & surfaceNodes) {
      BrainRegionSettings settings;
      settings.skullBase.height = skullBaseHeight;
      settings.skullBase.superior = VectorFromObject(superior, "superior");
      LabelVolume region;
      settings.craniotomy = CraniotomySphereFrom(centre, radius);
      if (!mask.is_none())
      {
        region = LabelVolumeFromImage(mask, "craniotomy_mask");
        settings.craniotomy.mask = &region;
      }
      settings.contact = contact;
      const std::vector<Index> surface =
        surfaceNodes.is_none() && model.nodeSets.count("surface") ? model.nodeSets.at("surface")
                                                                   : SurfaceNodesOrBoundary(model, surfaceNodes);
      SetBrainRegions(model, surface, settings);
      return model;
    },
    py::arg("model"), py::kw_only(), py::arg("craniotomy_centre") = py::none(), py::arg("craniotomy_radius") = 0.0,
    py::arg("craniotomy_mask") = py::none(), py::arg("skull_base_height") = SkullBaseSettings{}.height,
    py::arg("superior") = py::make_tuple(0.0, 0.0, 1.0), py::arg("contact") = true,
    py::arg("surface_nodes") = py::none(),
    "A copy of the model with its surface regions (itk::BiomechanicalRegionsFilter's method): node sets "
    "'skull_base' (fixed), 'exposed' (the craniotomy: a sphere or a mask) and 'contact' (every other surface node). "
    "Surface nodes: surface_nodes, else the model's 'surface' set, else its boundary nodes.");
  module.def(
    "map_materials",
    [](Model model, const py::object & memberships, const std::vector<Material> & classMaterials,
       const py::object & tumourMask, const Material & tumour, int threads) {
      const ScalarVolume volume = ScalarVolumeFromImage(memberships, "memberships");
      LabelVolume        tumourVolume;
      if (!tumourMask.is_none())
      {
        tumourVolume = LabelVolumeFromImage(tumourMask, "tumour_mask");
      }
      MaterialMappingSettings settings;
      settings.classMaterials = classMaterials;
      settings.tumour = tumour;
      settings.sampling.threads = threads;
      std::vector<std::string> warnings;
      {
        py::gil_scoped_release release;
        MapMaterialsFromMemberships(model, volume, settings, tumourMask.is_none() ? nullptr : &tumourVolume, &warnings);
      }
      WarnInPython(warnings);
      return model;
    },
    py::arg("model"), py::arg("memberships"), py::kw_only(), py::arg("class_materials") = std::vector<Material>{},
    py::arg("tumour_mask") = py::none(), py::arg("tumour_material") = TumourMaterial(), py::arg("threads") = 0,
    "A copy of the model with materials mixed from tissue-class memberships (itk::BiomechanicalMaterialMappingFilter's "
    "method): memberships as classify_tissue gives them; class_materials one per class (empty: CSF for the darkest "
    "class, parenchyma for the others).");
}

void
BindModelBuilding(py::module_ & module)
{
  BindClassificationAndGrids(module);
  BindRegionsAndMaterials(module);
}

void
BindLoads(py::module_ & module)
{
  const auto settingsOf = [](double maxDistance, double smoothing) {
    SurfaceLoadSettings settings;
    settings.maxDistance = maxDistance;
    settings.smoothing = smoothing;
    return settings;
  };
  module.def(
    "displacements_from_surface",
    [settingsOf](const Model & model, const py::object & exposedNodes, const ContactSurface & surface, double maxDistance) {
      LoadReport report;
      auto       load = DisplacementsFromSurface(model, IndicesFromArray(exposedNodes, "exposed_nodes"), surface,
                                           settingsOf(maxDistance, 0.0), &report);
      return py::make_tuple(load, LoadReportDict(report));
    },
    py::arg("model"), py::arg("exposed_nodes"), py::arg("surface"), py::kw_only(),
    py::arg("max_distance") = SurfaceLoadSettings{}.maxDistance,
    "Each exposed node moves to its closest point of the intraoperative surface: (PrescribedDisplacement, report).");
  module.def(
    "displacements_from_points",
    [settingsOf](const Model & model, const py::object & exposedNodes, const py::object & points,
                 const py::object & displacements, double maxDistance, double smoothing,
                 const std::optional<ContactSurface> & modelSurface) {
      LoadReport report;
      auto load = DisplacementsFromSparsePoints(model, IndicesFromArray(exposedNodes, "exposed_nodes"),
                                                PointsFromArray(points, "points"), PointsFromArray(displacements, "displacements"),
                                                settingsOf(maxDistance, smoothing), &report,
                                                modelSurface ? &*modelSurface : nullptr);
      return py::make_tuple(load, LoadReportDict(report));
    },
    py::arg("model"), py::arg("exposed_nodes"), py::arg("points"), py::arg("displacements"), py::kw_only(),
    py::arg("max_distance") = SurfaceLoadSettings{}.maxDistance, py::arg("smoothing") = SurfaceLoadSettings{}.smoothing,
    py::arg("model_surface") = py::none(),
    "Sparse displacements (tracked points, electrodes) interpolated to the exposed nodes with the thin-plate spline.");
  module.def(
    "displacements_between_surfaces",
    [settingsOf](const Model & model, const py::object & exposedNodes, const ContactSurface & preoperative,
                 const ContactSurface & intraoperative, double reach, double spacing, double maxDistance) {
      LoadReport report;
      auto load = DisplacementsBetweenSurfaces(model, IndicesFromArray(exposedNodes, "exposed_nodes"), preoperative,
                                               intraoperative, reach, spacing, settingsOf(maxDistance, 0.0), &report);
      return py::make_tuple(load, LoadReportDict(report));
    },
    py::arg("model"), py::arg("exposed_nodes"), py::arg("preoperative_surface"), py::arg("intraoperative_surface"),
    py::kw_only(), py::arg("reach"), py::arg("spacing") = kDefaultScanSpacing,
    py::arg("max_distance") = SurfaceLoadSettings{}.maxDistance,
    "Surface to surface: scanner-visible points of the smooth preoperative surface matched to the intraoperative one.");
}

} // namespace bmr::python
