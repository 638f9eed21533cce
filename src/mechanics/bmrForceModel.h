// Internal-force kernels of the Total Lagrangian formulation (private to the core).
//
// Everything that depends only on the reference configuration is computed once:
// shape-function gradients, volumes, hourglass shape vectors and stiffnesses,
// nodal volumes for the average-nodal-pressure tetrahedron, and a schedule of
// the cells (two colours of slabs, or many colours of blocks) that lets forces
// be assembled in parallel without atomics and in a fixed order (deterministic
// for any thread count).
#ifndef bmrForceModel_h
#define bmrForceModel_h

#include "bmrMeshless.h"
#include "bmrConstitutiveLaw.h"
#include "bmrModel.h"
#include "bmrNodeOrder.h"
#include "bmrBinaryStream.h"
#include "bmrSolver.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <memory>
#include <string>
#include <vector>

namespace bmr
{

struct Energies
{
  double strain = 0.0;    // N*mm, includes hourglass energy
  double hourglass = 0.0; // N*mm
};

/** Smallest critical time step 2 / sqrt(waveBound / density) over the
 *  integration units (cells or points), and the index of that unit. */
double
SmallestStableStep(const std::vector<double> & waveBound, const std::vector<double> & density, Index * unit);

/** Work items (cells or integration points) in blocks of consecutive items,
 *  the blocks coloured so that blocks of one colour share no node. Blocks of
 *  a colour are processed in parallel, each sequentially (in chunks of the
 *  kernel's SIMD block), scattering forces without atomics; every node then
 *  receives its contributions in the same order whatever the number of
 *  threads. */
struct ColouredSchedule
{
  std::vector<Index> items;         // item indices, colour by colour, block by block
  std::vector<Index> blockOffsets;  // block b: items [blockOffsets[b], blockOffsets[b + 1])
  std::vector<Index> colourOffsets; // colour c: blocks [colourOffsets[c], colourOffsets[c + 1])
};

/** Schedules items whose nodes are the rows of (offsets, nodes), with one
 *  centre each: in a locality-preserving (Morton) order of their centres, cut
 *  into blocks of `blockSize`, coloured greedily (14-43 colours on the
 *  brain-sized benchmark); `box` is the frame of the Morton code (e.g. the
 *  model's nodes). */
ColouredSchedule
ScheduleByColour(const std::vector<Index> &   offsets,
                 const std::vector<Index> &   nodes,
                 const std::vector<Vector3> & centres,
                 const Eigen::AlignedBox3d &  box,
                 Index                        nodeCount,
                 Index                        blockSize);

/** Slabs per colour of the force kernels' schedules. Fixed, not taken from
 *  the thread count, so that results stay independent of it; it bounds the
 *  useful threads at 8 (the slabs of a colour are dealt out whole). */
constexpr Index kSlabsPerColour = 8;

/** Two colours of slabs instead: the items cut along the box's longest axis
 *  into 2 x slabsPerColour slabs of equal count (halved while a node is
 *  shared by slabs two apart, down to 4), even slabs one colour, odd slabs
 *  the other; each slab is one block (Morton order within), processed by one
 *  thread in chunks. Two barriers per pass instead of one per colour, and
 *  each thread's nodes stay together: on the brain-sized benchmark with 2
 *  threads, hexahedra 35-38 -> 31-34 ns per element-step, ANP 18-19 -> 15-16,
 *  meshless 50 -> 44-48 (2026-11-26, docs/thread-scaling.md). Empty when
 *  even 4 slabs are too thin (the caller then colours blocks). */
ColouredSchedule
ScheduleBySlabs(const std::vector<Index> &   offsets,
                const std::vector<Index> &   nodes,
                const std::vector<Vector3> & centres,
                const Eigen::AlignedBox3d &  box,
                Index                        nodeCount,
                Index                        slabsPerColour);

/** The force kernels' schedule: slabs (ScheduleBySlabs, kSlabsPerColour),
 *  or coloured blocks of `blockSize` (ScheduleByColour) where slabs would be
 *  too thin. */
ColouredSchedule
ScheduleWork(const std::vector<Index> &   offsets,
             const std::vector<Index> &   nodes,
             const std::vector<Vector3> & centres,
             const Eigen::AlignedBox3d &  box,
             Index                        nodeCount,
             Index                        blockSize);

/** The collapse barrier's bulk modulus per unit (cell or integration point;
 *  internal units): the larger of the unit's own kappa and the model's, which
 *  is `settingPascal` or, for 0, the volume-weighted median of the units'
 *  kappa (the bulk tissue's). */
std::vector<double>
CollapseModuli(const std::vector<double> & kappa, const std::vector<double> & volume, double settingPascal);

/** Dynamic relaxation's masses that follow the stiffness diagonal (Jacobi)
 *  and are scaled so that Gershgorin's bound holds. A unit (cell or
 *  integration point) of stiffness s = M V (P-wave modulus times volume)
 *  with shape-function gradient norms g_a adds s g_a^2 to node a's diagonal
 *  and s g_a sum_b g_b to its row bound; the masses are the diagonal times
 *  the largest row-to-diagonal ratio. Sharing each unit's bound equally
 *  instead gives a node with small gradients (the rim of a meshless
 *  support, the blunt corner of a flat tetrahedron) as much mass as the
 *  others: slow modes (docs/solver.md). */
class DiagonalMasses
{
public:
  explicit DiagonalMasses(Index nodeCount);
  void AddUnit(const Index * nodes, const double * gradientNorms, int count, double stiffness);
  /** A unit whose bound is already shared equally (hexahedra with hourglass
   *  control); added as it is, outside the Gershgorin scaling. */
  void AddEqualShares(const Index * nodes, int count, double bound);
  /** The masses times `factor`. */
  std::vector<double> Masses(double factor) const;

private:
  std::vector<double> m_Diagonal;
  std::vector<double> m_RowBounds;
  std::vector<double> m_EqualShares;
};

/** Bytes held by a table (StreamedBytesPerStep). */
template <typename Table>
std::size_t
BytesOf(const Table & table)
{
  return table.size() * sizeof(table[0]);
}

/** Internal forces, masses and stable time steps of one discretization; the
 *  integrators see only this. Failures are reported by the index of the
 *  integration unit (model cell, or integration point), which Describe() names. */
class ForceModel
{
public:
  virtual ~ForceModel() = default;

  virtual Index NodeCount() const = 0;

  /** Internal forces f (3 per node, N) at displacements u (3 per node, mm).
   *  Returns -1, or the smallest index of a unit whose Jacobian is not positive
   *  (forces are then meaningless). */
  virtual Index ComputeInternalForces(const double * u, double * f) = 0;

  /** Lumped nodal masses (t) of the physical densities. */
  virtual std::vector<double> LumpedMasses() const = 0;

  /** Nodal masses of dynamic relaxation, chosen so that a bound on the
   *  stiffness keeps the step timeStep / safety stable: hexahedra share each
   *  cell's bound equally among their nodes, tetrahedra and the meshless
   *  model follow the stiffness diagonal (DiagonalMasses). With `collapse`, for
   *  the stiffness once the collapse barrier engages (soft units get
   *  heavier), else for the reference state. */
  virtual std::vector<double> ScaledMasses(double timeStep, double safety, bool collapse) const = 0;

  /** Smallest unit critical time step (s) for the physical densities, and its unit. */
  virtual double CriticalTimeStep(Index * unit = nullptr) const = 0;

  virtual Energies ComputeEnergies(const double * u) const = 0;

  /** Cauchy stress (Pa) per unit: per model cell, or per integration point. */
  virtual std::vector<Eigen::Matrix3d> CauchyStress(const double * u) const = 0;

  /** The unit for messages, e.g. "hexahedron cell 12" or "integration point 7 at (1, 2, 3) mm". */
  virtual std::string Describe(Index unit) const = 0;

  /** Names of the parts in use, for SolveResult::activeComponents. */
  virtual void AddComponents(std::vector<std::string> & components) const = 0;
  /** Bytes of the tables one force pass reads or writes, each counted once per
   *  pass that streams it; the node arrays (u, f and the like) are not
   *  counted. The memory roofline's numerator (SolvePartSeconds). */
  virtual std::size_t StreamedBytesPerStep() const = 0;
  /** A copy working with `threads` threads (a stored SolverPrecomputation's for one solve). */
  virtual std::unique_ptr<ForceModel> Clone(int threads) const = 0;

  /** Its tables (everything but the threads), for SolverPrecomputation. */
  virtual void Write(BinaryWriter & out) const = 0;
};

/** Hexahedra with hourglass control and linear or ANP tetrahedra. */
class FiniteElementForceModel : public ForceModel
{
public:
  FiniteElementForceModel(const Model & model, const SolverSettings & settings, int threads);

  Index NodeCount() const override { return m_NodeCount; }
  Index HexahedronCount() const { return static_cast<Index>(m_HexNodes.size()); }
  Index TetrahedronCount() const { return static_cast<Index>(m_TetNodes.size()); }
  bool  UsesAverageNodalPressure() const { return m_AverageNodalPressure && !m_TetNodes.empty(); }

  Index                        ComputeInternalForces(const double * u, double * f) override;
  std::vector<double>          LumpedMasses() const override;
  std::vector<double>          ScaledMasses(double timeStep, double safety, bool collapse) const override;
  double                       CriticalTimeStep(Index * cell = nullptr) const override;
  Energies                     ComputeEnergies(const double * u) const override;
  std::vector<Eigen::Matrix3d> CauchyStress(const double * u) const override;
  std::string                  Describe(Index cell) const override;
  void                         AddComponents(std::vector<std::string> & components) const override;
  std::size_t                  StreamedBytesPerStep() const override;

  /** Model cell index of the given kernel cell (hexahedra first, then tetrahedra). */
  Index ModelCell(Index kernelCell) const { return m_ModelCell[kernelCell]; }

  std::unique_ptr<ForceModel> Clone(int threads) const override;
  void                        Write(BinaryWriter & out) const override;
  /** The inverse of Write (one thread: a stored model is used through Clone); checks that every index lies in
   *  range (bmr::Error otherwise). */
  static std::unique_ptr<FiniteElementForceModel> Read(BinaryReader & in, bool laws);

  /** Lists every member but the threads to `visit` (bmrBinaryStream.h), in
   *  one order for writing and reading; without `laws` as format version 1
   *  wrote them (every material neo-Hookean). */
  template <typename Self, typename Visitor>
  static void VisitMembers(Self & self, Visitor & visit, bool laws = true)
  {
    visit(self.m_NodeCount);
    visit(self.m_AverageNodalPressure);
    visit(self.m_HourglassControl);
    visit(self.m_CellTypes);
    visit(self.m_HexNodes);
    visit(self.m_HexB);
    visit(self.m_HexXH);
    visit(self.m_HexHourglassStiffness);
    visit(self.m_TetNodes);
    visit(self.m_TetB);
    visit(self.m_TetAveraged);
    visit(self.m_TetJacobian);
    visit(self.m_NodalPressure);
    visit(self.m_NodeTetOffsets);
    visit(self.m_NodeTets);
    visit(self.m_NodeTetWeights);
    visit(self.m_NodalVolume);
    visit(self.m_NodalBulkModulus);
    visit(self.m_Volume);
    visit(self.m_Mu);
    visit(self.m_Kappa);
    visit(self.m_Collapse);
    visit(self.m_Density);
    visit(self.m_WaveBound);
    visit(self.m_CollapseWaveBound);
    visit(self.m_ModelCell);
    visit(self.m_HexBlockOffsets);
    visit(self.m_HexColourOffsets);
    visit(self.m_TetBlockOffsets);
    visit(self.m_TetColourOffsets);
    visit(self.m_FirstTouchOffsets);
    visit(self.m_FirstTouchNodes);
    visit(self.m_UntouchedNodes);
    if (laws)
    {
      visit(self.m_SecondModulus);
    }
  }

private:
  FiniteElementForceModel() = default;

  /** Cells per chunk of a slab, and per block where ScheduleCells falls back
   *  to colours; measured with colours on the brain-sized benchmark
   *  (2026-11-26, docs/thread-scaling.md): hexahedra in blocks of 256 made
   *  116 blocks in 14 colours (3-15 blocks a colour); blocks of 128 took
   *  37.2 instead of 40.9 ns per element-step with 2 threads and 56.8
   *  instead of 54.5 with one (64: 41, 32: 44 ns); colours balanced in size
   *  gained nothing. Tetrahedra in blocks of 512 took 16.7-17.4 instead of
   *  18.2-18.5 ns with 2 threads (1024: 17.4; 128: 19.2). */
  static constexpr Index kHexahedraPerBlock = 128;
  static constexpr Index kTetrahedraPerBlock = 512;

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

  /** ANP: which tetrahedra share nodal pressures (the nearly incompressible
   *  ones), each node's cells, weights, volume and bulk modulus, and those
   *  cells' bounds (and `waveModulus`) raised to their nodes' moduli. */
  void PrepareAverageNodalPressure(Index hexCount, std::vector<double> & waveModulus);
  /** The nodes each block touches first (ZeroFirstTouched) and those no cell touches. */
  void OrderFirstTouches();
  void TetrahedronDilatations(Index begin, Index end, const double * u);
  /** Adds the forces of hexahedra [begin, end) to f; returns the first
   *  inverted one or -1. kSecondInvariant: some material is Mooney-Rivlin
   *  (bmrConstitutiveLaw.h). */
  template <bool kSecondInvariant>
  Index AddHexahedronForces(Index begin, Index end, const double * u, double * f) const;
  /** Adds the forces of tetrahedra [begin, end) to f; returns the first inverted one or -1. */
  template <bool kSecondInvariant>
  Index AddTetrahedronForces(Index begin, Index end, const double * u, double * f) const;

  int   m_Threads = 1;
  Index m_NodeCount = 0;
  bool  m_AverageNodalPressure = false;
  bool  m_HourglassControl = false;
  std::vector<CellType> m_CellTypes; // model cells, for messages

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
  /** ANP shares nodal pressures among cells with kappa above this many times mu
   *  (Poisson's ratio above 0.4); the others keep their own J. */
  static constexpr double kNearlyIncompressible = 14.0 / 3.0;
  std::vector<double>               m_TetAveraged;   // ANP: 1 for cells that share nodal pressures, else 0
  std::vector<double>               m_TetJacobian;   // per step, ANP
  std::vector<double>               m_NodalPressure; // per step, ANP: kappa_n (J_n - 1)
  // Nodal averaging of J: per node, the tetrahedra around it and their weights
  // V_e / sum V_e; the node's share of their volume (sum V_e / 4) and its bulk
  // modulus (the same weighted mean of the cells').
  std::vector<Index>  m_NodeTetOffsets;
  std::vector<Index>  m_NodeTets;
  std::vector<double> m_NodeTetWeights;
  std::vector<double> m_NodalVolume;
  std::vector<double> m_NodalBulkModulus;

  /** 2 C01 of kernel cell k (0 for the neo-Hookean law). */
  double SecondModulus(Index k) const { return m_SecondModulus.empty() ? 0.0 : m_SecondModulus[k]; }
  UnitModuli UnitModuliOf(Index k) const { return { m_Mu[k], SecondModulus(k), m_Kappa[k], m_Collapse[k] }; }

  /** ANP: node n's pressure kappa_n (J_n - 1) from the tetrahedra's J. */
  double NodalPressure(Index n, const double * tetJacobian) const;
  /** ANP: the nodal pressures kappa_n (J_n - 1) at displacements u. */
  std::vector<double> NodalPressures(const double * u) const;
  /** Tetrahedron t's pressure: the mean of its nodes' (ANP), or its own kappa (J - 1). */
  double TetrahedronPressure(Index t, double J, const std::vector<double> & nodalPressure) const;

  // Per kernel cell (hexahedra first): reference volume, material constants
  // (internal units), characteristic wave-number bound q = n B:B (1 + hourglass).
  std::vector<double> m_Volume;
  std::vector<double> m_Mu;            // the small-strain shear modulus, 2 (C10 + C01)
  std::vector<double> m_SecondModulus; // 2 C01; empty when every material is neo-Hookean
  std::vector<double> m_Kappa;
  std::vector<double> m_Collapse; // the collapse barrier's bulk modulus (CollapseModuli)
  std::vector<double> m_Density;
  std::vector<double> m_WaveBound;
  std::vector<double> m_CollapseWaveBound; // added to m_WaveBound once the collapse barrier engages
  std::vector<Index>  m_ModelCell;

  // Kernel cells are stored colour by colour, block (slab) by block; blocks of
  // one colour share no node (see ScheduleCells).
  std::vector<Index> m_HexBlockOffsets;
  std::vector<Index> m_HexColourOffsets;
  std::vector<Index> m_TetBlockOffsets;
  std::vector<Index> m_TetColourOffsets;
  // The nodes each block touches first in that order (hexahedral blocks,
  // then tetrahedral ones): the block zeroes their forces before it adds to
  // them, so the force pass needs no zeroing pass and no barrier after it.
  // Nodes of no cell are zeroed apart.
  std::vector<Index> m_FirstTouchOffsets;
  std::vector<Index> m_FirstTouchNodes;
  std::vector<Index> m_UntouchedNodes;
  void               ZeroFirstTouched(Index block, double * f) const;
};

/** Meshless (MTLED) internal forces: the deformation gradient at each
 *  integration point from the MLS shape-function derivatives of its
 *  neighbours, neo-Hookean stress, f_I = sum_p w_p P_p grad phi_I(x_p).
 *  Forces are gathered node by node from per-point stresses, so the sums run
 *  in a fixed order whatever the thread count. */
class MeshlessForceModel : public ForceModel
{
public:
  /** `shapeFunctions`: the table at model.meshless.integrationPoints, with
   *  gradients. Throws bmr::Error for a node in the support of no integration
   *  point (it would have neither mass nor stiffness). */
  MeshlessForceModel(const Model & model, ShapeFunctionTable shapeFunctions, const SolverSettings & settings,
                     int threads);

  Index                        NodeCount() const override { return m_NodeCount; }
  Index                        PointCount() const { return static_cast<Index>(m_KernelPoint.size()); }
  Index                        ComputeInternalForces(const double * u, double * f) override;
  std::vector<double>          LumpedMasses() const override;
  std::vector<double>          ScaledMasses(double timeStep, double safety, bool collapse) const override;
  double                       CriticalTimeStep(Index * point = nullptr) const override;
  Energies                     ComputeEnergies(const double * u) const override;
  std::vector<Eigen::Matrix3d> CauchyStress(const double * u) const override;
  std::string                  Describe(Index point) const override;
  void                         AddComponents(std::vector<std::string> & components) const override;
  std::size_t                  StreamedBytesPerStep() const override;

  /** Deformation gradient at an integration point. */
  Eigen::Matrix3d DeformationGradientAt(Index point, const double * u) const;

  std::unique_ptr<ForceModel> Clone(int threads) const override;
  void                        Write(BinaryWriter & out) const override;
  /** The inverse of Write (one thread: a stored model is used through Clone); checks that every index lies in
   *  range (bmr::Error otherwise). */
  static std::unique_ptr<MeshlessForceModel> Read(BinaryReader & in, bool laws);

  /** Lists every member but the threads and the per-step buffers to `visit`;
   *  without `laws` as format version 1 wrote them. */
  template <typename Self, typename Visitor>
  static void VisitMembers(Self & self, Visitor & visit, bool laws = true)
  {
    visit(self.m_NodeCount);
    visit(self.m_Positions);
    visit(self.m_Weight);
    visit(self.m_Mu);
    visit(self.m_Kappa);
    visit(self.m_Collapse);
    visit(self.m_Density);
    visit(self.m_WaveBound);
    visit(self.m_KernelPoint);
    visit(self.m_KernelBlockOffsets);
    visit(self.m_KernelColourOffsets);
    visit(self.m_KernelOffsets);
    visit(self.m_Numbering);
    visit(self.m_KernelNodes);
    visit(self.m_KernelGradients);
    visit(self.m_KernelMaterial);
    visit(self.m_KernelIndexOfPoint);
    if (laws)
    {
      visit(self.m_KernelSecondModulus);
    }
  }

private:
  MeshlessForceModel() = default;

  /** Adds the forces of kernel points [first, last) (at most kPointsPerBlock)
   *  to the padded forces; returns the first inverted point in the kernel's
   *  order (its index there, not the point's) or -1. */
  template <bool kSecondInvariant>
  Index AddPointForces(Index first, Index last);
  /** 2 C01 of integration point p (0 for the neo-Hookean law). */
  double SecondModulusOfPoint(Index p) const
  {
    return m_KernelSecondModulus.empty() ? 0.0 : m_KernelSecondModulus[m_KernelIndexOfPoint[p]];
  }

  /** Integration points per chunk of a slab, or per block of ScheduleByColour
   *  where slabs are too thin; measured with colours:
   *  blocks of 128 took 45.2-48.1 instead of 54.3-59.3 ns per point-step with
   *  2 threads on the brain-sized benchmark, 85.8 instead of 81.3 with one
   *  (2026-11-26; 64: 50, 256: 45.0 and 87.8 ns). */
  static constexpr Index kPointsPerBlock = 128;

  int                  m_Threads = 1;
  Index                m_NodeCount = 0;
  std::vector<Vector3> m_Positions;
  std::vector<double>  m_Weight;    // mm^3
  std::vector<double>  m_Mu;        // internal units
  std::vector<double>  m_Kappa;
  std::vector<double>  m_Collapse;  // the collapse barrier's bulk modulus (CollapseModuli)
  std::vector<double>  m_Density;
  std::vector<double>  m_WaveBound; // (lambda + 2 mu) n sum |grad phi|^2 (explicit dynamics' time step)
  // The force kernel's table, in the order of the coloured schedule, so that
  // one pass streams it once per step: per kernel point its integration point,
  // weight and moduli; per entry the node and grad phi. It is the only copy
  // (the MLS table given to the constructor is released): at 100,000 DOF it
  // holds 4 M entries, 16 bytes each.
  // Reading the MLS table's rows in schedule order instead took 2.7 times as
  // long (brain-sized benchmark, 2 threads, 2026-11-25): the rows' jumps
  // defeat the prefetcher.
  std::vector<Index>  m_KernelPoint;
  std::vector<Index>  m_KernelBlockOffsets;
  std::vector<Index>  m_KernelColourOffsets;
  std::vector<Index>  m_KernelOffsets;
  MortonNumbering     m_Numbering; // the kernel's numbering of the nodes
  std::vector<Index>  m_KernelNodes; // slots (m_Numbering), not model nodes
  // grad phi in single precision: 16 instead of 28 bytes an entry streamed
  // per step, for relative errors of 6e-8 (docs/thread-scaling.md); sums in double.
  std::vector<float>  m_KernelGradients; // 3 per entry, and one float of padding at the end
  Vector3 KernelGradient(Index k) const
  {
    const float * g = &m_KernelGradients[3 * static_cast<std::size_t>(k)];
    return Vector3(g[0], g[1], g[2]);
  }
  std::vector<double> m_KernelMaterial;  // weight, mu, kappa, collapse modulus per kernel point
  std::vector<double> m_KernelSecondModulus; // 2 C01 per kernel point; empty when every material is neo-Hookean
  std::vector<Index>  m_KernelIndexOfPoint; // integration point -> its kernel point
  // u and f with 4 slots per node (x, y, z, 0), so that a neighbour's three
  // components are one SIMD load or store (brain-sized kernel, 1 thread:
  // 105-110 -> 99.5 ns per point-step; docs/thread-scaling.md).
  std::vector<double> m_PaddedDisplacements;
  std::vector<double> m_PaddedForces;
};

} // namespace bmr

#endif
