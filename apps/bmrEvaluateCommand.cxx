// biomech evaluate: edge-based Hausdorff distance between the intraoperative
// image and the registered preoperative image (itk::EdgeHausdorffDistanceImageFilter),
// with a JSON report and optional overlay PNGs. docs/evaluation.md describes it.
#include "bmrImageCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkEdgeHausdorffDistanceImageFilter.h"

#include "bmrCommandSupport.h"

#include "bmrMeshIO.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bmr
{
namespace app
{
namespace
{

// Every image is read as a 3D float volume: a 2D image (PNG, ...) becomes one slice.
using ImageType = itk::Image<float, 3>;
using FilterType = itk::EdgeHausdorffDistanceImageFilter<ImageType, ImageType>;

struct EvaluateOptions
{
  std::string fixed;
  std::string moving;
  std::string mask;
  double      variance = 0.0;
  double      upperThreshold = 0.0;
  double      lowerThreshold = 0.0;
  double      thresholdQuantile = 0.0;
  std::string sliceAxis = "2";
  double      distanceThreshold = 0.0;
  std::string output;
  std::string overlays;
  bool        quiet = false;
};

/** An ITK exception's description as one plain line (itk::PlainDescription), without the filter's name. */
std::string
PlainMessage(const itk::ExceptionObject & exception)
{
  std::string       message = itk::PlainDescription(exception.GetDescription());
  const std::string prefix = "EdgeHausdorffDistanceImageFilter: ";
  if (const auto position = message.rfind(prefix); position != std::string::npos)
  {
    return message.substr(position + prefix.size());
  }
  return message;
}

/** One PNG per slice (across `axis`) that has edges; returns the number written. */
std::size_t
WriteOverlays(const FilterType & filter, const ImageType * fixed, unsigned int axis, bool twoDimensional,
              const fs::path & folder)
{
  CreateFolder(folder);
  const auto [grey0, grey1] = OverlayGreyRange(fixed);
  const std::vector<itk::IndexValueType> slices =
    itk::EdgeOverlaySlices(filter.GetFixedEdges(), filter.GetMovingEdges(), axis);
  for (const itk::IndexValueType slice : slices)
  {
    const auto overlay =
      itk::MakeEdgeOverlaySlice(filter.GetFixedEdges(), filter.GetMovingEdges(), fixed, axis, slice, grey0, grey1);
    char name[64];
    if (twoDimensional)
    {
      std::snprintf(name, sizeof(name), "edges.png");
    }
    else
    {
      std::snprintf(name, sizeof(name), "edges-axis%u-%04ld.png", axis, static_cast<long>(slice));
    }
    WriteImageAtomically(overlay.GetPointer(), folder / name);
  }
  return slices.size();
}

std::string
Percent(double fraction)
{
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f%%", 100.0 * fraction);
  return text;
}

void
PrintTable(const itk::EdgeHausdorffResult & result, const std::string & mode)
{
  std::printf("edge-based Hausdorff distance (mm), %s\n", mode.c_str());
  std::printf("  percentile      %8s %8s %8s %8s %8s\n", "50", "75", "90", "95", "100");
  const auto row = [](const char * name, const std::vector<double> & curve) {
    std::printf("  %-15s", name);
    for (const int k : { 50, 75, 90, 95, 100 })
    {
      std::printf(" %8.3f", curve[static_cast<std::size_t>(k - 1)]);
    }
    std::printf("\n");
  };
  row("fixed->moving", result.fixedToMoving);
  row("moving->fixed", result.movingToFixed);
  row("symmetric", result.symmetric);
  std::printf("  within %g mm: %s of the edge pixels (fixed %s, moving %s)\n",
              result.distanceThreshold,
              Percent(result.fractionWithinThreshold).c_str(),
              Percent(result.fractionFixedWithinThreshold).c_str(),
              Percent(result.fractionMovingWithinThreshold).c_str());
  std::printf("  edge pixels: fixed %zu, moving %zu\n", result.fixedEdgePixels, result.movingEdgePixels);
  if (!result.message.empty())
  {
    std::printf("  note: %s\n", result.message.c_str());
  }
}

int
RunEvaluate(const EvaluateOptions & options)
{
  StepTimer          timer(!options.quiet);
  ImageType::Pointer fixed;
  ImageType::Pointer moving;
  ImageType::Pointer mask;
  timer.Run("read", [&] {
    fixed = ReadImage<ImageType>(options.fixed, "fixed (intraoperative) image");
    moving = ReadImage<ImageType>(options.moving, "moving (registered preoperative) image");
    if (!options.mask.empty())
    {
      mask = ReadImage<ImageType>(options.mask, "mask");
    }
  });

  // A 2D image read as a volume has one slice: it is evaluated in 2D whatever --slice-axis says.
  const bool twoDimensional = fixed->GetLargestPossibleRegion().GetSize()[2] == 1;
  const int  sliceAxis = twoDimensional ? 2 : options.sliceAxis == "none" ? -1 : std::stoi(options.sliceAxis);

  auto filter = FilterType::New();
  filter->SetFixedImage(fixed);
  filter->SetMovingImage(moving);
  if (mask)
  {
    filter->SetMaskImage(mask);
  }
  filter->SetVariance(options.variance);
  filter->SetUpperThreshold(options.upperThreshold);
  filter->SetLowerThreshold(options.lowerThreshold);
  filter->SetUpperThresholdQuantile(options.thresholdQuantile);
  filter->SetSliceAxis(sliceAxis);
  filter->SetDistanceThreshold(options.distanceThreshold);
  try
  {
    timer.Run("evaluate", [&] { filter->Update(); });
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(PlainMessage(exception));
  }
  const itk::EdgeHausdorffResult & result = filter->GetResult();
  if (!result.valid)
  {
    throw Error(result.message + " (options --upper-threshold, --lower-threshold, --variance, --mask)");
  }

  std::ostringstream mode;
  if (twoDimensional)
  {
    mode << "2D image";
  }
  else if (sliceAxis < 0)
  {
    mode << "whole 3D image";
  }
  else
  {
    mode << "slices across axis " << sliceAxis << " (" << result.slicesEvaluated << " evaluated, "
         << result.slicesSkipped << " skipped)";
  }

  std::size_t overlayFiles = 0;
  if (!options.overlays.empty())
  {
    // Whole-image mode shows axial (axis 2) slices of the 3D edges.
    const unsigned int overlayAxis = sliceAxis < 0 ? 2u : static_cast<unsigned int>(sliceAxis);
    overlayFiles = timer.Run(
      "overlays", [&] { return WriteOverlays(*filter, fixed, overlayAxis, twoDimensional, options.overlays); });
  }

  if (!options.output.empty())
  {
    json report;
    report["command"] = "evaluate";
    report["fixed"] = options.fixed;
    report["moving"] = options.moving;
    report["mask"] = options.mask.empty() ? json(nullptr) : json(options.mask);
    const auto size = fixed->GetLargestPossibleRegion().GetSize();
    const auto spacing = fixed->GetSpacing();
    report["image"] = {
      { "dimension", twoDimensional ? 2 : 3 },
      { "size", twoDimensional ? json{ size[0], size[1] } : json{ size[0], size[1], size[2] } },
      { "spacing_mm", twoDimensional ? json{ spacing[0], spacing[1] } : json{ spacing[0], spacing[1], spacing[2] } }
    };
    report["mode"] = twoDimensional ? "2d" : sliceAxis < 0 ? "3d" : "slices";
    report["parameters"] = { { "variance_mm2", filter->GetVariance() },
                             { "automatic_thresholds", filter->GetAutomaticThresholds() },
                             { "upper_threshold_quantile", filter->GetUpperThresholdQuantile() },
                             { "lower_threshold_ratio", filter->GetLowerThresholdRatio() },
                             { "upper_threshold", filter->GetUpperThreshold() },
                             { "lower_threshold", filter->GetLowerThreshold() },
                             { "slice_axis",
                               twoDimensional  ? json(nullptr)
                               : sliceAxis < 0 ? json("none")
                                               : json(sliceAxis) },
                             { "distance_threshold_mm", result.distanceThreshold } };
    report["thresholds_used"] = {
      { "fixed",
        { { "upper", filter->GetFixedUpperThresholdUsed() }, { "lower", filter->GetFixedLowerThresholdUsed() } } },
      { "moving",
        { { "upper", filter->GetMovingUpperThresholdUsed() }, { "lower", filter->GetMovingLowerThresholdUsed() } } }
    };
    report["valid"] = result.valid;
    report["message"] = result.message;
    std::vector<int> percentiles(100);
    for (int k = 1; k <= 100; ++k)
    {
      percentiles[static_cast<std::size_t>(k - 1)] = k;
    }
    report["percentiles"] = percentiles;
    report["fixed_to_moving_mm"] = result.fixedToMoving;
    report["moving_to_fixed_mm"] = result.movingToFixed;
    report["symmetric_mm"] = result.symmetric;
    report["hausdorff_mm"] = result.symmetric.back();
    report["fraction_within_threshold"] = { { "fixed_to_moving", result.fractionFixedWithinThreshold },
                                            { "moving_to_fixed", result.fractionMovingWithinThreshold },
                                            { "pooled", result.fractionWithinThreshold } };
    report["counts"] = { { "fixed_edge_pixels", result.fixedEdgePixels },
                         { "moving_edge_pixels", result.movingEdgePixels },
                         { "slices_evaluated", result.slicesEvaluated },
                         { "slices_skipped", result.slicesSkipped } };
    if (!options.overlays.empty())
    {
      report["overlays"] = { { "folder", options.overlays }, { "files", overlayFiles } };
    }
    report["seconds"] = timer.Json();
    CreateParentFolder(options.output);
    WriteTextFileAtomically(options.output, report.dump(2) + "\n");
  }

  if (!options.quiet)
  {
    PrintTable(result, mode.str());
    if (!options.overlays.empty())
    {
      std::printf("wrote %zu overlay PNG(s) to %s\n", overlayFiles, options.overlays.c_str());
    }
    if (!options.output.empty())
    {
      std::printf("wrote %s\n", options.output.c_str());
    }
  }
  return 0;
}

} // namespace

std::function<int()>
AddEvaluateCommand(CLI::App & app)
{
  auto options = std::make_shared<EvaluateOptions>();
  {
    // The filter's defaults are the command's defaults.
    const auto defaults = FilterType::New();
    options->variance = defaults->GetVariance();
    options->thresholdQuantile = defaults->GetUpperThresholdQuantile();
    options->distanceThreshold = defaults->GetDistanceThreshold();
  }

  CLI::App * command = app.add_subcommand(
    "evaluate", "Edge-based Hausdorff distance between the intraoperative image and the registered preoperative image");
  command->add_option("fixed", options->fixed, "Intraoperative image")->required();
  command->add_option("moving", options->moving, "Registered preoperative image, on the intraoperative grid")
    ->required();
  command->add_option("--mask", options->mask, "Region of interest on the intraoperative grid (voxels > 0)");
  command->add_option("--variance", options->variance, "Canny Gaussian variance (mm^2)")
    ->check(CLI::PositiveNumber)
    ->capture_default_str();
  command
    ->add_option("--upper-threshold",
                 options->upperThreshold,
                 "Canny upper threshold, gradient magnitude per pixel (default: automatic per image)")
    ->check(CLI::PositiveNumber);
  command
    ->add_option(
      "--lower-threshold", options->lowerThreshold, "Canny lower threshold (default: 0.4 x the upper threshold)")
    ->check(CLI::PositiveNumber);
  command
    ->add_option("--threshold-quantile",
                 options->thresholdQuantile,
                 "Automatic upper threshold: this quantile of each image's gradient magnitude")
    ->check(CLI::Range(0.01, 0.999))
    ->capture_default_str();
  command
    ->add_option(
      "--slice-axis", options->sliceAxis, "Evaluate slice by slice across axis 0, 1 or 2, or the whole 3D image (none)")
    ->check(CLI::IsMember({ "0", "1", "2", "none" }))
    ->capture_default_str();
  command
    ->add_option("--threshold", options->distanceThreshold, "Distance within which an edge counts as registered (mm)")
    ->check(CLI::NonNegativeNumber)
    ->capture_default_str();
  command->add_option("-o,--output", options->output, "Report (.json)");
  command->add_option(
    "--overlays", options->overlays, "Folder for one PNG per slice with edges: fixed red, moving blue, both green");
  command->add_flag("--quiet,-q", options->quiet, "Print nothing but errors");

  return [=]() -> int {
    if (command->parsed())
    {
      return RunEvaluate(*options);
    }
    return -1;
  };
}

} // namespace app
} // namespace bmr
