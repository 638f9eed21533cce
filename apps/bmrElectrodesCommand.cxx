// biomech electrodes: electrode contacts from an intraoperative CT, carried
// into the preoperative MRI and projected onto its brain surface, as the
// sparse displacements `biomech register --sparse-displacements` takes
// (bmrElectrodes.h; docs/registration.md, "Electrodes from CT").
#include "bmrImageCommands.h"

// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkBiomechanicalTransformIO.h"

#include "bmrCommandSupport.h"
#include "bmrElectrodes.h"

#include "bmrMeshIO.h"

#include <nlohmann/json.hpp>

#include <filesystem>
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

struct ElectrodesOptions
{
  std::string                   ct;
  std::string                   mri;
  std::string                   mask;
  std::string                   output;
  ElectrodeLocalisationSettings settings;
  std::vector<double>           projectAlong;
  bool                          quiet = false;
};

int
RunElectrodes(ElectrodesOptions options)
{
  if (!options.projectAlong.empty())
  {
    options.settings.projectionDirection = Vector3(options.projectAlong[0], options.projectAlong[1], options.projectAlong[2]);
  }
  StepTimer                           timer(!options.quiet);
  const RegistrationImage::Pointer    ct = timer.Run("read", [&] { return ReadImage<RegistrationImage>(options.ct, "CT"); });
  const RegistrationImage::Pointer    mri = ReadImage<RegistrationImage>(options.mri, "preoperative MRI");
  std::vector<std::string>            warnings;
  const RegistrationLabelImage::Pointer mask = timer.Run("brain-mask", [&] {
    return options.mask.empty() ? AtlasBrainMask(mri) : ReadMaskImage(options.mask, "brain mask");
  });
  const ContactSurface surface = timer.Run("surface", [&] { return ElectrodeReferenceSurface(mask, &warnings); });
  const ElectrodeLocalisation located =
    timer.Run("electrodes", [&] { return LocateElectrodes(ct, mri, surface, options.settings); });
  warnings.insert(warnings.end(), located.warnings.begin(), located.warnings.end());

  const fs::path output(options.output);
  CreateFolder(output);
  std::error_code ignored;
  fs::remove(output / "electrodes-report.json", ignored); // the report is written last: its presence means success
  std::ostringstream contacts;
  contacts << "contact,ct_x,ct_y,ct_z,x,y,z,volume_mm3\n";
  for (std::size_t k = 0; k < located.contacts.size(); ++k)
  {
    const Vector3 & inCt = located.contactsInCt[k].position;
    const Vector3 & inMri = located.contacts[k];
    contacts << k << "," << inCt.x() << "," << inCt.y() << "," << inCt.z() << "," << inMri.x() << "," << inMri.y()
             << "," << inMri.z() << "," << located.contactsInCt[k].volume << "\n";
  }
  WriteTextFileAtomically((output / "contacts.csv").string(), contacts.str());
  WriteSparseDisplacements((output / "sparse-displacements.csv").string(), located.loads);
  itk::WriteBiomechanicalTransform(located.alignment.ctToMri, (output / "ct-to-mri.tfm").string());

  double largest = 0.0;
  for (const Vector3 & u : located.loads.displacements)
  {
    largest = std::max(largest, u.norm());
  }
  json report = { { "ct", options.ct },
                  { "mri", options.mri },
                  { "mask", options.mask.empty() ? "atlas" : options.mask },
                  { "contacts", located.contacts.size() },
                  { "projection", options.settings.projectionDirection ? "along a direction" : "closest point" },
                  { "largest_displacement_mm", largest },
                  { "alignment", { { "metric", located.alignment.metricValue },
                                   { "iterations_last_level", located.alignment.iterations },
                                   { "seconds", located.alignment.seconds } } },
                  { "warnings", warnings },
                  { "seconds", timer.Json() } };
  WriteTextFileAtomically((output / "electrodes-report.json").string(), report.dump(2) + "\n");
  for (const std::string & warning : warnings)
  {
    std::cerr << "biomech: warning: " << warning << "\n";
  }
  if (!options.quiet)
  {
    std::cout << located.contacts.size() << " contacts; largest displacement " << largest << " mm; wrote "
              << (output / "sparse-displacements.csv").string() << "\n";
  }
  return 0;
}

} // namespace

std::function<int()>
AddElectrodesCommand(CLI::App & app)
{
  auto       options = std::make_shared<ElectrodesOptions>();
  CLI::App * command = app.add_subcommand(
    "electrodes", "Electrode contacts from an intraoperative CT as sparse displacements of the preoperative brain "
                  "surface (for register --sparse-displacements)");
  command->add_option("ct", options->ct, "Intraoperative CT with the electrode grid (Hounsfield units)")->required();
  command->add_option("mri", options->mri, "Preoperative MRI (T1)")->required();
  command->add_option("--mask", options->mask, "Brain mask of the MRI (voxels > 0; default: atlas skull stripping)");
  command->add_option("--contacts", options->settings.detection.expectedContacts,
                      "Number of contacts expected (0: any); another count is an error")
    ->check(CLI::NonNegativeNumber);
  command->add_option("--threshold", options->settings.detection.threshold, "Metal threshold (HU)")
    ->capture_default_str();
  command->add_option("--contact-volume", options->settings.detection.minimumVolume,
                      "Smallest metal volume of a contact (mm^3)")
    ->check(CLI::NonNegativeNumber)
    ->capture_default_str();
  command->add_option("--max-contact-volume", options->settings.detection.maximumVolume,
                      "Largest metal volume of a contact (mm^3)")
    ->check(CLI::PositiveNumber)
    ->capture_default_str();
  command->add_option("--project-along", options->projectAlong,
                      "Find each contact's preoperative place along this direction X Y Z in the MRI's space (e.g. "
                      "gravity's, along which the brain sank); default: the closest point of the surface")
    ->expected(3);
  command->add_option("-o,--output", options->output, "Output folder")->required();
  command->add_flag("--quiet,-q", options->quiet, "Print nothing but warnings and errors");
  return [=]() -> int { return command->parsed() ? RunElectrodes(*options) : -1; };
}

} // namespace app
} // namespace bmr
