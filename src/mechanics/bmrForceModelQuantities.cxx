// The finite-element model's quantities derived from its cells and state:
// lumped and scaled masses, critical time step, energies, Cauchy stress,
// nodal pressures, and the description of a cell or of the model.
#include "bmrForceModel.h"

#include "bmrConstitutiveLaw.h"
#include "bmrShape.h"
#include "bmrUnits.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace bmr
{

namespace
{

template <int N>
inline Eigen::Matrix3d
DeformationGradient(const double * u, const std::array<Index, N> & nodes, const double * B)
{
  Eigen::Matrix3d F = Eigen::Matrix3d::Identity();
  for (int a = 0; a < N; ++a)
  {
    const double * ua = u + 3 * static_cast<std::size_t>(nodes[a]);
    const double * Ba = B + 3 * a;
    for (int i = 0; i < 3; ++i)
    {
      for (int j = 0; j < 3; ++j)
      {
        F(i, j) += ua[i] * Ba[j];
      }
    }
  }
  return F;
}

// Hourglass mode amplitudes m_alpha = Gamma_alpha^T u, with the Flanagan-Belytschko
// vectors Gamma = h - B (X^T h) expanded so that only X^T h (3x4) is stored:
// m_alpha = h_alpha^T u - (F - I) (X^T h)_alpha.
inline void
HourglassModes(const double (&u)[8][3], const Eigen::Matrix3d & F, const double * XH, double (&modes)[4][3])
{
  for (int alpha = 0; alpha < 4; ++alpha)
  {
    for (int i = 0; i < 3; ++i)
    {
      double m = 0.0;
      for (int a = 0; a < 8; ++a)
      {
        m += kHourglassBase[a][alpha] * u[a][i];
      }
      for (int j = 0; j < 3; ++j)
      {
        m -= (F(i, j) - (i == j ? 1.0 : 0.0)) * XH[4 * j + alpha];
      }
      modes[alpha][i] = m;
    }
  }
}

} // namespace

std::vector<double>
FiniteElementForceModel::LumpedMasses() const
{
  // Each cell's mass shared equally by its nodes.
  std::vector<double> masses(m_NodeCount, 0.0);
  auto                add = [&](Index k, const Index * nodes, int count) {
    const double share = m_Density[k] * m_Volume[k] / count;
    for (int a = 0; a < count; ++a)
    {
      masses[nodes[a]] += share;
    }
  };
  for (Index e = 0; e < HexahedronCount(); ++e)
  {
    add(e, m_HexNodes[e].data(), 8);
  }
  for (Index t = 0; t < TetrahedronCount(); ++t)
  {
    add(HexahedronCount() + t, m_TetNodes[t].data(), 4);
  }
  return masses;
}

DiagonalMasses::DiagonalMasses(Index nodeCount)
  : m_Diagonal(static_cast<std::size_t>(nodeCount), 0.0)
  , m_RowBounds(static_cast<std::size_t>(nodeCount), 0.0)
  , m_EqualShares(static_cast<std::size_t>(nodeCount), 0.0)
{}

void
DiagonalMasses::AddUnit(const Index * nodes, const double * gradientNorms, int count, double stiffness)
{
  double normSum = 0.0;
  for (int a = 0; a < count; ++a)
  {
    normSum += gradientNorms[a];
  }
  for (int a = 0; a < count; ++a)
  {
    m_Diagonal[nodes[a]] += stiffness * gradientNorms[a] * gradientNorms[a];
    m_RowBounds[nodes[a]] += stiffness * gradientNorms[a] * normSum;
  }
}

void
DiagonalMasses::AddEqualShares(const Index * nodes, int count, double bound)
{
  for (int a = 0; a < count; ++a)
  {
    m_EqualShares[nodes[a]] += bound / count;
  }
}

std::vector<double>
DiagonalMasses::Masses(double factor) const
{
  // The ratio comes from the diagonal-shaped units only: the equal shares
  // already bound their rows, and scaling them too would make the nodes of
  // hexahedra in a mixed mesh heavier than needed. m = ratio D + B still
  // bounds every Gershgorin row sum.
  // A node whose gradients (nearly) vanish has (nearly) no stiffness; the
  // floor keeps the ratio and its mass finite (the solve then reports what
  // does not converge).
  const double diagonalFloor = 1e-12 * *std::max_element(m_Diagonal.begin(), m_Diagonal.end());
  double       ratio = 1.0;
  for (std::size_t n = 0; n < m_Diagonal.size(); ++n)
  {
    if (m_Diagonal[n] > 0.0)
    {
      ratio = std::max(ratio, m_RowBounds[n] / std::max(m_Diagonal[n], diagonalFloor));
    }
  }
  std::vector<double> masses(m_Diagonal.size());
  double              largest = 0.0;
  for (std::size_t n = 0; n < m_Diagonal.size(); ++n)
  {
    const double diagonal = m_EqualShares[n] > 0.0 ? m_Diagonal[n] : std::max(m_Diagonal[n], diagonalFloor);
    masses[n] = ratio * diagonal + m_EqualShares[n];
    largest = std::max(largest, masses[n]);
  }
  // The same floor where no unit adds anything (only hexahedra, or none).
  for (double & mass : masses)
  {
    mass = factor * std::max(mass, 1e-12 * largest);
  }
  return masses;
}

std::vector<double>
FiniteElementForceModel::ScaledMasses(double timeStep, double safety, bool collapse) const
{
  // Critical step 2 / sqrt(q M / rho) = timeStep / safety  =>  rho = q M (timeStep / safety)^2 / 4.
  const double   factor = 0.25 * (timeStep / safety) * (timeStep / safety);
  const auto     bound = [&](Index k) { return (m_WaveBound[k] + (collapse ? m_CollapseWaveBound[k] : 0.0)) * m_Volume[k]; };
  DiagonalMasses masses(m_NodeCount);
  for (Index e = 0; e < HexahedronCount(); ++e)
  {
    masses.AddEqualShares(m_HexNodes[e].data(), 8, bound(e));
  }
  // A tetrahedron's bound is 4 B:B M V: its stiffness M V follows from it.
  const std::size_t count = m_TetNodes.size();
  for (Index t = 0; t < TetrahedronCount(); ++t)
  {
    double norms[4], squares = 0.0;
    for (int a = 0; a < 4; ++a)
    {
      double square = 0.0;
      for (int j = 0; j < 3; ++j)
      {
        const double g = m_TetB[(3 * a + j) * count + static_cast<std::size_t>(t)];
        square += g * g;
      }
      norms[a] = std::sqrt(square);
      squares += square;
    }
    masses.AddUnit(m_TetNodes[t].data(), norms, 4, bound(HexahedronCount() + t) / (4.0 * squares));
  }
  return masses.Masses(factor);
}

std::vector<double>
CollapseModuli(const std::vector<double> & kappa, const std::vector<double> & volume, double settingPascal)
{
  double modelModulus = settingPascal * units::PascalToInternal;
  if (settingPascal == 0.0 && !kappa.empty())
  {
    // Volume-weighted median: the modulus below which half of the body lies.
    std::vector<std::size_t> order(kappa.size());
    std::iota(order.begin(), order.end(), std::size_t{ 0 });
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return kappa[a] < kappa[b]; });
    const double total = std::accumulate(volume.begin(), volume.end(), 0.0);
    double       below = 0.0;
    for (const std::size_t k : order)
    {
      below += volume[k];
      modelModulus = kappa[k];
      if (below >= 0.5 * total)
      {
        break;
      }
    }
  }
  std::vector<double> moduli(kappa.size());
  for (std::size_t k = 0; k < kappa.size(); ++k)
  {
    moduli[k] = std::max(kappa[k], modelModulus);
  }
  return moduli;
}

double
SmallestStableStep(const std::vector<double> & waveBound, const std::vector<double> & density, Index * unit)
{
  double smallest = std::numeric_limits<double>::infinity();
  Index  where = -1;
  for (std::size_t k = 0; k < waveBound.size(); ++k)
  {
    const double step = 2.0 / std::sqrt(waveBound[k] / density[k]);
    if (step < smallest)
    {
      smallest = step;
      where = static_cast<Index>(k);
    }
  }
  if (unit)
  {
    *unit = where;
  }
  return smallest;
}

double
FiniteElementForceModel::CriticalTimeStep(Index * cell) const
{
  Index        kernelCell = -1;
  const double step = SmallestStableStep(m_WaveBound, m_Density, &kernelCell);
  if (cell)
  {
    *cell = kernelCell < 0 ? -1 : m_ModelCell[kernelCell];
  }
  return step;
}

Energies
FiniteElementForceModel::ComputeEnergies(const double * u) const
{
  Energies    energies;
  const Index hexCount = HexahedronCount();
  for (Index e = 0; e < hexCount; ++e)
  {
    const Eigen::Matrix3d F = DeformationGradient<8>(u, m_HexNodes[e], ComponentsOf<24>(m_HexB, e).data());
    const double          J = F.determinant();
    energies.strain += m_Volume[e] * StrainEnergyDensityOfLaw(F, J, J, UnitModuliOf(e));
    double ue[8][3];
    for (int a = 0; a < 8; ++a)
    {
      for (int i = 0; i < 3; ++i)
      {
        ue[a][i] = u[3 * static_cast<std::size_t>(m_HexNodes[e][a]) + i];
      }
    }
    double modes[4][3];
    HourglassModes(ue, F, ComponentsOf<12>(m_HexXH, e).data(), modes);
    for (const auto & mode : modes)
    {
      energies.hourglass += 0.5 * m_HexHourglassStiffness[e] * (mode[0] * mode[0] + mode[1] * mode[1] + mode[2] * mode[2]);
    }
  }
  // ANP: the isochoric energy per cell, the volumetric one per node (the
  // potential of the nodal pressures).
  const bool averaged = UsesAverageNodalPressure();
  for (Index t = 0; t < TetrahedronCount(); ++t)
  {
    const Eigen::Matrix3d F = DeformationGradient<4>(u, m_TetNodes[t], ComponentsOf<12>(m_TetB, t).data());
    const double          J = F.determinant();
    const Index           k = hexCount + t;
    energies.strain +=
      m_Volume[k] * StrainEnergyDensityOfLaw(F, J, J, { m_Mu[k], SecondModulus(k),
                                                        m_TetAveraged[t] > 0.0 ? 0.0 : m_Kappa[k], m_Collapse[k] });
  }
  if (averaged)
  {
    const std::vector<double> pressure = NodalPressures(u);
    for (Index n = 0; n < m_NodeCount; ++n)
    {
      if (m_NodalBulkModulus[n] > 0.0)
      {
        energies.strain += 0.5 * m_NodalVolume[n] * pressure[n] * pressure[n] / m_NodalBulkModulus[n];
      }
    }
  }
  energies.strain += energies.hourglass;
  return energies;
}

std::vector<Eigen::Matrix3d>
FiniteElementForceModel::CauchyStress(const double * u) const
{
  std::vector<Eigen::Matrix3d> stress(m_ModelCell.size());
  const Index                  hexCount = HexahedronCount();
  const std::vector<double>    nodalPressure = UsesAverageNodalPressure() ? NodalPressures(u) : std::vector<double>{};
  for (std::size_t k = 0; k < m_ModelCell.size(); ++k)
  {
    const Index     index = static_cast<Index>(k);
    Eigen::Matrix3d F;
    double          volumeRatio = 0.0;
    if (index < hexCount)
    {
      F = DeformationGradient<8>(u, m_HexNodes[index], ComponentsOf<24>(m_HexB, index).data());
      volumeRatio = F.determinant();
    }
    else
    {
      const Index t = index - hexCount;
      F = DeformationGradient<4>(u, m_TetNodes[t], ComponentsOf<12>(m_TetB, t).data());
      // FirstPiola's volumetric term kappa (volumeRatio - 1) is the cell's pressure.
      volumeRatio = 1.0 + TetrahedronPressure(t, F.determinant(), nodalPressure) / m_Kappa[k];
    }
    const Eigen::Matrix3d cof = Cofactor(F);
    const double          J = F.col(0).dot(cof.col(0));
    const Eigen::Matrix3d P = FirstPiolaOfLaw(F, cof, J, volumeRatio, UnitModuliOf(static_cast<Index>(k)));
    stress[m_ModelCell[k]] = (P * F.transpose() / J) * units::InternalToPascal;
  }
  return stress;
}

std::vector<double>
FiniteElementForceModel::NodalPressures(const double * u) const
{
  std::vector<double> tetJ(TetrahedronCount());
  for (Index t = 0; t < TetrahedronCount(); ++t)
  {
    tetJ[t] = DeformationGradient<4>(u, m_TetNodes[t], ComponentsOf<12>(m_TetB, t).data()).determinant();
  }
  std::vector<double> pressure(m_NodeCount, 0.0);
  for (Index n = 0; n < m_NodeCount; ++n)
  {
    pressure[n] = NodalPressure(n, tetJ.data());
  }
  return pressure;
}

double
FiniteElementForceModel::NodalPressure(Index n, const double * tetJacobian) const
{
  // The mean of J - 1, not of J: exactly 0 at rest, and no cancellation.
  double dilatation = 0.0;
  for (Index k = m_NodeTetOffsets[n]; k < m_NodeTetOffsets[n + 1]; ++k)
  {
    dilatation += m_NodeTetWeights[k] * (tetJacobian[m_NodeTets[k]] - 1.0);
  }
  return m_NodalBulkModulus[n] * dilatation;
}

double
FiniteElementForceModel::TetrahedronPressure(Index t, double J, const std::vector<double> & nodalPressure) const
{
  if (nodalPressure.empty() || m_TetAveraged[t] == 0.0)
  {
    return m_Kappa[HexahedronCount() + t] * (J - 1.0);
  }
  const auto & nodes = m_TetNodes[t];
  return 0.25 * (nodalPressure[nodes[0]] + nodalPressure[nodes[1]] + nodalPressure[nodes[2]] + nodalPressure[nodes[3]]);
}

std::string
FiniteElementForceModel::Describe(Index cell) const
{
  return std::string(CellTypeName(m_CellTypes[cell])) + " cell " + std::to_string(cell);
}

void
FiniteElementForceModel::AddComponents(std::vector<std::string> & components) const
{
  if (HexahedronCount() > 0)
  {
    components.push_back("hexahedra");
    if (m_HourglassControl)
    {
      components.push_back("hourglass-control");
    }
  }
  if (TetrahedronCount() > 0)
  {
    components.push_back(UsesAverageNodalPressure() ? "anp-tetrahedra" : "linear-tetrahedra");
  }
}

} // namespace bmr
