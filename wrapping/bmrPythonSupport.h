// Conversions between the module's C++ types and Python/NumPy, shared by the
// two translation units of the binding (core in bmrPythonCore.cxx, ITK layer
// in bmrPythonImages.cxx).
//
// Conventions (docs/python.md): points and vectors are (N, 3) float64 arrays
// in ITK physical space (mm, LPS); node ids are int32 arrays; images are the
// Python class biomechanical_registration.Image, whose `array` is ITK
// Python's [z, y, x] (or [z, y, x, component]) view of the voxel buffer and
// whose spacing, origin and direction are in ITK's (x, y, z) order.
#ifndef bmrPythonSupport_h
#define bmrPythonSupport_h

#include "bmrBrainSurfaces.h"
#include "bmrImageVolume.h"
#include "bmrModel.h"
#include "bmrSettingsTable.h"
#include "bmrSolver.h"
#include "bmrSurfaceLoads.h"

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <algorithm>
#include <filesystem>

#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace bmr::python
{
namespace py = pybind11;

// ---------------------------------------------------------------------------
// Arrays.
// ---------------------------------------------------------------------------

/** (N, 3) float64 array of points or vectors. */
py::array_t<double>
ArrayFromPoints(const std::vector<Vector3> & points);

/** Points from anything NumPy reads as an (N, 3) array of finite numbers; a
 *  ValueError names `what` and the shape it got. */
std::vector<Vector3>
PointsFromArray(const py::handle & object, const std::string & what);

/** Three finite numbers (a point, a vector). */
Vector3
VectorFromObject(const py::handle & object, const std::string & what);

/** The C++ code's warnings as Python RuntimeWarnings. */
inline void
WarnInPython(const std::vector<std::string> & warnings)
{
  for (const std::string & warning : warnings)
  {
    PyErr_WarnEx(PyExc_RuntimeWarning, warning.c_str(), 1);
  }
}

/** The craniotomy sphere of the keywords craniotomy_centre and
 *  craniotomy_radius (mm): none (radius 0) without a centre; a centre needs a
 *  radius > 0 (ValueError). A mask, and a sphere beside a mask, are
 *  bmr::CheckCraniotomyRegion's to judge. */
inline CraniotomyRegion
CraniotomySphereFrom(const py::handle & centre, double radius)
{
  CraniotomyRegion sphere;
  if (centre.is_none())
  {
    return sphere;
  }
  sphere.centre = VectorFromObject(centre, "craniotomy_centre");
  if (!(radius > 0.0))
  {
    throw py::value_error("craniotomy_centre needs craniotomy_radius > 0 (mm)");
  }
  sphere.radius = radius;
  return sphere;
}

py::array_t<Index>
ArrayFromIndices(const std::vector<Index> & indices);

/** Node ids from a 1-D sequence of integers (no range check: the callee does it). */
std::vector<Index>
IndicesFromArray(const py::handle & object, const std::string & what);

/** A load's report (bmr::LoadReport) as a dict: used, rejected, correspondence distances (mm), warnings. */
py::dict
LoadReportDict(const LoadReport & report);

/** Three booleans (x, y, z components). */
std::array<bool, 3>
ComponentsFromObject(const py::handle & object, const std::string & what);

// ---------------------------------------------------------------------------
// Images: biomechanical_registration.Image <-> core volumes.
// ---------------------------------------------------------------------------

/** Geometry of a Python Image; ValueError for a missing or malformed field. */
ImageGeometry
GeometryFromImage(const py::handle & image, const std::string & what);

/** Float intensities (any real dtype, cast to float32; components from a 4-D array). */
ScalarVolume
ScalarVolumeFromImage(const py::handle & image, const std::string & what);

/** Masks and label maps: uint8 or bool arrays, or integers within 0..255. */
LabelVolume
LabelVolumeFromImage(const py::handle & image, const std::string & what);

/** A Python Image of a core volume: float32 or uint8, [z, y, x] (+ components). */
py::object
ImageFromVolume(const ScalarVolume & volume);
py::object
ImageFromVolume(const LabelVolume & volume);

/** True for None. */
inline bool
IsNone(const py::handle & object)
{
  return object.is_none();
}

// ---------------------------------------------------------------------------
// Long calls: the GIL is released, progress goes to a Python callable.
// ---------------------------------------------------------------------------

/** Thrown through C++ code when the Python callback raised (or Ctrl-C was
 *  pressed); RunWithoutGil turns it back into the Python exception. */
struct CallbackInterrupted
{};

/** Forwards progress to `callback(stage, fraction, info)` (fraction in [0, 1],
 *  or -1 when unknown; info a dict of numbers). Called from the thread that
 *  runs the computation, which holds no GIL: Report takes it. A Python
 *  exception from the callback, or a pending KeyboardInterrupt, stops the
 *  computation: at once where the caller may be interrupted
 *  (CallbackInterrupted), otherwise (stage ends, reported from destructors)
 *  when the call returns. */
class ProgressReporter
{
public:
  explicit ProgressReporter(py::object callback)
    : m_Callback(std::move(callback))
  {}

  void Report(const std::string & stage, double fraction, const std::vector<std::pair<const char *, double>> & info = {},
              bool interrupt = true);

  /** The solver's callback, reporting stage `stage`. */
  ProgressCallback SolverCallback(const std::string & stage = "solve");
  /** The solver's frame callback: `frames(time, step, displacements, strain_energy, kinetic_energy)`
   *  with the displacements as an (N, 3) array; empty for None. */
  FrameCallback FrameForwarder(py::object frames);
  /** The pipeline's stage callback (start: fraction 0; end: 1 and the seconds); never throws. */
  std::function<void(const std::string &, double)> StageCallback();

  bool Failed() const { return m_Error != nullptr; }
  /** Re-raises the stored Python exception (with the GIL held). */
  [[noreturn]] void Rethrow();

private:
  py::object                              m_Callback;
  py::object                              m_Frames;
  std::unique_ptr<py::error_already_set> m_Error;
};

/** Runs `call` without the GIL; a Python exception raised in a progress
 *  callback during it is re-raised here. */
template <typename Call>
auto
RunWithoutGil(ProgressReporter & reporter, Call && call) -> decltype(call())
{
  try
  {
    auto result = [&] {
      py::gil_scoped_release release;
      return call();
    }();
    if (reporter.Failed())
    {
      reporter.Rethrow();
    }
    return result;
  }
  catch (const CallbackInterrupted &)
  {
    reporter.Rethrow();
  }
}

/** Binds files, model building and loads (bmrPythonModelBuilding.cxx). */
void
BindFiles(py::module_ & module);
void
BindModelBuilding(py::module_ & module);
void
BindLoads(py::module_ & module);

/** Binds the ITK layer (bmrPythonImages.cxx). */
void
BindImages(py::module_ & module);

/** A table row's value as Python gives it: float, int, bool, str (a choice).
 *  A value of the wrong type is a TypeError and one outside the row's range a
 *  ValueError, both naming the setting (pybind's own messages do not). */
inline double
SettingValueFromPython(const SettingFieldBase & row, const py::handle & value)
{
  using Kind = SettingFieldBase::Kind;
  const std::string name = "setting '" + row.name + "'";
  if (row.kind == Kind::Choice)
  {
    const auto found = py::isinstance<py::str>(value)
                         ? std::find(row.choices.begin(), row.choices.end(), value.cast<std::string>())
                         : row.choices.end();
    if (found == row.choices.end())
    {
      throw py::value_error(name + " must be one of " + row.Range() + ", got " + std::string(py::repr(value)));
    }
    return static_cast<double>(found - row.choices.begin());
  }
  const bool isBool = py::isinstance<py::bool_>(value);
  const bool isNumber = !isBool && (py::isinstance<py::int_>(value) || py::isinstance<py::float_>(value));
  const bool typeOk = row.kind == Kind::Flag      ? isBool
                      : row.kind == Kind::Integer ? isNumber && py::isinstance<py::int_>(value)
                                                  : isNumber;
  if (!typeOk)
  {
    throw py::type_error(name + " must be " +
                         (row.kind == Kind::Flag      ? std::string("True or False")
                          : row.kind == Kind::Integer ? std::string("an integer")
                                                      : std::string("a number")) +
                         ", got " + std::string(py::repr(value)));
  }
  const double number = isBool ? (value.cast<bool>() ? 1.0 : 0.0) : value.cast<double>();
  if (const std::string problem = row.Check(number); !problem.empty())
  {
    throw py::value_error(name + " " + problem);
  }
  return number;
}

/** A table row's value as a Python object (float, int, bool, str). */
template <typename TSettings>
py::object
SettingValueToPython(const SettingField<TSettings> & row, const TSettings & settings)
{
  using Kind = SettingFieldBase::Kind;
  switch (row.kind)
  {
    case Kind::Text:
      return py::str(row.getText(settings));
    case Kind::Choice:
      return py::str(row.Text(settings));
    case Kind::Flag:
      return py::bool_(row.get(settings) != 0.0);
    case Kind::Integer:
      return py::int_(static_cast<long long>(row.get(settings)));
    default:
      return py::float_(row.get(settings));
  }
}

} // namespace bmr::python

#endif
