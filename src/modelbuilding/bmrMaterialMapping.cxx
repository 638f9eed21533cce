// Material mapping from tissue memberships or labels to cells and meshless
// integration points (Zhang, Joldes, Wittek, Miller, IJNMBE 2013). Over 800
// lines: the two mappings share the sampling of cells and points.
#include "bmrMaterialMapping.h"
#include "bmrThreads.h"

#include <nanoflann.hpp>
#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <numeric>
#include <set>
#include <sstream>
#include <tuple>

namespace bmr
{
namespace
{

constexpr int kMaxSamplesPerDirection = 32;

// Unit-cube corners in VTK_HEXAHEDRON order.
constexpr int kCorner[8][3] = { { 0, 0, 0 }, { 1, 0, 0 }, { 1, 1, 0 }, { 0, 1, 0 },
                                { 0, 0, 1 }, { 1, 0, 1 }, { 1, 1, 1 }, { 0, 1, 1 } };
// Hexahedron edges grouped by parametric direction (r, s, t), VTK ordering.
constexpr int kHexEdgesByDirection[12][2] = { { 0, 1 }, { 3, 2 }, { 4, 5 }, { 7, 6 }, { 0, 3 }, { 1, 2 },
                                              { 4, 7 }, { 5, 6 }, { 0, 4 }, { 1, 5 }, { 2, 6 }, { 3, 7 } };

struct Sample
{
  Vector3 x;
  double  weight;
};

int
SamplesPerDirection(double extent, double sampleSpacing)
{
  const double n = std::floor(extent / sampleSpacing) + 1.0;
  return static_cast<int>(std::clamp(n, 1.0, static_cast<double>(kMaxSamplesPerDirection)));
}

// Hexahedron: n[0] x n[1] x n[2] midpoints of the parametric cube, weighted
// by |det J|. The trilinear map is expanded once per cell,
// x = a0 + a1 r + a2 s + a3 t + a4 rs + a5 st + a6 rt + a7 rst, r, s, t in [0, 1].
void
HexahedronSamples(const std::array<Vector3, 8> & p, const int n[3], std::vector<Sample> & samples)
{
  const Vector3 a0 = p[0];
  const Vector3 a1 = p[1] - p[0];
  const Vector3 a2 = p[3] - p[0];
  const Vector3 a3 = p[4] - p[0];
  const Vector3 a4 = p[2] - p[1] - p[3] + p[0];
  const Vector3 a5 = p[7] - p[3] - p[4] + p[0];
  const Vector3 a6 = p[5] - p[1] - p[4] + p[0];
  const Vector3 a7 = p[6] - p[2] - p[5] - p[7] + p[1] + p[3] + p[4] - p[0];
  for (int k = 0; k < n[2]; ++k)
  {
    const double t = (k + 0.5) / n[2];
    for (int j = 0; j < n[1]; ++j)
    {
      const double s = (j + 0.5) / n[1];
      for (int i = 0; i < n[0]; ++i)
      {
        const double    r = (i + 0.5) / n[0];
        Eigen::Matrix3d jacobian;
        jacobian.col(0) = a1 + a4 * s + a6 * t + a7 * (s * t);
        jacobian.col(1) = a2 + a4 * r + a5 * t + a7 * (r * t);
        jacobian.col(2) = a3 + a5 * s + a6 * r + a7 * (r * s);
        const Vector3 x = a0 + a1 * r + a2 * s + a3 * t + a4 * (r * s) + a5 * (s * t) + a6 * (r * t) + a7 * (r * s * t);
        samples.push_back({ x, std::abs(jacobian.determinant()) });
      }
    }
  }
}

// Tetrahedron v0..v3 = {v0 + t1 e1 + t2 e2 + t3 e3 : 1 >= t1 >= t2 >= t3 >= 0}
// with e1 = v1 - v0, e2 = v2 - v1, e3 = v3 - v2 (the Kuhn simplex of the unit
// cube, mapped). Its regular (Freudenthal) subdivision into n^3 sub-tetrahedra
// of equal volume: the Kuhn simplices of the n^3 sub-cubes (a, b, c) that lie
// in it, which needs a >= b >= c and, on a tie, the local order to agree. The
// samples are their centroids, equally weighted.
void
TetrahedronSamples(const std::array<Vector3, 4> & v, int n, std::vector<Sample> & samples)
{
  static constexpr int kOrders[6][3] = { { 0, 1, 2 }, { 0, 2, 1 }, { 1, 0, 2 }, { 1, 2, 0 }, { 2, 0, 1 }, { 2, 1, 0 } };
  const Vector3        e[3] = { v[1] - v[0], v[2] - v[1], v[3] - v[2] };
  for (int a = 0; a < n; ++a)
    for (int b = 0; b <= a; ++b)
      for (int c = 0; c <= b; ++c)
        for (const auto & order : kOrders)
        {
          int position[3];
          for (int p = 0; p < 3; ++p)
          {
            position[order[p]] = p;
          }
          if ((a == b && position[0] > position[1]) || (b == c && position[1] > position[2]))
          {
            continue;
          }
          // Centroid of the local Kuhn simplex 0, e_o0, e_o0 + e_o1, (1,1,1).
          double local[3];
          local[order[0]] = 0.75;
          local[order[1]] = 0.5;
          local[order[2]] = 0.25;
          const double t[3] = { (a + local[0]) / n, (b + local[1]) / n, (c + local[2]) / n };
          samples.push_back({ v[0] + t[0] * e[0] + t[1] * e[1] + t[2] * e[2], 1.0 });
        }
}

void
CubeSamples(const Vector3 & centre, double edge, int n, std::vector<Sample> & samples)
{
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i)
      {
        const Vector3 offset((i + 0.5) / n - 0.5, (j + 0.5) / n - 0.5, (k + 0.5) / n - 0.5);
        samples.push_back({ centre + edge * offset, 1.0 });
      }
}

// The things that get a material: the model's cells, then (meshless models)
// its integration points.
class Sites
{
public:
  Sites(const Model & model, const MaterialSampling & sampling, const ImageGeometry & image, const char * who)
    : m_Model(model)
    , m_Sampling(sampling)
  {
    if (!(sampling.samplesPerVoxel > 0.0) || !std::isfinite(sampling.samplesPerVoxel))
    {
      throw Error(std::string(who) + ": samplesPerVoxel " + std::to_string(sampling.samplesPerVoxel) +
                  " must be a positive number (default 1)");
    }
    if (!(sampling.neighbourhoodSize >= 0.0) || !std::isfinite(sampling.neighbourhoodSize))
    {
      throw Error(std::string(who) + ": neighbourhoodSize " + std::to_string(sampling.neighbourhoodSize) +
                  " mm must be 0 (automatic) or positive");
    }
    m_Meshless = model.discretization == Discretization::Meshless;
    if (!m_Meshless && model.cells.empty())
    {
      throw Error(std::string(who) + ": the model has no cells; build a mesh before mapping materials");
    }
    if (m_Meshless)
    {
      const auto & meshless = model.meshless;
      if (meshless.integrationPoints.empty() || meshless.integrationWeights.size() != meshless.integrationPoints.size())
      {
        throw Error(std::string(who) + ": the meshless model has " + std::to_string(meshless.integrationPoints.size()) +
                    " integration points and " + std::to_string(meshless.integrationWeights.size()) +
                    " weights; make its integration points first (MakeMeshlessFromCells)");
      }
    }
    m_SampleSpacing = image.spacing.cwiseAbs().minCoeff() / sampling.samplesPerVoxel;
  }

  bool        Meshless() const { return m_Meshless; }
  std::size_t CellCount() const { return m_Model.cells.size(); }
  std::size_t Count() const
  {
    return m_Model.cells.size() + (m_Meshless ? m_Model.meshless.integrationPoints.size() : 0);
  }

  std::string Name(std::size_t site) const
  {
    std::ostringstream text;
    if (site < CellCount())
    {
      text << "cell " << site;
    }
    else
    {
      text << "integration point " << site - CellCount();
    }
    const Vector3 centre = Centre(site);
    text << " (centre " << FormatPoint(centre) << " mm)";
    return text.str();
  }

  Vector3 Centre(std::size_t site) const
  {
    if (site >= CellCount())
    {
      return m_Model.meshless.integrationPoints[site - CellCount()];
    }
    const Cell & cell = m_Model.cells[site];
    const int    count = NodesPerCell(cell.type);
    Vector3      sum = Vector3::Zero();
    for (int a = 0; a < count; ++a)
    {
      sum += m_Model.nodes[cell.nodes[a]];
    }
    return sum / count;
  }

  void Samples(std::size_t site, std::vector<Sample> & samples) const
  {
    samples.clear();
    if (site >= CellCount())
    {
      const std::size_t point = site - CellCount();
      const double      edge = m_Sampling.neighbourhoodSize > 0.0
                                 ? m_Sampling.neighbourhoodSize
                                 : std::cbrt(std::abs(m_Model.meshless.integrationWeights[point]));
      CubeSamples(m_Model.meshless.integrationPoints[point], edge, SamplesPerDirection(edge, m_SampleSpacing), samples);
      return;
    }
    const Cell & cell = m_Model.cells[site];
    if (cell.type == CellType::Hexahedron)
    {
      std::array<Vector3, 8> corner;
      for (int a = 0; a < 8; ++a)
      {
        corner[a] = m_Model.nodes[cell.nodes[a]];
      }
      // Per parametric direction, the longest of its 4 edges sets the count.
      int n[3];
      for (int d = 0; d < 3; ++d)
      {
        double longest = 0.0;
        for (int e = 4 * d; e < 4 * d + 4; ++e)
        {
          longest = std::max(longest, (corner[kHexEdgesByDirection[e][0]] - corner[kHexEdgesByDirection[e][1]]).norm());
        }
        n[d] = SamplesPerDirection(longest, m_SampleSpacing);
      }
      HexahedronSamples(corner, n, samples);
    }
    else
    {
      std::array<Vector3, 4> corner;
      for (int a = 0; a < 4; ++a)
      {
        corner[a] = m_Model.nodes[cell.nodes[a]];
      }
      // n^3 samples in the volume V: at least one per spacing^3.
      const double volume = std::abs((corner[1] - corner[0]).cross(corner[2] - corner[0]).dot(corner[3] - corner[0])) / 6.0;
      TetrahedronSamples(corner, SamplesPerDirection(std::cbrt(volume), m_SampleSpacing), samples);
    }
  }

private:
  const Model &            m_Model;
  const MaterialSampling & m_Sampling;
  bool                     m_Meshless = false;
  double                   m_SampleSpacing = 1.0;
};

void
CheckNodes(const Model & model, const char * who)
{
  for (const Cell & cell : model.cells)
  {
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      if (cell.nodes[a] < 0 || static_cast<std::size_t>(cell.nodes[a]) >= model.nodes.size())
      {
        throw Error(std::string(who) + ": a cell refers to node " + std::to_string(cell.nodes[a]) + " of " +
                    std::to_string(model.nodes.size()) + "; fix the model (Model::Validate)");
      }
    }
  }
}

// Continuous index of a point, or false when it lies outside the image
// (beyond the outer faces of the border voxels).
bool
ContinuousIndex(const ImageGeometry & geometry, const Vector3 & x, Vector3 & index)
{
  index = geometry.PointToIndex(x);
  constexpr double slack = 1e-9;
  for (int d = 0; d < 3; ++d)
  {
    if (!(index[d] >= -0.5 - slack && index[d] <= geometry.size[d] - 0.5 + slack))
    {
      return false;
    }
  }
  return true;
}

// The 8 voxels of trilinear interpolation (clamped at the border: the border
// voxel's value extends half a voxel outward) and their weights.
void
TrilinearStencil(const ImageGeometry & geometry, const Vector3 & index, std::size_t offsets[8], double weights[8])
{
  int    low[3];
  double fraction[3];
  for (int d = 0; d < 3; ++d)
  {
    const double clamped = std::clamp(index[d], 0.0, static_cast<double>(geometry.size[d] - 1));
    low[d] = std::min(static_cast<int>(std::floor(clamped)), std::max(geometry.size[d] - 2, 0));
    fraction[d] = geometry.size[d] > 1 ? clamped - low[d] : 0.0;
  }
  for (int c = 0; c < 8; ++c)
  {
    int    at[3];
    double weight = 1.0;
    for (int d = 0; d < 3; ++d)
    {
      at[d] = std::min(low[d] + kCorner[c][d], geometry.size[d] - 1);
      weight *= kCorner[c][d] ? fraction[d] : 1.0 - fraction[d];
    }
    offsets[c] = geometry.Offset(at[0], at[1], at[2]);
    weights[c] = weight;
  }
}

// Voxel centres (physical) as nanoflann's dataset.
struct VoxelCloud
{
  std::vector<Vector3> points;

  std::size_t kdtree_get_point_count() const { return points.size(); }
  double      kdtree_get_pt(std::size_t index, std::size_t dimension) const { return points[index][dimension]; }
  template <class BoundingBox>
  bool kdtree_get_bbox(BoundingBox &) const
  {
    return false;
  }
};
using VoxelTree =
  nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, VoxelCloud>, VoxelCloud, 3, std::uint32_t>;

/** The voxels where `inside` holds that have a 6-neighbour where it does not
 *  or lie on the image border. The inside voxel nearest to a point that no
 *  inside voxel's cell contains is always one of them (a step toward the point
 *  along an axis where it lies more than half a voxel away gets closer). */
template <typename Inside>
std::vector<std::size_t>
BoundaryVoxels(const ImageGeometry & geometry, const Inside & inside)
{
  std::vector<std::size_t> boundary;
  const int                nx = geometry.size[0], ny = geometry.size[1], nz = geometry.size[2];
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
      {
        const std::size_t n = geometry.Offset(i, j, k);
        if (!inside(n))
        {
          continue;
        }
        if (i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1 ||
            !inside(n - 1) || !inside(n + 1) || !inside(n - nx) || !inside(n + nx) ||
            !inside(n - static_cast<std::size_t>(nx) * ny) || !inside(n + static_cast<std::size_t>(nx) * ny))
        {
          boundary.push_back(n);
        }
      }
  return boundary;
}

/** Nearest voxel (by centre) among the given ones; built only when a cell needs it. */
class NearestVoxel
{
public:
  NearestVoxel(const ImageGeometry & geometry, std::vector<std::size_t> offsets)
    : m_Offsets(std::move(offsets))
  {
    const std::size_t nx = geometry.size[0], ny = geometry.size[1];
    m_Cloud.points.reserve(m_Offsets.size());
    for (std::size_t offset : m_Offsets)
    {
      m_Cloud.points.push_back(geometry.IndexToPoint(Vector3(static_cast<double>(offset % nx),
                                                             static_cast<double>((offset / nx) % ny),
                                                             static_cast<double>(offset / (nx * ny)))));
    }
    m_Tree = std::make_unique<VoxelTree>(3, m_Cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  }
  std::size_t Find(const Vector3 & x) const
  {
    std::uint32_t index = 0;
    double        distance = 0.0;
    m_Tree->knnSearch(x.data(), 1, &index, &distance);
    return m_Offsets[index];
  }

private:
  std::vector<std::size_t>   m_Offsets;
  VoxelCloud                 m_Cloud;
  std::unique_ptr<VoxelTree> m_Tree;
};

// Mixed values are rounded to 9 significant digits: cells with the same
// average memberships then share one material although their sums were
// rounded differently (a change far below any physical meaning).
double
RoundSignificant(double value)
{
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.9g", value);
  return std::strtod(buffer, nullptr);
}

std::string
MixtureName(double youngsModulus, double poissonRatio)
{
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "mix(E=%.6g,nu=%.4g)", youngsModulus, poissonRatio);
  return buffer;
}

/** Collects materials, one entry per distinct MaterialKey (E, nu, rho, law, its parameters), in order of first use. */
class MaterialTable
{
public:
  Index Add(const Material & material)
  {
    std::vector<double> key = MaterialKey(material);
    const auto          found = m_Index.find(key);
    if (found != m_Index.end())
    {
      return found->second;
    }
    const Index index = static_cast<Index>(m_Materials.size());
    m_Materials.push_back(material);
    m_Index.emplace(std::move(key), index);
    return index;
  }
  std::vector<Material> Take() { return std::move(m_Materials); }

private:
  std::vector<Material>                                  m_Materials;
  std::map<std::vector<double>, Index> m_Index;
};

/** The model's cells, then (meshless) its integration points: the sites that carry a material. */
std::size_t
SiteCount(const Model & model)
{
  return model.cells.size() +
         (model.discretization == Discretization::Meshless ? model.meshless.integrationPoints.size() : 0);
}

void
AssignMaterials(Model & model, const std::vector<Material> & siteMaterial)
{
  MaterialTable      table;
  const std::size_t  count = SiteCount(model);
  std::vector<Index> index(count);
  for (std::size_t site = 0; site < count; ++site)
  {
    index[site] = table.Add(siteMaterial[site]);
  }
  model.materials = table.Take();
  for (std::size_t cell = 0; cell < model.cells.size(); ++cell)
  {
    model.cells[cell].material = index[cell];
  }
  if (model.discretization == Discretization::Meshless)
  {
    model.meshless.integrationMaterials.assign(index.begin() + static_cast<std::ptrdiff_t>(model.cells.size()),
                                               index.end());
  }
}

void
ThrowOutsideImage(const Sites & sites, std::size_t site, const ImageGeometry & geometry, const char * who)
{
  throw Error(std::string(who) + ": " + sites.Name(site) + " lies entirely outside the image (" +
              geometry.Describe() + "); the model and the image must share physical space (mm, LPS)");
}

// The membership image, the masks and the class materials checked against each other.
void
CheckMembershipInputs(const ScalarVolume & memberships, const std::vector<Material> & materials, int csfClass,
                      const LabelVolume * tumourMask, const LabelVolume * resectionMask, const char * who)
{
  const ImageGeometry & geometry = memberships.geometry;
  const std::size_t     voxels = geometry.VoxelCount();
  const int             classes = memberships.components;
  if (voxels == 0 || classes < 1 || memberships.values.size() != voxels * static_cast<std::size_t>(classes))
  {
    throw Error(std::string(who) + ": the membership image (" + geometry.Describe() + ", " +
                std::to_string(classes) + " components) holds " + std::to_string(memberships.values.size()) +
                " values; give the memberships of a tissue classification");
  }
  for (std::size_t n = 0; n < memberships.values.size(); ++n)
  {
    const float u = memberships.values[n];
    if (!std::isfinite(u) || u < 0.0f)
    {
      std::ostringstream text;
      text << who << ": membership " << u << " of class " << n % classes << " at voxel offset " << n / classes
           << " is not a finite non-negative number; give the memberships of a tissue classification";
      throw Error(text.str());
    }
  }
  if (static_cast<int>(materials.size()) != classes)
  {
    throw Error(std::string(who) + ": " + std::to_string(materials.size()) + " class materials for a membership image of " +
                std::to_string(classes) + " classes; give one material per class (ascending centroid) or none for the defaults");
  }
  if (csfClass < 0 || csfClass >= classes)
  {
    throw Error(std::string(who) + ": the CSF class " + std::to_string(csfClass) + " is not one of the " +
                std::to_string(classes) + " classes; give 0 .. " + std::to_string(classes - 1));
  }
  for (const auto & [mask, name] : { std::pair{ tumourMask, "tumour mask" }, std::pair{ resectionMask, "resection mask" } })
  {
    if (mask && (!mask->geometry.SameGridAs(geometry) || mask->values.size() != voxels))
    {
      throw Error(std::string(who) + ": the " + name + " is not on the membership image's grid: " + name + " " +
                  mask->geometry.Describe() + ", memberships " + geometry.Describe() + "; resample the " + name +
                  " onto the image grid");
    }
  }
}

// Class weights are gathered per distinct material (grey and white matter
// with equal values form one group).
struct MaterialGroups
{
  explicit MaterialGroups(const std::vector<Material> & materials)
    : groupOf(materials.size())
  {
    std::map<std::vector<double>, int> groupOfKey;
    for (std::size_t k = 0; k < materials.size(); ++k)
    {
      const auto [group, added] = groupOfKey.emplace(MaterialKey(materials[k]), static_cast<int>(first.size()));
      if (added)
      {
        first.push_back(static_cast<int>(k));
      }
      groupOf[k] = group->second;
    }
  }

  std::size_t Count() const { return first.size(); }

  /** The material of groups mixed by weight: one group's values exactly, else
   *  the weighted mean of the moduli, the density and every law parameter,
   *  with the law of the groups that are not neo-Hookean (a neo-Hookean
   *  class is such a law at its parameters' neutral values). */
  Material Mixture(const std::vector<Material> & materials, const std::vector<double> & groupWeight) const
  {
    int used = 0, last = 0;
    for (std::size_t g = 0; g < first.size(); ++g)
    {
      if (groupWeight[g] > 0.0)
      {
        ++used;
        last = static_cast<int>(g);
      }
    }
    if (used == 1)
    {
      return materials[first[last]]; // exactly the class values
    }
    Material material;
    material.youngsModulus = material.poissonRatio = material.density = 0.0;
    for (const MaterialParameter & parameter : MaterialParameters())
    {
      material.*parameter.value = 0.0;
    }
    material.law = MaterialLaw::NeoHookean;
    for (std::size_t g = 0; g < first.size(); ++g)
    {
      const Material & pure = materials[first[g]];
      material.youngsModulus += groupWeight[g] * pure.youngsModulus;
      material.poissonRatio += groupWeight[g] * pure.poissonRatio;
      material.density += groupWeight[g] * pure.density;
      for (const MaterialParameter & parameter : MaterialParameters())
      {
        material.*parameter.value += groupWeight[g] * pure.*parameter.value;
      }
      if (pure.law != MaterialLaw::NeoHookean)
      {
        material.law = pure.law;
      }
    }
    material.youngsModulus = RoundSignificant(material.youngsModulus);
    material.poissonRatio = RoundSignificant(material.poissonRatio);
    material.density = RoundSignificant(material.density);
    for (const MaterialParameter & parameter : MaterialParameters())
    {
      material.*parameter.value = RoundSignificant(material.*parameter.value);
    }
    material.name = MixtureName(material.youngsModulus, material.poissonRatio);
    return material;
  }

  std::vector<int> groupOf; // per class (the tumour last)
  std::vector<int> first;   // per group, its first class
};

/** Each site's material mixed from `materials` (the classes, the tumour
 *  last) by its shares (SiteCount(model) rows of materials.size()). */
void
MixMaterials(Model & model, const std::vector<Material> & materials, const std::vector<double> & shares, int threads)
{
  const MaterialGroups  groups(materials);
  const std::size_t     extended = materials.size();
  const std::size_t     count = SiteCount(model);
  std::vector<Material> siteMaterial(count);
#pragma omp parallel num_threads(threads)
  {
    std::vector<double> groupWeight(groups.Count());
#pragma omp for schedule(static)
    for (std::ptrdiff_t s = 0; s < static_cast<std::ptrdiff_t>(count); ++s)
    {
      std::fill(groupWeight.begin(), groupWeight.end(), 0.0);
      for (std::size_t k = 0; k < extended; ++k)
      {
        groupWeight[groups.groupOf[k]] += shares[static_cast<std::size_t>(s) * extended + k];
      }
      siteMaterial[s] = groups.Mixture(materials, groupWeight);
    }
  }
  AssignMaterials(model, siteMaterial);
}

// Memberships of a voxel with the tumour as an extra class; removed tissue
// (inside the brain: where the memberships or the tumour are) is the CSF
// class's fluid.
struct MembershipVoxels
{
  const ScalarVolume & memberships;
  const LabelVolume *  tumourMask;
  const LabelVolume *  resectionMask;
  int                  csfClass;

  int  Classes() const { return memberships.components; }
  bool IsTumour(std::size_t offset) const { return tumourMask && tumourMask->values[offset] != 0; }
  bool IsResected(std::size_t offset) const { return resectionMask && resectionMask->values[offset] != 0; }
  bool Inside(std::size_t offset) const
  {
    double sum = 0.0;
    for (int k = 0; k < Classes(); ++k)
    {
      sum += memberships.values[offset * Classes() + k];
    }
    return sum > 0.0 || IsTumour(offset);
  }

  /** Adds `weight` times the voxel's memberships (Classes() + 1 values) to `sum`. */
  void Add(std::size_t offset, double weight, double * sum) const
  {
    const int     classes = Classes();
    const float * u = &memberships.values[offset * classes];
    if (IsResected(offset))
    {
      if (IsTumour(offset) || std::accumulate(u, u + classes, 0.0) > 0.0)
      {
        sum[csfClass] += weight;
      }
      return;
    }
    if (IsTumour(offset))
    {
      sum[classes] += weight;
      return;
    }
    for (int k = 0; k < classes; ++k)
    {
      sum[k] += weight * u[k];
    }
  }
};

// Per site the memberships averaged over its samples (Classes() + 1 values
// each) and its status: 0 done, 1 no sample inside the image, 2 no sample
// inside the mask.
void
AverageMemberships(const Sites & sites, const MembershipVoxels & voxels, int threads, std::vector<double> & average,
                   std::vector<std::uint8_t> & status)
{
  const ImageGeometry & geometry = voxels.memberships.geometry;
  const int             extended = voxels.Classes() + 1;
  const std::size_t     count = sites.Count();
#pragma omp parallel num_threads(threads)
  {
    std::vector<Sample> samples;
    std::vector<double> sum(extended);
#pragma omp for schedule(dynamic, 64)
    for (std::ptrdiff_t s = 0; s < static_cast<std::ptrdiff_t>(count); ++s)
    {
      sites.Samples(static_cast<std::size_t>(s), samples);
      std::fill(sum.begin(), sum.end(), 0.0);
      bool inImage = false;
      for (const Sample & sample : samples)
      {
        Vector3 index;
        if (!ContinuousIndex(geometry, sample.x, index))
        {
          continue;
        }
        inImage = true;
        std::size_t offsets[8];
        double      weights[8];
        TrilinearStencil(geometry, index, offsets, weights);
        for (int c = 0; c < 8; ++c)
        {
          if (weights[c] != 0.0)
          {
            voxels.Add(offsets[c], sample.weight * weights[c], sum.data());
          }
        }
      }
      double total = 0.0;
      for (double value : sum)
      {
        total += value;
      }
      if (!inImage)
      {
        status[s] = 1;
      }
      else if (!(total > 0.0))
      {
        status[s] = 2;
      }
      else
      {
        for (int k = 0; k < extended; ++k)
        {
          average[s * extended + k] = sum[k] / total;
        }
      }
    }
  }
}

// Sites with no sample inside the mask take the memberships of the nearest
// mask voxel; a site outside the image is an error. Returns how many took them.
std::size_t
AverageOfNearestVoxel(const Sites & sites, const MembershipVoxels & voxels, const std::vector<std::uint8_t> & status,
                      std::vector<double> & average, const char * who)
{
  const ImageGeometry &         geometry = voxels.memberships.geometry;
  const int                     extended = voxels.Classes() + 1;
  std::size_t                   fallbacks = 0;
  std::unique_ptr<NearestVoxel> nearest;
  for (std::size_t s = 0; s < sites.Count(); ++s)
  {
    if (status[s] == 1)
    {
      ThrowOutsideImage(sites, s, geometry, who);
    }
    if (status[s] != 2)
    {
      continue;
    }
    if (!nearest)
    {
      const std::vector<std::size_t> inside =
        BoundaryVoxels(geometry, [&](std::size_t n) { return voxels.Inside(n); });
      if (inside.empty())
      {
        throw Error(std::string(who) + ": the membership image (" + geometry.Describe() +
                    ") has no voxel inside the mask (all memberships are 0); classify the tissue first");
      }
      nearest = std::make_unique<NearestVoxel>(geometry, inside);
    }
    std::vector<double> sum(extended, 0.0);
    voxels.Add(nearest->Find(sites.Centre(s)), 1.0, sum.data());
    double total = 0.0;
    for (double value : sum)
    {
      total += value;
    }
    for (int k = 0; k < extended; ++k)
    {
      average[s * extended + k] = sum[k] / total;
    }
    ++fallbacks;
  }
  return fallbacks;
}

} // namespace

Material
ParenchymaMaterial()
{
  return Material{ "parenchyma", 3000.0, 0.49, 1000.0 };
}

Material
CsfMaterial()
{
  return Material{ "csf", 10.0, 0.1, 1000.0 };
}

Material
TumourMaterial()
{
  return Material{ "tumour", 6000.0, 0.49, 1000.0 };
}

Material
CsfClassMaterial(const MaterialMappingSettings & settings)
{
  return settings.classMaterials.empty() ? CsfMaterial() : settings.classMaterials.front();
}

std::vector<Material>
DefaultClassMaterials(int classes, const Material & csf, const Material & parenchyma)
{
  if (classes < 1)
  {
    throw Error("DefaultClassMaterials: " + std::to_string(classes) + " classes; give at least 1");
  }
  std::vector<Material> materials(classes, parenchyma);
  materials[0] = csf;
  return materials;
}

void
MapMaterialsFromMemberships(Model &                         model,
                            const ScalarVolume &            memberships,
                            const MaterialMappingSettings & settings,
                            const LabelVolume *             tumourMask,
                            std::vector<std::string> *      warnings,
                            const LabelVolume *             resectionMask)
{
  const char *          who = "material mapping";
  const ImageGeometry & geometry = memberships.geometry;
  const int             classes = memberships.components;
  std::vector<Material> materials =
    settings.classMaterials.empty() && classes >= 1 ? DefaultClassMaterials(classes) : settings.classMaterials;
  CheckMembershipInputs(memberships, materials, settings.csfClass, tumourMask, resectionMask, who);
  CheckNodes(model, who);
  const Sites sites(model, settings.sampling, geometry, who);

  // The tumour is the last class.
  materials.push_back(settings.tumour);
  const int                  extended = classes + 1;
  const MembershipVoxels     voxels{ memberships, tumourMask, resectionMask, settings.csfClass };
  const std::size_t          count = sites.Count();
  std::vector<double>        average(count * extended, 0.0);
  std::vector<std::uint8_t>  status(count, 0);
  AverageMemberships(sites, voxels, ThreadCount(settings.sampling.threads), average, status);
  const std::size_t fallbacks = AverageOfNearestVoxel(sites, voxels, status, average, who);
  if (fallbacks > 0 && warnings)
  {
    warnings->push_back(std::string(who) + ": " + std::to_string(fallbacks) +
                        " cells or integration points have no sample inside the mask and took the memberships of "
                        "the nearest mask voxel; the mesh reaches outside the brain mask");
  }

  MixMaterials(model, materials, average, ThreadCount(settings.sampling.threads));
  model.tissueMixture.classes = std::move(materials);
  model.tissueMixture.shares = std::move(average);
}

void
RemixTissueModuli(Model & model, const std::vector<double> & factors, int threads)
{
  const TissueMixture & mixture = model.tissueMixture;
  if (mixture.Empty())
  {
    throw Error("tissue moduli: the model's materials are not mixed from tissue classes (a scene or a label map); "
                "map them from class memberships (MapMaterialsFromMemberships) or scale every modulus together");
  }
  if (factors.size() != mixture.classes.size() || mixture.shares.size() != SiteCount(model) * factors.size())
  {
    throw Error("tissue moduli: " + std::to_string(factors.size()) + " factors for " +
                std::to_string(mixture.classes.size()) + " classes and " + std::to_string(mixture.shares.size()) +
                " shares for " + std::to_string(SiteCount(model)) + " cells and integration points; give one factor "
                "per class of the model's tissue mixture");
  }
  std::vector<Material> scaled = mixture.classes;
  for (std::size_t k = 0; k < scaled.size(); ++k)
  {
    if (!(factors[k] > 0.0) || !std::isfinite(factors[k]))
    {
      throw Error("tissue moduli: the factor of class " + std::to_string(k) + " is " + std::to_string(factors[k]) +
                  "; give positive factors");
    }
    scaled[k].youngsModulus *= factors[k];
  }
  MixMaterials(model, scaled, mixture.shares, ThreadCount(threads));
}

void
MapMaterialsFromLabels(Model &                         model,
                       const LabelVolume &             labels,
                       const std::map<int, Material> & materialOfLabel,
                       const MaterialSampling &        sampling,
                       std::vector<std::string> *      warnings)
{
  const char *          who = "material mapping from labels";
  const ImageGeometry & geometry = labels.geometry;
  const std::size_t     voxels = geometry.VoxelCount();
  if (voxels == 0 || labels.components != 1 || labels.values.size() != voxels)
  {
    throw Error(std::string(who) + ": the label image (" + geometry.Describe() + ") holds " +
                std::to_string(labels.values.size()) + " values; give a scalar label image");
  }
  CheckNodes(model, who);
  const Sites sites(model, sampling, geometry, who);
  const bool  backgroundHasMaterial = materialOfLabel.count(0) > 0;
  auto        counts = [&](int label) { return label != 0 || backgroundHasMaterial; };

  const std::size_t count = sites.Count();
  // Winning label per site; -1: no sample inside the image, -2: no labelled sample.
  std::vector<int> winner(count, -1);
  // Smallest label without a material met by each site (256: none).
  std::vector<int> missing(count, 256);
#pragma omp parallel num_threads(ThreadCount(sampling.threads))
  {
    std::vector<Sample>     samples;
    std::array<double, 256> votes;
#pragma omp for schedule(dynamic, 64)
    for (std::ptrdiff_t s = 0; s < static_cast<std::ptrdiff_t>(count); ++s)
    {
      sites.Samples(static_cast<std::size_t>(s), samples);
      votes.fill(0.0);
      bool inImage = false;
      for (const Sample & sample : samples)
      {
        Vector3 index;
        if (!ContinuousIndex(geometry, sample.x, index))
        {
          continue;
        }
        inImage = true;
        int at[3];
        for (int d = 0; d < 3; ++d)
        {
          at[d] = std::clamp(static_cast<int>(std::lround(index[d])), 0, geometry.size[d] - 1);
        }
        const int label = labels.values[geometry.Offset(at[0], at[1], at[2])];
        if (counts(label))
        {
          votes[label] += sample.weight;
        }
      }
      if (!inImage)
      {
        continue;
      }
      int best = -2;
      for (int label = 0; label < 256; ++label)
      {
        if (votes[label] > 0.0)
        {
          if (best < 0 || votes[label] > votes[best])
          {
            best = label;
          }
          if (!materialOfLabel.count(label))
          {
            missing[s] = std::min(missing[s], label);
          }
        }
      }
      winner[s] = best;
    }
  }

  std::set<int> missingLabels;
  std::size_t   firstMissing = count;
  for (std::size_t s = 0; s < count; ++s)
  {
    if (winner[s] == -1)
    {
      ThrowOutsideImage(sites, s, geometry, who);
    }
    if (missing[s] < 256)
    {
      missingLabels.insert(missing[s]);
      firstMissing = std::min(firstMissing, s);
    }
  }

  std::size_t                   fallbacks = 0;
  std::unique_ptr<NearestVoxel> nearest;
  for (std::size_t s = 0; s < count; ++s)
  {
    if (winner[s] != -2)
    {
      continue;
    }
    if (!nearest)
    {
      const std::vector<std::size_t> labelled =
        BoundaryVoxels(geometry, [&](std::size_t n) { return counts(labels.values[n]); });
      if (labelled.empty())
      {
        throw Error(std::string(who) + ": the label image (" + geometry.Describe() +
                    ") has no labelled (non-zero) voxel; give a label map of the brain");
      }
      nearest = std::make_unique<NearestVoxel>(geometry, labelled);
    }
    winner[s] = labels.values[nearest->Find(sites.Centre(s))];
    if (!materialOfLabel.count(winner[s]))
    {
      missingLabels.insert(winner[s]);
      firstMissing = std::min(firstMissing, s);
    }
    ++fallbacks;
  }
  if (!missingLabels.empty())
  {
    std::ostringstream text;
    text << who << ": label" << (missingLabels.size() > 1 ? "s " : " ");
    for (auto it = missingLabels.begin(); it != missingLabels.end(); ++it)
    {
      text << (it == missingLabels.begin() ? "" : ", ") << *it;
    }
    text << " of the label image " << (missingLabels.size() > 1 ? "have" : "has")
         << " no material (first met by " << sites.Name(firstMissing)
         << "); add a material for each label the model covers";
    throw Error(text.str());
  }
  if (fallbacks > 0 && warnings)
  {
    warnings->push_back(std::string(who) + ": " + std::to_string(fallbacks) +
                        " cells or integration points have no labelled sample and took the label of the nearest "
                        "labelled voxel; the mesh reaches outside the label map");
  }

  std::vector<Material> siteMaterial(count);
  for (std::size_t s = 0; s < count; ++s)
  {
    siteMaterial[s] = materialOfLabel.at(winner[s]);
    if (siteMaterial[s].name.empty())
    {
      siteMaterial[s].name = "label " + std::to_string(winner[s]);
    }
  }
  AssignMaterials(model, siteMaterial);
  model.tissueMixture = {}; // one material per label, no mixture
}

} // namespace bmr
