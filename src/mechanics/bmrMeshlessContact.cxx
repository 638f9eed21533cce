#include "bmrMeshlessContact.h"

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace bmr
{

// Contact acts on the MLS-interpolated positions of the slave nodes. A slave
// in contact contributes one constraint, n . (Phi_s u) = n . c, with c its
// projection onto the surface and n the surface normal there: the linearised
// gap, so the tangential motion stays free (frictionless). Holding all three
// components at c instead can, in principle, let the corrections carry
// tangential forces that depend on the masses (not seen on a flat plane:
// MeshlessContact.SlidingIsUnresisted passes with both).
// The shape functions do not interpolate: where nodes are close together a
// node's own parameter barely moves its interpolated position, and adding
// each slave's correction to its own parameter (a Jacobi iteration on the
// shape-function matrix) pumps neighbouring parameters apart in opposite
// directions, a mode with almost no stiffness that never settles (seen on
// Colin27). Instead the parameters change by the mass-weighted least amount
// that meets every constraint, as EBCIEM does for prescribed displacements:
// Kaczmarz sweeps over the slaves in contact converge to it whatever the
// coupling, but slowly where many neighbours press together, so each
// detection solves for it directly (SolveActiveGaps) and the sweeps only
// close what round-off leaves or take over where that system is singular.
// A slave once in contact keeps its constraint for the rest of the
// step (a neighbour's correction must not release it and make the contact set
// flicker from step to step); slaves pushed into the surface by the
// corrections join the set, and the sweeps repeat.
// With EBCIEM the steady state must meet the prescribed values and the
// contacts together. Projecting onto each in turn converges to that
// (alternating projections) but slowly where a slave's support touches a
// constrained node's: on the meshless Colin27 scene 9 of EBCIEM's projections
// a step, 22 % of the solve, for 3 such slaves among 80. Such a slave's
// correction moves instead along its shape functions minus what EBCIEM would
// take back (EssentialBoundary::CouplingOf), which keeps every prescribed
// value: the sweeps then converge to the same least change with no
// projection in between.
namespace
{
constexpr int kDetections = 8;
constexpr int kSweeps = 64;
constexpr int kPreconditionedIterations = 12;
} // namespace

struct MeshlessContact::ActiveSystem
{
  // Per node, the slaves whose support holds it and their shape function
  // there; per node its index among the slaves (-1: none).
  std::vector<Index>  nodeSlaveOffsets;
  std::vector<Index>  nodeSlaves;
  std::vector<double> nodeSlaveShapes;
  std::vector<Index>  slaveOfNode;
  // Per slave s, once it has been active while the masses stayed: for every
  // slave t whose support meets P_s's, phi_t . P_s per axis, so that
  // (A P^T)_ts = sum_i n_t,i n_s,i products_i whatever the normals.
  struct Overlap
  {
    Index   slave;
    Vector3 products;
  };
  std::vector<std::vector<Overlap>> overlaps;
  std::vector<char>                 overlapsKnown;
  std::vector<double>               inverseMassSeen;
  std::vector<Vector3>              column; // per slave, one column's sums while computing overlaps
  std::vector<char>                 marked;
  std::vector<Index>                touched;
  // The solve: indices into m_Active of its rows (row norm > 0), per slave
  // its row (-1: none), the system and the gaps.
  std::vector<std::size_t>    rows;
  std::vector<Index>          rowOfSlave;
  Eigen::SparseMatrix<double> matrix; // lower triangle of A P^T
  Eigen::VectorXd             gaps;
  // The last factorisation, of an earlier system, and per slave its row
  // there (-1: none); the preconditioner's work vectors.
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> factorisation;
  bool                                               factorised = false;
  std::vector<Index>                                 factorisedRowOfSlave;
  Eigen::VectorXd                                    factorisedSpace;
  Eigen::VectorXd                                    factorisedSolution;

  ActiveSystem(const std::vector<Index> & slaves, const ShapeFunctionTable & shapes, Index nodeCount)
  {
    slaveOfNode.assign(nodeCount, -1);
    nodeSlaveOffsets.assign(static_cast<std::size_t>(nodeCount) + 1, 0);
    for (std::size_t s = 0; s < slaves.size(); ++s)
    {
      slaveOfNode[slaves[s]] = static_cast<Index>(s);
      for (Index k = shapes.offsets[slaves[s]]; k < shapes.offsets[slaves[s] + 1]; ++k)
      {
        ++nodeSlaveOffsets[shapes.nodes[k] + 1];
      }
    }
    for (Index n = 0; n < nodeCount; ++n)
    {
      nodeSlaveOffsets[n + 1] += nodeSlaveOffsets[n];
    }
    nodeSlaves.resize(nodeSlaveOffsets.back());
    nodeSlaveShapes.resize(nodeSlaveOffsets.back());
    std::vector<Index> next(nodeSlaveOffsets.begin(), nodeSlaveOffsets.end() - 1);
    for (std::size_t s = 0; s < slaves.size(); ++s)
    {
      for (Index k = shapes.offsets[slaves[s]]; k < shapes.offsets[slaves[s] + 1]; ++k)
      {
        const Index slot = next[shapes.nodes[k]]++;
        nodeSlaves[slot] = static_cast<Index>(s);
        nodeSlaveShapes[slot] = shapes.values[k];
      }
    }
    column.assign(slaves.size(), Vector3::Zero());
    marked.assign(slaves.size(), 0);
    overlaps.resize(slaves.size());
    overlapsKnown.assign(slaves.size(), 0);
    rowOfSlave.assign(slaves.size(), -1);
    factorisedRowOfSlave.assign(slaves.size(), -1);
  }
};

MeshlessContact::~MeshlessContact() = default;

MeshlessContact::MeshlessContact(const std::vector<std::unique_ptr<RigidContact>> & contacts,
                                 const ShapeFunctionTable &                         nodeShapes,
                                 Index                                              nodeCount)
  : m_Contacts(contacts)
  , m_NodeShapes(nodeShapes)
  , m_Projected(3 * static_cast<std::size_t>(nodeCount), 0.0)
  , m_Normals(nodeCount, Vector3::Zero())
  , m_Targets(nodeCount, 0.0)
{
  for (const auto & contact : contacts)
  {
    m_Slaves.insert(m_Slaves.end(), contact->SlaveNodes().begin(), contact->SlaveNodes().end());
  }
  std::sort(m_Slaves.begin(), m_Slaves.end());
  m_Slaves.erase(std::unique(m_Slaves.begin(), m_Slaves.end()), m_Slaves.end());
}

void
MeshlessContact::SetEssentialBoundary(const EssentialBoundary * essential, const std::vector<Index> & constrainedDofs)
{
  m_Essential = essential;
  if (!essential)
  {
    return;
  }
  m_EssentialSupport.assign(m_Projected.size(), 0);
  for (const Index dof : constrainedDofs)
  {
    const Index node = dof / 3;
    for (Index k = m_NodeShapes.offsets[node]; k < m_NodeShapes.offsets[node + 1]; ++k)
    {
      m_EssentialSupport[3 * m_NodeShapes.nodes[k] + dof % 3] = 1;
    }
  }
}

void
MeshlessContact::Enforce(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass,
                         const std::vector<char> & dofConstrained, double lengthScale, int threads, long long & sweeps)
{
  // Nodal imposition keeps constrained parameters fixed; EBCIEM restores the
  // constrained interpolated values instead.
  const auto weight = [&](Index dof) { return m_Essential || !dofConstrained[dof] ? inverseMass[dof] : 0.0; };
  std::fill(inContact.begin(), inContact.end(), 0);
  m_Active.clear();
  if (m_ParameterSnapshot.empty())
  {
    StartTrackingMotion(u);
  }
  for (int detection = 0; detection < kDetections; ++detection)
  {
    InterpolateMovedSlaves(u, threads);
    if (!DetectPenetrations(inContact, dofConstrained, threads) && detection > 0)
    {
      break;
    }
    PrepareRows(weight);
    SolveActiveGaps(u, weight, inverseMass, 1e-9 * lengthScale);
    Sweep(u, weight, 1e-9 * lengthScale, sweeps);
  }
}

void
MeshlessContact::StartSolve()
{
  m_ParameterSnapshot.clear();
  if (m_System)
  {
    m_System->factorised = false;
  }
}

void
MeshlessContact::StartTrackingMotion(const double * u)
{
  // Slaves far from every surface need no interpolation (most of them, most
  // steps): a slave's interpolated position moves by at most sum_K |phi_K|
  // times the largest parameter change, so it is interpolated again only once
  // the parameters' accumulated largest change could carry it across its
  // clearance. On the meshless Colin27 scene (12,054 slaves) 93 % of the
  // interpolations are skipped: 3.0 s of the solve before, 1.4 s with this
  // pass over the parameters.
  m_ParameterSnapshot.assign(u, u + m_Projected.size());
  m_ParameterMotion = 0.0;
  m_SlaveMotionMark.assign(m_Slaves.size(), 0.0);
  m_Clearance.assign(m_Normals.size(), 0.0);
  m_SlaveShapeSum.resize(m_Slaves.size());
  for (std::size_t s = 0; s < m_Slaves.size(); ++s)
  {
    const Index node = m_Slaves[s];
    double      sum = 0.0;
    for (Index k = m_NodeShapes.offsets[node]; k < m_NodeShapes.offsets[node + 1]; ++k)
    {
      sum += std::abs(m_NodeShapes.values[k]);
    }
    m_SlaveShapeSum[s] = sum;
  }
}

void
MeshlessContact::InterpolateMovedSlaves(const double * u, int threads)
{
  const std::size_t dofCount = m_Projected.size();
  double            largestChange = 0.0;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(max : largestChange)
  for (std::size_t d = 0; d < dofCount; ++d)
  {
    largestChange = std::max(largestChange, std::abs(u[d] - m_ParameterSnapshot[d]));
    m_ParameterSnapshot[d] = u[d];
  }
  m_ParameterMotion += largestChange;
  const Index slaveCount = static_cast<Index>(m_Slaves.size());
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index s = 0; s < slaveCount; ++s)
  {
    const Index node = m_Slaves[s];
    if (m_SlaveShapeSum[s] * (m_ParameterMotion - m_SlaveMotionMark[s]) < m_Clearance[node])
    {
      continue; // its position in the buffer is where the clearance was measured
    }
    m_SlaveMotionMark[s] = m_ParameterMotion;
    const Vector3 value = m_NodeShapes.Interpolate(node, u);
    for (int i = 0; i < 3; ++i)
    {
      m_Projected[3 * node + i] = value[i];
    }
  }
}

bool
MeshlessContact::DetectPenetrations(std::vector<char> & inContact, const std::vector<char> & dofConstrained, int threads)
{
  m_Penetrating.assign(m_Normals.size(), 0);
  bool added = false;
  for (const Index node : m_Slaves)
  {
    m_Clearance[node] = std::numeric_limits<double>::infinity();
  }
  for (const auto & contact : m_Contacts)
  {
    contact->Enforce(m_Projected.data(), dofConstrained, m_Penetrating, threads, nullptr, &m_SlaveNormals,
                     &m_SurfaceClearances);
    const std::vector<Index> & slaves = contact->SlaveNodes();
    for (std::size_t k = 0; k < slaves.size(); ++k)
    {
      m_Clearance[slaves[k]] = std::min(m_Clearance[slaves[k]], m_SurfaceClearances[k]);
    }
    for (std::size_t k = 0; k < slaves.size(); ++k)
    {
      const Index     node = slaves[k];
      const Vector3 & normal = m_SlaveNormals[k];
      if (!m_Penetrating[node] || !(normal.norm() > 0.0)) // penetrating another surface
      {
        continue;
      }
      m_Normals[node] = normal;
      m_Targets[node] = normal.dot(Vector3(m_Projected[3 * node], m_Projected[3 * node + 1], m_Projected[3 * node + 2]));
      if (!inContact[node])
      {
        inContact[node] = 1;
        m_Active.push_back(node);
        added = true;
      }
    }
  }
  return added;
}

template <typename Weight>
void
MeshlessContact::PrepareRows(const Weight & weight)
{
  std::sort(m_Active.begin(), m_Active.end());
  m_RowNorms.assign(m_Active.size(), 0.0);
  m_Couplings.assign(m_Active.size(), nullptr);
  for (std::size_t a = 0; a < m_Active.size(); ++a)
  {
    const Index     node = m_Active[a];
    const Vector3 & n = m_Normals[node];
    bool            coupled = false;
    for (Index k = m_NodeShapes.offsets[node]; k < m_NodeShapes.offsets[node + 1]; ++k)
    {
      const double phi = m_NodeShapes.values[k];
      for (int i = 0; i < 3; ++i)
      {
        const Index d = 3 * m_NodeShapes.nodes[k] + i;
        m_RowNorms[a] += phi * phi * n[i] * n[i] * weight(d);
        coupled = coupled || (m_Essential && m_EssentialSupport[d]);
      }
    }
    if (coupled)
    {
      m_Couplings[a] = &m_Essential->CouplingOf(node);
      const double plain = m_RowNorms[a];
      for (int i = 0; i < 3; ++i)
      {
        m_RowNorms[a] -= n[i] * n[i] * (*m_Couplings[a])[i].projected;
      }
      if (m_RowNorms[a] <= 1e-9 * plain) // the row lies in the span of the prescribed rows
      {
        m_RowNorms[a] = 0.0;
      }
    }
  }
}

template <typename Weight>
void
MeshlessContact::SolveActiveGaps(double * u, const Weight & weight, const std::vector<double> & inverseMass,
                                 double tolerance)
{
  // The sweeps converge to the least mass-weighted change u + P^T lambda
  // that closes every gap, (A P^T) lambda = gaps, with A's rows n . phi_s
  // and P's the sweeps' directions M^-1 (n . phi_s) less EBCIEM's share; A P^T
  // is symmetric positive semi-definite. Where many neighbouring slaves press
  // on the skull (gravity) the sweeps need hundreds of passes; the system,
  // some hundred rows of a few dozen neighbours each, factorises in about a
  // millisecond.
  if (!m_System)
  {
    m_System = std::make_unique<ActiveSystem>(m_Slaves, m_NodeShapes, static_cast<Index>(m_Normals.size()));
  }
  ActiveSystem & system = *m_System;
  if (system.inverseMassSeen != inverseMass) // a restart with heavier masses
  {
    system.inverseMassSeen = inverseMass;
    system.overlapsKnown.assign(m_Slaves.size(), 0);
    system.factorised = false;
  }
  system.rows.clear();
  for (std::size_t a = 0; a < m_Active.size(); ++a)
  {
    if (m_RowNorms[a] > 0.0)
    {
      system.rows.push_back(a);
    }
  }
  const auto rowCount = static_cast<Eigen::Index>(system.rows.size());
  if (rowCount == 0)
  {
    return;
  }
  AssembleActiveSystem(weight);
  system.gaps.resize(rowCount);
  for (Eigen::Index r = 0; r < rowCount; ++r)
  {
    system.gaps[r] = Gap(m_Active[system.rows[r]], u);
  }
  Eigen::VectorXd multipliers;
  if (!SolveWithEarlierFactorisation(multipliers, tolerance))
  {
    if (!Factorise())
    {
      return;
    }
    multipliers = system.factorisation.solve(system.gaps);
  }
  for (Eigen::Index r = 0; r < rowCount; ++r)
  {
    AddDirection(u, weight, system.rows[r], multipliers[r]);
  }
}

bool
MeshlessContact::Factorise()
{
  ActiveSystem & system = *m_System;
  // A shift of 1e-12 of the largest diagonal keeps nearly dependent rows
  // (slaves with almost the same support and normal) from dividing by
  // round-off; the sweeps after this close what it leaves.
  system.factorisation.setShift(1e-12 * system.matrix.diagonal().maxCoeff());
  system.factorisation.compute(system.matrix);
  system.factorised =
    system.factorisation.info() == Eigen::Success && system.factorisation.vectorD().minCoeff() > 0.0;
  std::fill(system.factorisedRowOfSlave.begin(), system.factorisedRowOfSlave.end(), -1);
  for (std::size_t r = 0; system.factorised && r < system.rows.size(); ++r)
  {
    system.factorisedRowOfSlave[system.slaveOfNode[m_Active[system.rows[r]]]] = static_cast<Index>(r);
  }
  return system.factorised;
}

bool
MeshlessContact::SolveWithEarlierFactorisation(Eigen::VectorXd & multipliers, double tolerance)
{
  // From step to step the active slaves stay mostly the same and their
  // normals turn a little: the last factorisation, on the rows it shares
  // with this system (the others scaled by their diagonal), preconditions
  // conjugate gradients, which then need a few iterations where a new
  // factorisation (with its ordering) costs as much as dozens.
  ActiveSystem & system = *m_System;
  if (!system.factorised)
  {
    return false;
  }
  const auto         rowCount = static_cast<Eigen::Index>(system.rows.size());
  std::vector<Index> earlierRow(system.rows.size());
  Eigen::Index       shared = 0;
  for (Eigen::Index r = 0; r < rowCount; ++r)
  {
    earlierRow[r] = system.factorisedRowOfSlave[system.slaveOfNode[m_Active[system.rows[r]]]];
    shared += earlierRow[r] >= 0 ? 1 : 0;
  }
  if (10 * shared < 9 * rowCount)
  {
    return false;
  }
  const Eigen::VectorXd diagonal = system.matrix.diagonal();
  const auto precondition = [&](const Eigen::VectorXd & residual, Eigen::VectorXd & result) {
    system.factorisedSpace.setZero(system.factorisation.rows());
    for (Eigen::Index r = 0; r < rowCount; ++r)
    {
      if (earlierRow[r] >= 0)
      {
        system.factorisedSpace[earlierRow[r]] = residual[r];
      }
    }
    system.factorisedSolution = system.factorisation.solve(system.factorisedSpace);
    for (Eigen::Index r = 0; r < rowCount; ++r)
    {
      result[r] = earlierRow[r] >= 0 ? system.factorisedSolution[earlierRow[r]] : residual[r] / diagonal[r];
    }
  };
  multipliers.setZero(rowCount);
  Eigen::VectorXd residual = system.gaps;
  Eigen::VectorXd preconditioned(rowCount);
  precondition(residual, preconditioned);
  Eigen::VectorXd direction = preconditioned;
  double          product = residual.dot(preconditioned);
  for (int iteration = 0; iteration < kPreconditionedIterations; ++iteration)
  {
    if (residual.cwiseAbs().maxCoeff() <= tolerance)
    {
      return true;
    }
    const Eigen::VectorXd applied = system.matrix.selfadjointView<Eigen::Lower>() * direction;
    const double          curvature = direction.dot(applied);
    if (!(curvature > 0.0))
    {
      return false;
    }
    const double step = product / curvature;
    multipliers += step * direction;
    residual -= step * applied;
    precondition(residual, preconditioned);
    const double next = residual.dot(preconditioned);
    direction = preconditioned + (next / product) * direction;
    product = next;
  }
  return residual.cwiseAbs().maxCoeff() <= tolerance;
}

template <typename Weight>
void
MeshlessContact::AssembleActiveSystem(const Weight & weight)
{
  ActiveSystem & system = *m_System;
  const auto     rowCount = static_cast<Index>(system.rows.size());
  for (Index r = 0; r < rowCount; ++r)
  {
    system.rowOfSlave[system.slaveOfNode[m_Active[system.rows[r]]]] = r;
  }
  // Column by column, rows ascending: the active rows are in the slaves'
  // order, and so is each slave's list of overlaps.
  system.matrix.resize(rowCount, rowCount);
  system.matrix.setZero();
  system.matrix.reserve(32 * static_cast<Eigen::Index>(rowCount));
  for (Index q = 0; q < rowCount; ++q)
  {
    system.matrix.startVec(q);
    const std::size_t a = system.rows[q];
    const Index       node = m_Active[a];
    const Index       slave = system.slaveOfNode[node];
    if (!system.overlapsKnown[slave])
    {
      ComputeOverlaps(slave, m_Couplings[a], weight);
    }
    const Vector3 &                           n = m_Normals[node];
    const std::vector<ActiveSystem::Overlap> & overlaps = system.overlaps[slave];
    // The lower triangle: rows from q on are the slaves from this one on.
    const auto from = std::lower_bound(overlaps.begin(), overlaps.end(), slave,
                                       [](const ActiveSystem::Overlap & o, Index s) { return o.slave < s; });
    for (auto overlap = from; overlap != overlaps.end(); ++overlap)
    {
      const Index r = system.rowOfSlave[overlap->slave];
      if (r >= 0)
      {
        const Vector3 & m = m_Normals[m_Active[system.rows[r]]];
        system.matrix.insertBack(r, q) = m.cwiseProduct(n).dot(overlap->products);
      }
    }
  }
  system.matrix.finalize();
  for (Index r = 0; r < rowCount; ++r)
  {
    system.rowOfSlave[system.slaveOfNode[m_Active[system.rows[r]]]] = -1;
  }
}

template <typename Weight>
void
MeshlessContact::ComputeOverlaps(Index slave, const std::array<EssentialBoundary::Coupling, 3> * coupling,
                                 const Weight & weight)
{
  ActiveSystem & system = *m_System;
  // P_s = sum_i (M_i^-1 phi_s - z_s,i) e_i; phi_t . P_s through the slaves
  // whose support holds each node of P_s.
  system.touched.clear();
  const auto add = [&](Index node, const Vector3 & direction) {
    for (Index slot = system.nodeSlaveOffsets[node]; slot < system.nodeSlaveOffsets[node + 1]; ++slot)
    {
      const Index t = system.nodeSlaves[slot];
      if (!system.marked[t])
      {
        system.marked[t] = 1;
        system.touched.push_back(t);
      }
      system.column[t] += system.nodeSlaveShapes[slot] * direction;
    }
  };
  const Index node = m_Slaves[slave];
  for (Index k = m_NodeShapes.offsets[node]; k < m_NodeShapes.offsets[node + 1]; ++k)
  {
    const Index other = m_NodeShapes.nodes[k];
    add(other, m_NodeShapes.values[k] *
                 Vector3(weight(3 * other), weight(3 * other + 1), weight(3 * other + 2)));
  }
  for (int i = 0; coupling && i < 3; ++i)
  {
    for (std::size_t j = 0; j < (*coupling)[i].nodes.size(); ++j)
    {
      Vector3 direction = Vector3::Zero();
      direction[i] = -(*coupling)[i].values[j];
      add((*coupling)[i].nodes[j], direction);
    }
  }
  std::sort(system.touched.begin(), system.touched.end());
  std::vector<ActiveSystem::Overlap> & overlaps = system.overlaps[slave];
  overlaps.clear();
  for (const Index t : system.touched)
  {
    overlaps.push_back({ t, system.column[t] });
    system.column[t].setZero();
    system.marked[t] = 0;
  }
  system.overlapsKnown[slave] = 1;
}

double
MeshlessContact::Gap(Index node, const double * u) const
{
  return m_Targets[node] - m_Normals[node].dot(m_NodeShapes.Interpolate(node, u));
}

template <typename Weight>
void
MeshlessContact::AddDirection(double * u, const Weight & weight, std::size_t a, double multiplier) const
{
  const Index     node = m_Active[a];
  const Vector3 & n = m_Normals[node];
  for (Index k = m_NodeShapes.offsets[node]; k < m_NodeShapes.offsets[node + 1]; ++k)
  {
    for (int i = 0; i < 3; ++i)
    {
      const Index d = 3 * m_NodeShapes.nodes[k] + i;
      u[d] += multiplier * m_NodeShapes.values[k] * n[i] * weight(d);
    }
  }
  for (int i = 0; m_Couplings[a] && i < 3; ++i)
  {
    const EssentialBoundary::Coupling & coupling = (*m_Couplings[a])[i];
    for (std::size_t j = 0; j < coupling.nodes.size(); ++j)
    {
      u[3 * coupling.nodes[j] + i] -= multiplier * n[i] * coupling.values[j];
    }
  }
}

template <typename Weight>
void
MeshlessContact::Sweep(double * u, const Weight & weight, double tolerance, long long & sweeps) const
{
  // Kaczmarz sweeps until the gaps close.
  for (int sweep = 0; sweep < kSweeps; ++sweep)
  {
    ++sweeps;
    double largest = 0.0;
    for (std::size_t a = 0; a < m_Active.size(); ++a)
    {
      const double gap = Gap(m_Active[a], u);
      largest = std::max(largest, std::abs(gap));
      if (m_RowNorms[a] > 0.0)
      {
        AddDirection(u, weight, a, gap / m_RowNorms[a]);
      }
    }
    if (largest <= tolerance)
    {
      return;
    }
  }
}

} // namespace bmr
