// `biomech fit-transform` and `biomech warp`: from a solve's nodal
// displacements to an ITK transform file, and from a transform to a warped
// image.
#include "bmrImageCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalTransformIO.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkImageIOFactory.h"
#include "itkTransformWarpImageFilter.h"

#include "bmrCommandSupport.h"

#include "bmrMeshIO.h"

#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace bmr
{
namespace app
{
namespace
{

using PointSetType = itk::DisplacementPointSetType<3>;
using FitterType = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>;
using ReferenceImageType = itk::Image<float, 3>;

struct FitTransformOptions
{
  std::string displacements;
  std::string reference;
  std::string output;
  std::string forwardOutput;
  std::string fieldOutput;
  std::string report;
  double      tolerance = 0.1;
  double      minimumSpacing = 1.0;
  bool        rejectOutside = false;
  bool        quiet = false;
};

struct WarpOptions
{
  std::string image;
  std::string transform;
  std::string output;
  std::string reference;
  std::string interpolation = "linear";
  double      defaultValue = 0.0;
};

/** Reference positions and displacements from a solve's result mesh (point
 *  data "displacement") or a CSV file with columns x,y,z,ux,uy,uz (mm). */
PointSetType::Pointer
ReadDisplacements(const std::string & path)
{
  const std::string extension = fs::path(path).extension().string();
  if (extension == ".csv")
  {
    std::ifstream stream(path);
    if (!stream)
    {
      throw Error("cannot read displacements '" + path + "': no such file");
    }
    std::vector<Vector3> nodes;
    std::vector<Vector3> displacements;
    std::string          line;
    std::size_t          lineNumber = 0;
    while (std::getline(stream, line))
    {
      ++lineNumber;
      if (line.empty() || line[0] == '#' || (lineNumber == 1 && line.find_first_of("xXuU") != std::string::npos))
      {
        continue; // comment or header
      }
      std::replace(line.begin(), line.end(), ',', ' ');
      std::istringstream values(line);
      double             v[6];
      for (double & value : v)
      {
        if (!(values >> value))
        {
          throw Error("cannot read displacements '" + path + "': line " + std::to_string(lineNumber) +
                      " does not hold 6 numbers x,y,z,ux,uy,uz (mm)");
        }
      }
      nodes.emplace_back(v[0], v[1], v[2]);
      displacements.emplace_back(v[3], v[4], v[5]);
    }
    return itk::MakeDisplacementPointSet<PointSetType>(nodes, displacements);
  }
  const MeshData mesh = ReadMesh(path);
  const auto     found = mesh.pointData.find("displacement");
  if (found == mesh.pointData.end() || found->second.components != 3 ||
      found->second.Tuples() != mesh.model.nodes.size())
  {
    throw Error("'" + path + "' has no 3-component point-data array \"displacement\" with one value per point; give "
                "the result .vtu of 'biomech solve' or a CSV x,y,z,ux,uy,uz");
  }
  std::vector<Vector3> displacements(mesh.model.nodes.size());
  for (std::size_t n = 0; n < displacements.size(); ++n)
  {
    displacements[n] = Vector3(found->second.values[3 * n], found->second.values[3 * n + 1],
                               found->second.values[3 * n + 2]);
  }
  return itk::MakeDisplacementPointSet<PointSetType>(mesh.model.nodes, displacements);
}

json
FitReportJson(const itk::BSplineFitReport & report)
{
  return { { "maximum_residual_mm", report.maximumResidual },
           { "rms_residual_mm", report.rmsResidual },
           { "levels", report.levels },
           { "control_point_spacing_mm", report.controlPointSpacing },
           { "mesh_size", report.meshSize },
           { "tolerance_reached", report.toleranceReached } };
}

void
CheckTransformPath(const std::string & path, const std::string & option)
{
  const std::string extension = fs::path(path).extension().string();
  if (extension != ".h5" && extension != ".hdf5" && extension != ".tfm" && extension != ".txt")
  {
    throw Error(option + " '" + path + "': the extension must be .h5 or .hdf5 (HDF5) or .tfm or .txt (ITK text)");
  }
}

void
WriteTransform(const itk::TransformBaseTemplate<double> * transform, const std::string & path)
{
  try
  {
    itk::WriteBiomechanicalTransform(transform, path);
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(itk::PlainDescription(exception.GetDescription()));
  }
}

int
RunFitTransform(const FitTransformOptions & options)
{
  // Checked before any work, so a wrong name costs nothing and writes nothing.
  CheckTransformPath(options.output, "-o");
  if (!options.forwardOutput.empty())
  {
    CheckTransformPath(options.forwardOutput, "--forward-output");
  }
  const std::vector<fs::path> outputs = { options.output, options.forwardOutput, options.fieldOutput, options.report };
  for (const fs::path & output : outputs)
  {
    if (!output.empty())
    {
      std::error_code ignored;
      fs::remove(output, ignored); // an earlier run's file must not pass for this run's
      CreateParentFolder(output);
    }
  }

  StepTimer timer(!options.quiet && ::isatty(STDERR_FILENO) != 0);
  const PointSetType::Pointer points = timer.Run("read", [&] { return ReadDisplacements(options.displacements); });
  const ReferenceImageType::Pointer reference =
    timer.Run("read", [&] { return ReadImage<ReferenceImageType>(options.reference, "reference image"); });

  auto fitter = FitterType::New();
  fitter->SetInput(points);
  fitter->SetReferenceImage(reference);
  fitter->SetTolerance(options.tolerance);
  fitter->SetMinimumControlPointSpacing(options.minimumSpacing);
  fitter->SetExtendDomainToPoints(!options.rejectOutside);
  fitter->SetGenerateForwardTransform(!options.forwardOutput.empty());
  fitter->SetGenerateDisplacementField(!options.fieldOutput.empty());
  timer.Run("fit", [&] {
    try
    {
      fitter->Update();
    }
    catch (const itk::ExceptionObject & exception)
    {
      throw Error(std::string("fitting the transform failed: ") +
                  itk::PlainDescription(exception.GetDescription()));
    }
  });

  const auto & backward = fitter->GetReport();
  json         report = { { "displacements", options.displacements },
                          { "reference_image", options.reference },
                          { "points", points->GetNumberOfPoints() },
                          { "tolerance_mm", options.tolerance },
                          { "minimum_control_point_spacing_mm", options.minimumSpacing },
                          { "domain_extended", fitter->GetDomainExtended() },
                          { "backward", FitReportJson(backward) },
                          { "transform", options.output } };
  try
  {
    timer.Run("write", [&] {
      WriteTransform(fitter->GetTransform(), options.output);
      if (!options.forwardOutput.empty())
      {
        WriteTransform(fitter->GetForwardTransform(), options.forwardOutput);
        report["forward"] = FitReportJson(fitter->GetForwardReport());
        report["forward_transform"] = options.forwardOutput;
      }
      if (!options.fieldOutput.empty())
      {
        WriteImageAtomically(fitter->GetDisplacementFieldTransform()->GetDisplacementField(), options.fieldOutput);
        report["displacement_field"] = options.fieldOutput;
      }
    });
    report["seconds"] = timer.Json();
    if (!options.report.empty())
    {
      WriteTextFileAtomically(options.report, report.dump(2) + "\n");
    }
  }
  catch (...)
  {
    // All of the outputs or none.
    for (const fs::path & output : outputs)
    {
      std::error_code ignored;
      if (!output.empty())
      {
        fs::remove(output, ignored);
      }
    }
    throw;
  }

  const bool reached = backward.toleranceReached &&
                       (options.forwardOutput.empty() || fitter->GetForwardReport().toleranceReached);
  if (!options.quiet)
  {
    auto line = [](const char * name, const itk::BSplineFitReport & fit) {
      std::ostringstream text;
      text << std::fixed << std::setprecision(3) << "  " << name << ": maximum residual " << fit.maximumResidual
           << " mm, RMS " << fit.rmsResidual << " mm, " << fit.levels << " levels, control points every "
           << std::setprecision(1) << fit.controlPointSpacing[0] << " x " << fit.controlPointSpacing[1] << " x "
           << fit.controlPointSpacing[2] << " mm" << (fit.toleranceReached ? "" : "  (TOLERANCE NOT REACHED)") << "\n";
      return text.str();
    };
    std::cout << "fit-transform: " << points->GetNumberOfPoints() << " points"
              << (fitter->GetDomainExtended() ? ", domain extended beyond the reference image to hold them" : "")
              << "\n"
              << line("backward (resampling)", backward);
    if (!options.forwardOutput.empty())
    {
      std::cout << line("forward", fitter->GetForwardReport());
    }
    std::cout << "  wrote " << options.output << "\n";
  }
  if (!reached)
  {
    std::cerr << "biomech: the largest residual is above the tolerance of " << options.tolerance
              << " mm at the minimum control-point spacing of " << options.minimumSpacing
              << " mm (transform written, report says tolerance_reached: false); lower --min-spacing or raise "
                 "--tolerance\n";
    return 2;
  }
  return 0;
}

template <typename TPixel>
void
WarpWithPixelType(const WarpOptions & options, const itk::Transform<double, 3, 3> * transform)
{
  using ImageType = itk::Image<TPixel, 3>;
  using WarpType = itk::TransformWarpImageFilter<ImageType>;
  auto warp = WarpType::New();
  warp->SetInput(ReadImage<ImageType>(options.image, "image"));
  typename ImageType::Pointer reference;
  if (!options.reference.empty())
  {
    reference = ReadImage<ImageType>(options.reference, "reference image");
    warp->SetReferenceImage(reference);
  }
  warp->SetTransform(transform);
  warp->SetInterpolation(options.interpolation == "nearest"   ? itk::WarpInterpolation::NearestNeighbor
                         : options.interpolation == "bspline" ? itk::WarpInterpolation::BSpline
                                                              : itk::WarpInterpolation::Linear);
  warp->SetDefaultPixelValue(static_cast<TPixel>(options.defaultValue));
  try
  {
    warp->Update();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(std::string("warping '") + options.image +
                "' failed: " + itk::PlainDescription(exception.GetDescription()));
  }
  WriteImageAtomically(warp->GetOutput(), options.output);
}

int
RunWarp(const WarpOptions & options)
{
  std::error_code ignored;
  fs::remove(options.output, ignored);
  CreateParentFolder(options.output);

  itk::TransformBaseTemplate<double>::Pointer read;
  try
  {
    read = itk::ReadBiomechanicalTransform(options.transform);
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(itk::PlainDescription(exception.GetDescription()));
  }
  const auto * transform = dynamic_cast<const itk::Transform<double, 3, 3> *>(read.GetPointer());
  if (transform == nullptr)
  {
    throw Error("transform '" + options.transform + "' is a " + read->GetNameOfClass() +
                ", not a 3D transform; warp takes 3D images and 3D transforms");
  }

  // The pixel type of the file is kept: label maps stay integer labels.
  const ImageFileInfo info = ReadImageFileInfo(options.image, "image");
  if (info.dimension != 3 || info.components != 1)
  {
    throw Error("image '" + options.image + "' has " + std::to_string(info.dimension) + " dimensions and " +
                std::to_string(info.components) + " components per voxel; warp takes 3D scalar images");
  }
  using Component = itk::IOComponentEnum;
  switch (info.component)
  {
    case Component::UCHAR:
      WarpWithPixelType<unsigned char>(options, transform);
      break;
    case Component::CHAR:
      WarpWithPixelType<signed char>(options, transform);
      break;
    case Component::USHORT:
      WarpWithPixelType<unsigned short>(options, transform);
      break;
    case Component::SHORT:
      WarpWithPixelType<short>(options, transform);
      break;
    case Component::UINT:
    case Component::INT:
      WarpWithPixelType<int>(options, transform);
      break;
    default:
      WarpWithPixelType<float>(options, transform);
      break;
  }
  return 0;
}

} // namespace

std::function<int()>
AddTransformCommands(CLI::App & app)
{
  auto       fit = std::make_shared<FitTransformOptions>();
  CLI::App * fitCommand = app.add_subcommand(
    "fit-transform",
    "Fit a cubic B-spline transform (ITK .h5/.tfm) to a solve's nodal displacements: the resampling map that warps "
    "the preoperative image. Exit 0 fitted, 2 tolerance not reached (written, report says so), 1 error");
  fitCommand->add_option("displacements", fit->displacements,
                         "Result .vtu of 'biomech solve' (point data \"displacement\") or CSV x,y,z,ux,uy,uz (mm)")
    ->required();
  fitCommand->add_option("reference", fit->reference, "Image whose grid is the transform's domain (preoperative MRI)")
    ->required();
  fitCommand->add_option("-o,--output", fit->output, "Backward (resampling) transform, .h5 or .tfm")->required();
  fitCommand->add_option("--forward-output", fit->forwardOutput, "Also fit and write the forward map x -> x + u(x)");
  fitCommand->add_option("--displacement-field-output", fit->fieldOutput,
                         "Also write the backward map sampled on the reference grid (vector image, e.g. .nii.gz)");
  fitCommand->add_option("--report", fit->report, "Report JSON: residuals, levels, control-point spacing, times");
  fitCommand->add_option("--tolerance", fit->tolerance, "Largest residual at the nodes to stop adding levels (mm)")
    ->capture_default_str()
    ->check(CLI::PositiveNumber);
  fitCommand->add_option("--min-spacing", fit->minimumSpacing, "Finest control-point spacing (mm)")
    ->capture_default_str()
    ->check(CLI::PositiveNumber);
  fitCommand->add_flag("--reject-outside", fit->rejectOutside,
                       "Error for nodes outside the reference image (default: grow the domain to hold them)");
  fitCommand->add_flag("--quiet,-q", fit->quiet, "Print nothing but warnings and errors");

  auto       warp = std::make_shared<WarpOptions>();
  CLI::App * warpCommand =
    app.add_subcommand("warp", "Resample a 3D image (any scalar pixel type) through a transform file");
  warpCommand->add_option("image", warp->image, "Image to warp (e.g. the preoperative MRI or a label map)")->required();
  warpCommand->add_option("transform", warp->transform, "Resampling transform (.h5, .tfm), e.g. from fit-transform")
    ->required();
  warpCommand->add_option("-o,--output", warp->output, "Warped image")->required();
  warpCommand->add_option("--reference", warp->reference, "Output grid (default: the image's own grid)");
  warpCommand->add_option("--interpolation", warp->interpolation, "linear, bspline (cubic) or nearest (label maps)")
    ->capture_default_str()
    ->check(CLI::IsMember({ "linear", "bspline", "nearest" }));
  warpCommand->add_option("--default-value", warp->defaultValue, "Value of voxels that map outside the image")
    ->capture_default_str();

  return [=]() -> int {
    if (fitCommand->parsed())
    {
      return RunFitTransform(*fit);
    }
    if (warpCommand->parsed())
    {
      return RunWarp(*warp);
    }
    return -1;
  };
}

} // namespace app
} // namespace bmr
