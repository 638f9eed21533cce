// Conversions shared by the Python module's bindings (bmrPythonSupport.h):
// numpy arrays to and from points, indices and vectors; ITK-convention image
// objects to and from the core's volumes; progress callbacks.
#include "bmrPythonSupport.h"

#include "bmrBrainSurfaces.h"
#include "bmrFuzzyCMeans.h"
#include "bmrImageGrids.h"
#include "bmrMeshGenerators.h"
#include "bmrMeshIO.h"
#include "bmrScene.h"
#include "bmrSurfaceLoads.h"

#include <Python.h>
#include <pybind11/eigen.h>
#include <pybind11/functional.h>

#include <cmath>
#include <cstring>
#include <sstream>

namespace bmr::python
{

// ---------------------------------------------------------------------------
// Arrays.
// ---------------------------------------------------------------------------

py::array_t<double>
ArrayFromPoints(const std::vector<Vector3> & points)
{
  py::array_t<double> array({ static_cast<py::ssize_t>(points.size()), py::ssize_t{ 3 } });
  auto                view = array.mutable_unchecked<2>();
  for (std::size_t i = 0; i < points.size(); ++i)
  {
    for (int d = 0; d < 3; ++d)
    {
      view(static_cast<py::ssize_t>(i), d) = points[i][d];
    }
  }
  return array;
}

namespace
{

/** `object` as a C-contiguous float64 array; ValueError naming `what` when NumPy cannot read it as numbers. */
py::array_t<double, py::array::c_style | py::array::forcecast>
DoubleArray(const py::handle & object, const std::string & what)
{
  try
  {
    return py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(object);
  }
  catch (const py::error_already_set &)
  {
  }
  throw py::value_error(what + " must be numbers (an array or a sequence)");
}

std::string
ShapeText(const py::array & array)
{
  std::ostringstream text;
  text << "(";
  for (py::ssize_t d = 0; d < array.ndim(); ++d)
  {
    text << (d > 0 ? ", " : "") << array.shape(d);
  }
  text << (array.ndim() == 1 ? ",)" : ")");
  return text.str();
}

} // namespace

std::vector<Vector3>
PointsFromArray(const py::handle & object, const std::string & what)
{
  const auto array = DoubleArray(object, what);
  if (!array || array.ndim() != 2 || array.shape(1) != 3)
  {
    throw py::value_error(what + " must be an (N, 3) array of x, y, z (mm); got shape " +
                          (array ? ShapeText(array) : std::string("none")));
  }
  const auto           view = array.unchecked<2>();
  std::vector<Vector3> points(static_cast<std::size_t>(array.shape(0)));
  for (py::ssize_t i = 0; i < array.shape(0); ++i)
  {
    points[static_cast<std::size_t>(i)] = Vector3(view(i, 0), view(i, 1), view(i, 2));
    if (!points[static_cast<std::size_t>(i)].allFinite())
    {
      throw py::value_error(what + " row " + std::to_string(i) + " is not finite: " +
                            FormatPoint(points[static_cast<std::size_t>(i)]));
    }
  }
  return points;
}

Vector3
VectorFromObject(const py::handle & object, const std::string & what)
{
  const auto array = DoubleArray(object, what);
  if (!array || array.ndim() != 1 || array.shape(0) != 3)
  {
    throw py::value_error(what + " must be three numbers (x, y, z); got shape " +
                          (array ? ShapeText(array) : std::string("none")));
  }
  const Vector3 vector(array.at(0), array.at(1), array.at(2));
  if (!vector.allFinite())
  {
    throw py::value_error(what + " is not finite: " + FormatPoint(vector));
  }
  return vector;
}

py::array_t<Index>
ArrayFromIndices(const std::vector<Index> & indices)
{
  py::array_t<Index> array(static_cast<py::ssize_t>(indices.size()));
  if (!indices.empty())
  {
    std::memcpy(array.mutable_data(), indices.data(), indices.size() * sizeof(Index));
  }
  return array;
}

std::vector<Index>
IndicesFromArray(const py::handle & object, const std::string & what)
{
  py::array array;
  try
  {
    array = py::array::ensure(object);
  }
  catch (const py::error_already_set &)
  {
  }
  if (!array || array.ndim() != 1 ||
      (array.size() > 0 && array.dtype().kind() != 'i' && array.dtype().kind() != 'u'))
  {
    throw py::value_error(what + " must be a 1-D sequence of integer node ids");
  }
  const auto values = py::array_t<long long, py::array::c_style | py::array::forcecast>::ensure(array);
  std::vector<Index> indices(static_cast<std::size_t>(values.size()));
  for (py::ssize_t i = 0; i < values.size(); ++i)
  {
    const long long value = values.at(i);
    if (value < 0 || value > std::numeric_limits<Index>::max())
    {
      throw py::value_error(what + " holds " + std::to_string(value) + ", which is not a node id (0 or more)");
    }
    indices[static_cast<std::size_t>(i)] = static_cast<Index>(value);
  }
  return indices;
}

std::array<bool, 3>
ComponentsFromObject(const py::handle & object, const std::string & what)
{
  const auto sequence = py::cast<std::vector<bool>>(object);
  if (sequence.size() != 3)
  {
    throw py::value_error(what + " must be three booleans (x, y, z)");
  }
  return { sequence[0], sequence[1], sequence[2] };
}

py::dict
LoadReportDict(const LoadReport & report)
{
  py::dict result;
  result["used"] = report.usedPoints;
  result["rejected"] = report.rejectedPoints;
  result["max_correspondence_distance_mm"] = report.maxCorrespondenceDistance;
  result["rms_correspondence_distance_mm"] = report.rmsCorrespondenceDistance;
  result["warnings"] = report.warnings;
  return result;
}

// ---------------------------------------------------------------------------
// Images.
// ---------------------------------------------------------------------------

namespace
{

py::object
ImageClass()
{
  return py::module_::import("biomechanical_registration.image").attr("Image");
}

py::object
ImageAttribute(const py::handle & image, const char * name, const std::string & what)
{
  if (image.is_none() || !py::hasattr(image, name))
  {
    throw py::type_error(what + " must be a biomechanical_registration.Image (from image_from_array or imread); "
                                "got " +
                         std::string(py::str(py::type::of(image).attr("__name__"))));
  }
  return image.attr(name);
}

/** The image's array with `what` in messages: 3-D, or 4-D when `components` is allowed. */
py::array
ImageArray(const py::handle & image, const std::string & what, bool allowComponents)
{
  const py::array array = py::array::ensure(ImageAttribute(image, "array", what));
  if (!array || !(array.ndim() == 3 || (allowComponents && array.ndim() == 4)))
  {
    throw py::value_error(what + " must be a 3-D image: its array must have shape (z, y, x)" +
                          std::string(allowComponents ? " or (z, y, x, components)" : "") + ", got " +
                          (array ? ShapeText(array) : std::string("none")));
  }
  for (py::ssize_t d = 0; d < array.ndim(); ++d)
  {
    if (array.shape(d) == 0)
    {
      throw py::value_error(what + " is empty: its array has shape " + ShapeText(array));
    }
  }
  return array;
}

template <typename T>
void
FillVolume(const py::handle & image, const py::array & array, const std::string & what, Volume<T> & volume)
{
  volume.geometry = GeometryFromImage(image, what);
  // [z, y, x] in NumPy is x fastest in memory: ITK's buffer order.
  volume.geometry.size = { static_cast<int>(array.shape(2)), static_cast<int>(array.shape(1)),
                           static_cast<int>(array.shape(0)) };
  volume.components = array.ndim() == 4 ? static_cast<int>(array.shape(3)) : 1;
  volume.values.resize(volume.geometry.VoxelCount() * static_cast<std::size_t>(volume.components));
}

template <typename T>
py::object
MakeImage(const Volume<T> & volume)
{
  std::vector<py::ssize_t> shape{ volume.geometry.size[2], volume.geometry.size[1], volume.geometry.size[0] };
  if (volume.components != 1)
  {
    shape.push_back(volume.components);
  }
  py::array_t<T> array(shape);
  if (!volume.values.empty())
  {
    std::memcpy(array.mutable_data(), volume.values.data(), volume.values.size() * sizeof(T));
  }
  const ImageGeometry &  geometry = volume.geometry;
  py::array_t<double>    direction({ 3, 3 });
  auto                   view = direction.mutable_unchecked<2>();
  for (int row = 0; row < 3; ++row)
  {
    for (int column = 0; column < 3; ++column)
    {
      view(row, column) = geometry.direction(row, column);
    }
  }
  return ImageClass()(array, py::arg("spacing") = py::make_tuple(geometry.spacing.x(), geometry.spacing.y(), geometry.spacing.z()),
                      py::arg("origin") = py::make_tuple(geometry.origin.x(), geometry.origin.y(), geometry.origin.z()),
                      py::arg("direction") = direction);
}

} // namespace

ImageGeometry
GeometryFromImage(const py::handle & image, const std::string & what)
{
  ImageGeometry geometry;
  const auto    array = ImageArray(image, what, true);
  geometry.size = { static_cast<int>(array.shape(2)), static_cast<int>(array.shape(1)), static_cast<int>(array.shape(0)) };
  geometry.spacing = VectorFromObject(ImageAttribute(image, "spacing", what), what + " spacing");
  if ((geometry.spacing.array() <= 0.0).any())
  {
    throw py::value_error(what + " spacing must be positive (mm); got " + FormatPoint(geometry.spacing));
  }
  geometry.origin = VectorFromObject(ImageAttribute(image, "origin", what), what + " origin");
  const auto direction = DoubleArray(ImageAttribute(image, "direction", what), what + " direction");
  if (!direction || direction.ndim() != 2 || direction.shape(0) != 3 || direction.shape(1) != 3)
  {
    throw py::value_error(what + " direction must be a 3 x 3 matrix (columns: the index axes' directions)");
  }
  for (int row = 0; row < 3; ++row)
  {
    for (int column = 0; column < 3; ++column)
    {
      geometry.direction(row, column) = direction.at(row, column);
    }
  }
  if (!geometry.direction.allFinite() || std::abs(std::abs(geometry.direction.determinant()) - 1.0) > 1e-3)
  {
    throw py::value_error(what + " direction must be a rotation (orthonormal columns, determinant +-1)");
  }
  return geometry;
}

ScalarVolume
ScalarVolumeFromImage(const py::handle & image, const std::string & what)
{
  const py::array array = ImageArray(image, what, true);
  const char      kind = array.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u' && kind != 'b')
  {
    throw py::type_error(what + " must hold numbers; its array has dtype " + std::string(py::str(array.dtype())));
  }
  ScalarVolume volume;
  FillVolume(image, array, what, volume);
  const auto values = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(array);
  std::memcpy(volume.values.data(), values.data(), volume.values.size() * sizeof(float));
  return volume;
}

LabelVolume
LabelVolumeFromImage(const py::handle & image, const std::string & what)
{
  const py::array array = ImageArray(image, what, false);
  const char      kind = array.dtype().kind();
  if (kind != 'u' && kind != 'i' && kind != 'b')
  {
    throw py::type_error(what + " must be a mask or label image of dtype uint8 or bool (labels 0..255); its array has "
                                "dtype " +
                         std::string(py::str(array.dtype())) + ": convert it, e.g. (array > 0).astype(numpy.uint8)");
  }
  LabelVolume volume;
  FillVolume(image, array, what, volume);
  const auto values = py::array_t<long long, py::array::c_style | py::array::forcecast>::ensure(array);
  const long long * data = values.data();
  for (std::size_t k = 0; k < volume.values.size(); ++k)
  {
    if (data[k] < 0 || data[k] > 255)
    {
      throw py::value_error(what + " holds the label " + std::to_string(data[k]) +
                            "; masks and label maps take labels 0..255");
    }
    volume.values[k] = static_cast<std::uint8_t>(data[k]);
  }
  return volume;
}

py::object
ImageFromVolume(const ScalarVolume & volume)
{
  return MakeImage(volume);
}

py::object
ImageFromVolume(const LabelVolume & volume)
{
  return MakeImage(volume);
}

// ---------------------------------------------------------------------------
// Progress.
// ---------------------------------------------------------------------------

void
ProgressReporter::Report(const std::string & stage, double fraction,
                         const std::vector<std::pair<const char *, double>> & info, bool interrupt)
{
  if (m_Error)
  {
    if (interrupt)
      throw CallbackInterrupted{};
    return;
  }
  py::gil_scoped_acquire acquire;
  try
  {
    // Ctrl-C in a notebook or terminal stops a long solve here.
    if (PyErr_CheckSignals() != 0)
    {
      throw py::error_already_set();
    }
    if (!m_Callback.is_none())
    {
      py::dict details;
      for (const auto & [key, value] : info)
      {
        details[key] = value;
      }
      m_Callback(stage, fraction, details);
    }
  }
  catch (py::error_already_set & error)
  {
    m_Error = std::make_unique<py::error_already_set>(std::move(error));
    if (interrupt)
      throw CallbackInterrupted{};
  }
}

std::function<void(const std::string &, double)>
ProgressReporter::StageCallback()
{
  return [this](const std::string & stage, double seconds) {
    if (seconds < 0.0)
      Report(stage, 0.0, {}, false);
    else
      Report(stage, 1.0, { { "seconds", seconds } }, false);
  };
}

ProgressCallback
ProgressReporter::SolverCallback(const std::string & stage)
{
  return [this, stage](int step, double fraction, double estimatedError) {
    Report(stage, fraction, { { "step", static_cast<double>(step) }, { "estimated_error", estimatedError } });
  };
}

FrameCallback
ProgressReporter::FrameForwarder(py::object frames)
{
  if (frames.is_none())
  {
    return {};
  }
  m_Frames = std::move(frames);
  return [this](const SolveFrame & frame) {
    if (m_Error)
    {
      throw CallbackInterrupted{};
    }
    py::gil_scoped_acquire acquire;
    try
    {
      m_Frames(frame.time, frame.step, ArrayFromPoints(frame.displacements), frame.strainEnergy, frame.kineticEnergy);
    }
    catch (py::error_already_set & error)
    {
      m_Error = std::make_unique<py::error_already_set>(std::move(error));
      throw CallbackInterrupted{};
    }
  };
}

void
ProgressReporter::Rethrow()
{
  if (m_Error)
  {
    throw * m_Error;
  }
  throw std::runtime_error("a progress callback stopped the computation");
}

} // namespace bmr::python
