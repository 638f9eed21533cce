// biomech bspline-register: intensity-based B-spline registration of the
// preoperative (moving) image to the intraoperative (fixed) image, the
// baseline that validation compares the biomechanical registration with
// (itk::BSplineIntensityRegistrationFilter; docs/bspline-registration.md).
#include "bmrImageCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBSplineIntensityRegistrationFilter.h"
#include "itkBiomechanicalTransformIO.h"
#include "itkImageIOFactory.h"
#include "itkImageRegionConstIterator.h"
#include "itkImageRegionIterator.h"
#include "itkMultiThreaderBase.h"

#include "bmrCommandSupport.h"

#include "bmrMeshIO.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bmr
{
namespace app
{
namespace
{

struct BSplineRegisterOptions
{
  std::string               fixed;
  std::string               moving;
  std::string               output;
  std::string               transform;
  std::string               report;
  std::string               mask;
  std::string               metric = "mattes";
  std::string               initialize = "identity";
  bool                      noTranslation = false;
  bool                      noMeshRefinement = false;
  double                    controlPointSpacing = 20.0;
  std::vector<unsigned int> iterations; // empty: the filter's default, 100 halved per level
  std::vector<unsigned int> shrinkFactors{ 4, 2, 1 };
  std::vector<double>       smoothingSigmas{ 2.0, 1.0, 0.0 };
  double                    samplingPercentage = 0.2;
  unsigned long             maximumSamples = 20000;
  unsigned int              histogramBins = 50;
  int                       seed = 121212;
  unsigned int              metricWorkUnits = 1;
  int                       threads = 0;
  bool                      quiet = false;
};

/** The warped image is written with the moving image's component type when
 *  it is an integer type of at most 16 bits (rounded and clamped), else as
 *  float (the registration's precision; 32-bit integers fit exactly up to 2^24). */
std::string
OutputPixelName(itk::IOComponentEnum component)
{
  switch (component)
  {
    case itk::IOComponentEnum::UCHAR:
      return "uint8";
    case itk::IOComponentEnum::CHAR:
      return "int8";
    case itk::IOComponentEnum::USHORT:
      return "uint16";
    case itk::IOComponentEnum::SHORT:
      return "int16";
    default:
      return "float32";
  }
}

template <typename TPixel, unsigned int Dimension>
void
WriteWarped(const itk::Image<float, Dimension> * warped, const fs::path & path)
{
  if constexpr (std::is_same_v<TPixel, float>)
  {
    WriteImageAtomically(warped, path);
  }
  else
  {
    using OutputImageType = itk::Image<TPixel, Dimension>;
    auto output = OutputImageType::New();
    output->CopyInformation(warped);
    output->SetRegions(warped->GetLargestPossibleRegion());
    output->Allocate();
    itk::ImageRegionConstIterator<itk::Image<float, Dimension>> in(warped, warped->GetLargestPossibleRegion());
    itk::ImageRegionIterator<OutputImageType>                   out(output, output->GetLargestPossibleRegion());
    const double lowest = static_cast<double>(std::numeric_limits<TPixel>::lowest());
    const double highest = static_cast<double>(std::numeric_limits<TPixel>::max());
    for (; !in.IsAtEnd(); ++in, ++out)
    {
      out.Set(static_cast<TPixel>(std::clamp(std::round(static_cast<double>(in.Get())), lowest, highest)));
    }
    WriteImageAtomically(output.GetPointer(), path);
  }
}

template <unsigned int Dimension>
void
WriteWarpedAs(itk::IOComponentEnum component, const itk::Image<float, Dimension> * warped, const fs::path & path)
{
  switch (component)
  {
    case itk::IOComponentEnum::UCHAR:
      return WriteWarped<unsigned char, Dimension>(warped, path);
    case itk::IOComponentEnum::CHAR:
      return WriteWarped<signed char, Dimension>(warped, path);
    case itk::IOComponentEnum::USHORT:
      return WriteWarped<unsigned short, Dimension>(warped, path);
    case itk::IOComponentEnum::SHORT:
      return WriteWarped<short, Dimension>(warped, path);
    default:
      return WriteWarped<float, Dimension>(warped, path);
  }
}

void
RemoveFiles(const std::vector<fs::path> & paths)
{
  for (const fs::path & path : paths)
  {
    std::error_code ignored;
    fs::remove(path, ignored);
  }
}

template <typename T>
json
ArrayJson(const T & values, unsigned int count)
{
  json array = json::array();
  for (unsigned int i = 0; i < count; ++i)
  {
    array.push_back(values[i]);
  }
  return array;
}

// The report of a registration (without its stage times).
template <unsigned int Dimension, typename Filter>
json
BSplineRegisterReport(const Filter & filter, const BSplineRegisterOptions & options, const ImageFileInfo & movingInfo)
{
  const unsigned int levels = static_cast<unsigned int>(options.shrinkFactors.size());
  json               report;
  report["fixed"] = options.fixed;
  report["moving"] = options.moving;
  report["mask"] = options.mask.empty() ? json(nullptr) : json(options.mask);
  report["warped"] = options.output;
  report["transform"] = options.transform.empty() ? json(nullptr) : json(options.transform);
  report["dimension"] = Dimension;
  report["warped_pixel_type"] = OutputPixelName(movingInfo.component);
  std::vector<unsigned int> iterationsPerLevel(levels);
  for (unsigned int level = 0; level < levels; ++level)
  {
    iterationsPerLevel[level] = filter.IterationsAtLevel(level);
  }
  report["parameters"] = { { "metric", options.metric },
                           { "control_point_spacing_mm", options.controlPointSpacing },
                           { "shrink_factors", options.shrinkFactors },
                           { "smoothing_sigmas_mm", options.smoothingSigmas },
                           { "max_iterations_per_level", iterationsPerLevel },
                           { "refine_mesh_per_level", !options.noMeshRefinement },
                           { "initialize", options.initialize },
                           { "translation_stage", !options.noTranslation },
                           { "histogram_bins", options.histogramBins },
                           { "sampling_strategy", "random" },
                           { "sampling_percentage", options.samplingPercentage },
                           { "max_samples", options.maximumSamples },
                           { "random_seed", options.seed },
                           { "metric_work_units", options.metricWorkUnits },
                           { "threads", itk::MultiThreaderBase::GetGlobalDefaultNumberOfThreads() } };
  json meshSizes = json::array();
  for (const auto & meshSize : filter.GetMeshSizesPerLevel())
  {
    meshSizes.push_back(ArrayJson(meshSize, Dimension));
  }
  report["mesh_sizes"] = meshSizes;
  report["initial_translation_mm"] = ArrayJson(filter.GetInitialTranslation(), Dimension);
  report["final_metric"] = filter.GetFinalMetricValue();
  report["final_metric_meaning"] =
    options.metric == "correlation" ? "-r^2 (normalised correlation squared, negated)" : "-(Mattes mutual information)";
  report["iterations"] = { { "per_level", filter.GetIterationsPerLevel() },
                           { "total", filter.GetIterationsRun() },
                           { "translation_stage", filter.GetTranslationIterationsRun() } };
  report["stop_condition"] = filter.GetStopConditionDescription();
  report["registration_seconds"] = filter.GetElapsedSeconds();
  report["warp_seconds"] = filter.GetWarpElapsedSeconds();
  return report;
}

template <unsigned int Dimension>
int
RunBSplineRegister(const BSplineRegisterOptions & options, const ImageFileInfo & movingInfo)
{
  using ImageType = itk::Image<float, Dimension>;
  using FilterType = itk::BSplineIntensityRegistrationFilter<ImageType, ImageType, ImageType>;

  StepTimer                   timer(!options.quiet);
  typename ImageType::Pointer fixed;
  typename ImageType::Pointer moving;
  typename ImageType::Pointer mask;
  timer.Run("read", [&] {
    fixed = ReadImage<ImageType>(options.fixed, "fixed image");
    moving = ReadImage<ImageType>(options.moving, "moving image");
    if (!options.mask.empty())
    {
      // Read as float so that any mask pixel type keeps "> 0 is inside".
      mask = ReadImage<ImageType>(options.mask, "mask");
    }
  });

  auto filter = FilterType::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  if (mask)
  {
    filter->SetFixedMask(mask);
  }
  filter->SetMetric(options.metric == "correlation" ? FilterType::MetricType::Correlation
                                                    : FilterType::MetricType::MattesMutualInformation);
  filter->SetTranslationInitialization(options.initialize == "moments"
                                         ? FilterType::TranslationInitializationType::Moments
                                         : FilterType::TranslationInitializationType::Identity);
  filter->SetUseTranslationStage(!options.noTranslation);
  filter->SetRefineMeshPerLevel(!options.noMeshRefinement);
  filter->SetControlPointSpacing(options.controlPointSpacing);
  filter->SetShrinkFactors(options.shrinkFactors);
  filter->SetSmoothingSigmas(options.smoothingSigmas);
  filter->SetNumberOfIterations(options.iterations);
  filter->SetMetricSamplingPercentage(options.samplingPercentage);
  filter->SetMaximumNumberOfMetricSamples(options.maximumSamples);
  filter->SetNumberOfHistogramBins(options.histogramBins);
  filter->SetRandomSeed(options.seed);
  filter->SetMetricNumberOfWorkUnits(options.metricWorkUnits);
  timer.Run("register", [&] {
    try
    {
      filter->Update();
    }
    catch (const itk::ExceptionObject & exception)
    {
      throw Error(std::string("bspline-register failed: ") +
                  itk::PlainDescription(exception.GetDescription()));
    }
  });

  json report = BSplineRegisterReport<Dimension>(*filter, options, movingInfo);

  // Everything is computed; a failed write removes what this run wrote.
  std::vector<fs::path> written;
  try
  {
    timer.Run("write", [&] {
      const fs::path output(options.output);
      CreateParentFolder(output);
      WriteWarpedAs<Dimension>(movingInfo.component, filter->GetOutput(), output);
      written.push_back(output);
      if (!options.transform.empty())
      {
        CreateParentFolder(options.transform);
        try
        {
          itk::WriteBiomechanicalTransform(filter->GetTransform(), options.transform);
        }
        catch (const itk::ExceptionObject & exception)
        {
          throw Error(itk::PlainDescription(exception.GetDescription()));
        }
        written.push_back(options.transform);
      }
    });
    if (!options.report.empty())
    {
      report["seconds"] = timer.Json();
      CreateParentFolder(options.report);
      WriteTextFileAtomically(options.report, report.dump(2) + "\n");
    }
  }
  catch (...)
  {
    RemoveFiles(written);
    throw;
  }

  if (!options.quiet)
  {
    std::ostringstream translation;
    for (unsigned int d = 0; d < Dimension; ++d)
    {
      translation << (d > 0 ? " " : "") << filter->GetInitialTranslation()[d];
    }
    std::ostringstream iterations;
    for (std::size_t level = 0; level < filter->GetIterationsPerLevel().size(); ++level)
    {
      iterations << (level > 0 ? " + " : "") << filter->GetIterationsPerLevel()[level];
    }
    std::cout << "bspline-register " << options.moving << " -> " << options.fixed << " (" << Dimension << "D)\n"
              << "  metric            " << options.metric << ", final " << filter->GetFinalMetricValue() << "\n"
              << "  mesh              " << filter->GetMeshSizesPerLevel().back() << " cells ("
              << options.controlPointSpacing << " mm)\n"
              << "  translation       " << translation.str() << " mm\n"
              << "  iterations        " << iterations.str() << " = " << filter->GetIterationsRun() << "\n"
              << "  registration      " << filter->GetElapsedSeconds() << " s\n"
              << "  warp              " << filter->GetWarpElapsedSeconds() << " s\n"
              << "  warped            " << options.output << " (" << OutputPixelName(movingInfo.component) << ")\n";
    if (!options.transform.empty())
    {
      std::cout << "  transform         " << options.transform << "\n";
    }
    if (!options.report.empty())
    {
      std::cout << "  report            " << options.report << "\n";
    }
  }
  return 0;
}

int
RunBSplineRegister(const BSplineRegisterOptions & options)
{
  // Checks that need no image come first, so a mistake costs no registration.
  if (!options.transform.empty())
  {
    const std::string extension = fs::path(options.transform).extension().string();
    if (extension != ".h5" && extension != ".hdf5" && extension != ".tfm" && extension != ".txt")
    {
      throw Error("--transform '" + options.transform +
                  "': the extension must be .h5 or .hdf5 (HDF5) or .tfm or .txt "
                  "(ITK text)");
    }
  }
  if (itk::ImageIOFactory::CreateImageIO(options.output.c_str(), itk::IOFileModeEnum::WriteMode).IsNull())
  {
    throw Error("cannot write image '" + options.output +
                "': not an image format biomech writes (.nii, .nii.gz, .nrrd, .mha, "
                ".mhd, .png)");
  }
  if (options.iterations.size() > 1 && options.iterations.size() != options.shrinkFactors.size())
  {
    throw Error("--iterations needs one value for every level or one per level (" +
                std::to_string(options.shrinkFactors.size()) + " levels)");
  }

  const ImageFileInfo fixedInfo = ReadImageFileInfo(options.fixed, "fixed image");
  const ImageFileInfo movingInfo = ReadImageFileInfo(options.moving, "moving image");
  if (fixedInfo.dimension != movingInfo.dimension)
  {
    throw Error("the fixed image '" + options.fixed + "' is " + std::to_string(fixedInfo.dimension) +
                "D but the moving image '" + options.moving + "' is " + std::to_string(movingInfo.dimension) +
                "D; register images of the same dimension");
  }
  if (!options.mask.empty())
  {
    const ImageFileInfo maskInfo = ReadImageFileInfo(options.mask, "mask");
    if (maskInfo.dimension != fixedInfo.dimension)
    {
      throw Error("the mask '" + options.mask + "' is " + std::to_string(maskInfo.dimension) +
                  "D but the fixed image is " + std::to_string(fixedInfo.dimension) + "D");
    }
  }
  const std::string outputExtension = fs::path(options.output).extension().string();
  const std::string pixel = OutputPixelName(movingInfo.component);
  if ((outputExtension == ".png" || outputExtension == ".PNG") && pixel != "uint8" && pixel != "uint16")
  {
    throw Error("cannot write '" + options.output +
                "': PNG holds 8- or 16-bit unsigned pixels but the warped image is " + pixel +
                " (the moving image's type); write .nii.gz or .mha instead");
  }
  if (options.threads > 0)
  {
    itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(static_cast<itk::ThreadIdType>(options.threads));
  }
  switch (fixedInfo.dimension)
  {
    case 2:
      return RunBSplineRegister<2>(options, movingInfo);
    case 3:
      return RunBSplineRegister<3>(options, movingInfo);
    default:
      throw Error("the fixed image '" + options.fixed + "' is " + std::to_string(fixedInfo.dimension) +
                  "D; bspline-register handles 2D and 3D images");
  }
}

} // namespace

std::function<int()>
AddBSplineRegisterCommand(CLI::App & app)
{
  auto       options = std::make_shared<BSplineRegisterOptions>();
  CLI::App * command = app.add_subcommand(
    "bspline-register",
    "Intensity-based B-spline registration (the baseline): warp MOVING (preoperative) onto FIXED (intraoperative)");
  command->add_option("fixed", options->fixed, "Fixed (intraoperative) image, 2D or 3D")->required();
  command->add_option("moving", options->moving, "Moving (preoperative) image, same dimension")->required();
  command
    ->add_option("-o,--output",
                 options->output,
                 "Warped moving image on the fixed grid (moving pixel type up to 16-bit integers, else float)")
    ->required();
  command->add_option(
    "--transform", options->transform, "Write the B-spline transform (fixed -> moving points) as .h5 or .tfm");
  command->add_option("--report", options->report, "Write a JSON report (parameters, metric, iterations, times)");
  command->add_option("--mask", options->mask, "Fixed-image mask (voxels > 0): only metric samples inside count");
  command->add_option("--metric", options->metric, "mattes (mutual information, any modalities) or correlation")
    ->check(CLI::IsMember({ "mattes", "correlation" }))
    ->capture_default_str();
  command
    ->add_option("--initialize",
                 options->initialize,
                 "Start: identity (images aligned in physical space) or moments (centres of mass)")
    ->check(CLI::IsMember({ "identity", "moments" }))
    ->capture_default_str();
  command->add_flag("--no-translation", options->noTranslation, "Skip the translation stage before the B-spline");
  command->add_flag(
    "--no-mesh-refinement", options->noMeshRefinement, "Use the final control point spacing at every level");
  command->add_option("--control-point-spacing", options->controlPointSpacing, "Final B-spline mesh spacing (mm)")
    ->check(CLI::PositiveNumber)
    ->capture_default_str();
  command
    ->add_option("--iterations",
                 options->iterations,
                 "Maximum L-BFGS-B iterations: one value or one per level [default: 100 halved per level]")
    ->expected(1, -1);
  command->add_option("--shrink-factors", options->shrinkFactors, "Pyramid shrink factor per level, coarse to fine")
    ->expected(1, -1)
    ->capture_default_str();
  command->add_option("--smoothing-sigmas", options->smoothingSigmas, "Gaussian sigma per level (mm)")
    ->expected(1, -1)
    ->capture_default_str();
  command->add_option("--sampling-percentage", options->samplingPercentage, "Fraction of voxels used as metric samples")
    ->check(CLI::Range(1e-6, 1.0))
    ->capture_default_str();
  command->add_option("--max-samples", options->maximumSamples, "Most metric samples per level (0: no limit)")
    ->capture_default_str();
  command->add_option("--histogram-bins", options->histogramBins, "Mattes histogram bins")->capture_default_str();
  command->add_option("--seed", options->seed, "Seed of the metric sampling")->capture_default_str();
  command
    ->add_option("--metric-work-units",
                 options->metricWorkUnits,
                 "Metric work units (1: bitwise repeatable; more: faster, last bits vary)")
    ->check(CLI::Range(1, 256))
    ->capture_default_str();
  command->add_option("--threads", options->threads, "ITK threads (0: all cores)")->check(CLI::Range(0, 4096));
  command->add_flag("--quiet,-q", options->quiet, "Print nothing but errors");

  return [=]() -> int {
    if (!command->parsed())
    {
      return -1;
    }
    return RunBSplineRegister(*options);
  };
}

} // namespace app
} // namespace bmr
