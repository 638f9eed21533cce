#ifndef itkBiomechanicalModelObject_h
#define itkBiomechanicalModelObject_h

#include "itkCommonEnums.h"
#include "itkDataObject.h"
#include "itkDefaultStaticMeshTraits.h"
#include "itkMesh.h"
#include "itkPointSet.h"
#include "itkVector.h"
#include "itkObjectFactory.h"
#include "itkTriangleCell.h"

#include "bmrModel.h"

namespace bmr
{
class SolverPrecomputation; // bmrSolver.h
}

#include <algorithm>
#include <array>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace itk
{

/** Reference positions carrying displacements, both in double precision
 * (itk::PointSet's default coordinates are float): the loads, the solution,
 * the transform fitter's input. */
template <unsigned int VDimension>
using DisplacementPointSetType =
  PointSet<Vector<double, VDimension>, VDimension,
           DefaultStaticMeshTraits<Vector<double, VDimension>, VDimension, VDimension, double, double>>;

/** A triangle surface in double precision (mm): brain and skull surfaces,
 * intraoperative surfaces, contact masters. */
using BiomechanicalSurfaceMeshType = Mesh<double, 3, DefaultStaticMeshTraits<double, 3, 3, double, double>>;

/** \class BiomechanicalModelObject
 * \brief A biomechanical model (bmr::Model) as a pipeline data object.
 *
 * It carries everything the mechanics core solves: nodes (mm), cells
 * (hexahedra, tetrahedra) or, for a meshless model, the integration points
 * and the shape-function settings, the materials of every cell or
 * integration point, node sets, fixed and prescribed displacements, rigid
 * contact surfaces and gravity (bmrModel.h). An itk::Mesh holds one pixel
 * type per point and per cell and no integration points, so the model
 * travels between filters in this object: BiomechanicalGridImageFilter
 * produces it (GetModelOutput()) and BiomechanicalDeformationFilter consumes
 * it.
 *
 * It may also carry the model's Total Lagrangian precomputation
 * (bmr::SolverPrecomputation: shape-function derivatives, hourglass vectors,
 * MLS tables), made before surgery and read back from a model bundle; every
 * BiomechanicalDeformationFilter that solves the model then uses it instead
 * of computing its own. SetModel keeps it: a solve of a model whose reference
 * configuration it does not fit fails with an exception that names the
 * difference.
 *
 * \ingroup BiomechanicalRegistration
 */
class BiomechanicalModelObject : public DataObject
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BiomechanicalModelObject);

  using Self = BiomechanicalModelObject;
  using Superclass = DataObject;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BiomechanicalModelObject, DataObject);

  void
  SetModel(const bmr::Model & model)
  {
    m_Model = model;
    this->Modified();
  }
  void
  SetModel(bmr::Model && model)
  {
    m_Model = std::move(model);
    this->Modified();
  }
  const bmr::Model &
  GetModel() const
  {
    return m_Model;
  }

  /** The model's precomputation (null: none; each solve makes its own). */
  void
  SetPrecomputation(std::shared_ptr<const bmr::SolverPrecomputation> precomputation)
  {
    m_Precomputation = std::move(precomputation);
    this->Modified();
  }
  const std::shared_ptr<const bmr::SolverPrecomputation> &
  GetPrecomputation() const
  {
    return m_Precomputation;
  }

  void
  Initialize() override
  {
    Superclass::Initialize();
    m_Model = bmr::Model{};
    m_Precomputation.reset();
  }

  void
  Graft(const DataObject * data) override
  {
    if (const auto * other = dynamic_cast<const Self *>(data))
    {
      m_Model = other->m_Model;
      m_Precomputation = other->m_Precomputation;
    }
  }

protected:
  BiomechanicalModelObject() = default;
  ~BiomechanicalModelObject() override = default;

  void
  PrintSelf(std::ostream & os, Indent indent) const override
  {
    Superclass::PrintSelf(os, indent);
    os << indent << "Nodes: " << m_Model.nodes.size() << ", cells: " << m_Model.cells.size()
       << ", integration points: " << m_Model.meshless.integrationPoints.size()
       << ", materials: " << m_Model.materials.size() << std::endl;
    os << indent << "Precomputation: " << (m_Precomputation ? "yes" : "none") << std::endl;
  }

private:
  bmr::Model                                       m_Model;
  std::shared_ptr<const bmr::SolverPrecomputation> m_Precomputation;
};

/** A triangle itk::Mesh (mm) as the core's surface (bmr::ContactSurface with
 *  its defaults: body inside), its points numbered in container order. Throws
 *  ExceptionObject naming `what` for a mesh without triangles or with another
 *  cell type. */
template <typename TMesh>
bmr::ContactSurface
MakeContactSurfaceFromMesh(const TMesh * mesh, const std::string & what)
{
  bmr::ContactSurface surface;
  if (mesh == nullptr || mesh->GetPoints() == nullptr || mesh->GetNumberOfCells() == 0)
  {
    itkGenericExceptionMacro(<< "the " << what << " has no triangles; give a closed triangle mesh (mm).");
  }
  // Point identifiers to vertex numbers: a table where the identifiers are
  // dense (ITK's default vector containers number them 0..n-1), else a map
  // (a std::map alone took about 0.05 s per Colin27 isosurface, perf of `register`).
  IdentifierType largestId = 0;
  for (auto it = mesh->GetPoints()->Begin(); it != mesh->GetPoints()->End(); ++it)
  {
    largestId = std::max(largestId, it.Index());
  }
  const bool                           dense = largestId < 2 * mesh->GetPoints()->Size();
  std::vector<bmr::Index>              table(dense ? largestId + 1 : 0, -1);
  std::map<IdentifierType, bmr::Index> sparse;
  for (auto it = mesh->GetPoints()->Begin(); it != mesh->GetPoints()->End(); ++it)
  {
    const auto number = static_cast<bmr::Index>(surface.vertices.size());
    if (dense)
    {
      table[it.Index()] = number;
    }
    else
    {
      sparse[it.Index()] = number;
    }
    surface.vertices.emplace_back(it.Value()[0], it.Value()[1], it.Value()[2]);
  }
  const auto vertexOf = [&](IdentifierType id) -> bmr::Index {
    if (dense)
    {
      return id < table.size() ? table[id] : -1;
    }
    const auto found = sparse.find(id);
    return found != sparse.end() ? found->second : -1;
  };
  for (auto it = mesh->GetCells()->Begin(); it != mesh->GetCells()->End(); ++it)
  {
    const auto * cell = it.Value();
    if (cell->GetType() != CellGeometryEnum::TRIANGLE_CELL)
    {
      itkGenericExceptionMacro(<< "cell " << it.Index() << " of the " << what
                               << " is not a triangle; give a triangle mesh.");
    }
    std::array<bmr::Index, 3> triangle{};
    auto                      id = cell->PointIdsBegin();
    for (int v = 0; v < 3; ++v, ++id)
    {
      triangle[v] = vertexOf(*id);
      if (triangle[v] < 0)
      {
        itkGenericExceptionMacro(<< "cell " << it.Index() << " of the " << what << " refers to point " << *id
                                 << ", which the mesh does not have; give a mesh whose cells use its points.");
      }
    }
    surface.triangles.push_back(triangle);
  }
  return surface;
}

/** Marks a mesh or point set that a source filled whole as produced: its
 *  buffered region is the whole set, as is its requested region. Without
 *  this the buffered region stays unset (-1), every downstream Update()
 *  finds the requested region outside it, and the pipeline runs the source
 *  again (the brain-surface source, 1.8 s, ran once more in each
 *  registration). */
template <typename TPointSet>
void
MarkPointSetProduced(TPointSet * pointSet)
{
  pointSet->SetRequestedRegionToLargestPossibleRegion();
  pointSet->SetBufferedRegion(pointSet->GetRequestedRegion());
}

/** Positions (mm) as an ITK points container (of a mesh or point set), in order. */
template <typename TPointsContainer>
typename TPointsContainer::Pointer
MakePointsContainer(const std::vector<bmr::Vector3> & positions)
{
  auto container = TPointsContainer::New();
  container->Reserve(static_cast<typename TPointsContainer::ElementIdentifier>(positions.size()));
  for (std::size_t p = 0; p < positions.size(); ++p)
  {
    typename TPointsContainer::Element point;
    for (unsigned int d = 0; d < 3; ++d)
    {
      point[d] = positions[p][d];
    }
    container->SetElement(p, point);
  }
  return container;
}

/** The core's surface as a triangle itk::Mesh (mm): the inverse of
 *  MakeContactSurfaceFromMesh, points and triangles in the surface's order. */
template <typename TMesh>
void
FillMeshFromContactSurface(const bmr::ContactSurface & surface, TMesh * mesh)
{
  using CellType = typename TMesh::CellType;
  using CellAutoPointer = typename CellType::CellAutoPointer;

  mesh->Initialize();
  mesh->SetPoints(MakePointsContainer<typename TMesh::PointsContainer>(surface.vertices));
  for (std::size_t t = 0; t < surface.triangles.size(); ++t)
  {
    CellAutoPointer cell;
    cell.TakeOwnership(new TriangleCell<CellType>);
    for (unsigned int k = 0; k < 3; ++k)
    {
      cell->SetPointId(k, static_cast<typename TMesh::PointIdentifier>(surface.triangles[t][k]));
    }
    mesh->SetCell(t, cell);
  }
  MarkPointSetProduced(mesh);
}

/** A new triangle itk::Mesh of the core's surface (see FillMeshFromContactSurface). */
template <typename TMesh>
typename TMesh::Pointer
MakeMeshFromContactSurface(const bmr::ContactSurface & surface)
{
  auto mesh = TMesh::New();
  FillMeshFromContactSurface(surface, mesh.GetPointer());
  return mesh;
}

} // namespace itk

#endif
