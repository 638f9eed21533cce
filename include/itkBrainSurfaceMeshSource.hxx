#ifndef itkBrainSurfaceMeshSource_hxx
#define itkBrainSurfaceMeshSource_hxx

#include "itkBrainSurfaceMeshSource.h"

#include "itkBiomechanicalImageConversion.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIterator.h"
#include "itkSignedMaurerDistanceMapImageFilter.h"
#include "itkTriangleCell.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

namespace itk
{

template <typename TMaskImage, typename TOutputMesh>
BrainSurfaceMeshSource<TMaskImage, TOutputMesh>::BrainSurfaceMeshSource()
{
  this->ProcessObject::SetNumberOfRequiredOutputs(2);
  this->ProcessObject::SetNthOutput(1, this->MakeOutput(1));
}

template <typename TMaskImage, typename TOutputMesh>
auto
BrainSurfaceMeshSource<TMaskImage, TOutputMesh>::GetSkullOutput() -> OutputMeshType *
{
  return dynamic_cast<OutputMeshType *>(this->ProcessObject::GetOutput(1));
}

template <typename TMaskImage, typename TOutputMesh>
void
BrainSurfaceMeshSource<TMaskImage, TOutputMesh>::GenerateData()
{
  const MaskImageType * mask = this->GetInput(0);
  if (mask == nullptr)
  {
    itkExceptionMacro("no brain mask: set the input (voxels > 0 are brain)");
  }
  if (!(m_SkullGap >= 0.0) || !std::isfinite(m_SkullGap))
  {
    itkExceptionMacro("SkullGap " << m_SkullGap << " mm must be a finite number >= 0 (default 1.5 mm)");
  }
  if (!(m_SkullClosing >= 0.0) || !std::isfinite(m_SkullClosing))
  {
    itkExceptionMacro("SkullClosing " << m_SkullClosing << " mm must be a finite number >= 0 (default 1; 0: no closing)");
  }

  // The mask's bounding box padded with background: ceil((gap + closing) / spacing) + 2
  // voxels along each axis, so the dilated (skull) level set closes inside the
  // volume. Cropped to the box, the distance maps and isosurfaces cover about
  // half of Colin27's 181 x 217 x 181 voxels.
  typename MaskImageType::RegionType region;
  {
    const auto & buffered = mask->GetBufferedRegion();
    Index<3>     low, high;
    low.Fill(NumericTraits<IndexValueType>::max());
    high.Fill(NumericTraits<IndexValueType>::NonpositiveMin());
    for (ImageRegionConstIteratorWithIndex<MaskImageType> it(mask, buffered); !it.IsAtEnd(); ++it)
    {
      if (it.Get() > NumericTraits<typename MaskImageType::PixelType>::ZeroValue())
      {
        for (unsigned int d = 0; d < 3; ++d)
        {
          low[d] = std::min(low[d], it.GetIndex()[d]);
          high[d] = std::max(high[d], it.GetIndex()[d]);
        }
      }
    }
    if (low[0] > high[0])
    {
      itkExceptionMacro("the brain mask (" << buffered.GetSize() << " voxels) has no voxel > 0: nothing to triangulate. "
                                           << "Give a brain mask (for example from AtlasBrainMaskImageFilter)");
    }
    region.SetIndex(low);
    for (unsigned int d = 0; d < 3; ++d)
    {
      region.SetSize(d, static_cast<SizeValueType>(high[d] - low[d] + 1));
    }
  }
  typename BinaryImageType::RegionType   paddedRegion;
  typename BinaryImageType::IndexType    firstIndex = region.GetIndex();
  Index<3>                               pad;
  for (unsigned int d = 0; d < 3; ++d)
  {
    pad[d] = static_cast<IndexValueType>(std::ceil((m_SkullGap + m_SkullClosing) / mask->GetSpacing()[d])) + 2;
    paddedRegion.SetIndex(d, 0);
    paddedRegion.SetSize(d, region.GetSize()[d] + 2 * static_cast<SizeValueType>(pad[d]));
    firstIndex[d] -= pad[d];
  }
  typename BinaryImageType::PointType paddedOrigin;
  mask->TransformIndexToPhysicalPoint(firstIndex, paddedOrigin);
  auto brain = BinaryImageType::New();
  brain->SetRegions(paddedRegion);
  brain->SetSpacing(mask->GetSpacing());
  brain->SetDirection(mask->GetDirection());
  brain->SetOrigin(paddedOrigin);
  brain->Allocate(true);
  auto background = BinaryImageType::New();
  background->CopyInformation(brain);
  background->SetRegions(paddedRegion);
  background->Allocate();
  background->FillBuffer(1);

  for (ImageRegionConstIteratorWithIndex<MaskImageType> it(mask, region); !it.IsAtEnd(); ++it)
  {
    if (it.Get() > NumericTraits<typename MaskImageType::PixelType>::ZeroValue())
    {
      typename BinaryImageType::IndexType index;
      for (unsigned int d = 0; d < 3; ++d)
      {
        index[d] = it.GetIndex()[d] - region.GetIndex()[d] + pad[d];
      }
      brain->SetPixel(index, 1);
      background->SetPixel(index, 0);
    }
  }

  // Maurer distances are to the centres of the boundary voxels of the object:
  // +h/2 biased for the brain, -h/2 for the complement; their mean is unbiased.
  using DistanceFilterType = SignedMaurerDistanceMapImageFilter<BinaryImageType, DistanceImageType>;
  auto distanceInBrain = DistanceFilterType::New();
  distanceInBrain->SetInput(brain);
  distanceInBrain->SetBackgroundValue(0);
  distanceInBrain->SetUseImageSpacing(true);
  distanceInBrain->SetSquaredDistance(false);
  distanceInBrain->SetInsideIsPositive(false);
  auto distanceInBackground = DistanceFilterType::New();
  distanceInBackground->SetInput(background);
  distanceInBackground->SetBackgroundValue(0);
  distanceInBackground->SetUseImageSpacing(true);
  distanceInBackground->SetSquaredDistance(false);
  distanceInBackground->SetInsideIsPositive(true); // positive in the brain's complement
  distanceInBrain->Update();
  distanceInBackground->Update();
  this->UpdateProgress(0.4f);

  bmr::ScalarVolume signedDistance = MakeBiomechanicalVolume<float>(distanceInBrain->GetOutput());
  {
    const bmr::ScalarVolume other = MakeBiomechanicalVolume<float>(distanceInBackground->GetOutput());
    for (std::size_t n = 0; n < signedDistance.values.size(); ++n)
    {
      signedDistance.values[n] = 0.5f * (signedDistance.values[n] + other.values[n]);
    }
  }

  bmr::BrainSurfaceSettings settings;
  settings.skullGap = m_SkullGap;
  settings.skullClosing = m_SkullClosing;
  settings.isosurface.smoothingIterations = m_SmoothingIterations;
  settings.isosurface.smoothingPassBand = m_SmoothingPassBand;
  settings.isosurface.targetEdgeLength = m_TargetEdgeLength;
  settings.skull = m_ComputeSkull;
  m_Warnings.clear();
  try
  {
    m_Surfaces = bmr::ExtractBrainSurfaces(signedDistance, settings, &m_Warnings);
  }
  catch (const bmr::Error & error)
  {
    itkExceptionMacro("brain surfaces: " << error.what());
  }
  for (const auto & warning : m_Warnings)
  {
    itkWarningMacro(<< warning);
  }
  this->UpdateProgress(0.9f);

  FillMeshFromContactSurface(m_Surfaces.brain, this->GetOutput());
  FillMeshFromContactSurface(m_Surfaces.skull, this->GetSkullOutput());
  this->UpdateProgress(1.0f);
}

template <typename TMaskImage, typename TOutputMesh>
void
BrainSurfaceMeshSource<TMaskImage, TOutputMesh>::PrintSelf(std::ostream & os, Indent indent) const
{
  Superclass::PrintSelf(os, indent);
  os << indent << "SkullGap: " << m_SkullGap << " mm" << std::endl;
  os << indent << "SkullClosing: " << m_SkullClosing << " mm" << std::endl;
  os << indent << "SmoothingIterations: " << m_SmoothingIterations << std::endl;
  os << indent << "SmoothingPassBand: " << m_SmoothingPassBand << std::endl;
  os << indent << "TargetEdgeLength: " << m_TargetEdgeLength << " mm" << std::endl;
  os << indent << "ComputeSkull: " << (m_ComputeSkull ? "On" : "Off") << std::endl;
  os << indent << "Brain surface: " << m_Surfaces.brain.vertices.size() << " vertices, "
     << m_Surfaces.brain.triangles.size() << " triangles" << std::endl;
  os << indent << "Skull surface: " << m_Surfaces.skull.vertices.size() << " vertices, "
     << m_Surfaces.skull.triangles.size() << " triangles" << std::endl;
}

} // namespace itk

#endif
