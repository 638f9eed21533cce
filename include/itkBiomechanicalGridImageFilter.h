#ifndef itkBiomechanicalGridImageFilter_h
#define itkBiomechanicalGridImageFilter_h

#include "bmrImageGrids.h"

#include "itkBiomechanicalModelObject.h"
#include "itkImageToMeshFilter.h"
#include "itkMesh.h"

#include <string>
#include <vector>

namespace itk
{

/** \class BiomechanicalGridImageFilter
 * \brief Computational grid of a biomechanical model from a mask or label image.
 *
 * The input is a 3D mask or label image (0 = outside, labels 1..255 = tissue).
 * The output is an itk::Mesh<int, 3> in the image's physical space (mm):
 * its points are the model's nodes and its cells HexahedronCell (VTK / ITK
 * corner order) or TetrahedronCell (positively oriented); the cell data of
 * each cell is its image label. A meshless grid gives points and no cells.
 *
 * GetModel() returns the mechanics core's model (bmr::Model, see
 * bmrModel.h): nodes, cells, one material "parenchyma" (E = 3000 Pa, nu =
 * 0.49, rho = 1000 kg/m^3), node sets "all" and "surface", and for a meshless
 * grid the integration points and weights (model.meshless). It can be
 * written with bmr::WriteMesh (.vtu, node sets as point-data masks).
 * GetModelOutput() (output 1) carries the same model down the pipeline
 * (BiomechanicalModelObject), e.g. to BiomechanicalDeformationFilter.
 *
 * Grid kinds and parameters: see bmr::MakeGridFromLabels and
 * bmr::ImageGridSettings (bmrImageGrids.h). Defaults: hexahedra, element
 * size 5 mm, facet angle 25 degrees, facet distance 0 (elementSize / 8),
 * radius-edge ratio 3, optimisation on, seed 1.
 *
 * Errors of the core (empty mask, element size below the voxel spacing or
 * above half the body's extent, ...) are rethrown as itk::ExceptionObject
 * with the core's message; its warnings go through itkWarningMacro.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TLabelImage>
class ITK_TEMPLATE_EXPORT BiomechanicalGridImageFilter : public ImageToMeshFilter<TLabelImage, Mesh<int, 3>>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BiomechanicalGridImageFilter);

  using Self = BiomechanicalGridImageFilter;
  using Superclass = ImageToMeshFilter<TLabelImage, Mesh<int, 3>>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BiomechanicalGridImageFilter, ImageToMeshFilter);

  using InputImageType = TLabelImage;
  using OutputMeshType = Mesh<int, 3>;
  using GridKind = bmr::ImageGridKind;

  static_assert(TLabelImage::ImageDimension == 3, "BiomechanicalGridImageFilter needs a 3D label image");

  /** Grid kind (default hexahedra). */
  void SetGridKind(GridKind kind)
  {
    if (m_Settings.kind != kind)
    {
      m_Settings.kind = kind;
      this->Modified();
    }
  }
  GridKind GetGridKind() const { return m_Settings.kind; }
  /** "hexahedra", "tetrahedra", "mixed" or "meshless"; throws for other names. */
  void SetGridKindByName(const std::string & name);

  /** Element size (mm), default 5: hexahedron edge, tetrahedron target edge, meshless spacing. */
  void SetElementSize(double value)
  {
    if (m_Settings.elementSize != value)
    {
      m_Settings.elementSize = value;
      this->Modified();
    }
  }
  double GetElementSize() const { return m_Settings.elementSize; }
  /** CGAL facet angle lower bound (degrees, default 25). */
  void SetFacetAngle(double value)
  {
    if (m_Settings.facetAngle != value)
    {
      m_Settings.facetAngle = value;
      this->Modified();
    }
  }
  double GetFacetAngle() const { return m_Settings.facetAngle; }
  /** CGAL facet distance (mm, default 0: elementSize / 8). */
  void SetFacetDistance(double value)
  {
    if (m_Settings.facetDistance != value)
    {
      m_Settings.facetDistance = value;
      this->Modified();
    }
  }
  double GetFacetDistance() const { return m_Settings.facetDistance; }
  /** CGAL cell radius-edge ratio (default 3). */
  void SetCellRadiusEdgeRatio(double value)
  {
    if (m_Settings.cellRadiusEdgeRatio != value)
    {
      m_Settings.cellRadiusEdgeRatio = value;
      this->Modified();
    }
  }
  double GetCellRadiusEdgeRatio() const { return m_Settings.cellRadiusEdgeRatio; }
  /** CGAL perturb + exude (default on). */
  void SetOptimise(bool value)
  {
    if (m_Settings.optimise != value)
    {
      m_Settings.optimise = value;
      this->Modified();
    }
  }
  bool GetOptimise() const { return m_Settings.optimise; }
  /** Seed of CGAL's random numbers (default 1). */
  void SetSeed(std::uint32_t value)
  {
    if (m_Settings.seed != value)
    {
      m_Settings.seed = value;
      this->Modified();
    }
  }
  std::uint32_t GetSeed() const { return m_Settings.seed; }

  /** All settings at once (meshless shape functions and integration included). */
  void SetSettings(const bmr::ImageGridSettings & settings)
  {
    m_Settings = settings;
    this->Modified();
  }
  const bmr::ImageGridSettings & GetSettings() const { return m_Settings; }

  /** The core model of the last update. */
  const bmr::Model & GetModel() const { return m_Grid.model; }
  /** The same model as a pipeline output (output 1), e.g. the input of
   *  BiomechanicalDeformationFilter after material mapping. */
  BiomechanicalModelObject * GetModelOutput()
  {
    return itkDynamicCastInDebugMode<BiomechanicalModelObject *>(this->ProcessObject::GetOutput(1));
  }
  /** For a meshless point cloud: the tetrahedra whose region its
   *  integration points cover (the body, e.g. to rasterise for its surfaces);
   *  empty for a finite-element grid. */
  const bmr::Model & GetMeshlessBody() const { return m_Grid.meshlessBody; }
  /** Image label of each cell of the last update (empty for meshless). */
  const std::vector<int> & GetCellLabels() const { return m_Grid.cellLabels; }
  /** Size and quality figures of the last update. */
  const bmr::GridQuality & GetQuality() const { return m_Grid.quality; }
  /** Warnings of the last update (also sent through itkWarningMacro). */
  const std::vector<std::string> & GetWarnings() const { return m_Warnings; }

protected:
  BiomechanicalGridImageFilter();
  ~BiomechanicalGridImageFilter() override = default;

  using Superclass::MakeOutput;
  DataObject::Pointer MakeOutput(ProcessObject::DataObjectPointerArraySizeType index) override;

  void GenerateData() override;
  void PrintSelf(std::ostream & os, Indent indent) const override;

private:
  bmr::ImageGridSettings m_Settings;
  bmr::ImageGrid         m_Grid;
  std::vector<std::string> m_Warnings;
};

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkBiomechanicalGridImageFilter.hxx"
#endif

#endif
