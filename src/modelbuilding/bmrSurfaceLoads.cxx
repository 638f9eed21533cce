// The exposed surface's prescribed displacements from intraoperative data:
// sparse points (a polyharmonic spline), a displaced surface (its visible
// vertices matched and refined from their neighbours) and their reports.
// Over 800 lines: the three share the exposed nodes' checks, the distance
// report and the rejection of far matches.
#include "bmrSurfaceLoads.h"
#include "bmrClosestPoint.h"
#include "bmrMeshIO.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <iomanip>
#include <limits>
#include <map>
#include <set>
#include <sstream>

namespace bmr
{

namespace
{

constexpr std::size_t kListedInWarning = 20; // entries named in one warning before "... and N more"

void
ValidateExposedNodes(const Model & model, const std::vector<Index> & exposedNodes, const char * function)
{
  if (exposedNodes.empty())
  {
    throw Error(std::string(function) +
                ": no exposed nodes; select the craniotomy region first (SurfaceNodesInSphere or SurfaceNodesInMask)");
  }
  for (const Index node : exposedNodes)
  {
    if (node < 0 || static_cast<std::size_t>(node) >= model.nodes.size())
    {
      throw Error(std::string(function) + ": exposed node id " + std::to_string(node) + " is not a node of the model (" +
                  std::to_string(model.nodes.size()) + " nodes)");
    }
  }
}

void
ValidateSettings(const SurfaceLoadSettings & settings, const char * function)
{
  if (!(settings.maxDistance > 0.0) || !std::isfinite(settings.maxDistance) || !(settings.smoothing >= 0.0) ||
      !std::isfinite(settings.smoothing))
  {
    throw Error(std::string(function) + ": maxDistance must be a positive number of mm and smoothing >= 0 (given " +
                std::to_string(settings.maxDistance) + " and " + std::to_string(settings.smoothing) + ")");
  }
}

// Max and RMS of distances, summed in input order (deterministic).
void
FillDistanceStatistics(const std::vector<double> & distances, LoadReport & report)
{
  double maximum = 0.0;
  double sumSquares = 0.0;
  for (const double d : distances)
  {
    maximum = std::max(maximum, d);
    sumSquares += d * d;
  }
  report.maxCorrespondenceDistance = maximum;
  report.rmsCorrespondenceDistance = distances.empty() ? 0.0 : std::sqrt(sumSquares / distances.size());
}

std::string
Trim(const std::string & text)
{
  const auto first = text.find_first_not_of(" \t\r");
  if (first == std::string::npos)
  {
    return {};
  }
  const auto last = text.find_last_not_of(" \t\r");
  return text.substr(first, last - first + 1);
}

std::vector<std::string>
SplitFields(const std::string & line)
{
  std::vector<std::string> fields;
  std::stringstream        stream(line);
  std::string              field;
  while (std::getline(stream, field, ','))
  {
    fields.push_back(Trim(field));
  }
  if (!line.empty() && line.back() == ',')
  {
    fields.emplace_back();
  }
  return fields;
}

} // namespace

PrescribedDisplacement
DisplacementsFromSurface(const Model &               model,
                         const std::vector<Index> &  exposedNodes,
                         const ContactSurface &      intraoperativeSurface,
                         const SurfaceLoadSettings & settings,
                         LoadReport *                report)
{
  const char * function = "DisplacementsFromSurface";
  ValidateExposedNodes(model, exposedNodes, function);
  ValidateSettings(settings, function);
  const std::string surfaceName = "intraoperative surface '" + intraoperativeSurface.name + "'";
  const TriangleSurfaceTree surface(intraoperativeSurface.vertices, intraoperativeSurface.triangles, surfaceName);

  LoadReport             local;
  LoadReport &           out = report ? *report : local;
  out = LoadReport{};
  PrescribedDisplacement load;
  std::vector<double>    usedDistances;
  std::ostringstream     rejected;
  rejected.precision(4);
  for (const Index node : exposedNodes)
  {
    const Vector3 & x = model.nodes[node];
    const Vector3   displacement = surface.Closest(x).point - x;
    const double    distance = displacement.norm();
    if (distance > settings.maxDistance)
    {
      if (out.rejectedPoints < kListedInWarning)
      {
        rejected << (out.rejectedPoints > 0 ? ", " : "") << "node " << node << " (" << distance << " mm)";
      }
      ++out.rejectedPoints;
      continue;
    }
    load.nodes.push_back(node);
    load.displacements.push_back(displacement);
    usedDistances.push_back(distance);
  }
  out.usedPoints = load.nodes.size();
  FillDistanceStatistics(usedDistances, out);
  if (out.rejectedPoints > 0)
  {
    std::ostringstream warning;
    warning << out.rejectedPoints << " of " << exposedNodes.size() << " exposed nodes are farther than "
            << settings.maxDistance << " mm from the " << surfaceName << " and are left out of the load: "
            << rejected.str();
    if (out.rejectedPoints > kListedInWarning)
    {
      warning << ", ... and " << out.rejectedPoints - kListedInWarning << " more";
    }
    out.warnings.push_back(warning.str());
  }
  if (load.nodes.empty())
  {
    throw Error(std::string(function) + ": every exposed node is farther than " + std::to_string(settings.maxDistance) +
                " mm from the " + surfaceName + " (" + rejected.str() +
                "). Check that the surface is registered to the preoperative image (same physical space, mm) "
                "and that the craniotomy region faces it, or raise maxDistance");
  }
  return load;
}

namespace
{
// The measurement points within maxDistance of the model's surface (its
// boundary, or `modelSurface`), with their displacements; the rest counted,
// listed and warned about in `out`.
void
KeepPointsNearSurface(const Model & model, const std::vector<Vector3> & points,
                      const std::vector<Vector3> & displacements, double maxDistance,
                      const ContactSurface * modelSurface, LoadReport & out, std::vector<Vector3> & keptPoints,
                      std::vector<Vector3> & keptDisplacements, const char * function)
{
  const auto boundary = modelSurface ? modelSurface->triangles : model.BoundaryTriangles();
  if (boundary.empty())
  {
    throw Error(std::string(function) + ": the model has no boundary faces (a point cloud has no cells): give the "
                                        "model's surface (e.g. the brain surface) to measure the points' distance to");
  }
  const TriangleSurfaceTree surface(modelSurface ? modelSurface->vertices : model.nodes, boundary,
                                    "model boundary surface");

  std::vector<double>  usedDistances;
  std::ostringstream   rejected;
  rejected.precision(4);
  for (std::size_t i = 0; i < points.size(); ++i)
  {
    const double distance = (surface.Closest(points[i]).point - points[i]).norm();
    if (distance > maxDistance)
    {
      if (out.rejectedPoints < kListedInWarning)
      {
        rejected << (out.rejectedPoints > 0 ? ", " : "") << "point " << i << " at " << FormatPoint(points[i]) << " mm ("
                 << distance << " mm)";
      }
      ++out.rejectedPoints;
      continue;
    }
    keptPoints.push_back(points[i]);
    keptDisplacements.push_back(displacements[i]);
    usedDistances.push_back(distance);
  }
  out.usedPoints = keptPoints.size();
  FillDistanceStatistics(usedDistances, out);
  if (out.rejectedPoints > 0)
  {
    std::ostringstream warning;
    warning << out.rejectedPoints << " of " << points.size() << " measurement points are farther than "
            << maxDistance << " mm from the model surface and are rejected: " << rejected.str();
    if (out.rejectedPoints > kListedInWarning)
    {
      warning << ", ... and " << out.rejectedPoints - kListedInWarning << " more";
    }
    out.warnings.push_back(warning.str());
  }
  if (keptPoints.empty())
  {
    throw Error(std::string(function) + ": every measurement point is farther than " +
                std::to_string(maxDistance) + " mm from the model surface (" + rejected.str() +
                "). Check that the points are in the preoperative image's physical space (mm), or raise maxDistance");
  }
}

// Polyharmonic spline phi(r) = r with an affine part through the kept
// points, evaluated at load.nodes, in coordinates centred at the points'
// centroid and scaled by their extent (conditioning only: phi is homogeneous
// of degree 1, so the interpolant is unchanged). ITK's
// ThinPlateSplineKernelTransform is not used because the core does not
// include ITK; the dense solve below is a few lines of Eigen.
void
InterpolatePolyharmonic(const std::vector<Vector3> & nodes, const std::vector<Vector3> & keptPoints,
                        const std::vector<Vector3> & keptDisplacements, const Vector3 & centroid, double scale,
                        double smoothing, PrescribedDisplacement & load, LoadReport & out, const char * function)
{
  const std::vector<Index> & exposedNodes = load.nodes;
  const std::size_t          n = keptPoints.size();
  auto scaled = [&](const Vector3 & x) -> Vector3 { return (x - centroid) / scale; };
  const Eigen::Index size = static_cast<Eigen::Index>(n) + 4;
  Eigen::MatrixXd    system = Eigen::MatrixXd::Zero(size, size);
  Eigen::MatrixXd    rhs = Eigen::MatrixXd::Zero(size, 3);
  std::vector<Vector3> q(n);
  for (std::size_t i = 0; i < n; ++i)
  {
    q[i] = scaled(keptPoints[i]);
  }
  for (std::size_t i = 0; i < n; ++i)
  {
    const auto ii = static_cast<Eigen::Index>(i);
    for (std::size_t j = 0; j < n; ++j)
    {
      system(ii, static_cast<Eigen::Index>(j)) = (q[i] - q[j]).norm();
    }
    system(ii, ii) += smoothing / scale;
    system(ii, n) = system(n, ii) = 1.0;
    for (int d = 0; d < 3; ++d)
    {
      system(ii, n + 1 + d) = system(n + 1 + d, ii) = q[i][d];
    }
    rhs.row(ii) = keptDisplacements[i].transpose();
  }
  const Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd> decomposition(system);
  const Eigen::MatrixXd coefficients = decomposition.solve(rhs);
  if (!coefficients.allFinite())
  {
    throw Error(std::string(function) + ": the interpolation system of " + std::to_string(n) +
                " points could not be solved; remove duplicate points");
  }
  if (decomposition.rank() < size && decomposition.rank() >= static_cast<Eigen::Index>(n) + 3)
  {
    out.warnings.push_back(std::string(function) + ": the " + std::to_string(n) +
                           " measurement points are coplanar; the displacement gradient across their plane is "
                           "taken as zero (minimum-norm affine part)");
  }

  const auto count = static_cast<std::int64_t>(exposedNodes.size());
#pragma omp parallel for schedule(static)
  for (std::int64_t e = 0; e < count; ++e)
  {
    const Vector3 x = scaled(nodes[exposedNodes[e]]);
    Vector3       u = coefficients.row(static_cast<Eigen::Index>(n)).transpose();
    for (int d = 0; d < 3; ++d)
    {
      u += x[d] * coefficients.row(static_cast<Eigen::Index>(n) + 1 + d).transpose();
    }
    for (std::size_t i = 0; i < n; ++i)
    {
      u += (x - q[i]).norm() * coefficients.row(static_cast<Eigen::Index>(i)).transpose();
    }
    load.displacements[e] = u;
  }
}

} // namespace

PrescribedDisplacement
DisplacementsFromSparsePoints(const Model &                model,
                              const std::vector<Index> &   exposedNodes,
                              const std::vector<Vector3> & points,
                              const std::vector<Vector3> & displacements,
                              const SurfaceLoadSettings &  settings,
                              LoadReport *                 report,
                              const ContactSurface *       modelSurface)
{
  const char * function = "DisplacementsFromSparsePoints";
  ValidateExposedNodes(model, exposedNodes, function);
  ValidateSettings(settings, function);
  if (points.size() != displacements.size())
  {
    throw Error(std::string(function) + ": " + std::to_string(points.size()) + " points but " +
                std::to_string(displacements.size()) + " displacements; give one displacement per point");
  }
  if (points.empty())
  {
    throw Error(std::string(function) + ": no measurement points; give at least one point with its displacement");
  }
  for (std::size_t i = 0; i < points.size(); ++i)
  {
    if (!points[i].allFinite() || !displacements[i].allFinite())
    {
      throw Error(std::string(function) + ": measurement point " + std::to_string(i) + " at " + FormatPoint(points[i]) +
                  " mm with displacement " + FormatPoint(displacements[i]) +
                  " mm has a NaN or infinite value; remove or fix it");
    }
  }
  LoadReport   local;
  LoadReport & out = report ? *report : local;
  out = LoadReport{};
  std::vector<Vector3> keptPoints, keptDisplacements;
  KeepPointsNearSurface(model, points, displacements, settings.maxDistance, modelSurface, out, keptPoints,
                        keptDisplacements, function);

  PrescribedDisplacement load;
  load.nodes = exposedNodes;
  load.displacements.resize(exposedNodes.size());
  const std::size_t n = keptPoints.size();

  Vector3 centroid = Vector3::Zero();
  for (const auto & p : keptPoints)
  {
    centroid += p;
  }
  centroid /= static_cast<double>(n);
  double scale = 0.0;
  for (const auto & p : keptPoints)
  {
    scale = std::max(scale, (p - centroid).norm());
  }

  if (n < 4 || scale < 1e-9)
  {
    // An affine field needs 4 non-coplanar points; with fewer (or all at one
    // place) the only defensible field is a translation: the mean displacement.
    Vector3 mean = Vector3::Zero();
    for (const auto & d : keptDisplacements)
    {
      mean += d;
    }
    mean /= static_cast<double>(n);
    out.warnings.push_back(std::string(function) + ": only " + std::to_string(n) +
                           " distinct measurement point(s) kept; every exposed node gets their mean displacement " +
                           FormatPoint(mean) + " mm (a translation). Give 4 or more points to interpolate a field");
    std::fill(load.displacements.begin(), load.displacements.end(), mean);
    return load;
  }

  InterpolatePolyharmonic(model.nodes, keptPoints, keptDisplacements, centroid, scale, settings.smoothing, load, out,
                          function);
  return load;
}

namespace
{
// A directed projection's ray starts this far (mm) before the point: outside the brain for a point on its surface.
constexpr double kProjectionReach = 50.0;
// Passes of the refinement of the exposed surface's matches from their neighbours' local fit.
constexpr int kMatchRefinements = 2;

/** The parameter t of the first intersection of the ray point + t direction,
 *  t > -reach, with the surface (Moeller-Trumbore against every triangle),
 *  or NaN when it misses the surface. */
double
FirstRayHit(const ContactSurface & surface, const Vector3 & point, const Vector3 & direction, double reach)
{
  double first = std::numeric_limits<double>::quiet_NaN();
  for (const auto & triangle : surface.triangles)
  {
    const Vector3 & a = surface.vertices[triangle[0]];
    const Vector3   edge1 = surface.vertices[triangle[1]] - a, edge2 = surface.vertices[triangle[2]] - a;
    const Vector3   p = direction.cross(edge2);
    const double    determinant = edge1.dot(p);
    if (std::abs(determinant) < 1e-12)
    {
      continue;
    }
    const Vector3 s = point - a;
    const double  u = s.dot(p) / determinant;
    const Vector3 q = s.cross(edge1);
    const double  v = direction.dot(q) / determinant;
    const double  t = edge2.dot(q) / determinant;
    if (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > -reach && !(t >= first))
    {
      first = t;
    }
  }
  return first;
}
// What a scanner looking into the opening sees: per lateral cell of
// `spacing` (across the direction the opening faces, the mean area-weighted
// normal of the preoperative surface's vertices within `reach` of the exposed
// nodes), the vertex facing it that lies highest along it. Deeper vertices
// (sulci, the fissure) are hidden, and their closest intraoperative points
// would belong to the displaced crowns above them.
struct VisibleSurface
{
  VisibleSurface(const Model & model, const std::vector<Index> & exposedNodes, const ContactSurface & preoperativeSurface,
                 double reach, double spacing, const char * function)
  {
    // Area-weighted vertex normals of the preoperative surface.
    const std::vector<Vector3> & points = preoperativeSurface.vertices;
    std::vector<Vector3>         normals(points.size(), Vector3::Zero());
    for (const auto & triangle : preoperativeSurface.triangles)
    {
      const Vector3 normal =
        (points[triangle[1]] - points[triangle[0]]).cross(points[triangle[2]] - points[triangle[0]]);
      for (const Index vertex : triangle)
      {
        normals[vertex] += normal;
      }
    }
    // The vertices near the exposed nodes, and the direction the opening faces.
    std::vector<Index> near;
    Vector3            facing = Vector3::Zero();
    for (std::size_t v = 0; v < points.size(); ++v)
    {
      for (const Index node : exposedNodes)
      {
        if ((points[v] - model.nodes[node]).squaredNorm() <= reach * reach)
        {
          near.push_back(static_cast<Index>(v));
          facing += normals[v];
          break;
        }
      }
    }
    if (near.empty() || facing.norm() == 0.0)
    {
      throw Error(std::string(function) + ": no vertex of the preoperative surface '" + preoperativeSurface.name +
                  "' lies within " + std::to_string(reach) + " mm of the exposed nodes; give the surface the model was "
                  "made from");
    }
    facing.normalize();
    across1 = facing.unitOrthogonal();
    across2 = facing.cross(across1);
    std::map<std::pair<long, long>, Index> highest;
    for (const Index v : near)
    {
      const double length = normals[v].norm();
      if (length == 0.0 || normals[v].dot(facing) < 0.5 * length)
      {
        continue; // a sulcus wall or the far side
      }
      const Vector3 &             x = points[v];
      const std::pair<long, long> cell{ std::lround(std::floor(x.dot(across1) / spacing)),
                                        std::lround(std::floor(x.dot(across2) / spacing)) };
      const auto [entry, inserted] = highest.emplace(cell, v);
      if (!inserted && x.dot(facing) > points[entry->second].dot(facing))
      {
        entry->second = v;
      }
    }
    for (const auto & entry : highest)
    {
      vertices.push_back(entry.second);
    }
  }

  std::vector<Index> vertices; // in the lateral cells' order
  Vector3            across1, across2;
};

// A robust local linear fit of the neighbours' values (over the lateral
// coordinates, so that the prediction is unbiased where the motion varies and
// at the patch's edge) predicts each scanned vertex's value.
class NeighbourFit
{
public:
  // The scanned vertices stay put, so their neighbourhoods are found once.
  NeighbourFit(const std::vector<Vector3> & scanned, double spacing, const Vector3 & across1, const Vector3 & across2)
    : m_Scanned(scanned)
    , m_Across1(across1)
    , m_Across2(across2)
    , m_Neighbourhoods(scanned.size())
  {
    for (std::size_t k = 0; k < scanned.size(); ++k)
    {
      for (std::size_t j = 0; j < scanned.size(); ++j)
      {
        if ((scanned[j] - scanned[k]).norm() <= 2.5 * spacing)
        {
          m_Neighbourhoods[k].push_back(j);
        }
      }
    }
  }

  /** Within `slack` times the outlier bound max(1 mm, 20 %) of the prediction. */
  static bool Acceptable(const Vector3 & value, const Vector3 & predicted, double slack)
  {
    return (value - predicted).norm() <= slack * std::max(1.0, 0.2 * predicted.norm());
  }

  std::vector<Vector3> Predict(const std::vector<Vector3> & values) const
  {
    std::vector<Vector3> predictions(values.size());
    for (std::size_t k = 0; k < m_Scanned.size(); ++k)
    {
      predictions[k] = PredictOne(k, values);
    }
    return predictions;
  }

private:
  Vector3 PredictOne(std::size_t k, const std::vector<Vector3> & values) const
  {
    const std::vector<std::size_t> &   neighbours = m_Neighbourhoods[k];
    std::array<std::vector<double>, 3> components;
    for (const std::size_t j : neighbours)
    {
      for (int axis = 0; axis < 3; ++axis)
      {
        components[axis].push_back(values[j][axis]);
      }
    }
    Vector3 median;
    for (int axis = 0; axis < 3; ++axis)
    {
      auto & component = components[axis];
      std::nth_element(component.begin(), component.begin() + component.size() / 2, component.end());
      median[axis] = component[component.size() / 2];
    }
    // Least squares of value = a + B (lateral offset), first over the
    // neighbours within 3 times the outlier bound of their median, then over
    // those within the bound of that fit.
    Vector3 predicted = median;
    for (const double slack : { 3.0, 1.0 })
    {
      Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
      Eigen::Matrix3d right = Eigen::Matrix3d::Zero(); // column axis: sum of basis * value
      int             used = 0;
      for (const std::size_t j : neighbours)
      {
        if (!Acceptable(values[j], predicted, slack))
        {
          continue;
        }
        const Vector3 offset = m_Scanned[j] - m_Scanned[k];
        const Vector3 basis(1.0, offset.dot(m_Across1), offset.dot(m_Across2));
        normal += basis * basis.transpose();
        right += basis * values[j].transpose();
        ++used;
      }
      const Eigen::FullPivLU<Eigen::Matrix3d> lu(normal);
      if (used < 6 || lu.rank() < 3)
      {
        break; // too few for a plane: keep the median
      }
      predicted = lu.solve(right).row(0).transpose();
    }
    return predicted;
  }

  const std::vector<Vector3> &          m_Scanned;
  Vector3                               m_Across1, m_Across2;
  std::vector<std::vector<std::size_t>> m_Neighbourhoods;
};
} // namespace

PrescribedDisplacement
DisplacementsBetweenSurfaces(const Model &               model,
                             const std::vector<Index> &  exposedNodes,
                             const ContactSurface &      preoperativeSurface,
                             const ContactSurface &      intraoperativeSurface,
                             double                      reach,
                             double                      spacing,
                             const SurfaceLoadSettings & settings,
                             LoadReport *                report,
                             const ContactSurface *      modelSurface)
{
  const char * function = "DisplacementsBetweenSurfaces";
  ValidateExposedNodes(model, exposedNodes, function);
  ValidateSettings(settings, function);
  if (settings.matchDirection && !(settings.matchDirection->norm() > 0.0 && settings.matchDirection->allFinite()))
  {
    throw Error(std::string(function) + ": the match direction must be a finite non-zero vector, got " +
                FormatPoint(*settings.matchDirection));
  }
  if (!(reach > 0.0) || !(spacing > 0.0))
  {
    throw Error(std::string(function) + ": reach and spacing must be > 0 mm");
  }
  const std::string surfaceName = "intraoperative surface '" + intraoperativeSurface.name + "'";
  const TriangleSurfaceTree surface(intraoperativeSurface.vertices, intraoperativeSurface.triangles, surfaceName);

  const VisibleSurface visible(model, exposedNodes, preoperativeSurface, reach, spacing, function);
  const std::vector<Vector3> & vertices = preoperativeSurface.vertices;
  std::vector<Vector3> scanned, matched;
  std::size_t          missed = 0;
  for (const Index v : visible.vertices)
  {
    if (settings.matchDirection)
    {
      const Vector3 unit = settings.matchDirection->normalized();
      const double  t = FirstRayHit(intraoperativeSurface, vertices[v], unit, kProjectionReach);
      if (!std::isfinite(t))
      {
        ++missed; // beyond the scanned patch
        continue;
      }
      scanned.push_back(vertices[v]);
      matched.push_back(t * unit);
      continue;
    }
    scanned.push_back(vertices[v]);
    matched.push_back(surface.Closest(vertices[v]).point - vertices[v]);
  }
  if (scanned.empty() && settings.matchDirection)
  {
    throw Error(std::string(function) + ": no visible vertex of the preoperative surface meets the " +
                intraoperativeSurface.name + " along the match direction " + FormatPoint(*settings.matchDirection));
  }
  // Closest points (and rays) jump where the motion is larger than the
  // features: at the rim of a sulcus or of the fissure the match lands on the
  // other side. Each match is therefore refined from its neighbours
  // (NeighbourFit), and the closest point of the displaced surface to the
  // prediction is its match (the prediction's error is mostly normal to the
  // surface, so the snap removes it while the neighbours' tangential motion
  // stays). A match that still differs from the prediction by more than
  // max(1 mm, 20 %) is an outlier.
  const NeighbourFit fit(scanned, spacing, visible.across1, visible.across2);
  for (int pass = 0; pass < kMatchRefinements; ++pass)
  {
    const std::vector<Vector3> predictions = fit.Predict(matched);
    for (std::size_t k = 0; k < scanned.size(); ++k)
    {
      matched[k] = surface.Closest(scanned[k] + predictions[k]).point - scanned[k];
    }
  }
  const std::vector<Vector3> predictions = fit.Predict(matched);
  std::vector<Vector3>       points, displacements;
  std::size_t                outliers = 0;
  for (std::size_t k = 0; k < scanned.size(); ++k)
  {
    if (!NeighbourFit::Acceptable(matched[k], predictions[k], 1.0))
    {
      ++outliers;
      continue;
    }
    points.push_back(scanned[k]);
    displacements.push_back(matched[k]);
  }
  // Matches that are too far are rejected by (b)'s distance check on the points' displacement.
  std::vector<Vector3> keptPoints, keptDisplacements;
  std::size_t          rejected = 0;
  for (std::size_t k = 0; k < points.size(); ++k)
  {
    if (displacements[k].norm() > settings.maxDistance)
    {
      ++rejected;
      continue;
    }
    keptPoints.push_back(points[k]);
    keptDisplacements.push_back(displacements[k]);
  }
  if (keptPoints.empty())
  {
    throw Error(std::string(function) + ": every point of the exposed region is farther than " +
                std::to_string(settings.maxDistance) + " mm from the " + surfaceName +
                ". Check that the surface is registered to the preoperative image (same physical space, mm) "
                "and that the craniotomy region faces it, or raise maxDistance");
  }
  PrescribedDisplacement load = DisplacementsFromSparsePoints(model, exposedNodes, keptPoints, keptDisplacements,
                                                              settings, report, modelSurface);
  if (report != nullptr && outliers > 0)
  {
    report->rejectedPoints += outliers;
    report->warnings.push_back(std::to_string(outliers) + " of " + std::to_string(scanned.size()) +
                               " exposed-surface matches differ from their neighbours' local fit by more than max(1 mm, 20%) "
                               "even after being refined from it (matches across a sulcus or the fissure) and are "
                               "left out of the load");
  }
  if (report != nullptr && missed > 0)
  {
    report->warnings.push_back(std::to_string(missed) + " visible preoperative vertices meet no point of the " +
                               surfaceName + " along the match direction (beyond the scan's edge) and are not matched");
  }
  if (report != nullptr && rejected > 0)
  {
    report->rejectedPoints += rejected;
    report->warnings.push_back(std::to_string(rejected) + " of " + std::to_string(points.size()) +
                               " exposed-surface points are farther than " + std::to_string(settings.maxDistance) +
                               " mm from the " + surfaceName + " and are left out of the load");
  }
  return load;
}

SparseDisplacements
ProjectOntoSurface(const std::vector<Vector3> & displacedPoints, const ContactSurface & referenceSurface,
                   const Vector3 * direction)
{
  if (displacedPoints.empty())
  {
    throw Error("ProjectOntoSurface: no points to project onto the " + referenceSurface.name + " surface");
  }
  if (direction != nullptr && !(direction->norm() > 0.0 && direction->allFinite()))
  {
    throw Error("ProjectOntoSurface: the projection direction must be a finite non-zero vector, got " +
                FormatPoint(*direction));
  }
  // Builds the tree, which also checks the surface (vertex indices, finite vertices, area).
  const TriangleSurfaceTree surface(referenceSurface.vertices, referenceSurface.triangles, referenceSurface.name);
  SparseDisplacements       result;
  for (std::size_t k = 0; k < displacedPoints.size(); ++k)
  {
    const Vector3 & point = displacedPoints[k];
    if (!point.allFinite())
    {
      throw Error("ProjectOntoSurface: point " + std::to_string(k) + " is not finite: " + FormatPoint(point));
    }
    Vector3 reference = Vector3::Zero();
    if (direction == nullptr)
    {
      reference = surface.Closest(point).point;
    }
    else
    {
      const Vector3 unit = direction->normalized();
      const double  t = FirstRayHit(referenceSurface, point, unit, kProjectionReach);
      if (!std::isfinite(t))
      {
        throw Error("ProjectOntoSurface: the ray along " + FormatPoint(unit) + " through point " + std::to_string(k) +
                    " " + FormatPoint(point) + " misses the " + referenceSurface.name + " surface");
      }
      reference = point + t * unit;
    }
    result.points.push_back(reference);
    result.displacements.push_back(point - reference);
  }
  return result;
}

void
WriteSparseDisplacements(const std::string & csvPath, const SparseDisplacements & sparse)
{
  if (sparse.points.size() != sparse.displacements.size())
  {
    throw Error("cannot write '" + csvPath + "': " + std::to_string(sparse.points.size()) + " points but " +
                std::to_string(sparse.displacements.size()) + " displacements");
  }
  std::ostringstream csv;
  csv << std::setprecision(17) << "x,y,z,ux,uy,uz\n";
  for (std::size_t k = 0; k < sparse.points.size(); ++k)
  {
    const Vector3 & x = sparse.points[k];
    const Vector3 & u = sparse.displacements[k];
    csv << x.x() << "," << x.y() << "," << x.z() << "," << u.x() << "," << u.y() << "," << u.z() << "\n";
  }
  WriteTextFileAtomically(csvPath, csv.str());
}

SparseDisplacements
ReadSparseDisplacements(const std::string & csvPath)
{
  std::ifstream file(csvPath);
  if (!file)
  {
    throw Error("sparse displacements '" + csvPath + "': cannot open the file; check the path");
  }
  SparseDisplacements result;
  std::string         line;
  std::size_t         lineNumber = 0;
  bool                headerSeen = false;
  const std::vector<std::string> header{ "x", "y", "z", "ux", "uy", "uz" };
  while (std::getline(file, line))
  {
    ++lineNumber;
    const std::string trimmed = Trim(line);
    if (trimmed.empty() || trimmed[0] == '#')
    {
      continue;
    }
    const auto  fields = SplitFields(trimmed);
    const std::string where = "sparse displacements '" + csvPath + "', line " + std::to_string(lineNumber);
    if (!headerSeen)
    {
      if (fields != header)
      {
        throw Error(where + ": expected the header 'x,y,z,ux,uy,uz' (mm), found '" + trimmed + "'");
      }
      headerSeen = true;
      continue;
    }
    if (fields.size() != 6)
    {
      throw Error(where + ": expected 6 comma-separated numbers x,y,z,ux,uy,uz, found " + std::to_string(fields.size()) +
                  " fields in '" + trimmed + "'");
    }
    double values[6];
    for (int f = 0; f < 6; ++f)
    {
      const char * begin = fields[f].c_str();
      char *       end = nullptr;
      values[f] = std::strtod(begin, &end);
      if (fields[f].empty() || end != begin + fields[f].size() || !std::isfinite(values[f]))
      {
        throw Error(where + ": field " + header[f] + " = '" + fields[f] + "' is not a finite number");
      }
    }
    result.points.emplace_back(values[0], values[1], values[2]);
    result.displacements.emplace_back(values[3], values[4], values[5]);
  }
  if (!headerSeen)
  {
    throw Error("sparse displacements '" + csvPath + "': the file is empty; expected the header 'x,y,z,ux,uy,uz' and rows");
  }
  if (result.points.empty())
  {
    throw Error("sparse displacements '" + csvPath + "': the file has a header but no rows of points");
  }
  return result;
}

} // namespace bmr
