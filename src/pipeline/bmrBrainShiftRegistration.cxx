// The one-call registration: the chain of the module's ITK filters from the
// preoperative image to the warped image and its evaluation (its report and
// overlays: bmrRegistrationReport.cxx; the update's gravity fit:
// bmrGravityFit.cxx). Over 800 lines on purpose: one chain, and one
// translation unit for ITK's slow templates.
#include "bmrBrainShiftRegistration.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkAtlasBrainMaskImageFilter.h"
#include "itkBiomechanicalDeformationFilter.h"
#include "itkBiomechanicalGridImageFilter.h"
#include "itkBiomechanicalImageConversion.h"
#include "itkBiomechanicalImageIO.h"
#include "itkBiomechanicalLoadsFilter.h"
#include "itkBiomechanicalMaterialMappingFilter.h"
#include "itkBiomechanicalRegionsFilter.h"
#include "itkBrainSurfaceMeshSource.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkEdgeHausdorffDistanceImageFilter.h"
#include "itkFuzzyCMeansClassifierImageFilter.h"
#include "itkIdentityTransform.h"
#include "itkTransformWarpImageFilter.h"

#include "bmrPipelineDetail.h"
#include "bmrRegistrationUpdate.h"
#include "bmrScene.h"
#include "bmrUnits.h"

#include <omp.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <future>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>

namespace bmr
{

// ---------------------------------------------------------------------------
// StageTimer
// ---------------------------------------------------------------------------

void
StageTimer::Start(const std::string & name)
{
  if (m_Callback)
  {
    m_Callback(name, -1.0);
  }
}

void
StageTimer::Finish(const std::string & name, Clock::time_point start)
{
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  m_Seconds.emplace_back(name, seconds);
  if (m_Callback)
  {
    m_Callback(name, seconds);
  }
}

nlohmann::json
StageTimer::Json() const
{
  nlohmann::json times = nlohmann::json::object();
  double         total = 0.0;
  for (const auto & [name, seconds] : m_Seconds)
  {
    times[name] = times.contains(name) ? times[name].get<double>() + seconds : seconds;
    total += seconds;
  }
  times["total"] = total;
  return times;
}

double
StageTimer::Seconds(const std::string & name) const
{
  double seconds = 0.0;
  for (const auto & stage : m_Seconds)
  {
    if (stage.first == name)
    {
      seconds += stage.second;
    }
  }
  return seconds;
}

namespace
{

/** Checks that the intraoperative data name one source of the exposed surface's motion. */
void
CheckIntraoperativeData(const IntraoperativeData & data)
{
  const bool surface = !data.surface.triangles.empty();
  const bool sparse = !data.sparse.points.empty();
  if (surface && sparse)
  {
    throw Error("give one source of intraoperative displacements: a surface or sparse displacements, not both");
  }
  if (!surface && !sparse && data.image.IsNull())
  {
    throw Error("no intraoperative data: give an intraoperative surface, sparse displacements or an "
                "intraoperative image");
  }
  if (data.sparse.points.size() != data.sparse.displacements.size())
  {
    throw Error("the sparse intraoperative data have " + std::to_string(data.sparse.points.size()) + " points but " +
                std::to_string(data.sparse.displacements.size()) + " displacements; give one displacement per point");
  }
}

/** The volume (mm^3) of brain a resection removes; a mask with no voxel
 *  inside the brain is a mistake, not a no-op. */
double
ResectedVolume(const LabelVolume & resection, const LabelVolume & brain)
{
  std::size_t inside = 0;
  for (std::size_t voxel = 0; voxel < resection.values.size(); ++voxel)
  {
    inside += resection.values[voxel] != 0 && brain.values[voxel] != 0;
  }
  if (inside == 0)
  {
    throw Error("the resection mask has no voxel inside the brain mask: give the removed tissue as a mask on the "
                "preoperative image's grid (voxels > 0), or no resection mask");
  }
  return static_cast<double>(inside) * brain.geometry.VoxelVolume();
}

/** The exposed surface of an intraoperative image: the smooth surface of its
 *  brain mask (given, or from atlas skull stripping), made as the cortex it
 *  is matched to (CortexSurfaceOfMask of the preoperative mask), so that both
 *  surfaces show the same detail. */
ContactSurface
IntraoperativeSurfaceOfImage(const IntraoperativeData & data, const AtlasSettings & atlas,
                             std::vector<std::string> & warnings)
{
  const RegistrationLabelImage::ConstPointer mask =
    data.imageBrainMask.IsNotNull() ? data.imageBrainMask
                                    : RegistrationLabelImage::ConstPointer(AtlasBrainMask(data.image, atlas));
  try
  {
    ContactSurface surface = CortexSurfaceOfMask(mask, warnings);
    surface.name = "brain surface of the intraoperative image";
    return surface;
  }
  catch (const Error & error)
  {
    throw Error(std::string("the intraoperative brain mask: ") + error.what());
  }
}



} // namespace

RegistrationLabelImage::Pointer
ThresholdMask(const RegistrationImage * image)
{
  auto mask = RegistrationLabelImage::New();
  mask->CopyInformation(image);
  mask->SetRegions(image->GetBufferedRegion());
  mask->Allocate();
  const float *   values = image->GetBufferPointer();
  unsigned char * inside = mask->GetBufferPointer();
  for (std::size_t voxel = 0, count = image->GetBufferedRegion().GetNumberOfPixels(); voxel < count; ++voxel)
  {
    inside[voxel] = values[voxel] > 0.0f ? 1 : 0;
  }
  return mask;
}

LabelVolume
MaskVolume(const RegistrationLabelImage * image, const std::string & what, const ImageGeometry * grid)
{
  LabelVolume mask = itk::MakeBiomechanicalVolume<std::uint8_t>(image);
  for (auto & value : mask.values)
  {
    value = value > 0 ? 1 : 0;
  }
  if (grid != nullptr && !mask.geometry.SameGridAs(*grid))
  {
    throw Error("the " + what + " is not on the image grid: it has " + mask.geometry.Describe() +
                ", the image has " + grid->Describe() + "; resample it onto the image (nearest neighbour) first");
  }
  return mask;
}

RegistrationLabelImage::Pointer
AtlasBrainMask(const RegistrationImage * image, const AtlasSettings & settings)
{
  auto filter = itk::AtlasBrainMaskImageFilter<RegistrationImage>::New();
  filter->SetInput(image);
  filter->SetAtlasImage(itk::ReadBiomechanicalImage<RegistrationImage>(settings.image, "atlas"));
  filter->SetAtlasMaskImage(itk::ReadBiomechanicalImage<RegistrationImage>(settings.mask, "atlas mask"));
  filter->SetUseBSplineStage(settings.bsplineStage);
  UpdateStage(filter.GetPointer(), "skull stripping failed");
  return filter->GetOutput();
}

BrainSurfaces
BrainSurfacesOfMask(const RegistrationLabelImage * mask, double skullGap, std::vector<std::string> & warnings,
                    bool skull, double skullClosing)
{
  auto source = itk::BrainSurfaceMeshSource<RegistrationLabelImage>::New();
  source->SetInput(mask);
  source->SetSkullGap(skullGap);
  source->SetSkullClosing(skullClosing);
  source->SetComputeSkull(skull);
  UpdateStage(source.GetPointer(), "brain surfaces");
  warnings.insert(warnings.end(), source->GetWarnings().begin(), source->GetWarnings().end());
  return BrainSurfaces{ source->GetBrainSurface(), source->GetSkullSurface() };
}

BrainSurfaces
BrainSurfacesOfMask(const LabelVolume & mask, double skullGap, std::vector<std::string> & warnings, bool skull,
                    double skullClosing)
{
  return BrainSurfacesOfMask(itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(mask).GetPointer(), skullGap,
                             warnings, skull, skullClosing);
}

ContactSurface
CortexSurfaceOfMask(const RegistrationLabelImage * brainMask, std::vector<std::string> & warnings)
{
  return BrainSurfacesOfMask(brainMask, BrainSurfaceSettings{}.skullGap, warnings, false).brain;
}

// ---------------------------------------------------------------------------
// The model.
// ---------------------------------------------------------------------------

namespace
{

using TissueClassifier = itk::FuzzyCMeansClassifierImageFilter<RegistrationImage, RegistrationLabelImage>;

// The fuzzy c-means classification inside the brain mask, its fit and
// warnings recorded in `result`.
TissueClassifier::Pointer
ClassifyTissue(const RegistrationImage * image, const RegistrationLabelImage * mask,
               const FuzzyCMeansSettings & settings, StageTimer & timer, BrainModel & result)
{
  auto classifier = TissueClassifier::New();
  classifier->SetInput(image);
  classifier->SetMaskImage(mask);
  classifier->SetNumberOfClasses(static_cast<unsigned int>(std::max(settings.classes, 0)));
  classifier->SetFuzziness(settings.fuzziness);
  classifier->SetTolerance(settings.tolerance);
  classifier->SetMaximumNumberOfIterations(static_cast<unsigned int>(std::max(settings.maxIterations, 0)));
  timer.Run("classify", [&] { UpdateStage(classifier.GetPointer(), "tissue classification"); });
  result.warnings.insert(result.warnings.end(), classifier->GetWarnings().begin(), classifier->GetWarnings().end());
  result.classificationFit.centroids = classifier->GetCentroids();
  result.classificationFit.iterations = static_cast<int>(classifier->GetNumberOfIterations());
  result.classificationFit.converged = classifier->GetConverged();
  result.membershipImage = classifier->GetOutput();
  result.tissueLabelImage = classifier->GetLabelOutput();
  return classifier;
}

// Which class is the CSF (into `result`) and the class materials in the
// classes' order: the classes are in ascending centroid order, the settings'
// materials in T1 order (the CSF first).
MaterialMappingSettings
ClassMaterials(BrainModel & result, const BrainModelSettings & settings)
{
  MaterialMappingSettings   classMapping = settings.materials;
  const int                 classes = static_cast<int>(result.classificationFit.centroids.size());
  const std::vector<double> volumes =
    ClassVolumes(itk::MakeBiomechanicalVolume<std::uint8_t>(result.tissueLabelImage.GetPointer()), classes);
  result.csfClass = ChooseCsfClass(result.classificationFit.centroids, volumes, settings.contrast);
  result.csfVolume = volumes[static_cast<std::size_t>(result.csfClass.csfClass)];
  if (classMapping.classMaterials.empty())
  {
    classMapping.classMaterials = DefaultClassMaterials(classes);
  }
  if (result.csfClass.contrast == TissueContrast::T2)
  {
    std::reverse(classMapping.classMaterials.begin(), classMapping.classMaterials.end());
  }
  classMapping.csfClass = result.csfClass.csfClass;
  return classMapping;
}

// The brain and skull surfaces. The skull is the boundary of the body dilated
// by the gap, and the body is the model's cells (for a point cloud, the
// tetrahedra its integration points cover), not the mask: the corners of a
// staircase hexahedral grid stick out of the mask by up to half a cell. A
// user's skull (`skullSurface`, e.g. segmented from CT) replaces the dilated
// body as the contact master.
BrainSurfaces
MakeBrainSurfaces(const itk::BiomechanicalGridImageFilter<RegistrationLabelImage> & grid, const ImageGeometry & maskGeometry,
                  const BrainModelSettings & settings, const ContactSurface & skullSurface, StageTimer & timer,
                  std::vector<std::string> & warnings)
{
  auto surfaces = itk::BrainSurfaceMeshSource<RegistrationLabelImage>::New();
  timer.Run("surfaces", [&] {
    const Model & body = grid.GetModel().cells.empty() ? grid.GetMeshlessBody() : grid.GetModel();
    surfaces->SetInput(
      itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(RasterizeCells(body, maskGeometry)));
    surfaces->SetSkullGap(settings.skullGap);
    surfaces->SetSkullClosing(settings.skullClosing);
    UpdateStage(surfaces.GetPointer(), "brain surfaces");
  });
  warnings.insert(warnings.end(), surfaces->GetWarnings().begin(), surfaces->GetWarnings().end());
  BrainSurfaces result{ surfaces->GetBrainSurface(), surfaces->GetSkullSurface() };
  if (!skullSurface.triangles.empty())
  {
    result.skull = skullSurface;
    result.skull.bodySide = ContactSurface::Side::Inside;
  }
  result.skull.name = "skull";
  return result;
}

} // namespace

BrainModel
PrepareBrainModel(const RegistrationImage *      image,
                  const RegistrationLabelImage * brainMask,
                  const RegistrationLabelImage * tumourMask,
                  const ContactSurface &         skullSurface,
                  const BrainModelSettings &     settings,
                  StageTimer &                   timer,
                  bool                           cortexSurface)
{
  if (image == nullptr)
  {
    throw Error("no preoperative image: give the preoperative MRI");
  }
  // Checked before the long stages; the regions filter selects the nodes.
  if (settings.craniotomyRadius > 0.0 || settings.craniotomyMask.IsNotNull())
  {
    CheckCraniotomyChoice(settings.craniotomyRadius, settings.craniotomyMask.IsNotNull());
  }
  const int threads = settings.threads > 0 ? settings.threads : omp_get_max_threads();

  BrainModel result;
  auto &     warnings = result.warnings;
  const ImageGeometry geometry = itk::MakeBiomechanicalGeometry(image);

  // The brain mask (1 inside) on the image grid.
  RegistrationLabelImage::ConstPointer mask = brainMask;
  if (brainMask != nullptr)
  {
    result.brainMask = MaskVolume(brainMask, "brain mask", &geometry);
  }
  else
  {
    mask = timer.Run("skull-strip", [&] { return AtlasBrainMask(image, settings.atlas); });
    result.brainMask = MaskVolume(mask, "brain mask", &geometry);
  }
  // The cortex of the preoperative mask, which a displaced surface is matched
  // to, depends on the mask alone: it is made beside the model's stages
  // (their serial parts leave a core free) and waited for at the end. The
  // README demo's `register`, 2 threads, 4 runs alternating: model 2.90 ->
  // 2.68 s (medians; "loads" 0.68 -> 0.08 s, "classify" 0.21 -> 0.44 s).
  std::future<std::pair<ContactSurface, std::vector<std::string>>> cortex;
  if (cortexSurface)
  {
    cortex = std::async(std::launch::async, [mask] {
      std::vector<std::string> cortexWarnings;
      ContactSurface           surface = CortexSurfaceOfMask(mask, cortexWarnings);
      return std::make_pair(std::move(surface), std::move(cortexWarnings));
    });
  }
  {
    CraniotomyRegion craniotomy;
    craniotomy.centre = settings.craniotomyCentre;
    craniotomy.radius = settings.craniotomyRadius;
    CheckBrainRegionsOnMask(result.brainMask, craniotomy, PatientSkullBase(settings.skullBase, image),
                            "the craniotomy radius (--craniotomy-radius)", "--skull-base-height");
  }
  LabelVolume tumour;
  if (tumourMask != nullptr)
  {
    tumour = MaskVolume(tumourMask, "tumour mask", &geometry);
  }
  if (settings.resectionMask.IsNotNull())
  {
    result.resectedVolume = ResectedVolume(MaskVolume(settings.resectionMask, "resection mask", &geometry),
                                           result.brainMask);
  }

  const auto                    classifier = ClassifyTissue(image, mask, settings.classifier, timer, result);
  const MaterialMappingSettings classMapping = ClassMaterials(result, settings);

  // The tumour is a second label, so that tetrahedral meshes conform to its boundary.
  LabelVolume labels = result.brainMask;
  for (std::size_t voxel = 0; voxel < tumour.values.size(); ++voxel)
  {
    if (tumour.values[voxel] != 0 && labels.values[voxel] != 0)
    {
      labels.values[voxel] = 2;
    }
  }
  auto grid = itk::BiomechanicalGridImageFilter<RegistrationLabelImage>::New();
  grid->SetInput(itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(labels));
  ImageGridSettings gridSettings = settings.grid;
  gridSettings.threads = settings.threads;
  grid->SetSettings(gridSettings);
  timer.Run("grid", [&] { UpdateStage(grid.GetPointer(), "grid"); });
  warnings.insert(warnings.end(), grid->GetWarnings().begin(), grid->GetWarnings().end());
  result.gridQuality = grid->GetQuality();

  auto materials = itk::BiomechanicalMaterialMappingFilter<itk::VectorImage<float, 3>, RegistrationLabelImage>::New();
  materials->SetModelInput(grid->GetModelOutput());
  materials->SetMemberships(classifier->GetOutput());
  if (tumourMask != nullptr)
  {
    materials->SetTumourMask(tumourMask);
  }
  if (settings.resectionMask.IsNotNull())
  {
    materials->SetResectionMask(settings.resectionMask);
  }
  materials->SetClassMaterials(classMapping.classMaterials);
  materials->SetCsfClass(classMapping.csfClass);
  materials->SetTumourMaterial(settings.materials.tumour);
  materials->SetSampling(settings.materials.sampling);
  materials->SetNumberOfWorkUnits(static_cast<itk::ThreadIdType>(threads));
  timer.Run("materials", [&] { UpdateStage(materials.GetPointer(), "material mapping"); });
  warnings.insert(warnings.end(), materials->GetWarnings().begin(), materials->GetWarnings().end());

  result.surfaces = MakeBrainSurfaces(*grid, result.brainMask.geometry, settings, skullSurface, timer, warnings);

  const auto regions = BrainRegionsFilter(materials->GetOutput(), settings, image, settings.craniotomyRadius);
  UpdateStage(regions.GetPointer(), "model regions");
  TakeRegions(result, regions->GetOutput());
  if (regions->GetFixedNodesExposed() > 0)
  {
    warnings.push_back("the craniotomy reaches into the fixed band at the skull base: its " +
                       std::to_string(regions->GetFixedNodesExposed()) +
                       " surface nodes there are exposed (loaded), not fixed");
  }
  if (cortex.valid())
  {
    auto [cortexSurface, cortexWarnings] = cortex.get();
    result.cortex = std::move(cortexSurface);
    warnings.insert(warnings.end(), cortexWarnings.begin(), cortexWarnings.end());
  }
  return result;
}

namespace
{

/** Gravity and the CSF's level are the model's, not a filter's. */
void
SetBodyLoads(BrainModel & result, const BrainModelSettings & settings)
{
  if (!settings.gravity.isZero() || settings.csfDrainedDepth)
  {
    Model model = result.pipelineModel->GetModel();
    model.bodyAcceleration = settings.gravity;
    if (settings.csfDrainedDepth)
    {
      if (settings.gravity.isZero() || !(*settings.csfDrainedDepth >= 0.0))
      {
        throw Error(settings.gravity.isZero()
                      ? "a CSF drained depth is given without gravity; give the gravity the CSF drains under."
                      : "the CSF drained depth is " + std::to_string(*settings.csfDrainedDepth) +
                          " mm; give a depth of 0 mm or more below the brain's top.");
      }
      const Vector3 up = -settings.gravity.normalized();
      Index         top = 0;
      for (std::size_t n = 1; n < model.nodes.size(); ++n)
      {
        top = model.nodes[n].dot(up) > model.nodes[top].dot(up) ? static_cast<Index>(n) : top;
      }
      model.fluidSurface = model.nodes[top] - *settings.csfDrainedDepth * up;
    }
    const auto precomputation = result.pipelineModel->GetPrecomputation();
    result.pipelineModel = itk::BiomechanicalModelObject::New();
    result.pipelineModel->SetModel(std::move(model));
    result.pipelineModel->SetPrecomputation(precomputation); // gravity leaves the reference configuration as it is
  }
  result.model = result.pipelineModel->GetModel();
}

/** The exposed nodes' displacements from the intraoperative data ("loads"). */
void
LoadExposedSurface(BrainModel & result, const IntraoperativeData & intraoperative, const BrainModelSettings & settings,
                   StageTimer & timer)
{
  auto &  warnings = result.warnings;
  Model & model = result.model;
  auto    loads = itk::BiomechanicalLoadsFilter<itk::DisplacementPointSetType<3>>::New();
  loads->SetModelInput(result.pipelineModel);
  loads->SetMaxDistance(intraoperative.maxDistance);
  loads->SetMatchDirection(intraoperative.surfaceMatchDirection);
  if (model.cells.empty())
  {
    // A point cloud has no cells: distances are measured to the body's surface.
    loads->SetModelSurface(itk::MakeMeshFromContactSurface<itk::BiomechanicalSurfaceMeshType>(result.surfaces.brain));
  }
  timer.Run("loads", [&] {
    if (!intraoperative.sparse.points.empty())
    {
      loads->SetSparseDisplacements(itk::MakeDisplacementPointSet<itk::DisplacementPointSetType<3>>(
        intraoperative.sparse.points, intraoperative.sparse.displacements));
    }
    else
    {
      if (result.cortex.triangles.empty())
      {
        throw Error("the model has no cortex surface to match the intraoperative surface to; prepare it with "
                    "the cortex (PrepareBrainModel(..., cortex = true), as `biomech prepare` does)");
      }
      // Surface to surface: neither the staircase of a hexahedral grid nor
      // the walls of sulci inside the opening are brain motion. Staircase
      // nodes lie up to about a cell from the model's smoothed surface.
      const double elementSize = std::max(result.gridQuality.meanEdgeLength, settings.grid.elementSize);
      const ContactSurface displaced = intraoperative.surface.triangles.empty()
                                         ? IntraoperativeSurfaceOfImage(intraoperative, settings.atlas, warnings)
                                         : intraoperative.surface;
      loads->SetIntraoperativeSurface(itk::MakeMeshFromContactSurface<itk::BiomechanicalSurfaceMeshType>(displaced));
      // A scan images the cortex, so its partner is the smooth surface of
      // the brain mask, not that of the model's cells: a smoothed staircase
      // of 5 mm cells lies about a millimetre off the cortex, which bent
      // the matches and left out a quarter of them (docs/registration.md).
      loads->SetPreoperativeSurface(itk::MakeMeshFromContactSurface<itk::BiomechanicalSurfaceMeshType>(result.cortex));
      loads->SetScanReach(elementSize);
      loads->SetScanSpacing(kDefaultScanSpacing);
    }
    UpdateStage(loads.GetPointer(), "loads");
  });
  result.load = loads->GetPrescribedDisplacement();
  result.loadReport = loads->GetLoadReport();
  warnings.insert(warnings.end(), result.loadReport.warnings.begin(), result.loadReport.warnings.end());
  result.prescribedDisplacements = loads->GetOutput();
  model.prescribedDisplacements = { result.load };
}

/** Contact: the regions filter's "contact" nodes may touch the skull. */
void
SetSkullContact(BrainModel & result, const BrainModelSettings & settings)
{
  Model & model = result.model;
  if (settings.contact && !model.NodeSet("contact").empty())
  {
    result.contactSurface = itk::MakeMeshFromContactSurface<itk::BiomechanicalSurfaceMeshType>(result.surfaces.skull);
    ContactSurface master = result.surfaces.skull;
    master.slaveNodeSet = "contact";
    model.contactSurfaces = { master };
  }
  if (result.load.nodes.empty() && settings.gravity.isZero())
  {
    result.warnings.push_back("the model has no load (no intraoperative measurements and no gravity): its solution is zero");
  }
}

} // namespace

void
LoadBrainModel(BrainModel & model, const IntraoperativeData & intraoperative, const BrainModelSettings & settings,
               StageTimer & timer)
{
  CheckIntraoperativeData(intraoperative);
  if (model.pipelineModel.IsNull())
  {
    throw Error("the brain model is empty: prepare it first (PrepareBrainModel, or read a model bundle)");
  }
  SetBodyLoads(model, settings);
  LoadExposedSurface(model, intraoperative, settings, timer);
  SetSkullContact(model, settings);
}

namespace
{
/** The solves' threads: the solver's setting, else the model building's (0: OpenMP's default). */
int
SolverThreads(const BrainShiftRegistrationSettings & settings)
{
  return settings.solver.threads != 0 ? settings.solver.threads : settings.model.threads;
}
} // namespace

UpdateFilters::UpdateFilters(const BrainModel &                     model,
                             const BrainShiftUpdateInputs &         inputs,
                             const BrainShiftRegistrationSettings & settings)
  : m_Model(model)
  , m_Inputs(inputs)
  , m_Settings(settings)
{}

UpdateDeformation::Pointer
UpdateFilters::MakeDeformation(const itk::BiomechanicalModelObject * model) const
{
  auto deformation = UpdateDeformation::New();
  deformation->SetModelInput(model);
  if (m_Model.prescribedDisplacements.IsNotNull())
  {
    deformation->SetPrescribedDisplacements(m_Model.prescribedDisplacements);
  }
  if (m_Model.contactSurface.IsNotNull())
  {
    deformation->SetContactSurface(m_Model.contactSurface);
  }
  deformation->SetSolverSettings(m_Settings.solver);
  deformation->SetWarmStart(m_Inputs.previous);
  // 0: OpenMP's default (OMP_NUM_THREADS), as the solver's own default.
  const int threads = SolverThreads(m_Settings);
  deformation->SetNumberOfWorkUnits(static_cast<itk::ThreadIdType>(threads > 0 ? threads : omp_get_max_threads()));
  return deformation;
}

UpdateFitter::Pointer
UpdateFilters::FitTransform(const UpdateDeformation * deformation) const
{
  auto fitter = UpdateFitter::New();
  fitter->SetInput(deformation->GetOutput());
  fitter->SetReferenceImage(m_Inputs.preoperativeImage);
  fitter->SetTolerance(m_Settings.fitTolerance);
  fitter->SetMinimumControlPointSpacing(m_Settings.minimumControlPointSpacing);
  UpdateStage(fitter.GetPointer(), "fitting the transform failed");
  return fitter;
}

void
PrecomputeBrainModel(BrainModel & model, const BrainShiftRegistrationSettings & settings, StageTimer & timer)
{
  if (model.pipelineModel.IsNull())
  {
    throw Error("the brain model is empty: prepare it first (PrepareBrainModel)");
  }
  timer.Run("precompute", [&] {
    SolverSettings solver = settings.solver;
    solver.threads = SolverThreads(settings);
    // A model object of its own: the one given may be shared (a read bundle's, updated again later).
    auto object = itk::BiomechanicalModelObject::New();
    object->Graft(model.pipelineModel);
    object->SetPrecomputation(std::make_shared<const SolverPrecomputation>(object->GetModel(), solver));
    model.pipelineModel = object;
  });
}

BrainModel
BuildBrainModel(const RegistrationImage *      image,
                const RegistrationLabelImage * brainMask,
                const RegistrationLabelImage * tumourMask,
                const ContactSurface &         skullSurface,
                const IntraoperativeData *     intraoperative,
                const BrainModelSettings &     settings,
                StageTimer &                   timer)
{
  if (intraoperative != nullptr)
  {
    CheckIntraoperativeData(*intraoperative);
    CheckCraniotomyChoice(settings.craniotomyRadius, settings.craniotomyMask.IsNotNull());
  }
  const bool surfaceLoad = intraoperative != nullptr && intraoperative->sparse.points.empty();
  BrainModel result = PrepareBrainModel(image, brainMask, tumourMask, skullSurface, settings, timer, surfaceLoad);
  SetBodyLoads(result, settings);
  if (intraoperative != nullptr)
  {
    LoadExposedSurface(result, *intraoperative, settings, timer);
  }
  SetSkullContact(result, settings);
  return result;
}

// ---------------------------------------------------------------------------
// Evaluation.
// ---------------------------------------------------------------------------

EdgeEvaluation
EvaluateEdges(const RegistrationImage *      fixed,
              const RegistrationImage *      moving,
              const RegistrationLabelImage * mask,
              int                            sliceAxis,
              double                         distanceThreshold,
              const EdgeDetectionSettings &  edges)
{
  auto filter = itk::EdgeHausdorffDistanceImageFilter<RegistrationImage, RegistrationLabelImage>::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  if (mask != nullptr)
  {
    filter->SetMaskImage(mask);
  }
  filter->SetSliceAxis(sliceAxis);
  filter->SetDistanceThreshold(distanceThreshold);
  if (edges.variance)
    filter->SetVariance(*edges.variance);
  if (edges.upperThresholdQuantile)
    filter->SetUpperThresholdQuantile(*edges.upperThresholdQuantile);
  if (edges.lowerThresholdRatio)
    filter->SetLowerThresholdRatio(*edges.lowerThresholdRatio);
  if (edges.upperThreshold.has_value() != edges.lowerThreshold.has_value())
  {
    throw Error("fixed edge thresholds need both the upper and the lower threshold (or neither, for automatic ones)");
  }
  if (edges.upperThreshold)
  {
    filter->SetAutomaticThresholds(false);
    filter->SetUpperThreshold(*edges.upperThreshold);
    filter->SetLowerThreshold(*edges.lowerThreshold);
  }
  UpdateStage(filter.GetPointer(), "edge-based evaluation failed");
  const itk::EdgeHausdorffResult & result = filter->GetResult();
  EdgeEvaluation                   evaluation;
  evaluation.valid = result.valid;
  evaluation.message = result.message;
  evaluation.symmetric = result.symmetric;
  evaluation.fractionWithinThreshold = result.fractionWithinThreshold;
  evaluation.fixedEdges = result.fixedEdgePixels;
  evaluation.movingEdges = result.movingEdgePixels;
  evaluation.fixedEdgeImage = const_cast<RegistrationLabelImage *>(filter->GetFixedEdges());
  evaluation.movingEdgeImage = const_cast<RegistrationLabelImage *>(filter->GetMovingEdges());
  return evaluation;
}

namespace
{

template <typename TImage>
typename TImage::Pointer
Warp(const TImage *                                      image,
     const itk::Transform<double, 3, 3> *                transform,
     const itk::ImageBase<3> *                           reference,
     itk::WarpInterpolation                              interpolation)
{
  auto warp = itk::TransformWarpImageFilter<TImage>::New();
  warp->SetInput(image);
  warp->SetTransform(transform);
  if (reference != nullptr)
  {
    warp->SetReferenceImage(reference);
  }
  warp->SetInterpolation(interpolation);
  UpdateStage(warp.GetPointer(), "warping failed");
  typename TImage::Pointer output = warp->GetOutput();
  output->DisconnectPipeline();
  return output;
}

} // namespace

RegistrationImage::Pointer
WarpImage(const RegistrationImage * image, const itk::Transform<double, 3, 3> * transform,
          const itk::ImageBase<3> * grid)
{
  return Warp(image, transform, grid, itk::WarpInterpolation::Linear);
}

RegistrationLabelImage::Pointer
WarpLabelImage(const RegistrationLabelImage * labels, const itk::Transform<double, 3, 3> * transform,
               const itk::ImageBase<3> * grid)
{
  return Warp(labels, transform, grid, itk::WarpInterpolation::NearestNeighbor);
}

// ---------------------------------------------------------------------------
// The registration.
// ---------------------------------------------------------------------------

namespace
{

/** The checks of the intraoperative phase's inputs, before any long stage. */
void
CheckUpdateInputs(const BrainShiftUpdateInputs & inputs, const BrainShiftRegistrationSettings & settings)
{
  if (inputs.preoperativeImage.IsNull())
  {
    throw Error("no preoperative image: give the preoperative MRI");
  }
  for (std::size_t k = 0; k < inputs.labelMaps.size(); ++k)
  {
    if (inputs.labelMaps[k].IsNull())
    {
      throw Error("label map " + std::to_string(k) + " is empty: give a label image on the preoperative grid");
    }
  }
  CheckIntraoperativeData(inputs.intraoperative);
  if (settings.gravityFitCandidates != 0)
  {
    if (settings.gravityFitCandidates < 3)
    {
      throw Error("gravity_fit_candidates is " + std::to_string(settings.gravityFitCandidates) +
                  "; give 0 (gravity as given) or 3 or more sizes to try");
    }
    if (settings.model.gravity.isZero())
    {
      throw Error("a gravity fit needs gravity: give its direction and the largest size to try (--gravity)");
    }
    if (inputs.intraoperative.image.IsNull())
    {
      throw Error("a gravity fit compares the registered image with the intraoperative one: give the "
                  "intraoperative image (--intraoperative-image)");
    }
  }
}

/** A bundle's precomputation serves every update made with its settings;
 *  other solver settings, or a model prepared without it, make their own. */
void
RefreshPrecomputation(BrainShiftRegistrationResult & result, const BrainShiftRegistrationSettings & settings)
{
  if (result.model.pipelineModel.IsNull())
  {
    return;
  }
  const auto &      stored = result.model.pipelineModel->GetPrecomputation();
  const std::string mismatch =
    stored ? stored->Mismatch(result.model.pipelineModel->GetModel(), settings.solver) : std::string();
  if (!stored || !mismatch.empty())
  {
    if (stored)
    {
      result.model.warnings.push_back("the prepared model's precomputation was made " + mismatch +
                                      ": made again for this update (stage precompute); prepare the bundle with "
                                      "these settings to save it");
    }
    PrecomputeBrainModel(result.model, settings, result.timer);
  }
}

/** Warnings about the weight the settings put on the brain. */
void
AddGravityWarnings(BrainShiftRegistrationResult & result, const BrainShiftRegistrationSettings & settings)
{
  if (!settings.model.gravity.isZero())
  {
    // Soft CSF cells cannot carry a fluid's weight: they are crushed and the brain sinks through them.
    const Material csf = CsfClassMaterial(settings.model.materials);
    if (csf.density >= 100.0 && csf.youngsModulus < ParenchymaMaterial().youngsModulus)
    {
      std::ostringstream warning;
      warning << "gravity acts on the CSF class with " << csf.density << " kg/m^3 on " << csf.youngsModulus
              << " Pa cells, which cannot carry a fluid's weight; after CSF loss the CSF is drained: give "
                 "csf_density 1 (--csf-density 1)";
      result.warnings.push_back(warning.str());
    }
  }
  else if (result.model.resectedVolume > 0.0)
  {
    // Measured in the validation study: 5 mm hexahedra without gravity 1.56 -> 1.95 mm p95 with the resection.
    result.warnings.push_back("the resection mask frees the cavity's walls, but without gravity nothing makes them "
                              "sag and the soft cavity takes up part of the exposed surface's sag instead; give "
                              "gravity (--gravity, and --gravity-fit-candidates with an intraoperative image)");
  }
}

/** The registered and unregistered images on the intraoperative grid and their edge evaluations. */
void
EvaluateOnIntraoperativeImage(BrainShiftRegistrationResult &         result,
                              const BrainShiftUpdateInputs &         inputs,
                              const BrainShiftRegistrationSettings & settings)
{
  const RegistrationImage * intraoperativeImage = inputs.intraoperative.image.GetPointer();
  auto                      identity = itk::IdentityTransform<double, 3>::New();
  result.unregisteredOnIntraoperativeGrid = WarpImage(inputs.preoperativeImage, identity, intraoperativeImage);
  result.registeredOnIntraoperativeGrid = WarpImage(inputs.preoperativeImage, result.transform, intraoperativeImage);
  // The brain of the intraoperative image: its own mask, or the registered preoperative mask.
  if (inputs.intraoperative.imageBrainMask.IsNotNull())
  {
    result.evaluationMask = const_cast<RegistrationLabelImage *>(inputs.intraoperative.imageBrainMask.GetPointer());
  }
  else
  {
    const auto preoperativeMask = itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(result.model.brainMask);
    result.evaluationMask = WarpLabelImage(preoperativeMask, result.transform, intraoperativeImage);
  }
  result.unregistered = EvaluateEdges(intraoperativeImage, result.unregisteredOnIntraoperativeGrid,
                                      result.evaluationMask, settings.evaluationSliceAxis,
                                      settings.evaluationDistanceThreshold);
  result.registered = EvaluateEdges(intraoperativeImage, result.registeredOnIntraoperativeGrid, result.evaluationMask,
                                    settings.evaluationSliceAxis, settings.evaluationDistanceThreshold);
}

/** The intraoperative phase into `result`, whose model is prepared and whose timer runs on. */
void
UpdateInto(BrainShiftRegistrationResult &         result,
           const BrainShiftUpdateInputs &         inputs,
           const BrainShiftRegistrationSettings & settings,
           const ProgressCallback &               solverProgress)
{
  StageTimer & timer = result.timer;
  RefreshPrecomputation(result, settings);
  LoadBrainModel(result.model, inputs.intraoperative, settings.model, timer);
  result.warnings = result.model.warnings;
  AddGravityWarnings(result, settings);

  // The solve and the fit continue the model's pipeline: the deformation
  // filter takes the regions' model, the loads' point set and the skull; its
  // output (the nodes carrying their displacements) is the fitter's input.
  const UpdateFilters        filters(result.model, inputs, settings);
  UpdateDeformation::Pointer deformation;
  UpdateFitter::Pointer      fitted; // the gravity fit's best transform: its solve and fit are the registration's
  result.gravity = result.model.model.bodyAcceleration;
  if (settings.gravityFitCandidates > 0)
  {
    const GravityFitChoice choice =
      timer.Run("gravity fit", [&] { return FitGravity(result, inputs, settings, filters); });
    deformation = choice.deformation;
    fitted = choice.fitter;
  }
  else
  {
    deformation = filters.MakeDeformation(result.model.pipelineModel);
  }
  if (solverProgress)
  {
    deformation->AddObserver(itk::ProgressEvent(), [&](const itk::EventObject &) {
      if (deformation->GetCurrentStep() > 0)
      {
        solverProgress(deformation->GetCurrentStep(), -1.0, deformation->GetCurrentEstimatedError());
      }
    });
  }
  result.solve = timer.Run("solve", [&] {
    UpdateStage(deformation.GetPointer(), "the solve failed");
    return deformation->GetSolveResult();
  });
  result.warnings.insert(result.warnings.end(), result.solve.warnings.begin(), result.solve.warnings.end());
  if (!result.solve.converged)
  {
    result.warnings.push_back("the solve did not converge: " + result.solve.message +
                              "; the transform and the warped image come from the last state");
  }

  timer.Run("fit", [&] {
    const auto fitter = fitted ? fitted : filters.FitTransform(deformation);
    result.transform = const_cast<RegistrationTransform *>(fitter->GetTransform());
    const itk::BSplineFitReport & report = fitter->GetReport();
    result.fitMaxResidual = report.maximumResidual;
    result.fitRmsResidual = report.rmsResidual;
    result.fitLevels = static_cast<int>(report.levels);
    result.fitToleranceReached = report.toleranceReached;
  });
  if (!result.fitToleranceReached)
  {
    std::ostringstream warning;
    warning << "the transform fit did not reach " << settings.fitTolerance << " mm at the nodes (largest residual "
            << result.fitMaxResidual << " mm at " << settings.minimumControlPointSpacing << " mm control points)";
    result.warnings.push_back(warning.str());
  }

  result.warpedImage = timer.Run("warp", [&] {
    return WarpImage(inputs.preoperativeImage, result.transform);
  });
  if (!inputs.labelMaps.empty())
  {
    timer.Run("warp-labels", [&] {
      for (const auto & labels : inputs.labelMaps)
      {
        result.warpedLabelMaps.push_back(WarpLabelImage(labels, result.transform));
      }
    });
  }
  if (inputs.intraoperative.image.IsNotNull())
  {
    timer.Run("evaluate", [&] { EvaluateOnIntraoperativeImage(result, inputs, settings); });
  }
}

} // namespace

BrainShiftRegistrationResult
UpdateBrainShift(BrainModel                             model,
                 const BrainShiftUpdateInputs &         inputs,
                 const BrainShiftRegistrationSettings & settings,
                 const StageCallback &                  stageCallback,
                 const ProgressCallback &               solverProgress)
{
  CheckUpdateInputs(inputs, settings);
  if (!inputs.previous.Empty() && inputs.previous.state.size() != model.model.nodes.size())
  {
    throw Error("the previous update's solution has " + std::to_string(inputs.previous.state.size()) +
                " nodes, the prepared model " + std::to_string(model.model.nodes.size()) +
                ": it is of another model; give an update of this model, or none");
  }
  BrainShiftRegistrationResult result;
  result.timer = StageTimer(stageCallback);
  result.model = std::move(model);
  UpdateInto(result, inputs, settings, solverProgress);
  return result;
}

BrainShiftRegistrationResult
RegisterBrainShift(const BrainShiftRegistrationInputs &   inputs,
                   const BrainShiftRegistrationSettings & settings,
                   const StageCallback &                  stageCallback,
                   const ProgressCallback &               solverProgress,
                   BrainModel *                           prepared)
{
  const BrainShiftUpdateInputs update{ inputs.preoperativeImage, inputs.labelMaps, inputs.intraoperative, WarmStart{} };
  CheckUpdateInputs(update, settings);
  CheckCraniotomyChoice(settings.model.craniotomyRadius, settings.model.craniotomyMask.IsNotNull());
  BrainShiftRegistrationResult result;
  result.timer = StageTimer(stageCallback);
  const bool surfaceLoad = inputs.intraoperative.sparse.points.empty();
  result.model = PrepareBrainModel(inputs.preoperativeImage, inputs.brainMask, inputs.tumourMask, inputs.skullSurface,
                                   settings.model, result.timer, surfaceLoad);
  PrecomputeBrainModel(result.model, settings, result.timer);
  if (prepared != nullptr)
  {
    *prepared = result.model;
  }
  UpdateInto(result, update, settings, solverProgress);
  return result;
}

} // namespace bmr
