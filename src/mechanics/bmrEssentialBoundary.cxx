#include "bmrEssentialBoundary.h"

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>

#include <algorithm>
#include <sstream>

namespace bmr
{

struct EssentialBoundary::Component
{
  int                                         axis = 0;
  std::vector<Index>                          nodes;    // constrained nodes of this component
  std::vector<std::size_t>                    position; // index into the caller's constrained-dof list
  Eigen::SparseMatrix<double, Eigen::RowMajor> phi;     // rows: constrained nodes, columns: all nodes
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver; // Phi_B M^-1 Phi_B^T
};

EssentialBoundary::EssentialBoundary(const ShapeFunctionTable & nodeShapes,
                                     const std::vector<Index> & constrainedDofs,
                                     const std::vector<double> & mass)
  : m_NodeShapes(nodeShapes)
  , m_ConstrainedCount(constrainedDofs.size())
{
  const Index nodeCount = static_cast<Index>(mass.size());
  m_InverseMass.resize(mass.size());
  for (std::size_t n = 0; n < mass.size(); ++n)
  {
    m_InverseMass[n] = 1.0 / mass[n];
  }
  for (int axis = 0; axis < 3; ++axis)
  {
    auto component = std::make_unique<Component>();
    component->axis = axis;
    for (std::size_t k = 0; k < constrainedDofs.size(); ++k)
    {
      if (constrainedDofs[k] % 3 == axis)
      {
        component->nodes.push_back(constrainedDofs[k] / 3);
        component->position.push_back(k);
      }
    }
    if (component->nodes.empty())
    {
      continue;
    }
    std::vector<Eigen::Triplet<double>> entries;
    for (std::size_t row = 0; row < component->nodes.size(); ++row)
    {
      const Index node = component->nodes[row];
      for (Index k = nodeShapes.offsets[node]; k < nodeShapes.offsets[node + 1]; ++k)
      {
        entries.emplace_back(static_cast<Index>(row), nodeShapes.nodes[k], nodeShapes.values[k]);
      }
    }
    component->phi.resize(static_cast<Index>(component->nodes.size()), nodeCount);
    component->phi.setFromTriplets(entries.begin(), entries.end());
    const Eigen::VectorXd                       inverseMass = Eigen::Map<const Eigen::VectorXd>(m_InverseMass.data(), nodeCount);
    const Eigen::SparseMatrix<double>           scaled = component->phi * inverseMass.asDiagonal();
    const Eigen::SparseMatrix<double>           matrix = scaled * Eigen::SparseMatrix<double>(component->phi.transpose());
    component->solver.compute(matrix);
    bool regular = component->solver.info() == Eigen::Success;
    if (regular)
    {
      // LDLT of a singular Gram matrix succeeds with (near-)zero pivots.
      const Eigen::VectorXd pivots = component->solver.vectorD();
      regular = pivots.minCoeff() > 1e-12 * pivots.maxCoeff();
    }
    if (!regular)
    {
      std::ostringstream message;
      message << "EBCIEM: the shape functions of the nodes constrained in " << "xyz"[axis]
              << " are linearly dependent, so their interpolated values cannot be prescribed independently "
                 "(constrained nodes much denser than the nodal spacing elsewhere?). Make the constrained "
                 "nodes no denser than the rest, or use \"essential_boundary\": \"nodal\".";
      throw Error(message.str());
    }
    m_Components.push_back(std::move(component));
  }
}

EssentialBoundary::~EssentialBoundary() = default;

void
EssentialBoundary::Impose(double * u, const std::vector<double> & targets, int threads) const
{
  // Runs every step: only the constrained rows and their neighbours are touched.
  const int componentCount = static_cast<int>(m_Components.size());
#pragma omp parallel for num_threads(std::max(1, std::min(threads, componentCount))) schedule(static, 1)
  for (int c = 0; c < componentCount; ++c)
  {
    const auto &    component = m_Components[static_cast<std::size_t>(c)];
    const auto &    phi = component->phi;
    const Index     rows = phi.rows();
    Eigen::VectorXd residual(rows);
    for (Index row = 0; row < rows; ++row)
    {
      double interpolated = 0.0;
      for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator entry(phi, row); entry; ++entry)
      {
        interpolated += entry.value() * u[3 * static_cast<std::size_t>(entry.col()) + component->axis];
      }
      residual[row] = targets[component->position[row]] - interpolated;
    }
    const Eigen::VectorXd multipliers = component->solver.solve(residual);
    for (Index row = 0; row < rows; ++row)
    {
      for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator entry(phi, row); entry; ++entry)
      {
        const Index node = static_cast<Index>(entry.col());
        u[3 * static_cast<std::size_t>(node) + component->axis] += m_InverseMass[node] * entry.value() * multipliers[row];
      }
    }
  }
}

const std::array<EssentialBoundary::Coupling, 3> &
EssentialBoundary::CouplingOf(Index node) const
{
  if (m_Couplings.empty())
  {
    m_Couplings.resize(m_InverseMass.size());
  }
  auto & cached = m_Couplings[static_cast<std::size_t>(node)];
  if (cached)
  {
    return *cached;
  }
  cached = std::make_unique<std::array<Coupling, 3>>();
  const Index     nodeCount = static_cast<Index>(m_InverseMass.size());
  Eigen::VectorXd weighted = Eigen::VectorXd::Zero(nodeCount); // M^-1 phi_s
  for (Index k = m_NodeShapes.offsets[node]; k < m_NodeShapes.offsets[node + 1]; ++k)
  {
    weighted[m_NodeShapes.nodes[k]] = m_InverseMass[m_NodeShapes.nodes[k]] * m_NodeShapes.values[k];
  }
  for (const auto & component : m_Components)
  {
    const Eigen::VectorXd overlap = component->phi * weighted; // A_i M^-1 phi_s
    if (overlap.cwiseAbs().maxCoeff() == 0.0)
    {
      continue;
    }
    const Eigen::VectorXd multipliers = component->solver.solve(overlap);
    const Eigen::VectorXd change = component->phi.transpose() * multipliers;
    Coupling &            coupling = (*cached)[static_cast<std::size_t>(component->axis)];
    coupling.projected = overlap.dot(multipliers);
    for (Index n = 0; n < nodeCount; ++n)
    {
      if (change[n] != 0.0)
      {
        coupling.nodes.push_back(n);
        coupling.values.push_back(m_InverseMass[n] * change[n]);
      }
    }
  }
  return *cached;
}

std::vector<double>
EssentialBoundary::Reactions(const double * residual) const
{
  std::vector<double> reactions(m_ConstrainedCount, 0.0);
  for (const auto & component : m_Components)
  {
    const Index nodeCount = static_cast<Index>(m_InverseMass.size());
    Eigen::Map<const Eigen::VectorXd, 0, Eigen::InnerStride<3>> r(residual + component->axis, nodeCount);
    Eigen::VectorXd weighted(nodeCount);
    for (Index n = 0; n < nodeCount; ++n)
    {
      weighted[n] = m_InverseMass[n] * r[n];
    }
    const Eigen::VectorXd lambda = component->solver.solve(component->phi * weighted);
    for (std::size_t row = 0; row < component->nodes.size(); ++row)
    {
      reactions[component->position[row]] = lambda[static_cast<Index>(row)];
    }
  }
  return reactions;
}

} // namespace bmr
