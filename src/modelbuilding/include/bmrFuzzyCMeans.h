// Fuzzy c-means tissue classification of an MRI (Bezdek's fuzzy c-means on
// voxel intensities), as used by Zhang, Joldes, Wittek and Miller,
// "Patient-specific computational biomechanics of the brain without
// segmentation and meshing", IJNMBE 2013: every voxel gets a membership in
// each tissue class instead of a hard label. Plain C++17, no ITK.
#ifndef bmrFuzzyCMeans_h
#define bmrFuzzyCMeans_h

#include "bmrImageVolume.h"

#include <functional>
#include <string>
#include <vector>

namespace bmr
{

struct FuzzyCMeansSettings
{
  /** Number of classes K (>= 2). 2: CSF and parenchyma; 3: CSF, grey and white
   *  matter on a T1 image. */
  int classes = 2;
  /** Fuzziness exponent m (> 1); 2 is the usual choice, m -> 1 approaches k-means. */
  double fuzziness = 2.0;
  /** Convergence: the largest centroid change of an iteration, relative to the
   *  intensity range (max - min) of the classified samples, falls below this. */
  double tolerance = 1e-5;
  /** Iteration limit; reaching it leaves FuzzyCMeansResult::converged false. */
  int maxIterations = 300;
  /** OpenMP threads; 0: OpenMP's default. Results do not depend on it. */
  int threads = 0;
};

struct FuzzyCMeansResult
{
  std::vector<double> centroids; // class centres in intensity units, ascending
  int                 iterations = 0;
  bool                converged = false;
  double              lastChange = 0.0; // largest relative centroid change of the last iteration
};

/** Fits K centroids to the samples. The data are reduced exactly to their
 *  distinct values with counts (equal samples contribute identically), so an
 *  8-bit image costs 256 points per iteration. Initial centroids: the
 *  (k + 0.5) / K quantiles of the samples (of the distinct values when those
 *  coincide). Sums run over fixed blocks reduced in order: the result is the
 *  same for any thread count.
 *  Throws bmr::Error for classes < 2, fuzziness <= 1, tolerance <= 0,
 *  maxIterations < 1, a non-finite sample, or fewer distinct values than classes.
 *  Not converging within maxIterations is not an error: converged is false. */
FuzzyCMeansResult
FitFuzzyCMeans(const std::vector<float> & samples, const FuzzyCMeansSettings & settings);

/** Memberships u_k (k < centroids.size()) of an intensity value:
 *  u_k = 1 / sum_j (d_k / d_j)^(2 / (m - 1)), d_k = |value - c_k|. They sum to 1;
 *  a value equal to a centroid has membership 1 in that class. The centroids
 *  must be distinct. */
void
FuzzyMemberships(double value, const std::vector<double> & centroids, double fuzziness, float * out);

struct TissueClassification
{
  FuzzyCMeansResult fit;
  /** components = classes, class k in component k (ascending centroid); 0 outside the mask. */
  ScalarVolume memberships;
  /** 1..K: the class of largest membership (the lower class on a tie); 0 outside the mask. */
  LabelVolume labels;
};

/** Fuzzy c-means on the intensities inside the mask (voxels with a non-zero
 *  mask value; nullptr: every voxel), then the memberships and hard labels of
 *  every voxel inside it (OpenMP, deterministic). `progress` receives fractions
 *  in [0, 1] from the calling thread and ends with 1. A run that does not
 *  converge adds a warning to `warnings` (when given).
 *  Throws bmr::Error (message names the problem and what to do) for: an empty
 *  or multi-component intensity volume, a mask on another grid, an empty or
 *  all-background mask, a NaN or infinite intensity inside the mask (names the
 *  voxel index), classes < 2, fuzziness <= 1, and more classes than distinct
 *  intensities inside the mask. */
TissueClassification
ClassifyTissue(const ScalarVolume &                 intensities,
               const LabelVolume *                  mask,
               const FuzzyCMeansSettings &          settings,
               const std::function<void(double)> & progress = {},
               std::vector<std::string> *           warnings = nullptr);

/** Where the CSF lies on the image's intensity scale: darkest on a
 *  T1-weighted image, brightest on a T2-weighted one; Auto decides from the
 *  classes (ChooseCsfClass). */
enum class TissueContrast
{
  Auto,
  T1,
  T2
};

/** "auto", "t1", "t2". */
std::string
TissueContrastName(TissueContrast contrast);

/** Parses "auto", "t1", "t2"; throws bmr::Error naming the choices. */
TissueContrast
ParseTissueContrast(const std::string & name);

/** The volume (mm^3) of each class of hard labels 1..`classes` (0: outside; element k: label k + 1). */
std::vector<double>
ClassVolumes(const LabelVolume & labels, int classes);

/** The class that is the CSF, and the contrast it was chosen for. */
struct CsfClassChoice
{
  TissueContrast contrast = TissueContrast::T1; // T1 or T2, never Auto
  int            csfClass = 0;                  // index in ascending centroid order
  /** Why (Auto: both cues, with their numbers; else "given"). */
  std::string reason;
};

/** The CSF class of a classification whose classes are in ascending centroid
 *  order with `classVolumes` (any unit): for T1 the darkest, for T2 the
 *  brightest. Auto (at least 3 classes) uses two cues that hold on both
 *  contrasts inside a brain mask: the CSF class is the end class of smaller
 *  volume (grey and white matter fill most of the brain), and the end class
 *  farther in intensity from its neighbour (on T1 grey matter lies nearer
 *  white matter than CSF; on T2 nearer white matter too, CSF far above). When
 *  the cues disagree, or with 2 classes, the contrast cannot be told and a
 *  bmr::Error says to give it. */
CsfClassChoice
ChooseCsfClass(const std::vector<double> & centroids, const std::vector<double> & classVolumes, TissueContrast contrast);

} // namespace bmr

#endif
