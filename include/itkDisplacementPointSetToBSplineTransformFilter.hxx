#ifndef itkDisplacementPointSetToBSplineTransformFilter_hxx
#define itkDisplacementPointSetToBSplineTransformFilter_hxx

#include "itkDisplacementPointSetToBSplineTransformFilter.h"

#include "itkMultiThreaderBase.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace itk
{

template <typename TPointSet>
DisplacementPointSetToBSplineTransformFilter<TPointSet>::DisplacementPointSetToBSplineTransformFilter()
{
  this->SetNumberOfRequiredInputs(1);
  this->SetNumberOfRequiredOutputs(3);
  for (unsigned int n = 0; n < 3; ++n)
  {
    this->SetNthOutput(n, this->MakeOutput(n));
  }
}

template <typename TPointSet>
void
DisplacementPointSetToBSplineTransformFilter<TPointSet>::SetInput(const PointSetType * pointSet)
{
  this->SetNthInput(0, const_cast<PointSetType *>(pointSet));
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::GetInput() const -> const PointSetType *
{
  return itkDynamicCastInDebugMode<const PointSetType *>(this->GetPrimaryInput());
}

template <typename TPointSet>
DataObject::Pointer
DisplacementPointSetToBSplineTransformFilter<TPointSet>::MakeOutput(DataObjectPointerArraySizeType index)
{
  if (index == 2)
  {
    return DisplacementFieldTransformOutputType::New().GetPointer();
  }
  return BSplineTransformOutputType::New().GetPointer();
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::GetTransformOutput() -> BSplineTransformOutputType *
{
  return static_cast<BSplineTransformOutputType *>(this->ProcessObject::GetOutput(0));
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::GetTransform() const -> const BSplineTransformType *
{
  return static_cast<const BSplineTransformOutputType *>(this->ProcessObject::GetOutput(0))->Get();
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::GetForwardTransform() const -> const BSplineTransformType *
{
  return static_cast<const BSplineTransformOutputType *>(this->ProcessObject::GetOutput(1))->Get();
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::GetDisplacementFieldTransform() const
  -> const DisplacementFieldTransformType *
{
  return static_cast<const DisplacementFieldTransformOutputType *>(this->ProcessObject::GetOutput(2))->Get();
}

template <typename TPointSet>
void
DisplacementPointSetToBSplineTransformFilter<TPointSet>::VerifyPreconditions() ITKv5_CONST
{
  if (this->GetInput() == nullptr)
  {
    itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: no input; call SetInput() with a point set of "
                      "reference positions carrying displacements (mm), e.g. from MakeDisplacementPointSet().");
  }
  if (this->GetReferenceImage() == nullptr)
  {
    itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: no reference image; call SetReferenceImage() "
                      "with the image whose grid is the transform's domain (usually the preoperative image).");
  }
  if (!(m_Tolerance > 0.0))
  {
    itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: Tolerance is " << m_Tolerance
                                                                                    << " mm; it must be > 0.");
  }
  if (!(m_MinimumControlPointSpacing > 0.0))
  {
    itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: MinimumControlPointSpacing is "
                      << m_MinimumControlPointSpacing << " mm; it must be > 0.");
  }
  Superclass::VerifyPreconditions();
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::MakeDomain(const std::vector<PointType> & points) -> Domain
{
  const ReferenceImageType * reference = this->GetReferenceImage();
  const auto                 region = reference->GetLargestPossibleRegion();
  Domain                     domain;
  domain.spacing = reference->GetSpacing();
  domain.direction = reference->GetDirection();

  // Continuous index of every point in the reference grid; the domain spans
  // the region and, when allowed, every point, in whole voxels.
  const auto inverse = reference->GetInverseDirection();
  double     low[Dimension];
  double     high[Dimension];
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    if (region.GetSize()[d] < 2)
    {
      itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: the reference image has "
                        << region.GetSize()[d] << " voxel(s) along axis " << d
                        << "; the domain needs at least 2 along every axis.");
    }
    // One voxel of margin: no reference voxel on the spline's boundary.
    low[d] = static_cast<double>(region.GetIndex()[d]) - 1.0;
    high[d] = static_cast<double>(region.GetIndex()[d] + static_cast<IndexValueType>(region.GetSize()[d]));
  }
  const auto origin = reference->GetOrigin();
  m_DomainExtended = false;
  for (std::size_t n = 0; n < points.size(); ++n)
  {
    bool outside = false;
    for (unsigned int d = 0; d < Dimension; ++d)
    {
      double projected = 0.0;
      for (unsigned int e = 0; e < Dimension; ++e)
      {
        projected += inverse[d][e] * (points[n][e] - origin[e]);
      }
      const double index = projected / domain.spacing[d];
      const double regionLow = static_cast<double>(region.GetIndex()[d]);
      const double regionHigh = regionLow + static_cast<double>(region.GetSize()[d]) - 1.0;
      if (index < regionLow || index > regionHigh)
      {
        outside = true;
      }
      low[d] = std::min(low[d], std::floor(index) - 1.0);
      high[d] = std::max(high[d], std::ceil(index) + 1.0);
    }
    if (outside && !m_ExtendDomainToPoints)
    {
      itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: point "
                        << points[n] << " (data point " << n
                        << ") lies outside the reference image's physical extent; use a reference image that "
                           "covers the model and its deformed positions, or turn ExtendDomainToPoints on.");
    }
    m_DomainExtended = m_DomainExtended || outside;
  }

  typename ReferenceImageType::IndexType first;
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    first[d] = static_cast<IndexValueType>(low[d]);
    domain.size[d] = static_cast<SizeValueType>(high[d] - low[d]) + 1;
  }
  reference->TransformIndexToPhysicalPoint(first, domain.origin);
  return domain;
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::Fit(const std::vector<PointType> &  points,
                                                             const std::vector<VectorType> & values,
                                                             const Domain &                  domain,
                                                             BSplineFitReport &              report) const ->
  typename BSplineTransformType::Pointer
{
  // The multilevel approximation runs in the core (bmrBSplineField.h says why not ITK's filter).
  std::vector<bmr::Vector3> corePoints(points.size());
  std::vector<bmr::Vector3> coreValues(values.size());
  for (std::size_t n = 0; n < points.size(); ++n)
  {
    corePoints[n] = bmr::Vector3(points[n][0], points[n][1], points[n][2]);
    coreValues[n] = bmr::Vector3(values[n][0], values[n][1], values[n][2]);
  }
  bmr::ImageGeometry coreDomain;
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    coreDomain.size[d] = static_cast<int>(domain.size[d]);
    coreDomain.spacing[d] = domain.spacing[d];
    coreDomain.origin[d] = domain.origin[d];
    for (unsigned int e = 0; e < Dimension; ++e)
    {
      coreDomain.direction(d, e) = domain.direction[d][e];
    }
  }
  bmr::BSplineFitSettings settings;
  settings.tolerance = m_Tolerance;
  settings.minimumSpacing = m_MinimumControlPointSpacing;
  bmr::BSplineFitResult fit;
  try
  {
    fit = bmr::FitMultilevelBSpline(corePoints, coreValues, coreDomain, settings);
  }
  catch (const bmr::Error & error)
  {
    itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: " << error.what());
  }
  typename BSplineTransformType::Pointer transform = MakeBSplineTransform(fit.lattice);

  // The report comes from the ITK transform itself: what users resample with.
  std::vector<double> residualNorms(points.size());
  MultiThreaderBase::New()->ParallelizeArray(
    0,
    points.size(),
    [&](SizeValueType n) {
      const auto moved = transform->TransformPoint(points[n]);
      residualNorms[n] = ((moved - points[n]) - values[n]).GetNorm();
    },
    nullptr);
  report = BSplineFitReport{};
  double sumOfSquares = 0.0;
  for (double norm : residualNorms)
  {
    report.maximumResidual = std::max(report.maximumResidual, norm);
    sumOfSquares += norm * norm;
  }
  report.rmsResidual = std::sqrt(sumOfSquares / static_cast<double>(points.size()));
  report.levels = static_cast<unsigned int>(fit.levels);
  report.toleranceReached = report.maximumResidual <= m_Tolerance;
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    report.meshSize.push_back(static_cast<unsigned int>(fit.meshSize[d]));
    report.controlPointSpacing.push_back(fit.controlPointSpacing[d]);
  }
  return transform;
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::SampleOnReferenceGrid(
  const BSplineTransformType * transform) const -> typename DisplacementFieldTransformType::Pointer
{
  typename DisplacementFieldType::Pointer field = SampleBSplineTransform(transform, this->GetReferenceImage());
  auto                                    fieldTransform = DisplacementFieldTransformType::New();
  fieldTransform->SetDisplacementField(field);
  return fieldTransform;
}

template <typename TPointSet>
void
DisplacementPointSetToBSplineTransformFilter<TPointSet>::GenerateData()
{
  const PointSetType * input = this->GetInput();
  const std::size_t    count = input->GetNumberOfPoints();
  std::size_t          needed = 1;
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    needed *= SplineOrder + 1;
  }
  if (count < needed)
  {
    itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: "
                      << count << " data points; the coarsest cubic B-spline has " << needed
                      << " control points per component, so give at least " << needed
                      << " points (e.g. every node of the model).");
  }
  if (input->GetPointData() == nullptr || input->GetPointData()->Size() != count)
  {
    itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: the point set has "
                      << count << " points but " << (input->GetPointData() ? input->GetPointData()->Size() : 0)
                      << " displacements; give one displacement (point data) per point.");
  }

  std::vector<PointType>  reference(count);
  std::vector<VectorType> displacement(count);
  for (std::size_t n = 0; n < count; ++n)
  {
    const auto & point = input->GetPoints()->ElementAt(n);
    const auto & value = input->GetPointData()->ElementAt(n);
    for (unsigned int d = 0; d < Dimension; ++d)
    {
      reference[n][d] = point[d];
      displacement[n][d] = value[d];
      if (!std::isfinite(reference[n][d]) || !std::isfinite(displacement[n][d]))
      {
        itkExceptionMacro("DisplacementPointSetToBSplineTransformFilter: point "
                          << n << " has a NaN or infinite " << (std::isfinite(reference[n][d]) ? "displacement " : "position ")
                          << value << " at " << point << "; the solve that produced it failed: check its report.");
      }
    }
  }

  // Backward map: data at the deformed positions, carrying -u.
  std::vector<PointType>  deformed(count);
  std::vector<VectorType> negated(count);
  for (std::size_t n = 0; n < count; ++n)
  {
    deformed[n] = reference[n] + displacement[n];
    negated[n] = -displacement[n];
  }

  // One domain for both directions, so the backward fit does not depend on
  // whether the forward one is asked for.
  std::vector<PointType> all(reference);
  all.insert(all.end(), deformed.begin(), deformed.end());
  const Domain domain = this->MakeDomain(all);

  auto backward = this->Fit(deformed, negated, domain, m_Report);
  this->UpdateProgress(m_GenerateForwardTransform ? 0.45f : 0.9f);
  static_cast<BSplineTransformOutputType *>(this->ProcessObject::GetOutput(0))->Set(backward);

  m_ForwardReport = BSplineFitReport{};
  typename BSplineTransformType::Pointer forward;
  if (m_GenerateForwardTransform)
  {
    forward = this->Fit(reference, displacement, domain, m_ForwardReport);
    this->UpdateProgress(0.9f);
  }
  static_cast<BSplineTransformOutputType *>(this->ProcessObject::GetOutput(1))->Set(forward);

  typename DisplacementFieldTransformType::Pointer field;
  if (m_GenerateDisplacementField)
  {
    field = this->SampleOnReferenceGrid(backward);
  }
  static_cast<DisplacementFieldTransformOutputType *>(this->ProcessObject::GetOutput(2))->Set(field);
  this->UpdateProgress(1.0f);
}

template <typename TPointSet>
void
DisplacementPointSetToBSplineTransformFilter<TPointSet>::PrintSelf(std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "Tolerance: " << m_Tolerance << " mm" << std::endl;
  os << indent << "MinimumControlPointSpacing: " << m_MinimumControlPointSpacing << " mm" << std::endl;
  os << indent << "ExtendDomainToPoints: " << m_ExtendDomainToPoints << std::endl;
  os << indent << "GenerateForwardTransform: " << m_GenerateForwardTransform << std::endl;
  os << indent << "GenerateDisplacementField: " << m_GenerateDisplacementField << std::endl;
  os << indent << "Report: levels " << m_Report.levels << ", maximum residual " << m_Report.maximumResidual
     << " mm, RMS " << m_Report.rmsResidual << " mm, tolerance reached " << m_Report.toleranceReached << std::endl;
  os << indent << "DomainExtended: " << m_DomainExtended << std::endl;
}

} // namespace itk

#endif
