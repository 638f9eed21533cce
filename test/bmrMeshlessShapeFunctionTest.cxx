// MLS shape functions: polynomial reproduction (linear basis, modified
// quadratic basis), exact derivatives, determinism, error messages and
// displacement interpolation.
#include "bmrMeshGenerators.h"
#include "bmrMeshless.h"
#include "bmrTemporaryFolderTest.h"
#include "bmrTestUtilities.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <cstring>
#include <map>
#include <random>
#include <vector>

namespace bmr
{
namespace test
{
namespace
{

// A 10 mm cube of (divisions + 1)^3 nodes, interior nodes moved randomly by up
// to a quarter of the grid spacing.
std::vector<Vector3>
JitteredCloud(int divisions, std::uint32_t seed = 7)
{
  Model model = MakeBlockMesh(Vector3(10, 10, 10), { divisions, divisions, divisions }, GridCells::Hexahedra);
  DistortInteriorNodes(model, 0.25, seed);
  return model.nodes;
}

std::vector<Vector3>
RandomPoints(int count, const Vector3 & low, const Vector3 & high, std::uint32_t seed = 11)
{
  std::mt19937                           generator(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<Vector3>                   points(count);
  for (auto & p : points)
  {
    for (int d = 0; d < 3; ++d)
    {
      p[d] = low[d] + (high[d] - low[d]) * unit(generator);
    }
  }
  return points;
}

MlsSettings
Settings(MlsBasis basis, double dilatation = 2.0)
{
  MlsSettings settings;
  settings.basis = basis;
  settings.dilatation = dilatation;
  return settings;
}

Vector3
Gradient(const ShapeFunctionTable & table, Index entry)
{
  return Vector3(table.gradients[3 * entry], table.gradients[3 * entry + 1], table.gradients[3 * entry + 2]);
}

// A vector field of 3 components, each c + b.X + X^T Q X (Q symmetric), with
// its exact gradient (row c = d u_c / dX).
struct PolynomialField
{
  Vector3                constant;
  Matrix3                linear;
  std::array<Matrix3, 3> quadratic;

  Vector3 operator()(const Vector3 & X) const
  {
    Vector3 u = constant + linear * X;
    for (int c = 0; c < 3; ++c)
    {
      u[c] += X.dot(quadratic[c] * X);
    }
    return u;
  }
  Matrix3 Gradient(const Vector3 & X) const
  {
    Matrix3 g = linear;
    for (int c = 0; c < 3; ++c)
    {
      g.row(c) += 2.0 * (quadratic[c] * X).transpose();
    }
    return g;
  }
};

PolynomialField
MakeField(bool withQuadratic)
{
  PolynomialField field;
  field.constant = Vector3(0.3, -1.2, 2.5);
  field.linear << 0.11, -0.42, 0.27, 0.05, 0.31, -0.19, -0.23, 0.08, 0.44;
  for (int c = 0; c < 3; ++c)
  {
    field.quadratic[c].setZero();
    if (withQuadratic)
    {
      Matrix3 q;
      q << 0.03 * (c + 1), -0.02, 0.01 * c, 0.015, -0.025, 0.02, -0.01 * c, 0.035, 0.012 * (2 - c);
      field.quadratic[c] = 0.5 * (q + q.transpose());
    }
  }
  return field;
}

// Largest errors of the MLS approximation of `field` (values relative to the
// largest nodal value, gradients relative to the largest gradient), of the
// partition of unity and of sum grad phi = 0, over all points of the table.
struct ReproductionErrors
{
  double value = 0.0;
  double gradient = 0.0;
  double partition = 0.0;
  double gradientSum = 0.0;
  bool   finite = true;
};

ReproductionErrors
Reproduction(const MovingLeastSquares &   mls,
             const ShapeFunctionTable &   table,
             const std::vector<Vector3> & points,
             const PolynomialField &      field)
{
  std::vector<Vector3> nodal;
  double               valueScale = 0.0;
  for (const auto & X : mls.Nodes())
  {
    nodal.push_back(field(X));
    valueScale = std::max(valueScale, nodal.back().norm());
  }
  ReproductionErrors errors;
  for (Index p = 0; p < table.PointCount(); ++p)
  {
    Vector3 u = Vector3::Zero();
    Matrix3 g = Matrix3::Zero();
    double  sum = 0.0;
    Vector3 gradientSum = Vector3::Zero();
    for (Index k = table.offsets[p]; k < table.offsets[p + 1]; ++k)
    {
      const Index node = table.nodes[k];
      u += table.values[k] * nodal[node];
      g += nodal[node] * Gradient(table, k).transpose();
      sum += table.values[k];
      gradientSum += Gradient(table, k);
      errors.finite = errors.finite && std::isfinite(table.values[k]) && Gradient(table, k).allFinite();
    }
    const Matrix3 exact = field.Gradient(points[p]);
    errors.value = std::max(errors.value, (u - field(points[p])).norm() / valueScale);
    errors.gradient = std::max(errors.gradient, (g - exact).norm() / std::max(exact.norm(), 1e-300));
    errors.partition = std::max(errors.partition, std::abs(sum - 1.0));
    errors.gradientSum = std::max(errors.gradientSum, gradientSum.norm());
  }
  return errors;
}

// Reciprocal condition number (min / max eigenvalue) of a symmetric matrix.
template <class MatrixType>
double
ReciprocalCondition(const MatrixType & matrix)
{
  const Eigen::SelfAdjointEigenSolver<MatrixType> eigen(matrix, Eigen::EigenvaluesOnly);
  return eigen.eigenvalues()(0) / eigen.eigenvalues()(eigen.eigenvalues().size() - 1);
}

// The plain (unregularised) quadratic moment matrix at x from the
// neighbours in row p of the table, in coordinates scaled by their mean
// support radius, recomputed independently of the implementation.
Eigen::Matrix<double, 10, 10>
PlainQuadraticMoment(const MovingLeastSquares & mls, const ShapeFunctionTable & table, Index p, const Vector3 & x)
{
  double scale = 0.0;
  for (Index k = table.offsets[p]; k < table.offsets[p + 1]; ++k)
  {
    scale += mls.SupportRadius(table.nodes[k]);
  }
  scale /= (table.offsets[p + 1] - table.offsets[p]);
  Eigen::Matrix<double, 10, 10> moment = Eigen::Matrix<double, 10, 10>::Zero();
  for (Index k = table.offsets[p]; k < table.offsets[p + 1]; ++k)
  {
    const Index                  node = table.nodes[k];
    const double                 s = (mls.Nodes()[node] - x).norm() / mls.SupportRadius(node);
    const double                 w = 1.0 - 6.0 * s * s + 8.0 * s * s * s - 3.0 * s * s * s * s;
    const Vector3                q = (mls.Nodes()[node] - x) / scale;
    Eigen::Matrix<double, 10, 1> b;
    b << 1, q.x(), q.y(), q.z(), q.x() * q.x(), q.y() * q.y(), q.z() * q.z(), q.x() * q.y(), q.y() * q.z(),
      q.z() * q.x();
    moment += w * b * b.transpose();
  }
  return moment;
}

} // namespace

TEST(MlsShapeFunctions, NodalSpacingAndSupportRadiusOnRegularGrid)
{
  const Model              grid = MakeBlockMesh(Vector3(10, 10, 10), { 5, 5, 5 }, GridCells::Hexahedra);
  const MovingLeastSquares mls(grid.nodes, Settings(MlsBasis::Linear, 2.5));
  // Node (2, 2, 2) of the grid: its 6 nearest nodes are the face neighbours at 2 mm.
  const Index interior = 2 + 6 * (2 + 6 * 2);
  ASSERT_TRUE(grid.nodes[interior].isApprox(Vector3(4, 4, 4)));
  EXPECT_NEAR(mls.NodalSpacing(interior), 2.0, 1e-12);
  EXPECT_NEAR(mls.SupportRadius(interior), 5.0, 1e-12);
  // A corner node has 3 neighbours at 2 mm and 3 at 2 sqrt(2) mm.
  EXPECT_NEAR(mls.NodalSpacing(0), (3.0 * 2.0 + 3.0 * 2.0 * std::sqrt(2.0)) / 6.0, 1e-12);
  EXPECT_EQ(mls.NodeCount(), 216);
}

TEST(MlsShapeFunctions, LinearBasisReproducesLinearFields)
{
  const MovingLeastSquares mls(JitteredCloud(6), Settings(MlsBasis::Linear));
  const auto               points = RandomPoints(200, Vector3(0.5, 0.5, 0.5), Vector3(9.5, 9.5, 9.5));
  const ShapeFunctionTable table = mls.Evaluate(points, true, 1, "integration point");
  const ReproductionErrors errors = Reproduction(mls, table, points, MakeField(false));
  ASSERT_EQ(table.PointCount(), 200);
  EXPECT_TRUE(errors.finite);
  EXPECT_LT(errors.value, 1e-10);
  EXPECT_LT(errors.gradient, 1e-10);
  EXPECT_LT(errors.partition, 1e-10);
  EXPECT_LT(errors.gradientSum, 1e-10);
  // Rows are ascending and not trivially small.
  for (Index p = 0; p < table.PointCount(); ++p)
  {
    EXPECT_GE(table.offsets[p + 1] - table.offsets[p], 4);
    EXPECT_TRUE(std::is_sorted(table.nodes.begin() + table.offsets[p], table.nodes.begin() + table.offsets[p + 1]));
  }
  // The linear basis does not reproduce a quadratic field: the check above can fail.
  EXPECT_GT(Reproduction(mls, table, points, MakeField(true)).value, 1e-4);
  RecordProperty("linearValueError", Sci(errors.value));
}

TEST(MlsShapeFunctions, ModifiedQuadraticReproducesQuadraticFields)
{
  // Where the plain quadratic moment matrix is well conditioned (checked
  // below), a regularisation mu changes the fit only by ~mu^2: with mu = 1e-6
  // quadratics are reproduced to round-off. (The default mu = 1e-3, chosen for
  // robustness on nearly degenerate clouds, reproduces them to ~4e-7.) On this
  // jittered cloud that holds at dilatation 2 (~35 neighbours per point) and
  // at 3.5 (~150).
  const auto nodes = JitteredCloud(6);
  const auto points = RandomPoints(100, Vector3(1, 1, 1), Vector3(9, 9, 9));
  for (double dilatation : { 2.0, 3.5 })
  {
    SCOPED_TRACE("dilatation " + std::to_string(dilatation));
    MlsSettings settings = Settings(MlsBasis::ModifiedQuadratic, dilatation);
    settings.quadraticRegularization = 1e-6;
    const MovingLeastSquares mls(nodes, settings);
    const ShapeFunctionTable table = mls.Evaluate(points, true, 1, "integration point");
    for (Index p = 0; p < table.PointCount(); ++p)
    {
      ASSERT_GT(ReciprocalCondition(PlainQuadraticMoment(mls, table, p, points[p])), 1e-6) << "point " << p;
    }
    const ReproductionErrors quadratic = Reproduction(mls, table, points, MakeField(true));
    EXPECT_TRUE(quadratic.finite);
    EXPECT_LT(quadratic.value, 1e-10);
    EXPECT_LT(quadratic.gradient, 1e-10);
    EXPECT_LT(quadratic.partition, 1e-10);
    EXPECT_LT(quadratic.gradientSum, 1e-10);
    RecordProperty("quadraticValueError" + std::to_string(int(10 * dilatation)), Sci(quadratic.value));
    RecordProperty("quadraticGradientError" + std::to_string(int(10 * dilatation)), Sci(quadratic.gradient));
  }
  // A strong regularisation visibly damps the quadratic terms: the tolerance
  // above is meaningful.
  MlsSettings settings = Settings(MlsBasis::ModifiedQuadratic, 3.5);
  settings.quadraticRegularization = 1e-2;
  const MovingLeastSquares damped(nodes, settings);
  EXPECT_GT(Reproduction(damped, damped.Evaluate(points, true, 1), points, MakeField(true)).value, 1e-7);
}

TEST(MlsShapeFunctions, ModifiedQuadraticReproducesLinearFieldsAtLinearDensity)
{
  // Default settings on the jittered cloud (the density chosen for the linear basis).
  {
    const MovingLeastSquares mls(JitteredCloud(6), Settings(MlsBasis::ModifiedQuadratic));
    const auto               points = RandomPoints(200, Vector3(0.5, 0.5, 0.5), Vector3(9.5, 9.5, 9.5));
    const ShapeFunctionTable table = mls.Evaluate(points, true, 1, "integration point");
    const ReproductionErrors errors = Reproduction(mls, table, points, MakeField(false));
    EXPECT_TRUE(errors.finite);
    EXPECT_LT(errors.value, 1e-10);
    EXPECT_LT(errors.gradient, 1e-10);
    EXPECT_LT(errors.partition, 1e-10);
    EXPECT_LT(errors.gradientSum, 1e-10);
  }
  // A slab one cell thick: all nodes lie on the planes z = 0 and z = 2, so
  // z^2 - 2z vanishes at every node and the plain quadratic moment matrix is
  // singular, while the linear block is well conditioned. The regularised
  // matrix still gives finite shape functions that reproduce linear fields.
  const Model              slab = MakeBlockMesh(Vector3(10, 10, 2), { 5, 5, 1 }, GridCells::Hexahedra);
  const MovingLeastSquares mls(slab.nodes, Settings(MlsBasis::ModifiedQuadratic));
  const auto               points = RandomPoints(100, Vector3(2, 2, 0.1), Vector3(8, 8, 1.9));
  const ShapeFunctionTable table = mls.Evaluate(points, true, 1, "integration point");
  for (Index p = 0; p < table.PointCount(); ++p)
  {
    const auto moment = PlainQuadraticMoment(mls, table, p, points[p]);
    ASSERT_LT(ReciprocalCondition(moment), 1e-14) << "point " << p;
    ASSERT_GT(ReciprocalCondition(Eigen::Matrix4d(moment.topLeftCorner<4, 4>())), 1e-3) << "point " << p;
  }
  const ReproductionErrors errors = Reproduction(mls, table, points, MakeField(false));
  EXPECT_TRUE(errors.finite);
  EXPECT_LT(errors.value, 1e-10);
  EXPECT_LT(errors.gradient, 1e-10);
  EXPECT_LT(errors.partition, 1e-10);
  EXPECT_LT(errors.gradientSum, 1e-10);
  RecordProperty("slabLinearValueError", Sci(errors.value));
}

TEST(MlsShapeFunctions, DerivativesMatchCentralDifferences)
{
  const auto nodes = JitteredCloud(5);
  const auto points = RandomPoints(40, Vector3(0.5, 0.5, 0.5), Vector3(9.5, 9.5, 9.5), 23);
  for (MlsBasis basis : { MlsBasis::Linear, MlsBasis::ModifiedQuadratic })
  {
    SCOPED_TRACE(basis == MlsBasis::Linear ? "linear" : "modified quadratic");
    const MovingLeastSquares mls(nodes, Settings(basis));
    const ShapeFunctionTable table = mls.Evaluate(points, true, 1);
    // Shifted copies of the points: +h and -h along each axis.
    const double         h = 1e-5; // mm; the nodal spacing is 2 mm
    std::vector<Vector3> shifted;
    for (const auto & x : points)
    {
      for (int d = 0; d < 3; ++d)
      {
        shifted.push_back(x + h * Vector3::Unit(d));
        shifted.push_back(x - h * Vector3::Unit(d));
      }
    }
    const ShapeFunctionTable values = mls.Evaluate(shifted, false, 1);
    auto                     valueAt = [&](Index point, Index node)
    {
      for (Index k = values.offsets[point]; k < values.offsets[point + 1]; ++k)
      {
        if (values.nodes[k] == node)
        {
          return values.values[k];
        }
      }
      return 0.0; // outside the node's support
    };
    double worst = 0.0;
    for (Index p = 0; p < table.PointCount(); ++p)
    {
      double scale = 0.0;
      for (Index k = table.offsets[p]; k < table.offsets[p + 1]; ++k)
      {
        scale = std::max(scale, Gradient(table, k).norm());
      }
      for (Index k = table.offsets[p]; k < table.offsets[p + 1]; ++k)
      {
        Vector3 difference;
        for (int d = 0; d < 3; ++d)
        {
          difference[d] =
            (valueAt(6 * p + 2 * d, table.nodes[k]) - valueAt(6 * p + 2 * d + 1, table.nodes[k])) / (2.0 * h);
        }
        worst = std::max(worst, (difference - Gradient(table, k)).norm() / scale);
      }
    }
    EXPECT_LT(worst, 1e-6);
    RecordProperty(basis == MlsBasis::Linear ? "linearDerivativeError" : "quadraticDerivativeError", Sci(worst));
  }
}

TEST(MlsShapeFunctions, IdenticalForOneAndTwoThreads)
{
  const auto nodes = JitteredCloud(6);
  const auto points = RandomPoints(1500, Vector3(0, 0, 0), Vector3(10, 10, 10), 5); // several blocks of rows
  for (MlsBasis basis : { MlsBasis::Linear, MlsBasis::ModifiedQuadratic })
  {
    const MovingLeastSquares mls(nodes, Settings(basis));
    const ShapeFunctionTable one = mls.Evaluate(points, true, 1);
    const ShapeFunctionTable two = mls.Evaluate(points, true, 2);
    EXPECT_EQ(one.offsets, two.offsets);
    EXPECT_EQ(one.nodes, two.nodes);
    ASSERT_EQ(one.values.size(), two.values.size());
    ASSERT_EQ(one.gradients.size(), two.gradients.size());
    EXPECT_EQ(0, std::memcmp(one.values.data(), two.values.data(), one.values.size() * sizeof(double)));
    EXPECT_EQ(0, std::memcmp(one.gradients.data(), two.gradients.data(), one.gradients.size() * sizeof(double)));
    EXPECT_EQ(one.gradients.size(), 3 * one.values.size());
    EXPECT_TRUE(mls.Evaluate(points, false, 2).gradients.empty());
  }
}

TEST(MlsShapeFunctions, PointWithTooFewNeighboursThrows)
{
  const MovingLeastSquares mls(JitteredCloud(4), Settings(MlsBasis::Linear));
  std::vector<Vector3>     points = { Vector3(5, 5, 5), Vector3(2, 3, 4), Vector3(7, 7, 7), Vector3(40, 5, 5) };
  const std::string        message = ErrorMessage([&] { mls.Evaluate(points, true, 2, "integration point"); });
  EXPECT_CONTAINS(message, "integration point 3 at (40, 5, 5) mm");
  EXPECT_CONTAINS(message, "0 MLS neighbours");
  EXPECT_CONTAINS(message, "Increase the dilatation (now 2)");
  // Just outside a face, the point sees only a few nodes.
  points[3] = Vector3(13.5, 5, 5);
  EXPECT_CONTAINS(ErrorMessage([&] { mls.Evaluate(points, false, 1, "sample"); }), "sample 3 at (13.5, 5, 5) mm");
}

TEST(MlsShapeFunctions, CoplanarNeighboursThrow)
{
  // A planar node cloud: every moment matrix is singular.
  std::vector<Vector3> plane;
  for (int i = 0; i < 6; ++i)
  {
    for (int j = 0; j < 6; ++j)
    {
      plane.emplace_back(2.0 * i, 1.5 * j + 0.1 * i, 0.0);
    }
  }
  MlsSettings              settings = Settings(MlsBasis::ModifiedQuadratic, 2.5);
  const MovingLeastSquares mls(plane, settings);
  const std::string message = ErrorMessage([&] { mls.Evaluate({ Vector3(5, 4, 0) }, true, 1, "integration point"); });
  EXPECT_CONTAINS(message, "integration point 0 at (5, 4, 0) mm has an ill-conditioned MLS moment matrix");
  EXPECT_CONTAINS(message, "coplanar");
  EXPECT_CONTAINS(message, "Increase the dilatation (now 2.5)");
  // The first failing point is reported, whatever the thread count.
  std::vector<Vector3> points(1000, Vector3(5, 4, 0));
  EXPECT_CONTAINS(ErrorMessage([&] { mls.Evaluate(points, false, 2, "p"); }), "p 0 at");
}

TEST(MlsShapeFunctions, DuplicateNodesAndBadSettingsThrow)
{
  std::vector<Vector3> nodes = JitteredCloud(3);
  const Index          last = static_cast<Index>(nodes.size());
  {
    std::vector<Vector3> duplicated = nodes;
    duplicated.push_back(nodes[5]);
    const std::string message = ErrorMessage([&] { MovingLeastSquares(duplicated, Settings(MlsBasis::Linear)); });
    EXPECT_CONTAINS(message, "MLS nodes 5 and " + std::to_string(last) + " coincide");
  }
  EXPECT_CONTAINS(ErrorMessage(
                    [&] {
                      MovingLeastSquares({ Vector3(0, 0, 0), Vector3(1, 0, 0), Vector3(0, 1, 0) }, MlsSettings());
                    }),
                  "at least 4 nodes");
  {
    std::vector<Vector3> broken = nodes;
    broken[7].y() = std::nan("");
    EXPECT_CONTAINS(ErrorMessage([&] { MovingLeastSquares(broken, MlsSettings()); }), "MLS node 7 has a non-finite");
  }
  for (double dilatation : { 1.0, 0.5, 10.5, std::nan("") })
  {
    EXPECT_CONTAINS(ErrorMessage([&] { MovingLeastSquares(nodes, Settings(MlsBasis::Linear, dilatation)); }),
                    "MLS dilatation");
  }
  for (double mu : { 0.0, -1e-6, 1e-9, 2.0, std::nan("") })
  {
    MlsSettings settings = Settings(MlsBasis::ModifiedQuadratic);
    settings.quadraticRegularization = mu;
    EXPECT_CONTAINS(ErrorMessage([&] { MovingLeastSquares(nodes, settings); }), "MLS quadratic regularisation");
    settings.basis = MlsBasis::Linear; // unused by the linear basis
    EXPECT_NO_THROW(MovingLeastSquares(nodes, settings));
  }
  const MovingLeastSquares mls(nodes, MlsSettings());
  EXPECT_CONTAINS(ErrorMessage([&] { mls.Evaluate({ Vector3(1, std::nan(""), 1) }, false, 1, "point"); }),
                  "point 0 at");
}

TEST(MlsShapeFunctions, InterpolateDisplacementsReproducesLinearField)
{
  const MovingLeastSquares mls(JitteredCloud(5), Settings(MlsBasis::Linear));
  const PolynomialField    field = MakeField(false);
  std::vector<Vector3>     parameters;
  for (const auto & X : mls.Nodes())
  {
    parameters.push_back(field(X));
  }
  const auto                 points = RandomPoints(300, Vector3(0, 0, 0), Vector3(10, 10, 10), 3);
  const std::vector<Vector3> u = InterpolateDisplacements(mls, parameters, points, 2);
  ASSERT_EQ(u.size(), points.size());
  double error = 0.0;
  for (std::size_t p = 0; p < points.size(); ++p)
  {
    error = std::max(error, (u[p] - field(points[p])).norm());
  }
  EXPECT_LT(error, 1e-10 * MaxNorm(parameters));
  parameters.pop_back();
  EXPECT_CONTAINS(ErrorMessage([&] { InterpolateDisplacements(mls, parameters, points, 1); }), "nodal parameters");
}

} // namespace test
} // namespace bmr
