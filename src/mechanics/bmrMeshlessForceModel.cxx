#include "bmrForceModel.h"

#include "bmrConstitutiveLaw.h"
#include "bmrUnits.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>

namespace bmr
{
// How far ahead (in floats, 1 KiB) the force kernel asks for its streamed
// shape-function gradients. The hardware prefetcher alone left the kernel
// waiting on that stream: 129 -> 105-110 ns per point-step with one thread,
// 76 -> 66 with two (brain-sized model, 2026-11-26); the same prefetch made
// the element kernels slower, so they do without.
constexpr std::size_t kGradientPrefetchDistance = 256;

MeshlessForceModel::MeshlessForceModel(const Model &          model,
                                       ShapeFunctionTable     shapeFunctions,
                                       const SolverSettings & settings,
                                       int                    threads)
  : m_Threads(std::max(1, threads))
  , m_NodeCount(static_cast<Index>(model.nodes.size()))
  , m_Positions(model.meshless.integrationPoints)
  , m_Weight(model.meshless.integrationWeights)
{
  // The table is needed only to build the kernel's copy: keeping it as well
  // would hold every entry twice (and its unused values) through the solve.
  const ShapeFunctionTable table = std::move(shapeFunctions);
  const Index              pointCount = table.PointCount();
  if (pointCount != static_cast<Index>(m_Positions.size()) ||
      table.gradients.size() != 3 * table.nodes.size())
  {
    throw Error("meshless force model: the shape-function table does not match the integration points "
                "(internal error; please report it).");
  }
  m_Mu.resize(pointCount);
  m_Kappa.resize(pointCount);
  m_Density.resize(pointCount);
  m_WaveBound.resize(pointCount);
  for (Index p = 0; p < pointCount; ++p)
  {
    const Material & material = model.materials[model.meshless.integrationMaterials[p]];
    m_Mu[p] = material.ShearModulus() * units::PascalToInternal;
    m_Kappa[p] = material.BulkModulus() * units::PascalToInternal;
    m_Density[p] = material.density * units::DensityToInternal;
    // Element-by-element bound on the highest frequency with the point's mass
    // shared equally by its n neighbours: omega^2 <= (lambda + 2 mu) n sum|grad phi|^2 / rho,
    // the same bound as the finite elements' n B:B.
    double gradientSquares = 0.0;
    for (Index k = table.offsets[p]; k < table.offsets[p + 1]; ++k)
    {
      for (int j = 0; j < 3; ++j)
      {
        gradientSquares += table.gradients[3 * k + j] * table.gradients[3 * k + j];
      }
    }
    const Index neighbours = table.offsets[p + 1] - table.offsets[p];
    m_WaveBound[p] = (m_Kappa[p] + 4.0 * m_Mu[p] / 3.0) * neighbours * gradientSquares;
  }
  // The collapse barrier's modulus raises dynamic relaxation's masses where it engages.
  m_Collapse = CollapseModuli(m_Kappa, m_Weight, settings.collapseBulkModulus);

  std::vector<Index> pointsOfNode(m_NodeCount, 0);
  for (const Index node : table.nodes)
  {
    ++pointsOfNode[node];
  }
  for (Index n = 0; n < m_NodeCount; ++n)
  {
    if (pointsOfNode[n] == 0)
    {
      std::ostringstream message;
      const Vector3 &    x = model.nodes[n];
      message << "meshless model: node " << n << " at " << FormatPoint(x)
              << " mm lies in the support of no integration point, so it has neither mass nor stiffness. "
                 "Use smaller background cells or more integration points per cell, increase the dilatation, "
                 "or remove the node if it lies outside the body.";
      throw Error(message.str());
    }
  }

  // The kernel's table in schedule order.
  const ColouredSchedule schedule =
    ScheduleWork(table.offsets, table.nodes, m_Positions, BoundingBox(model.nodes), m_NodeCount, kPointsPerBlock);
  m_KernelPoint = schedule.items;
  m_Numbering = MortonNumbering(model.nodes);
  m_KernelBlockOffsets = schedule.blockOffsets;
  m_KernelColourOffsets = schedule.colourOffsets;
  m_PaddedDisplacements.assign(4 * static_cast<std::size_t>(m_NodeCount), 0.0);
  m_PaddedForces.assign(4 * static_cast<std::size_t>(m_NodeCount), 0.0);
  m_KernelOffsets.assign(1, 0);
  m_KernelNodes.reserve(table.nodes.size());
  m_KernelGradients.reserve(table.gradients.size());
  m_KernelMaterial.reserve(4 * static_cast<std::size_t>(pointCount));
  for (const Index p : m_KernelPoint)
  {
    for (Index k = table.offsets[p]; k < table.offsets[p + 1]; ++k)
    {
      m_KernelNodes.push_back(m_Numbering.Slot(table.nodes[k]));
      for (int j = 0; j < 3; ++j)
      {
        m_KernelGradients.push_back(static_cast<float>(table.gradients[3 * k + j]));
      }
    }
    m_KernelOffsets.push_back(static_cast<Index>(m_KernelNodes.size()));
    m_KernelMaterial.insert(m_KernelMaterial.end(), { m_Weight[p], m_Mu[p], m_Kappa[p], m_Collapse[p] });
  }
  m_KernelGradients.push_back(0.0f); // the last entry's 4-float load (LoadGradient)
  m_KernelIndexOfPoint.resize(pointCount);
  for (Index q = 0; q < pointCount; ++q)
  {
    m_KernelIndexOfPoint[m_KernelPoint[q]] = q;
  }
  m_KernelSecondModulus = SecondInvariantModuli(
    static_cast<std::size_t>(pointCount),
    [&](std::size_t q) -> const Material & {
      return model.materials[model.meshless.integrationMaterials[m_KernelPoint[q]]];
    },
    units::PascalToInternal);
}

Eigen::Matrix3d
MeshlessForceModel::DeformationGradientAt(Index p, const double * u) const
{
  double F[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 }; // row-major F_ij
  const Index * nodes = m_KernelNodes.data();
  const Index   q = m_KernelIndexOfPoint[p];
  for (Index k = m_KernelOffsets[q]; k < m_KernelOffsets[q + 1]; ++k)
  {
    const double * uI = u + 3 * static_cast<std::size_t>(m_Numbering.Node(nodes[k]));
    const Vector3  g = KernelGradient(k);
    for (int i = 0; i < 3; ++i)
    {
      for (int j = 0; j < 3; ++j)
      {
        F[3 * i + j] += uI[i] * g[j];
      }
    }
  }
  Eigen::Matrix3d result;
  result << F[0], F[1], F[2], F[3], F[4], F[5], F[6], F[7], F[8];
  return result;
}

namespace
{
// x, y, z and a zero of one node, or a column of a 3 x 3 matrix: GCC's vector
// extension, one AVX register (two SSE2 registers without AVX).
using Lanes = double __attribute__((vector_size(32)));

inline Lanes
LoadLanes(const double * source)
{
  Lanes lanes;
  std::memcpy(&lanes, source, sizeof lanes);
  return lanes;
}

/** Entry k's gradient and the next float (lane 3, to be ignored), widened to double. */
inline Lanes
LoadGradient(const float * source)
{
  using Floats = float __attribute__((vector_size(16)));
  Floats floats;
  std::memcpy(&floats, source, sizeof floats);
  return __builtin_convertvector(floats, Lanes);
}

inline void
StoreLanes(double * target, Lanes lanes)
{
  std::memcpy(target, &lanes, sizeof lanes);
}
} // namespace

// Points [first, last) of the kernel's order, three passes: F of each point
// from its neighbours, then w P with one point per SIMD lane (the
// constitutive law, with its divisions, was 40 % of a scalar one-pass
// kernel), then f_I += w P grad phi_I scattered to the neighbours. Returns
// the first inverted point's index in the kernel's order, or -1.
template <bool kSecondInvariant>
Index
MeshlessForceModel::AddPointForces(Index first, Index last)
{
  const Index *      nodes = m_KernelNodes.data();
  const float *      gradients = m_KernelGradients.data();
  const double *     material = m_KernelMaterial.data();
  const double *     paddedU = m_PaddedDisplacements.data();
  double *           paddedF = m_PaddedForces.data();
  alignas(64) double stress[9][kPointsPerBlock]; // F, then w P, component-major
  for (Index q = first; q < last; ++q)
  {
    // The rows of F = I + sum_I u_I grad phi_I^T (one converted load of the
    // gradient, its 4th lane the next entry's and ignored), over even and odd
    // entries apart to halve the chain of dependent additions.
    Lanes       even0 = { 1, 0, 0, 0 }, even1 = { 0, 1, 0, 0 }, even2 = { 0, 0, 1, 0 };
    Lanes       odd0 = {}, odd1 = {}, odd2 = {};
    const Index begin = m_KernelOffsets[q], end = m_KernelOffsets[q + 1];
    Index       k = begin;
    for (; k + 1 < end; k += 2)
    {
      const double * uA = paddedU + 4 * static_cast<std::size_t>(nodes[k]);
      const double * uB = paddedU + 4 * static_cast<std::size_t>(nodes[k + 1]);
      const float *  g = gradients + 3 * static_cast<std::size_t>(k);
      __builtin_prefetch(g + kGradientPrefetchDistance);
      const Lanes gA = LoadGradient(g), gB = LoadGradient(g + 3);
      even0 += uA[0] * gA;
      even1 += uA[1] * gA;
      even2 += uA[2] * gA;
      odd0 += uB[0] * gB;
      odd1 += uB[1] * gB;
      odd2 += uB[2] * gB;
    }
    if (k < end)
    {
      const double * uA = paddedU + 4 * static_cast<std::size_t>(nodes[k]);
      const Lanes    gA = LoadGradient(gradients + 3 * static_cast<std::size_t>(k));
      even0 += uA[0] * gA;
      even1 += uA[1] * gA;
      even2 += uA[2] * gA;
    }
    const Lanes row[3] = { even0 + odd0, even1 + odd1, even2 + odd2 };
    for (int c = 0; c < 9; ++c)
    {
      stress[c][q - first] = row[c / 3][c % 3];
    }
  }
  Index inverted = std::numeric_limits<Index>::max();
#pragma omp simd reduction(min : inverted)
  for (Index q = first; q < last; ++q)
  {
    const Index local = q - first;
    const Matrix3x3 F = { { { stress[0][local], stress[1][local], stress[2][local] },
                            { stress[3][local], stress[4][local], stress[5][local] },
                            { stress[6][local], stress[7][local], stress[8][local] } } };
    const Matrix3x3 cof = CofactorOf(F);
    const double    J = DeterminantOf(F, cof);
    const double *  m = material + 4 * static_cast<std::size_t>(q); // weight, mu, kappa, collapse
    const Matrix3x3 A = ScaledMooneyRivlinFirstPiola<kSecondInvariant>(
      F, cof, J, m[2] * (J - 1.0), m[1], kSecondInvariant ? m_KernelSecondModulus[q] : 0.0, m[3], m[0]);
    if (!(J > 0.0))
    {
      inverted = std::min(inverted, q); // the kernel's order: a lookup here kept GCC from vectorising the loop
    }
    #pragma GCC unroll 9
    for (int c = 0; c < 9; ++c)
    {
      stress[c][local] = A.m[c / 3][c % 3];
    }
  }
  if (inverted != std::numeric_limits<Index>::max())
  {
    return inverted; // forces are meaningless now; the caller stops
  }
  for (Index q = first; q < last; ++q)
  {
    const Index local = q - first;
    const Lanes column[3] = { { stress[0][local], stress[3][local], stress[6][local], 0.0 },
                              { stress[1][local], stress[4][local], stress[7][local], 0.0 },
                              { stress[2][local], stress[5][local], stress[8][local], 0.0 } };
    const Index end = m_KernelOffsets[q + 1]; // a local: the stores below may alias any member for GCC
    for (Index k = m_KernelOffsets[q]; k < end; ++k)
    {
      double *       fI = paddedF + 4 * static_cast<std::size_t>(nodes[k]);
      const Lanes    g = LoadGradient(gradients + 3 * static_cast<std::size_t>(k));
      using Mask = long long __attribute__((vector_size(32)));
      StoreLanes(fI, LoadLanes(fI) + (column[0] * __builtin_shuffle(g, Mask{ 0, 0, 0, 0 }) +
                                      column[1] * __builtin_shuffle(g, Mask{ 1, 1, 1, 1 }) +
                                      column[2] * __builtin_shuffle(g, Mask{ 2, 2, 2, 2 })));
    }
  }
  return -1;
}

Index
MeshlessForceModel::ComputeInternalForces(const double * u, double * f)
{
  // Blocks of one colour share no node, so the scatter of AddPointForces
  // needs no atomics and each node sums its contributions in schedule order
  // for any thread count.
  const Index       nodeCount = m_NodeCount;
  double *          paddedU = m_PaddedDisplacements.data();
  double *          paddedF = m_PaddedForces.data();
  Index             firstInverted = std::numeric_limits<Index>::max();
#pragma omp parallel num_threads(m_Threads) reduction(min : firstInverted)
  {
#pragma omp for schedule(static)
    for (Index slot = 0; slot < nodeCount; ++slot)
    {
      const double * uN = u + 3 * static_cast<std::size_t>(m_Numbering.Node(slot));
      StoreLanes(paddedU + 4 * static_cast<std::size_t>(slot), Lanes{ uN[0], uN[1], uN[2], 0.0 });
      StoreLanes(paddedF + 4 * static_cast<std::size_t>(slot), Lanes{});
    }
    for (std::size_t colour = 0; colour + 1 < m_KernelColourOffsets.size(); ++colour)
    {
#pragma omp for schedule(dynamic, 1)
      for (Index block = m_KernelColourOffsets[colour]; block < m_KernelColourOffsets[colour + 1]; ++block)
      {
        // A slab (ScheduleBySlabs) is one block of many chunks; a coloured block is one chunk.
        for (Index first = m_KernelBlockOffsets[block]; first < m_KernelBlockOffsets[block + 1]; first += kPointsPerBlock)
        {
          const Index last = std::min(first + kPointsPerBlock, m_KernelBlockOffsets[block + 1]);
          const Index inverted =
            m_KernelSecondModulus.empty() ? AddPointForces<false>(first, last) : AddPointForces<true>(first, last);
          if (inverted >= 0)
          {
            firstInverted = std::min(firstInverted, inverted);
          }
        }
      }
    }
#pragma omp for schedule(static)
    for (Index slot = 0; slot < nodeCount; ++slot)
    {
      double * fN = f + 3 * static_cast<std::size_t>(m_Numbering.Node(slot));
      for (int i = 0; i < 3; ++i)
      {
        fN[i] = paddedF[4 * static_cast<std::size_t>(slot) + i];
      }
    }
  }
  return firstInverted == std::numeric_limits<Index>::max() ? -1 : m_KernelPoint[firstInverted];
}

std::vector<double>
MeshlessForceModel::LumpedMasses() const
{
  // Each integration point's mass shared equally by its neighbours.
  std::vector<double> masses(m_NodeCount, 0.0); // in slot order
  for (Index p = 0; p < PointCount(); ++p)
  {
    const Index  q = m_KernelIndexOfPoint[p];
    const Index  begin = m_KernelOffsets[q], end = m_KernelOffsets[q + 1];
    const double share = m_Density[p] * m_Weight[p] / (end - begin);
    for (Index k = begin; k < end; ++k)
    {
      masses[m_KernelNodes[k]] += share;
    }
  }
  return m_Numbering.InNodeOrder(masses);
}

std::vector<double>
MeshlessForceModel::ScaledMasses(double timeStep, double safety, bool collapse) const
{
  // Following the stiffness diagonal rather than sharing each point's bound
  // equally: on Colin27 at 4.25 mm 2,681 instead of 5,128 steps (docs/solver.md).
  const double        factor = 0.25 * (timeStep / safety) * (timeStep / safety);
  DiagonalMasses      masses(m_NodeCount);
  std::vector<double> norms;
  for (Index q = 0; q < PointCount(); ++q)
  {
    const Index  p = m_KernelPoint[q];
    const double modulus = m_Kappa[p] + 4.0 * m_Mu[p] / 3.0;
    const Index  begin = m_KernelOffsets[q], end = m_KernelOffsets[q + 1];
    norms.resize(end - begin);
    for (Index k = begin; k < end; ++k)
    {
      const Vector3 g = KernelGradient(k);
      norms[k - begin] = g.norm();
    }
    masses.AddUnit(&m_KernelNodes[begin], norms.data(), static_cast<int>(end - begin),
                   m_Weight[p] * (collapse ? std::max(modulus, m_Collapse[p]) : modulus));
  }
  return m_Numbering.InNodeOrder(masses.Masses(factor));
}

double
MeshlessForceModel::CriticalTimeStep(Index * point) const
{
  return SmallestStableStep(m_WaveBound, m_Density, point);
}

Energies
MeshlessForceModel::ComputeEnergies(const double * u) const
{
  Energies energies;
  for (Index p = 0; p < PointCount(); ++p)
  {
    const Eigen::Matrix3d F = DeformationGradientAt(p, u);
    const double          J = F.determinant();
    energies.strain +=
      m_Weight[p] * StrainEnergyDensityOfLaw(F, J, J, { m_Mu[p], SecondModulusOfPoint(p), m_Kappa[p], m_Collapse[p] });
  }
  return energies;
}

std::vector<Eigen::Matrix3d>
MeshlessForceModel::CauchyStress(const double * u) const
{
  std::vector<Eigen::Matrix3d> stress(PointCount());
  for (Index p = 0; p < PointCount(); ++p)
  {
    const Eigen::Matrix3d F = DeformationGradientAt(p, u);
    const Eigen::Matrix3d cof = Cofactor(F);
    const double          J = F.col(0).dot(cof.col(0));
    const Eigen::Matrix3d P =
      FirstPiolaOfLaw(F, cof, J, J, { m_Mu[p], SecondModulusOfPoint(p), m_Kappa[p], m_Collapse[p] });
    stress[p] = (P * F.transpose() / J) * units::InternalToPascal;
  }
  return stress;
}

std::string
MeshlessForceModel::Describe(Index point) const
{
  std::ostringstream text;
  const Vector3 &    x = m_Positions[point];
  text << "integration point " << point << " at " << FormatPoint(x) << " mm";
  return text.str();
}

void
MeshlessForceModel::AddComponents(std::vector<std::string> & components) const
{
  components.push_back("meshless-integration-points");
}

std::size_t
MeshlessForceModel::StreamedBytesPerStep() const
{
  return BytesOf(m_KernelOffsets) + BytesOf(m_KernelNodes) + BytesOf(m_KernelGradients) + BytesOf(m_KernelMaterial) +
         BytesOf(m_KernelSecondModulus);
}

} // namespace bmr
