#ifndef itkDisplacementPointSetToBSplineTransformFilter_hxx
#define itkDisplacementPointSetToBSplineTransformFilter_hxx

#include "itkDisplacementPointSetToBSplineTransformFilter.h"

#include "itkBSplineControlPointImageFilter.h"
#include "itkBSplineScatteredDataPointSetToImageFilter.h"
#include "itkImageRegionConstIterator.h"
#include "itkImageRegionIterator.h"
#include "itkMultiThreaderBase.h"
#include "itkRegionOfInterestImageFilter.h"

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
    domain.offsetInReference[d] = first[d] - region.GetIndex()[d];
  }
  reference->TransformIndexToPhysicalPoint(first, domain.origin);
  return domain;
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::Fit(const std::vector<PointType> &  points,
                                                             const std::vector<VectorType> & values,
                                                             const Domain &                  domain,
                                                             BSplineFitReport &              report,
                                                             float                           progressStart,
                                                             float progressEnd) -> typename BSplineTransformType::Pointer
{
  using FitPointSetType = PointSet<VectorType, Dimension>;
  using LatticeType = Image<VectorType, Dimension>;
  using FitterType = BSplineScatteredDataPointSetToImageFilter<FitPointSetType, LatticeType>;
  using RefinerType = BSplineControlPointImageFilter<LatticeType, LatticeType>;
  using CoefficientImageType = typename BSplineTransformType::ImageType;

  const std::size_t count = points.size();
  auto              pointSet = FitPointSetType::New();
  pointSet->GetPoints()->Reserve(count);
  pointSet->GetPointData()->Reserve(count);
  // ITK's scattered-data filter places points by (point - origin) / spacing
  // along the world axes, ignoring the direction cosines: give it the points
  // in the domain's own (unrotated) frame. The values stay physical vectors.
  const auto toDomainFrame = domain.direction.GetInverse();
  for (std::size_t n = 0; n < count; ++n)
  {
    PointType inFrame = domain.origin;
    for (unsigned int d = 0; d < Dimension; ++d)
    {
      for (unsigned int e = 0; e < Dimension; ++e)
      {
        inFrame[d] += toDomainFrame[d][e] * (points[n][e] - domain.origin[e]);
      }
    }
    pointSet->GetPoints()->SetElement(n, inFrame);
  }

  // First mesh: one span along the longest axis, about square spans elsewhere.
  double extent[Dimension];
  double longest = 0.0;
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    extent[d] = domain.spacing[d] * static_cast<double>(domain.size[d] - 1);
    longest = std::max(longest, extent[d]);
  }
  unsigned int mesh[Dimension];
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    mesh[d] = std::max(1u, static_cast<unsigned int>(std::lround(extent[d] / longest)));
  }
  auto finestSpacing = [&](unsigned int scale) {
    double spacing = longest;
    for (unsigned int d = 0; d < Dimension; ++d)
    {
      spacing = std::min(spacing, extent[d] / static_cast<double>(mesh[d] * scale));
    }
    return spacing;
  };

  std::vector<VectorType>             residual(values);
  typename LatticeType::Pointer       total;
  typename BSplineTransformType::Pointer levelTransform = BSplineTransformType::New();
  auto makeTransform = [](const LatticeType * lattice, BSplineTransformType * transform) {
    typename BSplineTransformType::CoefficientImageArray coefficients;
    for (unsigned int c = 0; c < Dimension; ++c)
    {
      coefficients[c] = CoefficientImageType::New();
      coefficients[c]->CopyInformation(lattice);
      coefficients[c]->SetRegions(lattice->GetLargestPossibleRegion());
      coefficients[c]->Allocate();
      ImageRegionConstIterator<LatticeType>     in(lattice, lattice->GetLargestPossibleRegion());
      ImageRegionIterator<CoefficientImageType> out(coefficients[c], coefficients[c]->GetLargestPossibleRegion());
      for (; !in.IsAtEnd(); ++in, ++out)
      {
        out.Set(in.Get()[c]);
      }
    }
    transform->SetCoefficientImages(coefficients);
  };
  // Residual norms of `displacementOf` at every point, in point order (so the
  // result does not depend on the thread count).
  std::vector<double> residualNorms(count);
  auto                measure = [&](BSplineFitReport & measured) {
    double sumOfSquares = 0.0;
    measured.maximumResidual = 0.0;
    for (double norm : residualNorms)
    {
      measured.maximumResidual = std::max(measured.maximumResidual, norm);
      sumOfSquares += norm * norm;
    }
    measured.rmsResidual = std::sqrt(sumOfSquares / static_cast<double>(count));
  };

  // Levels: about log2(longest / minimum spacing), at least one.
  const unsigned int maximumLevels =
    1u + static_cast<unsigned int>(std::max(0.0, std::floor(std::log2(finestSpacing(1) / m_MinimumControlPointSpacing))));
  unsigned int scale = 1;
  report = BSplineFitReport{};
  for (unsigned int level = 0;; ++level, scale *= 2)
  {
    for (std::size_t n = 0; n < count; ++n)
    {
      pointSet->GetPointData()->SetElement(n, residual[n]);
    }
    auto fitter = FitterType::New();
    fitter->SetInput(pointSet);
    fitter->SetOrigin(domain.origin);
    fitter->SetSpacing(domain.spacing);
    fitter->SetSize(domain.size);
    fitter->SetDirection(domain.direction);
    fitter->SetSplineOrder(SplineOrder);
    typename FitterType::ArrayType controlPoints;
    for (unsigned int d = 0; d < Dimension; ++d)
    {
      controlPoints[d] = mesh[d] * scale + SplineOrder;
    }
    fitter->SetNumberOfControlPoints(controlPoints);
    fitter->SetNumberOfLevels(1);
    fitter->SetGenerateOutputImage(false);
    fitter->SetNumberOfWorkUnits(m_FittingWorkUnits);
    fitter->Update();
    typename LatticeType::Pointer lattice = fitter->GetPhiLattice();
    lattice->DisconnectPipeline();

    // This level's correction at the points, then the sum of the levels as one lattice.
    makeTransform(lattice, levelTransform);
    MultiThreaderBase::New()->ParallelizeArray(
      0,
      count,
      [&](SizeValueType n) {
        const auto moved = levelTransform->TransformPoint(points[n]);
        for (unsigned int d = 0; d < Dimension; ++d)
        {
          residual[n][d] -= moved[d] - points[n][d];
        }
        residualNorms[n] = residual[n].GetNorm();
      },
      nullptr);
    if (total)
    {
      auto refiner = RefinerType::New();
      refiner->SetInput(total);
      refiner->SetSplineOrder(SplineOrder);
      typename RefinerType::ArrayType twoLevels;
      twoLevels.Fill(2);
      typename LatticeType::Pointer refined = refiner->RefineControlPointLattice(twoLevels);
      if (refined->GetLargestPossibleRegion().GetSize() != lattice->GetLargestPossibleRegion().GetSize())
      {
        itkExceptionMacro("internal error: refined lattice " << refined->GetLargestPossibleRegion().GetSize()
                                                             << " does not match level lattice "
                                                             << lattice->GetLargestPossibleRegion().GetSize());
      }
      ImageRegionConstIterator<LatticeType> coarse(refined, refined->GetLargestPossibleRegion());
      ImageRegionIterator<LatticeType>      fine(lattice, lattice->GetLargestPossibleRegion());
      for (; !fine.IsAtEnd(); ++coarse, ++fine)
      {
        fine.Set(fine.Get() + coarse.Get());
      }
    }
    total = lattice;

    report.levels = level + 1;
    measure(report);
    this->UpdateProgress(progressStart + (progressEnd - progressStart) * static_cast<float>(level + 1) /
                                           static_cast<float>(maximumLevels));
    if (report.maximumResidual <= m_Tolerance || level + 1 >= maximumLevels)
    {
      break;
    }
  }

  auto transform = BSplineTransformType::New();
  makeTransform(total, transform);

  // The report comes from the final transform itself, not from the level bookkeeping.
  MultiThreaderBase::New()->ParallelizeArray(
    0,
    count,
    [&](SizeValueType n) {
      const auto moved = transform->TransformPoint(points[n]);
      double     squared = 0.0;
      for (unsigned int d = 0; d < Dimension; ++d)
      {
        const double difference = (moved[d] - points[n][d]) - values[n][d];
        squared += difference * difference;
      }
      residualNorms[n] = std::sqrt(squared);
    },
    nullptr);
  measure(report);
  report.toleranceReached = report.maximumResidual <= m_Tolerance;
  report.controlPointSpacing.clear();
  report.meshSize.clear();
  const auto meshSize = transform->GetTransformDomainMeshSize();
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    report.meshSize.push_back(static_cast<unsigned int>(meshSize[d]));
    report.controlPointSpacing.push_back(extent[d] / static_cast<double>(meshSize[d]));
  }
  return transform;
}

template <typename TPointSet>
auto
DisplacementPointSetToBSplineTransformFilter<TPointSet>::SampleOnReferenceGrid(const BSplineTransformType * transform,
                                                                             const Domain & domain) const ->
  typename DisplacementFieldTransformType::Pointer
{
  using LatticeType = Image<VectorType, Dimension>;
  using SamplerType = BSplineControlPointImageFilter<LatticeType, DisplacementFieldType>;

  // The control-point lattice of the transform, as the sampler reads it.
  const auto coefficients = transform->GetCoefficientImages();
  auto       lattice = LatticeType::New();
  lattice->CopyInformation(coefficients[0]);
  lattice->SetRegions(coefficients[0]->GetLargestPossibleRegion());
  lattice->Allocate();
  {
    ImageRegionIterator<LatticeType> out(lattice, lattice->GetLargestPossibleRegion());
    std::vector<ImageRegionConstIterator<typename BSplineTransformType::ImageType>> in;
    for (unsigned int c = 0; c < Dimension; ++c)
    {
      in.emplace_back(coefficients[c], coefficients[c]->GetLargestPossibleRegion());
    }
    for (; !out.IsAtEnd(); ++out)
    {
      VectorType value;
      for (unsigned int c = 0; c < Dimension; ++c)
      {
        value[c] = in[c].Get();
        ++in[c];
      }
      out.Set(value);
    }
  }

  // Sampled over the whole fitting domain, then cut to the reference grid.
  auto sampler = SamplerType::New();
  sampler->SetInput(lattice);
  sampler->SetSplineOrder(SplineOrder);
  sampler->SetOrigin(domain.origin);
  sampler->SetSpacing(domain.spacing);
  sampler->SetSize(domain.size);
  sampler->SetDirection(domain.direction);
  sampler->Update();
  typename DisplacementFieldType::Pointer field = sampler->GetOutput();

  const auto referenceRegion = this->GetReferenceImage()->GetLargestPossibleRegion();
  typename DisplacementFieldType::RegionType cut;
  for (unsigned int d = 0; d < Dimension; ++d)
  {
    cut.SetIndex(d, -domain.offsetInReference[d]);
    cut.SetSize(d, referenceRegion.GetSize()[d]);
  }
  using CropType = RegionOfInterestImageFilter<DisplacementFieldType, DisplacementFieldType>;
  auto crop = CropType::New();
  crop->SetInput(field);
  crop->SetRegionOfInterest(cut);
  crop->Update();
  typename DisplacementFieldType::Pointer cropped = crop->GetOutput();
  cropped->DisconnectPipeline();
  // The crop starts at index 0; give it the reference image's own region and origin.
  typename DisplacementFieldType::RegionType region = cropped->GetLargestPossibleRegion();
  region.SetIndex(referenceRegion.GetIndex());
  cropped->SetRegions(region);
  cropped->SetOrigin(this->GetReferenceImage()->GetOrigin());

  auto fieldTransform = DisplacementFieldTransformType::New();
  fieldTransform->SetDisplacementField(cropped);
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

  const float backwardEnd = m_GenerateForwardTransform ? 0.45f : 0.9f;
  auto        backward = this->Fit(deformed, negated, domain, m_Report, 0.0f, backwardEnd);
  static_cast<BSplineTransformOutputType *>(this->ProcessObject::GetOutput(0))->Set(backward);

  m_ForwardReport = BSplineFitReport{};
  typename BSplineTransformType::Pointer forward;
  if (m_GenerateForwardTransform)
  {
    forward = this->Fit(reference, displacement, domain, m_ForwardReport, 0.45f, 0.9f);
  }
  static_cast<BSplineTransformOutputType *>(this->ProcessObject::GetOutput(1))->Set(forward);

  typename DisplacementFieldTransformType::Pointer field;
  if (m_GenerateDisplacementField)
  {
    field = this->SampleOnReferenceGrid(backward, domain);
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
  os << indent << "FittingWorkUnits: " << m_FittingWorkUnits << std::endl;
  os << indent << "Report: levels " << m_Report.levels << ", maximum residual " << m_Report.maximumResidual
     << " mm, RMS " << m_Report.rmsResidual << " mm, tolerance reached " << m_Report.toleranceReached << std::endl;
  os << indent << "DomainExtended: " << m_DomainExtended << std::endl;
}

} // namespace itk

#endif
