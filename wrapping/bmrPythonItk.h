// What the ITK layer of the Python binding shares between its translation
// units (bmrPythonImages.cxx, bmrPythonSynthetic.cxx): images and
// transforms between Python and ITK, ITK errors as
// biomechanical_registration.Error, stage times as a dict.
#ifndef bmrPythonItk_h
#define bmrPythonItk_h

// ITK before the core: ITK's bundled Eigen must be seen before the system
// Eigen (the pipeline header includes ITK's first).
#include "bmrBrainShiftRegistration.h"

#include "itkBiomechanicalImageConversion.h"
#include "itkVectorImage.h"

#include "bmrPythonSupport.h"

namespace bmr::python
{

using TransformType = itk::Transform<double, 3, 3>;
using VectorImageType = itk::VectorImage<float, 3>;

/** A transform as Python sees it: any ITK transform of 3-D points (the
 *  registrations give B-spline backward maps: intraoperative -> preoperative). */
struct PythonTransform
{
  TransformType::ConstPointer transform;
};

inline RegistrationImage::Pointer
ItkImage(const py::handle & image, const std::string & what)
{
  return itk::MakeImageFromBiomechanicalVolume<RegistrationImage>(ScalarVolumeFromImage(image, what));
}

inline RegistrationImage::Pointer
OptionalItkImage(const py::handle & image, const std::string & what)
{
  return image.is_none() ? nullptr : ItkImage(image, what);
}

inline RegistrationLabelImage::Pointer
ItkLabelImage(const py::handle & image, const std::string & what)
{
  return image.is_none() ? nullptr
                         : itk::MakeImageFromBiomechanicalVolume<RegistrationLabelImage>(LabelVolumeFromImage(image, what));
}

inline py::object
PythonImage(const RegistrationImage * image)
{
  if (image == nullptr)
    return py::none();
  return ImageFromVolume(itk::MakeBiomechanicalVolume<float>(image));
}

inline py::object
PythonImage(const RegistrationLabelImage * image)
{
  if (image == nullptr)
    return py::none();
  return ImageFromVolume(itk::MakeBiomechanicalVolume<std::uint8_t>(image));
}

/** ITK exceptions (filters, readers, writers) become biomechanical_registration.Error with ITK's description. */
template <typename Call>
auto
TranslateItkErrors(Call && call) -> decltype(call())
{
  try
  {
    return call();
  }
  catch (const itk::ExceptionObject & exception)
  {
    throw Error(exception.GetDescription());
  }
}

inline py::dict
StageSeconds(const StageTimer & timer)
{
  py::dict seconds;
  for (const auto & [stage, value] : timer.Stages())
  {
    seconds[py::str(stage)] = value;
  }
  return seconds;
}

void
BindSyntheticScenes(py::module_ & module);

} // namespace bmr::python

#endif
