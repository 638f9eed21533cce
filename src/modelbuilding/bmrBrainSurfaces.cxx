// Brain and skull surfaces from a mask (VTK's flying edges, decimation and
// orientation checks), and the regions of a model's surface they define:
// exposed (craniotomy sphere or mask), skull base, contact. Over 800 lines:
// the regions are chosen on these surfaces, and one translation unit keeps
// VTK's headers compiled once.
#include "bmrBrainSurfaces.h"
#include "bmrClosestPoint.h"

#include <vtkCellArray.h>
#include <vtkCleanPolyData.h>
#include <vtkFlyingEdges3D.h>
#include <vtkFloatArray.h>
#include <vtkIdList.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataConnectivityFilter.h>
#include <vtkSmartPointer.h>
#include <vtkTriangleFilter.h>
#include <vtkWindowedSincPolyDataFilter.h>

#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Bounded_normal_change_placement.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Edge_length_cost.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Edge_length_stop_predicate.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/LindstromTurk_placement.h>
#include <CGAL/Surface_mesh_simplification/edge_collapse.h>

#include <nanoflann.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iterator>
#include <limits>
#include <sstream>
#include <utility>

namespace bmr
{

namespace
{

ContactSurface
ToContactSurface(vtkPolyData * polyData, const std::string & name)
{
  ContactSurface surface;
  surface.name = name;
  surface.bodySide = ContactSurface::Side::Inside;
  vtkPoints * points = polyData->GetPoints();
  const vtkIdType pointCount = points ? points->GetNumberOfPoints() : 0;
  surface.vertices.resize(static_cast<std::size_t>(pointCount));
  for (vtkIdType p = 0; p < pointCount; ++p)
  {
    double x[3];
    points->GetPoint(p, x);
    surface.vertices[p] = Vector3(x[0], x[1], x[2]);
  }
  vtkCellArray *    polys = polyData->GetPolys();
  vtkNew<vtkIdList> ids;
  polys->InitTraversal();
  while (polys->GetNextCell(ids))
  {
    if (ids->GetNumberOfIds() != 3)
    {
      continue; // the pipeline ends with a triangle filter; nothing else is expected
    }
    const std::array<Index, 3> t{ static_cast<Index>(ids->GetId(0)), static_cast<Index>(ids->GetId(1)),
                                  static_cast<Index>(ids->GetId(2)) };
    if (t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
    {
      surface.triangles.push_back(t);
    }
  }
  return surface;
}

vtkSmartPointer<vtkPolyData>
CleanTriangles(vtkPolyData * input)
{
  vtkNew<vtkTriangleFilter> triangles;
  triangles->SetInputData(input);
  triangles->PassVertsOff();
  triangles->PassLinesOff();
  vtkNew<vtkCleanPolyData> clean;
  clean->SetInputConnection(triangles->GetOutputPort());
  clean->PointMergingOn();
  clean->SetTolerance(0.0);
  clean->ConvertLinesToPointsOff();
  clean->ConvertPolysToLinesOff();
  clean->ConvertStripsToPolysOff();
  clean->Update();
  vtkSmartPointer<vtkPolyData> output = clean->GetOutput();
  return output;
}

void
ValidateSurfaceNodes(const Model & model, const std::vector<Index> & surfaceNodes, const char * function)
{
  if (surfaceNodes.empty())
  {
    throw Error(std::string(function) + ": the list of surface nodes is empty; pass model.BoundaryNodes() or a node set");
  }
  for (const Index node : surfaceNodes)
  {
    if (node < 0 || static_cast<std::size_t>(node) >= model.nodes.size())
    {
      throw Error(std::string(function) + ": surface node id " + std::to_string(node) + " is not a node of the model (" +
                  std::to_string(model.nodes.size()) + " nodes)");
    }
  }
}

std::vector<Index>
SortedUnique(std::vector<Index> ids)
{
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  return ids;
}

// nanoflann adaptor over a list of points (the library's KD-tree is used for
// the nearest-node distance that error messages report).
struct PointCloud
{
  std::vector<Vector3> points;
  std::size_t          kdtree_get_point_count() const { return points.size(); }
  double               kdtree_get_pt(std::size_t i, std::size_t d) const { return points[i][static_cast<int>(d)]; }
  template <class Box>
  bool kdtree_get_bbox(Box &) const
  {
    return false;
  }
};
using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, PointCloud>, PointCloud, 3, std::size_t>;

// Edge-collapse decimation (CGAL Surface_mesh_simplification): collapses the
// shortest edges first while the shortest is below `edgeLength`, placing the
// new vertex by Lindstrom-Turk (volume preserving) unless that flips a
// normal. Collapses obey the link condition, so a closed manifold stays one
// (VTK's quadric decimation does not guarantee that on brain surfaces).
ContactSurface
DecimateToEdgeLength(const ContactSurface & surface, double edgeLength)
{
  using Kernel = CGAL::Simple_cartesian<double>;
  using Mesh = CGAL::Surface_mesh<Kernel::Point_3>;
  namespace SMS = CGAL::Surface_mesh_simplification;
  Mesh                           mesh;
  std::vector<Mesh::Vertex_index> handles;
  handles.reserve(surface.vertices.size());
  for (const auto & v : surface.vertices)
  {
    handles.push_back(mesh.add_vertex(Kernel::Point_3(v.x(), v.y(), v.z())));
  }
  for (const auto & t : surface.triangles)
  {
    if (mesh.add_face(handles[t[0]], handles[t[1]], handles[t[2]]) == Mesh::null_face())
    {
      throw Error("surface '" + surface.name + "' is not a manifold; cannot decimate it");
    }
  }
  const SMS::Edge_length_stop_predicate<double>                                stop(edgeLength);
  const SMS::Edge_length_cost<Mesh>                                            cost;
  const SMS::Bounded_normal_change_placement<SMS::LindstromTurk_placement<Mesh>> placement;
  SMS::edge_collapse(mesh, stop, CGAL::parameters::get_cost(cost).get_placement(placement));
  mesh.collect_garbage();

  ContactSurface decimated;
  decimated.name = surface.name;
  decimated.bodySide = surface.bodySide;
  for (const auto v : mesh.vertices())
  {
    const auto & p = mesh.point(v);
    decimated.vertices.emplace_back(p.x(), p.y(), p.z());
  }
  for (const auto f : mesh.faces())
  {
    std::array<Index, 3> t{};
    int                  k = 0;
    for (const auto v : CGAL::vertices_around_face(mesh.halfedge(f), mesh))
    {
      t[k++] = static_cast<Index>(v.idx());
    }
    decimated.triangles.push_back(t);
  }
  return decimated;
}

} // namespace

bool
IsClosedOrientedSurface(const ContactSurface & surface)
{
  if (surface.triangles.empty())
  {
    return false;
  }
  // Closed and consistently oriented: every directed edge occurs once and so
  // does its reverse. The edges are bucketed by their first vertex (a counting
  // sort), in linear time: two sorts of all the edges took about 0.05 s per
  // Colin27 isosurface of 250,000-350,000 triangles (perf of `register`).
  Index vertexCount = 0;
  for (const auto & t : surface.triangles)
  {
    for (const Index v : t)
    {
      if (v < 0)
      {
        return false;
      }
      vertexCount = std::max(vertexCount, v + 1);
    }
  }
  std::vector<std::size_t> offsets(static_cast<std::size_t>(vertexCount) + 1, 0);
  for (const auto & t : surface.triangles)
  {
    for (const Index v : t)
    {
      ++offsets[static_cast<std::size_t>(v) + 1];
    }
  }
  for (std::size_t v = 1; v < offsets.size(); ++v)
  {
    offsets[v] += offsets[v - 1];
  }
  std::vector<Index>       targets(offsets.back());
  std::vector<std::size_t> next(offsets.begin(), offsets.end() - 1);
  for (const auto & t : surface.triangles)
  {
    for (int k = 0; k < 3; ++k)
    {
      targets[next[static_cast<std::size_t>(t[k])]++] = t[(k + 1) % 3];
    }
  }
  const auto edgesFrom = [&](Index v) {
    return std::make_pair(targets.begin() + static_cast<std::ptrdiff_t>(offsets[static_cast<std::size_t>(v)]),
                          targets.begin() + static_cast<std::ptrdiff_t>(offsets[static_cast<std::size_t>(v) + 1]));
  };
  for (Index v = 0; v < vertexCount; ++v)
  {
    const auto [first, last] = edgesFrom(v);
    std::sort(first, last);
    if (std::adjacent_find(first, last) != last)
    {
      return false;
    }
  }
  for (Index v = 0; v < vertexCount; ++v)
  {
    const auto [first, last] = edgesFrom(v);
    for (auto to = first; to != last; ++to)
    {
      const auto [reverseFirst, reverseLast] = edgesFrom(*to);
      if (!std::binary_search(reverseFirst, reverseLast, v))
      {
        return false;
      }
    }
  }
  return true;
}

double
EnclosedVolume(const ContactSurface & surface)
{
  // Divergence theorem with a reference point at the centroid of the vertices
  // (smaller round-off than the origin for surfaces far from it).
  Vector3 reference = Vector3::Zero();
  for (const auto & v : surface.vertices)
  {
    reference += v;
  }
  if (!surface.vertices.empty())
  {
    reference /= static_cast<double>(surface.vertices.size());
  }
  double sixTimesVolume = 0.0;
  for (const auto & t : surface.triangles)
  {
    const Vector3 a = surface.vertices[t[0]] - reference;
    const Vector3 b = surface.vertices[t[1]] - reference;
    const Vector3 c = surface.vertices[t[2]] - reference;
    sixTimesVolume += a.dot(b.cross(c));
  }
  return sixTimesVolume / 6.0;
}

ContactSurface
DecimateSurface(const ContactSurface & surface, double targetEdgeLength, std::vector<std::string> * warnings)
{
  const double meanEdge = surface.MeanEdgeLength();
  if (!(targetEdgeLength > meanEdge))
  {
    return surface;
  }
  // Collapsing edges up to 2/3 of the target gives a mean edge near the target (measured on spheres).
  ContactSurface decimated = DecimateToEdgeLength(surface, 2.0 / 3.0 * targetEdgeLength);
  if (IsClosedOrientedSurface(decimated))
  {
    decimated.flipNormals = surface.flipNormals;
    decimated.slaveNodeSet = surface.slaveNodeSet;
    return decimated;
  }
  if (warnings)
  {
    warnings->push_back("surface '" + surface.name + "': decimation to a mean edge length of " +
                        std::to_string(targetEdgeLength) + " mm broke the surface's topology; the undecimated surface "
                        "(mean edge " + std::to_string(meanEdge) + " mm) is kept");
  }
  return surface;
}

ContactSurface
ExtractIsosurface(const ScalarVolume &       field,
                  double                     level,
                  const IsosurfaceSettings & settings,
                  std::vector<std::string> * warnings)
{
  const std::string  name = "isosurface '" + settings.name + "' at level " + std::to_string(level);
  const ImageGeometry & geometry = field.geometry;
  if (geometry.VoxelCount() == 0 || field.values.size() != geometry.VoxelCount() * static_cast<std::size_t>(field.components))
  {
    throw Error(name + ": the volume is empty or its values do not match its size (" + geometry.Describe() + ")");
  }
  if (field.components != 1)
  {
    throw Error(name + ": the volume has " + std::to_string(field.components) + " components; give a scalar volume");
  }
  if (!std::isfinite(level) || settings.smoothingIterations < 0 || !(settings.smoothingPassBand > 0.0) ||
      !(settings.targetEdgeLength >= 0.0))
  {
    throw Error(name + ": level must be finite, smoothingIterations >= 0, smoothingPassBand > 0 and targetEdgeLength >= 0");
  }

  // Copy into a volume padded by one voxel of "outside" value, so the level
  // set is closed even where it reaches the border. Values within a tiny
  // fraction of a voxel of the level are pushed outside: marching cubes then
  // never places a vertex exactly on a grid point, which would create
  // degenerate triangles and pinched (non-manifold) vertices.
  const double          minimumSpacing = geometry.spacing.minCoeff();
  const float           nudge = static_cast<float>(level + 1e-4 * minimumSpacing);
  const float           outside = static_cast<float>(level + minimumSpacing);
  const std::array<int, 3> padded{ geometry.size[0] + 2, geometry.size[1] + 2, geometry.size[2] + 2 };
  vtkNew<vtkImageData>  image;
  image->SetDimensions(padded[0], padded[1], padded[2]);
  image->SetSpacing(1.0, 1.0, 1.0);
  image->SetOrigin(-1.0, -1.0, -1.0); // index space of the unpadded volume
  image->AllocateScalars(VTK_FLOAT, 1);
  auto *      buffer = static_cast<float *>(image->GetScalarPointer());
  std::size_t insideCount = 0;
  for (int k = 0; k < padded[2]; ++k)
  {
    for (int j = 0; j < padded[1]; ++j)
    {
      for (int i = 0; i < padded[0]; ++i)
      {
        float value = outside;
        if (i > 0 && j > 0 && k > 0 && i <= geometry.size[0] && j <= geometry.size[1] && k <= geometry.size[2])
        {
          value = field.At(i - 1, j - 1, k - 1);
          if (!std::isfinite(value))
          {
            throw Error(name + ": voxel (" + std::to_string(i - 1) + ", " + std::to_string(j - 1) + ", " +
                        std::to_string(k - 1) + ") is not a finite number; fix the input volume");
          }
          if (std::abs(static_cast<double>(value) - level) < 1e-4 * minimumSpacing)
          {
            value = nudge;
          }
          insideCount += value < level ? 1 : 0;
        }
        buffer[static_cast<std::size_t>(i) +
               static_cast<std::size_t>(padded[0]) * (static_cast<std::size_t>(j) + static_cast<std::size_t>(padded[1]) * k)] =
          value;
      }
    }
  }
  if (insideCount == 0)
  {
    throw Error(name + ": no voxel of the volume (" + geometry.Describe() +
                ") lies below the level, so the level set encloses nothing; check the mask or the level");
  }

  vtkNew<vtkFlyingEdges3D> contour;
  contour->SetInputData(image);
  contour->SetValue(0, level);
  contour->ComputeNormalsOff();
  contour->ComputeGradientsOff();
  contour->ComputeScalarsOff();
  contour->InterpolateAttributesOff();

  vtkNew<vtkPolyDataConnectivityFilter> connectivity;
  connectivity->SetInputConnection(contour->GetOutputPort());
  if (settings.keepLargestComponent)
  {
    connectivity->SetExtractionModeToLargestRegion();
  }
  else
  {
    connectivity->SetExtractionModeToAllRegions();
  }
  connectivity->Update();
  const int regions = connectivity->GetNumberOfExtractedRegions();
  if (settings.keepLargestComponent && regions > 1 && warnings)
  {
    warnings->push_back(name + ": the level set has " + std::to_string(regions) +
                        " connected components; only the largest is kept");
  }

  // Index space -> physical space (spacing, direction cosines, origin), before
  // smoothing and decimation, so both see true lengths.
  vtkSmartPointer<vtkPolyData> surfaceData = CleanTriangles(connectivity->GetOutput());
  {
    vtkPoints *     indexPoints = surfaceData->GetPoints();
    vtkNew<vtkPoints> physicalPoints;
    physicalPoints->SetDataTypeToDouble(); // marching cubes gives float points; keep full precision from here on
    physicalPoints->SetNumberOfPoints(indexPoints->GetNumberOfPoints());
    for (vtkIdType p = 0; p < indexPoints->GetNumberOfPoints(); ++p)
    {
      double x[3];
      indexPoints->GetPoint(p, x);
      const Vector3 physical = geometry.IndexToPoint(Vector3(x[0], x[1], x[2]));
      physicalPoints->SetPoint(p, physical.data());
    }
    surfaceData->SetPoints(physicalPoints);
  }

  if (settings.smoothingIterations > 0)
  {
    vtkNew<vtkWindowedSincPolyDataFilter> smoother;
    smoother->SetInputData(surfaceData);
    smoother->SetNumberOfIterations(settings.smoothingIterations);
    smoother->SetPassBand(settings.smoothingPassBand);
    smoother->BoundarySmoothingOff();
    smoother->FeatureEdgeSmoothingOff();
    smoother->NonManifoldSmoothingOn();
    smoother->NormalizeCoordinatesOn();
    smoother->Update();
    surfaceData = vtkSmartPointer<vtkPolyData>::New();
    surfaceData->ShallowCopy(smoother->GetOutput());
  }

  ContactSurface surface = ToContactSurface(surfaceData, settings.name);
  if (!IsClosedOrientedSurface(surface))
  {
    throw Error(name + ": marching cubes gave a surface that is not closed and manifold (" +
                std::to_string(surface.triangles.size()) + " triangles); smooth the volume or change the level");
  }

  if (EnclosedVolume(surface) < 0.0)
  {
    for (auto & t : surface.triangles)
    {
      std::swap(t[1], t[2]);
    }
  }
  if (settings.targetEdgeLength > 0.0)
  {
    surface = DecimateSurface(surface, settings.targetEdgeLength, warnings);
  }
  return surface;
}

BrainSurfaces
ExtractBrainSurfaces(const ScalarVolume &         signedDistance,
                     const BrainSurfaceSettings & settings,
                     std::vector<std::string> *   warnings)
{
  if (!std::isfinite(settings.skullGap) || settings.skullGap < 0.0)
  {
    throw Error("brain surfaces: skullGap " + std::to_string(settings.skullGap) +
                " mm must be a finite number >= 0 (default 1.5 mm, the CSF layer)");
  }
  if (!std::isfinite(settings.skullClosing) || settings.skullClosing < 0.0)
  {
    throw Error("brain surfaces: skullClosing " + std::to_string(settings.skullClosing) +
                " mm must be a finite number >= 0 (0: no closing)");
  }
  BrainSurfaces      surfaces;
  // The skull is refined against the undecimated brain; both are decimated at the end.
  IsosurfaceSettings brainSettings = settings.isosurface;
  brainSettings.name = "brain";
  brainSettings.targetEdgeLength = 0.0;
  surfaces.brain = ExtractIsosurface(signedDistance, 0.0, brainSettings, warnings);
  brainSettings.targetEdgeLength = settings.isosurface.targetEdgeLength;
  if (!settings.skull)
  {
    surfaces.brain = DecimateSurface(surfaces.brain, brainSettings.targetEdgeLength, warnings);
    return surfaces;
  }
  IsosurfaceSettings skullSettings = settings.isosurface;
  skullSettings.name = "skull";

  // A distance map of a mask measures to voxel centres: on oblique parts of the
  // staircase it is biased by up to ~0.4 voxel a few voxels away from the
  // boundary. The skull is an offset of the brain, so outside voxels in a band
  // around the level skullGap get their exact distance to the (smoothed)
  // brain surface; farther voxels keep their values, which are farther than
  // the level either way.
  ScalarVolume          skullField = signedDistance;
  const ImageGeometry & geometry = signedDistance.geometry;
  const double          margin = 2.0 * geometry.spacing.maxCoeff();
  const double          dilation = settings.skullGap + settings.skullClosing;
  const TriangleSurfaceTree brain(surfaces.brain.vertices, surfaces.brain.triangles, "isosurface 'brain' at level 0");
  // Exact distances to `tree` for the voxels whose field value lies in
  // (low, high]; `sign` -1 gives negative distances (inside).
  const auto exactDistances = [&](ScalarVolume & field, const TriangleSurfaceTree & tree, double low, double high,
                                  float sign) {
    const auto slices = geometry.size[2];
#pragma omp parallel for schedule(dynamic, 1)
    for (int k = 0; k < slices; ++k)
    {
      // A query whose neighbour in the row (i - 1) was queried starts from
      // that neighbour's closest point: its distance bounds the search from
      // the start (Colin27's skull band in `register`, 2 threads: about
      // 0.51 -> 0.44 s; from the row's last query wherever it was, often
      // across the brain: 1.34 s).
      for (int j = 0; j < geometry.size[1]; ++j)
      {
        TriangleSurfaceTree::Hit last{ Vector3::Zero(), -1, 0.0 };
        int                      lastI = -2;
        for (int i = 0; i < geometry.size[0]; ++i)
        {
          float & value = field.At(i, j, k);
          if (value > low && value <= high)
          {
            const Vector3 query = geometry.IndexToPoint(Vector3(i, j, k));
            last = lastI == i - 1 ? tree.Closest(query, last) : tree.Closest(query);
            lastI = i;
            value = sign * static_cast<float>(std::sqrt(last.squaredDistance));
          }
        }
      }
    }
  };
  exactDistances(skullField, brain, 0.0, dilation + margin, 1.0f);
  if (settings.skullClosing > 0.0)
  {
    // Closing = dilation by gap + r, then erosion by r: the level -r of the
    // signed distance to the dilated surface. Voxels nearer the brain than
    // gap - margin are more than r + margin inside it; they keep a value
    // below the level.
    IsosurfaceSettings dilatedSettings = skullSettings;
    dilatedSettings.name = "dilated brain";
    dilatedSettings.targetEdgeLength = 0.0;
    const ContactSurface      dilated = ExtractIsosurface(skullField, dilation, dilatedSettings, warnings);
    const TriangleSurfaceTree dilatedTree(dilated.vertices, dilated.triangles, "isosurface 'dilated brain'");
    ScalarVolume              closed = skullField;
    for (float & value : closed.values)
    {
      value = value <= settings.skullGap - margin ? static_cast<float>(-(settings.skullClosing + margin))
                                                  : static_cast<float>(value - dilation);
    }
    exactDistances(closed, dilatedTree, -(settings.skullClosing + margin), 0.0, -1.0f);
    surfaces.skull = ExtractIsosurface(closed, -settings.skullClosing, skullSettings, warnings);
  }
  else
  {
    surfaces.skull = ExtractIsosurface(skullField, settings.skullGap, skullSettings, warnings);
  }
  surfaces.brain = DecimateSurface(surfaces.brain, brainSettings.targetEdgeLength, warnings);
  surfaces.skull.bodySide = ContactSurface::Side::Inside;
  return surfaces;
}

std::vector<Index>
SurfaceNodesInSphere(const Model & model, const std::vector<Index> & surfaceNodes, const Vector3 & centre, double radius)
{
  ValidateSurfaceNodes(model, surfaceNodes, "SurfaceNodesInSphere");
  if (!centre.allFinite() || !std::isfinite(radius) || !(radius > 0.0))
  {
    throw Error("region sphere (centre " + FormatPoint(centre) + " mm, radius " + std::to_string(radius) +
                " mm): the centre must be finite and the radius positive");
  }
  std::vector<Index> selected;
  double             nearest = std::numeric_limits<double>::infinity();
  for (const Index node : surfaceNodes)
  {
    const double distance = (model.nodes[node] - centre).norm();
    nearest = std::min(nearest, distance);
    if (distance <= radius)
    {
      selected.push_back(node);
    }
  }
  if (selected.empty())
  {
    std::ostringstream message;
    message << "region sphere (centre " << FormatPoint(centre) << " mm, radius " << radius
            << " mm) selects no surface node: the nearest surface node is " << nearest
            << " mm from its centre. Move the centre onto the brain surface or use a radius of at least "
            << std::ceil(nearest + 1.0) << " mm";
    throw Error(message.str());
  }
  return SortedUnique(std::move(selected));
}

std::vector<Index>
SurfaceNodesInMask(const Model &              model,
                   const std::vector<Index> & surfaceNodes,
                   const LabelVolume &        regionMask,
                   double                     tolerance)
{
  ValidateSurfaceNodes(model, surfaceNodes, "SurfaceNodesInMask");
  const ImageGeometry & geometry = regionMask.geometry;
  if (regionMask.components != 1 || regionMask.values.size() != geometry.VoxelCount() || geometry.VoxelCount() == 0)
  {
    throw Error("region mask (" + geometry.Describe() + "): the mask must be a non-empty scalar label volume");
  }
  if (tolerance < 0.0)
  {
    tolerance = geometry.spacing.norm();
  }
  if (!std::isfinite(tolerance))
  {
    throw Error("region mask: tolerance must be a finite number of mm");
  }
  if (std::none_of(regionMask.values.begin(), regionMask.values.end(), [](std::uint8_t v) { return v != 0; }))
  {
    throw Error("region mask (" + geometry.Describe() + ") has no non-zero voxel; draw the region on the mask");
  }

  std::vector<Index> selected;
  for (const Index node : surfaceNodes)
  {
    const Vector3 & x = model.nodes[node];
    const Vector3   index = geometry.PointToIndex(x);
    // Direction cosines are orthonormal: the tolerance ball spans tolerance / spacing voxels along each index axis.
    std::array<int, 3> lower{}, upper{};
    for (int d = 0; d < 3; ++d)
    {
      const double reach = tolerance / geometry.spacing[d];
      lower[d] = std::max(0, static_cast<int>(std::ceil(index[d] - reach - 1e-9)));
      upper[d] = std::min(geometry.size[d] - 1, static_cast<int>(std::floor(index[d] + reach + 1e-9)));
    }
    bool found = false;
    for (int k = lower[2]; k <= upper[2] && !found; ++k)
    {
      for (int j = lower[1]; j <= upper[1] && !found; ++j)
      {
        for (int i = lower[0]; i <= upper[0] && !found; ++i)
        {
          if (regionMask.At(i, j, k) != 0 && (geometry.IndexToPoint(Vector3(i, j, k)) - x).norm() <= tolerance)
          {
            found = true;
          }
        }
      }
    }
    if (found)
    {
      selected.push_back(node);
    }
  }
  if (selected.empty())
  {
    PointCloud cloud;
    for (const Index node : surfaceNodes)
    {
      cloud.points.push_back(model.nodes[node]);
    }
    KdTree tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    tree.buildIndex();
    double nearest = std::numeric_limits<double>::infinity();
    for (int k = 0; k < geometry.size[2]; ++k)
    {
      for (int j = 0; j < geometry.size[1]; ++j)
      {
        for (int i = 0; i < geometry.size[0]; ++i)
        {
          if (regionMask.At(i, j, k) != 0)
          {
            const Vector3 p = geometry.IndexToPoint(Vector3(i, j, k));
            std::size_t   id = 0;
            double        squared = 0.0;
            tree.knnSearch(p.data(), 1, &id, &squared);
            nearest = std::min(nearest, std::sqrt(squared));
          }
        }
      }
    }
    std::ostringstream message;
    message << "region mask (" << geometry.Describe() << ") selects no surface node within the tolerance of "
            << tolerance << " mm: the nearest surface node is " << nearest
            << " mm from a mask voxel. Check that the mask is on the same image as the model, or raise the tolerance to at least "
            << std::ceil(nearest + 0.5) << " mm";
    throw Error(message.str());
  }
  return SortedUnique(std::move(selected));
}

void
CheckCraniotomyChoice(double radius, bool maskGiven)
{
  if (radius > 0.0 && maskGiven)
  {
    throw Error("give the craniotomy either as a sphere (centre, radius) or as a mask, not both");
  }
  if (!(radius > 0.0) && !maskGiven)
  {
    throw Error("no craniotomy region: give its centre and radius (> 0 mm) or a craniotomy mask");
  }
}

void
CheckCraniotomyRegion(const CraniotomyRegion & region)
{
  CheckCraniotomyChoice(region.radius, region.mask != nullptr);
}

std::vector<Index>
ExposedSurfaceNodes(const Model & model, const std::vector<Index> & surfaceNodes, const CraniotomyRegion & region)
{
  CheckCraniotomyRegion(region);
  return region.mask != nullptr ? SurfaceNodesInMask(model, surfaceNodes, *region.mask)
                                : SurfaceNodesInSphere(model, surfaceNodes, region.centre, region.radius);
}

std::size_t
SetBrainRegions(Model & model, const std::vector<Index> & surfaceNodes, const BrainRegionSettings & settings)
{
  std::vector<Index> fixed = SkullBaseNodes(model, surfaceNodes, settings.skullBase);
  std::vector<Index> exposed;
  std::size_t        fixedNodesExposed = 0;
  if (settings.craniotomy.Given())
  {
    exposed = ExposedSurfaceNodes(model, surfaceNodes, settings.craniotomy);
    // The opening takes precedence: a craniotomy low on the head (suboccipital,
    // low temporal) reaches into the default fixed band, and a node both fixed
    // and loaded would be two constraints on one degree of freedom.
    const std::size_t before = fixed.size();
    std::vector<Index> kept;
    std::set_difference(fixed.begin(), fixed.end(), exposed.begin(), exposed.end(), std::back_inserter(kept));
    fixed = std::move(kept);
    fixedNodesExposed = before - fixed.size();
  }
  std::vector<Index> contact;
  if (settings.contact)
  {
    std::vector<char> constrained(model.nodes.size(), 0);
    for (const auto * set : { &fixed, &exposed })
    {
      for (const Index node : *set)
      {
        constrained[static_cast<std::size_t>(node)] = 1;
      }
    }
    for (const Index node : surfaceNodes)
    {
      if (!constrained[static_cast<std::size_t>(node)])
      {
        contact.push_back(node);
      }
    }
  }
  model.nodeSets["skull_base"] = std::move(fixed);
  model.fixedConstraints = { FixedConstraint{ "skull_base", { true, true, true } } };
  model.nodeSets.erase("exposed");
  if (settings.craniotomy.Given())
  {
    model.nodeSets["exposed"] = std::move(exposed);
  }
  model.nodeSets.erase("contact");
  if (settings.contact)
  {
    model.nodeSets["contact"] = std::move(contact);
  }
  return fixedNodesExposed;
}

void
CheckBrainRegionsOnMask(const LabelVolume &       brainMask,
                        const CraniotomyRegion &  craniotomy,
                        const SkullBaseSettings & skullBase,
                        const std::string &       craniotomyOption,
                        const std::string &       heightOption)
{
  // Only a sphere can be checked here; a craniotomy mask's own check needs the model's nodes.
  if (!(craniotomy.radius > 0.0) || craniotomy.mask != nullptr)
  {
    return;
  }
  const ImageGeometry & geometry = brainMask.geometry;
  const auto inside = [&](int i, int j, int k) {
    return i >= 0 && j >= 0 && k >= 0 && i < geometry.size[0] && j < geometry.size[1] && k < geometry.size[2] &&
           brainMask.At(i, j, k) != 0;
  };
  const bool    band = skullBase.sphereRadius <= 0.0 && skullBase.mask == nullptr && skullBase.superior.norm() > 0.0;
  const Vector3 up = band ? Vector3(skullBase.superior.normalized()) : Vector3::UnitZ();
  std::vector<Vector3> surface;
  double               lowest = std::numeric_limits<double>::infinity();
  for (int k = 0; k < geometry.size[2]; ++k)
  {
    for (int j = 0; j < geometry.size[1]; ++j)
    {
      for (int i = 0; i < geometry.size[0]; ++i)
      {
        if (inside(i, j, k) && !(inside(i - 1, j, k) && inside(i + 1, j, k) && inside(i, j - 1, k) &&
                                 inside(i, j + 1, k) && inside(i, j, k - 1) && inside(i, j, k + 1)))
        {
          surface.push_back(geometry.IndexToPoint(Vector3(i, j, k)));
          lowest = std::min(lowest, surface.back().dot(up));
        }
      }
    }
  }
  if (surface.empty())
  {
    throw Error("the brain mask (" + geometry.Describe() + ") is empty: give a mask with the brain's voxels > 0");
  }
  double      nearest = std::numeric_limits<double>::infinity();
  std::size_t bandVoxels = 0, bandVoxelsOpen = 0;
  for (const Vector3 & point : surface)
  {
    const double distance = (point - craniotomy.centre).norm();
    nearest = std::min(nearest, distance);
    if (band && point.dot(up) <= lowest + skullBase.height)
    {
      ++bandVoxels;
      bandVoxelsOpen += distance <= craniotomy.radius ? 1 : 0;
    }
  }
  std::ostringstream message;
  if (nearest > craniotomy.radius)
  {
    message << "the craniotomy (centre " << FormatPoint(craniotomy.centre) << " mm, radius " << craniotomy.radius
            << " mm) does not reach the brain's surface: the nearest surface voxel of the brain mask is " << nearest
            << " mm from its centre. Move the centre onto the exposed brain surface, or raise " << craniotomyOption
            << " to at least " << std::ceil(nearest + 1.0) << " mm";
    throw Error(message.str());
  }
  if (bandVoxels > 0 && bandVoxelsOpen == bandVoxels)
  {
    message << "the craniotomy (centre " << FormatPoint(craniotomy.centre) << " mm, radius " << craniotomy.radius
            << " mm) covers the whole fixed band at the skull base (the brain's surface within " << skullBase.height
            << " mm of its lowest point), so nothing would hold the brain stem: make the craniotomy smaller ("
            << craniotomyOption << ") or raise " << heightOption << " so that the band reaches beyond the opening";
    throw Error(message.str());
  }
}

std::vector<Index>
SkullBaseNodes(const Model & model, const std::vector<Index> & surfaceNodes, const SkullBaseSettings & settings)
{
  ValidateSurfaceNodes(model, surfaceNodes, "SkullBaseNodes");
  if (settings.sphereRadius > 0.0)
  {
    return SurfaceNodesInSphere(model, surfaceNodes, settings.sphereCentre, settings.sphereRadius);
  }
  if (settings.mask)
  {
    return SurfaceNodesInMask(model, surfaceNodes, *settings.mask, settings.maskTolerance);
  }
  if (!std::isfinite(settings.height) || settings.height < 0.0)
  {
    throw Error("skull base region: height " + std::to_string(settings.height) + " mm must be a finite number >= 0");
  }
  const double length = settings.superior.norm();
  if (!(length > 0.0) || !std::isfinite(length))
  {
    throw Error("skull base region: the superior direction " + FormatPoint(settings.superior) + " must be a non-zero vector");
  }
  const Vector3 up = settings.superior / length;
  double        lowest = std::numeric_limits<double>::infinity();
  for (const Index node : surfaceNodes)
  {
    lowest = std::min(lowest, model.nodes[node].dot(up));
  }
  std::vector<Index> selected;
  for (const Index node : surfaceNodes)
  {
    if (model.nodes[node].dot(up) <= lowest + settings.height)
    {
      selected.push_back(node);
    }
  }
  return SortedUnique(std::move(selected));
}

} // namespace bmr
