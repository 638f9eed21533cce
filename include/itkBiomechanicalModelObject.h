#ifndef itkBiomechanicalModelObject_h
#define itkBiomechanicalModelObject_h

#include "itkDataObject.h"
#include "itkObjectFactory.h"

#include "bmrModel.h"

namespace itk
{

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

  void
  Initialize() override
  {
    Superclass::Initialize();
    m_Model = bmr::Model{};
  }

  void
  Graft(const DataObject * data) override
  {
    if (const auto * other = dynamic_cast<const Self *>(data))
    {
      m_Model = other->m_Model;
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
  }

private:
  bmr::Model m_Model;
};

} // namespace itk

#endif
