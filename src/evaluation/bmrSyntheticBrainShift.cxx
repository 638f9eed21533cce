#include "bmrSyntheticBrainShift.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBSplineIntensityRegistrationFilter.h"
#include "itkBiomechanicalImageConversion.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkImageRegionIteratorWithIndex.h"

#include "bmrUnits.h"

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

/** Piecewise-linear intensity map through the tissue classes' centres: 0 -> 0,
 *  centre k -> target k, beyond the brightest centre the last segment's ratio. */
struct ClassIntensityMap
{
  std::vector<double> centres; // ascending
  std::vector<double> targets;

  double operator()(double value) const
  {
    if (value <= 0.0)
    {
      return value * targets.front() / centres.front();
    }
    double x0 = 0.0, y0 = 0.0;
    for (std::size_t k = 0; k < centres.size(); ++k)
    {
      if (value <= centres[k])
      {
        return y0 + (value - x0) * (targets[k] - y0) / (centres[k] - x0);
      }
      x0 = centres[k];
      y0 = targets[k];
    }
    return value * targets.back() / centres.back();
  }
};

/** The intraoperative grid: `spacing` over the preoperative image's extent,
 *  cropped to a cube of edge `fieldOfView` (mm; 0: no cropping) centred on `centre`. */
RegistrationImage::Pointer
IntraoperativeGrid(const RegistrationImage * image, const Vector3 & spacing, double fieldOfView, const Vector3 & centre)
{
  RegistrationImage::Pointer grid = ResampledGrid(image, spacing);
  if (fieldOfView <= 0.0)
  {
    return grid;
  }
  const auto size = grid->GetLargestPossibleRegion().GetSize();
  std::array<double, 3> lower{ 1e300, 1e300, 1e300 }, upper{ -1e300, -1e300, -1e300 };
  for (int corner = 0; corner < 8; ++corner)
  {
    RegistrationImage::PointType point;
    for (unsigned int d = 0; d < 3; ++d)
    {
      point[d] = centre[d] + ((corner >> d) & 1 ? 0.5 : -0.5) * fieldOfView;
    }
    itk::ContinuousIndex<double, 3> index;
    grid->TransformPhysicalPointToContinuousIndex(point, index);
    for (unsigned int d = 0; d < 3; ++d)
    {
      lower[d] = std::min(lower[d], index[d]);
      upper[d] = std::max(upper[d], index[d]);
    }
  }
  RegistrationImage::IndexType first;
  RegistrationImage::SizeType  cropped;
  for (unsigned int d = 0; d < 3; ++d)
  {
    const double from = std::max(0.0, std::ceil(lower[d]));
    const double to = std::min(static_cast<double>(size[d]) - 1.0, std::floor(upper[d]));
    if (!(to >= from))
    {
      throw Error("the intraoperative field of view (a " + std::to_string(fieldOfView) + " mm cube around " +
                  FormatPoint(centre) + ") holds no voxel of the image; enlarge it or give 0 for the whole head");
    }
    first[d] = static_cast<itk::IndexValueType>(from);
    cropped[d] = static_cast<itk::SizeValueType>(to - from) + 1;
  }
  RegistrationImage::PointType origin;
  grid->TransformIndexToPhysicalPoint(first, origin);
  grid->SetOrigin(origin);
  grid->SetRegions(cropped);
  return grid;
}

/** Where the backward map takes a voxel into the resection cavity: the image
 *  there shows `fluid`, and the brain mask loses it. */
void
FillResectionCavity(RegistrationImage * image, RegistrationLabelImage * brainMask, const RegistrationTransform * backward,
                    const Vector3 & centre, double radius, float fluid)
{
  itk::ImageRegionIteratorWithIndex<RegistrationLabelImage> it(brainMask, brainMask->GetBufferedRegion());
  for (; !it.IsAtEnd(); ++it)
  {
    RegistrationLabelImage::PointType point;
    brainMask->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    const auto    source = backward->TransformPoint(point);
    const Vector3 x(source[0], source[1], source[2]);
    if ((x - centre).norm() <= radius)
    {
      it.Set(0);
      if (image != nullptr)
      {
        image->SetPixel(it.GetIndex(), fluid);
      }
    }
  }
}

/** Mean of the model's nodes: where "down" points to from the craniotomy. */
Vector3
NodeCentroid(const Model & model)
{
  Vector3 centroid = Vector3::Zero();
  for (const Vector3 & node : model.nodes)
  {
    centroid += node;
  }
  return centroid / static_cast<double>(model.nodes.size());
}

} // namespace

RegistrationImage::Pointer
MakeImageInContrast(const RegistrationImage * image, const RegistrationLabelImage * brainMask,
                    IntraoperativeContrast contrast)
{
  if (image == nullptr || brainMask == nullptr ||
      image->GetBufferedRegion().GetSize() != brainMask->GetBufferedRegion().GetSize())
  {
    throw Error("MakeImageInContrast: give an image and a brain mask on the same grid");
  }
  std::vector<float> samples;
  const float *         values = image->GetBufferPointer();
  const unsigned char * inside = brainMask->GetBufferPointer();
  const std::size_t     count = image->GetBufferedRegion().GetNumberOfPixels();
  for (std::size_t n = 0; n < count; ++n)
  {
    if (inside[n] > 0)
    {
      samples.push_back(values[n]);
    }
  }
  FuzzyCMeansSettings classes;
  classes.classes = 3;
  const FuzzyCMeansResult fit = FitFuzzyCMeans(samples, classes);
  ClassIntensityMap       map;
  map.centres = fit.centroids;
  const double white = fit.centroids.back();
  if (!(fit.centroids.front() > 0.0) || !(fit.centroids[1] > fit.centroids[0]) || !(white > fit.centroids[1]))
  {
    throw Error("the intraoperative contrast needs three distinct positive tissue intensities in the brain; "
                "the preoperative image's classes are at " + FormatPoint(Vector3(fit.centroids[0], fit.centroids[1], white)));
  }
  for (const double centre : fit.centroids)
  {
    // T2-like: CSF twice as bright as white matter, grey matter 1.3 times.
    // Low-field T1: half the contrast of each class against white matter.
    const std::size_t k = map.targets.size();
    map.targets.push_back(contrast == IntraoperativeContrast::T2Like       ? white * std::array<double, 3>{ 1.0, 0.65, 0.5 }[k]
                          : contrast == IntraoperativeContrast::LowFieldT1 ? white - 0.5 * (white - centre)
                                                                           : centre);
  }
  auto result = RegistrationImage::New();
  result->CopyInformation(image);
  result->SetRegions(image->GetBufferedRegion());
  result->Allocate();
  float * mapped = result->GetBufferPointer();
  for (std::size_t n = 0; n < count; ++n)
  {
    mapped[n] = static_cast<float>(map(values[n]));
  }
  return result;
}

void
ApplyBiasField(RegistrationImage * image, double amplitude, std::uint32_t seed)
{
  std::mt19937                     random(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::array<double, 9>            weights{}; // x, y, z, xx, yy, zz, xy, yz, zx
  for (double & weight : weights)
  {
    weight = normal(random);
  }
  const auto size = image->GetBufferedRegion().GetSize();
  const auto polynomial = [&](const RegistrationImage::IndexType & index) {
    std::array<double, 3> x{};
    for (unsigned int d = 0; d < 3; ++d)
    {
      x[d] = size[d] > 1 ? 2.0 * static_cast<double>(index[d]) / static_cast<double>(size[d] - 1) - 1.0 : 0.0;
    }
    return weights[0] * x[0] + weights[1] * x[1] + weights[2] * x[2] + weights[3] * x[0] * x[0] +
           weights[4] * x[1] * x[1] + weights[5] * x[2] * x[2] + weights[6] * x[0] * x[1] + weights[7] * x[1] * x[2] +
           weights[8] * x[2] * x[0];
  };
  double                                              largest = 0.0;
  itk::ImageRegionIteratorWithIndex<RegistrationImage> it(image, image->GetBufferedRegion());
  for (it.GoToBegin(); !it.IsAtEnd(); ++it)
  {
    largest = std::max(largest, std::abs(polynomial(it.GetIndex())));
  }
  for (it.GoToBegin(); !it.IsAtEnd(); ++it)
  {
    it.Set(static_cast<float>(it.Get() * (1.0 + amplitude * polynomial(it.GetIndex()) / largest)));
  }
}

void
AddImageNoise(RegistrationImage * image, double deviation, NoiseModel model, std::uint32_t seed)
{
  std::mt19937                     random(seed);
  std::normal_distribution<double> normal(0.0, deviation);
  float *                          values = image->GetBufferPointer();
  for (std::size_t n = 0, count = image->GetBufferedRegion().GetNumberOfPixels(); n < count; ++n)
  {
    const double real = values[n] + normal(random);
    values[n] = static_cast<float>(model == NoiseModel::Rician ? std::hypot(real, normal(random)) : real);
  }
}

const char *
IntraoperativeContrastName(IntraoperativeContrast contrast)
{
  switch (contrast)
  {
    case IntraoperativeContrast::T2Like:
      return "t2";
    case IntraoperativeContrast::LowFieldT1:
      return "low-field-t1";
    default:
      return "preoperative";
  }
}

IntraoperativeContrast
ParseIntraoperativeContrast(const std::string & name)
{
  for (const IntraoperativeContrast contrast :
       { IntraoperativeContrast::Preoperative, IntraoperativeContrast::T2Like, IntraoperativeContrast::LowFieldT1 })
  {
    if (name == IntraoperativeContrastName(contrast))
    {
      return contrast;
    }
  }
  throw Error("unknown intraoperative contrast '" + name + "'; choose preoperative, t2 or low-field-t1");
}

namespace
{
void
CheckSyntheticSettings(const SyntheticBrainShiftSettings & settings)
{
  if (!(settings.targetShift > 0.0))
  {
    throw Error("MakeSyntheticBrainShift: the target shift must be > 0 mm");
  }
  if (!(settings.freeRim >= 0.0 && settings.freeRim < 1.0))
  {
    throw Error("MakeSyntheticBrainShift: the free rim is a fraction of the craniotomy's radius in [0, 1) (0.2 for "
                "shifts of 15 mm and more)");
  }
  if (!(settings.biasField >= 0.0 && settings.biasField < 1.0))
  {
    throw Error("MakeSyntheticBrainShift: the bias field's amplitude must be in [0, 1) (0.2: +-20 %)");
  }
  if (!(settings.fieldOfView == 0.0 || settings.fieldOfView >= 2.0 * settings.scanMargin + 20.0))
  {
    throw Error("MakeSyntheticBrainShift: the field of view must be 0 (the whole head) or at least " +
                std::to_string(2.0 * settings.scanMargin + 20.0) + " mm, to show the craniotomy");
  }
  if (settings.resectionMargin >= 0.0 && !(settings.tumourRadius > 0.0))
  {
    throw Error("MakeSyntheticBrainShift: a resection removes the tumour; give a tumour (centre and radius) "
                "or no resection margin");
  }
  const bool heterogeneous = settings.greyMatterYoungsModulus != 0.0 || settings.whiteMatterYoungsModulus != 0.0;
  if (heterogeneous && !(settings.greyMatterYoungsModulus > 0.0 && settings.whiteMatterYoungsModulus > 0.0))
  {
    throw Error("MakeSyntheticBrainShift: give grey and white matter's Young's moduli both > 0 Pa (e.g. 1390 and "
                "1895), or both 0 for one parenchyma");
  }
  if (!(settings.mooneyRivlinShare >= 0.0 && settings.mooneyRivlinShare <= 1.0))
  {
    throw Error("MakeSyntheticBrainShift: the Mooney-Rivlin share is " + std::to_string(settings.mooneyRivlinShare) +
                "; give C01 / (C10 + C01) in (0, 1], or 0 for the registration's neo-Hookean law");
  }
}

Material
TruthCsfMaterial(const SyntheticBrainShiftSettings & settings)
{
  Material csf = CsfMaterial();
  csf.youngsModulus = settings.csfYoungsModulus;
  csf.poissonRatio = settings.csfPoissonRatio;
  csf.density = settings.csfDensity;
  return csf;
}

// The truth's model: the registration's pipeline on the same images with the
// truth's grid, classes and materials (grey and white matter apart, a
// Mooney-Rivlin parenchyma, when asked).
BrainModelSettings
TruthModelSettings(const SyntheticBrainShiftSettings & settings, const Material & csf)
{
  const bool heterogeneous = settings.greyMatterYoungsModulus != 0.0 || settings.whiteMatterYoungsModulus != 0.0;
  BrainModelSettings modelSettings;
  modelSettings.grid = settings.grid;
  modelSettings.craniotomyCentre = settings.craniotomyCentre;
  modelSettings.craniotomyRadius = settings.craniotomyRadius;
  modelSettings.threads = settings.threads;
  modelSettings.skullClosing = settings.skullClosing;
  Material parenchyma = ParenchymaMaterial();
  parenchyma.poissonRatio = settings.poissonRatio;
  if (heterogeneous)
  {
    modelSettings.classifier.classes = 3; // CSF, grey and white matter, in ascending T1 intensity
  }
  modelSettings.materials.classMaterials = DefaultClassMaterials(modelSettings.classifier.classes, csf, parenchyma);
  if (heterogeneous)
  {
    modelSettings.materials.classMaterials[1].name = "grey matter";
    modelSettings.materials.classMaterials[1].youngsModulus = settings.greyMatterYoungsModulus;
    modelSettings.materials.classMaterials[2].name = "white matter";
    modelSettings.materials.classMaterials[2].youngsModulus = settings.whiteMatterYoungsModulus;
  }
  modelSettings.materials.tumour.youngsModulus = settings.tumourStiffness * ParenchymaMaterial().youngsModulus;
  modelSettings.materials.tumour.poissonRatio = settings.poissonRatio;
  if (settings.mooneyRivlinShare > 0.0)
  {
    // Every class but the CSF (the first, darkest), and the tumour.
    for (std::size_t k = 1; k < modelSettings.materials.classMaterials.size(); ++k)
    {
      modelSettings.materials.classMaterials[k].law = MaterialLaw::MooneyRivlin;
      modelSettings.materials.classMaterials[k].secondInvariantShare = settings.mooneyRivlinShare;
    }
    modelSettings.materials.tumour.law = MaterialLaw::MooneyRivlin;
    modelSettings.materials.tumour.secondInvariantShare = settings.mooneyRivlinShare;
  }
  return modelSettings;
}

// The cavity's cells hold drained fluid: the CSF's material, weightless.
void
CarveResectionCavity(SyntheticBrainShift & truth, const RegistrationLabelImage * brainMask,
                     const SyntheticBrainShiftSettings & settings, const Material & csf)
{
  Model & model = truth.model.model;
  truth.resectionCavityRadius = settings.tumourRadius + settings.resectionMargin;
  truth.resectionMask = SphereMask(brainMask, settings.tumourCentre, truth.resectionCavityRadius);
  Material cavity = csf;
  cavity.name = "resection cavity";
  model.materials.push_back(cavity);
  std::size_t cavityCells = 0;
  for (Cell & cell : model.cells)
  {
    Vector3 centre = Vector3::Zero();
    const int corners = NodesPerCell(cell.type);
    for (int k = 0; k < corners; ++k)
    {
      centre += model.nodes[cell.nodes[k]];
    }
    if ((centre / corners - settings.tumourCentre).norm() <= truth.resectionCavityRadius)
    {
      cell.material = static_cast<Index>(model.materials.size() - 1);
      ++cavityCells;
    }
  }
  if (cavityCells == 0)
  {
    throw Error("the resection cavity (radius " + std::to_string(truth.resectionCavityRadius) +
                " mm around the tumour) holds no cell of the ground truth's " + ImageGridKindName(settings.grid.kind) +
                "; give a finite-element ground truth and a larger tumour or margin");
  }
}

// Skull-contact nodes deeper than settings.bondedDepth below the
// craniotomy's centre held fixed instead of sliding.
void
BondSkullContact(Model & model, const SyntheticBrainShiftSettings & settings, const Vector3 & down)
{
  std::vector<Index> & contact = model.nodeSets["contact"];
  std::vector<Index> & bonded = model.nodeSets["bonded to the skull"];
  for (const Index node : contact)
  {
    if ((model.nodes[node] - settings.craniotomyCentre).dot(down) > settings.bondedDepth)
    {
      bonded.push_back(node);
    }
  }
  if (bonded.empty())
  {
    throw Error("MakeSyntheticBrainShift: no skull-contact node lies deeper than the bonded depth of " +
                std::to_string(settings.bondedDepth) + " mm below the craniotomy's centre; give a smaller depth");
  }
  const std::set<Index> held(bonded.begin(), bonded.end());
  contact.erase(std::remove_if(contact.begin(), contact.end(), [&](Index node) { return held.count(node) > 0; }),
                contact.end());
  model.fixedConstraints.push_back(FixedConstraint{ "bonded to the skull" });
}

} // namespace

SyntheticBrainShift
MakeSyntheticBrainShiftModel(const RegistrationImage *           preoperativeImage,
                             const RegistrationLabelImage *      brainMask,
                             const SyntheticBrainShiftSettings & settings,
                             const StageCallback &               stageCallback)
{
  if (preoperativeImage == nullptr || brainMask == nullptr)
  {
    throw Error("MakeSyntheticBrainShift: give the preoperative image and its brain mask");
  }
  CheckSyntheticSettings(settings);
  SyntheticBrainShift truth;
  truth.timer = StageTimer(stageCallback);
  StageTimer & timer = truth.timer;

  if (settings.tumourRadius > 0.0)
  {
    truth.tumourMask = SphereMask(brainMask, settings.tumourCentre, settings.tumourRadius);
  }

  const Material           csf = TruthCsfMaterial(settings);
  const BrainModelSettings modelSettings = TruthModelSettings(settings, csf);
  truth.model = BuildBrainModel(preoperativeImage, brainMask, truth.tumourMask, ContactSurface{}, nullptr,
                                modelSettings, timer);
  Model & model = truth.model.model;
  if (settings.resectionMargin >= 0.0)
  {
    CarveResectionCavity(truth, brainMask, settings, csf);
  }
  const Vector3 down = (NodeCentroid(model) - settings.craniotomyCentre).normalized();
  truth.down = down;

  // The sag of the exposed surface, and gravity on the rest.
  PrescribedDisplacement sag;
  for (const Index node : truth.model.exposedNodes)
  {
    const double r = (model.nodes[node] - settings.craniotomyCentre).norm() / settings.craniotomyRadius;
    if (r > 1.0 - settings.freeRim)
    {
      continue; // the free rim: the model decides how the opening's edge follows
    }
    sag.nodes.push_back(node);
    sag.displacements.push_back(settings.targetShift * std::max(0.0, 1.0 - r * r) * down);
  }
  model.prescribedDisplacements = { sag };
  // The exposed nodes are moved or free, not in contact: the skull is open there.
  if (!model.contactSurfaces.empty())
  {
    std::vector<char> exposed(model.nodes.size(), 0);
    for (const Index node : truth.model.exposedNodes)
    {
      exposed[node] = 1;
    }
    std::vector<Index> & contact = model.nodeSets["contact"];
    contact.erase(std::remove_if(contact.begin(), contact.end(), [&](Index node) { return exposed[node] != 0; }),
                  contact.end());
  }
  truth.gravity = settings.gravity * units::StandardGravity * down;
  model.bodyAcceleration = truth.gravity;
  if (settings.csfDrainedDepth >= 0.0)
  {
    // As the registration's BrainModelSettings::csfDrainedDepth: the level hangs from the brain's highest node.
    const auto top = std::max_element(model.nodes.begin(), model.nodes.end(),
                                      [&](const Vector3 & a, const Vector3 & b) { return a.dot(down) > b.dot(down); });
    model.fluidSurface = *top + settings.csfDrainedDepth * down;
  }
  if (settings.bondedDepth >= 0.0)
  {
    BondSkullContact(model, settings, down);
  }
  return truth;
}

namespace
{
// The exposed surface as a surface scanner would see it: the cortex (the
// smooth surface of the brain mask, not that of the ground truth's cells)
// inside the craniotomy, moved by the ground truth; and the tracked points.
void
ScanExposedSurface(SyntheticBrainShift & truth, const RegistrationLabelImage * brainMask,
                   const SyntheticBrainShiftSettings & settings, const RegistrationTransform & forward)
{
// A little wider than the opening, as a scanner sees it: the registration's
// exposed nodes at the rim then find their partners on the surface, not on its edge.
const double             patchRadius = settings.craniotomyRadius + settings.scanMargin;
std::vector<std::string> surfaceWarnings; // the truth's model reports the same mask's
const ContactSurface     cortex = CortexSurfaceOfMask(brainMask, surfaceWarnings);
std::vector<Index>       newIndex(cortex.vertices.size(), -1);
ContactSurface &         exposed = truth.exposedSurface;
exposed.name = "displaced exposed surface";
for (const auto & triangle : cortex.triangles)
{
  bool inside = true;
  for (const Index vertex : triangle)
  {
    inside = inside && (cortex.vertices[vertex] - settings.craniotomyCentre).norm() <= patchRadius;
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
      const Vector3 & v = cortex.vertices[triangle[k]];
      const auto      moved = forward.TransformPoint(RegistrationTransform::InputPointType(v.data()));
      mapped = static_cast<Index>(exposed.vertices.size());
      exposed.vertices.emplace_back(moved[0], moved[1], moved[2]);
    }
    copy[k] = mapped;
  }
  exposed.triangles.push_back(copy);
}
// Tracked points: the first vertex of the ground truth's surface met in
// each cube of trackedPointSpacing within the opening (they sample the
// truth's motion; the validation study's results rest on them).
std::set<std::array<long, 3>> taken;
for (const Vector3 & v : truth.model.surfaces.brain.vertices)
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
  const auto moved = forward.TransformPoint(RegistrationTransform::InputPointType(v.data()));
  truth.trackedPoints.points.push_back(v);
  truth.trackedPoints.displacements.emplace_back(moved[0] - v.x(), moved[1] - v.y(), moved[2] - v.z());
}
if (exposed.triangles.empty())
{
  throw Error("the craniotomy (centre " + FormatPoint(settings.craniotomyCentre) + ", radius " +
              std::to_string(settings.craniotomyRadius) + " mm) contains no triangle of the brain surface");
}
}

// The intraoperative image: the preoperative image in the intraoperative
// contrast, warped by the ground truth onto the intraoperative grid (its
// field of view), the resection cavity filled with fluid, bias field, noise;
// and its brain mask.
void
MakeIntraoperativeImages(SyntheticBrainShift & truth, const RegistrationImage * preoperativeImage,
                         const RegistrationLabelImage * brainMask, const SyntheticBrainShiftSettings & settings,
                         const Vector3 & centroid, const Vector3 & down)
{
const RegistrationImage::ConstPointer source =
  settings.contrast == IntraoperativeContrast::Preoperative
    ? RegistrationImage::ConstPointer(preoperativeImage)
    : RegistrationImage::ConstPointer(MakeImageInContrast(preoperativeImage, brainMask, settings.contrast));
const double fieldDepth = std::min(std::max(0.0, 0.5 * settings.fieldOfView - settings.scanMargin),
                                   (centroid - settings.craniotomyCentre).norm());
const auto   grid = IntraoperativeGrid(preoperativeImage, settings.intraoperativeSpacing, settings.fieldOfView,
                                       settings.craniotomyCentre + fieldDepth * down);
truth.intraoperativeImage = WarpImage(source, truth.truthTransform, grid);
truth.intraoperativeBrainMask = WarpLabelImage(brainMask, truth.truthTransform, grid);
truth.intraoperativeBrainOnPreoperativeGrid = WarpLabelImage(brainMask, truth.truthTransform);
if (truth.resectionCavityRadius > 0.0)
{
  // Fluid: as dark as the darkest 2 % of the brain (as bright as the brightest 2 % in T2), i.e. CSF.
  std::vector<float> brain;
  for (itk::ImageRegionConstIteratorWithIndex<RegistrationLabelImage> it(truth.intraoperativeBrainMask,
                                                                         truth.intraoperativeBrainMask->GetBufferedRegion());
       !it.IsAtEnd(); ++it)
  {
    if (it.Get() > 0)
    {
      brain.push_back(truth.intraoperativeImage->GetPixel(it.GetIndex()));
    }
  }
  const bool  bright = settings.contrast == IntraoperativeContrast::T2Like;
  const auto  fluid = brain.begin() + static_cast<std::ptrdiff_t>((bright ? 0.98 : 0.02) * static_cast<double>(brain.size()));
  std::nth_element(brain.begin(), fluid, brain.end());
  FillResectionCavity(truth.intraoperativeImage, truth.intraoperativeBrainMask, truth.truthTransform,
                      settings.tumourCentre, truth.resectionCavityRadius, *fluid);
  FillResectionCavity(nullptr, truth.intraoperativeBrainOnPreoperativeGrid, truth.truthTransform,
                      settings.tumourCentre, truth.resectionCavityRadius, 0.0F);
}
if (settings.biasField > 0.0)
{
  ApplyBiasField(truth.intraoperativeImage, settings.biasField, settings.seed + 1);
}
if (settings.noise > 0.0)
{
  AddImageNoise(truth.intraoperativeImage, settings.noise * OverlayGreyRange(preoperativeImage).second,
                settings.noiseModel, settings.seed);
}
}

} // namespace

SyntheticBrainShift
MakeSyntheticBrainShift(const RegistrationImage *           preoperativeImage,
                        const RegistrationLabelImage *      brainMask,
                        const SyntheticBrainShiftSettings & settings,
                        const StageCallback &               stageCallback)
{
  SyntheticBrainShift truth = MakeSyntheticBrainShiftModel(preoperativeImage, brainMask, settings, stageCallback);
  StageTimer &        timer = truth.timer;
  const Model &       model = truth.model.model;
  const Vector3       down = truth.down;
  const Vector3       centroid = NodeCentroid(model);
  SolverSettings solverSettings;
  solverSettings.tolerance = settings.solverTolerance;
  if (settings.solverMaxSteps > 0)
  {
    solverSettings.maxSteps = settings.solverMaxSteps;
  }
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
    truth.forwardTransform = forward;
  });

  timer.Run("exposed-surface", [&] { ScanExposedSurface(truth, brainMask, settings, *forward); });

  timer.Run("intraop-image",
            [&] { MakeIntraoperativeImages(truth, preoperativeImage, brainMask, settings, centroid, down); });
  return truth;
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
