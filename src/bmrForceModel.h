// Internal-force kernels of the Total Lagrangian formulation (private to the core).
//
// Everything that depends only on the reference configuration is computed once:
// shape-function gradients, volumes, hourglass shape vectors and stiffnesses,
// nodal volumes for the average-nodal-pressure tetrahedron, and a colouring of
// the cells that lets forces be assembled in parallel without atomics and in a
// fixed order (deterministic for any thread count).
#ifndef bmrForceModel_h
#define bmrForceModel_h

#include "bmrModel.h"
#include "bmrSolver.h"

#include <Eigen/Core>

#include <vector>

namespace bmr
{

struct Energies
{
  double strain = 0.0;    // N*mm, includes hourglass energy
  double hourglass = 0.0; // N*mm
};

class ForceModel
{
public:
  ForceModel(const Model & model, const SolverSettings & settings, int threads);

  Index NodeCount() const { return m_NodeCount; }
  Index HexahedronCount() const { return static_cast<Index>(m_HexNodes.size()); }
  Index TetrahedronCount() const { return static_cast<Index>(m_TetNodes.size()); }
  bool  UsesAverageNodalPressure() const { return m_AverageNodalPressure && !m_TetNodes.empty(); }

  /** Internal forces f (3 per node, N) at displacements u (3 per node, mm).
   *  Returns -1, or the smallest index of a cell whose Jacobian is not positive
   *  (forces are then meaningless). */
  Index ComputeInternalForces(const double * u, double * f);

  /** Lumped nodal masses (t) of the physical densities. */
  std::vector<double> LumpedMasses() const;

  /** Lumped nodal masses chosen so that every cell's critical time step equals
   *  timeStep / safety (mass scaling of dynamic relaxation). */
  std::vector<double> ScaledMasses(double timeStep, double safety) const;

  /** Smallest cell critical time step (s) for the physical densities, and its cell. */
  double CriticalTimeStep(Index * cell = nullptr) const;

  Energies ComputeEnergies(const double * u) const;

  /** Cauchy stress per cell (Pa), cells in model order. */
  std::vector<Eigen::Matrix3d> CauchyStress(const double * u) const;

  /** Model cell index of the given kernel cell (hexahedra first, then tetrahedra). */
  Index ModelCell(Index kernelCell) const { return m_ModelCell[kernelCell]; }

private:
  /** Cells per block of the parallel schedule (see ScheduleCells). */
  static constexpr Index kCellsPerBlock = 256;

  /** The `Width` values of one cell from component-major storage. */
  template <int Width>
  static std::array<double, Width> ComponentsOf(const std::vector<double> & values, Index cell)
  {
    const std::size_t         count = values.size() / Width;
    std::array<double, Width> out;
    for (int c = 0; c < Width; ++c)
    {
      out[c] = values[c * count + static_cast<std::size_t>(cell)];
    }
    return out;
  }

  /** Nodal lumped masses from a mass per kernel cell, shared equally by its nodes. */
  template <typename CellMass>
  std::vector<double> LumpToNodes(const CellMass & cellMass) const;

  void TetrahedronDilatations(Index begin, Index end, const double * u);
  /** Adds the forces of hexahedra [begin, end) to f; returns the first inverted one or -1. */
  Index AddHexahedronForces(Index begin, Index end, const double * u, double * f) const;
  /** Adds the forces of tetrahedra [begin, end) to f; returns the first inverted one or -1. */
  Index AddTetrahedronForces(Index begin, Index end, const double * u, double * f) const;

  int   m_Threads;
  Index m_NodeCount;
  bool  m_AverageNodalPressure;

  // Hexahedra: nodes, B = (1/V) integral dN/dX (8x3) and X^T h (3x4), from
  // which the hourglass vectors follow, both component-major like m_TetB;
  // hourglass stiffness per cell.
  std::vector<std::array<Index, 8>> m_HexNodes;
  std::vector<double>               m_HexB;
  std::vector<double>               m_HexXH;
  std::vector<double>               m_HexHourglassStiffness; // N/mm

  // Tetrahedra: nodes, dN/dX component-major: m_TetB[c * count + t], c = 3 a + j.
  std::vector<std::array<Index, 4>> m_TetNodes;
  std::vector<double>               m_TetB;
  std::vector<double>               m_TetJacobian; // per step, ANP
  std::vector<double>               m_NodalJacobian;
  // Nodal averaging of J: per node, the tetrahedra around it and their weights V_e / sum V_e.
  std::vector<Index>  m_NodeTetOffsets;
  std::vector<Index>  m_NodeTets;
  std::vector<double> m_NodeTetWeights;

  // Per kernel cell (hexahedra first): reference volume, material constants
  // (internal units), characteristic wave-number bound q = n B:B (1 + hourglass).
  std::vector<double> m_Volume;
  std::vector<double> m_Mu;
  std::vector<double> m_Kappa;
  std::vector<double> m_Density;
  std::vector<double> m_WaveBound;
  std::vector<Index>  m_ModelCell;

  // Kernel cells are stored colour by colour, block by block; blocks of one
  // colour share no node (see ScheduleCells).
  std::vector<Index> m_HexBlockOffsets;
  std::vector<Index> m_HexColourOffsets;
  std::vector<Index> m_TetBlockOffsets;
  std::vector<Index> m_TetColourOffsets;
};

} // namespace bmr

#endif
