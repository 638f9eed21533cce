// Grids from a mask or label image: the input's checks, the dispatch to each
// kind's maker (bmrImageGridBody.h), the grids' quality and rasterisation.
#include "bmrImageGridBody.h"
#include "bmrNodeOrder.h"

namespace bmr
{
using namespace grids;

namespace
{

Body
CheckInput(const LabelVolume & labels, const ImageGridSettings & settings)
{
  const ImageGeometry & geometry = labels.geometry;
  if (labels.components != 1)
  {
    throw Error("MakeGridFromLabels: the label volume has " + std::to_string(labels.components) +
                " components per voxel; give a scalar mask or label image (1 component, 0 = outside).");
  }
  if (geometry.size[0] <= 0 || geometry.size[1] <= 0 || geometry.size[2] <= 0 ||
      labels.values.size() != geometry.VoxelCount())
  {
    throw Error("MakeGridFromLabels: the label volume is empty or its " + std::to_string(labels.values.size()) +
                " values do not fill its grid of " + geometry.Describe() + "; give a 3D mask or label image.");
  }
  for (int d = 0; d < 3; ++d)
  {
    if (!(geometry.spacing[d] > 0.0) || !std::isfinite(geometry.spacing[d]))
    {
      throw Error("MakeGridFromLabels: the label image has a non-positive voxel spacing (" + geometry.Describe() +
                  "); fix the image header.");
    }
  }
  Body body;
  body.labels = &labels;
  body.lower = { geometry.size[0], geometry.size[1], geometry.size[2] };
  body.upper = { -1, -1, -1 };
  for (int k = 0; k < geometry.size[2]; ++k)
  {
    for (int j = 0; j < geometry.size[1]; ++j)
    {
      for (int i = 0; i < geometry.size[0]; ++i)
      {
        if (labels.values[geometry.Offset(i, j, k)] > 0)
        {
          ++body.voxels;
          const int index[3] = { i, j, k };
          for (int d = 0; d < 3; ++d)
          {
            body.lower[d] = std::min(body.lower[d], index[d]);
            body.upper[d] = std::max(body.upper[d], index[d]);
          }
        }
      }
    }
  }
  if (body.voxels == 0)
  {
    throw Error("MakeGridFromLabels: the mask is empty (every voxel is background 0) on " + geometry.Describe() +
                "; give a mask or label image with tissue labels > 0.");
  }
  body.maskVolume = static_cast<double>(body.voxels) * geometry.VoxelVolume();
  body.flipped = geometry.direction.determinant() < 0.0;

  const double smallestSpacing = geometry.spacing.minCoeff();
  const double h = settings.elementSize;
  if (!std::isfinite(h) || h < smallestSpacing * (1.0 - 1e-9))
  {
    throw Error("MakeGridFromLabels: element size " + Number(h) +
                " mm is smaller than the voxel spacing; the smallest allowed element size is " +
                Number(smallestSpacing) + " mm (the smallest voxel spacing of " + geometry.Describe() + ").");
  }
  Vector3 extent;
  for (int d = 0; d < 3; ++d)
  {
    extent[d] = (body.upper[d] - body.lower[d] + 1) * geometry.spacing[d];
  }
  if (extent.minCoeff() < 2.0 * h)
  {
    throw Error("MakeGridFromLabels: element size " + Number(h) + " mm is too large for the body, whose extent is " +
                Number(extent[0]) + " x " + Number(extent[1]) + " x " + Number(extent[2]) +
                " mm along the image axes: it must be at least 2 elements across. Use an element size of at most " +
                Number(0.5 * extent.minCoeff()) + " mm.");
  }
  return body;
}

// ----------------------------------------------------------------------------
// Quality

/** Smallest corner Jacobian with unit edge vectors (1 for a cube). */
double
HexScaledJacobian(const Model & model, const Cell & cell)
{
  static const int neighbours[8][3] = { { 1, 3, 4 }, { 2, 0, 5 }, { 3, 1, 6 }, { 0, 2, 7 },
                                        { 7, 5, 0 }, { 4, 6, 1 }, { 5, 7, 2 }, { 6, 4, 3 } };
  double minimum = std::numeric_limits<double>::max();
  for (int c = 0; c < 8; ++c)
  {
    const Vector3 & p = model.nodes[cell.nodes[c]];
    const Vector3   a = (model.nodes[cell.nodes[neighbours[c][0]]] - p).normalized();
    const Vector3   b = (model.nodes[cell.nodes[neighbours[c][1]]] - p).normalized();
    const Vector3   d = (model.nodes[cell.nodes[neighbours[c][2]]] - p).normalized();
    minimum = std::min(minimum, a.cross(b).dot(d));
  }
  return minimum;
}

/** Renumbers the nodes (and the cells' references; nothing else may name a
 *  node yet) in Morton order. CGAL lists a mesh's vertices in no spatial
 *  order, and the force kernels then fetch each cell's nodes from as many
 *  distant cache lines (docs/thread-scaling.md). */
void
NumberNodesInMortonOrder(Model & model)
{
  const MortonNumbering numbering(model.nodes);
  std::vector<Vector3>  nodes(model.nodes.size());
  for (Index slot = 0; slot < static_cast<Index>(nodes.size()); ++slot)
  {
    nodes[slot] = model.nodes[numbering.Node(slot)];
  }
  model.nodes = std::move(nodes);
  for (Cell & cell : model.cells)
  {
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      cell.nodes[a] = numbering.Slot(cell.nodes[a]);
    }
  }
}

} // namespace

const char *
ImageGridKindName(ImageGridKind kind)
{
  switch (kind)
  {
    case ImageGridKind::Hexahedra:
      return "hexahedra";
    case ImageGridKind::Tetrahedra:
      return "tetrahedra";
    case ImageGridKind::Mixed:
      return "mixed";
    case ImageGridKind::Meshless:
      return "meshless";
  }
  return "unknown";
}

ImageGridKind
ParseImageGridKind(const std::string & name)
{
  if (name == "hexahedra" || name == "hex" || name == "hexahedron")
    return ImageGridKind::Hexahedra;
  if (name == "tetrahedra" || name == "tet" || name == "tetrahedron")
    return ImageGridKind::Tetrahedra;
  if (name == "mixed")
    return ImageGridKind::Mixed;
  if (name == "meshless")
    return ImageGridKind::Meshless;
  throw Error("unknown grid kind '" + name + "': use hexahedra, tetrahedra, mixed or meshless.");
}

GridQuality
MeasureGridQuality(const Model & model)
{
  GridQuality quality;
  quality.nodes = model.nodes.size();
  quality.cells = model.cells.size();
  double      jacobianSum = 0.0, edgeSum = 0.0;
  std::size_t edgeCount = 0;
  quality.minScaledJacobian = model.cells.empty() ? 0.0 : std::numeric_limits<double>::max();
  double minDihedral = std::numeric_limits<double>::max(), maxDihedral = 0.0;
  static const int tetEdges[6][2] = { { 0, 1 }, { 0, 2 }, { 0, 3 }, { 1, 2 }, { 1, 3 }, { 2, 3 } };
  static const int hexEdges[12][2] = { { 0, 1 }, { 1, 2 }, { 2, 3 }, { 3, 0 }, { 4, 5 }, { 5, 6 },
                                       { 6, 7 }, { 7, 4 }, { 0, 4 }, { 1, 5 }, { 2, 6 }, { 3, 7 } };
  for (std::size_t e = 0; e < model.cells.size(); ++e)
  {
    const Cell & cell = model.cells[e];
    quality.meshVolume += CellVolume(model, static_cast<Index>(e));
    double shortest = std::numeric_limits<double>::max(), longest = 0.0;
    auto   edge = [&](int a, int b) {
      const double length = (model.nodes[cell.nodes[a]] - model.nodes[cell.nodes[b]]).norm();
      shortest = std::min(shortest, length);
      longest = std::max(longest, length);
      edgeSum += length;
      ++edgeCount;
    };
    double scaled = 0.0;
    if (cell.type == CellType::Hexahedron)
    {
      ++quality.hexahedra;
      for (const auto & ed : hexEdges)
        edge(ed[0], ed[1]);
      scaled = HexScaledJacobian(model, cell);
    }
    else
    {
      ++quality.tetrahedra;
      for (const auto & ed : tetEdges)
        edge(ed[0], ed[1]);
      const Vector3 * x[4] = { &model.nodes[cell.nodes[0]], &model.nodes[cell.nodes[1]], &model.nodes[cell.nodes[2]],
                               &model.nodes[cell.nodes[3]] };
      const double six = 6.0 * TetrahedronVolume(*x[0], *x[1], *x[2], *x[3]);
      scaled = std::numeric_limits<double>::max();
      for (int c = 0; c < 4; ++c)
      {
        double lengths = std::sqrt(2.0);
        for (int o = 1; o < 4; ++o)
          lengths /= (*x[(c + o) % 4] - *x[c]).norm();
        scaled = std::min(scaled, six * lengths);
      }
      // Dihedral angles from the outward face normals: angle = pi - angle(n_k, n_l).
      Vector3 normals[4];
      for (int k = 0; k < 4; ++k)
      {
        const Vector3 & a = *x[(k + 1) % 4];
        const Vector3 & b = *x[(k + 2) % 4];
        const Vector3 & c = *x[(k + 3) % 4];
        Vector3         n = (b - a).cross(c - a);
        if (n.dot(*x[k] - a) > 0.0)
          n = -n;
        normals[k] = n.normalized();
      }
      for (int k = 0; k < 4; ++k)
        for (int l = k + 1; l < 4; ++l)
        {
          const double angle = 180.0 - std::acos(std::clamp(normals[k].dot(normals[l]), -1.0, 1.0)) * 180.0 / kPi;
          minDihedral = std::min(minDihedral, angle);
          maxDihedral = std::max(maxDihedral, angle);
        }
    }
    quality.minScaledJacobian = std::min(quality.minScaledJacobian, scaled);
    jacobianSum += scaled;
    quality.maxAspectRatio = std::max(quality.maxAspectRatio, longest / shortest);
  }
  if (!model.cells.empty())
  {
    quality.meanScaledJacobian = jacobianSum / model.cells.size();
    quality.meanEdgeLength = edgeSum / edgeCount;
  }
  if (quality.tetrahedra > 0)
  {
    quality.minDihedralAngleDeg = minDihedral;
    quality.maxDihedralAngleDeg = maxDihedral;
  }
  return quality;
}

/** The largest face-connected (6-connected) part of the tissue voxels: specks
 *  of a skull-stripped mask would otherwise become loose, unloaded pieces of
 *  the model. Labels inside the part are kept. */
LabelVolume
LargestConnectedTissue(const LabelVolume & labels, std::vector<std::string> & warnings)
{
  const ImageGeometry & geometry = labels.geometry;
  const std::size_t     voxels = geometry.VoxelCount();
  if (labels.components != 1 || labels.values.size() != voxels)
  {
    return labels; // CheckInput names the problem
  }
  std::vector<std::int32_t> component(voxels, -1);
  std::vector<std::size_t>  sizes;
  std::vector<std::size_t>  stack;
  const std::size_t         strideY = static_cast<std::size_t>(geometry.size[0]);
  const std::size_t         strideZ = strideY * static_cast<std::size_t>(geometry.size[1]);
  for (std::size_t seed = 0; seed < voxels; ++seed)
  {
    if (labels.values[seed] == 0 || component[seed] >= 0)
    {
      continue;
    }
    const auto  id = static_cast<std::int32_t>(sizes.size());
    std::size_t size = 0;
    component[seed] = id;
    stack.push_back(seed);
    while (!stack.empty())
    {
      const std::size_t voxel = stack.back();
      stack.pop_back();
      ++size;
      const int i = static_cast<int>(voxel % strideY);
      const int j = static_cast<int>((voxel / strideY) % geometry.size[1]);
      const int k = static_cast<int>(voxel / strideZ);
      const std::pair<bool, std::size_t> neighbours[6] = {
        { i > 0, voxel - 1 },       { i + 1 < geometry.size[0], voxel + 1 },
        { j > 0, voxel - strideY }, { j + 1 < geometry.size[1], voxel + strideY },
        { k > 0, voxel - strideZ }, { k + 1 < geometry.size[2], voxel + strideZ }
      };
      for (const auto & [exists, neighbour] : neighbours)
      {
        if (exists && labels.values[neighbour] != 0 && component[neighbour] < 0)
        {
          component[neighbour] = id;
          stack.push_back(neighbour);
        }
      }
    }
    sizes.push_back(size);
  }
  if (sizes.size() <= 1)
  {
    return labels;
  }
  const auto  largest = static_cast<std::int32_t>(std::max_element(sizes.begin(), sizes.end()) - sizes.begin());
  LabelVolume kept = labels;
  for (std::size_t voxel = 0; voxel < voxels; ++voxel)
  {
    if (component[voxel] != largest)
    {
      kept.values[voxel] = 0;
    }
  }
  warnings.push_back("grid: the mask has " + std::to_string(sizes.size()) + " separate parts; kept the largest (" +
                     std::to_string(sizes[largest]) + " voxels), dropped " +
                     std::to_string(std::accumulate(sizes.begin(), sizes.end(), std::size_t{ 0 }) - sizes[largest]) +
                     " voxels in the others (they would be loose pieces of the model)");
  return kept;
}

ImageGrid
MakeGridFromLabels(const LabelVolume & inputLabels, const ImageGridSettings & settings, std::vector<std::string> * warnings)
{
  const auto  started = std::chrono::steady_clock::now();
  std::vector<std::string> localWarnings;
  const LabelVolume labels = LargestConnectedTissue(inputLabels, localWarnings);
  const Body  body = CheckInput(labels, settings);
  ImageGrid   result;
  switch (settings.kind)
  {
    case ImageGridKind::Hexahedra:
    case ImageGridKind::Mixed:
      result = MakeHexahedralGrid(body, settings.elementSize, settings.kind == ImageGridKind::Mixed, &localWarnings);
      break;
    case ImageGridKind::Tetrahedra:
      result = MakeTetrahedralGrid(body, settings, &localWarnings);
      NumberNodesInMortonOrder(result.model);
      AddStandardNodeSets(result.model);
      break;
    case ImageGridKind::Meshless:
      result = MakeMeshlessGrid(body, settings, &localWarnings);
      break;
  }
  result.model.Validate();

  if (settings.kind == ImageGridKind::Meshless)
  {
    GridQuality & quality = result.quality;
    quality.nodes = result.model.nodes.size();
    quality.integrationPoints = result.model.meshless.integrationPoints.size();
    quality.meshVolume = 0.0;
    for (double w : result.model.meshless.integrationWeights)
      quality.meshVolume += w;
  }
  else
  {
    result.quality = MeasureGridQuality(result.model);
  }
  result.quality.maskVolume = body.maskVolume;
  result.quality.volumeError = (result.quality.meshVolume - body.maskVolume) / body.maskVolume;
  result.quality.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  if (warnings)
    warnings->insert(warnings->end(), localWarnings.begin(), localWarnings.end());
  return result;
}

std::string
FormatGridQuality(const GridQuality & q)
{
  std::ostringstream text;
  text << std::setprecision(4);
  text << "grid: " << q.nodes << " nodes (" << 3 * q.nodes << " DOF), " << q.cells << " cells (" << q.hexahedra
       << " hexahedra, " << q.tetrahedra << " tetrahedra)";
  if (q.integrationPoints > 0)
    text << ", " << q.integrationPoints << " integration points";
  text << ", " << q.seconds << " s\n";
  text << "volume: mesh " << q.meshVolume / 1000.0 << " mL, mask " << q.maskVolume / 1000.0 << " mL, error "
       << 100.0 * q.volumeError << " %\n";
  if (q.cells > 0)
  {
    text << "quality: scaled Jacobian min " << q.minScaledJacobian << " mean " << q.meanScaledJacobian
         << ", max aspect ratio " << q.maxAspectRatio << ", mean edge " << q.meanEdgeLength << " mm";
    if (q.tetrahedra > 0)
      text << ", dihedral angles " << q.minDihedralAngleDeg << " .. " << q.maxDihedralAngleDeg << " deg";
    text << "\n";
  }
  if (q.integrationPoints > 0)
  {
    text << "meshless: MLS neighbours per integration point min " << q.minNeighboursPerPoint << " mean "
         << q.meanNeighboursPerPoint << ", mean nodal spacing " << q.meanEdgeLength << " mm\n";
  }
  return text.str();
}

LabelVolume
RasterizeCells(const Model & model, const ImageGeometry & grid)
{
  if (model.cells.empty())
  {
    throw Error("RasterizeCells: the model has no cells (a meshless model's body is its mask)");
  }
  LabelVolume volume;
  volume.geometry = grid;
  volume.values.assign(grid.VoxelCount(), 0);
  const auto cellCount = static_cast<std::int64_t>(model.cells.size());
#pragma omp parallel for schedule(dynamic, 64)
  for (std::int64_t cellId = 0; cellId < cellCount; ++cellId)
  {
    const Cell & cell = model.cells[cellId];
    const int    tetCount = cell.type == CellType::Hexahedron ? 6 : 1;
    for (int t = 0; t < tetCount; ++t)
    {
      // Vertices in continuous index space, where voxel centres are integers.
      Eigen::Matrix<double, 3, 4> corners;
      for (int q = 0; q < 4; ++q)
      {
        const Index node = cell.type == CellType::Hexahedron ? cell.nodes[KuhnTetrahedra[t][q]] : cell.nodes[q];
        corners.col(q) = grid.PointToIndex(model.nodes[node]);
      }
      Eigen::Matrix3d edges;
      edges << corners.col(1) - corners.col(0), corners.col(2) - corners.col(0), corners.col(3) - corners.col(0);
      const Eigen::Matrix3d toBarycentric = edges.inverse();
      const Vector3         lower = corners.rowwise().minCoeff();
      const Vector3         upper = corners.rowwise().maxCoeff();
      // Voxel centres on a cell's face (7 mm cells on 1 mm voxels put many
      // there) must count whatever the image's placement: an image file's
      // geometry in single precision (NIfTI) moves the nodes by 1e-5 voxel
      // 1 m from the origin, and a 1e-9 tolerance let that decide (a
      // registration 0.65 mm different, docs/model-building.md).
      constexpr double      kOnFace = 1e-3; // voxels, in the bounds; barycentric, in the test
      int                   first[3], last[3];
      for (int d = 0; d < 3; ++d)
      {
        first[d] = std::max(0, static_cast<int>(std::ceil(lower[d] - kOnFace)));
        last[d] = std::min(grid.size[d] - 1, static_cast<int>(std::floor(upper[d] + kOnFace)));
      }
      for (int k = first[2]; k <= last[2]; ++k)
      {
        for (int j = first[1]; j <= last[1]; ++j)
        {
          for (int i = first[0]; i <= last[0]; ++i)
          {
            const Vector3 local = toBarycentric * (Vector3(i, j, k) - corners.col(0));
            // Inclusive: a voxel centre on a face shared by two cells counts for the body.
            if (local.minCoeff() >= -kOnFace && local.sum() <= 1.0 + kOnFace)
            {
              std::uint8_t & value = volume.values[grid.Offset(i, j, k)];
#pragma omp atomic write
              value = 1;
            }
          }
        }
      }
    }
  }
  return volume;
}

} // namespace bmr
