// Colin27 from Debian's mricron-data for the tests that run the pipeline on a
// real brain: where it lies, whether it is installed, and the image and its
// brain mask read once per test program.
#ifndef bmrColin27_h
#define bmrColin27_h

#include "bmrBrainShiftRegistration.h"
#include "itkBiomechanicalImageIO.h"

#include <filesystem>

namespace bmr_test
{

inline const std::filesystem::path Colin27Folder("/usr/share/mricron/templates");

inline bool
HaveColin27()
{
  return std::filesystem::exists(Colin27Folder / "ch2.nii.gz") &&
         std::filesystem::exists(Colin27Folder / "ch2bet.nii.gz");
}

/** Colin27, read once for all tests. */
struct Colin27
{
  bmr::RegistrationImage::Pointer      image;
  bmr::RegistrationLabelImage::Pointer mask;

  static const Colin27 & Get()
  {
    static const Colin27 data = [] {
      Colin27 colin;
      colin.image = itk::ReadBiomechanicalImage<bmr::RegistrationImage>((Colin27Folder / "ch2.nii.gz").string(), "Colin27");
      colin.mask = bmr::ThresholdMask(
        itk::ReadBiomechanicalImage<bmr::RegistrationImage>((Colin27Folder / "ch2bet.nii.gz").string(), "mask"));
      return colin;
    }();
    return data;
  }
};

} // namespace bmr_test

#endif
