// bmrImageBenchmark: time of the image stages after a solve, with their error
// beside the time. Writes its section of docs/benchmarks.md.
//
//   bmrImageBenchmark [--output docs/benchmarks.md] [--repeats 3] [--no-baseline]
//
// Case: Colin27 (Debian mricron-data) resampled onto a 256 x 256 x 128 grid
// (1 x 1 x 1.5 mm); a brain-sized ellipsoid of about 30,000 hexahedral-mesh
// nodes placed in it and solved (craniotomy pushed 10 mm, base fixed); then
//  1. the backward transform fitted to the nodal displacements
//     (itk::DisplacementPointSetToBSplineTransformFilter, defaults), residual
//     at the nodes beside the time;
//  2. the warp of the 256 x 256 x 128 image (itk::TransformWarpImageFilter,
//     linear), through the spline and through a dense field;
//  3. the B-spline intensity registration baseline on the same pair (fixed:
//     Colin27 warped by the fitted transform, moving: Colin27), with its
//     displacement error against that transform inside the brain and the
//     edge-based Hausdorff distances before and after.
#include "itkBSplineIntensityRegistrationFilter.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkEdgeHausdorffDistanceImageFilter.h"
#include "itkImageFileReader.h"
#include "itkImageRegionConstIteratorWithIndex.h"
#include "itkLinearInterpolateImageFunction.h"
#include "itkMultiThreaderBase.h"
#include "itkResampleImageFilter.h"
#include "itkTransformWarpImageFilter.h"

#include "bmrBenchmarkSupport.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"
#include "bmrSolver.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace
{

using bmr::benchmark::Fixed;

using ImageType = itk::Image<float, 3>;
using MaskType = itk::Image<unsigned char, 3>;
using PointSetType = itk::DisplacementPointSetType<3>;
using FitterType = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>;
using WarpType = itk::TransformWarpImageFilter<ImageType>;
using RegistrationType = itk::BSplineIntensityRegistrationFilter<ImageType>;
using EvaluatorType = itk::EdgeHausdorffDistanceImageFilter<ImageType>;
using Clock = std::chrono::steady_clock;
using bmr::Vector3;

constexpr double      kTargetFitAndWarpSeconds = 3.0;
const char * const    kColin27 = "/usr/share/mricron/templates/ch2.nii.gz";
const Vector3         kBrainSemiAxes(70.0, 85.0, 60.0); // mm, as the solver benchmark's brain
constexpr double      kCraniotomyRadius = 25.0;         // mm around the top
constexpr double      kCraniotomyDepth = 10.0;          // mm, pushed in
constexpr double      kBaseHeight = 15.0;               // mm above the lowest point: fixed
constexpr double      kCoarseSpacing = 2.0;             // mm, a coarser minimum control-point spacing for comparison

double
Seconds(Clock::time_point start)
{
  return std::chrono::duration<double>(Clock::now() - start).count();
}

template <typename T>
T
Median(std::vector<T> values)
{
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

/** Colin27 resampled (linear) onto a 256 x 256 x 128 grid of 1 x 1 x 1.5 mm about its centre. */
ImageType::Pointer
MakePreoperativeImage()
{
  auto reader = itk::ImageFileReader<ImageType>::New();
  reader->SetFileName(kColin27);
  reader->Update();
  const ImageType * colin = reader->GetOutput();
  itk::ContinuousIndex<double, 3> centreIndex;
  for (unsigned int d = 0; d < 3; ++d)
  {
    centreIndex[d] = 0.5 * (colin->GetLargestPossibleRegion().GetSize()[d] - 1);
  }
  ImageType::PointType centre;
  colin->TransformContinuousIndexToPhysicalPoint(centreIndex, centre);

  ImageType::SizeType    size = { { 256, 256, 128 } };
  ImageType::SpacingType spacing;
  spacing[0] = 1.0;
  spacing[1] = 1.0;
  spacing[2] = 1.5;
  ImageType::PointType origin;
  for (unsigned int d = 0; d < 3; ++d)
  {
    origin[d] = centre[d] - 0.5 * spacing[d] * (size[d] - 1);
  }
  auto resampler = itk::ResampleImageFilter<ImageType, ImageType>::New();
  resampler->SetInput(colin);
  resampler->SetSize(size);
  resampler->SetOutputSpacing(spacing);
  resampler->SetOutputOrigin(origin);
  resampler->Update();
  return resampler->GetOutput();
}

/** The brain-sized ellipsoid (about 30,000 nodes) centred at `centre`, solved. */
struct SolvedModel
{
  bmr::Model       model;
  bmr::SolveResult result;
  double           seconds = 0.0;
};

SolvedModel
SolveBrainModel(const Vector3 & centre)
{
  SolvedModel solved;
  // 3.88 mm gives about 30,000 nodes on these semi-axes.
  solved.model = bmr::MakeEllipsoidMesh(kBrainSemiAxes, 3.88, bmr::GridCells::Hexahedra);
  for (auto & node : solved.model.nodes)
  {
    node += centre;
  }
  const Vector3           top = centre + Vector3(0.0, 0.0, kBrainSemiAxes.z());
  const double            lowest = centre.z() - kBrainSemiAxes.z();
  std::vector<bmr::Index> base, craniotomy;
  for (const bmr::Index node : solved.model.NodeSet("surface"))
  {
    const Vector3 & p = solved.model.nodes[node];
    if (p.z() <= lowest + kBaseHeight)
    {
      base.push_back(node);
    }
    else if ((p - top).norm() <= kCraniotomyRadius)
    {
      craniotomy.push_back(node);
    }
  }
  solved.model.nodeSets["base"] = base;
  solved.model.nodeSets["craniotomy"] = craniotomy;
  solved.model.fixedConstraints.push_back(bmr::FixedConstraint{ "base", { true, true, true } });
  // A smooth sag, deepest at the centre of the craniotomy and zero at its rim,
  // as the exposed brain surface sinks (a flat punch would put a kink into
  // the field at the rim that no smooth transform reproduces).
  bmr::PrescribedDisplacement push;
  push.nodes = craniotomy;
  for (const bmr::Index node : craniotomy)
  {
    const double r = (solved.model.nodes[node] - top).norm() / kCraniotomyRadius;
    const double c = std::cos(0.5 * M_PI * r);
    push.displacements.push_back(Vector3(0.0, 0.0, -kCraniotomyDepth * c * c));
  }
  solved.model.prescribedDisplacements.push_back(push);

  bmr::SolverSettings settings;
  settings.integrator = bmr::Integrator::DynamicRelaxation;
  settings.tolerance = 0.01;
  const auto  start = Clock::now();
  bmr::Solver solver(solved.model, settings);
  solved.result = solver.Solve();
  solved.seconds = Seconds(start);
  if (!solved.result.converged)
  {
    throw bmr::Error("the benchmark's brain model did not converge: " + solved.result.message);
  }
  return solved;
}

/** Voxels of `grid` inside the ellipsoid (the brain of the case). */
MaskType::Pointer
BrainMask(const ImageType * grid, const Vector3 & centre)
{
  auto mask = MaskType::New();
  mask->CopyInformation(grid);
  mask->SetRegions(grid->GetLargestPossibleRegion());
  mask->Allocate();
  for (itk::ImageRegionIteratorWithIndex<MaskType> it(mask, mask->GetLargestPossibleRegion()); !it.IsAtEnd(); ++it)
  {
    ImageType::PointType p;
    mask->TransformIndexToPhysicalPoint(it.GetIndex(), p);
    double r = 0.0;
    for (unsigned int d = 0; d < 3; ++d)
    {
      const double q = (p[d] - centre[d]) / kBrainSemiAxes[d];
      r += q * q;
    }
    it.Set(r <= 1.0 ? 1 : 0);
  }
  return mask;
}

struct ErrorStatistics
{
  double mean = 0.0;
  double p95 = 0.0;
  double max = 0.0;
};

/** |a(y) - b(y)| over the voxels of `mask` (mm). */
ErrorStatistics
TransformDifference(const itk::Transform<double, 3, 3> * a, const itk::Transform<double, 3, 3> * b, const MaskType * mask)
{
  std::vector<double> errors;
  for (itk::ImageRegionConstIteratorWithIndex<MaskType> it(mask, mask->GetLargestPossibleRegion()); !it.IsAtEnd(); ++it)
  {
    if (it.Get() == 0)
    {
      continue;
    }
    ImageType::PointType y;
    mask->TransformIndexToPhysicalPoint(it.GetIndex(), y);
    errors.push_back((a->TransformPoint(y) - b->TransformPoint(y)).GetNorm());
  }
  ErrorStatistics statistics;
  std::sort(errors.begin(), errors.end());
  double sum = 0.0;
  for (double e : errors)
  {
    sum += e;
  }
  statistics.mean = sum / static_cast<double>(errors.size());
  statistics.p95 = errors[static_cast<std::size_t>(0.95 * (errors.size() - 1))];
  statistics.max = errors.back();
  return statistics;
}

itk::EdgeHausdorffResult
Evaluate(const ImageType * fixed, const ImageType * moving, const MaskType * mask)
{
  auto evaluator = EvaluatorType::New();
  evaluator->SetFixedImage(fixed);
  evaluator->SetMovingImage(moving);
  evaluator->SetMaskImage(mask);
  evaluator->Update();
  return evaluator->GetResult();
}

std::string
FitSummary(const itk::BSplineFitReport & fit)
{
  return "residual at the nodes: max " + Fixed(fit.maximumResidual, 3) + " mm, RMS " + Fixed(fit.rmsResidual, 3) +
         " mm; " + std::to_string(fit.levels) + " levels, control points every " +
         Fixed(fit.controlPointSpacing[0], 1) + " x " + Fixed(fit.controlPointSpacing[1], 1) + " x " +
         Fixed(fit.controlPointSpacing[2], 1) + " mm" + (fit.toleranceReached ? "" : " (tolerance not reached)");
}

// The B-spline intensity registration of the warped image back onto the
// preoperative one: its times, and its error against the known transform.
std::string
BaselineSection(const ImageType * preoperative, const ImageType * intraoperative, const Vector3 & centre,
                const itk::Transform<double, 3, 3> * truth)
{
  std::ostringstream baselineText;
  std::cerr << "bmrImageBenchmark: B-spline registration baseline\n";
  const MaskType::Pointer brain = BrainMask(preoperative, centre);
  auto                    registration = RegistrationType::New();
  registration->SetFixedImage(intraoperative);
  registration->SetMovingImage(preoperative);
  const auto start = Clock::now();
  registration->Update();
  const double total = Seconds(start);
  auto         identity = itk::IdentityTransform<double, 3>::New();
  const ErrorStatistics before = TransformDifference(truth, identity, brain);
  const ErrorStatistics after = TransformDifference(truth, registration->GetTransform(), brain);
  const itk::EdgeHausdorffResult unregistered = Evaluate(intraoperative, preoperative, brain);
  const itk::EdgeHausdorffResult registered = Evaluate(intraoperative, registration->GetOutput(), brain);
  auto row = [](const std::string & name, const ErrorStatistics & error, const itk::EdgeHausdorffResult & edges) {
    std::ostringstream text;
    text << "| " << name << " | " << Fixed(error.mean, 2) << " | " << Fixed(error.p95, 2) << " | "
         << Fixed(error.max, 2) << " | "
         << (edges.valid ? Fixed(edges.symmetric[49], 2) + " | " + Fixed(edges.symmetric[94], 2) + " | " +
                             Fixed(100.0 * edges.fractionWithinThreshold, 1)
                         : "n/a | n/a | n/a")
         << " |\n";
    return text.str();
  };
  baselineText << "### B-spline intensity registration baseline on the same pair\n\n"
               << "Fixed: the Colin27 grid warped by the fitted transform above (the 'intraoperative' image); "
               << "moving: Colin27. itk::BSplineIntensityRegistrationFilter with its defaults (docs/"
               << "bspline-registration.md): " << registration->GetIterationsRun() << " iterations in all, final "
               << "metric " << Fixed(registration->GetFinalMetricValue(), 4) << ".\n\n"
               << "| | seconds |\n|---|---|\n"
               << "| registration | " << Fixed(registration->GetElapsedSeconds(), 2) << " |\n"
               << "| warp of the moving image | " << Fixed(registration->GetWarpElapsedSeconds(), 2) << " |\n"
               << "| whole filter | " << Fixed(total, 2) << " |\n\n"
               << "Error beside the time: displacement error against the known transform inside the brain "
               << "(the ellipsoid, " << "mm), and the edge-based Hausdorff distance (itk::EdgeHausdorffDistance"
               << "ImageFilter, defaults: axial slices, within the brain) between the fixed image and the "
               << "moving one:\n\n"
               << "| | error mean | 95th pct | max | edge HD 50th pct (mm) | 95th pct (mm) | % edges <= 1.7 mm |\n"
               << "|---|---|---|---|---|---|---|\n"
               << row("no registration", before, unregistered)
               << row("B-spline registration", after, registered) << "\n";
  return baselineText.str();
}

} // namespace

int
main(int argc, char ** argv)
{
  std::string output = "docs/benchmarks.md";
  int         repeats = 3;
  bool        baseline = true;
  for (int a = 1; a < argc; ++a)
  {
    const std::string argument = argv[a];
    if (argument == "--output" && a + 1 < argc)
    {
      output = argv[++a];
    }
    else if (argument == "--repeats" && a + 1 < argc)
    {
      repeats = std::max(1, std::atoi(argv[++a]));
    }
    else if (argument == "--no-baseline")
    {
      baseline = false;
    }
    else
    {
      std::cerr << "usage: bmrImageBenchmark [--output docs/benchmarks.md] [--repeats 3] [--no-baseline]\n";
      return argument == "--help" ? 0 : 1;
    }
  }
  itk::Object::GlobalWarningDisplayOff();
  const std::string loadBefore = bmr::benchmark::LoadAverage();
  const int         threads = itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads();

  try
  {
    std::cerr << "bmrImageBenchmark: preoperative image and brain model\n";
    const ImageType::Pointer preoperative = MakePreoperativeImage();
    itk::ContinuousIndex<double, 3> middle;
    for (unsigned int d = 0; d < 3; ++d)
    {
      middle[d] = 0.5 * (preoperative->GetLargestPossibleRegion().GetSize()[d] - 1);
    }
    ImageType::PointType centrePoint;
    preoperative->TransformContinuousIndexToPhysicalPoint(middle, centrePoint);
    const Vector3     centre(centrePoint[0], centrePoint[1], centrePoint[2]);
    const SolvedModel solved = SolveBrainModel(centre);
    const auto        points = itk::MakeDisplacementPointSet<PointSetType>(solved.model.nodes, solved.result.displacements);

    // 1. Fit (median of the repeats); 2. warp through the spline and through a dense field.
    std::cerr << "bmrImageBenchmark: fit and warp, " << repeats << " repeats\n";
    std::vector<double>  fitSeconds, warpSeconds, resampleSeconds, coarseFitSeconds;
    itk::BSplineFitReport coarseFit;
    FitterType::Pointer  fitter;
    ImageType::Pointer   intraoperative;
    double               largestWarpDifference = 0.0;
    for (int r = 0; r < repeats; ++r)
    {
      fitter = FitterType::New();
      fitter->SetInput(points);
      fitter->SetReferenceImage(preoperative);
      auto start = Clock::now();
      fitter->Update();
      fitSeconds.push_back(Seconds(start));

      auto warp = WarpType::New();
      warp->SetInput(preoperative);
      warp->SetTransform(fitter->GetTransform());
      start = Clock::now();
      warp->Update();
      warpSeconds.push_back(Seconds(start));
      intraoperative = warp->GetOutput();

      // The generic path for comparison: the spline evaluated voxel by voxel.
      auto resampler = itk::ResampleImageFilter<ImageType, ImageType>::New();
      resampler->SetInput(preoperative);
      resampler->SetTransform(fitter->GetTransform());
      resampler->SetOutputParametersFromImage(preoperative);
      start = Clock::now();
      resampler->Update();
      resampleSeconds.push_back(Seconds(start));
      itk::ImageRegionConstIteratorWithIndex<ImageType> it(resampler->GetOutput(),
                                                          resampler->GetOutput()->GetLargestPossibleRegion());
      for (; !it.IsAtEnd(); ++it)
      {
        largestWarpDifference =
          std::max(largestWarpDifference, std::abs(double(it.Get()) - intraoperative->GetPixel(it.GetIndex())));
      }

      auto coarseFitter = FitterType::New();
      coarseFitter->SetInput(points);
      coarseFitter->SetReferenceImage(preoperative);
      coarseFitter->SetMinimumControlPointSpacing(kCoarseSpacing);
      start = Clock::now();
      coarseFitter->Update();
      coarseFitSeconds.push_back(Seconds(start));
      coarseFit = coarseFitter->GetReport();
    }
    const auto & fit = fitter->GetReport();
    const double fitTime = Median(fitSeconds);
    const double warpTime = Median(warpSeconds);
    const double resampleTime = Median(resampleSeconds);
    const double coarseFitTime = Median(coarseFitSeconds);
    double       largestDisplacement = 0.0;
    for (const auto & u : solved.result.displacements)
    {
      largestDisplacement = std::max(largestDisplacement, u.norm());
    }

    // 3. The baseline on the same pair.
    const std::string baselineText =
      baseline ? BaselineSection(preoperative, intraoperative, centre, fitter->GetTransform()) : "";

    std::ostringstream section;
    const std::time_t  now = std::time(nullptr);
    char               date[64];
    std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M UTC", std::gmtime(&now));
    section << bmr::benchmark::ImageSectionBegin << "\n"
            << "## From displacements to a warped image\n\n"
            << "Written by `bmrImageBenchmark` (benchmarks/bmrImageBenchmark.cxx, run by scripts/run-benchmarks.sh). "
            << "CPU " << bmr::benchmark::CpuModel() << ", " << threads << " ITK threads, " << date
            << ", load average at start " << loadBefore << ". Median of " << repeats << " runs.\n\n"
            << "Case: Colin27 resampled onto a 256 x 256 x 128 grid of 1 x 1 x 1.5 mm; a brain-sized ellipsoid "
            << "(semi-axes 70, 85, 60 mm) of " << solved.model.nodes.size() << " nodes (hexahedra, 3.88 mm) at its "
            << "centre, solved with dynamic relaxation to 0.01 mm in " << Fixed(solved.seconds, 2) << " s (craniotomy "
            << "of " << kCraniotomyRadius << " mm pushed " << kCraniotomyDepth << " mm, largest displacement "
            << Fixed(largestDisplacement, 2) << " mm). Fitted with the defaults: tolerance 0.1 mm, minimum "
            << "control-point spacing 1 mm.\n\n"
            << "| Stage | seconds | error beside the time |\n|---|---|---|\n"
            << "| fit backward transform (" << solved.model.nodes.size() << " nodes), defaults | " << Fixed(fitTime, 2)
            << " | " << FitSummary(fit) << " |\n"
            << "| warp 256 x 256 x 128, linear (TransformWarpImageFilter: spline sampled on the grid, then "
            << "WarpImageFilter) | " << Fixed(warpTime, 2) << " | |\n"
            << "| **fit + warp** | **" << Fixed(fitTime + warpTime, 2) << "** | target < " << kTargetFitAndWarpSeconds
            << " s: **" << (fitTime + warpTime < kTargetFitAndWarpSeconds ? "met" : "MISSED") << "** |\n"
            << "| for comparison: the same warp through ResampleImageFilter (spline evaluated per voxel) | "
            << Fixed(resampleTime, 2) << " | largest intensity difference from the fast warp: "
            << Fixed(largestWarpDifference, 4) << " (image range 0..255) |\n"
            << "| for comparison: fit with minimum control-point spacing " << kCoarseSpacing << " mm | "
            << Fixed(coarseFitTime, 2) << " | " << FitSummary(coarseFit) << " |\n\n"
            << baselineText << bmr::benchmark::ImageSectionEnd << "\n";

    std::cout << section.str();
    const std::string report = bmr::benchmark::WithImageSection(bmr::benchmark::ReadTextFile(output), section.str());
    bmr::WriteTextFileAtomically(output, report);
    std::cerr << "bmrImageBenchmark: wrote " << output << "\n";
  }
  catch (const std::exception & error)
  {
    std::cerr << "bmrImageBenchmark: error: " << error.what() << "\n";
    return 1;
  }
  return 0;
}
