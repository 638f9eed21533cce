// Integration points of the meshless (MTLED) discretization: Gauss points of
// a regular background grid kept where they lie inside the body region
// (bmrBodyRegion.cxx; Horton et al. 2010), and adaptive subdivision of the
// background cells guided by the integrals of the MLS shape functions
// (Joldes, Wittek, Miller 2015).
#include "bmrMeshless.h"
#include "bmrThreads.h"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
#include <sstream>

namespace bmr
{

namespace
{
// Background grids larger than this are a mistake (cell size far too small).
constexpr double kMaxBackgroundCells = 2e8;
constexpr int    kMaxSubdivisionLevels = 6;
// Points per MovingLeastSquares::Evaluate call in adaptive integration: large
// enough to amortise the call, small enough to bound the table's memory.
constexpr Index  kPointsPerEvaluation = 8192;
} // namespace

namespace
{

/** Gauss-Legendre rule on [0, 1]. */
struct GaussRule
{
  std::vector<double> abscissae;
  std::vector<double> weights;
};

GaussRule
MakeGaussRule(int points)
{
  switch (points)
  {
    case 1:
      return { { 0.5 }, { 1.0 } };
    case 2:
    {
      const double a = 0.5 / std::sqrt(3.0);
      return { { 0.5 - a, 0.5 + a }, { 0.5, 0.5 } };
    }
    default:
    {
      const double a = 0.5 * std::sqrt(0.6);
      return { { 0.5 - a, 0.5, 0.5 + a }, { 5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0 } };
    }
  }
}

void
ValidateSettings(const IntegrationSettings & settings)
{
  std::ostringstream message;
  message << "integration settings: ";
  if (!std::isfinite(settings.cellSize) || settings.cellSize < 0.0)
  {
    message << "cellSize is " << settings.cellSize
            << " mm; give a positive background cell edge, or 0 for the median nodal spacing.";
    throw Error(message.str());
  }
  if (settings.pointsPerDirection < 1 || settings.pointsPerDirection > 3)
  {
    message << "pointsPerDirection is " << settings.pointsPerDirection << "; use 1, 2 or 3 Gauss points per direction.";
    throw Error(message.str());
  }
  if (!(settings.adaptiveTolerance > 0.0))
  {
    message << "adaptiveTolerance is " << settings.adaptiveTolerance
            << "; it must be positive (e.g. 1e-3, relative to the cell volume).";
    throw Error(message.str());
  }
  if (settings.maxSubdivisionLevels < 0 || settings.maxSubdivisionLevels > kMaxSubdivisionLevels)
  {
    message << "maxSubdivisionLevels is " << settings.maxSubdivisionLevels << "; use 0 to " << kMaxSubdivisionLevels
            << " (each level multiplies the points of a cell by 8).";
    throw Error(message.str());
  }
  if (settings.interiorPointsPerDirection < 0 || settings.interiorPointsPerDirection > 3)
  {
    message << "interiorPointsPerDirection is " << settings.interiorPointsPerDirection
            << "; use 0 (no coarse interior blocks), 1, 2 or 3.";
    throw Error(message.str());
  }
  if (!(settings.interiorTolerance >= 0.0) || !std::isfinite(settings.interiorTolerance))
  {
    message << "interiorTolerance is " << settings.interiorTolerance
            << "; it must be finite and non-negative (e.g. 0.03; 0 keeps every block fine).";
    throw Error(message.str());
  }
}

/** A cube of the background grid or one of its descendants, or a coarse
 *  interior block. `background` numbers the root it descends from (a
 *  background cell, or a block of 2 x 2 x 2 with coarse interior blocks on);
 *  `path` holds the child numbers from that root down, 3 bits per level, most
 *  significant first, so that sorting leaves by it gives depth-first order. */
struct IntegrationCell
{
  Index    background = 0;
  Vector3  corner = Vector3::Zero();
  Vector3  size = Vector3::Zero(); // edges along x, y, z
  int      level = 0;
  uint32_t path = 0;
  bool     coarse = false; // an interior block of 2 x 2 x 2 background cells
};

/** Result of an accepted cell: its Gauss points inside the body. */
struct AcceptedCell
{
  uint32_t             path = 0;
  Index                background = 0;
  std::vector<Vector3> positions;
  std::vector<double>  weights;
  std::vector<Index>   materials;
};

/** Per-thread accumulators of I_parent - I_children, indexed by node. */
struct Scratch
{
  std::vector<double>       difference;
  std::vector<Vector3>      gradient; // I_coarse - I_fine of grad phi, coarse interior blocks
  std::vector<std::uint8_t> seen;
  std::vector<Index>        touched;
};

struct CellPoint
{
  Vector3 position;
  double  weight;
  Index   material;
};

/** Inside Gauss points of one level of a batch and their shape functions. */
struct Evaluated
{
  std::vector<CellPoint> points;
  ShapeFunctionTable     table;
};

class IntegrationGrid
{
public:
  IntegrationGrid(const BodyRegion &          body,
                  const MovingLeastSquares &  shapeFunctions,
                  const IntegrationSettings & settings,
                  double                      cellSize)
    : m_Body(body)
    , m_ShapeFunctions(shapeFunctions)
    , m_Settings(settings)
    , m_Rule(MakeGaussRule(settings.pointsPerDirection))
    , m_InteriorRule(MakeGaussRule(std::max(1, settings.interiorPointsPerDirection)))
    , m_BlockWidth(settings.interiorPointsPerDirection > 0 && !settings.adaptive ? 2 : 1)
    , m_PointsPerCell(settings.pointsPerDirection * settings.pointsPerDirection * settings.pointsPerDirection)
  {
    const Eigen::AlignedBox3d box = body.Bounds();
    m_Origin = box.min();
    double total = 1.0;
    for (int a = 0; a < 3; ++a)
    {
      // Whole cells span the body's box exactly, their edges as close to
      // cellSize as that allows: a box-shaped body (or a body made of a grid's
      // cells) is then not cut, and cut cells would lose the weight of their
      // outside points.
      const double cells = std::max(1.0, std::round(box.sizes()[a] / cellSize));
      total *= cells;
      m_Dimensions[a] = cells;
      m_CellSize[a] = box.sizes()[a] > 0.0 ? box.sizes()[a] / cells : cellSize;
    }
    if (!(total <= kMaxBackgroundCells))
    {
      std::ostringstream message;
      message << "MakeIntegrationPoints: a background grid of cell size " << cellSize << " mm over the body's box of "
              << box.sizes().transpose() << " mm would have " << total
              << " cells. Use a larger cellSize (0: the median nodal spacing).";
      throw Error(message.str());
    }
    for (int a = 0; a < 3; ++a)
    {
      m_Blocks[a] = (static_cast<Index>(m_Dimensions[a]) + m_BlockWidth - 1) / m_BlockWidth;
    }
    m_BackgroundCount = m_Blocks[0] * m_Blocks[1] * m_Blocks[2];
  }

  /** Roots of the integration: background cells, or blocks of 2 x 2 x 2 of
   *  them with coarse interior blocks on. */
  Index BackgroundCount() const { return m_BackgroundCount; }

  /** Whether roots are blocks of 2 x 2 x 2 cells that may be coarse. */
  bool CoarseBlocksOn() const { return m_BlockWidth == 2; }

  /** Cells of the background grid. */
  double CellCount() const { return m_Dimensions[0] * m_Dimensions[1] * m_Dimensions[2]; }

  /** First background cell (i, j, k) of a root. */
  Eigen::Array3i FirstCell(Index root) const
  {
    return m_BlockWidth * Eigen::Array3i(static_cast<int>(root % m_Blocks[0]),
                                         static_cast<int>((root / m_Blocks[0]) % m_Blocks[1]),
                                         static_cast<int>(root / (m_Blocks[0] * m_Blocks[1])));
  }

  /** A block as one coarse cell. */
  IntegrationCell CoarseCell(Index root) const
  {
    IntegrationCell cell;
    cell.background = root;
    cell.corner = m_Origin + m_CellSize.cwiseProduct(FirstCell(root).cast<double>().matrix());
    cell.size = 2.0 * m_CellSize;
    cell.coarse = true;
    return cell;
  }

  /** The background cells of a root that lie in the grid, in grid order (x
   *  fastest, then y, then z). */
  void FineCells(Index root, std::vector<IntegrationCell> & cells) const
  {
    const Eigen::Array3i first = FirstCell(root);
    for (int child = 0; child < m_BlockWidth * m_BlockWidth * m_BlockWidth; ++child)
    {
      const Eigen::Array3i index = first + Eigen::Array3i(child & 1, (child >> 1) & 1, (child >> 2) & 1);
      if ((index.cast<double>() >= Eigen::Array3d(m_Dimensions.data())).any())
      {
        continue;
      }
      IntegrationCell cell;
      cell.background = root;
      cell.corner = m_Origin + m_CellSize.cwiseProduct(index.cast<double>().matrix());
      cell.size = m_CellSize;
      // Non-adaptive with blocks on: the cells of a block sort in child order.
      cell.path = m_BlockWidth == 2 ? static_cast<uint32_t>(child) << (3 * (kMaxSubdivisionLevels - 1)) : 0;
      cells.push_back(cell);
    }
  }

  /** The 8 children, x fastest. */
  static IntegrationCell Child(const IntegrationCell & parent, int child)
  {
    IntegrationCell c = parent;
    c.size = 0.5 * parent.size;
    c.corner = parent.corner + c.size.cwiseProduct(Vector3(child & 1, (child >> 1) & 1, (child >> 2) & 1));
    c.level = parent.level + 1;
    c.path = parent.path | (static_cast<uint32_t>(child) << (3 * (kMaxSubdivisionLevels - c.level)));
    return c;
  }

  /** Gauss points of the cell that lie inside the body (x fastest). */
  void InsidePoints(const IntegrationCell & cell, std::vector<CellPoint> & points) const
  {
    const GaussRule & rule = cell.coarse ? m_InteriorRule : m_Rule;
    const int         n = static_cast<int>(rule.abscissae.size());
    const double      volume = cell.size.prod();
    for (int k = 0; k < n; ++k)
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
        {
          const Vector3 x =
            cell.corner + cell.size.cwiseProduct(Vector3(rule.abscissae[i], rule.abscissae[j], rule.abscissae[k]));
          const Index material = m_Body.MaterialAt(x);
          if (material >= 0)
          {
            points.push_back({ x, rule.weights[i] * rule.weights[j] * rule.weights[k] * volume, material });
          }
        }
  }

  /** Whether the root's block of 2 x 2 x 2 background cells is interior
   *  (its cells' inside points are left in `points`): all inside the grid,
   *  its cells' Gauss points (at their usual density) inside and in one
   *  material, and the ring of cells around it (their centres, and the
   *  corners of the grown block) in that material too. Near the boundary a
   *  coarse cell would be cut; near a material interface its few points
   *  would stand for the whole block in the supports of nodes that also
   *  reach the other material (a coarse block beside a 1 Pa cavity left a
   *  soft mode that dynamic relaxation did not converge). */
  bool Interior(Index root, std::vector<CellPoint> & points) const
  {
    const Eigen::Array3i first = FirstCell(root);
    if (((first + 2).cast<double>() > Eigen::Array3d(m_Dimensions.data())).any())
    {
      return false;
    }
    points.clear();
    std::vector<IntegrationCell> cells;
    FineCells(root, cells);
    for (const IntegrationCell & cell : cells)
    {
      InsidePoints(cell, points);
    }
    if (static_cast<Index>(points.size()) != 8 * m_PointsPerCell)
    {
      return false;
    }
    const Index material = points.front().material;
    if (!std::all_of(points.begin(), points.end(), [&](const CellPoint & p) { return p.material == material; }))
    {
      return false;
    }
    const Vector3 corner = m_Origin + m_CellSize.cwiseProduct(first.cast<double>().matrix());
    for (int c = 0; c < 8; ++c)
    {
      const Vector3 u(c & 1, (c >> 1) & 1, (c >> 2) & 1);
      if (m_Body.MaterialAt(corner - m_CellSize + 4.0 * m_CellSize.cwiseProduct(u)) != material)
      {
        return false;
      }
    }
    for (int k = -1; k <= 2; ++k)
      for (int j = -1; j <= 2; ++j)
        for (int i = -1; i <= 2; ++i)
        {
          const bool ring = i < 0 || i > 1 || j < 0 || j > 1 || k < 0 || k > 1;
          if (ring && m_Body.MaterialAt(corner + m_CellSize.cwiseProduct(Vector3(i + 0.5, j + 0.5, k + 0.5))) != material)
          {
            return false;
          }
        }
    return true;
  }

  /** The interior blocks among roots [first, last) whose coarse rule
   *  integrates the gradients of the shape functions as their cells' rule
   *  does: max over nodes |sum_coarse w grad phi_I - sum_fine w grad phi_I|
   *  at most interiorTolerance x the block's volume / its cell edge. These
   *  integrals are what a homogeneous deformation needs exact (integration
   *  consistency); they fail on irregular clouds, where the shape functions
   *  vary within a cell. */
  std::vector<char> CoarseBlocks(Index first, Index last, Scratch & scratch) const
  {
    std::vector<char> coarse(static_cast<std::size_t>(last - first), 0);
    if (!CoarseBlocksOn())
    {
      return coarse;
    }
    std::vector<CellPoint>             points;
    std::vector<CellPoint>             fine;
    std::vector<std::array<Index, 3>> ranges; // root offset, coarse points' begin, fine points' begin (end: next begin)
    for (Index b = first; b < last; ++b)
    {
      if (!Interior(b, fine))
      {
        continue;
      }
      const Index begin = static_cast<Index>(points.size());
      InsidePoints(CoarseCell(b), points);
      ranges.push_back({ b - first, begin, static_cast<Index>(points.size()) });
      points.insert(points.end(), fine.begin(), fine.end());
    }
    if (ranges.empty())
    {
      return coarse;
    }
    std::vector<Vector3> positions(points.size());
    for (std::size_t p = 0; p < points.size(); ++p)
    {
      positions[p] = points[p].position;
    }
    const ShapeFunctionTable table = m_ShapeFunctions.Evaluate(positions, true, 1, "integration point");
    const double             edge = m_CellSize.minCoeff();
    for (std::size_t r = 0; r < ranges.size(); ++r)
    {
      const Index end = r + 1 < ranges.size() ? ranges[r + 1][1] : static_cast<Index>(points.size());
      for (Index p = ranges[r][1]; p < end; ++p)
      {
        const double sign = p < ranges[r][2] ? 1.0 : -1.0;
        for (Index e = table.offsets[p]; e < table.offsets[p + 1]; ++e)
        {
          const Index node = table.nodes[e];
          if (!scratch.seen[node])
          {
            scratch.seen[node] = 1;
            scratch.touched.push_back(node);
            scratch.gradient[node].setZero();
          }
          scratch.gradient[node] += sign * points[p].weight * Vector3(&table.gradients[3 * e]);
        }
      }
      double difference = 0.0;
      for (Index node : scratch.touched)
      {
        difference = std::max(difference, scratch.gradient[node].norm());
        scratch.seen[node] = 0;
      }
      scratch.touched.clear();
      const double measure = difference * edge / (8.0 * m_CellSize.prod());
      coarse[ranges[r][0]] = measure <= m_Settings.interiorTolerance ? 1 : 0;
    }
    return coarse;
  }

  /** How many corners of the cell, shrunk by 1% about its centre, the body
   *  contains: cells that only touch the body (a shared face) do not count. */
  int CornerProbes(const IntegrationCell & cell) const
  {
    int inside = 0;
    for (int corner = 0; corner < 8; ++corner)
    {
      const Vector3 u(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
      inside += m_Body.Contains(cell.corner + cell.size.cwiseProduct(0.01 * Vector3::Ones() + 0.98 * u)) ? 1 : 0;
    }
    return inside;
  }

  /** All accepted cells descending from background cells [first, last), in
   *  depth-first order. */
  std::vector<AcceptedCell> Process(Index first, Index last, Scratch & scratch) const
  {
    const std::vector<char>      coarse = CoarseBlocks(first, last, scratch);
    std::vector<Active>          active;
    std::vector<IntegrationCell> cells;
    for (Index b = first; b < last; ++b)
    {
      if (coarse[b - first])
      {
        active.push_back({ CoarseCell(b) });
        continue;
      }
      cells.clear();
      FineCells(b, cells);
      for (const IntegrationCell & cell : cells)
      {
        active.push_back({ cell });
      }
    }
    std::vector<AcceptedCell> accepted;
    ProcessLevel(active, nullptr, scratch, accepted);
    // Leaves of a tree sorted by (background cell, path) come in depth-first order.
    std::sort(accepted.begin(), accepted.end(), [](const AcceptedCell & a, const AcceptedCell & b) {
      return a.background != b.background ? a.background < b.background : a.path < b.path;
    });
    return accepted;
  }

  /** Background cells per work batch: a few thousand points per Evaluate
   *  call, but at least ~64 batches so that small grids still use all threads.
   *  Depends on the grid only, never on the thread count. */
  Index BatchSize() const
  {
    const int n = m_Settings.pointsPerDirection;
    const int perCell = (m_Settings.adaptive ? 9 : 1) * n * n * n * m_BlockWidth * m_BlockWidth * m_BlockWidth;
    return std::clamp<Index>(m_BackgroundCount / 64, 1, std::max<Index>(4, kPointsPerEvaluation / perCell));
  }

private:
  /** A cell to test and where its own inside Gauss points are: computed with
   *  its level (background cells) or inherited from its parent's test. */
  struct Active
  {
    IntegrationCell cell;
    bool            inherited = false;
    Index           ownBegin = 0;
    Index           ownEnd = 0;
  };

  /** Tests the cells of one level in chunks of a few thousand points (one
   *  Evaluate call each) and recurses into the children of the divided ones,
   *  so that memory stays bounded however deep the subdivision goes. The
   *  inherited points of `active` are in `previous`. */
  void ProcessLevel(std::vector<Active> &      active,
                    const Evaluated *          previous,
                    Scratch &                  scratch,
                    std::vector<AcceptedCell> & accepted) const
  {
    const bool        adaptive = m_Settings.adaptive && m_Settings.maxSubdivisionLevels > 0;
    const std::size_t chunk = std::max<std::size_t>(1, kPointsPerEvaluation / (9 * m_PointsPerCell));
    for (std::size_t start = 0; start < active.size(); start += chunk)
    {
      const std::size_t                  stop = std::min(active.size(), start + chunk);
      Evaluated                          current;
      std::vector<std::array<Index, 9>> children(stop - start); // child k: [children[c][k], children[c][k + 1])
      for (std::size_t c = 0; c < stop - start; ++c)
      {
        Active & a = active[start + c];
        if (!a.inherited)
        {
          a.ownBegin = static_cast<Index>(current.points.size());
          InsidePoints(a.cell, current.points);
          a.ownEnd = static_cast<Index>(current.points.size());
        }
        children[c][0] = static_cast<Index>(current.points.size());
        if (adaptive && a.cell.level < m_Settings.maxSubdivisionLevels)
        {
          for (int child = 0; child < 8; ++child)
          {
            InsidePoints(Child(a.cell, child), current.points);
            children[c][child + 1] = static_cast<Index>(current.points.size());
          }
        }
        else
        {
          std::fill(children[c].begin() + 1, children[c].end(), children[c][0]);
        }
      }
      if (adaptive && !current.points.empty())
      {
        std::vector<Vector3> positions(current.points.size());
        for (std::size_t p = 0; p < positions.size(); ++p)
        {
          positions[p] = current.points[p].position;
        }
        current.table = m_ShapeFunctions.Evaluate(positions, false, 1, "integration point");
      }

      std::vector<Active> next;
      for (std::size_t c = 0; c < stop - start; ++c)
      {
        const Active &    a = active[start + c];
        const Evaluated & own = a.inherited ? *previous : current;
        const bool        tested = adaptive && a.cell.level < m_Settings.maxSubdivisionLevels;
        bool              divide = false;
        if (tested)
        {
          // I_parent - I_children for every shape function seen in the cell.
          auto accumulate = [&](const Evaluated & source, Index p, double sign) {
            const ShapeFunctionTable & table = source.table;
            for (Index e = table.offsets[p]; e < table.offsets[p + 1]; ++e)
            {
              const Index node = table.nodes[e];
              if (!scratch.seen[node])
              {
                scratch.seen[node] = 1;
                scratch.touched.push_back(node);
              }
              scratch.difference[node] += sign * source.points[p].weight * table.values[e];
            }
          };
          for (Index p = a.ownBegin; p < a.ownEnd; ++p)
          {
            accumulate(own, p, 1.0);
          }
          for (Index p = children[c][0]; p < children[c][8]; ++p)
          {
            accumulate(current, p, -1.0);
          }
          double difference = 0.0;
          for (Index node : scratch.touched)
          {
            difference = std::max(difference, std::abs(scratch.difference[node]));
            scratch.difference[node] = 0.0;
            scratch.seen[node] = 0;
          }
          scratch.touched.clear();
          const double volume = a.cell.size.prod();
          divide = difference > m_Settings.adaptiveTolerance * volume;
          // When all Gauss points of the cell and its children lie on the same
          // side, the integrals cannot see a boundary crossing the cell: its
          // part of the body would be dropped (all outside) or its outside
          // counted (all inside), a one-sided error along the boundary. Probes
          // near the corners detect such cells, which are divided as well.
          const Index ownInside = a.ownEnd - a.ownBegin;
          const Index childrenInside = children[c][8] - children[c][0];
          if (!divide && ownInside == 0 && childrenInside == 0)
          {
            divide = CornerProbes(a.cell) > 0;
          }
          else if (!divide && ownInside == m_PointsPerCell && childrenInside == 8 * m_PointsPerCell)
          {
            divide = CornerProbes(a.cell) < 8;
          }
        }
        if (divide)
        {
          for (int child = 0; child < 8; ++child)
          {
            next.push_back({ Child(a.cell, child), true, children[c][child], children[c][child + 1] });
          }
          continue;
        }
        // Converged: keep the finer of the two rules compared (the children's
        // points), as adaptive quadrature does; untested: the cell's own points.
        const Evaluated & source = tested ? current : own;
        const Index       begin = tested ? children[c][0] : a.ownBegin;
        const Index       end = tested ? children[c][8] : a.ownEnd;
        if (end > begin)
        {
          AcceptedCell result;
          result.path = a.cell.path;
          result.background = a.cell.background;
          for (Index p = begin; p < end; ++p)
          {
            result.positions.push_back(source.points[p].position);
            result.weights.push_back(source.points[p].weight);
            result.materials.push_back(source.points[p].material);
          }
          accepted.push_back(std::move(result));
        }
      }
      if (!next.empty())
      {
        ProcessLevel(next, &current, scratch, accepted);
      }
    }
  }

  const BodyRegion &          m_Body;
  const MovingLeastSquares &  m_ShapeFunctions;
  const IntegrationSettings & m_Settings;
  GaussRule                   m_Rule;
  GaussRule                   m_InteriorRule;
  int                         m_BlockWidth; // background cells per block edge: 2 with coarse interior blocks
  Vector3                     m_CellSize;
  Index                       m_PointsPerCell;
  Vector3                     m_Origin = Vector3::Zero();
  std::array<double, 3>       m_Dimensions{ 1.0, 1.0, 1.0 };
  std::array<Index, 3>        m_Blocks{ 1, 1, 1 };
  Index                       m_BackgroundCount = 0;
};

} // namespace

// Order of the points: background cells in grid order (x fastest, then y,
// then z, from the body's minimum corner); within a cell its accepted
// descendants depth-first, children numbered x fastest; within an accepted
// cell its Gauss points, x fastest. Adaptive: a cell whose test passes
// contributes its children's points (the finer rule of the two compared); a
// cell at the deepest level its own.
IntegrationPoints
MakeIntegrationPoints(const BodyRegion &          body,
                      const MovingLeastSquares &  shapeFunctions,
                      const IntegrationSettings & settings,
                      int                         threads)
{
  ValidateSettings(settings);
  double cellSize = settings.cellSize;
  if (cellSize == 0.0)
  {
    // The median, not the mean: boundary nodes have fewer close neighbours and
    // larger spacings, and a grid of nodes then gets background cells that
    // match it exactly (a cut cell loses the weight of its outside points).
    const Index         nodeCount = shapeFunctions.NodeCount();
    std::vector<double> spacings(static_cast<std::size_t>(nodeCount));
    for (Index n = 0; n < nodeCount; ++n)
    {
      spacings[n] = shapeFunctions.NodalSpacing(n);
    }
    std::nth_element(spacings.begin(), spacings.begin() + spacings.size() / 2, spacings.end());
    cellSize = spacings.empty() ? 0.0 : spacings[spacings.size() / 2];
    if (!(cellSize > 0.0) || !std::isfinite(cellSize))
    {
      throw Error("MakeIntegrationPoints: the median nodal spacing is not positive; give IntegrationSettings::cellSize.");
    }
  }
  const IntegrationGrid grid(body, shapeFunctions, settings, cellSize);

  // Fixed batches of background cells, each processed whole by one thread:
  // the result does not depend on the thread count.
  const Index batchSize = grid.BatchSize();
  const Index batchCount = (grid.BackgroundCount() + batchSize - 1) / batchSize;
  std::vector<std::vector<AcceptedCell>> results(batchCount);
  std::vector<std::exception_ptr>        errors(batchCount);
  std::atomic<Index>                     firstFailure{ batchCount };
  const Index                            nodeCount = shapeFunctions.NodeCount();

#pragma omp parallel num_threads(ThreadCount(threads))
  {
    Scratch scratch;
    if (settings.adaptive || grid.CoarseBlocksOn())
    {
      scratch.seen.assign(nodeCount, 0);
    }
    if (settings.adaptive)
    {
      scratch.difference.assign(nodeCount, 0.0);
    }
    if (grid.CoarseBlocksOn())
    {
      scratch.gradient.assign(nodeCount, Vector3::Zero());
    }
#pragma omp for schedule(dynamic, 1)
    for (Index batch = 0; batch < batchCount; ++batch)
    {
      // Batches start in increasing order, so every batch before a failed one
      // runs and the error reported is always the first one.
      if (batch > firstFailure.load())
      {
        continue;
      }
      try
      {
        const Index first = batch * batchSize;
        results[batch] = grid.Process(first, std::min(first + batchSize, grid.BackgroundCount()), scratch);
      }
      catch (...)
      {
        errors[batch] = std::current_exception();
        Index expected = firstFailure.load();
        while (batch < expected && !firstFailure.compare_exchange_weak(expected, batch))
        {
        }
      }
    }
  }
  for (const auto & error : errors)
  {
    if (error)
    {
      std::rethrow_exception(error);
    }
  }

  IntegrationPoints result;
  std::size_t       count = 0;
  for (const auto & batch : results)
  {
    for (const auto & cell : batch)
    {
      count += cell.positions.size();
    }
  }
  result.positions.reserve(count);
  result.weights.reserve(count);
  result.materials.reserve(count);
  for (auto & batch : results)
  {
    for (const auto & cell : batch)
    {
      result.positions.insert(result.positions.end(), cell.positions.begin(), cell.positions.end());
      result.weights.insert(result.weights.end(), cell.weights.begin(), cell.weights.end());
      result.materials.insert(result.materials.end(), cell.materials.begin(), cell.materials.end());
    }
    std::vector<AcceptedCell>().swap(batch); // free as we go: peak memory stays near one copy
  }
  if (result.positions.empty())
  {
    std::ostringstream message;
    message << "MakeIntegrationPoints: no Gauss point of the " << grid.CellCount()
            << " background cells (cell size " << cellSize
            << " mm) lies inside the body. Use a smaller cellSize or more pointsPerDirection.";
    throw Error(message.str());
  }
  return result;
}

void
MakeMeshlessFromCells(Model & model, const MlsSettings & shapeFunctions, const IntegrationSettings & integration,
                      int threads)
{
  if (model.cells.empty())
  {
    throw Error("MakeMeshlessFromCells: the model has no cells, so the body's region is unknown. Give the cells of "
                "the body (they are used for point location only), or build the integration points from a surface "
                "with BodyRegion::FromSurface and MakeIntegrationPoints.");
  }
  const BodyRegion         body = BodyRegion::FromCells(model);
  const MovingLeastSquares mls(model.nodes, shapeFunctions);
  IntegrationPoints        points = MakeIntegrationPoints(body, mls, integration, threads);

  model.meshless.shapeFunctions = shapeFunctions;
  model.meshless.integrationPoints = std::move(points.positions);
  model.meshless.integrationWeights = std::move(points.weights);
  model.meshless.integrationMaterials = std::move(points.materials);
  model.discretization = Discretization::Meshless;
}

} // namespace bmr
