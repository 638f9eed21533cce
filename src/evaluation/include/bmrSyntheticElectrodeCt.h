// A synthetic CT with a known answer, for the electrode localisation of
// bmrElectrodes.h: a subdural grid on the brain of a synthetic brain shift
// (bmrSyntheticBrainShift.h), imaged in Hounsfield units, and the errors of a
// localisation against it. A fixture of the evaluation library (the demo, the
// tests), not of the product.
//
// Units: mm (physical space, LPS), Hounsfield units (HU).
#ifndef bmrSyntheticElectrodeCt_h
#define bmrSyntheticElectrodeCt_h

#include "bmrElectrodes.h"
#include "bmrSyntheticBrainShift.h"

namespace bmr
{

struct SyntheticElectrodeCtSettings
{
  /** The grid: rows x columns contacts `contactSpacing` apart in the plane
   *  across the ground truth's "down" through the craniotomy's centre, each
   *  dropped along "down" onto the brain mask's smooth surface (a standard
   *  subdural grid is 8 x 8 at 10 mm; it reaches under the bone beyond the
   *  opening). */
  int    rows = 8;
  int    columns = 8;
  double contactSpacing = 10.0; // mm
  /** Contacts are metal spheres of this radius (real ones: discs of 2.3 mm
   *  exposed diameter), centred on the brain surface. */
  double contactRadius = 1.25; // mm
  /** The CT's voxels (mm) and noise (HU, Gaussian). */
  Vector3 spacing = Vector3(1.0, 1.0, 1.0);
  double  noise = 10.0;
  /** Where the head lies in the CT scanner relative to the MRI: rotation
   *  (degrees about x, y, z, about the brain's centroid) and translation (mm). */
  Vector3       rotation = Vector3(3.0, -4.0, 5.0);
  Vector3       translation = Vector3(15.0, -10.0, 25.0);
  std::uint32_t seed = 1;
};

struct SyntheticElectrodeCt
{
  RegistrationImage::Pointer image;                // HU, in the CT scanner's frame
  std::vector<Vector3>       preoperativeContacts; // MRI space, on the undeformed brain surface
  std::vector<Vector3>       contacts;             // MRI space, moved by the ground truth
  RigidTransform::Pointer    mriToCt;              // MRI point -> CT point
};

/** A CT-like image of the head after the brain shift of `truth`, in
 *  Hounsfield units made from the preoperative T1: in the brain (`brainMask`
 *  > 0) 5 HU for CSF rising to 35 HU for white matter (a function of the T1
 *  intensity; a real CT's grey matter is brighter than its white matter);
 *  outside the brain but inside the head, bright T1 voxels are soft tissue
 *  (40 HU), dark ones CSF (5 HU) within 2.5 mm of the brain and bone (1,100
 *  HU) beyond; air -1000 HU. The brain is moved by the ground truth, the
 *  skull and scalp are not, and where the brain sank away there is fluid
 *  (5 HU). The head is placed in the scanner's frame by the rigid motion;
 *  the grid's contacts are metal at 3,000 HU with their partial volume; then
 *  Gaussian noise. No metal streaks or beam hardening. Throws bmr::Error. */
SyntheticElectrodeCt
MakeSyntheticElectrodeCt(const RegistrationImage *            preoperativeImage,
                         const RegistrationLabelImage *       brainMask,
                         const SyntheticBrainShift &          truth,
                         const Vector3 &                      craniotomyCentre,
                         const SyntheticElectrodeCtSettings & settings = {});

/** A localisation against the synthetic CT's truth: each found contact is
 *  matched to the nearest true one (MRI space). Detection error in the CT's
 *  frame, location error in the MRI's, and the error of the displacement
 *  each contact's projection measured (mm). */
struct ElectrodeLocalisationErrors
{
  bool   eachContactFoundOnce = false;
  double detectionMax = 0.0;
  double locationMean = 0.0, locationMax = 0.0;
  double displacementMean = 0.0, displacementMax = 0.0;
};
ElectrodeLocalisationErrors
MeasureElectrodeLocalisation(const ElectrodeLocalisation & located, const SyntheticElectrodeCt & truth);

} // namespace bmr

#endif
