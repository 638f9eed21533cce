// Brain-shift registration as an ordinary ITK pipeline, step by step, with the
// filters of the BiomechanicalRegistration module:
//
//   preoperative MRI + brain mask
//     -> fuzzy c-means tissue classes        (itk::FuzzyCMeansClassifierImageFilter)
//     -> hexahedral grid of the brain        (itk::BiomechanicalGridImageFilter)
//     -> materials from the memberships      (itk::BiomechanicalMaterialMappingFilter)
//     -> brain and skull surfaces            (itk::BrainSurfaceMeshSource)
//     -> fixed skull base, craniotomy, contact nodes (itk::BiomechanicalRegionsFilter)
//     -> craniotomy loaded by sparse intraoperative
//        displacements                       (itk::BiomechanicalLoadsFilter)
//     -> nonlinear solve to steady state     (itk::BiomechanicalDeformationFilter,
//        with the skull as contact surface    dynamic relaxation)
//     -> B-spline transform of the solution  (itk::DisplacementPointSetToBSplineTransformFilter)
//     -> warped preoperative image           (itk::TransformWarpImageFilter)
//     -> edge-based Hausdorff distance       (itk::EdgeHausdorffDistanceImageFilter)
//
// Usage:
//   BrainShiftRegistrationExample PREOP.nii.gz BRAINMASK.nii.gz SPARSE.csv CX CY CZ RADIUS OUTPUT_DIR [ELEMENT_SIZE_MM]
//
// SPARSE.csv holds displacements measured on the exposed brain surface
// (header x,y,z,ux,uy,uz, mm); the craniotomy is the sphere (CX, CY, CZ),
// RADIUS (mm, physical space of the image). Writes OUTPUT_DIR/warped.nii.gz,
// OUTPUT_DIR/transform.h5 (the backward map, for resampling; 3D Slicer reads
// it) and OUTPUT_DIR/summary.json. Exit status: 0 done, 1 error, 2 the solve
// did not converge (nothing written).
//
// On Colin27 (Debian's mricron-data):
//   BrainShiftRegistrationExample /usr/share/mricron/templates/ch2.nii.gz \
//     /usr/share/mricron/templates/ch2bet.nii.gz examples/data/colin27-superior-craniotomy.csv \
//     -11 43 84 30 out/example

// ITK's own headers first: they pull in ITK's bundled Eigen, which must be seen
// before the system Eigen of the module's core headers (bmr*.h, which some of
// the module's filters include too).
#include "itkBinaryThresholdImageFilter.h"
#include "itkImage.h"
#include "itkImageFileReader.h"
#include "itkImageFileWriter.h"
#include "itkTransform.h"

// The module's ITK filters.
#include "itkBiomechanicalDeformationFilter.h"
#include "itkBiomechanicalGridImageFilter.h"
#include "itkBiomechanicalImageConversion.h"
#include "itkBiomechanicalLoadsFilter.h"
#include "itkBiomechanicalMaterialMappingFilter.h"
#include "itkBiomechanicalRegionsFilter.h"
#include "itkBiomechanicalTransformIO.h"
#include "itkBrainSurfaceMeshSource.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkEdgeHausdorffDistanceImageFilter.h"
#include "itkFuzzyCMeansClassifierImageFilter.h"
#include "itkTransformWarpImageFilter.h"

// The mechanics core.
#include "bmrBrainSurfaces.h"
#include "bmrImageGrids.h"
#include "bmrMaterialMapping.h"
#include "bmrModel.h"
#include "bmrSolver.h"
#include "bmrSurfaceLoads.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace
{

using ImageType = itk::Image<float, 3>;
using MaskImageType = itk::Image<unsigned char, 3>;

/** Wall-clock seconds per pipeline stage, for the summary. */
class StageClock
{
public:
  /** Seconds since the previous lap (or construction), recorded under `stage`. */
  double Lap(const std::string & stage)
  {
    const auto   now = std::chrono::steady_clock::now();
    const double seconds = std::chrono::duration<double>(now - m_Last).count();
    m_Last = now;
    m_Seconds[stage] = seconds;
    m_Total += seconds;
    return seconds;
  }

  nlohmann::ordered_json Json() const
  {
    nlohmann::ordered_json seconds = m_Seconds;
    seconds["total"] = m_Total;
    return seconds;
  }

private:
  std::chrono::steady_clock::time_point m_Last = std::chrono::steady_clock::now();
  nlohmann::ordered_json                m_Seconds = nlohmann::ordered_json::object();
  double                                m_Total = 0.0;
};

/** Reads a scalar image; a missing file gets a plain message that names it. */
ImageType::Pointer
ReadInputImage(const std::string & path, const std::string & what)
{
  if (!std::filesystem::is_regular_file(path))
  {
    throw itk::ExceptionObject(__FILE__, __LINE__, "cannot read the " + what + " '" + path + "': no such file");
  }
  auto reader = itk::ImageFileReader<ImageType>::New();
  reader->SetFileName(path);
  reader->Update();
  return reader->GetOutput();
}

double
ParseNumber(const char * text, const std::string & what)
{
  char *       end = nullptr;
  const double value = std::strtod(text, &end);
  if (end == text || *end != '\0' || !std::isfinite(value))
  {
    throw std::invalid_argument(what + " must be a number, got '" + std::string(text) + "'");
  }
  return value;
}

void
PrintWarnings(const std::vector<std::string> & warnings)
{
  for (const std::string & warning : warnings)
  {
    std::cerr << "BrainShiftRegistrationExample: warning: " << warning << "\n";
  }
}

using PointSetType = itk::DisplacementPointSetType<3>;

// The filters that hold the model: its regions (fixed, exposed, contact
// nodes; the model object flows out of them), the exposed nodes' loads and
// the skull the brain stays inside.
struct PatientModel
{
  itk::BiomechanicalRegionsFilter<MaskImageType>::Pointer regions;
  itk::BiomechanicalLoadsFilter<PointSetType>::Pointer    loads;
  itk::BrainSurfaceMeshSource<MaskImageType>::Pointer     surfaces;
};

PatientModel
BuildPatientModel(const ImageType * preoperative, const MaskImageType * mask, const bmr::SparseDisplacements & measured,
                  const bmr::Vector3 & craniotomyCentre, double craniotomyRadius, double elementSize, StageClock & clock,
                  std::vector<std::string> & warnings)
{
  // 2. Tissue classes. Three, not two: on T1 two classes split grey from white
  // matter and grey matter would get the (very soft) CSF material.
  auto classifier = itk::FuzzyCMeansClassifierImageFilter<ImageType, MaskImageType>::New();
  classifier->SetInput(preoperative);
  classifier->SetMaskImage(mask);
  classifier->SetNumberOfClasses(3);
  classifier->Update();
  std::cout << "classify   3 classes, centroids";
  for (const double centroid : classifier->GetCentroids())
  {
    std::cout << " " << centroid;
  }
  std::cout << ", " << classifier->GetNumberOfIterations() << " iterations (" << clock.Lap("classify") << " s)\n";

  // 3. Hexahedral grid of the mask (staircase: whole cells whose centres lie in the brain).
  auto grid = itk::BiomechanicalGridImageFilter<MaskImageType>::New();
  grid->SetInput(mask);
  grid->SetGridKind(bmr::ImageGridKind::Hexahedra);
  grid->SetElementSize(elementSize);
  grid->Update();
  std::cout << "grid       " << grid->GetModel().nodes.size() << " nodes, " << grid->GetModel().cells.size()
            << " hexahedra of " << elementSize << " mm, volume error " << 100.0 * grid->GetQuality().volumeError
            << " % of the mask (" << clock.Lap("grid") << " s)\n";

  // 4. Materials: each cell mixes the class materials (CSF soft, parenchyma
  // 3 kPa) by its average membership. The grid's model output (output 1)
  // carries the model down the pipeline.
  auto mapping = itk::BiomechanicalMaterialMappingFilter<>::New();
  mapping->SetModelInput(grid->GetModelOutput());
  mapping->SetMemberships(classifier->GetOutput());
  mapping->Update();
  warnings.insert(warnings.end(), mapping->GetWarnings().begin(), mapping->GetWarnings().end());
  std::cout << "materials  " << mapping->GetOutput()->GetModel().materials.size() << " distinct mixtures (" << clock.Lap("materials") << " s)\n";

  // 5. Surfaces of the body the grid discretises, not of the mask: the corners
  // of a staircase grid stick out of the mask by up to half a cell and must
  // still lie inside the skull.
  auto surfaces = itk::BrainSurfaceMeshSource<MaskImageType>::New();
  surfaces->SetInput(itk::MakeImageFromBiomechanicalVolume<MaskImageType>(
    bmr::RasterizeCells(grid->GetModel(), itk::MakeBiomechanicalGeometry(mask))));
  surfaces->SetSkullGap(1.5); // mm of CSF between brain and skull
  surfaces->Update();
  std::cout << "surfaces   brain " << surfaces->GetBrainSurface().triangles.size() << " triangles, skull "
            << surfaces->GetSkullSurface().triangles.size() << " triangles (" << clock.Lap("surfaces") << " s)\n";

  // 6. Regions of the model's surface nodes: the skull base and brain stem
  // hold the brain (fixed); the craniotomy's surface is exposed, and the
  // measurements load it (all of it: sparse points are interpolated to every
  // exposed node); every other surface node may slide along the rigid skull
  // or leave it (node set "contact").
  auto regions = itk::BiomechanicalRegionsFilter<MaskImageType>::New();
  regions->SetModelInput(mapping->GetOutput());
  regions->SetCraniotomyCentre(craniotomyCentre);
  regions->SetCraniotomyRadius(craniotomyRadius);
  regions->Update();
  const bmr::Model & model = regions->GetOutput()->GetModel();
  const std::size_t  contactNodes = model.NodeSet("contact").size();

  //    The loads: the sparse displacements, interpolated (thin-plate spline)
  //    to every exposed node, as a point set of the exposed nodes.
  auto loads = itk::BiomechanicalLoadsFilter<PointSetType>::New();
  loads->SetModelInput(regions->GetOutput());
  loads->SetSparseDisplacements(itk::MakeDisplacementPointSet<PointSetType>(measured.points, measured.displacements));
  loads->Update();
  const bmr::LoadReport & loadReport = loads->GetLoadReport();
  warnings.insert(warnings.end(), loadReport.warnings.begin(), loadReport.warnings.end());
  const std::size_t loadedNodes = loads->GetOutput()->GetNumberOfPoints();
  std::cout << "regions    " << model.NodeSet("skull_base").size() << " fixed, " << loadedNodes
            << " loaded from " << loadReport.usedPoints << " measurements (" << loadReport.rejectedPoints
            << " rejected), " << contactNodes << " may touch the skull (" << clock.Lap("regions") << " s)\n";
  return { regions, loads, surfaces };
}

int
Run(int argc, char * argv[])
{
  const std::string           preoperativePath = argv[1];
  const std::string           maskPath = argv[2];
  const std::string           sparsePath = argv[3];
  const bmr::Vector3          craniotomyCentre(ParseNumber(argv[4], "CX"), ParseNumber(argv[5], "CY"),
                                               ParseNumber(argv[6], "CZ"));
  const double                craniotomyRadius = ParseNumber(argv[7], "RADIUS");
  const std::filesystem::path outputDirectory = argv[8];
  const double                elementSize = argc > 9 ? ParseNumber(argv[9], "ELEMENT_SIZE_MM") : 6.0;
  std::vector<std::string>    warnings;
  StageClock                  clock;

  // An earlier run's summary must not pass for this run's if this one fails.
  std::filesystem::create_directories(outputDirectory);
  std::filesystem::remove(outputDirectory / "summary.json");

  // 1. Inputs. ch2bet.nii.gz is a brain-extracted image, not a 0/1 mask: every voxel > 0 is brain.
  const ImageType::Pointer preoperative = ReadInputImage(preoperativePath, "preoperative image");
  auto                     threshold = itk::BinaryThresholdImageFilter<ImageType, MaskImageType>::New();
  threshold->SetInput(ReadInputImage(maskPath, "brain mask"));
  threshold->SetLowerThreshold(std::numeric_limits<float>::min()); // smallest float > 0 (inclusive bound)
  threshold->SetUpperThreshold(std::numeric_limits<float>::max());
  threshold->SetInsideValue(1);
  threshold->SetOutsideValue(0);
  threshold->Update();
  const MaskImageType::Pointer mask = threshold->GetOutput();
  // The intraoperative measurements: points on the exposed surface and their displacements (mm).
  const bmr::SparseDisplacements measured = bmr::ReadSparseDisplacements(sparsePath);
  std::cout << "read       " << preoperativePath << ", mask " << maskPath << " (" << clock.Lap("read") << " s)\n";

  // 2.-6. The model: tissue classes, grid, materials, surfaces, regions and loads.
  const PatientModel patient =
    BuildPatientModel(preoperative, mask, measured, craniotomyCentre, craniotomyRadius, elementSize, clock, warnings);
  const bmr::Model & model = patient.regions->GetOutput()->GetModel();
  const std::size_t  loadedNodes = patient.loads->GetOutput()->GetNumberOfPoints();

  // 7. Steady state of the nonlinear model under the enforced displacements,
  // the skull (the body stays inside it) as contact surface of the nodes in
  // the model's "contact" set. 0.01 mm: far below the 0.1 mm the registration needs.
  auto deformation = itk::BiomechanicalDeformationFilter<PointSetType>::New();
  deformation->SetModelInput(patient.regions->GetOutput());
  deformation->SetPrescribedDisplacements(patient.loads->GetOutput());
  deformation->SetContactSurface(patient.surfaces->GetSkullOutput());
  bmr::SolverSettings settings;
  settings.integrator = bmr::Integrator::DynamicRelaxation;
  settings.tolerance = 0.01;
  deformation->SetSolverSettings(settings);
  deformation->Update();
  const bmr::SolveResult & solution = deformation->GetSolveResult();
  std::cout << "solve      " << (solution.converged ? "converged" : "NOT CONVERGED") << " in " << solution.steps
            << " steps, estimated error " << solution.estimatedError << " mm, max displacement "
            << solution.maxDisplacement << " mm, " << solution.contactNodes << " nodes on the skull ("
            << clock.Lap("solve") << " s)\n";
  if (!solution.converged)
  {
    PrintWarnings(warnings);
    std::cerr << "BrainShiftRegistrationExample: error: the solve did not converge to " << settings.tolerance << " mm ("
              << solution.message << "); nothing written. Check the loads and the grid, or try "
              << "another element size.\n";
    return 2;
  }

  // 8. The nodal displacements as an ITK transform: a B-spline fitted directly
  // as the backward (resampling) map, refined until the largest residual at
  // the nodes is below 0.1 mm.
  auto fitter = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>::New();
  fitter->SetInput(deformation->GetOutput());
  fitter->SetReferenceImage(preoperative);
  fitter->Update();
  const itk::BSplineFitReport & fit = fitter->GetReport();
  std::cout << "fit        " << fit.levels << " levels, residual at the nodes max " << fit.maximumResidual
            << " mm, rms " << fit.rmsResidual << " mm" << (fit.toleranceReached ? "" : ", tolerance NOT reached")
            << " (" << clock.Lap("fit") << " s)\n";

  // 9. Warp the preoperative image into the intraoperative configuration.
  auto warp = itk::TransformWarpImageFilter<ImageType>::New();
  warp->SetInput(preoperative);
  warp->SetTransform(fitter->GetTransform());
  warp->Update();
  const ImageType::Pointer warped = warp->GetOutput();
  std::cout << "warp       " << preoperativePath << " (" << clock.Lap("warp") << " s)\n";

  // 10. How much the warp changed the image: Canny edges of the warped and the
  // original image inside the brain, and the distances between them.
  auto hausdorff = itk::EdgeHausdorffDistanceImageFilter<ImageType, MaskImageType>::New();
  hausdorff->SetFixedImage(warped);
  hausdorff->SetMovingImage(preoperative);
  hausdorff->SetMaskImage(mask);
  hausdorff->Update();
  const itk::EdgeHausdorffResult & edges = hausdorff->GetResult();
  if (!edges.valid)
  {
    throw std::runtime_error("edge-based Hausdorff distance: " + edges.message);
  }
  const double p95 = edges.symmetric[94]; // element K-1 is percentile K
  std::cout << "hausdorff  95th percentile " << p95 << " mm, " << 100.0 * edges.fractionWithinThreshold
            << " % of the edges within " << edges.distanceThreshold << " mm (" << clock.Lap("evaluate") << " s)\n";

  // 11. Results, the summary last: a folder with a summary is complete.
  itk::WriteImage(warped, (outputDirectory / "warped.nii.gz").string(), true);
  itk::WriteBiomechanicalTransform(fitter->GetTransform(), (outputDirectory / "transform.h5").string());
  clock.Lap("write");

  nlohmann::ordered_json summary;
  summary["preoperative_image"] = preoperativePath;
  summary["element_size_mm"] = elementSize;
  summary["nodes"] = model.nodes.size();
  summary["cells"] = model.cells.size();
  summary["loaded_nodes"] = loadedNodes;
  summary["converged"] = solution.converged;
  summary["solve_steps"] = solution.steps;
  summary["estimated_error_mm"] = solution.estimatedError;
  summary["max_displacement_mm"] = solution.maxDisplacement;
  summary["fit_max_residual_mm"] = fit.maximumResidual;
  summary["fit_rms_residual_mm"] = fit.rmsResidual;
  summary["hausdorff_p95_mm"] = p95;
  summary["fraction_within_threshold"] = edges.fractionWithinThreshold;
  summary["distance_threshold_mm"] = edges.distanceThreshold;
  summary["seconds"] = clock.Json();
  summary["warnings"] = warnings;
  std::ofstream summaryFile(outputDirectory / "summary.json");
  summaryFile << summary.dump(2) << "\n";
  if (!summaryFile.flush())
  {
    throw std::runtime_error("cannot write '" + (outputDirectory / "summary.json").string() + "'");
  }

  PrintWarnings(warnings);
  std::cout << "total      " << summary["seconds"]["total"].get<double>() << " s; wrote "
            << (outputDirectory / "warped.nii.gz").string() << ", transform.h5, summary.json\n";
  return 0;
}

} // namespace

int
main(int argc, char * argv[])
{
  if (argc < 9 || argc > 10)
  {
    std::cerr << "Usage: " << argv[0]
              << " PREOP.nii.gz BRAINMASK.nii.gz SPARSE.csv CX CY CZ RADIUS OUTPUT_DIR [ELEMENT_SIZE_MM]\n";
    return 1;
  }
  try
  {
    return Run(argc, argv);
  }
  catch (const itk::ExceptionObject & exception)
  {
    std::cerr << "BrainShiftRegistrationExample: error: " << exception.GetDescription() << "\n";
  }
  catch (const std::exception & exception)
  {
    std::cerr << "BrainShiftRegistrationExample: error: " << exception.what() << "\n";
  }
  return 1;
}
