#include "bmrMeshIO.h"

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
  if (pointCount == 0 || cellCount == 0)
  {
    throw Error("mesh '" + path + "' has no " + (pointCount == 0 ? "points" : "cells") +
                "; a volume mesh of hexahedra (VTK_HEXAHEDRON) or tetrahedra (VTK_TETRA) is needed");
  }

  mesh.model.nodes.resize(pointCount);
  for (vtkIdType point = 0; point < pointCount; ++point)
  {
    double coordinates[3];
    grid->GetPoint(point, coordinates);
    mesh.model.nodes[point] = Vector3(coordinates[0], coordinates[1], coordinates[2]);
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
      cell.nodes[local] = static_cast<Index>(cellPoints->GetId(local));
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
    mesh.cellLabels.resize(cellCount);
    for (vtkIdType cellId = 0; cellId < cellCount; ++cellId)
    {
      const double value = labels->second.values[cellId];
      if (!std::isfinite(value) || value != std::round(value))
      {
        std::ostringstream message;
        message << "mesh '" << path << "': cell " << cellId << " has material label " << value << " in array '"
                << labelArray << "'; labels must be integers";
        throw Error(message.str());
      }
      mesh.cellLabels[cellId] = static_cast<int>(value);
    }
  }
  return mesh;
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
  return grid;
}

/** Writes through a temporary file in the target folder and renames it. */
template <typename WriteFunction>
void
WriteAtomically(const std::string & path, const std::string & what, WriteFunction && write)
{
  const fs::path target(path);
  const fs::path folder = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code error;
  if (!fs::is_directory(folder, error))
  {
    throw Error("cannot write " + what + " '" + path + "': folder '" + folder.string() + "' does not exist");
  }
  const fs::path temporary =
    folder / ("." + target.filename().string() + "." + std::to_string(::getpid()) + ".tmp");
  try
  {
    write(temporary.string());
  }
  catch (...)
  {
    fs::remove(temporary, error);
    throw;
  }
  fs::rename(temporary, target, error);
  if (error)
  {
    fs::remove(temporary, error);
    throw Error("cannot write " + what + " '" + path + "': renaming the temporary file failed: " + error.message());
  }
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
