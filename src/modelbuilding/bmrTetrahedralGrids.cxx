// CGAL Mesh_3 on the labelled image: tetrahedral grids and the meshless
// cloud. All of CGAL's Mesh_3 stays in this file: it is expensive to compile.
#include "bmrImageGridBody.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Handle_hash_function.h>
#include <CGAL/Image_3.h>
#include <CGAL/ImageIO.h>
#include <CGAL/Labeled_mesh_domain_3.h>
#include <CGAL/Mesh_complex_3_in_triangulation_3.h>
#include <CGAL/Mesh_criteria_3.h>
#include <CGAL/Mesh_triangulation_3.h>
#include <CGAL/Random.h>
#include <CGAL/make_mesh_3.h>

#include <unordered_map>

namespace bmr
{
namespace grids
{

// ----------------------------------------------------------------------------
// CGAL Mesh_3 on the labelled image

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using MeshDomain = CGAL::Labeled_mesh_domain_3<Kernel>;
using Triangulation = CGAL::Mesh_triangulation_3<MeshDomain, CGAL::Default, CGAL::Sequential_tag>::type;
using Complex = CGAL::Mesh_complex_3_in_triangulation_3<Triangulation>;
using Criteria = CGAL::Mesh_criteria_3<Triangulation>;

double
DerivedFacetDistance(const ImageGridSettings & settings)
{
  return settings.facetDistance > 0.0 ? settings.facetDistance : settings.elementSize / 8.0;
}

/** Keeps the largest set of tetrahedra connected through shared faces (CGAL
 *  can leave small pieces where the mask narrows below the element size;
 *  loose pieces would be unconstrained bodies) and drops unused nodes. */
void
KeepLargestFaceConnectedTetrahedra(ImageGrid & grid, std::vector<std::string> * warnings)
{
  Model &          model = grid.model;
  const std::size_t cellCount = model.cells.size();
  // Union-find over cells sharing a face; faces found by sorting their node triples.
  std::vector<std::size_t> parent(cellCount);
  std::iota(parent.begin(), parent.end(), std::size_t{ 0 });
  auto root = [&](std::size_t c) {
    while (parent[c] != c)
    {
      parent[c] = parent[parent[c]];
      c = parent[c];
    }
    return c;
  };
  std::vector<std::pair<std::array<Index, 3>, std::size_t>> faces;
  faces.reserve(4 * cellCount);
  for (std::size_t c = 0; c < cellCount; ++c)
  {
    const auto & n = model.cells[c].nodes;
    for (int omitted = 0; omitted < 4; ++omitted)
    {
      std::array<Index, 3> face{};
      for (int v = 0, f = 0; v < 4; ++v)
      {
        if (v != omitted)
        {
          face[f++] = n[v];
        }
      }
      std::sort(face.begin(), face.end());
      faces.emplace_back(face, c);
    }
  }
  std::sort(faces.begin(), faces.end());
  for (std::size_t f = 1; f < faces.size(); ++f)
  {
    if (faces[f].first == faces[f - 1].first)
    {
      parent[root(faces[f].second)] = root(faces[f - 1].second);
    }
  }
  std::map<std::size_t, std::size_t> sizeOfRoot;
  for (std::size_t c = 0; c < cellCount; ++c)
  {
    ++sizeOfRoot[root(c)];
  }
  if (sizeOfRoot.size() <= 1)
  {
    return;
  }
  const auto largest = std::max_element(sizeOfRoot.begin(), sizeOfRoot.end(), [](const auto & a, const auto & b) {
                         return a.second < b.second;
                       })->first;
  std::vector<char> keep(cellCount, 0);
  std::vector<int>  keptLabels;
  for (std::size_t c = 0; c < cellCount; ++c)
  {
    if (root(c) == largest)
    {
      keep[c] = 1;
      keptLabels.push_back(grid.cellLabels[c]);
    }
  }
  Model kept = KeepCells(model, keep);
  if (warnings)
  {
    warnings->push_back("grid: the tetrahedral mesh has " + std::to_string(sizeOfRoot.size()) +
                        " face-connected parts; kept the largest (" + std::to_string(kept.cells.size()) +
                        " tetrahedra), dropped " + std::to_string(cellCount - kept.cells.size()) +
                        " tetrahedra in the others (where the mask narrows below the element size)");
  }
  model = std::move(kept);
  grid.cellLabels = std::move(keptLabels);
}

ImageGrid
MakeTetrahedralGrid(const Body & body, const ImageGridSettings & settings, std::vector<std::string> * warnings)
{
  const ImageGeometry & geometry = body.Geometry();
  if (!(settings.facetAngle > 0.0 && settings.facetAngle <= 30.0))
  {
    throw Error("MakeGridFromLabels: facet angle " + Number(settings.facetAngle) +
                " degrees is out of range; CGAL guarantees termination for (0, 30] degrees.");
  }
  if (!(settings.cellRadiusEdgeRatio >= 2.0))
  {
    throw Error("MakeGridFromLabels: cell radius-edge ratio " + Number(settings.cellRadiusEdgeRatio) +
                " must be at least 2 (CGAL's refinement does not terminate below).");
  }
  if (!(settings.facetDistance >= 0.0) || !std::isfinite(settings.facetDistance))
  {
    throw Error("MakeGridFromLabels: facet distance " + Number(settings.facetDistance) +
                " mm must be >= 0 (0: elementSize / 8).");
  }
  // CGAL's image descriptor over a copy of the voxels (x fastest, as in ITK).
  _image * image = ::_createImage(static_cast<std::size_t>(geometry.size[0]), static_cast<std::size_t>(geometry.size[1]),
                                  static_cast<std::size_t>(geometry.size[2]), 1, geometry.spacing[0],
                                  geometry.spacing[1], geometry.spacing[2], 1, WK_FIXED, SGN_UNSIGNED);
  if (image == nullptr)
  {
    throw Error("MakeGridFromLabels: could not allocate CGAL's copy of the label image (" + geometry.Describe() + ").");
  }
  std::memcpy(image->data, body.labels->values.data(), body.labels->values.size());
  image->tx = image->ty = image->tz = 0.0f;
  CGAL::Image_3 cgalImage(image); // owns the descriptor from here

  // CGAL draws random numbers (initial points, perturbation): seed them.
  CGAL::get_default_random() = CGAL::Random(static_cast<unsigned int>(settings.seed));
  CGAL::Random domainRandom(static_cast<unsigned int>(settings.seed));
  namespace params = CGAL::parameters;
  MeshDomain domain = MeshDomain::create_labeled_image_mesh_domain(cgalImage, params::p_rng = &domainRandom);
  const double h = settings.elementSize;
  Criteria     criteria(params::facet_angle = settings.facetAngle, params::facet_size = h / std::sqrt(3.0),
                    params::facet_distance = DerivedFacetDistance(settings),
                    params::cell_radius_edge_ratio = settings.cellRadiusEdgeRatio,
                    params::cell_size = h * std::sqrt(6.0) / 4.0);
  Complex complex;
  // No time limits: a time-limited optimisation would depend on the machine's speed.
  if (settings.optimise)
  {
    complex = CGAL::make_mesh_3<Complex>(domain, criteria, params::no_lloyd(), params::no_odt(),
                                         params::perturb(params::time_limit = 0, params::sliver_bound = 10.0),
                                         params::exude(params::time_limit = 0, params::sliver_bound = 15.0));
  }
  else
  {
    complex = CGAL::make_mesh_3<Complex>(domain, criteria, params::no_lloyd(), params::no_odt(),
                                         params::no_perturb(),
                                         params::no_exude());
  }

  ImageGrid result;
  Model &   model = result.model;
  model.materials.push_back(Parenchyma());
  // Nodes numbered in the order the cells first meet them (a hash map: a
  // std::map of the handles took a second for the 4.25 mm meshless cloud).
  std::unordered_map<Triangulation::Vertex_handle, Index, CGAL::Handle_hash_function> nodeOf;
  for (auto cell = complex.cells_in_complex_begin(); cell != complex.cells_in_complex_end(); ++cell)
  {
    Cell element;
    element.type = CellType::Tetrahedron;
    element.nodes.fill(0);
    for (int v = 0; v < 4; ++v)
    {
      const auto vertex = cell->vertex(v);
      auto       found = nodeOf.find(vertex);
      if (found == nodeOf.end())
      {
        const auto & point = vertex->point().point();
        found = nodeOf.emplace(vertex, static_cast<Index>(model.nodes.size())).first;
        model.nodes.push_back(body.ToPhysical(Vector3(point.x(), point.y(), point.z())));
      }
      element.nodes[v] = found->second;
    }
    if (TetrahedronVolume(model.nodes[element.nodes[0]], model.nodes[element.nodes[1]], model.nodes[element.nodes[2]],
                  model.nodes[element.nodes[3]]) < 0.0)
    {
      std::swap(element.nodes[1], element.nodes[2]);
    }
    model.cells.push_back(element);
    result.cellLabels.push_back(static_cast<int>(complex.subdomain_index(cell)));
  }
  if (model.cells.empty())
  {
    throw Error("MakeGridFromLabels: CGAL's mesh generator produced no tetrahedra for the mask (" +
                geometry.Describe() + ", " + std::to_string(body.voxels) +
                " tissue voxels); use a smaller element size or check the mask.");
  }
  KeepLargestFaceConnectedTetrahedra(result, warnings);
  return result;
}

// ----------------------------------------------------------------------------
// Meshless point cloud

namespace
{
/** The integration points of the cloud `result.model` over `region`, with its
 *  shape functions at the settings' dilatation or, where that leaves an
 *  integration point of a thin part uncovered, at the fallback's. */
void
IntegrateCloud(const BodyRegion & region, const ImageGridSettings & settings, ImageGrid & result,
               std::vector<std::string> * warnings)
{
  Model & model = result.model;
  MlsSettings mlsSettings = settings.meshlessShapeFunctions;
  for (;;)
  {
    // Out-of-range settings are the caller's error, not the cloud's: no fallback.
    const MovingLeastSquares mls(model.nodes, mlsSettings);
    try
    {
      IntegrationPoints points =
        MakeIntegrationPoints(region, mls, settings.meshlessIntegration, settings.threads);
      if (points.positions.empty())
      {
        throw Error("no integration point lies inside the body");
      }
      // The supports the solver will use: widened where the points are sparser than the nodes.
      const MovingLeastSquares covered(model.nodes, mlsSettings, points.positions);
      const ShapeFunctionTable table = covered.Evaluate(points.positions, false, settings.threads, "integration point");
      double minimum = std::numeric_limits<double>::max(), sum = 0.0;
      for (Index p = 0; p < table.PointCount(); ++p)
      {
        const double neighbours = table.offsets[p + 1] - table.offsets[p];
        minimum = std::min(minimum, neighbours);
        sum += neighbours;
      }
      result.quality.minNeighboursPerPoint = minimum;
      result.quality.meanNeighboursPerPoint = sum / table.PointCount();
      double spacing = 0.0;
      for (Index n = 0; n < mls.NodeCount(); ++n)
        spacing += mls.NodalSpacing(n);
      result.quality.meanEdgeLength = spacing / mls.NodeCount();
      model.meshless.shapeFunctions = mlsSettings;
      model.meshless.integrationPoints = std::move(points.positions);
      model.meshless.integrationWeights = std::move(points.weights);
      model.meshless.integrationMaterials = std::move(points.materials);
      model.discretization = Discretization::Meshless;
      break;
    }
    catch (const Error & error)
    {
      const double fallback = settings.meshlessFallbackDilatation;
      if (fallback > mlsSettings.dilatation)
      {
        if (warnings)
        {
          warnings->push_back("grid: the meshless cloud of spacing " + Number(settings.elementSize) +
                              " mm at MLS dilatation " + Number(mlsSettings.dilatation) +
                              " does not cover the body (" + error.what() +
                              "); made it with dilatation " + Number(fallback) +
                              " instead (more neighbours a point: a slower solve).");
        }
        mlsSettings.dilatation = fallback;
        continue;
      }
      throw Error(std::string("MakeGridFromLabels: the meshless point cloud of spacing ") +
                  Number(settings.elementSize) + " mm does not cover the body: " + error.what() +
                  " Increase meshlessShapeFunctions.dilatation (now " + Number(mlsSettings.dilatation) +
                  ") or use a smaller element size.");
    }
  }
}

} // namespace

ImageGrid
MakeMeshlessGrid(const Body & body, const ImageGridSettings & settings, std::vector<std::string> * warnings)
{
  const double h = settings.elementSize;
  // The body's surface: the boundary of the tetrahedral mesh of the same size.
  const ImageGrid              tetrahedra = MakeTetrahedralGrid(body, settings, warnings);
  std::vector<Vector3> meshSurfaceNodes;
  for (const Index n : tetrahedra.model.BoundaryNodes())
    meshSurfaceNodes.push_back(tetrahedra.model.nodes[n]);
  // The region is the union of the tetrahedra (point location only), which
  // does not need the surface to be a 2-manifold.
  const BodyRegion region = BodyRegion::FromCells(tetrahedra.model);

  // Interior nodes: the regular grid inside the body, away from the surface
  // nodes (a bucket grid of cell h finds the near ones: one fixed-radius query
  // per grid point, simpler here than a k-d tree).
  const ImageGeometry & geometry = body.Geometry();
  auto bucketOf = [h](const Vector3 & x) {
    return std::array<long, 3>{ static_cast<long>(std::floor(x[0] / h)), static_cast<long>(std::floor(x[1] / h)),
                                static_cast<long>(std::floor(x[2] / h)) };
  };
  struct BucketHash
  {
    std::size_t operator()(const std::array<long, 3> & k) const
    {
      return static_cast<std::size_t>(k[0] * 73856093L ^ k[1] * 19349663L ^ k[2] * 83492791L);
    }
  };
  std::unordered_map<std::array<long, 3>, std::vector<Index>, BucketHash> buckets;
  std::vector<Vector3>                                                    surfaceNodes;
  const double clearance = 0.5 * h;
  auto         nearSurface = [&](const Vector3 & x) {
    const auto key = bucketOf(x);
    for (long dz = -1; dz <= 1; ++dz)
      for (long dy = -1; dy <= 1; ++dy)
        for (long dx = -1; dx <= 1; ++dx)
        {
          auto it = buckets.find({ key[0] + dx, key[1] + dy, key[2] + dz });
          if (it == buckets.end())
            continue;
          for (Index n : it->second)
            if ((surfaceNodes[n] - x).squaredNorm() < clearance * clearance)
              return true;
        }
    return false;
  };
  // CGAL places surface vertices closer than h along fine features (1-2 mm
  // apart at h = 7 mm on Colin27). Such clusters hold too few integration
  // points for their shape functions to be independent: they leave local
  // modes of almost no stiffness, which dynamic relaxation resolves only
  // after tens of thousands of steps. The cloud keeps a surface vertex only
  // when no kept one lies within the clearance (in the mesh's order, so the
  // cloud is reproducible); the tetrahedral surface stays the body's surface.
  for (const Vector3 & x : meshSurfaceNodes)
  {
    if (!nearSurface(x))
    {
      buckets[bucketOf(x)].push_back(static_cast<Index>(surfaceNodes.size()));
      surfaceNodes.push_back(x);
    }
  }
  ImageGrid result;
  Model &   model = result.model;
  model.materials.push_back(Parenchyma());
  model.nodes = surfaceNodes;
  std::array<int, 3> count{};
  Vector3            start;
  for (int d = 0; d < 3; ++d)
  {
    const double lo = (body.lower[d] - 0.5) * geometry.spacing[d];
    const double hi = (body.upper[d] + 0.5) * geometry.spacing[d];
    count[d] = static_cast<int>(std::ceil((hi - lo) / h));
    start[d] = 0.5 * (lo + hi) - 0.5 * (count[d] - 1) * h;
  }
  for (int c = 0; c < count[2]; ++c)
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a)
      {
        const Vector3 g = start + h * Vector3(a, b, c);
        if (!body.NearestVoxelInside(g))
          continue;
        const Vector3 x = body.ToPhysical(g);
        if (!region.Contains(x) || nearSurface(x))
          continue;
        model.nodes.push_back(x);
      }
  AddStandardNodeSets(model);
  auto & surface = model.nodeSets["surface"];
  surface.resize(surfaceNodes.size());
  for (std::size_t n = 0; n < surfaceNodes.size(); ++n)
    surface[n] = static_cast<Index>(n);

  IntegrateCloud(region, settings, result, warnings);
  // The tetrahedra stay with the grid as the body's description (surfaces, rasterisation).
  result.meshlessBody = tetrahedra.model;
  return result;
}

} // namespace grids
} // namespace bmr
