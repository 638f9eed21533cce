#ifndef itkBiomechanicalGridImageFilter_hxx
#define itkBiomechanicalGridImageFilter_hxx

#include "itkBiomechanicalGridImageFilter.h"
#include "itkBiomechanicalImageConversion.h"

#include "itkHexahedronCell.h"
#include "itkImageRegionConstIterator.h"
#include "itkTetrahedronCell.h"

#include <cstdint>

namespace itk
{

template <typename TLabelImage>
BiomechanicalGridImageFilter<TLabelImage>::BiomechanicalGridImageFilter()
{
  this->SetNumberOfRequiredOutputs(2);
  this->SetNthOutput(1, this->MakeOutput(1));
}

template <typename TLabelImage>
DataObject::Pointer
BiomechanicalGridImageFilter<TLabelImage>::MakeOutput(ProcessObject::DataObjectPointerArraySizeType index)
{
  if (index == 1)
  {
    return BiomechanicalModelObject::New().GetPointer();
  }
  return Superclass::MakeOutput(index);
}

template <typename TLabelImage>
void
BiomechanicalGridImageFilter<TLabelImage>::SetGridKindByName(const std::string & name)
{
  try
  {
    this->SetGridKind(bmr::ParseImageGridKind(name));
  }
  catch (const bmr::Error & error)
  {
    itkExceptionMacro(<< error.what());
  }
}

template <typename TLabelImage>
void
BiomechanicalGridImageFilter<TLabelImage>::GenerateData()
{
  const InputImageType * input = this->GetInput();
  if (input == nullptr)
  {
    itkExceptionMacro(<< "no input label image: call SetInput with a 3D mask or label image.");
  }
  // Labels are copied into the core's 8-bit label volume; other values cannot be represented.
  bmr::LabelVolume labels;
  labels.geometry = MakeBiomechanicalGeometry(input);
  labels.components = 1;
  labels.values.resize(labels.geometry.VoxelCount());
  ImageRegionConstIterator<InputImageType> it(input, input->GetBufferedRegion());
  std::size_t                              n = 0;
  for (it.GoToBegin(); !it.IsAtEnd(); ++it, ++n)
  {
    const double value = static_cast<double>(it.Get());
    if (!(value >= 0.0 && value <= 255.0) || value != static_cast<double>(static_cast<int>(value)))
    {
      itkExceptionMacro(<< "label image voxel " << it.GetIndex() << " has value " << value
                        << "; labels must be integers 0 (outside) to 255. Relabel the image.");
    }
    labels.values[n] = static_cast<std::uint8_t>(value);
  }

  m_Warnings.clear();
  try
  {
    m_Grid = bmr::MakeGridFromLabels(labels, m_Settings, &m_Warnings);
  }
  catch (const bmr::Error & error)
  {
    m_Grid = bmr::ImageGrid{};
    itkExceptionMacro(<< error.what());
  }
  for (const auto & warning : m_Warnings)
  {
    itkWarningMacro(<< warning);
  }

  OutputMeshType * output = this->GetOutput();
  output->Initialize();
  const bmr::Model & model = m_Grid.model;
  output->SetPoints(MakePointsContainer<typename OutputMeshType::PointsContainer>(model.nodes));

  using CellType = typename OutputMeshType::CellType;
  using CellAutoPointer = typename CellType::CellAutoPointer;
  using HexahedronType = HexahedronCell<CellType>;
  using TetrahedronType = TetrahedronCell<CellType>;
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const bmr::Cell & cell = model.cells[c];
    CellAutoPointer   element;
    if (cell.type == bmr::CellType::Hexahedron)
    {
      element.TakeOwnership(new HexahedronType);
    }
    else
    {
      element.TakeOwnership(new TetrahedronType);
    }
    for (int v = 0; v < bmr::NodesPerCell(cell.type); ++v)
    {
      element->SetPointId(v, static_cast<typename OutputMeshType::PointIdentifier>(cell.nodes[v]));
    }
    output->SetCell(c, element);
    output->SetCellData(c, c < m_Grid.cellLabels.size() ? m_Grid.cellLabels[c] : 0);
  }
  MarkPointSetProduced(output);
  this->GetModelOutput()->SetModel(m_Grid.model);
}

template <typename TLabelImage>
void
BiomechanicalGridImageFilter<TLabelImage>::PrintSelf(std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "GridKind: " << bmr::ImageGridKindName(m_Settings.kind) << std::endl;
  os << indent << "ElementSize: " << m_Settings.elementSize << " mm" << std::endl;
  os << indent << "FacetAngle: " << m_Settings.facetAngle << " deg" << std::endl;
  os << indent << "FacetDistance: " << m_Settings.facetDistance << " mm" << std::endl;
  os << indent << "CellRadiusEdgeRatio: " << m_Settings.cellRadiusEdgeRatio << std::endl;
  os << indent << "Optimise: " << m_Settings.optimise << std::endl;
  os << indent << "Seed: " << m_Settings.seed << std::endl;
  os << indent << "MLS dilatation: " << m_Settings.meshlessShapeFunctions.dilatation
     << " (where it does not cover the body: " << m_Settings.meshlessFallbackDilatation << ")" << std::endl;
  os << indent << "Nodes: " << m_Grid.model.nodes.size() << ", cells: " << m_Grid.model.cells.size() << std::endl;
}

} // namespace itk

#endif
