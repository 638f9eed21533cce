// Brain and rigid skull surfaces of a brain mask, as itk::Mesh outputs and as
// the mechanics core's ContactSurface (bmrBrainSurfaces.h).
#ifndef itkBrainSurfaceMeshSource_h
#define itkBrainSurfaceMeshSource_h


#include "itkImage.h"
#include "itkImageToMeshFilter.h"
#include "itkDefaultStaticMeshTraits.h"
#include "itkMesh.h"
#include "itkBiomechanicalModelObject.h"

#include "bmrBrainSurfaces.h" // after ITK: ITK's bundled Eigen must come first

#include <string>
#include <vector>

namespace itk
{

/** \class BrainSurfaceMeshSource
 * \brief Triangulated brain surface and rigid skull (contact master) surface
 * of a brain mask.
 *
 * Input: a 3D brain mask (voxels > 0 are brain), any scalar pixel type, any
 * spacing and direction cosines.
 *
 * Outputs (itk::Mesh of TriangleCells, points in physical space, mm; the
 * default mesh type has double coordinates, as the core's surfaces, where
 * itk::Mesh<double, 3> would round them to float):
 *  - output 0 (GetOutput()): the brain surface, the level 0 of the signed
 *    distance to the mask boundary (halfway between brain and background voxel
 *    centres);
 *  - output 1 (GetSkullOutput()): the skull surface, the level +SkullGap of
 *    the same signed distance: the boundary of the mask dilated by SkullGap mm.
 * Both are closed, manifold and oriented with outward normals.
 * GetBrainSurface() and GetSkullSurface() give the same surfaces as
 * bmr::ContactSurface (the skull with bodySide Inside, a ready contact master).
 *
 * With SkullClosing r > 0 the skull is the boundary of the mask closed by a
 * ball of radius r and then dilated by SkullGap: it does not enter fissures
 * narrower than 2 (r + SkullGap) (bmr::BrainSurfaceSettings::skullClosing).
 *
 * Method: the mask's bounding box is padded by ceil((SkullGap + SkullClosing) / spacing) + 2
 * voxels of background (so the skull is closed where the mask touches the
 * image border); the signed distance (mm, negative inside) is the mean of ITK's
 * SignedMaurerDistanceMapImageFilter of the mask (zero on the brain's boundary
 * voxels) and of the negated one of its complement (zero on the background's
 * boundary voxels): each is biased by half a voxel, in opposite directions, so
 * the mean puts level 0 halfway between the voxel centres, also for
 * anisotropic voxels. The core (bmr::ExtractBrainSurfaces) then extracts,
 * smooths and optionally decimates the two level sets (VTK).
 *
 * Parameters: SkullGap (mm, default 1.5: the CSF layer between brain and
 * skull is about 1-3 mm), SkullClosing (mm, default 1), SmoothingIterations (default 20), SmoothingPassBand
 * (default 0.1), TargetEdgeLength (mm, default 0 = no decimation),
 * ComputeSkull (default on; off leaves output 1 empty and saves the skull's
 * exact-distance band and isosurface).
 *
 * Errors (itk::ExceptionObject): no input, an empty mask (no voxel > 0), a
 * negative SkullGap or SkullClosing, and the core's errors (bmr::Error messages).
 * Warnings of the core (dropped components, skipped decimation) are reported
 * with itkWarningMacro.
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TMaskImage,
          typename TOutputMesh = BiomechanicalSurfaceMeshType>
class ITK_TEMPLATE_EXPORT BrainSurfaceMeshSource : public ImageToMeshFilter<TMaskImage, TOutputMesh>
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(BrainSurfaceMeshSource);

  using Self = BrainSurfaceMeshSource;
  using Superclass = ImageToMeshFilter<TMaskImage, TOutputMesh>;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(BrainSurfaceMeshSource, ImageToMeshFilter);

  static_assert(TMaskImage::ImageDimension == 3, "BrainSurfaceMeshSource works on 3D masks");
  static_assert(TOutputMesh::PointDimension == 3, "BrainSurfaceMeshSource outputs 3D meshes");

  using MaskImageType = TMaskImage;
  using OutputMeshType = TOutputMesh;
  using DistanceImageType = Image<float, 3>;
  using BinaryImageType = Image<unsigned char, 3>;

  /** Gap between brain and skull surfaces, mm (default 1.5). */
  itkSetMacro(SkullGap, double);
  itkGetConstMacro(SkullGap, double);
  /** Radius of the closing of the mask before the skull is made, mm (default 0: none). */
  itkSetMacro(SkullClosing, double);
  itkGetConstMacro(SkullClosing, double);
  /** Windowed-sinc smoothing iterations (default 20; 0 = none). */
  itkSetMacro(SmoothingIterations, int);
  itkGetConstMacro(SmoothingIterations, int);
  /** Windowed-sinc pass band (default 0.1). */
  itkSetMacro(SmoothingPassBand, double);
  itkGetConstMacro(SmoothingPassBand, double);
  /** Target mean triangle edge length, mm (default 0: no decimation). */
  itkSetMacro(TargetEdgeLength, double);
  itkGetConstMacro(TargetEdgeLength, double);
  /** Off: only the brain surface; the skull output stays an empty mesh
   *  (default on). The anatomical surface a scan is matched to needs no skull. */
  itkSetMacro(ComputeSkull, bool);
  itkGetConstMacro(ComputeSkull, bool);
  itkBooleanMacro(ComputeSkull);

  /** The brain surface mesh (output 0). */
  OutputMeshType *
  GetBrainOutput()
  {
    return this->GetOutput();
  }
  /** The skull surface mesh (output 1). */
  OutputMeshType *
  GetSkullOutput();

  /** The surfaces of the last update as the core's type. */
  const bmr::ContactSurface &
  GetBrainSurface() const
  {
    return m_Surfaces.brain;
  }
  const bmr::ContactSurface &
  GetSkullSurface() const
  {
    return m_Surfaces.skull;
  }

  /** The core's warnings of the last update (also reported with itkWarningMacro),
   *  for programs that collect them in a report. */
  const std::vector<std::string> &
  GetWarnings() const
  {
    return m_Warnings;
  }

protected:
  BrainSurfaceMeshSource();
  ~BrainSurfaceMeshSource() override = default;

  void
  GenerateData() override;

  void
  PrintSelf(std::ostream & os, Indent indent) const override;

private:
  double             m_SkullGap{ bmr::BrainSurfaceSettings{}.skullGap };
  double             m_SkullClosing{ bmr::BrainSurfaceSettings{}.skullClosing };
  int                m_SmoothingIterations{ 20 };
  double             m_SmoothingPassBand{ 0.1 };
  double             m_TargetEdgeLength{ 0.0 };
  bool               m_ComputeSkull{ true };
  bmr::BrainSurfaces m_Surfaces;
  std::vector<std::string> m_Warnings;
};

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkBrainSurfaceMeshSource.hxx"
#endif

#endif
