#include "bmrEnsemble.h"

#include "bmrError.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace bmr
{

void
CheckEnsembleSettings(const EnsembleSettings & settings)
{
  const auto fail = [](const std::string & message) { throw Error("uncertainty: " + message); };
  if (settings.members < 2)
  {
    fail(std::to_string(settings.members) + " members; an ensemble needs at least 2 (16 is a good start)");
  }
  if (!(settings.gravityLow >= 0.0 && settings.gravityLow <= settings.gravityHigh))
  {
    std::ostringstream message;
    message << "the gravity range [" << settings.gravityLow << ", " << settings.gravityHigh
            << "] is not a range of non-negative fractions; give low <= high, e.g. 0.5 1.5";
    fail(message.str());
  }
  if (!(settings.youngsModulusSpread >= 0.0))
  {
    std::ostringstream message;
    message << "the Young's modulus spread is " << settings.youngsModulusSpread
            << "; give the standard deviation of its logarithm, 0 or more (0.3: within a factor of 1.8 at 2 sigma)";
    fail(message.str());
  }
  const bool poisson = settings.poissonLow != 0.0 || settings.poissonHigh != 0.0;
  if (poisson && !(settings.poissonLow > 0.0 && settings.poissonLow <= settings.poissonHigh && settings.poissonHigh < 0.5))
  {
    std::ostringstream message;
    message << "the Poisson's ratio range [" << settings.poissonLow << ", " << settings.poissonHigh
            << "] is not within (0, 0.5) with low <= high; give e.g. 0.45 0.499, or 0 0 to keep the model's";
    fail(message.str());
  }
  if (!(settings.tissueModulusSpread >= 0.0))
  {
    std::ostringstream message;
    message << "the tissue classes' modulus spread is " << settings.tissueModulusSpread
            << "; give the standard deviation of its logarithm, 0 or more";
    fail(message.str());
  }
  if (!(settings.skullGapSpread >= 0.0))
  {
    std::ostringstream message;
    message << "the skull gap spread is " << settings.skullGapSpread << " mm; give a standard deviation of 0 mm or more";
    fail(message.str());
  }
}

namespace
{

/** The parenchyma's Poisson's ratio the drawn offsets are measured from: the
 *  largest of the model's materials. */
double
NominalPoissonRatio(const Model & model)
{
  double largest = 0.0;
  for (const Material & material : model.materials)
  {
    largest = std::max(largest, material.poissonRatio);
  }
  return largest;
}

} // namespace

EnsembleDrawer::EnsembleDrawer(const EnsembleSettings & settings, const Model & nominal, double contactGap)
  : m_Settings(settings)
  , m_NominalPoisson(NominalPoissonRatio(nominal))
  , m_ContactGap(contactGap)
  , m_TissueClasses(nominal.tissueMixture.classes.size())
  , m_Random(settings.seed)
  , m_Gravity(settings.gravityLow, settings.gravityHigh)
  , m_Poisson(settings.poissonLow, settings.poissonHigh)
{
  CheckEnsembleSettings(settings);
  if (settings.skullGapSpread > 0.0 && !(contactGap > 0.0))
  {
    std::ostringstream message;
    message << "uncertainty: the gap is drawn (spread " << settings.skullGapSpread << " mm) but the nominal gap is "
            << contactGap << " mm; give the gap between the body and its contact surface (a narrower draw keeps a "
            << "tenth of it)";
    throw Error(message.str());
  }
  if (settings.tissueModulusSpread > 0.0 && m_TissueClasses == 0)
  {
    throw Error("uncertainty: the tissue classes' moduli are drawn but the model's materials are not mixed from "
                "tissue classes (a scene or a label map); draw one factor for all of them (the Young's modulus "
                "spread) instead");
  }
}

EnsembleDraw
EnsembleDrawer::Next()
{
  EnsembleDraw draw;
  draw.modulusFactor =
    m_Settings.youngsModulusSpread > 0.0 ? std::exp(m_Settings.youngsModulusSpread * StandardNormal()) : 1.0;
  draw.gravityFactor = m_Settings.gravityLow != m_Settings.gravityHigh ? m_Gravity(m_Random) : 1.0;
  const bool poisson = m_Settings.poissonLow != 0.0 || m_Settings.poissonHigh != 0.0;
  draw.poissonOffset = poisson ? m_Poisson(m_Random) - m_NominalPoisson : 0.0;
  draw.skullOffset = m_Settings.skullGapSpread > 0.0
                       ? std::max(m_Settings.skullGapSpread * StandardNormal(), -0.9 * m_ContactGap)
                       : 0.0;
  if (m_Settings.tissueModulusSpread > 0.0)
  {
    for (std::size_t k = 0; k < m_TissueClasses; ++k)
    {
      draw.tissueFactors.push_back(std::exp(m_Settings.tissueModulusSpread * StandardNormal()));
    }
  }
  return draw;
}

Model
DrawnModel(const Model & model, const EnsembleDraw & draw, const Vector3 & gravity)
{
  Model drawn = model;
  drawn.bodyAcceleration = draw.gravityFactor * gravity;
  for (Material & material : drawn.materials)
  {
    material.youngsModulus *= draw.modulusFactor;
    if (material.poissonRatio > kIncompressibleFrom)
    {
      material.poissonRatio = std::clamp(material.poissonRatio + draw.poissonOffset, kIncompressibleFrom, 0.4999);
    }
  }
  return drawn;
}

ContactSurface
NarrowedContactSurface(const ContactSurface & surface, double depth)
{
  ContactSurface       narrowed = surface;
  std::vector<Vector3> normals(surface.vertices.size(), Vector3::Zero());
  for (const auto & triangle : surface.OutwardTriangles())
  {
    const Vector3 normal = (surface.vertices[triangle[1]] - surface.vertices[triangle[0]])
                             .cross(surface.vertices[triangle[2]] - surface.vertices[triangle[0]]);
    for (const Index vertex : triangle)
    {
      normals[static_cast<std::size_t>(vertex)] += normal;
    }
  }
  const double towardBody = surface.bodySide == ContactSurface::Side::Inside ? -1.0 : 1.0;
  for (std::size_t v = 0; v < normals.size(); ++v)
  {
    if (normals[v].norm() > 0.0)
    {
      narrowed.vertices[v] += towardBody * depth * normals[v].normalized();
    }
  }
  return narrowed;
}

double
Percentile(std::vector<double> & values, double q)
{
  if (values.empty())
  {
    return 0.0;
  }
  std::sort(values.begin(), values.end());
  const double      position = q * static_cast<double>(values.size() - 1);
  const std::size_t below = static_cast<std::size_t>(std::floor(position));
  const std::size_t above = std::min(values.size() - 1, below + 1);
  return values[below] + (position - static_cast<double>(below)) * (values[above] - values[below]);
}

EnsembleSpread
SpreadOfMembers(const std::vector<std::vector<Vector3>> & displacements, const std::vector<std::size_t> & used)
{
  EnsembleSpread spread;
  if (used.empty())
  {
    return spread;
  }
  const std::size_t nodeCount = displacements[used.front()].size();
  spread.mean.assign(nodeCount, Vector3::Zero());
  for (const std::size_t m : used)
  {
    for (std::size_t n = 0; n < nodeCount; ++n)
    {
      spread.mean[n] += displacements[m][n] / static_cast<double>(used.size());
    }
  }
  spread.p95.resize(nodeCount);
  std::vector<double> distances(used.size());
  for (std::size_t n = 0; n < nodeCount; ++n)
  {
    for (std::size_t k = 0; k < used.size(); ++k)
    {
      distances[k] = (displacements[used[k]][n] - spread.mean[n]).norm();
    }
    spread.p95[n] = Percentile(distances, 0.95);
  }
  return spread;
}

void
ForEachMember(int count, int threads, const std::function<void(int member, int memberThreads)> & solve)
{
  const int available = threads > 0 ? threads : omp_get_max_threads();
  const int concurrent = std::max(1, std::min(count, available));
  const int memberThreads = std::max(1, available / concurrent);
#pragma omp parallel for num_threads(concurrent) schedule(dynamic, 1)
  for (int m = 0; m < count; ++m)
  {
    solve(m, memberThreads);
  }
}

} // namespace bmr
