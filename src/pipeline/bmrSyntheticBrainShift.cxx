#include "bmrSyntheticBrainShift.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBSplineIntensityRegistrationFilter.h"
#include "itkBiomechanicalImageConversion.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkImageRegionIteratorWithIndex.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>
#include <set>
#include <sstream>

namespace bmr
{
namespace
{

/** A sphere of voxels (inside the brain) on the preoperative grid. */
RegistrationLabelImage::Pointer
SphereMask(const RegistrationLabelImage * brainMask, const Vector3 & centre, double radius)
{
  auto mask = RegistrationLabelImage::New();
  mask->CopyInformation(brainMask);
  mask->SetRegions(brainMask->GetBufferedRegion());
  mask->Allocate();
  mask->FillBuffer(0);
  itk::ImageRegionIteratorWithIndex<RegistrationLabelImage> it(mask, mask->GetBufferedRegion());
  std::size_t                                              count = 0;
  for (; !it.IsAtEnd(); ++it)
  {
    RegistrationLabelImage::PointType point;
    mask->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    const Vector3 x(point[0], point[1], point[2]);
    if ((x - centre).norm() <= radius && brainMask->GetPixel(it.GetIndex()) > 0)
    {
      it.Set(1);
      ++count;
    }
  }
  if (count == 0)
  {
    throw Error("the synthetic tumour (centre " + FormatPoint(centre) + ", radius " + std::to_string(radius) +
                " mm) has no voxel inside the brain mask; move it into the brain");
  }
  return mask;
}

/** Largest displacement over the nodes of `nodes`. */
double
LargestDisplacement(const std::vector<Vector3> & displacements, const std::vector<Index> & nodes)
{
  double largest = 0.0;
  for (const Index node : nodes)
  {
    largest = std::max(largest, displacements[node].norm());
  }
  return largest;
}

/** An empty image with the given spacing covering the physical extent of `image` (same origin and directions). */
RegistrationImage::Pointer
ResampledGrid(const RegistrationImage * image, const Vector3 & spacing)
{
  const auto size = image->GetLargestPossibleRegion().GetSize();
  auto       grid = RegistrationImage::New();
  grid->SetOrigin(image->GetOrigin());
  grid->SetDirection(image->GetDirection());
  RegistrationImage::SpacingType newSpacing;
  RegistrationImage::SizeType    newSize;
  for (unsigned int d = 0; d < 3; ++d)
  {
    newSpacing[d] = spacing[d];
    const double extent = static_cast<double>(size[d] - 1) * image->GetSpacing()[d];
    newSize[d] = static_cast<itk::SizeValueType>(std::floor(extent / spacing[d])) + 1;
  }
  grid->SetSpacing(newSpacing);
  grid->SetRegions(newSize);
  return grid;
}

} // namespace

SyntheticBrainShift
MakeSyntheticBrainShift(const RegistrationImage *           preoperativeImage,
                        const RegistrationLabelImage *      brainMask,
                        const SyntheticBrainShiftSettings & settings,
                        const StageCallback &               stageCallback)
{
  if (preoperativeImage == nullptr || brainMask == nullptr)
  {
    throw Error("MakeSyntheticBrainShift: give the preoperative image and its brain mask");
  }
  if (!(settings.targetShift > 0.0))
  {
    throw Error("MakeSyntheticBrainShift: the target shift must be > 0 mm");
  }
  SyntheticBrainShift truth;
  truth.timer = StageTimer(stageCallback);
  StageTimer & timer = truth.timer;

  if (settings.tumourRadius > 0.0)
  {
    truth.tumourMask = SphereMask(brainMask, settings.tumourCentre, settings.tumourRadius);
  }

  BrainModelSettings modelSettings;
  modelSettings.grid = settings.grid;
  modelSettings.craniotomyCentre = settings.craniotomyCentre;
  modelSettings.craniotomyRadius = settings.craniotomyRadius;
  modelSettings.threads = settings.threads;
  Material csf = CsfMaterial();
  csf.youngsModulus = settings.csfYoungsModulus;
  csf.poissonRatio = settings.csfPoissonRatio;
  csf.density = settings.csfDensity;
  Material parenchyma = ParenchymaMaterial();
  parenchyma.poissonRatio = settings.poissonRatio;
  modelSettings.materials.classMaterials = DefaultClassMaterials(modelSettings.classifier.classes, csf, parenchyma);
  modelSettings.materials.tumour.youngsModulus = settings.tumourStiffness * ParenchymaMaterial().youngsModulus;
  modelSettings.materials.tumour.poissonRatio = settings.poissonRatio;
  truth.model = BuildBrainModel(preoperativeImage, brainMask, truth.tumourMask, ContactSurface{}, nullptr,
                                modelSettings, timer);
  Model & model = truth.model.model;
  Vector3 centroid = Vector3::Zero();
  for (const Vector3 & node : model.nodes)
  {
    centroid += node;
  }
  centroid /= static_cast<double>(model.nodes.size());
  const Vector3 down = (centroid - settings.craniotomyCentre).normalized();
  truth.down = down;

  // The sag of the exposed surface, and gravity on the rest.
  PrescribedDisplacement sag;
  for (const Index node : truth.model.exposedNodes)
  {
    const double r = (model.nodes[node] - settings.craniotomyCentre).norm() / settings.craniotomyRadius;
    sag.nodes.push_back(node);
    sag.displacements.push_back(settings.targetShift * std::max(0.0, 1.0 - r * r) * down);
  }
  model.prescribedDisplacements = { sag };
  // The exposed nodes are moved, not in contact.
  if (!model.contactSurfaces.empty())
  {
    std::vector<char> exposed(model.nodes.size(), 0);
    for (const Index node : sag.nodes)
    {
      exposed[node] = 1;
    }
    std::vector<Index> & contact = model.nodeSets["contact"];
    contact.erase(std::remove_if(contact.begin(), contact.end(), [&](Index node) { return exposed[node] != 0; }),
                  contact.end());
  }
  truth.gravity = settings.gravity * 9810.0 * down;
  model.bodyAcceleration = truth.gravity;

  SolverSettings solverSettings;
  solverSettings.tolerance = settings.solverTolerance;
  solverSettings.threads = settings.threads;
  truth.solve = timer.Run("truth-solve", [&] {
    try
    {
      Solver solver(model, solverSettings);
      return solver.Solve();
    }
    catch (const SolveError & error)
    {
      throw Error(std::string("the ground-truth solve failed: ") + error.what());
    }
  });
  if (!truth.solve.converged)
  {
    throw Error("the ground-truth solve did not converge: " + truth.solve.message);
  }
  truth.shift = LargestDisplacement(truth.solve.displacements, truth.model.exposedNodes);

  // The ground truth's maps: backward for warping, forward for moving the exposed surface.
  using PointSetType = itk::DisplacementPointSetType<3>;
  using FitterType = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>;
  RegistrationTransform::ConstPointer forward;
  timer.Run("truth-fit", [&] {
    auto fitter = FitterType::New();
    fitter->SetInput(itk::MakeDisplacementPointSet<PointSetType>(model.nodes, truth.solve.displacements));
    fitter->SetReferenceImage(preoperativeImage);
    fitter->SetTolerance(0.05);
    fitter->GenerateForwardTransformOn();
    fitter->Update();
    truth.truthTransform = const_cast<RegistrationTransform *>(fitter->GetTransform());
    truth.truthFitMaxResidual = fitter->GetReport().maximumResidual;
    forward = fitter->GetForwardTransform();
  });

  // The exposed surface as a surface scanner would see it: the smooth
  // preoperative brain surface inside the craniotomy, moved by the ground truth.
  timer.Run("exposed-surface", [&] {
    // A little wider than the opening, as a scanner sees it: the registration's
    // exposed nodes at the rim then find their partners on the surface, not on its edge.
    const double             patchRadius = settings.craniotomyRadius + settings.scanMargin;
    const ContactSurface &   brain = truth.model.surfaces.brain;
    std::vector<Index>       newIndex(brain.vertices.size(), -1);
    ContactSurface &         exposed = truth.exposedSurface;
    exposed.name = "displaced exposed surface";
    for (const auto & triangle : brain.triangles)
    {
      bool inside = true;
      for (const Index vertex : triangle)
      {
        inside = inside && (brain.vertices[vertex] - settings.craniotomyCentre).norm() <= patchRadius;
      }
      if (!inside)
      {
        continue;
      }
      std::array<Index, 3> copy{};
      for (int k = 0; k < 3; ++k)
      {
        Index & mapped = newIndex[triangle[k]];
        if (mapped < 0)
        {
          const Vector3 & v = brain.vertices[triangle[k]];
          const auto      moved = forward->TransformPoint(RegistrationTransform::InputPointType(v.data()));
          mapped = static_cast<Index>(exposed.vertices.size());
          exposed.vertices.emplace_back(moved[0], moved[1], moved[2]);
        }
        copy[k] = mapped;
      }
      exposed.triangles.push_back(copy);
    }
    // Tracked points: the first surface vertex met in each cube of trackedPointSpacing within the opening.
    std::set<std::array<long, 3>> taken;
    for (const Vector3 & v : brain.vertices)
    {
      if ((v - settings.craniotomyCentre).norm() > settings.craniotomyRadius)
      {
        continue;
      }
      const std::array<long, 3> cube{ std::lround(std::floor(v.x() / settings.trackedPointSpacing)),
                                      std::lround(std::floor(v.y() / settings.trackedPointSpacing)),
                                      std::lround(std::floor(v.z() / settings.trackedPointSpacing)) };
      if (!taken.insert(cube).second)
      {
        continue;
      }
      const auto moved = forward->TransformPoint(RegistrationTransform::InputPointType(v.data()));
      truth.trackedPoints.points.push_back(v);
      truth.trackedPoints.displacements.emplace_back(moved[0] - v.x(), moved[1] - v.y(), moved[2] - v.z());
    }
    if (exposed.triangles.empty())
    {
      throw Error("the craniotomy (centre " + FormatPoint(settings.craniotomyCentre) + ", radius " +
                  std::to_string(settings.craniotomyRadius) + " mm) contains no triangle of the brain surface");
    }
  });

  // The intraoperative image: the preoperative image warped by the ground
  // truth onto an intraoperative grid, with noise; and its brain mask.
  timer.Run("intraop-image", [&] {
    const auto grid = ResampledGrid(preoperativeImage, settings.intraoperativeSpacing);
    truth.intraoperativeImage = WarpImage(preoperativeImage, truth.truthTransform, grid);
    truth.intraoperativeBrainMask = WarpLabelImage(brainMask, truth.truthTransform, grid);
    truth.intraoperativeBrainOnPreoperativeGrid = WarpLabelImage(brainMask, truth.truthTransform);
    if (settings.noise > 0.0)
    {
      const double                     level = OverlayGreyRange(preoperativeImage).second;
      std::mt19937                     random(settings.seed);
      std::normal_distribution<double> normal(0.0, settings.noise * level);
      float *                          values = truth.intraoperativeImage->GetBufferPointer();
      for (std::size_t n = 0, count = truth.intraoperativeImage->GetBufferedRegion().GetNumberOfPixels(); n < count;
           ++n)
      {
        values[n] = static_cast<float>(values[n] + normal(random));
      }
    }
  });
  return truth;
}

DisplacementError
MeasureDisplacementError(const itk::Transform<double, 3, 3> * transform,
                         const itk::Transform<double, 3, 3> * truth,
                         const RegistrationLabelImage *       region,
                         int                                  stride)
{
  if (truth == nullptr || region == nullptr || stride < 1)
  {
    throw Error("MeasureDisplacementError: give the ground-truth transform, the region and a stride >= 1");
  }
  const auto          size = region->GetBufferedRegion().GetSize();
  const auto          start = region->GetBufferedRegion().GetIndex();
  std::vector<double> errors;
  RegistrationLabelImage::IndexType index;
  for (index[2] = start[2]; index[2] < start[2] + static_cast<itk::IndexValueType>(size[2]); index[2] += stride)
  {
    for (index[1] = start[1]; index[1] < start[1] + static_cast<itk::IndexValueType>(size[1]); index[1] += stride)
    {
      for (index[0] = start[0]; index[0] < start[0] + static_cast<itk::IndexValueType>(size[0]); index[0] += stride)
      {
        if (region->GetPixel(index) == 0)
        {
          continue;
        }
        RegistrationLabelImage::PointType x;
        region->TransformIndexToPhysicalPoint(index, x);
        const auto expected = truth->TransformPoint(x);
        const auto estimate = transform != nullptr ? transform->TransformPoint(x) : x;
        errors.push_back(expected.EuclideanDistanceTo(estimate));
      }
    }
  }
  DisplacementError result;
  result.samples = errors.size();
  if (errors.empty())
  {
    throw Error("MeasureDisplacementError: the region has no voxel; give the brain mask of the intraoperative image");
  }
  double sum = 0.0;
  for (const double error : errors)
  {
    sum += error;
  }
  result.mean = sum / static_cast<double>(errors.size());
  const auto p95 = errors.begin() + static_cast<std::ptrdiff_t>(std::ceil(0.95 * static_cast<double>(errors.size())) - 1);
  std::nth_element(errors.begin(), p95, errors.end());
  result.p95 = *p95;
  result.max = *std::max_element(errors.begin(), errors.end());
  return result;
}

BaselineRegistration
RegisterWithBSplineBaseline(const RegistrationImage *      fixed,
                            const RegistrationImage *      moving,
                            const RegistrationLabelImage * fixedMask,
                            const BaselineSettings &       settings)
{
  using FilterType = itk::BSplineIntensityRegistrationFilter<RegistrationImage, RegistrationImage, RegistrationLabelImage>;
  auto filter = FilterType::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  if (fixedMask != nullptr)
  {
    filter->SetFixedMask(fixedMask);
  }
  filter->SetShrinkFactors(settings.shrinkFactors);
  filter->SetSmoothingSigmas(settings.smoothingSigmas);
  if (settings.iterations > 0)
  {
    filter->SetNumberOfIterations(settings.iterations);
  }
  if (settings.controlPointSpacing)
    filter->SetControlPointSpacing(*settings.controlPointSpacing);
  if (settings.useTranslationStage)
    filter->SetUseTranslationStage(*settings.useTranslationStage);
  if (settings.translationIterations)
    filter->SetTranslationNumberOfIterations(*settings.translationIterations);
  if (settings.refineMeshPerLevel)
    filter->SetRefineMeshPerLevel(*settings.refineMeshPerLevel);
  if (settings.histogramBins)
    filter->SetNumberOfHistogramBins(*settings.histogramBins);
  if (settings.metricSamplingPercentage)
    filter->SetMetricSamplingPercentage(*settings.metricSamplingPercentage);
  if (settings.costFunctionConvergenceFactor)
    filter->SetCostFunctionConvergenceFactor(*settings.costFunctionConvergenceFactor);
  if (settings.randomSeed)
    filter->SetRandomSeed(*settings.randomSeed);
  const auto start = std::chrono::steady_clock::now();
  try
  {
    filter->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(std::string("B-spline registration failed: ") + exception.GetDescription());
  }
  BaselineRegistration result;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  result.transform = const_cast<RegistrationTransform *>(filter->GetTransform());
  result.warpedOnFixedGrid = filter->GetOutput();
  result.warpedOnFixedGrid->DisconnectPipeline();
  return result;
}

} // namespace bmr
