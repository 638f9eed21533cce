// The Python module biomechanical_registration._bmr: errors, models and the
// solver, and the module's definition. Files, model building and loads are
// bound in bmrPythonModelBuilding.cxx, the ITK layer in bmrPythonImages.cxx,
// the conversions they share are in bmrPythonConversions.cxx.
#include "bmrPythonSupport.h"

#include "bmrSolverSettingsTable.h"

#include "bmrBrainSurfaces.h"
#include "bmrFuzzyCMeans.h"
#include "bmrImageGrids.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"
#include "bmrScene.h"
#include "bmrSurfaceLoads.h"

#include <Python.h>

#include <algorithm>
#include <pybind11/eigen.h>
#include <pybind11/functional.h>

#include <cmath>
#include <cstring>
#include <sstream>

namespace bmr::python
{

// ---------------------------------------------------------------------------
// Model helpers.
// ---------------------------------------------------------------------------

namespace
{

constexpr int kVtkHexahedron = 12;
constexpr int kVtkTetra = 10;

/** (M, 8) with -1 padding for tetrahedra when the mesh has hexahedra; (M, 4) when it has only tetrahedra. */
py::array_t<Index>
CellArray(const Model & model)
{
  bool anyHexahedron = false;
  for (const Cell & cell : model.cells)
  {
    anyHexahedron = anyHexahedron || cell.type == CellType::Hexahedron;
  }
  const int          columns = anyHexahedron || model.cells.empty() ? 8 : 4;
  py::array_t<Index> array({ static_cast<py::ssize_t>(model.cells.size()), static_cast<py::ssize_t>(columns) });
  auto               view = array.mutable_unchecked<2>();
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const Cell & cell = model.cells[c];
    for (int k = 0; k < columns; ++k)
    {
      view(static_cast<py::ssize_t>(c), k) = k < NodesPerCell(cell.type) ? cell.nodes[static_cast<std::size_t>(k)] : -1;
    }
  }
  return array;
}

/** Cells from (M, 4) tetrahedra, (M, 8) hexahedra, or (M, 8) with -1 in the last four columns for tetrahedra. */
std::vector<Cell>
CellsFromArray(const py::handle & object)
{
  const auto array = py::array_t<long long, py::array::c_style | py::array::forcecast>::ensure(object);
  if (!array || array.ndim() != 2 || (array.shape(1) != 4 && array.shape(1) != 8))
  {
    throw py::value_error("cells must be an (M, 4) array of tetrahedra or an (M, 8) array of hexahedra (VTK node "
                          "order; -1 in the last four columns marks a tetrahedron in a mixed mesh)");
  }
  const auto        view = array.unchecked<2>();
  std::vector<Cell> cells(static_cast<std::size_t>(array.shape(0)));
  for (py::ssize_t c = 0; c < array.shape(0); ++c)
  {
    Cell & cell = cells[static_cast<std::size_t>(c)];
    const bool tetrahedron = array.shape(1) == 4 || view(c, 4) < 0;
    cell.type = tetrahedron ? CellType::Tetrahedron : CellType::Hexahedron;
    for (int k = 0; k < NodesPerCell(cell.type); ++k)
    {
      if (view(c, k) < 0 || view(c, k) > std::numeric_limits<Index>::max())
      {
        throw py::value_error("cell " + std::to_string(c) + " has the node id " + std::to_string(view(c, k)) +
                              "; node ids are 0 or more");
      }
      cell.nodes[static_cast<std::size_t>(k)] = static_cast<Index>(view(c, k));
    }
  }
  return cells;
}

ContactSurface
MakeSurface(const py::handle & vertices, const py::handle & triangles, const std::string & name,
            const std::string & bodySide, bool flipNormals, const std::string & slaveNodeSet)
{
  ContactSurface surface;
  surface.name = name;
  surface.vertices = PointsFromArray(vertices, "surface vertices");
  const auto array = py::array_t<long long, py::array::c_style | py::array::forcecast>::ensure(triangles);
  if (!array || array.ndim() != 2 || array.shape(1) != 3)
  {
    throw py::value_error("surface triangles must be an (M, 3) array of vertex ids");
  }
  for (py::ssize_t t = 0; t < array.shape(0); ++t)
  {
    std::array<Index, 3> triangle{};
    for (int k = 0; k < 3; ++k)
    {
      const long long id = array.at(t, k);
      if (id < 0 || id >= static_cast<long long>(surface.vertices.size()))
      {
        throw py::value_error("surface triangle " + std::to_string(t) + " names vertex " + std::to_string(id) +
                              ", but the surface has " + std::to_string(surface.vertices.size()) + " vertices");
      }
      triangle[static_cast<std::size_t>(k)] = static_cast<Index>(id);
    }
    surface.triangles.push_back(triangle);
  }
  if (bodySide != "inside" && bodySide != "outside")
  {
    throw py::value_error("body_side must be 'inside' or 'outside', not '" + bodySide + "'");
  }
  surface.bodySide = bodySide == "outside" ? ContactSurface::Side::Outside : ContactSurface::Side::Inside;
  surface.flipNormals = flipNormals;
  surface.slaveNodeSet = slaveNodeSet;
  return surface;
}

py::array_t<Index>
TriangleArray(const std::vector<std::array<Index, 3>> & triangles)
{
  py::array_t<Index> array({ static_cast<py::ssize_t>(triangles.size()), py::ssize_t{ 3 } });
  if (!triangles.empty())
  {
    std::memcpy(array.mutable_data(), triangles.data(), triangles.size() * sizeof(triangles[0]));
  }
  return array;
}

LoadCurve
MakeCurve(const std::string & shape, double rampTime)
{
  LoadCurve curve;
  if (shape == "smooth")
    curve.shape = LoadCurve::Shape::Smooth;
  else if (shape == "linear")
    curve.shape = LoadCurve::Shape::Linear;
  else if (shape == "step")
    curve.shape = LoadCurve::Shape::Step;
  else
    throw py::value_error("curve must be 'smooth', 'linear' or 'step', not '" + shape + "'");
  if (!(rampTime > 0.0))
  {
    throw py::value_error("ramp_time must be positive (s)");
  }
  curve.rampTime = rampTime;
  return curve;
}

std::string
CurveName(const LoadCurve & curve)
{
  return curve.shape == LoadCurve::Shape::Linear ? "linear" : (curve.shape == LoadCurve::Shape::Step ? "step" : "smooth");
}

const char *
IntegratorName(Integrator integrator)
{
  return integrator == Integrator::ExplicitDynamics ? "explicit_dynamics" : "dynamic_relaxation";
}

void
BindErrors(py::module_ & module)
{
  // bmr::Error (and its SolveError) -> biomechanical_registration.Error /
  // SolveError (with .step and .element), both RuntimeErrors as in ITK Python.
  static py::exception<Error> error(module, "Error", PyExc_RuntimeError);
  static py::exception<SolveError> solveError(module, "SolveError", error.ptr());
  py::register_exception_translator([](std::exception_ptr pointer) {
    try
    {
      if (pointer)
        std::rethrow_exception(pointer);
    }
    catch (const SolveError & exception)
    {
      py::object instance = py::reinterpret_borrow<py::object>(solveError.ptr())(exception.what());
      instance.attr("step") = exception.Step();
      instance.attr("element") = exception.Element();
      PyErr_SetObject(solveError.ptr(), instance.ptr());
    }
    catch (const Error & exception)
    {
      error(exception.what());
    }
  });
}

std::string
JoinedParameterNames()
{
  std::string names;
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    names += (names.empty() ? "" : ", ") + std::string(parameter.name);
  }
  return names;
}

// The materials: the hyperelastic laws and the tools' Ogden material.
void
BindMaterials(py::module_ & module)
{
  py::class_<Material> material(
    module, "Material",
    "Hyperelastic material (Pa, -, kg/m^3): law 'neo-hookean' or 'mooney-rivlin' (bmr.material_laws()); E and nu give "
    "the small-strain moduli of every law; a law's parameters (bmr.material_parameters(), e.g. second_invariant_share "
    "= C01 / (C10 + C01)) are keywords and attributes.");
  material
    .def(py::init([](const std::string & name, double youngsModulus, double poissonRatio, double density,
                     const std::string & law, const py::kwargs & parameters) {
           Material made{ name, youngsModulus, poissonRatio, density };
           made.law = MaterialLawNamed(law);
           for (const auto & [key, value] : parameters)
           {
             const std::string keyword = py::str(key);
             const auto        known = std::find_if(MaterialParameters().begin(), MaterialParameters().end(),
                                                    [&](const MaterialParameter & p) { return keyword == p.name; });
             if (known == MaterialParameters().end())
             {
               throw py::type_error("Material() got an unexpected keyword '" + keyword +
                                    "'; the laws' parameters are: " + JoinedParameterNames());
             }
             made.*known->value = value.cast<double>();
           }
           if (const std::string problem = MaterialLawProblem(made); !problem.empty())
           {
             throw Error("Material '" + name + "' " + problem + ".");
           }
           return made;
         }),
         py::arg("name") = "material", py::arg("youngs_modulus") = Material{}.youngsModulus,
         py::arg("poisson_ratio") = Material{}.poissonRatio, py::arg("density") = Material{}.density,
         py::arg("law") = DescribeMaterialLaw(Material{}.law).name)
    .def_readwrite("name", &Material::name)
    .def_readwrite("youngs_modulus", &Material::youngsModulus)
    .def_readwrite("poisson_ratio", &Material::poissonRatio)
    .def_readwrite("density", &Material::density)
    .def_property(
      "law", [](const Material & m) { return std::string(DescribeMaterialLaw(m.law).name); },
      [](Material & m, const std::string & name) { m.law = MaterialLawNamed(name); })
    .def_property_readonly("shear_modulus", &Material::ShearModulus)
    .def_property_readonly("bulk_modulus", &Material::BulkModulus)
    .def("__repr__", [](const Material & m) {
      std::ostringstream text;
      text << "Material(name='" << m.name << "', youngs_modulus=" << m.youngsModulus
           << ", poisson_ratio=" << m.poissonRatio << ", density=" << m.density;
      if (m.law != MaterialLaw::NeoHookean)
      {
        text << ", law='" << DescribeMaterialLaw(m.law).name << "'";
        for (const MaterialParameter & parameter : MaterialParameters())
        {
          text << ", " << parameter.name << "=" << m.*parameter.value;
        }
      }
      text << ")";
      return text.str();
    });
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    const auto value = parameter.value;
    material.def_property(
      parameter.name, [value](const Material & m) { return m.*value; }, [value](Material & m, double v) { m.*value = v; },
      parameter.meaning);
  }
  module.def("material_laws", &MaterialLawNameList, "The names of the constitutive laws a Material can take.");
  module.def(
    "material_parameters",
    [] {
      std::vector<std::string> names;
      for (const MaterialParameter & parameter : MaterialParameters())
      {
        names.emplace_back(parameter.name);
      }
      return names;
    },
    "The names of the laws' parameters, Material's keywords and attributes beside E, nu and the density.");

  py::class_<OgdenViscoelasticMaterial>(module, "OgdenMaterial",
                                        "Miller and Chinzei's Ogden-type hyperviscoelastic law for stresses near a tool "
                                        "(Pa, s): shear relaxation mu(t) = mu0 (1 - sum g_k (1 - exp(-t / tau_k))).")
    .def(py::init([](double mu0, double alpha, const std::vector<double> & g, const std::vector<double> & tau,
                     double poissonRatio) {
           OgdenViscoelasticMaterial material{ mu0, alpha, g, tau, poissonRatio };
           material.Validate();
           return material;
         }),
         py::arg("mu0") = OgdenViscoelasticMaterial{}.mu0, py::arg("alpha") = OgdenViscoelasticMaterial{}.alpha,
         py::arg("g") = OgdenViscoelasticMaterial{}.g, py::arg("tau") = OgdenViscoelasticMaterial{}.tau,
         py::arg("poisson_ratio") = OgdenViscoelasticMaterial{}.poissonRatio)
    .def_readonly("mu0", &OgdenViscoelasticMaterial::mu0)
    .def_readonly("alpha", &OgdenViscoelasticMaterial::alpha)
    .def_readonly("g", &OgdenViscoelasticMaterial::g)
    .def_readonly("tau", &OgdenViscoelasticMaterial::tau)
    .def_readonly("poisson_ratio", &OgdenViscoelasticMaterial::poissonRatio)
    .def("cauchy_stress", [](const OgdenViscoelasticMaterial & material, const Eigen::Matrix3d & F) {
      return OgdenElasticCauchy(material, F);
    }, py::arg("F"), "The instantaneous (t = 0) Cauchy stress (Pa) of a deformation gradient.");
}

void
BindSurfacesAndLoads(py::module_ & module)
{
  py::class_<ContactSurface>(module, "Surface",
                             "Triangulated surface (mm): a rigid contact surface, a brain or skull surface, an "
                             "intraoperative surface.")
    .def(py::init(&MakeSurface), py::arg("vertices"), py::arg("triangles"), py::arg("name") = "surface",
         py::arg("body_side") = "inside", py::arg("flip_normals") = false, py::arg("slave_node_set") = "")
    .def_property(
      "vertices", [](const ContactSurface & surface) { return ArrayFromPoints(surface.vertices); },
      [](ContactSurface & surface, const py::object & vertices) {
        surface.vertices = PointsFromArray(vertices, "surface vertices");
      })
    .def_property_readonly("triangles", [](const ContactSurface & surface) { return TriangleArray(surface.triangles); })
    .def_readwrite("name", &ContactSurface::name)
    .def_property(
      "body_side",
      [](const ContactSurface & surface) {
        return surface.bodySide == ContactSurface::Side::Outside ? "outside" : "inside";
      },
      [](ContactSurface & surface, const std::string & side) {
        surface = MakeSurface(ArrayFromPoints(surface.vertices), TriangleArray(surface.triangles), surface.name, side,
                              surface.flipNormals, surface.slaveNodeSet);
      })
    .def_readwrite("flip_normals", &ContactSurface::flipNormals)
    .def_readwrite("slave_node_set", &ContactSurface::slaveNodeSet)
    .def_readwrite("offset", &ContactSurface::offset,
                   "Contact offset (mm): the body keeps this far from the surface; negative: it may pass it by that much.")
    .def("is_closed", &IsClosedOrientedSurface, "True for a closed, consistently oriented surface.")
    .def("enclosed_volume", &EnclosedVolume, "Volume enclosed by a closed surface (mm^3).")
    .def("__repr__", [](const ContactSurface & surface) {
      return "Surface(name='" + surface.name + "', " + std::to_string(surface.vertices.size()) + " vertices, " +
             std::to_string(surface.triangles.size()) + " triangles)";
    });

  py::class_<PrescribedDisplacement>(module, "PrescribedDisplacement",
                                     "Enforced displacements (mm) of nodes, ramped by a load curve.")
    .def(py::init([](const py::object & nodes, const py::object & displacements, const py::object & components,
                     const std::string & curve, double rampTime) {
           PrescribedDisplacement load;
           load.nodes = IndicesFromArray(nodes, "nodes");
           load.displacements = PointsFromArray(displacements, "displacements");
           if (load.nodes.size() != load.displacements.size())
           {
             throw py::value_error("nodes and displacements differ in length (" + std::to_string(load.nodes.size()) +
                                   " and " + std::to_string(load.displacements.size()) + ")");
           }
           load.components = ComponentsFromObject(components, "components");
           load.curve = MakeCurve(curve, rampTime);
           return load;
         }),
         py::arg("nodes"), py::arg("displacements"), py::arg("components") = py::make_tuple(true, true, true),
         py::arg("curve") = "smooth", py::arg("ramp_time") = 1.0)
    .def_property_readonly("nodes", [](const PrescribedDisplacement & load) { return ArrayFromIndices(load.nodes); })
    .def_property_readonly("displacements",
                           [](const PrescribedDisplacement & load) { return ArrayFromPoints(load.displacements); })
    .def_property_readonly("components", [](const PrescribedDisplacement & load) {
      return py::make_tuple(load.components[0], load.components[1], load.components[2]);
    })
    .def_property_readonly("curve", [](const PrescribedDisplacement & load) { return CurveName(load.curve); })
    .def_property_readonly("ramp_time", [](const PrescribedDisplacement & load) { return load.curve.rampTime; })
    .def("__repr__", [](const PrescribedDisplacement & load) {
      return "PrescribedDisplacement(" + std::to_string(load.nodes.size()) + " nodes)";
    });
}

void
BindTools(py::module_ & module)
{
  py::class_<RigidTool>(module, "Tool",
                        "A rigid surgical tool moved along a trajectory (explicit dynamics; dynamic relaxation ramps it "
                        "to its last pose). Tool frame: the tip at the origin, the tool along +z.")
    .def(py::init([](const std::string & name, const std::string & shape, double radius, double length, double width,
                     const std::optional<ContactSurface> & surface, const py::object & times, const py::object & positions,
                     const py::object & rotations, const std::string & slaveNodeSet, double stressRegionRadius,
                     const std::optional<OgdenViscoelasticMaterial> & stressMaterial) {
           RigidTool tool;
           tool.name = name;
           if (shape == "probe")
             tool.shape = RigidTool::Shape::Probe;
           else if (shape == "spatula")
             tool.shape = RigidTool::Shape::Spatula;
           else if (shape == "surface")
             tool.shape = RigidTool::Shape::Surface;
           else
             throw py::value_error("shape must be 'probe', 'spatula' or 'surface', not '" + shape + "'");
           tool.radius = radius;
           tool.length = length;
           tool.width = width;
           if (surface)
             tool.surface = *surface;
           const auto at = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(times);
           if (!at || at.ndim() != 1 || at.size() == 0)
             throw py::value_error("times must be a 1-D sequence of at least one time (s)");
           const std::vector<Vector3> where = PointsFromArray(positions, "positions");
           const std::vector<Vector3> turn = rotations.is_none() ? std::vector<Vector3>(where.size(), Vector3::Zero())
                                                                 : PointsFromArray(rotations, "rotations");
           if (where.size() != static_cast<std::size_t>(at.size()) || turn.size() != where.size())
             throw py::value_error("times, positions and rotations need one entry per pose");
           for (std::size_t k = 0; k < where.size(); ++k)
             tool.trajectory.push_back(ToolPose{ at.at(static_cast<py::ssize_t>(k)), where[k], turn[k] });
           tool.slaveNodeSet = slaveNodeSet;
           tool.stressRegionRadius = stressRegionRadius;
           if (stressMaterial)
             tool.stressMaterial = *stressMaterial;
           return tool;
         }),
         py::arg("name") = "tool", py::arg("shape") = "probe", py::arg("radius") = RigidTool{}.radius,
         py::arg("length") = RigidTool{}.length, py::arg("width") = RigidTool{}.width,
         py::arg("surface") = py::none(), py::kw_only(), py::arg("times"), py::arg("positions"),
         py::arg("rotations") = py::none(), py::arg("slave_node_set") = "", py::arg("stress_region_radius") = 0.0,
         py::arg("stress_material") = py::none(),
         "Trajectory: times (s), positions (N, 3) of the tool frame's origin (mm) and rotations (N, 3) as rotation "
         "vectors (axis times angle, rad).")
    .def_readonly("name", &RigidTool::name)
    .def_property_readonly("shape", [](const RigidTool & tool) { return std::string(ToolShapeName(tool.shape)); })
    .def_readonly("radius", &RigidTool::radius)
    .def_readonly("length", &RigidTool::length)
    .def_readonly("width", &RigidTool::width)
    .def_readonly("stress_region_radius", &RigidTool::stressRegionRadius)
    .def(
      "pose",
      [](const RigidTool & tool, double time) {
        const ToolPose pose = ToolPoseAt(tool, time);
        return py::make_tuple(Vector3(pose.position), Vector3(pose.rotation));
      },
      py::arg("time"), "(position, rotation vector) at a time.");

  py::class_<ToolHistory>(module, "ToolHistory", "A tool's motion and the tissue's load on it over a solve.")
    .def_readonly("name", &ToolHistory::name)
    .def_property_readonly("time", [](const ToolHistory & h) { return py::array_t<double>(static_cast<py::ssize_t>(h.time.size()), h.time.data()); })
    .def_property_readonly("position", [](const ToolHistory & h) { return ArrayFromPoints(h.position); })
    .def_property_readonly("force", [](const ToolHistory & h) { return ArrayFromPoints(h.force); }, "N, on the tool")
    .def_property_readonly("moment", [](const ToolHistory & h) { return ArrayFromPoints(h.moment); },
                           "N mm, on the tool about its origin")
    .def_property_readonly("contact_nodes", [](const ToolHistory & h) {
      return py::array_t<int>(static_cast<py::ssize_t>(h.contactNodes.size()), h.contactNodes.data());
    })
    .def_readonly("work", &ToolHistory::work, "J done by the tool on the tissue")
    .def_property_readonly("corrected_force", [](const ToolHistory & h) { return ArrayFromPoints(h.correctedForce); })
    .def_property_readonly("peak_stress", [](const ToolHistory & h) {
      return py::array_t<double>(static_cast<py::ssize_t>(h.peakStress.size()), h.peakStress.data());
    })
    .def_property_readonly("stress_cells", [](const ToolHistory & h) { return ArrayFromIndices(h.stressCells); })
    .def_property_readonly("ogden_stress", [](const ToolHistory & h) { return h.ogdenStress; })
    .def_property_readonly("neo_hookean_stress", [](const ToolHistory & h) { return h.neoHookeanStress; });
}

// The model's loads and boundary conditions, and its queries and copies.
void
BindModelLoads(py::class_<Model> & model)
{
  model
    .def_property(
      "gravity", [](const Model & model) { return py::make_tuple(model.bodyAcceleration.x(), model.bodyAcceleration.y(), model.bodyAcceleration.z()); },
      [](Model & model, const py::object & value) { model.bodyAcceleration = VectorFromObject(value, "gravity"); },
      "Body acceleration (mm/s^2), e.g. (0, 0, -9810).")
    .def_property(
      "fluid_surface",
      [](const Model & model) -> py::object {
        return model.fluidSurface ? py::object(py::make_tuple(model.fluidSurface->x(), model.fluidSurface->y(),
                                                              model.fluidSurface->z()))
                                  : py::object(py::none());
      },
      [](Model & model, const py::object & value) {
        model.fluidSurface = value.is_none() ? std::nullopt
                                             : std::optional<Vector3>(VectorFromObject(value, "fluid_surface"));
      },
      "A point (mm) on the surface of the CSF left after drainage: nodes below its level plane carry no weight; "
      "None: every node carries its weight.")
    .def(
      "fix",
      [](Model & model, const std::string & nodeSet, const py::object & components) {
        model.NodeSet(nodeSet);
        model.fixedConstraints.push_back(FixedConstraint{ nodeSet, ComponentsFromObject(components, "components") });
      },
      py::arg("node_set"), py::arg("components") = py::make_tuple(true, true, true),
      "Holds the nodes of a set at zero displacement in the chosen components.")
    .def_property_readonly("fixed_constraints",
                           [](const Model & model) {
                             py::list constraints;
                             for (const FixedConstraint & constraint : model.fixedConstraints)
                             {
                               constraints.append(py::make_tuple(
                                 constraint.nodeSet,
                                 py::make_tuple(constraint.components[0], constraint.components[1], constraint.components[2])));
                             }
                             return constraints;
                           })
    .def(
      "add_prescribed_displacement",
      [](Model & model, const PrescribedDisplacement & load) { model.prescribedDisplacements.push_back(load); },
      py::arg("load"))
    .def_readonly("prescribed_displacements", &Model::prescribedDisplacements)
    .def(
      "add_contact_surface", [](Model & model, const ContactSurface & surface) { model.contactSurfaces.push_back(surface); },
      py::arg("surface"), "A rigid surface the body stays on one side of (frictionless, with separation).")
    .def_readonly("contact_surfaces", &Model::contactSurfaces)
    .def(
      "add_tool", [](Model & model, const RigidTool & tool) { model.tools.push_back(tool); }, py::arg("tool"),
      "A rigid tool moved along its trajectory (frictionless contact, the body outside the tool).")
    .def_readonly("tools", &Model::tools)
    .def("clear_loads",
         [](Model & model) {
           model.fixedConstraints.clear();
           model.prescribedDisplacements.clear();
           model.contactSurfaces.clear();
           model.tools.clear();
           model.bodyAcceleration = Vector3::Zero();
         })
    .def_property_readonly("is_meshless",
                           [](const Model & model) { return model.discretization == Discretization::Meshless; })
    .def_property_readonly("integration_points",
                           [](const Model & model) { return ArrayFromPoints(model.meshless.integrationPoints); })
    .def("boundary_nodes", [](const Model & model) { return ArrayFromIndices(model.BoundaryNodes()); })
    .def("boundary_triangles", [](const Model & model) { return TriangleArray(model.BoundaryTriangles()); })
    .def("validate", &Model::Validate, "Raises Error naming the first bad cell, material or node set.")
    .def("__copy__", [](const Model & model) { return Model(model); })
    .def("__deepcopy__", [](const Model & model, const py::dict &) { return Model(model); }, py::arg("memo"))
    .def("copy", [](const Model & model) { return Model(model); })
    .def("__repr__", [](const Model & model) {
      const ModelCounts counts = CountModel(model);
      return "Model(" + std::to_string(counts.nodes) + " nodes, " + std::to_string(counts.cells) + " cells, " +
             std::to_string(counts.materials) + " materials" +
             (model.discretization == Discretization::Meshless
                ? ", meshless, " + std::to_string(counts.integrationPoints) + " integration points"
                : std::string()) +
             ")";
    });
}

void
BindModelClass(py::module_ & module)
{
  py::class_<Model> model(module, "Model",
                    "A mechanical model: nodes (mm), cells, materials, node sets, constraints, loads, contact "
                    "surfaces. Arrays are copies: assign to change them.");
  model
    .def(py::init([](const py::object & nodes, const py::object & cells, const std::vector<Material> & materials,
                     const py::object & cellMaterials, const std::map<std::string, py::object> & nodeSets) {
           Model model;
           model.nodes = PointsFromArray(nodes, "nodes");
           model.cells = CellsFromArray(cells);
           model.materials = materials.empty() ? std::vector<Material>{ Material{ "material" } } : materials;
           if (!cellMaterials.is_none())
           {
             const std::vector<Index> indices = IndicesFromArray(cellMaterials, "cell_materials");
             if (indices.size() != model.cells.size())
             {
               throw py::value_error("cell_materials has " + std::to_string(indices.size()) + " entries for " +
                                     std::to_string(model.cells.size()) + " cells");
             }
             for (std::size_t c = 0; c < indices.size(); ++c)
             {
               model.cells[c].material = indices[c];
             }
           }
           for (const auto & [name, ids] : nodeSets)
           {
             model.nodeSets[name] = IndicesFromArray(ids, "node set '" + name + "'");
           }
           model.Validate();
           return model;
         }),
         py::arg("nodes"), py::arg("cells"), py::arg("materials") = std::vector<Material>{},
         py::arg("cell_materials") = py::none(), py::arg("node_sets") = std::map<std::string, py::object>{},
         "Nodes (N, 3) mm; cells (M, 4) tetrahedra or (M, 8) hexahedra in VTK order (-1 in the last four columns "
         "for a tetrahedron of a mixed mesh); one material for every cell unless cell_materials indexes materials.")
    .def_property(
      "nodes", [](const Model & model) { return ArrayFromPoints(model.nodes); },
      [](Model & model, const py::object & nodes) {
        std::vector<Vector3> points = PointsFromArray(nodes, "nodes");
        if (points.size() != model.nodes.size())
        {
          throw py::value_error("the model has " + std::to_string(model.nodes.size()) + " nodes; got " +
                                std::to_string(points.size()));
        }
        model.nodes = std::move(points);
      })
    .def_property_readonly("cells", &CellArray)
    .def_property_readonly("cell_types",
                           [](const Model & model) {
                             py::array_t<std::uint8_t> types(static_cast<py::ssize_t>(model.cells.size()));
                             for (std::size_t c = 0; c < model.cells.size(); ++c)
                             {
                               types.mutable_at(static_cast<py::ssize_t>(c)) =
                                 model.cells[c].type == CellType::Hexahedron ? kVtkHexahedron : kVtkTetra;
                             }
                             return types;
                           },
                           "VTK cell type per cell: 12 hexahedron, 10 tetrahedron.")
    .def_property(
      "cell_materials",
      [](const Model & model) {
        std::vector<Index> indices;
        for (const Cell & cell : model.cells)
        {
          indices.push_back(cell.material);
        }
        return ArrayFromIndices(indices);
      },
      [](Model & model, const py::object & values) {
        const std::vector<Index> indices = IndicesFromArray(values, "cell_materials");
        if (indices.size() != model.cells.size())
        {
          throw py::value_error("cell_materials needs one entry per cell (" + std::to_string(model.cells.size()) + ")");
        }
        for (std::size_t c = 0; c < indices.size(); ++c)
        {
          model.cells[c].material = indices[c];
        }
      })
    .def_readwrite("materials", &Model::materials)
    .def_property_readonly("node_sets",
                           [](const Model & model) {
                             py::dict sets;
                             for (const auto & [name, ids] : model.nodeSets)
                             {
                               sets[py::str(name)] = ArrayFromIndices(ids);
                             }
                             return sets;
                           })
    .def(
      "add_node_set",
      [](Model & model, const std::string & name, const py::object & nodes) {
        model.nodeSets[name] = IndicesFromArray(nodes, "node set '" + name + "'");
      },
      py::arg("name"), py::arg("nodes"));
  BindModelLoads(model);
}

void
BindModel(py::module_ & module)
{
  BindMaterials(module);
  BindSurfacesAndLoads(module);
  BindTools(module);
  BindModelClass(module);
}

void
BindSolver(py::module_ & module)
{
  auto solverSettings =
    py::class_<SolverSettings>(module, "SolverSettings",
                               "Settings of the TLED solver: the attributes are the scene file's \"solver\" keys "
                               "(one table: docs/scene-format.md, biomech settings --markdown).")
      .def(py::init([](const py::kwargs & values) {
        SolverSettings settings;
        py::object     object = py::cast(settings);
        for (const auto & [key, value] : values)
        {
          if (FindSolverSetting(py::str(key)) == nullptr)
          {
            throw py::type_error("SolverSettings has no setting '" + std::string(py::str(key)) + "'");
          }
          object.attr(key) = value;
        }
        return object.cast<SolverSettings>();
      }));
  // One property per row of the table; a setter checks the value as the scene parser does.
  for (const SolverSettingField & field : SolverSettingFields())
  {
    const SolverSettingField * row = &field;
    solverSettings.def_property(
      field.name.c_str(),
      [row](const SolverSettings & settings) { return SettingValueToPython(*row, settings); },
      [row](SolverSettings & settings, const py::object & value) { row->set(settings, SettingValueFromPython(*row, value)); },
      (field.meaning + (field.unit.empty() ? std::string() : " (" + field.unit + ")")).c_str());
  }
  solverSettings
    .def("copy", [](const SolverSettings & settings) { return SolverSettings(settings); })
    .def("__repr__", [](const SolverSettings & settings) {
      std::ostringstream text;
      text << "SolverSettings(integrator='" << IntegratorName(settings.integrator) << "', tolerance=" << settings.tolerance
           << ", max_steps=" << settings.maxSteps << ", end_time=" << settings.endTime << ")";
      return text.str();
    });

  py::class_<SolveResult>(module, "SolveResult", "Displacements (mm), reaction forces (N) and convergence of a solve.")
    .def_property_readonly("displacements", [](const SolveResult & result) { return ArrayFromPoints(result.displacements); })
    .def_property_readonly("reaction_forces",
                           [](const SolveResult & result) { return ArrayFromPoints(result.reactionForces); })
    .def_property_readonly("cauchy_stress",
                           [](const SolveResult & result) {
                             py::array_t<double> array(
                               { static_cast<py::ssize_t>(result.cauchyStress.size()), py::ssize_t{ 3 }, py::ssize_t{ 3 } });
                             auto view = array.mutable_unchecked<3>();
                             for (std::size_t c = 0; c < result.cauchyStress.size(); ++c)
                             {
                               for (int i = 0; i < 3; ++i)
                                 for (int j = 0; j < 3; ++j)
                                   view(static_cast<py::ssize_t>(c), i, j) = result.cauchyStress[c](i, j);
                             }
                             return array;
                           },
                           "Cauchy stress (Pa) per cell (meshless: per integration point) when compute_stress was on.")
    .def_property_readonly("nodal_parameters",
                           [](const SolveResult & result) { return ArrayFromPoints(result.nodalParameters); })
    .def_readonly("converged", &SolveResult::converged)
    .def_readonly("steps", &SolveResult::steps)
    .def_readonly("time_step", &SolveResult::timeStep)
    .def_readonly("critical_time_step", &SolveResult::criticalTimeStep)
    .def_readonly("estimated_error", &SolveResult::estimatedError)
    .def_readonly("convergence_rate", &SolveResult::convergenceRate)
    .def_readonly("restarts", &SolveResult::restarts)
    .def_readonly("warm_started", &SolveResult::warmStarted, "Began from an earlier solve's steady state (update's previous).")
    .def_readonly("lowest_eigenvalue", &SolveResult::lowestEigenvalue,
                  "Dynamic relaxation: the damping's lowest-eigenvalue estimate at the end (a diagnostic).")
    .def_readonly("wall_seconds", &SolveResult::wallSeconds)
    .def_readonly("max_displacement", &SolveResult::maxDisplacement)
    .def_readonly("strain_energy", &SolveResult::strainEnergy)
    .def_readonly("hourglass_energy", &SolveResult::hourglassEnergy)
    .def_readonly("kinetic_energy", &SolveResult::kineticEnergy)
    .def_readonly("contact_nodes", &SolveResult::contactNodes)
    .def_readonly("max_penetration", &SolveResult::maxPenetration)
    .def_readonly("warnings", &SolveResult::warnings)
    .def_readonly("active_components", &SolveResult::activeComponents)
    .def_readonly("tools", &SolveResult::tools, "Per tool: its motion and the tissue's load on it (ToolHistory).")
    .def_readonly("message", &SolveResult::message)
    .def("__repr__", [](const SolveResult & result) {
      std::ostringstream text;
      text << "SolveResult(" << (result.converged ? "converged" : "NOT CONVERGED") << ", " << result.steps
           << " steps, max displacement " << result.maxDisplacement << " mm, estimated error " << result.estimatedError
           << " mm)";
      return text.str();
    });

  py::class_<Scene>(module, "Scene", "A parsed scene file (docs/scene-format.md): model, solver settings, outputs.")
    .def_readonly("path", &Scene::path)
    .def_readonly("description", &Scene::description)
    .def_readonly("mesh_source", &Scene::meshSource)
    .def_readwrite("model", &Scene::model)
    .def_readwrite("settings", &Scene::settings)
    .def_readonly("result_vtu_file", &Scene::resultVtuFile)
    .def_readonly("report_file", &Scene::reportFile)
    .def("__repr__", [](const Scene & scene) { return "Scene('" + scene.path + "')"; });

  module.def("read_scene", [](const std::filesystem::path & path) { return ReadScene(path.string()); }, py::arg("path"), "Reads a scene file (JSON, docs/scene-format.md).");
  module.def("parse_scene", [](const std::string & text, const std::filesystem::path & path) { return ParseScene(text, path.string()); }, py::arg("text"), py::arg("path"),
             "Parses scene JSON text as if it were the file `path` (relative paths inside it are relative to its folder).");

  module.def(
    "_solve",
    [](const Model & model, const SolverSettings & settings, const py::object & progress, const py::object & frames) {
      ProgressReporter    reporter(progress);
      const FrameCallback onFrame = reporter.FrameForwarder(frames);
      return RunWithoutGil(reporter, [&] {
        Solver solver(model, settings);
        return solver.Solve(reporter.SolverCallback(), onFrame);
      });
    },
    py::arg("model"), py::arg("settings"), py::arg("progress") = py::none(), py::arg("frames") = py::none());

  module.def(
    "report_json", [](const Scene & scene, const SolveResult & result) {
      return py::module_::import("json").attr("loads")(MakeReportJson(scene, result));
    },
    py::arg("scene"), py::arg("result"), "The run report of `biomech solve` (keys in docs/scene-format.md) as a dict.");
  module.def("format_report", &FormatReportTable, py::arg("scene"), py::arg("result"));
}

} // namespace

} // namespace bmr::python

PYBIND11_MODULE(_bmr, module)
{
  using namespace bmr::python;
  module.doc() = "C++ core of biomechanical_registration; use the package, not this module.";
  BindErrors(module);
  BindModel(module);
  BindSolver(module);
  BindFiles(module);
  BindModelBuilding(module);
  BindLoads(module);
  BindImages(module);
}
