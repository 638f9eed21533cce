#include "bmrForceModel.h"

#include "bmrConstitutiveLaw.h"
#include "bmrShape.h"
#include "bmrUnits.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <set>

namespace bmr
{

namespace
{

using TriangleKey = std::array<Index, 3>;

TriangleKey
SortedTriangle(Index a, Index b, Index c)
{
  TriangleKey key{ a, b, c };
  std::sort(key.begin(), key.end());
  return key;
}

// Faces of all tetrahedra, to find hexahedron faces that meet tetrahedra.
std::set<TriangleKey>
TetrahedronFaces(const Model & model)
{
  std::set<TriangleKey> faces;
  for (const Cell & cell : model.cells)
  {
    if (cell.type == CellType::Tetrahedron)
    {
      const auto & n = cell.nodes;
      faces.insert(SortedTriangle(n[0], n[1], n[2]));
      faces.insert(SortedTriangle(n[0], n[1], n[3]));
      faces.insert(SortedTriangle(n[0], n[2], n[3]));
      faces.insert(SortedTriangle(n[1], n[2], n[3]));
    }
  }
  return faces;
}

// b_a = integral of dN_a/dX over the hexahedron = integral of N_a n over its
// boundary. A face shared with two tetrahedra is integrated as those two
// triangles instead of as a bilinear quad, so that the hexahedron and its
// tetrahedral neighbours see the same face: mixed meshes then pass the patch
// test without pyramid transition cells.
void
UseTetrahedronFacesOfHexahedron(const std::array<Index, 8> & nodes,
                                const HexahedronCoordinates & x,
                                const std::set<TriangleKey> & tetFaces,
                                HexahedronIntegralsResult &   integrals)
{
  static constexpr int faces[6][4] = { { 0, 3, 2, 1 }, { 4, 5, 6, 7 }, { 0, 1, 5, 4 },
                                       { 1, 2, 6, 5 }, { 2, 3, 7, 6 }, { 3, 0, 4, 7 } };
  bool changed = false;
  for (const auto & face : faces)
  {
    const Index n0 = nodes[face[0]], n1 = nodes[face[1]], n2 = nodes[face[2]], n3 = nodes[face[3]];
    int         diagonal = -1; // 0: triangles (0,1,2),(0,2,3); 1: (0,1,3),(1,2,3)
    if (tetFaces.count(SortedTriangle(n0, n1, n2)) && tetFaces.count(SortedTriangle(n0, n2, n3)))
    {
      diagonal = 0;
    }
    else if (tetFaces.count(SortedTriangle(n0, n1, n3)) && tetFaces.count(SortedTriangle(n1, n2, n3)))
    {
      diagonal = 1;
    }
    if (diagonal < 0)
    {
      continue;
    }
    changed = true;
    // Remove the bilinear face integral (2x2 Gauss is exact for it) ...
    const double g = 1.0 / std::sqrt(3.0);
    for (const double r : { -g, g })
    {
      for (const double s : { -g, g })
      {
        const double  shape[4] = { 0.25 * (1 - r) * (1 - s), 0.25 * (1 + r) * (1 - s), 0.25 * (1 + r) * (1 + s),
                                   0.25 * (1 - r) * (1 + s) };
        Eigen::Vector3d dxdr = Eigen::Vector3d::Zero(), dxds = Eigen::Vector3d::Zero();
        const double    dr[4] = { -(1 - s), (1 - s), (1 + s), -(1 + s) };
        const double    ds[4] = { -(1 - r), -(1 + r), (1 + r), (1 - r) };
        for (int k = 0; k < 4; ++k)
        {
          dxdr += 0.25 * dr[k] * x.row(face[k]).transpose();
          dxds += 0.25 * ds[k] * x.row(face[k]).transpose();
        }
        const Eigen::Vector3d normalArea = dxdr.cross(dxds);
        for (int k = 0; k < 4; ++k)
        {
          integrals.b.row(face[k]) -= shape[k] * normalArea.transpose();
        }
      }
    }
    // ... and add the two triangles' integrals (a third of the area vector per corner).
    const int triangles[2][2][3] = { { { 0, 1, 2 }, { 0, 2, 3 } }, { { 0, 1, 3 }, { 1, 2, 3 } } };
    for (const auto & triangle : triangles[diagonal])
    {
      const Eigen::Vector3d a = x.row(face[triangle[0]]).transpose();
      const Eigen::Vector3d areaVector =
        0.5 * (x.row(face[triangle[1]]).transpose() - a).cross(x.row(face[triangle[2]]).transpose() - a);
      for (const int k : triangle)
      {
        integrals.b.row(face[k]) += areaVector.transpose() / 3.0;
      }
    }
  }
  if (changed)
  {
    // Volume of the polyhedron with those faces, consistent with b: sum_a X_a b_a^T = V I.
    integrals.volume = (x.transpose() * integrals.b).trace() / 3.0;
  }
}

// Adds the block-local nodal forces of cells [begin, end) (component-major,
// one column per cell) to the nodal vector, serially and in cell order.
template <std::size_t N, std::size_t Block>
void
AddBlockForces(const std::array<Index, N> * cellNodes, Index begin, Index end, const double (&forces)[3 * N][Block], double * f)
{
  for (Index cell = begin; cell < end; ++cell)
  {
    const Index local = cell - begin;
    for (std::size_t a = 0; a < N; ++a)
    {
      double * fa = f + 3 * static_cast<std::size_t>(cellNodes[cell][a]);
      fa[0] += forces[3 * a][local];
      fa[1] += forces[3 * a + 1][local];
      fa[2] += forces[3 * a + 2][local];
    }
  }
}

// Per-cell records of `width` values -> component-major: out[c * count + cell].
std::vector<double>
ComponentMajor(const std::vector<double> & records, std::size_t width)
{
  const std::size_t   count = records.size() / width;
  std::vector<double> out(records.size());
  for (std::size_t cell = 0; cell < count; ++cell)
  {
    for (std::size_t c = 0; c < width; ++c)
    {
      out[c * count + cell] = records[width * cell + c];
    }
  }
  return out;
}

// The model's cells of one type, scheduled by ScheduleWork (centres: their
// centroids); the schedule's items are model cell indices.
ColouredSchedule
ScheduleCells(const Model & model, CellType type, Index blockSize)
{
  const int           count = NodesPerCell(type);
  std::vector<Index>  cells, offsets{ 0 }, nodes;
  std::vector<Vector3> centres;
  for (Index c = 0; c < static_cast<Index>(model.cells.size()); ++c)
  {
    if (model.cells[c].type == type)
    {
      cells.push_back(c);
      Vector3 centre = Vector3::Zero();
      for (int a = 0; a < count; ++a)
      {
        nodes.push_back(model.cells[c].nodes[a]);
        centre += model.nodes[model.cells[c].nodes[a]];
      }
      offsets.push_back(static_cast<Index>(nodes.size()));
      centres.push_back(centre / count);
    }
  }
  ColouredSchedule schedule =
    ScheduleWork(offsets, nodes, centres, BoundingBox(model.nodes), static_cast<Index>(model.nodes.size()), blockSize);
  for (Index & item : schedule.items)
  {
    item = cells[item];
  }
  return schedule;
}

// One hexahedron's reference geometry: its nodes, shape-function gradients
// (mean over the cell), the hourglass basis X^T Gamma_base, volume, and the
// largest eigenvalue of gamma^T gamma for the Flanagan-Belytschko hourglass
// shape vectors gamma (orthogonal to every linear field).
struct HexahedronGeometry
{
  std::array<Index, 8>        nodes;
  HexahedronGradients         gradients;
  Eigen::Matrix<double, 3, 4> hourglassBasis;
  double                      volume;
  double                      hourglassNorm;
};

HexahedronGeometry
HexahedronGeometryOf(const Model & model, const Cell & cell, const std::set<TriangleKey> & tetFaces)
{
  Eigen::Matrix<double, 8, 4> hourglassBase;
  for (int a = 0; a < 8; ++a)
  {
    for (int alpha = 0; alpha < 4; ++alpha)
    {
      hourglassBase(a, alpha) = kHourglassBase[a][alpha];
    }
  }
  HexahedronGeometry    geometry;
  HexahedronCoordinates x;
  for (int a = 0; a < 8; ++a)
  {
    geometry.nodes[a] = cell.nodes[a];
    x.row(a) = model.nodes[geometry.nodes[a]].transpose();
  }
  HexahedronIntegralsResult integrals = HexahedronIntegrals(x);
  if (!tetFaces.empty())
  {
    UseTetrahedronFacesOfHexahedron(geometry.nodes, x, tetFaces, integrals);
  }
  geometry.gradients = integrals.b / integrals.volume;
  geometry.hourglassBasis = x.transpose() * hourglassBase;
  geometry.volume = integrals.volume;
  const Eigen::Matrix<double, 8, 4> gamma = hourglassBase - geometry.gradients * geometry.hourglassBasis;
  geometry.hourglassNorm = (gamma.transpose() * gamma).selfadjointView<Eigen::Lower>().eigenvalues().maxCoeff();
  return geometry;
}

} // namespace

FiniteElementForceModel::FiniteElementForceModel(const Model & model, const SolverSettings & settings, int threads)
  : m_Threads(std::max(1, threads))
  , m_NodeCount(static_cast<Index>(model.nodes.size()))
  , m_AverageNodalPressure(settings.tetrahedron == TetrahedronFormulation::AverageNodalPressure)
  , m_HourglassControl(settings.hourglassCoefficient > 0.0)
{
  for (const Cell & cell : model.cells)
  {
    m_CellTypes.push_back(cell.type);
  }
  // Kernel order: hexahedra, then tetrahedra, each colour by colour and block by block.
  const ColouredSchedule hexSchedule = ScheduleCells(model, CellType::Hexahedron, kHexahedraPerBlock);
  const ColouredSchedule tetSchedule = ScheduleCells(model, CellType::Tetrahedron, kTetrahedraPerBlock);
  m_ModelCell = hexSchedule.items;
  m_ModelCell.insert(m_ModelCell.end(), tetSchedule.items.begin(), tetSchedule.items.end());
  m_HexBlockOffsets = hexSchedule.blockOffsets;
  m_HexColourOffsets = hexSchedule.colourOffsets;
  m_TetBlockOffsets = tetSchedule.blockOffsets;
  m_TetColourOffsets = tetSchedule.colourOffsets;
  const Index hexCount = static_cast<Index>(hexSchedule.items.size());
  const std::size_t cellCount = m_ModelCell.size();
  m_Volume.resize(cellCount);
  m_Mu.resize(cellCount);
  m_Kappa.resize(cellCount);
  m_Density.resize(cellCount);
  m_WaveBound.resize(cellCount);
  // The volumetric part of each cell's wave-number bound (n B:B) and the
  // modulus the bound was made for, to raise it for the collapse barrier below.
  std::vector<double> volumetricWaveNumber(cellCount), waveModulus(cellCount);

  // Per cell, before the transposition to component-major storage below.
  std::vector<double>         tetGradients;      // 12 per tetrahedron
  std::vector<double>         hexGradients;      // 24 per hexahedron
  std::vector<double>         hexHourglassBasis; // 12 per hexahedron
  const std::set<TriangleKey> tetFaces =
    hexCount > 0 && hexCount < static_cast<Index>(cellCount) ? TetrahedronFaces(model) : std::set<TriangleKey>{};

  for (std::size_t k = 0; k < cellCount; ++k)
  {
    const Cell &     cell = model.cells[m_ModelCell[k]];
    const Material & material = model.materials[cell.material];
    const double     mu = material.ShearModulus() * units::PascalToInternal;
    const double     kappa = material.BulkModulus() * units::PascalToInternal;
    const double     pWaveModulus = kappa + 4.0 * mu / 3.0; // lambda + 2 mu
    m_Mu[k] = mu;
    m_Kappa[k] = kappa;
    m_Density[k] = material.density * units::DensityToInternal;

    if (cell.type == CellType::Hexahedron)
    {
      const HexahedronGeometry hexahedron = HexahedronGeometryOf(model, cell, tetFaces);
      const HexahedronGradients &         B = hexahedron.gradients;
      const Eigen::Matrix<double, 3, 4> & XH = hexahedron.hourglassBasis;
      const double                        BB = B.squaredNorm();
      m_HexNodes.push_back(hexahedron.nodes);
      for (int a = 0; a < 8; ++a)
      {
        for (int j = 0; j < 3; ++j)
        {
          hexGradients.push_back(B(a, j));
        }
      }
      for (int j = 0; j < 3; ++j)
      {
        for (int alpha = 0; alpha < 4; ++alpha)
        {
          hexHourglassBasis.push_back(XH(j, alpha));
        }
      }
      // Hourglass modes are (nearly) isochoric bending and twisting modes, so
      // their stiffness scales with the shear modulus; scaling it with
      // lambda + 2 mu (Flanagan-Belytschko) would lock nearly incompressible tissue.
      const double hourglassStiffness = settings.hourglassCoefficient * 2.0 * mu * hexahedron.volume * BB / 8.0;
      m_HexHourglassStiffness.push_back(hourglassStiffness);
      m_Volume[k] = hexahedron.volume;
      m_WaveBound[k] = 8.0 * BB + hourglassStiffness * hexahedron.hourglassNorm / (hexahedron.volume * pWaveModulus);
      volumetricWaveNumber[k] = 8.0 * BB;
    }
    else
    {
      TetrahedronCoordinates x;
      std::array<Index, 4>   nodes;
      for (int a = 0; a < 4; ++a)
      {
        nodes[a] = cell.nodes[a];
        x.row(a) = model.nodes[nodes[a]].transpose();
      }
      const TetrahedronGradients B = TetrahedronShapeGradients(x);
      m_TetNodes.push_back(nodes);
      for (int a = 0; a < 4; ++a)
      {
        for (int j = 0; j < 3; ++j)
        {
          tetGradients.push_back(B(a, j));
        }
      }
      m_Volume[k] = TetrahedronVolume(model.nodes[nodes[0]], model.nodes[nodes[1]], model.nodes[nodes[2]], model.nodes[nodes[3]]);
      m_WaveBound[k] = 4.0 * B.squaredNorm();
      volumetricWaveNumber[k] = m_WaveBound[k];
    }
    // Largest eigenvalue of the cell's stiffness over its lumped mass is at most
    // (lambda + 2 mu) / rho * q (Rayleigh bound); stored here without the density.
    m_WaveBound[k] *= pWaveModulus;
    waveModulus[k] = pWaveModulus;
  }

  // Component-major storage: the vectorised kernels read 8 cells' values at once.
  m_HexB = ComponentMajor(hexGradients, 24);
  m_HexXH = ComponentMajor(hexHourglassBasis, 12);
  const std::size_t tetCount = m_TetNodes.size();
  m_TetB = ComponentMajor(tetGradients, 12);

  m_NodalPressure.assign(m_NodeCount, 0.0);
  m_TetAveraged.assign(tetCount, 0.0);
  if (UsesAverageNodalPressure())
  {
    PrepareAverageNodalPressure(hexCount, waveModulus);
  }

  // The bound once the collapse barrier engages, for the masses of dynamic
  // relaxation: a collapsing soft cell must not outrun the time step.
  m_Collapse = CollapseModuli(m_Kappa, m_Volume, settings.collapseBulkModulus);
  m_SecondModulus = SecondInvariantModuli(
    cellCount, [&](std::size_t k) -> const Material & { return model.materials[model.cells[m_ModelCell[k]].material]; },
    units::PascalToInternal);
  m_CollapseWaveBound.resize(cellCount);
  for (std::size_t k = 0; k < cellCount; ++k)
  {
    m_CollapseWaveBound[k] = volumetricWaveNumber[k] * std::max(0.0, m_Collapse[k] - waveModulus[k]);
  }

  OrderFirstTouches();
}

void
FiniteElementForceModel::PrepareAverageNodalPressure(Index hexCount, std::vector<double> & waveModulus)
{
  const std::size_t tetCount = m_TetNodes.size();
  // Only nearly incompressible cells lock, so only they share nodal
  // pressures; a compressible cell (CSF) keeps its own J, so its volume
  // change does not load the parenchyma beside it nor the reverse
  // (Joldes et al. 2010 treat each material apart for the same reason).
  for (Index t = 0; t < static_cast<Index>(tetCount); ++t)
  {
    const Index k = hexCount + t;
    m_TetAveraged[t] = m_Kappa[k] > kNearlyIncompressible * m_Mu[k] ? 1.0 : 0.0;
  }
  m_TetJacobian.assign(tetCount, 1.0);
  m_NodeTetOffsets.assign(m_NodeCount + 1, 0);
  for (Index t = 0; t < static_cast<Index>(tetCount); ++t)
  {
    for (const Index n : m_TetNodes[t])
    {
      m_NodeTetOffsets[n + 1] += m_TetAveraged[t] > 0.0 ? 1 : 0;
    }
  }
  for (Index n = 0; n < m_NodeCount; ++n)
  {
    m_NodeTetOffsets[n + 1] += m_NodeTetOffsets[n];
  }
  m_NodeTets.resize(m_NodeTetOffsets.back());
  m_NodeTetWeights.resize(m_NodeTetOffsets.back());
  std::vector<Index>  fill(m_NodeTetOffsets.begin(), m_NodeTetOffsets.end() - 1);
  std::vector<double> nodalVolume(m_NodeCount, 0.0);
  for (Index t = 0; t < static_cast<Index>(tetCount); ++t)
  {
    for (const Index n : m_TetNodes[t])
    {
      if (m_TetAveraged[t] > 0.0)
      {
        m_NodeTets[fill[n]++] = t;
        nodalVolume[n] += m_Volume[hexCount + t];
      }
    }
  }
  // One bulk modulus and one pressure per node, so that the volumetric
  // energy sum_n V_n kappa_n (J_n - 1)^2 / 2 is a potential: averaging J
  // but keeping each cell's kappa gives a non-symmetric stiffness at
  // material interfaces (CSF beside parenchyma: 5000 to 1), whose
  // non-conservative forces sustain oscillations that dynamic relaxation
  // cannot damp.
  m_NodalVolume.assign(m_NodeCount, 0.0);
  m_NodalBulkModulus.assign(m_NodeCount, 0.0);
  for (Index n = 0; n < m_NodeCount; ++n)
  {
    m_NodalVolume[n] = 0.25 * nodalVolume[n];
    for (Index k = m_NodeTetOffsets[n]; k < m_NodeTetOffsets[n + 1]; ++k)
    {
      m_NodeTetWeights[k] = m_Volume[hexCount + m_NodeTets[k]] / nodalVolume[n];
      m_NodalBulkModulus[n] += m_NodeTetWeights[k] * m_Kappa[hexCount + m_NodeTets[k]];
    }
  }
  // The volumetric stiffness sum_n V_n kappa_n (J_n - 1)^2 is bounded cell
  // by cell (Cauchy-Schwarz on the weighted mean) with the mean kappa_n of
  // the cell's nodes in place of its own kappa.
  for (Index t = 0; t < static_cast<Index>(tetCount); ++t)
  {
    const Index k = hexCount + t;
    if (m_TetAveraged[t] > 0.0)
    {
      double kappa = 0.0;
      for (const Index n : m_TetNodes[t])
      {
        kappa += 0.25 * m_NodalBulkModulus[n];
      }
      const double factor = std::max(1.0, (kappa + 4.0 * m_Mu[k] / 3.0) / (m_Kappa[k] + 4.0 * m_Mu[k] / 3.0));
      m_WaveBound[k] *= factor;
      waveModulus[k] *= factor;
    }
  }
}

void
FiniteElementForceModel::OrderFirstTouches()
{
  std::vector<char> touched(static_cast<std::size_t>(m_NodeCount), 0);
  m_FirstTouchOffsets = { 0 };
  const auto firstTouches = [&](const auto & cellNodes, const std::vector<Index> & blockOffsets) {
    for (std::size_t block = 0; block + 1 < blockOffsets.size(); ++block)
    {
      for (Index cell = blockOffsets[block]; cell < blockOffsets[block + 1]; ++cell)
      {
        for (const Index node : cellNodes[cell])
        {
          if (!touched[node])
          {
            touched[node] = 1;
            m_FirstTouchNodes.push_back(node);
          }
        }
      }
      m_FirstTouchOffsets.push_back(static_cast<Index>(m_FirstTouchNodes.size()));
    }
  };
  firstTouches(m_HexNodes, m_HexBlockOffsets);
  firstTouches(m_TetNodes, m_TetBlockOffsets);
  for (Index node = 0; node < m_NodeCount; ++node)
  {
    if (!touched[node])
    {
      m_UntouchedNodes.push_back(node);
    }
  }
}

void
FiniteElementForceModel::ZeroFirstTouched(Index block, double * f) const
{
  for (Index k = m_FirstTouchOffsets[block]; k < m_FirstTouchOffsets[block + 1]; ++k)
  {
    double * fn = f + 3 * static_cast<std::size_t>(m_FirstTouchNodes[k]);
    fn[0] = fn[1] = fn[2] = 0.0;
  }
}

Index
FiniteElementForceModel::ComputeInternalForces(const double * u, double * f)
{
  const Index       hexCount = HexahedronCount();
  const bool        anp = UsesAverageNodalPressure();
  Index             firstInverted = std::numeric_limits<Index>::max();
  const Index       hexBlockCount = static_cast<Index>(m_HexBlockOffsets.size()) - 1;
  for (const Index node : m_UntouchedNodes)
  {
    f[3 * node] = f[3 * node + 1] = f[3 * node + 2] = 0.0;
  }

#pragma omp parallel num_threads(m_Threads) reduction(min : firstInverted)
  {
    // Hexahedra: static, since their blocks (slabs of equal size, or a few
    // coloured blocks a colour) are dealt out as evenly as by a dynamic
    // hand-out, which took 5-7 % longer with 2 threads on coloured blocks
    // (2026-11-26); the tetrahedra gain from the dynamic one.
    for (std::size_t colour = 0; colour + 1 < m_HexColourOffsets.size(); ++colour)
    {
#pragma omp for schedule(static)
      for (Index block = m_HexColourOffsets[colour]; block < m_HexColourOffsets[colour + 1]; ++block)
      {
        // A slab (ScheduleBySlabs) is one block of many chunks; a coloured block is one chunk.
        ZeroFirstTouched(block, f);
        for (Index chunk = m_HexBlockOffsets[block]; chunk < m_HexBlockOffsets[block + 1]; chunk += kHexahedraPerBlock)
        {
          const Index last = std::min(chunk + kHexahedraPerBlock, m_HexBlockOffsets[block + 1]);
          const Index inverted = m_SecondModulus.empty() ? AddHexahedronForces<false>(chunk, last, u, f)
                                                         : AddHexahedronForces<true>(chunk, last, u, f);
          if (inverted >= 0)
          {
            firstInverted = std::min(firstInverted, inverted);
          }
        }
      }
    }

    if (anp)
    {
      // Pass 1: element dilatations; pass 2: volume-weighted nodal averages.
#pragma omp for schedule(static)
      for (Index block = 0; block < static_cast<Index>(m_TetBlockOffsets.size()) - 1; ++block)
      {
        TetrahedronDilatations(m_TetBlockOffsets[block], m_TetBlockOffsets[block + 1], u);
      }
#pragma omp for schedule(static)
      for (Index n = 0; n < m_NodeCount; ++n)
      {
        m_NodalPressure[n] = NodalPressure(n, m_TetJacobian.data());
      }
    }

    for (std::size_t colour = 0; colour + 1 < m_TetColourOffsets.size(); ++colour)
    {
#pragma omp for schedule(dynamic, 1)
      for (Index block = m_TetColourOffsets[colour]; block < m_TetColourOffsets[colour + 1]; ++block)
      {
        ZeroFirstTouched(hexBlockCount + block, f);
        for (Index chunk = m_TetBlockOffsets[block]; chunk < m_TetBlockOffsets[block + 1]; chunk += kTetrahedraPerBlock)
        {
          const Index last = std::min(chunk + kTetrahedraPerBlock, m_TetBlockOffsets[block + 1]);
          const Index inverted = m_SecondModulus.empty() ? AddTetrahedronForces<false>(chunk, last, u, f)
                                                         : AddTetrahedronForces<true>(chunk, last, u, f);
          if (inverted >= 0)
          {
            firstInverted = std::min(firstInverted, hexCount + inverted);
          }
        }
      }
    }
  }
  return firstInverted == std::numeric_limits<Index>::max() ? Index{ -1 } : m_ModelCell[firstInverted];
}

// The small inner loops are unrolled explicitly: GCC vectorises the loop over
// cells (one cell per lane) only when no inner loop remains.
template <bool kSecondInvariant>
Index
FiniteElementForceModel::AddHexahedronForces(Index begin, Index end, const double * u, double * f) const
{
  const std::size_t  count = m_HexNodes.size();
  const double *     B = m_HexB.data();
  const double *     XH = m_HexXH.data();
  alignas(64) double forces[24][kHexahedraPerBlock];
  Index              firstInverted = std::numeric_limits<Index>::max();
#pragma omp simd reduction(min : firstInverted)
  for (Index e = begin; e < end; ++e)
  {
    Index  node[8];
    double ue[8][3], b[24], xh[12];
    #pragma GCC unroll 32
    for (int a = 0; a < 8; ++a)
    {
      node[a] = m_HexNodes[e][a];
      #pragma GCC unroll 32
      for (int i = 0; i < 3; ++i)
      {
        ue[a][i] = u[3 * node[a] + i];
      }
    }
    #pragma GCC unroll 32
    for (int c = 0; c < 24; ++c)
    {
      b[c] = B[c * count + e];
    }
    #pragma GCC unroll 32
    for (int c = 0; c < 12; ++c)
    {
      xh[c] = XH[c * count + e];
    }
    Matrix3x3 F;
    #pragma GCC unroll 32
    for (int i = 0; i < 3; ++i)
    {
      #pragma GCC unroll 32
      for (int j = 0; j < 3; ++j)
      {
        double sum = i == j ? 1.0 : 0.0;
        #pragma GCC unroll 32
        for (int a = 0; a < 8; ++a)
        {
          sum += ue[a][i] * b[3 * a + j];
        }
        F.m[i][j] = sum;
      }
    }
    const Matrix3x3 cof = CofactorOf(F);
    const double    J = DeterminantOf(F, cof);
    if (!(J > 0.0))
    {
      firstInverted = std::min(firstInverted, e);
    }
    // Hourglass mode amplitudes m_alpha = Gamma_alpha^T u with Gamma = h - B (X^T h).
    double modes[4][3];
    #pragma GCC unroll 32
    for (int alpha = 0; alpha < 4; ++alpha)
    {
      #pragma GCC unroll 32
      for (int i = 0; i < 3; ++i)
      {
        double m = 0.0;
        #pragma GCC unroll 32
        for (int a = 0; a < 8; ++a)
        {
          m += kHourglassBase[a][alpha] * ue[a][i];
        }
        #pragma GCC unroll 32
        for (int j = 0; j < 3; ++j)
        {
          m -= (F.m[i][j] - (i == j ? 1.0 : 0.0)) * xh[4 * j + alpha];
        }
        modes[alpha][i] = m;
      }
    }
    Matrix3x3 A = ScaledMooneyRivlinFirstPiola<kSecondInvariant>(F, cof, J, m_Kappa[e] * (J - 1.0), m_Mu[e],
                                                          kSecondInvariant ? m_SecondModulus[e] : 0.0, m_Collapse[e],
                                                          m_Volume[e]); // V P
    const double k = m_HexHourglassStiffness[e];
    // Hourglass forces k Gamma m folded in: k h m directly, and -k B (X^T h) m
    // through the same B as the stress term.
    #pragma GCC unroll 32
    for (int i = 0; i < 3; ++i)
    {
      #pragma GCC unroll 32
      for (int j = 0; j < 3; ++j)
      {
        A.m[i][j] -= k * (modes[0][i] * xh[4 * j] + modes[1][i] * xh[4 * j + 1] + modes[2][i] * xh[4 * j + 2] +
                        modes[3][i] * xh[4 * j + 3]);
      }
    }
    const Index local = e - begin;
    #pragma GCC unroll 32
    for (int a = 0; a < 8; ++a)
    {
      #pragma GCC unroll 32
      for (int i = 0; i < 3; ++i)
      {
        forces[3 * a + i][local] = A.m[i][0] * b[3 * a] + A.m[i][1] * b[3 * a + 1] + A.m[i][2] * b[3 * a + 2] +
                                   k * (kHourglassBase[a][0] * modes[0][i] + kHourglassBase[a][1] * modes[1][i] +
                                        kHourglassBase[a][2] * modes[2][i] + kHourglassBase[a][3] * modes[3][i]);
      }
    }
  }
  AddBlockForces(m_HexNodes.data(), begin, end, forces, f);
  return firstInverted == std::numeric_limits<Index>::max() ? Index{ -1 } : firstInverted;
}

// Deformation gradient of a tetrahedron from component-major gradients, as
// plain scalars so that the loops over cells vectorise (one cell per lane).
#define BMR_TETRAHEDRON_DEFORMATION_GRADIENT                                                                      \
  const Index i0 = m_TetNodes[t][0], i1 = m_TetNodes[t][1], i2 = m_TetNodes[t][2], i3 = m_TetNodes[t][3];        \
  double      b[12];                                                                                              \
  for (int c = 0; c < 12; ++c)                                                                                   \
  {                                                                                                              \
    b[c] = B[c * count + t];                                                                                     \
  }                                                                                                              \
  Matrix3x3 F;                                                                                                   \
  for (int i = 0; i < 3; ++i)                                                                                    \
  {                                                                                                              \
    for (int j = 0; j < 3; ++j)                                                                                  \
    {                                                                                                            \
      F.m[i][j] = (i == j ? 1.0 : 0.0) + u[3 * i0 + i] * b[j] + u[3 * i1 + i] * b[3 + j] +                       \
                  u[3 * i2 + i] * b[6 + j] + u[3 * i3 + i] * b[9 + j];                                           \
    }                                                                                                            \
  }

void
FiniteElementForceModel::TetrahedronDilatations(Index begin, Index end, const double * u)
{
  const std::size_t count = m_TetNodes.size();
  const double *    B = m_TetB.data();
  double *          jacobian = m_TetJacobian.data();
#pragma omp simd
  for (Index t = begin; t < end; ++t)
  {
    BMR_TETRAHEDRON_DEFORMATION_GRADIENT
    jacobian[t] = DeterminantOf(F, CofactorOf(F));
  }
}

template <bool kSecondInvariant>
Index
FiniteElementForceModel::AddTetrahedronForces(Index begin, Index end, const double * u, double * f) const
{
  const std::size_t count = m_TetNodes.size();
  const Index       hexCount = HexahedronCount();
  const double *    B = m_TetB.data();
  // 1 for ANP (the nodal average), 0 for the plain tetrahedron (the cell's J):
  // a multiplier rather than a branch keeps the loop vectorisable.
  const double * averagedCell = m_TetAveraged.data();
  const double * nodalPressure = m_NodalPressure.data();
  // Per-cell nodal forces of the block, component-major, then added serially.
  alignas(64) double forces[12][kTetrahedraPerBlock];
  Index              firstInverted = std::numeric_limits<Index>::max();
#pragma omp simd reduction(min : firstInverted)
  for (Index t = begin; t < end; ++t)
  {
    BMR_TETRAHEDRON_DEFORMATION_GRADIENT
    const Matrix3x3 cof = CofactorOf(F);
    const double    J = DeterminantOf(F, cof);
    if (!(J > 0.0))
    {
      firstInverted = std::min(firstInverted, t);
    }
    // Average nodal pressure: the mean of the cell's nodal pressures, so
    // pressure stays continuous across cells and material interfaces.
    const std::size_t k = static_cast<std::size_t>(hexCount + t);
    const double      averaged = averagedCell[t];
    const double      pressure =
      averaged * 0.25 * (nodalPressure[i0] + nodalPressure[i1] + nodalPressure[i2] + nodalPressure[i3]) +
      (1.0 - averaged) * m_Kappa[k] * (J - 1.0);
    // The collapse barrier acts on the cell's own J, which ANP leaves free.
    const Matrix3x3 A = ScaledMooneyRivlinFirstPiola<kSecondInvariant>(
      F, cof, J, pressure, m_Mu[k], kSecondInvariant ? m_SecondModulus[k] : 0.0, m_Collapse[k], m_Volume[k]); // V P
    const Index local = t - begin;
    for (int a = 0; a < 4; ++a)
    {
      for (int i = 0; i < 3; ++i)
      {
        forces[3 * a + i][local] = A.m[i][0] * b[3 * a] + A.m[i][1] * b[3 * a + 1] + A.m[i][2] * b[3 * a + 2];
      }
    }
  }
  AddBlockForces(m_TetNodes.data(), begin, end, forces, f);
  return firstInverted == std::numeric_limits<Index>::max() ? Index{ -1 } : firstInverted;
}

#undef BMR_TETRAHEDRON_DEFORMATION_GRADIENT

std::size_t
FiniteElementForceModel::StreamedBytesPerStep() const
{
  const std::size_t cellConstants =
    BytesOf(m_Volume) + BytesOf(m_Mu) + BytesOf(m_SecondModulus) + BytesOf(m_Kappa) + BytesOf(m_Collapse);
  std::size_t       bytes = cellConstants + BytesOf(m_HexNodes) + BytesOf(m_HexB) + BytesOf(m_HexXH) +
                      BytesOf(m_HexHourglassStiffness) + BytesOf(m_FirstTouchOffsets) + BytesOf(m_FirstTouchNodes);
  // Tetrahedra: F in the dilatation pass and again in the force pass; with
  // ANP the cells' J written and read, and the nodal averaging's tables.
  bytes += 2 * (BytesOf(m_TetNodes) + BytesOf(m_TetB)) + BytesOf(m_TetAveraged);
  if (UsesAverageNodalPressure())
  {
    bytes += 2 * BytesOf(m_TetJacobian) + BytesOf(m_NodeTetOffsets) + BytesOf(m_NodeTets) + BytesOf(m_NodeTetWeights) +
             BytesOf(m_NodalVolume) + BytesOf(m_NodalBulkModulus);
  }
  return bytes;
}

} // namespace bmr
