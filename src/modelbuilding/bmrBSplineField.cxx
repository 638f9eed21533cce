#include "bmrBSplineField.h"
#include "bmrThreads.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace bmr
{
namespace
{

/** Uniform cubic B-spline basis at t in [0, 1]: weights of controls i0 .. i0 + 3. */
inline void
CubicWeights(double t, double w[4])
{
  const double s = 1.0 - t;
  const double t2 = t * t;
  const double t3 = t2 * t;
  w[0] = s * s * s / 6.0;
  w[1] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0;
  w[2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0;
  w[3] = t3 / 6.0;
}

/** Span coordinate u in [0, spans] -> first control index and local parameter. */
inline void
Locate(double u, int spans, int & first, double & t)
{
  first = std::min(static_cast<int>(std::floor(u)), spans - 1);
  first = std::max(first, 0);
  t = u - first;
}

/** The lattice of `spans` per axis over the box of `domain`'s voxel centres. */
ImageGeometry
LatticeGeometry(const ImageGeometry & domain, const std::array<int, 3> & spans)
{
  ImageGeometry lattice;
  lattice.direction = domain.direction;
  for (int d = 0; d < 3; ++d)
  {
    lattice.size[d] = spans[d] + 3;
    lattice.spacing[d] = domain.spacing[d] * (domain.size[d] - 1) / spans[d];
  }
  // Control index 0 sits one spacing before the domain's first corner (cubic: (order - 1) / 2 = 1).
  lattice.origin = domain.origin - domain.direction * lattice.spacing;
  return lattice;
}

/** Exact refinement of a cubic B-spline lattice along `axis`: spans m -> 2m. */
std::vector<Vector3>
RefineAlongAxis(const std::vector<Vector3> & coarse, std::array<int, 3> & size, int axis)
{
  std::array<int, 3> fineSize = size;
  fineSize[axis] = 2 * size[axis] - 3;
  std::vector<Vector3> fine(static_cast<std::size_t>(fineSize[0]) * fineSize[1] * fineSize[2]);
  const std::size_t coarseStride = axis == 0 ? 1 : axis == 1 ? size[0] : static_cast<std::size_t>(size[0]) * size[1];
  for (int k = 0; k < fineSize[2]; ++k)
  {
    for (int j = 0; j < fineSize[1]; ++j)
    {
      for (int i = 0; i < fineSize[0]; ++i)
      {
        const int   index[3] = { i, j, k };
        const int   J = index[axis];
        int         coarseIndex[3] = { i, j, k };
        const std::size_t fineOffset =
          i + static_cast<std::size_t>(fineSize[0]) * (j + static_cast<std::size_t>(fineSize[1]) * k);
        Vector3     value;
        if (J % 2 == 1)
        {
          // A coarse control's position: (c[j-1] + 6 c[j] + c[j+1]) / 8.
          coarseIndex[axis] = (J + 1) / 2;
          const std::size_t c = coarseIndex[0] + static_cast<std::size_t>(size[0]) *
                                                   (coarseIndex[1] + static_cast<std::size_t>(size[1]) * coarseIndex[2]);
          value = (coarse[c - coarseStride] + 6.0 * coarse[c] + coarse[c + coarseStride]) / 8.0;
        }
        else
        {
          // Half-way between two coarse controls: (c[j] + c[j+1]) / 2.
          coarseIndex[axis] = J / 2;
          const std::size_t c = coarseIndex[0] + static_cast<std::size_t>(size[0]) *
                                                   (coarseIndex[1] + static_cast<std::size_t>(size[1]) * coarseIndex[2]);
          value = 0.5 * (coarse[c] + coarse[c + coarseStride]);
        }
        fine[fineOffset] = value;
      }
    }
  }
  size = fineSize;
  return fine;
}

/** One level's data: per point the first control index and the 64 weights. */
struct PointStencil
{
  std::size_t first = 0; // offset of control (i0, j0, k0)
  double      w[3][4];
};

PointStencil
Stencil(const Vector3 & spanCoordinates, const std::array<int, 3> & spans, const std::array<int, 3> & size)
{
  PointStencil stencil;
  int          first[3];
  for (int d = 0; d < 3; ++d)
  {
    double t = 0.0;
    Locate(spanCoordinates[d], spans[d], first[d], t);
    CubicWeights(t, stencil.w[d]);
  }
  stencil.first = first[0] + static_cast<std::size_t>(size[0]) * (first[1] + static_cast<std::size_t>(size[1]) * first[2]);
  return stencil;
}

Vector3
EvaluateStencil(const PointStencil & stencil, const std::vector<Vector3> & coefficients, const std::array<int, 3> & size)
{
  const std::size_t row = size[0];
  const std::size_t slice = row * size[1];
  Vector3           sum = Vector3::Zero();
  for (int c = 0; c < 4; ++c)
  {
    for (int b = 0; b < 4; ++b)
    {
      const double wyz = stencil.w[1][b] * stencil.w[2][c];
      const std::size_t base = stencil.first + c * slice + b * row;
      for (int a = 0; a < 4; ++a)
      {
        sum += (stencil.w[0][a] * wyz) * coefficients[base + a];
      }
    }
  }
  return sum;
}

} // namespace

Vector3
CubicBSplineLattice::Evaluate(const Vector3 & point) const
{
  const Vector3      local = geometry.PointToIndex(point); // continuous control index
  std::array<int, 3> spans;
  Vector3            u;
  for (int d = 0; d < 3; ++d)
  {
    spans[d] = geometry.size[d] - 3;
    u[d] = local[d] - 1.0;
    if (!(u[d] >= 0.0 && u[d] <= spans[d]))
    {
      return Vector3::Zero(); // outside the valid region, as ITK's BSplineTransform
    }
  }
  return EvaluateStencil(Stencil(u, spans, geometry.size), coefficients, geometry.size);
}

namespace
{
// Lee, Wolberg and Shin's B-spline approximation of `residual` at the points
// (`fraction` of the extent along each axis) on a lattice of `spans` (`size`
// control points per axis); the points' stencils into `stencils`.
std::vector<Vector3>
ApproximateResidual(const std::vector<Vector3> & fraction, const std::vector<Vector3> & residual,
                    const std::array<int, 3> & spans, const std::array<int, 3> & size,
                    std::vector<PointStencil> & stencils)
{
  const std::size_t count = fraction.size();
  const std::size_t controls = static_cast<std::size_t>(size[0]) * size[1] * size[2];
  const std::size_t row = size[0];
  const std::size_t slice = row * size[1];
  std::vector<Vector3> delta(controls, Vector3::Zero());
  std::vector<double>  omega(controls, 0.0);
  for (std::size_t n = 0; n < count; ++n)
  {
    const Vector3 u = fraction[n].cwiseProduct(Vector3(spans[0], spans[1], spans[2]));
    stencils[n] = Stencil(u, spans, size);
    const PointStencil & s = stencils[n];
    double               squares[3] = { 0.0, 0.0, 0.0 };
    for (int d = 0; d < 3; ++d)
    {
      for (int a = 0; a < 4; ++a)
      {
        squares[d] += s.w[d][a] * s.w[d][a];
      }
    }
    const double sumOfSquares = squares[0] * squares[1] * squares[2];
    for (int c = 0; c < 4; ++c)
    {
      for (int b = 0; b < 4; ++b)
      {
        const double      wyz = s.w[1][b] * s.w[2][c];
        const std::size_t base = s.first + c * slice + b * row;
        for (int a = 0; a < 4; ++a)
        {
          const double w = s.w[0][a] * wyz;
          delta[base + a] += (w * w * w / sumOfSquares) * residual[n];
          omega[base + a] += w * w;
        }
      }
    }
  }
  std::vector<Vector3> phi(controls, Vector3::Zero());
  for (std::size_t c = 0; c < controls; ++c)
  {
    if (omega[c] != 0.0)
    {
      phi[c] = delta[c] / omega[c];
    }
  }
  return phi;
}

} // namespace

BSplineFitResult
FitMultilevelBSpline(const std::vector<Vector3> & points,
                     const std::vector<Vector3> & values,
                     const ImageGeometry &        domain,
                     const BSplineFitSettings &   settings)
{
  if (points.size() != values.size() || points.empty())
  {
    throw Error("B-spline fit: " + std::to_string(points.size()) + " points and " + std::to_string(values.size()) +
                " values; give one value per point, at least one point");
  }
  if (!(settings.tolerance > 0.0) || !(settings.minimumSpacing > 0.0))
  {
    throw Error("B-spline fit: the tolerance and the minimum control-point spacing must be > 0 mm");
  }
  Vector3 extent;
  for (int d = 0; d < 3; ++d)
  {
    if (domain.size[d] < 2)
    {
      throw Error("B-spline fit: the domain has " + std::to_string(domain.size[d]) + " voxel(s) along axis " +
                  std::to_string(d) + "; it needs at least 2 along every axis");
    }
    extent[d] = domain.spacing[d] * (domain.size[d] - 1);
  }

  // Each point in the domain's frame, as a fraction of the extent along each axis.
  const std::size_t    count = points.size();
  std::vector<Vector3> fraction(count);
  for (std::size_t n = 0; n < count; ++n)
  {
    fraction[n] = (domain.direction.transpose() * (points[n] - domain.origin)).cwiseQuotient(extent);
    const double slack = 1e-9;
    if (!points[n].allFinite() || !values[n].allFinite())
    {
      throw Error("B-spline fit: point " + std::to_string(n) + " has a NaN or infinite position or value");
    }
    if ((fraction[n].array() < -slack).any() || (fraction[n].array() > 1.0 + slack).any())
    {
      std::ostringstream text;
      text << "B-spline fit: point " << n << " (" << points[n].transpose() << " mm) lies outside the domain ("
           << domain.Describe() << "); use a domain that holds every point";
      throw Error(text.str());
    }
    fraction[n] = fraction[n].cwiseMax(0.0).cwiseMin(1.0);
  }

  // First mesh: one span along the longest axis, about square spans elsewhere.
  const double       longest = extent.maxCoeff();
  std::array<int, 3> firstSpans;
  double             firstFinest = longest;
  for (int d = 0; d < 3; ++d)
  {
    firstSpans[d] = std::max(1, static_cast<int>(std::lround(extent[d] / longest)));
    firstFinest = std::min(firstFinest, extent[d] / firstSpans[d]);
  }
  const int maximumLevels =
    1 + static_cast<int>(std::max(0.0, std::floor(std::log2(firstFinest / settings.minimumSpacing))));

  BSplineFitResult     result;
  std::vector<Vector3> residual(values);
  std::vector<Vector3> total;
  std::array<int, 3>   totalSize{ 0, 0, 0 };
  std::array<int, 3>   spans = firstSpans;
  std::vector<PointStencil> stencils(count);
  for (int level = 0; level < maximumLevels; ++level)
  {
    if (level > 0)
    {
      for (int d = 0; d < 3; ++d)
      {
        spans[d] *= 2;
      }
    }
    const std::array<int, 3> size{ spans[0] + 3, spans[1] + 3, spans[2] + 3 };
    const std::size_t        controls = static_cast<std::size_t>(size[0]) * size[1] * size[2];
      std::vector<Vector3> phi = ApproximateResidual(fraction, residual, spans, size, stencils);

    // What is left for the next level, and the sum of the levels as one lattice.
    double largest = 0.0;
    for (std::size_t n = 0; n < count; ++n)
    {
      residual[n] -= EvaluateStencil(stencils[n], phi, size);
      largest = std::max(largest, residual[n].norm());
    }
    if (!total.empty())
    {
      for (int axis = 0; axis < 3; ++axis)
      {
        total = RefineAlongAxis(total, totalSize, axis);
      }
      for (std::size_t c = 0; c < controls; ++c)
      {
        phi[c] += total[c];
      }
    }
    total = std::move(phi);
    totalSize = size;
    result.levels = level + 1;
    if (largest <= settings.tolerance)
    {
      break;
    }
  }

  result.lattice.geometry = LatticeGeometry(domain, spans);
  result.lattice.coefficients = std::move(total);
  for (int d = 0; d < 3; ++d)
  {
    result.meshSize[d] = spans[d];
    result.controlPointSpacing[d] = result.lattice.geometry.spacing[d];
  }
  // The residual of the final lattice itself, not of the level bookkeeping.
  double sumOfSquares = 0.0;
  for (std::size_t n = 0; n < count; ++n)
  {
    const Vector3 u = fraction[n].cwiseProduct(Vector3(spans[0], spans[1], spans[2]));
    const double  r = (values[n] - EvaluateStencil(Stencil(u, spans, totalSize), result.lattice.coefficients, totalSize)).norm();
    result.maximumResidual = std::max(result.maximumResidual, r);
    sumOfSquares += r * r;
  }
  result.rmsResidual = std::sqrt(sumOfSquares / static_cast<double>(count));
  result.toleranceReached = result.maximumResidual <= settings.tolerance;
  return result;
}

void
SampleBSplineField(const CubicBSplineLattice & lattice, const ImageGeometry & grid, double * out, int threads)
{
  if (!grid.direction.isApprox(lattice.geometry.direction, 1e-6))
  {
    throw Error("B-spline sampling: the grid's direction differs from the lattice's; resample through the "
                "transform instead");
  }
  const std::array<int, 3> & size = lattice.geometry.size;
  for (int d = 0; d < 3; ++d)
  {
    if (size[d] < 4)
    {
      throw Error("B-spline sampling: the lattice has " + std::to_string(size[d]) +
                  " control points along an axis; a cubic spline needs at least 4");
    }
  }
  if (lattice.coefficients.size() != lattice.geometry.VoxelCount())
  {
    throw Error("B-spline sampling: the lattice has " + std::to_string(lattice.coefficients.size()) +
                " coefficients for " + std::to_string(lattice.geometry.VoxelCount()) + " control points");
  }

  // Per axis: the control index and weights of every grid line (the grid and
  // the lattice share their directions, so the span coordinate along an axis
  // depends on the grid index along that axis only).
  struct AxisStencil
  {
    std::vector<int>                   first;
    std::vector<std::array<double, 4>> w;
    std::vector<char>                  valid;
  };
  std::array<AxisStencil, 3> axes;
  const Vector3              offset = lattice.geometry.direction.transpose() * (grid.origin - lattice.geometry.origin);
  for (int d = 0; d < 3; ++d)
  {
    const int spans = size[d] - 3;
    axes[d].first.resize(grid.size[d]);
    axes[d].w.resize(grid.size[d]);
    axes[d].valid.resize(grid.size[d]);
    for (int i = 0; i < grid.size[d]; ++i)
    {
      const double u = (offset[d] + grid.spacing[d] * i) / lattice.geometry.spacing[d] - 1.0;
      axes[d].valid[i] = u >= 0.0 && u <= spans;
      double t = 0.0;
      Locate(u, spans, axes[d].first[i], t);
      CubicWeights(t, axes[d].w[i].data());
    }
  }

  const std::size_t row = size[0];
  const std::size_t slice = row * size[1];
  const std::size_t gridRow = grid.size[0];
  const std::size_t gridSlice = gridRow * grid.size[1];
#pragma omp parallel num_threads(ThreadCount(threads))
  {
    std::vector<Vector3> collapsedZ(slice);
    std::vector<Vector3> collapsedY(row);
#pragma omp for schedule(static)
    for (int k = 0; k < grid.size[2]; ++k)
    {
      double * sliceOut = out + 3 * gridSlice * k;
      if (!axes[2].valid[k])
      {
        std::fill(sliceOut, sliceOut + 3 * gridSlice, 0.0);
        continue;
      }
      const std::size_t zFirst = axes[2].first[k] * slice;
      for (std::size_t c = 0; c < slice; ++c)
      {
        collapsedZ[c] = axes[2].w[k][0] * lattice.coefficients[zFirst + c] +
                        axes[2].w[k][1] * lattice.coefficients[zFirst + slice + c] +
                        axes[2].w[k][2] * lattice.coefficients[zFirst + 2 * slice + c] +
                        axes[2].w[k][3] * lattice.coefficients[zFirst + 3 * slice + c];
      }
      for (int j = 0; j < grid.size[1]; ++j)
      {
        double * rowOut = sliceOut + 3 * gridRow * j;
        if (!axes[1].valid[j])
        {
          std::fill(rowOut, rowOut + 3 * gridRow, 0.0);
          continue;
        }
        const std::size_t yFirst = axes[1].first[j] * row;
        const auto &      wy = axes[1].w[j];
        for (std::size_t c = 0; c < row; ++c)
        {
          collapsedY[c] = wy[0] * collapsedZ[yFirst + c] + wy[1] * collapsedZ[yFirst + row + c] +
                          wy[2] * collapsedZ[yFirst + 2 * row + c] + wy[3] * collapsedZ[yFirst + 3 * row + c];
        }
        for (int i = 0; i < grid.size[0]; ++i)
        {
          Vector3 value = Vector3::Zero();
          if (axes[0].valid[i])
          {
            const int    x = axes[0].first[i];
            const auto & wx = axes[0].w[i];
            value = wx[0] * collapsedY[x] + wx[1] * collapsedY[x + 1] + wx[2] * collapsedY[x + 2] +
                    wx[3] * collapsedY[x + 3];
          }
          rowOut[3 * i] = value[0];
          rowOut[3 * i + 1] = value[1];
          rowOut[3 * i + 2] = value[2];
        }
      }
    }
  }
}

} // namespace bmr
