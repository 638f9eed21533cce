// VTK files of the module: volume meshes, results, surfaces, integration
// points, and the atomic writes every output goes through. Over 800 lines:
// the readers and writers share the conversions and the error handling.
#include "bmrMeshIO.h"

#include "bmrAtomicWrite.h"

#include <vtkCellArray.h>
#include <vtkCellData.h>
#include <vtkCellType.h>
#include <vtkCommand.h>
#include <vtkDataArray.h>
#include <vtkDoubleArray.h>
#include <vtkIdList.h>
#include <vtkIdTypeArray.h>
#include <vtkIntArray.h>
#include <vtkNew.h>
#include <vtkOBJReader.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataReader.h>
#include <vtkSTLReader.h>
#include <vtkSTLWriter.h>
#include <vtkPolyDataWriter.h>
#include <vtkXMLPolyDataWriter.h>
#include <vtkSmartPointer.h>
#include <vtkUnsignedCharArray.h>
#include <vtkUnstructuredGrid.h>
#include <vtkUnstructuredGridReader.h>
#include <vtkUnstructuredGridWriter.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLUnstructuredGridReader.h>
#include <vtkXMLUnstructuredGridWriter.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;

namespace bmr
{
namespace
{

std::string
LowerCaseExtension(const std::string & path)
{
  std::string extension = fs::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(), [](unsigned char c) {
    return static_cast<char>(std::tolower(c));
  });
  return extension;
}

/** Collects VTK error messages of one algorithm, so they end up in a
 *  bmr::Error instead of on the console. */
class ErrorCollector : public vtkCommand
{
public:
  static ErrorCollector * New() { return new ErrorCollector; }

  void Execute(vtkObject *, unsigned long, void * callData) override
  {
    if (callData != nullptr)
    {
      if (!m_Messages.empty())
      {
        m_Messages += "; ";
      }
      m_Messages += static_cast<const char *>(callData);
    }
  }
  bool                HasErrors() const { return !m_Messages.empty(); }
  const std::string & Messages() const { return m_Messages; }

private:
  std::string m_Messages;
};

void
RequireReadableFile(const std::string & path, const std::string & what)
{
  std::error_code error;
  if (!fs::exists(path, error))
  {
    throw Error(what + " '" + path + "' does not exist; check the path (relative paths in a scene are relative to the scene file)");
  }
  if (!fs::is_regular_file(path, error))
  {
    throw Error(what + " '" + path + "' is not a regular file");
  }
  std::ifstream probe(path, std::ios::binary);
  if (!probe)
  {
    throw Error(what + " '" + path + "' cannot be opened for reading; check its permissions");
  }
}

/** Runs a reader with errors captured; throws bmr::Error naming the path. */
template <typename ReaderType>
void
UpdateReader(ReaderType * reader, const std::string & path, const std::string & what)
{
  vtkNew<ErrorCollector> errors;
  reader->AddObserver(vtkCommand::ErrorEvent, errors);
  reader->SetFileName(path.c_str());
  // The XML parser and the pipeline print their own errors to the terminal;
  // ours below says the same in one line, naming the file.
  const int warningDisplay = vtkObject::GetGlobalWarningDisplay();
  vtkObject::GlobalWarningDisplayOff();
  reader->Update();
  vtkObject::SetGlobalWarningDisplay(warningDisplay);
  if (errors->HasErrors() || reader->GetErrorCode() != 0)
  {
    std::string detail = errors->HasErrors() ? errors->Messages() : "VTK error code " + std::to_string(reader->GetErrorCode());
    // VTK messages end with blank lines; keep the message on one line.
    detail.erase(std::remove(detail.begin(), detail.end(), '\n'), detail.end());
    throw Error(what + " '" + path + "' could not be read: " + detail);
  }
}

DataArray
CopyDataArray(vtkDataArray * array)
{
  DataArray copy;
  copy.components = array->GetNumberOfComponents();
  const vtkIdType tuples = array->GetNumberOfTuples();
  copy.values.resize(static_cast<std::size_t>(tuples) * copy.components);
  for (vtkIdType tuple = 0; tuple < tuples; ++tuple)
  {
    for (int component = 0; component < copy.components; ++component)
    {
      copy.values[tuple * copy.components + component] = array->GetComponent(tuple, component);
    }
  }
  return copy;
}

const char *
VtkCellTypeName(int type)
{
  switch (type)
  {
    case VTK_VERTEX: return "VTK_VERTEX";
    case VTK_LINE: return "VTK_LINE";
    case VTK_TRIANGLE: return "VTK_TRIANGLE";
    case VTK_QUAD: return "VTK_QUAD";
    case VTK_POLYGON: return "VTK_POLYGON";
    case VTK_TETRA: return "VTK_TETRA";
    case VTK_VOXEL: return "VTK_VOXEL";
    case VTK_HEXAHEDRON: return "VTK_HEXAHEDRON";
    case VTK_WEDGE: return "VTK_WEDGE";
    case VTK_PYRAMID: return "VTK_PYRAMID";
    case VTK_QUADRATIC_TETRA: return "VTK_QUADRATIC_TETRA";
    case VTK_QUADRATIC_HEXAHEDRON: return "VTK_QUADRATIC_HEXAHEDRON";
    default: return "another VTK cell type";
  }
}

MeshData
ConvertUnstructuredGrid(vtkUnstructuredGrid * grid, const std::string & path, const std::string & labelArray)
{
  MeshData mesh;
  const vtkIdType pointCount = grid->GetNumberOfPoints();
  const vtkIdType cellCount = grid->GetNumberOfCells();
  // A mesh without cells is a meshless point cloud; the scene decides whether it may be one.
  if (pointCount == 0)
  {
    throw Error("mesh '" + path +
                "' has no points; a volume mesh of hexahedra (VTK_HEXAHEDRON) or tetrahedra (VTK_TETRA) is needed");
  }

  mesh.model.nodes.resize(pointCount);
  for (vtkIdType point = 0; point < pointCount; ++point)
  {
    double coordinates[3];
    grid->GetPoint(point, coordinates);
    mesh.model.nodes[point] = Vector3(coordinates[0], coordinates[1], coordinates[2]);
  }

  // VTK does not check a legacy file's cell arrays: in a damaged file, offsets
  // that run backwards or past the connectivity, or fewer cell types than
  // cells, crash the reading of the cells below. Check them first.
  vtkCellArray *         cellArray = grid->GetCells();
  vtkUnsignedCharArray * cellTypes = grid->GetCellTypesArray();
  if (cellCount > 0)
  {
    const auto damaged = [&](const std::string & what) {
      return Error("mesh '" + path + "' is damaged: " + what + "; write the file again (truncated or edited?)");
    };
    if (cellArray == nullptr || cellTypes == nullptr || cellTypes->GetNumberOfTuples() != cellCount)
    {
      throw damaged("it lists " + std::to_string(cellCount) + " cells but " +
                    std::to_string(cellTypes == nullptr ? 0 : cellTypes->GetNumberOfTuples()) + " cell types");
    }
    vtkDataArray *  offsets = cellArray->GetOffsetsArray();
    const vtkIdType connectivitySize = cellArray->GetNumberOfConnectivityIds();
    if (offsets == nullptr || offsets->GetNumberOfTuples() != cellCount + 1 || offsets->GetTuple1(0) != 0.0)
    {
      throw damaged("its cell offsets do not match its " + std::to_string(cellCount) + " cells");
    }
    for (vtkIdType cellId = 0; cellId < cellCount; ++cellId)
    {
      const double begin = offsets->GetTuple1(cellId), end = offsets->GetTuple1(cellId + 1);
      if (!(end >= begin && end <= static_cast<double>(connectivitySize)))
      {
        throw damaged("the point list of cell " + std::to_string(cellId) + " does not lie within the connectivity");
      }
    }
  }

  mesh.model.cells.resize(cellCount);
  vtkNew<vtkIdList> cellPoints;
  for (vtkIdType cellId = 0; cellId < cellCount; ++cellId)
  {
    const int vtkType = grid->GetCellType(cellId);
    Cell &    cell = mesh.model.cells[cellId];
    if (vtkType == VTK_HEXAHEDRON)
    {
      cell.type = CellType::Hexahedron;
    }
    else if (vtkType == VTK_TETRA)
    {
      cell.type = CellType::Tetrahedron;
    }
    else
    {
      throw Error("mesh '" + path + "': cell " + std::to_string(cellId) + " has type " + VtkCellTypeName(vtkType) +
                  " (" + std::to_string(vtkType) +
                  "); supported cell types are VTK_HEXAHEDRON (12) and VTK_TETRA (10)");
    }
    grid->GetCellPoints(cellId, cellPoints);
    const int nodeCount = NodesPerCell(cell.type);
    if (cellPoints->GetNumberOfIds() != nodeCount)
    {
      throw Error("mesh '" + path + "': cell " + std::to_string(cellId) + " has " +
                  std::to_string(cellPoints->GetNumberOfIds()) + " points, expected " + std::to_string(nodeCount));
    }
    for (int local = 0; local < nodeCount; ++local)
    {
      const vtkIdType point = cellPoints->GetId(local);
      if (point < 0 || point >= pointCount)
      {
        throw Error("mesh '" + path + "': cell " + std::to_string(cellId) + " refers to point " +
                    std::to_string(point) + ", which does not exist (the mesh has points 0 to " +
                    std::to_string(pointCount - 1) + ")");
      }
      cell.nodes[local] = static_cast<Index>(point);
    }
  }

  vtkPointData * pointData = grid->GetPointData();
  for (int arrayIndex = 0; arrayIndex < pointData->GetNumberOfArrays(); ++arrayIndex)
  {
    vtkDataArray * array = pointData->GetArray(arrayIndex);
    if (array != nullptr && array->GetName() != nullptr)
    {
      mesh.pointData[array->GetName()] = CopyDataArray(array);
    }
  }
  vtkCellData * cellData = grid->GetCellData();
  for (int arrayIndex = 0; arrayIndex < cellData->GetNumberOfArrays(); ++arrayIndex)
  {
    vtkDataArray * array = cellData->GetArray(arrayIndex);
    if (array != nullptr && array->GetName() != nullptr)
    {
      mesh.cellData[array->GetName()] = CopyDataArray(array);
    }
  }

  const auto labels = mesh.cellData.find(labelArray);
  if (!labelArray.empty() && labels != mesh.cellData.end())
  {
    if (labels->second.components != 1)
    {
      throw Error("mesh '" + path + "': cell-data array '" + labelArray + "' has " +
                  std::to_string(labels->second.components) + " components; material labels need exactly one");
    }
    if (labels->second.Tuples() != static_cast<std::size_t>(cellCount))
    {
      throw Error("mesh '" + path + "': cell-data array '" + labelArray + "' has " +
                  std::to_string(labels->second.Tuples()) + " values for " + std::to_string(cellCount) + " cells");
    }
    mesh.cellLabels.resize(cellCount);
    for (vtkIdType cellId = 0; cellId < cellCount; ++cellId)
    {
      const double value = labels->second.values[cellId];
      if (!std::isfinite(value) || value != std::round(value) || std::abs(value) > 2147483647.0)
      {
        std::ostringstream message;
        message << "mesh '" << path << "': cell " << cellId << " has material label " << value << " in array '"
                << labelArray << "'; labels must be 32-bit integers";
        throw Error(message.str());
      }
      mesh.cellLabels[cellId] = static_cast<int>(value);
    }
  }
  return mesh;
}

/** Cell or point data "youngs_modulus", "poisson_ratio", "density" of the
 *  material index that materialOf(i) gives for each of `count` items, and
 *  where any material is not neo-Hookean also "material_law" (the law's code,
 *  bmrMaterialLaw.h) and every law parameter (MaterialParameters(), e.g.
 *  "second_invariant_share"): files of neo-Hookean models stay as they were,
 *  and a reader takes missing laws as neo-Hookean. The values are MaterialKey's. */
template <typename MaterialOf>
void
AddMaterialProperties(vtkDataSetAttributes * attributes, const Model & model, MaterialOf && materialOf, std::size_t count)
{
  const bool laws = std::any_of(model.materials.begin(), model.materials.end(),
                                [](const Material & material) { return material.law != MaterialLaw::NeoHookean; });
  std::vector<std::string> names{ "youngs_modulus", "poisson_ratio", "density", "material_law" };
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    names.emplace_back(parameter.name);
  }
  std::vector<std::vector<double>> keys;
  for (const Material & material : model.materials)
  {
    keys.push_back(MaterialKey(material));
  }
  for (std::size_t property = 0; property < (laws ? names.size() : 3); ++property)
  {
    vtkNew<vtkDoubleArray> values;
    values->SetName(names[property].c_str());
    values->SetNumberOfTuples(static_cast<vtkIdType>(count));
    for (std::size_t item = 0; item < count; ++item)
    {
      const Index material = materialOf(item);
      if (material < 0 || static_cast<std::size_t>(material) >= model.materials.size())
      {
        throw Error("cannot write material properties: item " + std::to_string(item) + " refers to material " +
                    std::to_string(material) + ", which does not exist");
      }
      values->SetValue(static_cast<vtkIdType>(item), keys[material][property]);
    }
    attributes->AddArray(values);
  }
}

vtkSmartPointer<vtkUnstructuredGrid>
MakeGrid(const Model & model)
{
  auto      grid = vtkSmartPointer<vtkUnstructuredGrid>::New();
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(static_cast<vtkIdType>(model.nodes.size()));
  for (std::size_t node = 0; node < model.nodes.size(); ++node)
  {
    points->SetPoint(static_cast<vtkIdType>(node), model.nodes[node].data());
  }
  grid->SetPoints(points);

  grid->Allocate(static_cast<vtkIdType>(model.cells.size()));
  vtkNew<vtkIntArray> material;
  material->SetName("material");
  material->SetNumberOfTuples(static_cast<vtkIdType>(model.cells.size()));
  for (std::size_t cellId = 0; cellId < model.cells.size(); ++cellId)
  {
    const Cell & cell = model.cells[cellId];
    const int    nodeCount = NodesPerCell(cell.type);
    vtkIdType    ids[8];
    for (int local = 0; local < nodeCount; ++local)
    {
      ids[local] = cell.nodes[local];
    }
    grid->InsertNextCell(cell.type == CellType::Hexahedron ? VTK_HEXAHEDRON : VTK_TETRA, nodeCount, ids);
    material->SetValue(static_cast<vtkIdType>(cellId), cell.material);
  }
  grid->GetCellData()->AddArray(material);
  // A mesh whose cells carry labels rather than material indices (no such
  // materials) is written with its labels only.
  const bool materialsResolved = std::all_of(model.cells.begin(), model.cells.end(), [&](const Cell & cell) {
    return cell.material >= 0 && static_cast<std::size_t>(cell.material) < model.materials.size();
  });
  if (!model.cells.empty() && materialsResolved)
  {
    AddMaterialProperties(grid->GetCellData(), model, [&](std::size_t cellId) { return model.cells[cellId].material; },
                          model.cells.size());
  }
  return grid;
}

template <typename WriterType>
void
RunWriter(WriterType * writer, const std::string & temporaryPath, const std::string & path, const std::string & what)
{
  vtkNew<ErrorCollector> errors;
  writer->AddObserver(vtkCommand::ErrorEvent, errors);
  writer->SetFileName(temporaryPath.c_str());
  if (writer->Write() != 1 || errors->HasErrors())
  {
    throw Error("cannot write " + what + " '" + path + "': " +
                (errors->HasErrors() ? errors->Messages() : std::string("the VTK writer failed")));
  }
}

void
WriteGrid(vtkUnstructuredGrid * grid, const std::string & path, const std::string & what)
{
  const std::string extension = LowerCaseExtension(path);
  if (extension != ".vtu" && extension != ".vtk")
  {
    throw Error("cannot write " + what + " '" + path + "': the file name must end in .vtu (XML) or .vtk (legacy)");
  }
  WriteAtomically(path, what, [&](const std::string & temporaryPath) {
    if (extension == ".vtu")
    {
      vtkNew<vtkXMLUnstructuredGridWriter> writer;
      writer->SetInputData(grid);
      writer->SetDataModeToAppended();
      writer->EncodeAppendedDataOff();
      // zlib's fastest level: VTK's default 5 took 0.7 s more to write the
      // 4.25 mm meshless Colin27 model's files, for files 1-2 % smaller.
      writer->SetCompressionLevel(1);
      RunWriter(writer.Get(), temporaryPath, path, what);
    }
    else
    {
      vtkNew<vtkUnstructuredGridWriter> writer;
      writer->SetInputData(grid);
      writer->SetFileTypeToASCII();
      RunWriter(writer.Get(), temporaryPath, path, what);
    }
  });
}

} // namespace

MeshData
ReadMesh(const std::string & path, const std::string & labelArray)
{
  RequireReadableFile(path, "mesh");
  const std::string extension = LowerCaseExtension(path);
  if (extension == ".vtu")
  {
    vtkNew<vtkXMLUnstructuredGridReader> reader;
    UpdateReader(reader.Get(), path, "mesh");
    return ConvertUnstructuredGrid(reader->GetOutput(), path, labelArray);
  }
  if (extension == ".vtk")
  {
    vtkNew<vtkUnstructuredGridReader> reader;
    UpdateReader(reader.Get(), path, "mesh");
    if (!reader->IsFileUnstructuredGrid())
    {
      throw Error("mesh '" + path + "' is a legacy VTK file but not an UNSTRUCTURED_GRID; a volume mesh is needed");
    }
    return ConvertUnstructuredGrid(reader->GetOutput(), path, labelArray);
  }
  throw Error("mesh '" + path + "' has an unsupported extension '" + extension +
              "'; supported are .vtu (VTK XML) and .vtk (legacy VTK unstructured grid)");
}

void
WriteMesh(const std::string & path, const Model & model)
{
  auto grid = MakeGrid(model);
  for (const auto & [name, ids] : model.nodeSets)
  {
    vtkNew<vtkUnsignedCharArray> mask;
    mask->SetName(name.c_str());
    mask->SetNumberOfTuples(static_cast<vtkIdType>(model.nodes.size()));
    mask->FillValue(0);
    for (const Index node : ids)
    {
      if (node < 0 || static_cast<std::size_t>(node) >= model.nodes.size())
      {
        throw Error("cannot write mesh '" + path + "': node set '" + name + "' refers to node " +
                    std::to_string(node) + ", which does not exist");
      }
      mask->SetValue(node, 1);
    }
    grid->GetPointData()->AddArray(mask);
  }
  WriteGrid(grid, path, "mesh");
}

void
WriteResultVtu(const std::string & path, const Model & model, const SolveResult & result)
{
  const std::size_t nodeCount = model.nodes.size();
  if (result.displacements.size() != nodeCount)
  {
    throw Error("cannot write result '" + path + "': " + std::to_string(result.displacements.size()) +
                " displacements for " + std::to_string(nodeCount) + " nodes");
  }
  auto grid = MakeGrid(model);

  vtkNew<vtkDoubleArray> displacement;
  displacement->SetName("displacement");
  displacement->SetNumberOfComponents(3);
  displacement->SetNumberOfTuples(static_cast<vtkIdType>(nodeCount));
  vtkNew<vtkDoubleArray> reaction;
  reaction->SetName("reaction_force");
  reaction->SetNumberOfComponents(3);
  reaction->SetNumberOfTuples(static_cast<vtkIdType>(nodeCount));
  for (std::size_t node = 0; node < nodeCount; ++node)
  {
    displacement->SetTuple(static_cast<vtkIdType>(node), result.displacements[node].data());
    const Vector3 force = node < result.reactionForces.size() ? result.reactionForces[node] : Vector3::Zero();
    reaction->SetTuple(static_cast<vtkIdType>(node), force.data());
  }
  grid->GetPointData()->AddArray(displacement);
  grid->GetPointData()->AddArray(reaction);
  grid->GetPointData()->SetActiveVectors("displacement");
  if (!result.nodalParameters.empty())
  {
    // Meshless: the MLS field's parameters, so the field can be evaluated anywhere later.
    vtkNew<vtkDoubleArray> parameters;
    parameters->SetName("mls_nodal_parameter");
    parameters->SetNumberOfComponents(3);
    parameters->SetNumberOfTuples(static_cast<vtkIdType>(nodeCount));
    for (std::size_t node = 0; node < nodeCount; ++node)
    {
      parameters->SetTuple(static_cast<vtkIdType>(node), result.nodalParameters[node].data());
    }
    grid->GetPointData()->AddArray(parameters);
  }

  if (!result.cauchyStress.empty())
  {
    if (result.cauchyStress.size() != model.cells.size())
    {
      throw Error("cannot write result '" + path + "': " + std::to_string(result.cauchyStress.size()) +
                  " stress tensors for " + std::to_string(model.cells.size()) + " cells");
    }
    vtkNew<vtkDoubleArray> stress;
    stress->SetName("cauchy_stress");
    stress->SetNumberOfComponents(9);
    stress->SetNumberOfTuples(static_cast<vtkIdType>(model.cells.size()));
    for (std::size_t cellId = 0; cellId < model.cells.size(); ++cellId)
    {
      const Eigen::Matrix3d & sigma = result.cauchyStress[cellId];
      double                  rowMajor[9];
      for (int row = 0; row < 3; ++row)
      {
        for (int column = 0; column < 3; ++column)
        {
          rowMajor[3 * row + column] = sigma(row, column);
        }
      }
      stress->SetTuple(static_cast<vtkIdType>(cellId), rowMajor);
    }
    grid->GetCellData()->AddArray(stress);
  }

  if (LowerCaseExtension(path) != ".vtu")
  {
    throw Error("cannot write result '" + path + "': the file name must end in .vtu");
  }
  WriteGrid(grid, path, "result");
}

ContactSurface
ReadSurface(const std::string & path)
{
  RequireReadableFile(path, "surface");
  const std::string         extension = LowerCaseExtension(path);
  vtkSmartPointer<vtkPolyData> polyData;
  if (extension == ".stl")
  {
    vtkNew<vtkSTLReader> reader;
    UpdateReader(reader.Get(), path, "surface");
    polyData = reader->GetOutput();
  }
  else if (extension == ".obj")
  {
    vtkNew<vtkOBJReader> reader;
    UpdateReader(reader.Get(), path, "surface");
    polyData = reader->GetOutput();
  }
  else if (extension == ".vtp")
  {
    vtkNew<vtkXMLPolyDataReader> reader;
    UpdateReader(reader.Get(), path, "surface");
    polyData = reader->GetOutput();
  }
  else if (extension == ".vtk")
  {
    vtkNew<vtkPolyDataReader> reader;
    UpdateReader(reader.Get(), path, "surface");
    if (!reader->IsFilePolyData())
    {
      throw Error("surface '" + path + "' is a legacy VTK file but not POLYDATA; a triangulated surface is needed");
    }
    polyData = reader->GetOutput();
  }
  else
  {
    throw Error("surface '" + path + "' has an unsupported extension '" + extension +
                "'; supported are .stl, .obj, .vtp and .vtk (legacy polydata)");
  }

  ContactSurface surface;
  surface.name = fs::path(path).stem().string();

  // Merge coincident points exactly: STL stores every vertex once per triangle.
  std::map<std::array<double, 3>, Index> mergedIndex;
  std::vector<Index>                     pointToVertex(polyData->GetNumberOfPoints(), -1);
  auto                                   vertexOf = [&](vtkIdType point) {
    Index & cached = pointToVertex[point];
    if (cached < 0)
    {
      double coordinates[3];
      polyData->GetPoint(point, coordinates);
      const std::array<double, 3> key{ coordinates[0], coordinates[1], coordinates[2] };
      const auto [position, inserted] = mergedIndex.emplace(key, static_cast<Index>(surface.vertices.size()));
      if (inserted)
      {
        surface.vertices.emplace_back(coordinates[0], coordinates[1], coordinates[2]);
      }
      cached = position->second;
    }
    return cached;
  };
  auto addTriangle = [&](vtkIdType a, vtkIdType b, vtkIdType c) {
    const std::array<Index, 3> triangle{ vertexOf(a), vertexOf(b), vertexOf(c) };
    // A triangle that collapsed when its points were merged has no area and no normal.
    if (triangle[0] != triangle[1] && triangle[1] != triangle[2] && triangle[0] != triangle[2])
    {
      surface.triangles.push_back(triangle);
    }
  };

  vtkNew<vtkIdList> cellPoints;
  for (vtkIdType cellId = 0; cellId < polyData->GetNumberOfCells(); ++cellId)
  {
    const int type = polyData->GetCellType(cellId);
    polyData->GetCellPoints(cellId, cellPoints);
    const vtkIdType count = cellPoints->GetNumberOfIds();
    if (type == VTK_TRIANGLE || type == VTK_QUAD || type == VTK_POLYGON)
    {
      // Fan triangulation keeps the polygon's orientation (exact for convex polygons).
      for (vtkIdType k = 1; k + 1 < count; ++k)
      {
        addTriangle(cellPoints->GetId(0), cellPoints->GetId(k), cellPoints->GetId(k + 1));
      }
    }
    else if (type == VTK_TRIANGLE_STRIP)
    {
      for (vtkIdType k = 0; k + 2 < count; ++k)
      {
        // Every second triangle of a strip is reversed to keep one orientation.
        if (k % 2 == 0)
        {
          addTriangle(cellPoints->GetId(k), cellPoints->GetId(k + 1), cellPoints->GetId(k + 2));
        }
        else
        {
          addTriangle(cellPoints->GetId(k + 1), cellPoints->GetId(k), cellPoints->GetId(k + 2));
        }
      }
    }
    // Vertices and lines carry no surface and are skipped.
  }

  if (surface.triangles.empty())
  {
    throw Error("surface '" + path + "' has no triangles (no polygons with area); a triangulated surface is needed");
  }
  // Drop vertices that only collapsed triangles used.
  std::vector<Index> compactIndex(surface.vertices.size(), -1);
  for (const auto & triangle : surface.triangles)
  {
    for (const Index vertex : triangle)
    {
      compactIndex[vertex] = 0;
    }
  }
  std::vector<Vector3> usedVertices;
  for (std::size_t vertex = 0; vertex < surface.vertices.size(); ++vertex)
  {
    if (compactIndex[vertex] == 0)
    {
      compactIndex[vertex] = static_cast<Index>(usedVertices.size());
      usedVertices.push_back(surface.vertices[vertex]);
    }
  }
  for (auto & triangle : surface.triangles)
  {
    for (Index & vertex : triangle)
    {
      vertex = compactIndex[vertex];
    }
  }
  surface.vertices = std::move(usedVertices);
  return surface;
}

void
WriteSurface(const std::string & path, const ContactSurface & surface)
{
  const std::string extension = LowerCaseExtension(path);
  if (extension != ".vtp" && extension != ".stl" && extension != ".vtk")
  {
    throw Error("cannot write surface '" + path + "': the file name must end in .vtp, .stl or .vtk");
  }
  if (surface.triangles.empty())
  {
    throw Error("cannot write surface '" + path + "': the surface has no triangles");
  }
  vtkNew<vtkPolyData> polyData;
  vtkNew<vtkPoints>   points;
  points->SetDataTypeToDouble();
  for (const Vector3 & vertex : surface.vertices)
  {
    points->InsertNextPoint(vertex.data());
  }
  vtkNew<vtkCellArray> polygons;
  for (const auto & triangle : surface.triangles)
  {
    const vtkIdType ids[3] = { triangle[0], triangle[1], triangle[2] };
    polygons->InsertNextCell(3, ids);
  }
  polyData->SetPoints(points);
  polyData->SetPolys(polygons);
  WriteAtomically(path, "surface", [&](const std::string & temporaryPath) {
    if (extension == ".vtp")
    {
      vtkNew<vtkXMLPolyDataWriter> writer;
      writer->SetInputData(polyData);
      writer->SetDataModeToAppended();
      writer->EncodeAppendedDataOff();
      writer->SetCompressionLevel(1); // zlib's fastest, as WriteGrid
      RunWriter(writer.Get(), temporaryPath, path, "surface");
    }
    else if (extension == ".stl")
    {
      vtkNew<vtkSTLWriter> writer;
      writer->SetInputData(polyData);
      writer->SetFileTypeToBinary();
      RunWriter(writer.Get(), temporaryPath, path, "surface");
    }
    else
    {
      vtkNew<vtkPolyDataWriter> writer;
      writer->SetInputData(polyData);
      writer->SetFileTypeToASCII();
      RunWriter(writer.Get(), temporaryPath, path, "surface");
    }
  });
}

void
WriteIntegrationPoints(const std::string & path, const Model & model)
{
  const MeshlessDiscretization & meshless = model.meshless;
  if (model.discretization != Discretization::Meshless || meshless.integrationPoints.empty())
  {
    throw Error("cannot write integration points '" + path + "': the model is not meshless (it has no integration points)");
  }
  if (LowerCaseExtension(path) != ".vtu")
  {
    throw Error("cannot write integration points '" + path + "': the file name must end in .vtu");
  }
  const std::size_t count = meshless.integrationPoints.size();
  auto              grid = vtkSmartPointer<vtkUnstructuredGrid>::New();
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(static_cast<vtkIdType>(count));
  grid->Allocate(static_cast<vtkIdType>(count));
  vtkNew<vtkDoubleArray> weights;
  weights->SetName("weight");
  weights->SetNumberOfTuples(static_cast<vtkIdType>(count));
  for (std::size_t point = 0; point < count; ++point)
  {
    points->SetPoint(static_cast<vtkIdType>(point), meshless.integrationPoints[point].data());
    const vtkIdType id = static_cast<vtkIdType>(point);
    grid->InsertNextCell(VTK_VERTEX, 1, &id);
    weights->SetValue(id, meshless.integrationWeights[point]);
  }
  grid->SetPoints(points);
  grid->GetPointData()->AddArray(weights);
  AddMaterialProperties(grid->GetPointData(), model, [&](std::size_t point) { return meshless.integrationMaterials[point]; },
                        count);
  WriteGrid(grid, path, "integration points");
}

IntegrationPointData
ReadIntegrationPoints(const std::string & path)
{
  RequireReadableFile(path, "integration points");
  if (LowerCaseExtension(path) != ".vtu")
  {
    throw Error("integration points '" + path + "': the file name must end in .vtu");
  }
  vtkNew<vtkXMLUnstructuredGridReader> reader;
  UpdateReader(reader.Get(), path, "integration points");
  vtkUnstructuredGrid * grid = reader->GetOutput();
  const vtkIdType       count = grid->GetNumberOfPoints();
  if (count == 0)
  {
    throw Error("integration points '" + path + "' has no points");
  }
  auto requireArray = [&](const char * name) {
    vtkDataArray * array = grid->GetPointData()->GetArray(name);
    if (array == nullptr || array->GetNumberOfComponents() != 1 || array->GetNumberOfTuples() != count)
    {
      throw Error("integration points '" + path + "' needs a point-data array '" + name +
                  "' with one value per point (files written by `biomech model` have it)");
    }
    return array;
  };
  vtkDataArray *       weights = requireArray("weight");
  vtkDataArray *       youngs = requireArray("youngs_modulus");
  vtkDataArray *       poisson = requireArray("poisson_ratio");
  vtkDataArray *       density = requireArray("density");
  // Written only for models with a law other than neo-Hookean (AddMaterialProperties).
  vtkDataArray *              law = grid->GetPointData()->GetArray("material_law");
  std::vector<vtkDataArray *> parameters;
  std::string                 lawArrays = "'material_law'";
  bool                        consistent = law == nullptr || law->GetNumberOfTuples() == count;
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    parameters.push_back(grid->GetPointData()->GetArray(parameter.name));
    lawArrays += std::string(", '") + parameter.name + "'";
    consistent = consistent && (law == nullptr) == (parameters.back() == nullptr) &&
                 (parameters.back() == nullptr || parameters.back()->GetNumberOfTuples() == count);
  }
  if (!consistent)
  {
    throw Error("integration points '" + path + "' needs all the point-data arrays " + lawArrays +
                " with one value per point, or none (neo-Hookean)");
  }
  IntegrationPointData data;
  data.positions.resize(count);
  data.weights.resize(count);
  data.materials.resize(count);
  for (vtkIdType point = 0; point < count; ++point)
  {
    grid->GetPoint(point, data.positions[point].data());
    data.weights[point] = weights->GetTuple1(point);
    Material & material = data.materials[point];
    material.youngsModulus = youngs->GetTuple1(point);
    material.poissonRatio = poisson->GetTuple1(point);
    material.density = density->GetTuple1(point);
    if (law != nullptr)
    {
      try
      {
        material.law = MaterialLawOfCode(law->GetTuple1(point));
      }
      catch (const Error & error)
      {
        throw Error("integration points '" + path + "': point " + std::to_string(point) + ": " + error.what());
      }
      for (std::size_t k = 0; k < parameters.size(); ++k)
      {
        material.*MaterialParameters()[k].value = parameters[k]->GetTuple1(point);
      }
      if (const std::string problem = MaterialLawProblem(material); !problem.empty())
      {
        throw Error("integration points '" + path + "': point " + std::to_string(point) + " " + problem);
      }
    }
    const bool valid = std::isfinite(data.positions[point].sum()) && data.weights[point] > 0.0 &&
                       material.youngsModulus > 0.0 && material.poissonRatio > -1.0 && material.poissonRatio < 0.5 &&
                       material.density > 0.0;
    if (!valid)
    {
      throw Error("integration points '" + path + "': point " + std::to_string(point) +
                  " has an invalid weight or material (weight and E, density > 0, -1 < nu < 0.5, finite position)");
    }
  }
  return data;
}

void
WriteTextFileAtomically(const std::string & path, const std::string & text)
{
  WriteAtomically(path, "file", [&](const std::string & temporaryPath) {
    std::ofstream stream(temporaryPath, std::ios::binary | std::ios::trunc);
    stream << text;
    stream.close();
    if (!stream)
    {
      throw Error("cannot write file '" + path + "': writing the temporary file '" + temporaryPath + "' failed");
    }
  });
}

} // namespace bmr
