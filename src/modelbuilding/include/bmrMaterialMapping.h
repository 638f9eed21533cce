// Material properties of a model's cells and meshless integration points from
// tissue-class memberships (fuzzy c-means, bmrFuzzyCMeans.h) or from a hard
// label map. After Zhang, Joldes, Wittek and Miller, "Patient-specific
// computational biomechanics of the brain without segmentation and meshing",
// IJNMBE 2013: the properties at a point mix the class values by membership.
// Plain C++17, no ITK.
#ifndef bmrMaterialMapping_h
#define bmrMaterialMapping_h

#include "bmrImageVolume.h"
#include "bmrModel.h"

#include <map>
#include <string>
#include <vector>

namespace bmr
{

/** Brain parenchyma (grey or white matter): E = 3000 Pa, nu = 0.49, 1000 kg/m^3. */
Material
ParenchymaMaterial();
/** Ventricles and CSF: E = 10 Pa, nu = 0.1, 1000 kg/m^3. */
Material
CsfMaterial();
/** Tumour, twice as stiff as parenchyma: E = 6000 Pa, nu = 0.49, 1000 kg/m^3. */
Material
TumourMaterial();

/** Materials of fuzzy c-means classes ordered by ascending centroid on a T1
 *  image, where the darkest class is CSF: class 0 `csf` (default CsfMaterial(),
 *  name "csf"), every other class `parenchyma` (default ParenchymaMaterial(),
 *  name "parenchyma"; grey and white matter share the parenchyma values in the
 *  literature). K = 2: [csf, parenchyma]; K = 3: [csf, parenchyma (grey),
 *  parenchyma (white)]. Throws bmr::Error for classes < 1. */
std::vector<Material>
DefaultClassMaterials(int classes, const Material & csf = CsfMaterial(),
                      const Material & parenchyma = ParenchymaMaterial());

/** How a cell or integration point samples the image. */
struct MaterialSampling
{
  /** Sample spacing = smallest voxel spacing / samplesPerVoxel (> 0); a cell
   *  gets at least one sample per spacing^3 of its volume. Hexahedra: an
   *  n_r x n_s x n_t grid of parametric midpoints weighted by the Jacobian,
   *  n_d = floor(longest edge along d / spacing) + 1. Tetrahedra: the
   *  centroids of their regular subdivision into n^3 sub-tetrahedra of equal
   *  volume, n = floor(cbrt(volume) / spacing) + 1. Both rules are exact for
   *  linear fields (on parallelepipeds and tetrahedra). At most 32 per direction. */
  double samplesPerVoxel = 1.0;
  /** Meshless integration points: edge (mm) of the axis-aligned cube centred
   *  at the point over which the image is averaged (n = floor(edge / spacing)
   *  + 1 midpoints per direction). 0: cbrt(w), w the point's weight (mm^3):
   *  the volume the point stands for, so the cubes of the points of an
   *  integration cell fill it (for 2 x 2 x 2 Gauss points, 1/8 of the cell),
   *  and adaptive (subdivided) cells get proportionally smaller neighbourhoods. */
  double neighbourhoodSize = 0.0;
  /** OpenMP threads; 0: OpenMP's default. Results do not depend on it. */
  int threads = 0;
};

struct MaterialMappingSettings
{
  /** One material per class (ascending centroid); empty: DefaultClassMaterials(K). */
  std::vector<Material> classMaterials;
  /** The CSF's class (ascending centroid; bmr::ChooseCsfClass): the fluid
   *  that fills a resection. 0 on a T1 image, the last class on a T2 one. */
  int csfClass = 0;
  /** Material of the voxels of the tumour mask (full membership there). */
  Material         tumour = TumourMaterial();
  MaterialSampling sampling;
};

/** The CSF class's material of these settings: the first class material
 *  (ascending centroid), or CsfMaterial() when the classes take the defaults. */
Material
CsfClassMaterial(const MaterialMappingSettings & settings);

/** Sets model.materials and each cell's material (and, for a meshless model,
 *  model.meshless.integrationMaterials) from a membership image (components =
 *  classes, 0 outside the mask, as ClassifyTissue writes it).
 *
 *  Per cell (or integration point) the memberships are averaged over the cell
 *  (or the point's neighbourhood cube, see MaterialSampling) with trilinear
 *  interpolation of the membership image; voxels of `tumourMask` (same grid,
 *  non-zero = tumour) count as membership 1 in an extra tumour class, and
 *  voxels of `resectionMask` (same grid, non-zero = tissue removed by the
 *  surgery, e.g. the planned resection) as membership 1 in the CSF's class
 *  (settings.csfClass), whose fluid fills the cavity (they override the tumour). Samples
 *  outside the image or the mask contribute nothing: the average is
 *  sum(u) / sum(sum_k u_k) over the samples, so it sums to 1. A cell with no
 *  sample inside the mask takes the memberships of the mask voxel nearest its
 *  centroid (reported in `warnings`).
 *
 *  Mixture (a choice, documented): E = sum_k u_k E_k, nu = sum_k u_k nu_k,
 *  rho = sum_k u_k rho_k, the rule of mixtures of Zhang et al. 2013. A cell
 *  whose weight lies entirely on classes with one set of values gets exactly
 *  those values and that class's name (the first such class); otherwise the
 *  material is named "mix(E=1234.5,nu=0.41)" and its values are rounded to 9
 *  significant digits (so that equal mixtures share an entry). Identical (E, nu, rho) triples
 *  share one entry of model.materials, in order of first use (cells, then
 *  integration points). Deterministic for any thread count.
 *
 *  Throws bmr::Error for: a model without cells (finite elements) or without
 *  integration points (meshless); an empty membership image or one with a
 *  negative or non-finite membership; classMaterials
 *  whose count differs from the image's components; a tumour or resection
 *  mask on another grid; a membership image with no voxel inside the mask; a cell or point
 *  entirely outside the image (the model is not in the image's physical space).
 *
 *  Records the classes and each site's shares in model.tissueMixture. */
void
MapMaterialsFromMemberships(Model &                         model,
                            const ScalarVolume &            memberships,
                            const MaterialMappingSettings & settings = {},
                            const LabelVolume *             tumourMask = nullptr,
                            std::vector<std::string> *      warnings = nullptr,
                            const LabelVolume *             resectionMask = nullptr);

/** The model's materials mixed again from its tissue mixture (which
 *  MapMaterialsFromMemberships records: Model::tissueMixture) with each
 *  class's Young's modulus scaled by its factor (one per class, the tumour
 *  last), as MapMaterialsFromMemberships mixes them: factors of 1 give its
 *  materials bit for bit. The mixture itself stays the nominal one. Throws
 *  bmr::Error for a model without a mixture, a factor count or a shares'
 *  size that does not fit, or a factor that is not positive. */
void
RemixTissueModuli(Model & model, const std::vector<double> & factors, int threads = 0);

/** Sets the same outputs from a hard label map: each cell (or integration
 *  point) takes the material of the label covering most of its samples
 *  (nearest-voxel lookup; the smaller label wins a tie). Label 0 is background
 *  and ignored unless materialOfLabel has an entry for it. A cell with no
 *  labelled sample takes the label of the labelled voxel nearest its centroid
 *  (reported in `warnings`). Materials with an empty name are named "label N".
 *  Throws bmr::Error for a label met by the model's samples that has no
 *  material (names the labels), an image without labelled voxels, and a cell
 *  or point entirely outside the image. */
void
MapMaterialsFromLabels(Model &                          model,
                       const LabelVolume &              labels,
                       const std::map<int, Material> &  materialOfLabel,
                       const MaterialSampling &         sampling = {},
                       std::vector<std::string> *       warnings = nullptr);

} // namespace bmr

#endif
