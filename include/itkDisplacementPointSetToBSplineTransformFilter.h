// From computed nodal displacements to a standard ITK transform: multilevel
// B-spline scattered-data approximation of the displacement field, fitted as
// the resampling (backward) map that itk::ResampleImageFilter needs.
#ifndef itkDisplacementPointSetToBSplineTransformFilter_h
#define itkDisplacementPointSetToBSplineTransformFilter_h

#include "itkBSplineLatticeConversion.h"
#include "itkBSplineTransform.h"
#include "itkDataObjectDecorator.h"
#include "itkDisplacementFieldTransform.h"
#include "itkImageBase.h"
#include "itkPointSet.h"
#include "itkProcessObject.h"
#include "itkVector.h"

#include "itkBiomechanicalModelObject.h" // DisplacementPointSetType

#include "bmrModel.h"

#include <string>
#include <vector>

namespace itk
{

/** How well a fitted B-spline reproduces the data (mm). */
struct BSplineFitReport
{
  double              maximumResidual = 0.0;  // largest |fitted - data| over the points
  double              rmsResidual = 0.0;      // root mean square of |fitted - data|
  unsigned int        levels = 0;             // multilevel B-spline levels used
  std::vector<double> controlPointSpacing;    // final control-point spacing per axis (mm)
  std::vector<unsigned int> meshSize;         // final B-spline mesh size per axis (control points - 3)
  bool                toleranceReached = false;
};

/** \class DisplacementPointSetToBSplineTransformFilter
 * \brief Fits a cubic itk::BSplineTransform to displacements given at
 * scattered points (for example the nodes of a solved biomechanical model),
 * so that ordinary ITK resampling warps the preoperative image into the
 * intraoperative configuration.
 *
 * Input (SetInput): a point set whose points are the reference
 * (preoperative) positions x and whose point data are the displacements u(x)
 * (mm). MakeDisplacementPointSet() builds it from a core model and solve.
 *
 * Domain (SetReferenceImage, required): the physical extent of the image grid
 * the transform will be used on (origin, spacing, size, direction cosines),
 * usually the preoperative image, grown by one voxel on every side (so that
 * no voxel of the grid sits on the spline's boundary, where ITK's
 * BSplineTransform may round it outside and return no displacement). Data
 * points outside it: by default
 * (ExtendDomainToPoints on) the domain grows by whole voxels of the reference
 * grid, in its own directions, until every point lies inside
 * (GetDomainExtended() says so); with ExtendDomainToPoints off such points are
 * an error naming the first of them.
 *
 * Output 0, GetTransform(): the backward (resampling) transform
 * T(y) = y + v(y), fitted directly: the data points are the deformed
 * positions y = x + u(x) carrying v = -u(x), so T(x + u) = x. Pass it to
 * itk::ResampleImageFilter with the intraoperative grid as output grid to warp
 * the preoperative image.
 * Output 1, GetForwardTransform() (GenerateForwardTransform on): x -> x + u(x),
 * for moving points (landmarks, surfaces) from preoperative to intraoperative
 * space.
 * Output 2, GetDisplacementFieldTransform() (GenerateDisplacementField on):
 * the backward map sampled on the reference image grid as an
 * itk::DisplacementFieldTransform (linear interpolation between voxels).
 *
 * Method: multilevel B-spline approximation (Lee, Wolberg and Shin 1997),
 * the algorithm of ITK's BSplineScatteredDataPointSetToImageFilter, run in the
 * core (bmr::FitMultilevelBSpline; bmrBSplineField.h says why, in short:
 * ITK's filter took 5.7 s for one 4 mm level on 29,000 points): the first mesh has one span along the longest axis of the domain and about
 * square spans elsewhere; each level doubles the mesh, fits the residual left
 * by the coarser levels and is added to them (the coarse lattice refined to
 * the fine mesh is exactly the same spline). Levels are added until the
 * largest residual at the data points is at most Tolerance (default 0.1 mm)
 * or the next level's control-point spacing would fall below
 * MinimumControlPointSpacing (default 1 mm, the voxel size of a typical
 * preoperative MRI: finer control points add nothing to the warp); GetReport() gives the residual
 * (maximum and RMS) and whether the tolerance was reached. The fit is not an
 * error when the tolerance is not reached: the report says so.
 *
 * Errors (ExceptionObject naming the problem and what to do): no input or
 * reference image; fewer points than the 4^Dimension control points of the
 * coarsest cubic spline; a NaN or infinite position or displacement (the
 * point is named); points outside the domain when ExtendDomainToPoints is off;
 * Tolerance <= 0 or MinimumControlPointSpacing <= 0.
 *
 * The fit is sequential and bitwise repeatable; the residual report and the
 * dense field are computed in parallel, point by point or voxel by voxel, so
 * they too do not depend on the thread count.
 *
 * Units: mm (ITK physical space).
 *
 * \ingroup BiomechanicalRegistration
 */
template <typename TPointSet = DisplacementPointSetType<3>>
class ITK_TEMPLATE_EXPORT DisplacementPointSetToBSplineTransformFilter : public ProcessObject
{
public:
  ITK_DISALLOW_COPY_AND_MOVE(DisplacementPointSetToBSplineTransformFilter);

  using Self = DisplacementPointSetToBSplineTransformFilter;
  using Superclass = ProcessObject;
  using Pointer = SmartPointer<Self>;
  using ConstPointer = SmartPointer<const Self>;

  itkNewMacro(Self);
  itkTypeMacro(DisplacementPointSetToBSplineTransformFilter, ProcessObject);

  static constexpr unsigned int Dimension = TPointSet::PointDimension;
  static_assert(Dimension == 3, "the fit runs in the 3D mechanics core");
  static constexpr unsigned int SplineOrder = 3;

  using PointSetType = TPointSet;
  using ReferenceImageType = ImageBase<Dimension>;
  using BSplineTransformType = BSplineTransform<double, Dimension, SplineOrder>;
  using DisplacementFieldTransformType = DisplacementFieldTransform<double, Dimension>;
  using DisplacementFieldType = typename DisplacementFieldTransformType::DisplacementFieldType;
  using BSplineTransformOutputType = DataObjectDecorator<BSplineTransformType>;
  using DisplacementFieldTransformOutputType = DataObjectDecorator<DisplacementFieldTransformType>;

  /** Reference positions (points) and displacements (point data), mm. */
  using Superclass::SetInput;
  void
  SetInput(const PointSetType * pointSet);
  const PointSetType *
  GetInput() const;

  /** The image grid whose physical extent is the transform's domain. Required. */
  itkSetInputMacro(ReferenceImage, ReferenceImageType);
  itkGetInputMacro(ReferenceImage, ReferenceImageType);

  /** Largest residual at the data points at which levels stop being added (mm, default 0.1). */
  itkSetMacro(Tolerance, double);
  itkGetConstMacro(Tolerance, double);
  /** Finest control-point spacing a level may have (mm, default 1). */
  itkSetMacro(MinimumControlPointSpacing, double);
  itkGetConstMacro(MinimumControlPointSpacing, double);
  /** Grow the domain to hold every data point (default true) or reject points outside it. */
  itkSetMacro(ExtendDomainToPoints, bool);
  itkGetConstMacro(ExtendDomainToPoints, bool);
  itkBooleanMacro(ExtendDomainToPoints);
  /** Also fit the forward transform x -> x + u(x) (default false). */
  itkSetMacro(GenerateForwardTransform, bool);
  itkGetConstMacro(GenerateForwardTransform, bool);
  itkBooleanMacro(GenerateForwardTransform);
  /** Also sample the backward map on the reference grid as a displacement field (default false). */
  itkSetMacro(GenerateDisplacementField, bool);
  itkGetConstMacro(GenerateDisplacementField, bool);
  itkBooleanMacro(GenerateDisplacementField);

  /** The backward (resampling) transform, output 0. */
  const BSplineTransformType *
  GetTransform() const;
  BSplineTransformOutputType *
  GetTransformOutput();
  /** The forward transform (null unless GenerateForwardTransform), output 1. */
  const BSplineTransformType *
  GetForwardTransform() const;
  /** The backward map on the reference grid (null unless GenerateDisplacementField), output 2. */
  const DisplacementFieldTransformType *
  GetDisplacementFieldTransform() const;

  /** Residuals and levels of the last Update(): backward and forward fits. */
  const BSplineFitReport &
  GetReport() const
  {
    return m_Report;
  }
  const BSplineFitReport &
  GetForwardReport() const
  {
    return m_ForwardReport;
  }
  /** True when the last Update() had to grow the domain beyond the reference grid. */
  itkGetConstMacro(DomainExtended, bool);

  using DataObjectPointerArraySizeType = ProcessObject::DataObjectPointerArraySizeType;
  using Superclass::MakeOutput;
  DataObject::Pointer
  MakeOutput(DataObjectPointerArraySizeType index) override;

protected:
  DisplacementPointSetToBSplineTransformFilter();
  ~DisplacementPointSetToBSplineTransformFilter() override = default;

  void
  PrintSelf(std::ostream & os, Indent indent) const override;

  void
  VerifyPreconditions() ITKv5_CONST override;

  void
  GenerateData() override;

private:
  /** The fitting domain: a grid in the reference image's directions. */
  struct Domain
  {
    typename ReferenceImageType::PointType     origin;
    typename ReferenceImageType::SpacingType   spacing;
    typename ReferenceImageType::SizeType      size;
    typename ReferenceImageType::DirectionType direction;
  };
  using VectorType = Vector<double, Dimension>;
  using PointType = typename BSplineTransformType::InputPointType;

  /** The reference grid, grown to hold `points` when allowed. */
  Domain
  MakeDomain(const std::vector<PointType> & points);

  /** Multilevel fit of `values` at `points` over `domain`; fills `report`. */
  typename BSplineTransformType::Pointer
  Fit(const std::vector<PointType> &  points,
      const std::vector<VectorType> & values,
      const Domain &                  domain,
      BSplineFitReport &              report) const;

  typename DisplacementFieldTransformType::Pointer
  SampleOnReferenceGrid(const BSplineTransformType * transform) const;

  double       m_Tolerance{ 0.1 };
  double       m_MinimumControlPointSpacing{ 1.0 };
  bool         m_ExtendDomainToPoints{ true };
  bool         m_GenerateForwardTransform{ false };
  bool         m_GenerateDisplacementField{ false };

  BSplineFitReport m_Report;
  BSplineFitReport m_ForwardReport;
  bool             m_DomainExtended{ false };
};

/** Sets `pointSet`'s points to `nodes` (reference positions, mm) carrying
 * `displacements` (mm), one per node, and marks the whole set as produced
 * (MarkPointSetProduced), as a filter's output must be or the pipeline runs
 * the filter again. Throws ExceptionObject when the counts differ. */
template <typename TPointSet>
void
FillDisplacementPointSet(TPointSet *                         pointSet,
                         const std::vector<bmr::Vector3> & nodes,
                         const std::vector<bmr::Vector3> & displacements)
{
  static_assert(TPointSet::PointDimension == 3, "the mechanics core is 3D");
  if (nodes.size() != displacements.size())
  {
    itkGenericExceptionMacro("displacement point set: " << nodes.size() << " nodes but " << displacements.size()
                                                         << " displacements; give the result of a solve of "
                                                            "this model (one displacement per node).");
  }
  auto data = TPointSet::PointDataContainer::New();
  data->Reserve(nodes.size());
  for (std::size_t n = 0; n < nodes.size(); ++n)
  {
    typename TPointSet::PixelType displacement;
    for (unsigned int d = 0; d < 3; ++d)
    {
      displacement[d] = displacements[n][d];
    }
    data->SetElement(n, displacement);
  }
  pointSet->SetPoints(MakePointsContainer<typename TPointSet::PointsContainer>(nodes));
  pointSet->SetPointData(data);
  MarkPointSetProduced(pointSet);
}

/** The fitter's input from the mechanics core: the points are `nodes`
 * (reference positions, mm) and carry `displacements` (mm), one per node,
 * e.g. bmr::Model::nodes and bmr::SolveResult::displacements (for a meshless
 * model these are the interpolated nodal displacements, not the MLS
 * parameters). Throws ExceptionObject when the counts differ. */
template <typename TPointSet = DisplacementPointSetType<3>>
typename TPointSet::Pointer
MakeDisplacementPointSet(const std::vector<bmr::Vector3> & nodes, const std::vector<bmr::Vector3> & displacements)
{
  auto pointSet = TPointSet::New();
  FillDisplacementPointSet(pointSet.GetPointer(), nodes, displacements);
  return pointSet;
}

} // namespace itk

#ifndef ITK_MANUAL_INSTANTIATION
#  include "itkDisplacementPointSetToBSplineTransformFilter.hxx"
#endif

#endif
