// Electrodes from an intraoperative CT: the epilepsy workflow. A subdural
// grid of electrode contacts lies on the shifted brain; the CT after
// implantation shows the contacts (metal, far brighter than bone) and the
// skull, but the brain hardly. The contacts are found in the CT, carried into
// the preoperative MRI's space by a rigid registration of the CT to the MRI
// (mutual information: the skull does not move) and projected onto the
// undeformed brain surface; contact minus projection is a sparse
// displacement that loads the registration's model
// (IntraoperativeData::sparse, or `biomech register --sparse-displacements`).
// The tests and the demo simulate a CT-like image with a known answer:
// bmrSyntheticElectrodeCt.h, in the evaluation library.
//
// Units: mm (physical space, LPS), Hounsfield units (HU).
#ifndef bmrElectrodes_h
#define bmrElectrodes_h
// ITK before the core: ITK's bundled Eigen must be seen before the system Eigen.
#include "itkEuler3DTransform.h"

#include "bmrBrainShiftRegistration.h"

#include <optional>
#include <string>
#include <vector>

namespace bmr
{

using RigidTransform = itk::Euler3DTransform<double>;

// ---------------------------------------------------------------------------
// Finding the contacts.
// ---------------------------------------------------------------------------

struct ElectrodeDetectionSettings
{
  /** Metal: voxels above this (HU) make a contact. Cortical bone stays below
   *  about 1,900 HU; platinum contacts saturate a CT at 3,000 HU or more. */
  double threshold = 2000.0;
  /** Soft tissue (HU): a voxel holds the fraction (value - tissue) /
   *  (peak - tissue) of metal, so partial volume places a contact between voxels. */
  double tissueLevel = 40.0;
  /** A contact's metal volume (mm^3): smaller blobs are noise, larger ones
   *  wires or several touching contacts; both are left out with a warning. */
  double minimumVolume = 1.0;
  double maximumVolume = 60.0;
  /** The number of contacts expected (0: any); another count is an error naming both. */
  int expectedContacts = 0;
};

struct ElectrodeContact
{
  Vector3 position;     // mm, physical space of the CT
  double  volume = 0.0; // mm^3 of metal
};

/** The contacts of a CT: connected components (26-neighbourhood) of the
 *  voxels above the threshold, each at the centroid of the metal fraction of
 *  its voxels and their neighbours, in raster order of the CT. Throws
 *  bmr::Error: no image, no voxel above the threshold, no blob of a
 *  contact's volume, a count other than the expected one; blobs of another
 *  volume are named in `warnings`. */
std::vector<ElectrodeContact>
DetectElectrodeContacts(const RegistrationImage *          ct,
                        const ElectrodeDetectionSettings & settings,
                        std::vector<std::string> *         warnings = nullptr);

// ---------------------------------------------------------------------------
// CT to MRI.
// ---------------------------------------------------------------------------

struct RigidAlignmentSettings
{
  unsigned int              histogramBins = 32;
  std::vector<unsigned int> shrinkFactors{ 4, 2, 1 };
  std::vector<double>       smoothingSigmas{ 2.0, 1.0, 0.0 }; // mm
  unsigned int              iterations = 100;                 // per level
  /** Metric samples per level (random, seeded): at most this many. */
  unsigned int maximumSamples = 100000;
  /** CT values are clipped to [-1000, this] HU for the metric: metal would
   *  otherwise take histogram bins the MRI has nothing to match with. */
  double metalClip = 1500.0;
  int    randomSeed = 1;
};

struct RigidAlignment
{
  RigidTransform::Pointer ctToMri; // CT point -> MRI point
  double                  metricValue = 0.0;
  unsigned int            iterations = 0; // of the last level
  double                  seconds = 0.0;
};

/** Rigid registration of a CT (fixed) to an MRI (moving) of the same head by
 *  Mattes mutual information (itk::ImageRegistrationMethodv4, Euler angles
 *  and translation, regular-step gradient descent, physical-shift scales),
 *  started with the heads' centroids aligned (CT above -500 HU, MRI above a
 *  fifth of its 99th intensity percentile). Repeats bitwise for any thread
 *  count. Throws bmr::Error. */
RigidAlignment
AlignCtToMri(const RegistrationImage * ct, const RegistrationImage * mri, const RigidAlignmentSettings & settings = {});

// ---------------------------------------------------------------------------
// The whole localisation.
// ---------------------------------------------------------------------------

struct ElectrodeLocalisationSettings
{
  ElectrodeDetectionSettings detection;
  RigidAlignmentSettings     alignment;
  /** How a contact finds its place on the undeformed brain surface (MRI
   *  space): empty, the closest point (the literature's projection; motion
   *  along the surface is lost); a direction, e.g. gravity's in the MRI's
   *  space when the brain sank along it, the surface's nearest intersection
   *  with the line through the contact along it. */
  std::optional<Vector3> projectionDirection;
};

struct ElectrodeLocalisation
{
  std::vector<ElectrodeContact> contactsInCt;
  std::vector<Vector3>          contacts; // MRI space: where the contacts lie on the shifted brain
  RigidAlignment                alignment;
  /** The registration's load: each contact's closest point on the undeformed
   *  brain surface and the displacement from there to the contact. */
  SparseDisplacements      loads;
  std::vector<std::string> warnings;
};

/** The surface contacts are projected onto: the brain mask's own smooth
 *  surface (level 0 of BrainSurfacesOfMask), not a model's staircase one.
 *  The surface extraction's warnings are appended to `warnings` when given. */
ContactSurface
ElectrodeReferenceSurface(const RegistrationLabelImage * brainMask, std::vector<std::string> * warnings = nullptr);

/** Detects the contacts in `ct`, aligns the CT to `mri` and projects the
 *  contacts onto `preoperativeBrainSurface` (the MRI's brain surface,
 *  ElectrodeReferenceSurface). Throws bmr::Error naming the failing step. */
ElectrodeLocalisation
LocateElectrodes(const RegistrationImage *             ct,
                 const RegistrationImage *             mri,
                 const ContactSurface &                preoperativeBrainSurface,
                 const ElectrodeLocalisationSettings & settings = {});

} // namespace bmr

#endif
