// Fuzzy c-means (Bezdek 1981) on voxel intensities. Written here rather than
// taken from ITK: ITK's Statistics module has k-means but no fuzzy c-means,
// and the core must not depend on ITK.
#include "bmrFuzzyCMeans.h"
#include "bmrThreads.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace bmr
{
namespace
{

void
CheckSettings(const FuzzyCMeansSettings & settings)
{
  if (settings.classes < 2)
  {
    std::ostringstream text;
    text << "fuzzy c-means: " << settings.classes
         << " classes requested; at least 2 classes are needed (2: CSF and parenchyma, 3: CSF, grey and white matter)";
    throw Error(text.str());
  }
  if (!(settings.fuzziness > 1.0) || !std::isfinite(settings.fuzziness))
  {
    std::ostringstream text;
    text << "fuzzy c-means: fuzziness m = " << settings.fuzziness
         << " is out of range; it must be a finite number above 1 (2 is the usual choice)";
    throw Error(text.str());
  }
  if (!(settings.tolerance > 0.0))
  {
    std::ostringstream text;
    text << "fuzzy c-means: tolerance " << settings.tolerance << " must be positive (default 1e-5)";
    throw Error(text.str());
  }
  if (settings.maxIterations < 1)
  {
    std::ostringstream text;
    text << "fuzzy c-means: maxIterations " << settings.maxIterations << " must be at least 1 (default 300)";
    throw Error(text.str());
  }
}

/** Memberships of x in classes with centres c[0..K). Computed as ratios to the
 *  nearest centre so that no power over- or underflows for any m. */
inline void
ComputeMemberships(double x, const double * centres, int classes, double exponent, double * u)
{
  int    nearest = 0;
  double nearestDistance = std::abs(x - centres[0]);
  for (int k = 1; k < classes; ++k)
  {
    const double d = std::abs(x - centres[k]);
    if (d < nearestDistance)
    {
      nearestDistance = d;
      nearest = k;
    }
  }
  if (nearestDistance == 0.0)
  {
    for (int k = 0; k < classes; ++k)
    {
      u[k] = k == nearest ? 1.0 : 0.0;
    }
    return;
  }
  double sum = 0.0;
  for (int k = 0; k < classes; ++k)
  {
    const double ratio = nearestDistance / std::abs(x - centres[k]); // in (0, 1]
    const double a = exponent == 2.0 ? ratio * ratio : std::pow(ratio, exponent);
    u[k] = a;
    sum += a;
  }
  for (int k = 0; k < classes; ++k)
  {
    u[k] /= sum;
  }
}

// Distinct sample values with their counts, ascending.
struct WeightedValues
{
  std::vector<double> values;
  std::vector<double> counts;
};

FuzzyCMeansResult
Fit(const std::vector<float> &            samples,
    const FuzzyCMeansSettings &           settings,
    const std::function<void(double)> &   progress, // fraction of the iteration limit
    WeightedValues *                      distinctOut = nullptr)
{
  CheckSettings(settings);
  if (samples.empty())
  {
    throw Error("fuzzy c-means: no samples to classify; give an image (and a mask) with voxels inside");
  }
  for (std::size_t n = 0; n < samples.size(); ++n)
  {
    if (!std::isfinite(samples[n]))
    {
      std::ostringstream text;
      text << "fuzzy c-means: sample " << n << " is " << samples[n]
           << " (NaN or infinite); replace non-finite intensities or mask them out";
      throw Error(text.str());
    }
  }
  const int classes = settings.classes;

  std::vector<float> sorted(samples);
  std::sort(sorted.begin(), sorted.end());
  WeightedValues data;
  for (std::size_t n = 0; n < sorted.size();)
  {
    std::size_t end = n + 1;
    while (end < sorted.size() && sorted[end] == sorted[n])
    {
      ++end;
    }
    data.values.push_back(sorted[n]);
    data.counts.push_back(static_cast<double>(end - n));
    n = end;
  }
  const std::size_t distinct = data.values.size();
  if (distinct < static_cast<std::size_t>(classes))
  {
    std::ostringstream text;
    text << "fuzzy c-means: " << classes << " classes requested but the image has only " << distinct
         << " distinct intensities inside the mask; ask for at most " << distinct << " classes";
    throw Error(text.str());
  }

  // Deterministic initialisation: the (k + 0.5) / K quantiles of the samples;
  // if some coincide (many equal samples), the quantiles of the distinct values,
  // which differ because there are at least K of them.
  std::vector<double> centres(classes);
  for (int k = 0; k < classes; ++k)
  {
    const auto at = std::min(sorted.size() - 1,
                             static_cast<std::size_t>((k + 0.5) / classes * static_cast<double>(sorted.size())));
    centres[k] = sorted[at];
  }
  if (std::adjacent_find(centres.begin(), centres.end()) != centres.end())
  {
    for (int k = 0; k < classes; ++k)
    {
      const auto at = std::min(distinct - 1, static_cast<std::size_t>((k + 0.5) / classes * static_cast<double>(distinct)));
      centres[k] = data.values[at];
    }
  }
  sorted.clear();
  sorted.shrink_to_fit();

  const double range = data.values.back() - data.values.front();
  const double exponent = 2.0 / (settings.fuzziness - 1.0);
  const double m = settings.fuzziness;

  // Fixed blocks, each summed serially, then the blocks summed in order: the
  // same floating-point operations for any thread count.
  constexpr std::size_t blockSize = 4096;
  const std::size_t     blocks = (distinct + blockSize - 1) / blockSize;
  std::vector<double>   partial(blocks * 2 * classes);

  FuzzyCMeansResult result;
  for (int iteration = 1; iteration <= settings.maxIterations; ++iteration)
  {
#pragma omp parallel for schedule(static) num_threads(ThreadCount(settings.threads)) if (blocks > 1)
    for (std::ptrdiff_t b = 0; b < static_cast<std::ptrdiff_t>(blocks); ++b)
    {
      double *          weightSum = &partial[b * 2 * classes];
      double *          valueSum = weightSum + classes;
      std::vector<double> u(classes);
      std::fill(weightSum, weightSum + 2 * classes, 0.0);
      const std::size_t end = std::min(distinct, (b + 1) * blockSize);
      for (std::size_t n = b * blockSize; n < end; ++n)
      {
        ComputeMemberships(data.values[n], centres.data(), classes, exponent, u.data());
        for (int k = 0; k < classes; ++k)
        {
          const double w = data.counts[n] * (m == 2.0 ? u[k] * u[k] : std::pow(u[k], m));
          weightSum[k] += w;
          valueSum[k] += w * data.values[n];
        }
      }
    }
    std::vector<double> weightSum(classes, 0.0), valueSum(classes, 0.0);
    for (std::size_t b = 0; b < blocks; ++b)
    {
      for (int k = 0; k < classes; ++k)
      {
        weightSum[k] += partial[b * 2 * classes + k];
        valueSum[k] += partial[b * 2 * classes + classes + k];
      }
    }
    double change = 0.0;
    for (int k = 0; k < classes; ++k)
    {
      // A class with no weight (impossible while centres are distinct) keeps its centre.
      const double updated = weightSum[k] > 0.0 ? valueSum[k] / weightSum[k] : centres[k];
      change = std::max(change, std::abs(updated - centres[k]) / range);
      centres[k] = updated;
    }
    result.iterations = iteration;
    result.lastChange = change;
    if (progress)
    {
      progress(static_cast<double>(iteration) / settings.maxIterations);
    }
    if (change < settings.tolerance)
    {
      result.converged = true;
      break;
    }
  }
  std::sort(centres.begin(), centres.end());
  result.centroids = centres;
  if (distinctOut)
  {
    *distinctOut = std::move(data);
  }
  return result;
}

std::string
VoxelText(const ImageGeometry & geometry, std::size_t offset)
{
  const std::size_t nx = geometry.size[0], ny = geometry.size[1];
  std::ostringstream text;
  text << "(" << offset % nx << ", " << (offset / nx) % ny << ", " << offset / (nx * ny) << ")";
  return text.str();
}

} // namespace

FuzzyCMeansResult
FitFuzzyCMeans(const std::vector<float> & samples, const FuzzyCMeansSettings & settings)
{
  return Fit(samples, settings, {});
}

void
FuzzyMemberships(double value, const std::vector<double> & centroids, double fuzziness, float * out)
{
  const int           classes = static_cast<int>(centroids.size());
  std::vector<double> u(classes);
  ComputeMemberships(value, centroids.data(), classes, 2.0 / (fuzziness - 1.0), u.data());
  for (int k = 0; k < classes; ++k)
  {
    out[k] = static_cast<float>(u[k]);
  }
}

TissueClassification
ClassifyTissue(const ScalarVolume &                 intensities,
               const LabelVolume *                  mask,
               const FuzzyCMeansSettings &          settings,
               const std::function<void(double)> & progress,
               std::vector<std::string> *           warnings)
{
  CheckSettings(settings);
  if (settings.classes > 255)
  {
    throw Error("tissue classification: " + std::to_string(settings.classes) +
                " classes requested; the label map holds at most 255 classes");
  }
  const ImageGeometry & geometry = intensities.geometry;
  const std::size_t     voxels = geometry.VoxelCount();
  if (voxels == 0 || intensities.values.size() != voxels * static_cast<std::size_t>(intensities.components))
  {
    std::ostringstream text;
    text << "tissue classification: the intensity image (" << geometry.Describe() << ") holds "
         << intensities.values.size() << " values; give a non-empty image with one value per voxel";
    throw Error(text.str());
  }
  if (intensities.components != 1)
  {
    std::ostringstream text;
    text << "tissue classification: the intensity image has " << intensities.components
         << " components per voxel; give a scalar (single-component) MRI";
    throw Error(text.str());
  }
  if (mask)
  {
    if (mask->geometry.VoxelCount() == 0 || mask->values.empty())
    {
      throw Error("tissue classification: the mask is empty (no voxels); give a brain mask on the image grid, or no "
                  "mask to classify every voxel");
    }
    if (!mask->geometry.SameGridAs(geometry) || mask->values.size() != voxels)
    {
      throw Error("tissue classification: the mask is not on the image grid: mask " + mask->geometry.Describe() +
                  ", image " + geometry.Describe() + "; resample the mask onto the image grid");
    }
  }
  auto inside = [&](std::size_t n) { return mask == nullptr || mask->values[n] != 0; };

  std::vector<float> samples;
  samples.reserve(mask ? voxels / 2 : voxels);
  for (std::size_t n = 0; n < voxels; ++n)
  {
    if (!inside(n))
    {
      continue;
    }
    const float value = intensities.values[n];
    if (!std::isfinite(value))
    {
      std::ostringstream text;
      text << "tissue classification: intensity " << value << " (NaN or infinite) at voxel index "
           << VoxelText(geometry, n) << " inside the mask; replace non-finite intensities or exclude them with the mask";
      throw Error(text.str());
    }
    samples.push_back(value);
  }
  if (samples.empty())
  {
    throw Error("tissue classification: the mask is all background (no non-zero voxel, " + geometry.Describe() +
                "); give a mask whose brain voxels are non-zero");
  }

  // Progress: fitting takes at most the first half, the memberships the rest.
  auto report = [&](double fraction) {
    if (progress)
    {
      progress(fraction);
    }
  };
  report(0.0);
  TissueClassification classification;
  classification.fit = Fit(samples, settings, [&](double fraction) { report(0.5 * fraction); });
  samples.clear();
  samples.shrink_to_fit();
  if (!classification.fit.converged && warnings)
  {
    std::ostringstream text;
    text << "tissue classification: fuzzy c-means did not converge in " << classification.fit.iterations
         << " iterations (last relative centroid change " << classification.fit.lastChange << ", tolerance "
         << settings.tolerance << "); raise maxIterations or the tolerance";
    warnings->push_back(text.str());
  }
  report(0.5);

  const int classes = settings.classes;
  classification.memberships.geometry = geometry;
  classification.memberships.components = classes;
  classification.memberships.values.assign(voxels * classes, 0.0f);
  classification.labels.geometry = geometry;
  classification.labels.components = 1;
  classification.labels.values.assign(voxels, 0);

  const std::vector<double> & centres = classification.fit.centroids;
  const double                exponent = 2.0 / (settings.fuzziness - 1.0);
  // Chunks run one after another (progress between them), voxels of a chunk in
  // parallel; every voxel is independent, so threads do not change results.
  constexpr int chunks = 16;
  for (int chunk = 0; chunk < chunks; ++chunk)
  {
    const std::ptrdiff_t first = static_cast<std::ptrdiff_t>(voxels * chunk / chunks);
    const std::ptrdiff_t last = static_cast<std::ptrdiff_t>(voxels * (chunk + 1) / chunks);
#pragma omp parallel num_threads(ThreadCount(settings.threads))
    {
      std::vector<double> u(classes);
#pragma omp for schedule(static)
      for (std::ptrdiff_t n = first; n < last; ++n)
      {
        if (!inside(static_cast<std::size_t>(n)))
        {
          continue;
        }
        ComputeMemberships(intensities.values[n], centres.data(), classes, exponent, u.data());
        float * out = &classification.memberships.values[static_cast<std::size_t>(n) * classes];
        int     best = 0;
        for (int k = 0; k < classes; ++k)
        {
          out[k] = static_cast<float>(u[k]);
          if (u[k] > u[best])
          {
            best = k;
          }
        }
        classification.labels.values[n] = static_cast<std::uint8_t>(best + 1);
      }
    }
    report(0.5 + 0.5 * (chunk + 1) / chunks);
  }
  return classification;
}

std::string
TissueContrastName(TissueContrast contrast)
{
  switch (contrast)
  {
    case TissueContrast::T1:
      return "t1";
    case TissueContrast::T2:
      return "t2";
    case TissueContrast::Auto:
      break;
  }
  return "auto";
}

TissueContrast
ParseTissueContrast(const std::string & name)
{
  for (const TissueContrast contrast : { TissueContrast::Auto, TissueContrast::T1, TissueContrast::T2 })
  {
    if (name == TissueContrastName(contrast))
    {
      return contrast;
    }
  }
  throw Error("unknown contrast '" + name + "': give t1 (CSF darkest), t2 (CSF brightest) or auto");
}

std::vector<double>
ClassVolumes(const LabelVolume & labels, int classes)
{
  std::vector<double> volumes(static_cast<std::size_t>(std::max(classes, 0)), 0.0);
  for (const std::uint8_t label : labels.values)
  {
    if (label >= 1 && label <= classes)
    {
      volumes[label - 1] += 1.0;
    }
  }
  for (double & volume : volumes)
  {
    volume *= labels.geometry.VoxelVolume();
  }
  return volumes;
}

CsfClassChoice
ChooseCsfClass(const std::vector<double> & centroids, const std::vector<double> & classVolumes, TissueContrast contrast)
{
  const int classes = static_cast<int>(centroids.size());
  if (classes < 2 || classVolumes.size() != centroids.size())
  {
    throw Error("ChooseCsfClass: " + std::to_string(classes) + " centroids and " +
                std::to_string(classVolumes.size()) + " class volumes; give one volume per class, at least 2 classes");
  }
  CsfClassChoice choice;
  if (contrast != TissueContrast::Auto)
  {
    choice.contrast = contrast;
    choice.csfClass = contrast == TissueContrast::T1 ? 0 : classes - 1;
    choice.reason = "given";
    return choice;
  }
  const int          last = classes - 1;
  std::ostringstream cues;
  cues << "end classes' volumes " << classVolumes[0] << " (darkest) and " << classVolumes[last]
       << " (brightest); their gaps to the next class " << centroids[1] - centroids[0] << " and "
       << centroids[last] - centroids[last - 1];
  if (classes < 3)
  {
    throw Error("cannot tell the image's contrast from 2 tissue classes (" + cues.str() +
                "): give the contrast (--contrast t1 or t2), or classify into 3 classes");
  }
  const bool darkBySize = classVolumes[0] < classVolumes[last];
  const bool darkByGap = centroids[1] - centroids[0] > centroids[last] - centroids[last - 1];
  if (darkBySize != darkByGap)
  {
    throw Error("cannot tell whether the CSF is the darkest or the brightest tissue class: " + cues.str() +
                " point different ways; give the contrast (--contrast t1 if the CSF is dark, t2 if it is bright)");
  }
  choice.contrast = darkBySize ? TissueContrast::T1 : TissueContrast::T2;
  choice.csfClass = darkBySize ? 0 : last;
  choice.reason = "auto: " + cues.str();
  return choice;
}

} // namespace bmr
