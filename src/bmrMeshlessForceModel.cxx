#include "bmrForceModel.h"

#include "bmrNeoHookean.h"
#include "bmrUnits.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace bmr
{

MeshlessForceModel::MeshlessForceModel(const Model & model, ShapeFunctionTable shapeFunctions, int threads)
  : m_Threads(std::max(1, threads))
  , m_NodeCount(static_cast<Index>(model.nodes.size()))
  , m_Table(std::move(shapeFunctions))
  , m_Positions(model.meshless.integrationPoints)
  , m_Weight(model.meshless.integrationWeights)
{
  const Index pointCount = m_Table.PointCount();
  if (pointCount != static_cast<Index>(m_Positions.size()) ||
      m_Table.gradients.size() != 3 * m_Table.nodes.size())
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
    for (Index k = m_Table.offsets[p]; k < m_Table.offsets[p + 1]; ++k)
    {
      for (int j = 0; j < 3; ++j)
      {
        gradientSquares += m_Table.gradients[3 * k + j] * m_Table.gradients[3 * k + j];
      }
    }
    const Index neighbours = m_Table.offsets[p + 1] - m_Table.offsets[p];
    m_WaveBound[p] = (m_Kappa[p] + 4.0 * m_Mu[p] / 3.0) * neighbours * gradientSquares;
  }

  // Transpose: node -> (point, grad phi_I(x_p)), points ascending.
  m_NodeOffsets.assign(m_NodeCount + 1, 0);
  for (const Index node : m_Table.nodes)
  {
    ++m_NodeOffsets[node + 1];
  }
  for (Index n = 0; n < m_NodeCount; ++n)
  {
    if (m_NodeOffsets[n + 1] == 0)
    {
      std::ostringstream message;
      const Vector3 &    x = model.nodes[n];
      message << "meshless model: node " << n << " at " << FormatPoint(x)
              << " mm lies in the support of no integration point, so it has neither mass nor stiffness. "
                 "Use smaller background cells or more integration points per cell, increase the dilatation, "
                 "or remove the node if it lies outside the body.";
      throw Error(message.str());
    }
    m_NodeOffsets[n + 1] += m_NodeOffsets[n];
  }
  m_NodePoints.resize(m_Table.nodes.size());
  m_NodeGradients.resize(3 * m_Table.nodes.size());
  std::vector<Index> fill(m_NodeOffsets.begin(), m_NodeOffsets.end() - 1);
  for (Index p = 0; p < pointCount; ++p)
  {
    for (Index k = m_Table.offsets[p]; k < m_Table.offsets[p + 1]; ++k)
    {
      const Index slot = fill[m_Table.nodes[k]]++;
      m_NodePoints[slot] = p;
      for (int j = 0; j < 3; ++j)
      {
        m_NodeGradients[3 * slot + j] = m_Table.gradients[3 * k + j];
      }
    }
  }
  m_WeightedStress.assign(9 * static_cast<std::size_t>(pointCount), 0.0);
}

Eigen::Matrix3d
MeshlessForceModel::DeformationGradientAt(Index p, const double * u) const
{
  double F[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 }; // row-major F_ij
  const Index * nodes = m_Table.nodes.data();
  const double *gradients = m_Table.gradients.data();
  for (Index k = m_Table.offsets[p]; k < m_Table.offsets[p + 1]; ++k)
  {
    const double * uI = u + 3 * static_cast<std::size_t>(nodes[k]);
    const double * g = gradients + 3 * static_cast<std::size_t>(k);
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

Index
MeshlessForceModel::ComputeInternalForces(const double * u, double * f)
{
  const Index pointCount = m_Table.PointCount();
  Index       firstInverted = std::numeric_limits<Index>::max();
  // Pass 1: w_p P_p at every point.
#pragma omp parallel for num_threads(m_Threads) schedule(static) reduction(min : firstInverted)
  for (Index p = 0; p < pointCount; ++p)
  {
    const Eigen::Matrix3d F = DeformationGradientAt(p, u);
    const Eigen::Matrix3d cof = Cofactor(F);
    const double          J = F.col(0).dot(cof.col(0));
    double *              wP = m_WeightedStress.data() + 9 * static_cast<std::size_t>(p);
    if (!(J > 0.0))
    {
      firstInverted = std::min(firstInverted, p);
      std::fill(wP, wP + 9, 0.0);
      continue;
    }
    const Eigen::Matrix3d P = m_Weight[p] * FirstPiola(F, cof, J, J, m_Mu[p], m_Kappa[p]);
    for (int i = 0; i < 3; ++i)
    {
      for (int j = 0; j < 3; ++j)
      {
        wP[3 * i + j] = P(i, j);
      }
    }
  }
  // Pass 2: f_I = sum_p (w P)_p grad phi_I(x_p), gathered per node in a fixed order.
#pragma omp parallel for num_threads(m_Threads) schedule(static)
  for (Index n = 0; n < m_NodeCount; ++n)
  {
    double fx = 0.0, fy = 0.0, fz = 0.0;
    for (Index k = m_NodeOffsets[n]; k < m_NodeOffsets[n + 1]; ++k)
    {
      const double * wP = m_WeightedStress.data() + 9 * static_cast<std::size_t>(m_NodePoints[k]);
      const double * g = m_NodeGradients.data() + 3 * static_cast<std::size_t>(k);
      fx += wP[0] * g[0] + wP[1] * g[1] + wP[2] * g[2];
      fy += wP[3] * g[0] + wP[4] * g[1] + wP[5] * g[2];
      fz += wP[6] * g[0] + wP[7] * g[1] + wP[8] * g[2];
    }
    f[3 * n] = fx;
    f[3 * n + 1] = fy;
    f[3 * n + 2] = fz;
  }
  return firstInverted == std::numeric_limits<Index>::max() ? -1 : firstInverted;
}

template <typename PointMass>
std::vector<double>
MeshlessForceModel::LumpToNodes(const PointMass & pointMass) const
{
  std::vector<double> masses(m_NodeCount, 0.0);
  for (Index p = 0; p < m_Table.PointCount(); ++p)
  {
    const Index  begin = m_Table.offsets[p], end = m_Table.offsets[p + 1];
    const double share = pointMass(p) / (end - begin);
    for (Index k = begin; k < end; ++k)
    {
      masses[m_Table.nodes[k]] += share;
    }
  }
  return masses;
}

std::vector<double>
MeshlessForceModel::LumpedMasses() const
{
  return LumpToNodes([this](Index p) { return m_Density[p] * m_Weight[p]; });
}

std::vector<double>
MeshlessForceModel::ScaledMasses(double timeStep, double safety) const
{
  const double factor = 0.25 * (timeStep / safety) * (timeStep / safety);
  return LumpToNodes([this, factor](Index p) { return factor * m_WaveBound[p] * m_Weight[p]; });
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
  for (Index p = 0; p < m_Table.PointCount(); ++p)
  {
    const Eigen::Matrix3d F = DeformationGradientAt(p, u);
    const double          J = F.determinant();
    energies.strain += m_Weight[p] * StrainEnergyDensity(F, J, J, m_Mu[p], m_Kappa[p]);
  }
  return energies;
}

std::vector<Eigen::Matrix3d>
MeshlessForceModel::CauchyStress(const double * u) const
{
  std::vector<Eigen::Matrix3d> stress(m_Table.PointCount());
  for (Index p = 0; p < m_Table.PointCount(); ++p)
  {
    const Eigen::Matrix3d F = DeformationGradientAt(p, u);
    const Eigen::Matrix3d cof = Cofactor(F);
    const double          J = F.col(0).dot(cof.col(0));
    const Eigen::Matrix3d P = FirstPiola(F, cof, J, J, m_Mu[p], m_Kappa[p]);
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

} // namespace bmr
