// Moving least squares shape functions (Element-Free Galerkin, Horton et al.
// 2010) and the modified MLS with a regularised quadratic basis (Joldes et
// al. 2015). Node-based compact supports, quartic-spline weights, exact
// derivatives; neighbours from a k-d tree.
#include "bmrMeshless.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include <nanoflann.hpp>

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>

namespace bmr
{

namespace
{
// Nodes over which the local nodal spacing is averaged (a node's face
// neighbours on a regular grid).
constexpr int kSpacingNeighbours = 6;
// Supports must overlap (dilatation > 1); beyond 10 a support holds thousands
// of nodes and the approximation degenerates into a global smoothing.
constexpr double kMinDilatation = 1.0;
constexpr double kMaxDilatation = 10.0;
// Smallest reciprocal condition number (min/max eigenvalue) of the linear 4x4
// block of the moment matrix in coordinates scaled by the support radius. A
// well-spread neighbourhood gives 1e-2..1e-1; the ratio is the squared
// thickness of the neighbourhood relative to its extent, so 1e-8 means a
// neighbourhood 1e4 times thinner than wide: shape function gradients across
// it would be ~1e4 times too large (stable time step, accuracy) and round-off
// in the solve reaches 1e-8. Exactly coplanar neighbours give ~1e-17.
constexpr double kMinReciprocalCondition = 1e-8;
// Guard on the full (regularised) quadratic moment matrix: smallest Cholesky
// pivot relative to the largest diagonal entry. mu^2 = 1e-12 (the default)
// keeps it near 1e-13 even where the plain quadratic matrix is singular; below
// ~10 eps the factorisation is round-off.
constexpr double kMinQuadraticPivotRatio = 1e-15;
// Regularisation mu of the quadratic coefficients (scaled coordinates): mu^2
// must stay well above round-off of the moment matrix (eps ~ 2e-16), and
// beyond 1 the quadratic terms are suppressed as strongly as the data fit.
constexpr double kMinRegularization = 1e-7;
constexpr double kMaxRegularization = 1.0;
// Nodes closer than this fraction of the cloud's bounding-box diagonal coincide.
constexpr double kDuplicateTolerance = 1e-9;
// k-d tree leaf size: 8..32 perform alike for supports of ~30..60 nodes.
constexpr int kLeafSize = 16;
// Evaluation points per block of the parallel loop; rows are assembled per
// block so that the table does not depend on the thread count.
constexpr Index kPointsPerBlock = 256;

std::string
FormatNumber(double value)
{
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.3g", value);
  return buffer;
}

// The node array as nanoflann's dataset.
struct NodeCloud
{
  const std::vector<Vector3> * nodes = nullptr;

  std::size_t kdtree_get_point_count() const { return nodes->size(); }
  double      kdtree_get_pt(std::size_t index, std::size_t dimension) const { return (*nodes)[index][dimension]; }
  template <class BoundingBox>
  bool kdtree_get_bbox(BoundingBox &) const
  {
    return false;
  }
};

using KdTree =
  nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, NodeCloud>, NodeCloud, 3, std::uint32_t>;

// nanoflann result set keeping the nodes whose own support contains the query
// point; the tree is searched with the largest support radius (squared
// distances, as nanoflann's L2 metric).
struct SupportResultSet
{
  double                      searchRadiusSquared;
  const std::vector<double> * radiusSquared;
  std::vector<Index> *        found;

  std::size_t size() const { return found->size(); }
  bool        full() const { return true; }
  double      worstDist() const { return searchRadiusSquared; }
  bool        addPoint(double distanceSquared, std::uint32_t node)
  {
    if (distanceSquared < (*radiusSquared)[node])
    {
      found->push_back(static_cast<Index>(node));
    }
    return true;
  }
};

// A support must hold several integration points, not only several nodes:
// where the nodes are denser than the integration points (fine surface
// features beside a coarser background grid), a node whose support holds two
// or three points has a share of their mass but almost no stiffness, and
// groups of such nodes form near-zero-energy modes that dynamic relaxation
// cannot damp (measured on Colin27: lowest eigenvalue 1e-9 of the highest).
// The distance to a node's k-th nearest integration point is its local
// integration spacing; the support is the dilatation times the larger of the
// two spacings. With 2 x 2 x 2 Gauss points per background cell of the nodal
// spacing, the 4th nearest point is closer than the nodal spacing everywhere
// (box corners included), and in coarse interior blocks of twice that edge
// it is at most the nodal spacing away (at a block's centre), so regular
// clouds keep their supports.
constexpr int kSpacingIntegrationPoints = 4;

std::vector<double>
IntegrationPointSpacing(const std::vector<Vector3> & nodes, const std::vector<Vector3> & points)
{
  std::vector<double> spacing(nodes.size(), 0.0);
  if (points.empty())
  {
    return spacing;
  }
  NodeCloud  cloud{ &points };
  KdTree     tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize));
  const auto k = static_cast<std::size_t>(std::min<std::size_t>(kSpacingIntegrationPoints, points.size()));
  const auto count = static_cast<Index>(nodes.size());
  for (Index node = 0; node < count; ++node)
  {
    std::uint32_t indices[kSpacingIntegrationPoints];
    double        distances[kSpacingIntegrationPoints];
    const auto    found = tree.knnSearch(nodes[node].data(), k, indices, distances);
    spacing[node] = found > 0 ? std::sqrt(distances[found - 1]) : 0.0;
  }
  return spacing;
}

// Polynomial bases in shifted, scaled coordinates q = (X - x) / r.
template <int M>
struct Basis;

template <>
struct Basis<4>
{
  static Eigen::Matrix<double, 4, 1> Evaluate(const Vector3 & q) { return { 1.0, q.x(), q.y(), q.z() }; }
};

template <>
struct Basis<10>
{
  static Eigen::Matrix<double, 10, 1> Evaluate(const Vector3 & q)
  {
    Eigen::Matrix<double, 10, 1> p;
    p << 1.0, q.x(), q.y(), q.z(), q.x() * q.x(), q.y() * q.y(), q.z() * q.z(), q.x() * q.y(), q.y() * q.z(),
      q.z() * q.x();
    return p;
  }
};

// Per-thread scratch, reused from point to point.
struct Scratch
{
  std::vector<Index>   neighbours;
  std::vector<Vector3> scaled;          // (X_I - x) / r_ref
  std::vector<double>  weights;         // w_I
  std::vector<Vector3> weightGradients; // d w_I / dx (1/mm)
  std::vector<double>  phi;
  std::vector<Vector3> phiGradients;
};

// The rows of one block of evaluation points.
struct Block
{
  std::vector<Index>  counts;
  std::vector<Index>  nodes;
  std::vector<double> values;
  std::vector<double> gradients;
  Index               failedPoint = -1; // first point of the block that failed
  std::string         message;
};
} // namespace

struct MovingLeastSquares::Impl
{
  std::vector<Vector3>    nodes;
  MlsSettings             settings;
  std::vector<double>     spacing;
  std::vector<double>     radius;
  std::vector<double>     radiusSquared;
  double                  maxRadius = 0.0;
  NodeCloud               cloud;
  std::unique_ptr<KdTree> tree;

  // Shape functions at x into the scratch (neighbours sorted). Returns an
  // empty string on success, else the reason (the caller names the point).
  template <int M>
  std::string ShapeFunctionsAt(const Vector3 & x, bool withGradients, Scratch & s) const;
  /** The quadratic basis: where the plain moment matrix is (nearly) singular,
   *  the round-off residual of linear consistency projected out with the
   *  linear moment matrix `linear`. */
  static void RestoreLinearConsistency(const Eigen::Matrix4d & linear, double inverseReference, bool withGradients,
                                       Scratch & s);
};

void
MovingLeastSquares::Impl::RestoreLinearConsistency(const Eigen::Matrix4d & linear, double inverseReference,
                                                   bool withGradients, Scratch & s)
{
  const std::size_t n = s.phi.size();
  // Where the plain quadratic moment matrix is (nearly) singular, gamma has
  // components of order 1/mu^2 that cancel in phi only in exact arithmetic;
  // round-off then breaks linear consistency. Project the round-off residual
  // of sum phi_I p_I = p(x) (and of its derivatives) out with the linear
  // moment matrix: zero in exact arithmetic, so phi and its exact
  // derivatives are unchanged, but consistency holds to round-off.
  const Eigen::LLT<Eigen::Matrix4d> linearLlt(linear);
  Eigen::Matrix4d                   residual = Eigen::Matrix4d::Zero();
  residual(0, 0) = -1.0; // sum phi_I p_I - p(x)
  for (int i = 0; i < 3; ++i)
  {
    residual(1 + i, 1 + i) = -inverseReference; // sum phi_I,i p_I - p_,i
  }
  for (std::size_t k = 0; k < n; ++k)
  {
    const Eigen::Vector4d p(1.0, s.scaled[k].x(), s.scaled[k].y(), s.scaled[k].z());
    residual.col(0) += s.phi[k] * p;
    if (withGradients)
    {
      residual.rightCols<3>() += p * s.phiGradients[k].transpose();
    }
  }
  const Eigen::Matrix4d correction = linearLlt.solve(residual); // columns 1..3 unused without gradients
  for (std::size_t k = 0; k < n; ++k)
  {
    const Eigen::Vector4d p(1.0, s.scaled[k].x(), s.scaled[k].y(), s.scaled[k].z());
    s.phi[k] -= s.weights[k] * correction.col(0).dot(p);
    if (withGradients)
    {
      s.phiGradients[k] -= s.weights[k] * (correction.rightCols<3>().transpose() * p);
    }
  }
}

template <int M>
std::string
MovingLeastSquares::Impl::ShapeFunctionsAt(const Vector3 & x, bool withGradients, Scratch & s) const
{
  using VectorM = Eigen::Matrix<double, M, 1>;
  using MatrixM = Eigen::Matrix<double, M, M>;

  s.neighbours.clear();
  SupportResultSet results{ maxRadius * maxRadius, &radiusSquared, &s.neighbours };
  tree->findNeighbors(results, x.data(), nanoflann::SearchParams());
  std::sort(s.neighbours.begin(), s.neighbours.end());
  const std::size_t n = s.neighbours.size();
  if (n < 4)
  {
    return "has only " + std::to_string(n) +
           " MLS neighbours (at least 4 needed): it lies outside or at the edge of the node cloud. Increase the "
           "dilatation (now " +
           FormatNumber(settings.dilatation) + ") or add nodes near this point.";
  }

  // Coordinates scaled by the mean support radius keep the moment matrix
  // near unit scale whatever the units and the nodal density.
  double referenceRadius = 0.0;
  for (Index node : s.neighbours)
  {
    referenceRadius += radius[node];
  }
  referenceRadius /= static_cast<double>(n);
  const double inverseReference = 1.0 / referenceRadius;

  s.scaled.resize(n);
  s.weights.resize(n);
  s.weightGradients.resize(n);
  MatrixM moment = MatrixM::Zero();
  for (std::size_t k = 0; k < n; ++k)
  {
    const Index   node = s.neighbours[k];
    const Vector3 d = nodes[node] - x;
    const double  r = radius[node];
    const double  t = std::min(d.norm() / r, 1.0);
    const double  u = 1.0 - t;
    // Quartic spline 1 - 6t^2 + 8t^3 - 3t^4 = (1-t)^3 (1+3t); its gradient in
    // x is 12 (1-t)^2 (X_I - x) / r^2 (no division by the distance).
    const double w = u * u * u * (1.0 + 3.0 * t);
    s.weights[k] = w;
    s.weightGradients[k] = (12.0 * u * u / (r * r)) * d;
    s.scaled[k] = d * inverseReference;
    const VectorM p = Basis<M>::Evaluate(s.scaled[k]);
    moment.noalias() += (w * p) * p.transpose();
  }

  // The linear block decides whether the neighbourhood spans 3-D space; it is
  // the same for both bases (the regularisation acts on quadratic terms only).
  const Eigen::Matrix4d                                linear = moment.template topLeftCorner<4, 4>();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> eigen(linear, Eigen::EigenvaluesOnly);
  const double                                         rcond = eigen.eigenvalues()(0) / eigen.eigenvalues()(3);
  if (!(rcond >= kMinReciprocalCondition))
  {
    return "has an ill-conditioned MLS moment matrix (" + std::to_string(n) +
           " neighbours, reciprocal condition number " + FormatNumber(rcond) +
           "): its neighbours are (nearly) coplanar or too few. Increase the dilatation (now " +
           FormatNumber(settings.dilatation) + ") or add nodes near this point.";
  }

  if constexpr (M == 10)
  {
    const double mu2 = settings.quadraticRegularization * settings.quadraticRegularization;
    for (int i = 4; i < 10; ++i)
    {
      moment(i, i) += mu2;
    }
  }
  const Eigen::LLT<MatrixM> llt(moment);
  if constexpr (M == 10)
  {
    const double pivot = llt.matrixLLT().diagonal().cwiseAbs2().minCoeff();
    const double ratio = pivot / moment.diagonal().maxCoeff();
    if (llt.info() != Eigen::Success || !(ratio >= kMinQuadraticPivotRatio))
    {
      return "has a singular regularised quadratic MLS moment matrix (" + std::to_string(n) +
             " neighbours, pivot ratio " + FormatNumber(ratio) + "): increase the quadratic regularisation (now " +
             FormatNumber(settings.quadraticRegularization) + "), increase the dilatation (now " +
             FormatNumber(settings.dilatation) + ") or add nodes near this point.";
    }
  }

  // gamma = A^-1 p(x), p(x) = e0 at the evaluation point (q = 0);
  // gamma_,i = A^-1 (p_,i - A_,i gamma), p_,i = e_{1+i} / r_ref,
  // A_,i = sum_I w_I,i p_I p_I^T (H is constant).
  const VectorM               gamma = llt.solve(VectorM::Unit(0));
  Eigen::Matrix<double, M, 3> gammaDerivative;
  if (withGradients)
  {
    Eigen::Matrix<double, M, 3> rhs = Eigen::Matrix<double, M, 3>::Zero();
    for (int i = 0; i < 3; ++i)
    {
      rhs(1 + i, i) = inverseReference;
    }
    for (std::size_t k = 0; k < n; ++k)
    {
      const VectorM p = Basis<M>::Evaluate(s.scaled[k]);
      rhs.noalias() -= (p.dot(gamma) * p) * s.weightGradients[k].transpose();
    }
    gammaDerivative = llt.solve(rhs);
  }
  // phi_I = gamma^T p_I w_I, phi_I,i = gamma_,i^T p_I w_I + gamma^T p_I w_I,i.
  s.phi.resize(n);
  s.phiGradients.resize(n);
  for (std::size_t k = 0; k < n; ++k)
  {
    const VectorM p = Basis<M>::Evaluate(s.scaled[k]);
    const double  c = p.dot(gamma);
    s.phi[k] = c * s.weights[k];
    if (withGradients)
    {
      s.phiGradients[k] = (gammaDerivative.transpose() * p) * s.weights[k] + c * s.weightGradients[k];
    }
  }

  if constexpr (M == 10)
  {
    RestoreLinearConsistency(linear, inverseReference, withGradients, s);
  }

  for (std::size_t k = 0; k < n; ++k)
  {
    if (!std::isfinite(s.phi[k]) || (withGradients && !s.phiGradients[k].allFinite()))
    {
      return "has non-finite MLS shape functions (" + std::to_string(n) +
             " neighbours): increase the dilatation (now " + FormatNumber(settings.dilatation) +
             ") or add nodes near this point.";
    }
  }
  return {};
}

MovingLeastSquares::MovingLeastSquares(std::vector<Vector3>         nodes,
                                       const MlsSettings &          settings,
                                       const std::vector<Vector3> & integrationPoints)
  : m_Impl(std::make_unique<Impl>())
{
  Impl & impl = *m_Impl;
  impl.nodes = std::move(nodes);
  impl.settings = settings;
  const auto count = static_cast<Index>(impl.nodes.size());
  if (count < 4)
  {
    throw Error("MLS shape functions need at least 4 nodes (got " + std::to_string(count) + "). Add nodes.");
  }
  if (!(settings.dilatation > kMinDilatation && settings.dilatation <= kMaxDilatation))
  {
    throw Error("MLS dilatation " + FormatNumber(settings.dilatation) + " is out of range: it must be above " +
                FormatNumber(kMinDilatation) + " (supports must overlap) and at most " + FormatNumber(kMaxDilatation) +
                "; 2 is typical for the linear basis.");
  }
  if (settings.basis == MlsBasis::ModifiedQuadratic && !(settings.quadraticRegularization >= kMinRegularization &&
                                                         settings.quadraticRegularization <= kMaxRegularization))
  {
    throw Error("MLS quadratic regularisation " + FormatNumber(settings.quadraticRegularization) +
                " is out of range for the modified quadratic basis: use a value in [" +
                FormatNumber(kMinRegularization) + ", " + FormatNumber(kMaxRegularization) + "] (default 1e-6).");
  }
  Eigen::AlignedBox3d bounds;
  for (Index node = 0; node < count; ++node)
  {
    if (!impl.nodes[node].allFinite())
    {
      throw Error("MLS node " + std::to_string(node) + " has a non-finite coordinate. Check the node positions.");
    }
    bounds.extend(impl.nodes[node]);
  }

  impl.cloud.nodes = &impl.nodes;
  impl.tree = std::make_unique<KdTree>(3, impl.cloud, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize));

  const double duplicate = kDuplicateTolerance * bounds.diagonal().norm();
  const int    nearest = std::min<Index>(kSpacingNeighbours, count - 1);
  impl.spacing.resize(count);
  impl.radius.resize(count);
  impl.radiusSquared.resize(count);
  for (Index node = 0; node < count; ++node)
  {
    std::uint32_t indices[kSpacingNeighbours + 1];
    double        distances[kSpacingNeighbours + 1];
    const auto    found = impl.tree->knnSearch(impl.nodes[node].data(), nearest + 1, indices, distances);
    double        sum = 0.0;
    int           used = 0;
    for (std::size_t k = 0; k < found; ++k)
    {
      if (static_cast<Index>(indices[k]) == node)
      {
        continue;
      }
      const double distance = std::sqrt(distances[k]);
      if (distance <= duplicate)
      {
        const auto other = static_cast<Index>(indices[k]);
        throw Error("MLS nodes " + std::to_string(std::min(node, other)) + " and " +
                    std::to_string(std::max(node, other)) + " coincide at " + FormatPoint(impl.nodes[node]) +
                    " mm. Remove duplicate nodes.");
      }
      if (used < nearest)
      {
        sum += distance;
        ++used;
      }
    }
    impl.spacing[node] = sum / used;
  }
  const std::vector<double> pointSpacing = IntegrationPointSpacing(impl.nodes, integrationPoints);
  for (Index node = 0; node < count; ++node)
  {
    impl.radius[node] = settings.dilatation * std::max(impl.spacing[node], pointSpacing[node]);
    impl.radiusSquared[node] = impl.radius[node] * impl.radius[node];
    impl.maxRadius = std::max(impl.maxRadius, impl.radius[node]);
  }
}

MovingLeastSquares::~MovingLeastSquares() = default;

std::unique_ptr<MovingLeastSquares>
MovingLeastSquares::ForModel(const Model & model)
{
  return std::make_unique<MovingLeastSquares>(model.nodes, model.meshless.shapeFunctions,
                                              model.meshless.integrationPoints);
}

const MlsSettings &
MovingLeastSquares::Settings() const
{
  return m_Impl->settings;
}

const std::vector<Vector3> &
MovingLeastSquares::Nodes() const
{
  return m_Impl->nodes;
}

Index
MovingLeastSquares::NodeCount() const
{
  return static_cast<Index>(m_Impl->nodes.size());
}

double
MovingLeastSquares::NodalSpacing(Index node) const
{
  return m_Impl->spacing.at(node);
}

double
MovingLeastSquares::SupportRadius(Index node) const
{
  return m_Impl->radius.at(node);
}

ShapeFunctionTable
MovingLeastSquares::Evaluate(const std::vector<Vector3> & points,
                             bool                         withGradients,
                             int                          threads,
                             const std::string &          pointLabel) const
{
  const Impl &       impl = *m_Impl;
  const auto         pointCount = static_cast<Index>(points.size());
  const Index        blockCount = (pointCount + kPointsPerBlock - 1) / kPointsPerBlock;
  const bool         quadratic = impl.settings.basis == MlsBasis::ModifiedQuadratic;
  std::vector<Block> blocks(blockCount);
  // Blocks after the first failed one are skipped; earlier ones still run so
  // that the reported point is the first failing one for any thread count.
  std::atomic<Index> firstFailedBlock{ blockCount };

  const int threadCount = threads > 0 ? threads : omp_get_max_threads();
#pragma omp parallel num_threads(threadCount)
  {
    Scratch scratch;
#pragma omp for schedule(dynamic, 1)
    for (Index b = 0; b < blockCount; ++b)
    {
      if (b > firstFailedBlock.load())
      {
        continue;
      }
      Block &     block = blocks[b];
      const Index begin = b * kPointsPerBlock;
      const Index end = std::min(pointCount, begin + kPointsPerBlock);
      block.counts.reserve(end - begin);
      try
      {
        for (Index point = begin; point < end; ++point)
        {
          const Vector3 & x = points[point];
          std::string     reason;
          if (!x.allFinite())
          {
            reason = "has a non-finite coordinate. Check the point positions.";
          }
          else
          {
            reason = quadratic ? impl.ShapeFunctionsAt<10>(x, withGradients, scratch)
                               : impl.ShapeFunctionsAt<4>(x, withGradients, scratch);
          }
          if (!reason.empty())
          {
            block.failedPoint = point;
            block.message = pointLabel + " " + std::to_string(point) + " at " + FormatPoint(x) + " mm " + reason;
            break;
          }
          const std::size_t n = scratch.neighbours.size();
          block.counts.push_back(static_cast<Index>(n));
          block.nodes.insert(block.nodes.end(), scratch.neighbours.begin(), scratch.neighbours.end());
          block.values.insert(block.values.end(), scratch.phi.begin(), scratch.phi.begin() + n);
          if (withGradients)
          {
            for (std::size_t k = 0; k < n; ++k)
            {
              block.gradients.insert(block.gradients.end(), scratch.phiGradients[k].data(),
                                     scratch.phiGradients[k].data() + 3);
            }
          }
        }
      }
      catch (const std::exception & error)
      {
        block.failedPoint = std::max(begin, static_cast<Index>(begin + block.counts.size()));
        block.message = pointLabel + " " + std::to_string(block.failedPoint) + ": " + error.what();
      }
      if (block.failedPoint >= 0)
      {
        Index current = firstFailedBlock.load();
        while (b < current && !firstFailedBlock.compare_exchange_weak(current, b))
        {
        }
      }
    }
  }

  const Index failed = firstFailedBlock.load();
  if (failed < blockCount)
  {
    throw Error(blocks[failed].message);
  }

  // Offsets by prefix sum over blocks, then a parallel copy into place.
  ShapeFunctionTable table;
  std::vector<Index> blockStart(blockCount + 1, 0);
  for (Index b = 0; b < blockCount; ++b)
  {
    blockStart[b + 1] = blockStart[b] + static_cast<Index>(blocks[b].nodes.size());
  }
  table.offsets.resize(pointCount + 1);
  table.offsets[0] = 0;
  table.nodes.resize(blockStart[blockCount]);
  table.values.resize(blockStart[blockCount]);
  if (withGradients)
  {
    table.gradients.resize(3 * static_cast<std::size_t>(blockStart[blockCount]));
  }
#pragma omp parallel for num_threads(threadCount) schedule(static)
  for (Index b = 0; b < blockCount; ++b)
  {
    const Block & block = blocks[b];
    const Index   begin = b * kPointsPerBlock;
    Index         offset = blockStart[b];
    for (std::size_t k = 0; k < block.counts.size(); ++k)
    {
      offset += block.counts[k];
      table.offsets[begin + k + 1] = offset;
    }
    std::copy(block.nodes.begin(), block.nodes.end(), table.nodes.begin() + blockStart[b]);
    std::copy(block.values.begin(), block.values.end(), table.values.begin() + blockStart[b]);
    std::copy(block.gradients.begin(), block.gradients.end(), table.gradients.begin() + 3 * blockStart[b]);
  }
  return table;
}

Vector3
ShapeFunctionTable::Interpolate(Index point, const double * nodalValues) const
{
  Vector3 sum = Vector3::Zero();
  for (Index k = offsets[point]; k < offsets[point + 1]; ++k)
  {
    const double * v = nodalValues + 3 * static_cast<std::size_t>(nodes[k]);
    sum += values[k] * Vector3(v[0], v[1], v[2]);
  }
  return sum;
}

std::vector<Vector3>
InterpolateDisplacements(const MovingLeastSquares &   shapeFunctions,
                         const std::vector<Vector3> & nodalParameters,
                         const std::vector<Vector3> & points,
                         int                          threads)
{
  if (static_cast<Index>(nodalParameters.size()) != shapeFunctions.NodeCount())
  {
    throw Error("meshless displacement interpolation got " + std::to_string(nodalParameters.size()) +
                " nodal parameters for " + std::to_string(shapeFunctions.NodeCount()) +
                " nodes. Pass the solution's nodalParameters of this model.");
  }
  const ShapeFunctionTable table = shapeFunctions.Evaluate(points, false, threads, "interpolation point");
  std::vector<Vector3>     displacements(points.size());
  const double *           parameters = nodalParameters.empty() ? nullptr : nodalParameters.front().data();
  const int                threadCount = threads > 0 ? threads : omp_get_max_threads();
#pragma omp parallel for num_threads(threadCount) schedule(static)
  for (Index point = 0; point < table.PointCount(); ++point)
  {
    displacements[point] = table.Interpolate(point, parameters);
  }
  return displacements;
}

} // namespace bmr
