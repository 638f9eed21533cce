// Surfaces and boundary regions (brain / skull surfaces of a mask, craniotomy
// and skull-base regions) and loads from intraoperative measurements
// (closest-point correspondence, thin-plate interpolation of sparse
// displacements, CSV reader). Units: mm.
// Over 800 lines: surfaces and the loads made from them share their
// synthetic brains and skulls.
#include "bmrBrainSurfaces.h"
#include "bmrClosestPoint.h"
#include "bmrContact.h"
#include "bmrMeshGenerators.h"
#include "bmrSurfaceLoads.h"
#include "bmrTemporaryFolderTest.h"

#include "itkBrainSurfaceMeshSource.h"
#include "itkImage.h"
#include "itkImageRegionIteratorWithIndex.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <sstream>

namespace
{

using bmr::Index;
using bmr::Vector3;
using MaskImage = itk::Image<unsigned char, 3>;
using SurfaceSource = itk::BrainSurfaceMeshSource<MaskImage>;

constexpr double kPi = 3.14159265358979323846;

// A mask image whose voxel centres x (physical) with inside(x) are 1.
MaskImage::Pointer
MakeMask(const std::array<int, 3> & size, const Vector3 & origin, const Eigen::Matrix3d & direction,
         const std::function<bool(const Vector3 &)> & inside, double spacing = 1.0)
{
  auto                  image = MaskImage::New();
  MaskImage::RegionType region;
  MaskImage::SpacingType itkSpacing;
  MaskImage::PointType  itkOrigin;
  MaskImage::DirectionType itkDirection;
  for (unsigned int d = 0; d < 3; ++d)
  {
    region.SetSize(d, size[d]);
    itkSpacing[d] = spacing;
    itkOrigin[d] = origin[d];
    for (unsigned int e = 0; e < 3; ++e)
    {
      itkDirection[d][e] = direction(d, e);
    }
  }
  image->SetRegions(region);
  image->SetSpacing(itkSpacing);
  image->SetOrigin(itkOrigin);
  image->SetDirection(itkDirection);
  image->Allocate(true);
  for (itk::ImageRegionIteratorWithIndex<MaskImage> it(image, region); !it.IsAtEnd(); ++it)
  {
    MaskImage::PointType p;
    image->TransformIndexToPhysicalPoint(it.GetIndex(), p);
    it.Set(inside(Vector3(p[0], p[1], p[2])) ? 1 : 0);
  }
  return image;
}

SurfaceSource::Pointer
RunSource(const MaskImage * mask, double gap, double closing = bmr::BrainSurfaceSettings{}.skullClosing)
{
  auto source = SurfaceSource::New();
  source->SetInput(mask);
  source->SetSkullGap(gap);
  source->SetSkullClosing(closing);
  source->Update();
  return source;
}

void
ExpectRadiiWithin(const bmr::ContactSurface & surface, const Vector3 & centre, double radius, double tolerance)
{
  double lowest = 1e300, highest = -1e300;
  for (const auto & v : surface.vertices)
  {
    const double r = (v - centre).norm();
    lowest = std::min(lowest, r);
    highest = std::max(highest, r);
  }
  EXPECT_GT(lowest, radius - tolerance) << surface.name;
  EXPECT_LT(highest, radius + tolerance) << surface.name;
}

// Independent closest point on a triangle (Ericson, Real-Time Collision Detection, 5.1.5).
Vector3
ClosestOnTriangle(const Vector3 & p, const Vector3 & a, const Vector3 & b, const Vector3 & c)
{
  const Vector3 ab = b - a, ac = c - a, ap = p - a;
  const double  d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0)
    return a;
  const Vector3 bp = p - b;
  const double  d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3)
    return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0)
    return a + d1 / (d1 - d3) * ab;
  const Vector3 cp = p - c;
  const double  d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6)
    return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0)
    return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  const double denominator = 1.0 / (va + vb + vc);
  return a + ab * (vb * denominator) + ac * (vc * denominator);
}

double
BruteForceDistance(const Vector3 & p, const bmr::ContactSurface & surface)
{
  double best = 1e300;
  for (const auto & t : surface.triangles)
  {
    best = std::min(best, (p - ClosestOnTriangle(p, surface.vertices[t[0]], surface.vertices[t[1]], surface.vertices[t[2]])).norm());
  }
  return best;
}

// A small brain-like ellipsoid grid mesh (5 mm hexahedra) for region and load tests.
const bmr::Model &
EllipsoidModel()
{
  static const bmr::Model model =
    bmr::MakeEllipsoidMesh(Vector3(40.0, 50.0, 35.0), 5.0, bmr::GridCells::Hexahedra);
  return model;
}

// A square plane patch [x0, x1] x [y0, y1] at height z, two triangles, normal +z.
bmr::ContactSurface
PlanePatch(double x0, double x1, double y0, double y1, double z)
{
  bmr::ContactSurface surface;
  surface.name = "plane";
  surface.vertices = { Vector3(x0, y0, z), Vector3(x1, y0, z), Vector3(x1, y1, z), Vector3(x0, y1, z) };
  surface.triangles = { { 0, 1, 2 }, { 0, 2, 3 } };
  return surface;
}

} // namespace

// ---------------------------------------------------------------------------
// Surfaces
// ---------------------------------------------------------------------------

TEST(BrainSurface, ClosedOrientedSurfaceCheckRefusesOpenFlippedAndRepeatedTriangles)
{
  // A tetrahedron's boundary, every face outward: closed and oriented.
  bmr::ContactSurface tetrahedron;
  tetrahedron.vertices = { Vector3(0, 0, 0), Vector3(1, 0, 0), Vector3(0, 1, 0), Vector3(0, 0, 1) };
  tetrahedron.triangles = { { 0, 2, 1 }, { 0, 1, 3 }, { 0, 3, 2 }, { 1, 2, 3 } };
  ASSERT_TRUE(bmr::IsClosedOrientedSurface(tetrahedron));
  EXPECT_GT(bmr::EnclosedVolume(tetrahedron), 0.0);

  bmr::ContactSurface open = tetrahedron;
  open.triangles.pop_back();
  EXPECT_FALSE(bmr::IsClosedOrientedSurface(open));

  bmr::ContactSurface flipped = tetrahedron;
  std::swap(flipped.triangles[3][1], flipped.triangles[3][2]);
  EXPECT_FALSE(bmr::IsClosedOrientedSurface(flipped));

  // A face twice (e.g. two triangles glued onto one): its edges occur twice.
  bmr::ContactSurface repeated = tetrahedron;
  repeated.triangles.push_back(repeated.triangles[0]);
  EXPECT_FALSE(bmr::IsClosedOrientedSurface(repeated));

  // The check is on edges: two tetrahedra sharing only a vertex pass it.
  bmr::ContactSurface pinched = tetrahedron;
  pinched.vertices.insert(pinched.vertices.end(), { Vector3(-1, 0, 0), Vector3(0, -1, 0), Vector3(0, 0, -1) });
  pinched.triangles.insert(pinched.triangles.end(), { { 0, 4, 5 }, { 0, 6, 4 }, { 0, 5, 6 }, { 4, 6, 5 } });
  EXPECT_TRUE(bmr::IsClosedOrientedSurface(pinched));

  // A degenerate triangle's edge from a vertex to itself is its own reverse,
  // but its other two edges are not matched.
  bmr::ContactSurface degenerate = tetrahedron;
  degenerate.triangles.push_back({ 1, 1, 2 });
  EXPECT_FALSE(bmr::IsClosedOrientedSurface(degenerate));

  bmr::ContactSurface negative = tetrahedron;
  negative.triangles[0][0] = -1;
  EXPECT_FALSE(bmr::IsClosedOrientedSurface(negative));

  EXPECT_FALSE(bmr::IsClosedOrientedSurface(bmr::ContactSurface{}));
}

TEST(BrainSurface, SphereMaskGivesClosedSphereAndSkullAtGap)
{
  const double radius = 30.0, gap = 2.0;
  const Vector3 centre(0.3, -0.2, 0.1); // off the voxel grid, so the mask is not symmetric
  const auto   mask = MakeMask({ 72, 72, 72 }, Vector3::Constant(-35.5), Eigen::Matrix3d::Identity(),
                             [&](const Vector3 & x) { return (x - centre).norm() <= radius; });
  const auto   source = RunSource(mask, gap);
  const auto & brain = source->GetBrainSurface();
  const auto & skull = source->GetSkullSurface();

  ASSERT_TRUE(bmr::IsClosedOrientedSurface(brain));
  ASSERT_TRUE(bmr::IsClosedOrientedSurface(skull));
  const double exact = 4.0 / 3.0 * kPi * radius * radius * radius;
  EXPECT_GT(bmr::EnclosedVolume(brain), 0.0); // outward normals
  EXPECT_NEAR(bmr::EnclosedVolume(brain), exact, 0.015 * exact);
  ExpectRadiiWithin(brain, centre, radius, 0.5);
  ExpectRadiiWithin(skull, centre, radius + gap, 0.5);
  EXPECT_EQ(skull.bodySide, bmr::ContactSurface::Side::Inside);

  // Every triangle's normal points away from the centre.
  for (const auto & t : brain.triangles)
  {
    const Vector3 normal = (brain.vertices[t[1]] - brain.vertices[t[0]]).cross(brain.vertices[t[2]] - brain.vertices[t[0]]);
    ASSERT_GT(normal.dot(brain.vertices[t[0]] - centre), 0.0);
  }
}

TEST(BrainSurface, SkullClosingBridgesAFissureAndKeepsTheGapElsewhere)
{
  // A ball with a fissure: the slab |x| < 3 mm cut from its upper half. The
  // skull at gap 1.5 mm follows the 6 mm fissure as a 3 mm thick blade; a
  // closing of radius 3 mm (bridging folds narrower than 2 (3 + 1.5) mm)
  // keeps it above the fissure, and leaves it at the gap where the ball is
  // convex.
  const double radius = 25.0, gap = 1.5, halfWidth = 3.0, closing = 3.0;
  const auto   mask = MakeMask({ 64, 64, 64 }, Vector3::Constant(-31.5), Eigen::Matrix3d::Identity(), [&](const Vector3 & x) {
    return x.norm() <= radius && !(x.z() > 0.0 && std::abs(x.x()) < halfWidth);
  });
  // No closing: the default 1 mm, nominally bridging folds narrower than 5 mm,
  // bridges this 6 mm one too on 1 mm voxels.
  const auto open = RunSource(mask, gap, 0.0);
  const auto closed = RunSource(mask, gap, closing);
  const bmr::ContactSurface & blade = open->GetSkullSurface();
  const bmr::ContactSurface & bridged = closed->GetSkullSurface();
  ASSERT_TRUE(bmr::IsClosedOrientedSurface(bridged));
  EXPECT_EQ(bridged.bodySide, bmr::ContactSurface::Side::Inside);

  // In the fissure, 15 mm up: the blade's faces stand 1.5 mm off; the bridged
  // skull is near the ball's top, about 10 mm away.
  const Vector3 inFissure(0.0, 0.0, 15.0);
  EXPECT_LT(BruteForceDistance(inFissure, blade), 2.0);
  EXPECT_GT(BruteForceDistance(inFissure, bridged), 8.0);
  EXPECT_GT(bmr::EnclosedVolume(bridged), bmr::EnclosedVolume(blade));
  // The lower, convex half: the skull at the gap, with or without closing.
  bmr::ContactSurface lower;
  for (const Vector3 & v : bridged.vertices)
  {
    if (v.z() < -5.0)
    {
      lower.vertices.push_back(v);
    }
  }
  ASSERT_GT(lower.vertices.size(), 100u);
  ExpectRadiiWithin(lower, Vector3::Zero(), radius + gap, 0.5);

  closed->SetSkullClosing(-1.0);
  EXPECT_THROW(closed->Update(), itk::ExceptionObject);
}

TEST(BrainSurface, HintedClosestPointsAreTheClosestWhateverTheHint)
{
  // The skull's exact distances start each query from the last one's hit.
  // On a fissured ball (a fold where the closest triangle jumps between the
  // walls), every hint, near or far or invalid, must give the brute-force
  // distance.
  const double radius = 20.0, halfWidth = 2.5;
  const auto   mask = MakeMask({ 52, 52, 52 }, Vector3::Constant(-25.5), Eigen::Matrix3d::Identity(), [&](const Vector3 & x) {
    return x.norm() <= radius && !(x.z() > 0.0 && std::abs(x.x()) < halfWidth);
  });
  const bmr::ContactSurface        surface = RunSource(mask, 1.5)->GetBrainSurface();
  const bmr::TriangleSurfaceTree   tree(surface.vertices, surface.triangles, "fissured ball");
  std::mt19937                     random(7);
  std::uniform_real_distribution<> coordinate(-radius - 4.0, radius + 4.0);
  const bmr::TriangleSurfaceTree::Hit far = tree.Closest(Vector3(0.0, 0.0, -radius - 3.0));
  int                                 checked = 0;
  for (int q = 0; q < 400; ++q)
  {
    const Vector3 query(coordinate(random), coordinate(random), coordinate(random));
    const double  expected = BruteForceDistance(query, surface);
    const auto    near = tree.Closest(query + Vector3(0.7, -0.4, 0.3));
    for (const bmr::TriangleSurfaceTree::Hit & hint :
         { near, far, bmr::TriangleSurfaceTree::Hit{ query, -1, 0.0 },
           bmr::TriangleSurfaceTree::Hit{ query, static_cast<Index>(surface.triangles.size()), 0.0 } })
    {
      const auto hit = tree.Closest(query, hint);
      ASSERT_NEAR(std::sqrt(hit.squaredDistance), expected, 1e-9) << "query " << query.transpose();
      ASSERT_NEAR((hit.point - query).norm(), expected, 1e-9);
      ++checked;
    }
  }
  EXPECT_EQ(checked, 1600);
}

TEST(BrainSurface, CandidateTrianglesHoldTheClosestPointOfEveryQueryNearThem)
{
  // Contact keeps, per slave, the triangles within d + 2 r of where it was
  // last searched (d: its distance there) and finds the closest point among
  // them while it stays within r. On the fissured ball (the closest triangle
  // jumps between the walls of the fold) every such query must give the
  // brute-force distance, and the candidates must be exactly the triangles
  // within the radius.
  const double radius = 20.0, halfWidth = 2.5, reach = 0.4;
  const auto   mask = MakeMask({ 52, 52, 52 }, Vector3::Constant(-25.5), Eigen::Matrix3d::Identity(), [&](const Vector3 & x) {
    return x.norm() <= radius && !(x.z() > 0.0 && std::abs(x.x()) < halfWidth);
  });
  const bmr::ContactSurface        surface = RunSource(mask, 1.5)->GetBrainSurface();
  const bmr::TriangleSurfaceTree   tree(surface.vertices, surface.triangles, "fissured ball");
  std::mt19937                     random(11);
  std::uniform_real_distribution<> coordinate(-radius - 4.0, radius + 4.0), unit(-1.0, 1.0);
  int                              checked = 0;
  for (int c = 0; c < 100; ++c)
  {
    // Centres near the surface and in the fissure, where contact searches.
    const Vector3 centre = c % 2 == 0 ? Vector3(coordinate(random), coordinate(random), coordinate(random))
                                      : Vector3(unit(random) * halfWidth, 8.0 * unit(random), radius * (0.3 + 0.5 * std::abs(unit(random))));
    const double  within = BruteForceDistance(centre, surface) + 2.0 * reach;
    const std::vector<Index> candidates = tree.TrianglesWithin(centre, within);
    ASSERT_FALSE(candidates.empty());
    for (std::size_t t = 0; t < surface.triangles.size(); ++t)
    {
      const auto &   corners = surface.triangles[t];
      const double   distance = (centre - ClosestOnTriangle(centre, surface.vertices[corners[0]], surface.vertices[corners[1]],
                                                            surface.vertices[corners[2]]))
                                .norm();
      const bool     listed = std::binary_search(candidates.begin(), candidates.end(), static_cast<Index>(t));
      if (std::abs(distance - within) > 1e-9)
      {
        ASSERT_EQ(listed, distance < within) << "triangle " << t << " at " << distance << " mm, radius " << within;
      }
    }
    for (int q = 0; q < 5; ++q)
    {
      const Vector3 query = centre + reach * Vector3(unit(random), unit(random), unit(random)).normalized() * std::abs(unit(random));
      const auto    hit = tree.ClosestAmong(query, candidates);
      ASSERT_NEAR(std::sqrt(hit.squaredDistance), BruteForceDistance(query, surface), 1e-9) << "query " << query.transpose();
      ASSERT_NEAR((hit.point - query).norm(), std::sqrt(hit.squaredDistance), 1e-9);
      ++checked;
    }
  }
  EXPECT_EQ(checked, 500);
  EXPECT_THROW(tree.ClosestAmong(Vector3::Zero(), {}), bmr::Error);
}

TEST(BrainSurface, ContactProjectsASlidingNodeOntoTheClosestPointAcrossAFold)
{
  // A slave node beyond the surface is moved onto its closest point. Slid in
  // steps shorter and longer than its candidates' reach through the fissure
  // (where the closest wall changes) and around the ball, it must land on
  // the brute-force closest point every time.
  const double radius = 20.0, halfWidth = 2.5;
  const auto   mask = MakeMask({ 52, 52, 52 }, Vector3::Constant(-25.5), Eigen::Matrix3d::Identity(), [&](const Vector3 & x) {
    return x.norm() <= radius && !(x.z() > 0.0 && std::abs(x.x()) < halfWidth);
  });
  bmr::ContactSurface surface = RunSource(mask, 1.5)->GetBrainSurface();
  surface.bodySide = bmr::ContactSurface::Side::Inside;
  const Vector3       start(-1.8, 0.0, 12.0);
  bmr::RigidContact   contact(surface, { 0 }, { start });
  const std::vector<char> held(3, 0);
  std::vector<char>       inContact(1, 0);
  int                     projected = 0;
  for (int step = 0; step <= 400; ++step)
  {
    // Across the fissure and back in steps of 0.036 mm, then around the ball in jumps of 0.32 mm.
    const double  s = step <= 200 ? step / 100.0 : (step - 200) / 200.0;
    const double  across = s <= 1.0 ? s : 2.0 - s;
    const Vector3 position = step <= 200 ? Vector3(-1.8 + 3.6 * across, 0.3 * s, 12.0 + 1.5 * s)
                                         : Vector3((radius + 1.0) * std::cos(3.0 * s), (radius + 1.0) * std::sin(3.0 * s), -3.0);
    std::vector<double> u = { position.x() - start.x(), position.y() - start.y(), position.z() - start.z() };
    std::fill(inContact.begin(), inContact.end(), 0);
    contact.Enforce(u.data(), held, inContact, 1);
    const Vector3 moved = start + Vector3(u[0], u[1], u[2]);
    const double  expected = BruteForceDistance(position, surface);
    if (inContact[0])
    {
      ASSERT_NEAR((moved - position).norm(), expected, 1e-9) << "step " << step;
      ASSERT_NEAR(BruteForceDistance(moved, surface), 0.0, 1e-9) << "step " << step;
      ++projected;
    }
    else
    {
      ASSERT_EQ(moved, position) << "step " << step;
    }
  }
  // Every position in the fissure and outside the ball lies beyond the surface.
  EXPECT_EQ(projected, 401);
}

TEST(BrainSurface, SmoothingKeepsVolumeAndDecimationReachesEdgeLength)
{
  // Core only: analytic signed distance of a sphere of radius 25 mm, 1 mm voxels.
  bmr::ScalarVolume field;
  field.geometry.size = { 60, 60, 60 };
  field.geometry.origin = Vector3::Constant(-29.5);
  field.values.resize(field.geometry.VoxelCount());
  for (int k = 0; k < 60; ++k)
    for (int j = 0; j < 60; ++j)
      for (int i = 0; i < 60; ++i)
        field.At(i, j, k) = static_cast<float>(field.geometry.IndexToPoint(Vector3(i, j, k)).norm() - 25.0);
  bmr::IsosurfaceSettings raw;
  raw.smoothingIterations = 0;
  const auto   unsmoothed = bmr::ExtractIsosurface(field, 0.0, raw);
  const auto   smoothed = bmr::ExtractIsosurface(field, 0.0);
  const double exact = 4.0 / 3.0 * kPi * 25.0 * 25.0 * 25.0;
  EXPECT_NEAR(bmr::EnclosedVolume(smoothed), bmr::EnclosedVolume(unsmoothed), 0.01 * bmr::EnclosedVolume(unsmoothed));
  EXPECT_NEAR(bmr::EnclosedVolume(smoothed), exact, 0.01 * exact);

  bmr::IsosurfaceSettings coarse;
  coarse.targetEdgeLength = 3.0;
  std::vector<std::string> warnings;
  const auto decimated = bmr::ExtractIsosurface(field, 0.0, coarse, &warnings);
  EXPECT_TRUE(warnings.empty()) << warnings.front();
  ASSERT_TRUE(bmr::IsClosedOrientedSurface(decimated));
  double edgeSum = 0.0;
  for (const auto & t : decimated.triangles)
    for (int k = 0; k < 3; ++k)
      edgeSum += (decimated.vertices[t[k]] - decimated.vertices[t[(k + 1) % 3]]).norm();
  const double meanEdge = edgeSum / (3.0 * decimated.triangles.size());
  EXPECT_NEAR(meanEdge, 3.0, 0.6);
  EXPECT_LT(decimated.triangles.size(), smoothed.triangles.size() / 4);
  EXPECT_NEAR(bmr::EnclosedVolume(decimated), exact, 0.02 * exact);
  ExpectRadiiWithin(decimated, Vector3::Zero(), 25.0, 0.5);

  // Nothing below the level: a clear error.
  const std::string message = bmr::test::ErrorMessage([&] { bmr::ExtractIsosurface(field, -30.0); });
  EXPECT_CONTAINS(message, "encloses nothing");
}

TEST(BrainSurface, MaskTouchingBorderGivesClosedSkull)
{
  // Sphere of radius 20 centred about 10 mm inside the image's x = 0 face: the mask is cut by the border.
  const double gap = 1.5;
  const Vector3 centre(10.2, 0.3, -0.2); // off the voxel grid, so no pole is flattened by the voxelisation
  const auto   mask = MakeMask({ 50, 50, 50 }, Vector3(0.0, -24.5, -24.5), Eigen::Matrix3d::Identity(),
                             [&](const Vector3 & x) { return (x - centre).norm() <= 20.0; });
  const auto   source = RunSource(mask, gap);
  ASSERT_TRUE(bmr::IsClosedOrientedSurface(source->GetBrainSurface()));
  ASSERT_TRUE(bmr::IsClosedOrientedSurface(source->GetSkullSurface()));
  // The brain reaches the image's first voxel centre (x = 0) and is closed
  // there, half a voxel out; the skull is the cut ball dilated by the gap, so
  // its flat face lies at x = -0.5 - gap.
  double lowestBrainX = 1e300, lowestSkullX = 1e300;
  for (const auto & v : source->GetBrainSurface().vertices)
    lowestBrainX = std::min(lowestBrainX, v.x());
  for (const auto & v : source->GetSkullSurface().vertices)
    lowestSkullX = std::min(lowestSkullX, v.x());
  EXPECT_NEAR(lowestBrainX, -0.5, 0.3);
  EXPECT_NEAR(lowestSkullX, -0.5 - gap, 0.3);
  // Away from the cut (and the rounded rim, x <= -0.5 + gap), the skull is the sphere of radius 20 + gap.
  for (const auto & v : source->GetSkullSurface().vertices)
  {
    const double r = (v - centre).norm();
    ASSERT_LT(r, 20.0 + gap + 0.5);
    if (v.x() > 3.0)
    {
      ASSERT_NEAR(r, 20.0 + gap, 0.5) << v.transpose();
    }
  }
}

TEST(BrainSurface, DirectionCosinesRotateTheSurface)
{
  // An ellipsoid in index space, once on an axis-aligned grid and once on a
  // rotated one: the same voxels, so the surfaces must be the same up to the rotation.
  const Eigen::Matrix3d rotation = Eigen::AngleAxisd(0.5, Vector3(1.0, 2.0, 2.0).normalized()).toRotationMatrix();
  const Vector3         semiAxes(22.0, 16.0, 12.0);
  const std::array<int, 3> size{ 52, 40, 32 };
  const Vector3         originAligned(-25.5, -19.5, -15.5);
  const Vector3         originRotated(10.0, -5.0, 3.0);
  auto                  insideAligned = [&](const Vector3 & x) { return x.cwiseQuotient(semiAxes).norm() <= 1.0; };
  auto insideRotated = [&](const Vector3 & x) {
    // Physical -> aligned frame: undo the rotation about the rotated image's origin.
    return insideAligned(rotation.transpose() * (x - originRotated) + originAligned);
  };
  const auto aligned = RunSource(MakeMask(size, originAligned, Eigen::Matrix3d::Identity(), insideAligned), 1.5);
  const auto rotated = RunSource(MakeMask(size, originRotated, rotation, insideRotated), 1.5);
  const auto & a = aligned->GetBrainSurface();
  const auto & b = rotated->GetBrainSurface();
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  ASSERT_EQ(a.triangles.size(), b.triangles.size());
  double largest = 0.0;
  for (std::size_t v = 0; v < a.vertices.size(); ++v)
  {
    const Vector3 expected = originRotated + rotation * (a.vertices[v] - originAligned);
    largest = std::max(largest, (b.vertices[v] - expected).norm());
  }
  EXPECT_LT(largest, 1e-6);
  EXPECT_NEAR(bmr::EnclosedVolume(b), bmr::EnclosedVolume(a), 1e-6 * bmr::EnclosedVolume(a));
  // And the rotated surface is the rotated ellipsoid (radial distance under 0.5 mm).
  for (const auto & x : b.vertices)
  {
    const Vector3 y = rotation.transpose() * (x - originRotated) + originAligned;
    const double  f = y.cwiseQuotient(semiAxes).norm();
    ASSERT_NEAR(y.norm() * (1.0 - 1.0 / f), 0.0, 0.5);
  }
}

TEST(BrainSurface, ItkOutputsMatchCoreSurfaces)
{
  const auto mask = MakeMask({ 24, 24, 24 }, Vector3::Constant(-11.5), Eigen::Matrix3d::Identity(),
                             [](const Vector3 & x) { return x.norm() <= 8.0; });
  const auto source = RunSource(mask, 1.5);
  const auto * brain = source->GetOutput();
  const auto * skull = source->GetSkullOutput();
  EXPECT_EQ(brain->GetNumberOfPoints(), source->GetBrainSurface().vertices.size());
  EXPECT_EQ(brain->GetNumberOfCells(), source->GetBrainSurface().triangles.size());
  EXPECT_EQ(skull->GetNumberOfPoints(), source->GetSkullSurface().vertices.size());
  EXPECT_EQ(skull->GetNumberOfCells(), source->GetSkullSurface().triangles.size());
  EXPECT_GT(skull->GetNumberOfPoints(), brain->GetNumberOfPoints());
  // Same coordinates and connectivity as the core surface.
  const auto & core = source->GetSkullSurface();
  for (std::size_t v = 0; v < core.vertices.size(); v += 7)
  {
    const auto p = skull->GetPoint(v);
    ASSERT_EQ(Vector3(p[0], p[1], p[2]), core.vertices[v]);
  }
  SurfaceSource::OutputMeshType::CellAutoPointer cell;
  ASSERT_TRUE(skull->GetCell(3, cell));
  ASSERT_EQ(cell->GetNumberOfPoints(), 3u);
  EXPECT_EQ(static_cast<Index>(cell->GetPointIds()[1]), core.triangles[3][1]);

  // An empty mask is a clear error.
  const auto empty = MakeMask({ 8, 8, 8 }, Vector3::Zero(), Eigen::Matrix3d::Identity(), [](const Vector3 &) { return false; });
  auto       failing = SurfaceSource::New();
  failing->SetInput(empty);
  try
  {
    failing->Update();
    ADD_FAILURE() << "an empty mask must throw";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_CONTAINS(error.GetDescription(), "no voxel > 0");
  }
}

// ---------------------------------------------------------------------------
// Regions
// ---------------------------------------------------------------------------

TEST(BrainSurfaceRegion, SphereSelectsExactlyTheNodesInside)
{
  const auto & model = EllipsoidModel();
  const auto   surface = model.BoundaryNodes();
  ASSERT_EQ(surface, model.NodeSet("surface"));
  const Vector3 centre(5.0, -10.0, 36.0);
  const double  radius = 18.0;
  const auto    selected = bmr::SurfaceNodesInSphere(model, surface, centre, radius);
  std::vector<Index> expected;
  for (const Index n : surface)
    if ((model.nodes[n] - centre).norm() <= radius)
      expected.push_back(n);
  EXPECT_EQ(selected, expected);
  EXPECT_GT(selected.size(), 5u);
  EXPECT_LT(selected.size(), surface.size() / 4);
}

TEST(BrainSurfaceRegion, SphereMissingTheSurfaceNamesTheDistance)
{
  const auto & model = EllipsoidModel();
  const auto   surface = model.BoundaryNodes();
  const Vector3 centre(0.0, 0.0, 120.0);
  double nearest = 1e300;
  for (const Index n : surface)
    nearest = std::min(nearest, (model.nodes[n] - centre).norm());
  const std::string message = bmr::test::ErrorMessage([&] { bmr::SurfaceNodesInSphere(model, surface, centre, 10.0); });
  std::ostringstream distance;
  distance << nearest;
  EXPECT_CONTAINS(message, "(0, 0, 120)");
  EXPECT_CONTAINS(message, "radius 10");
  EXPECT_CONTAINS(message, "nearest surface node is " + distance.str() + " mm");
  EXPECT_CONTAINS(message, "radius of at least");
}

TEST(BrainSurfaceRegion, MaskSelectsNodesNearMaskVoxels)
{
  const auto & model = EllipsoidModel();
  const auto   surface = model.BoundaryNodes();
  // 2 mm mask over the body; region: voxel centres with x >= 18 and z >= 0.
  bmr::LabelVolume mask;
  mask.geometry.size = { 50, 60, 44 };
  mask.geometry.spacing = Vector3::Constant(2.0);
  mask.geometry.origin = Vector3(-49.0, -59.0, -43.0);
  mask.values.assign(mask.geometry.VoxelCount(), 0);
  std::vector<Vector3> regionVoxels;
  for (int k = 0; k < 44; ++k)
    for (int j = 0; j < 60; ++j)
      for (int i = 0; i < 50; ++i)
      {
        const Vector3 p = mask.geometry.IndexToPoint(Vector3(i, j, k));
        if (p.x() >= 18.0 && p.z() >= 0.0)
        {
          mask.At(i, j, k) = 1;
          regionVoxels.push_back(p);
        }
      }
  const double tolerance = 2.0 * std::sqrt(3.0); // the default: one voxel diagonal
  const auto   selected = bmr::SurfaceNodesInMask(model, surface, mask);
  std::vector<Index> expected;
  for (const Index n : surface)
  {
    bool near = false;
    for (const auto & p : regionVoxels)
      near = near || (p - model.nodes[n]).norm() <= tolerance;
    if (near)
      expected.push_back(n);
  }
  EXPECT_EQ(selected, expected);
  EXPECT_GT(selected.size(), 10u);

  // A region far from the body selects nothing: error with the distance.
  std::fill(mask.values.begin(), mask.values.end(), 0);
  mask.At(0, 0, 0) = 1;
  const std::string message = bmr::test::ErrorMessage([&] { bmr::SurfaceNodesInMask(model, surface, mask); });
  EXPECT_CONTAINS(message, "selects no surface node");
  EXPECT_CONTAINS(message, "nearest surface node is");
}

TEST(BrainSurfaceRegion, SkullBaseIsTheBandAboveTheLowestNode)
{
  const auto & model = EllipsoidModel();
  const auto   surface = model.BoundaryNodes();
  double       lowest = 1e300;
  for (const Index n : surface)
    lowest = std::min(lowest, model.nodes[n].z());
  EXPECT_NEAR(lowest, -35.0, 5.0);
  const auto         selected = bmr::SkullBaseNodes(model, surface); // default 10 mm
  std::vector<Index> expected;
  for (const Index n : surface)
    if (model.nodes[n].z() <= lowest + 10.0)
      expected.push_back(n);
  EXPECT_EQ(selected, expected);

  // Another inferior direction (a tilted head) and a sphere instead of the band.
  bmr::SkullBaseSettings tilted;
  tilted.superior = Vector3(0.0, 1.0, 1.0);
  tilted.height = 8.0;
  const Vector3 up = tilted.superior.normalized();
  lowest = 1e300;
  for (const Index n : surface)
    lowest = std::min(lowest, model.nodes[n].dot(up));
  expected.clear();
  for (const Index n : surface)
    if (model.nodes[n].dot(up) <= lowest + 8.0)
      expected.push_back(n);
  EXPECT_EQ(bmr::SkullBaseNodes(model, surface, tilted), expected);

  bmr::SkullBaseSettings sphere;
  sphere.sphereCentre = Vector3(0.0, 0.0, -35.0);
  sphere.sphereRadius = 12.0;
  EXPECT_EQ(bmr::SkullBaseNodes(model, surface, sphere),
            bmr::SurfaceNodesInSphere(model, surface, sphere.sphereCentre, sphere.sphereRadius));
}

// ---------------------------------------------------------------------------
// Loads (a): closest-point correspondence to an intraoperative surface
// ---------------------------------------------------------------------------

TEST(SurfaceLoadFromSurface, NormalMotionOfPlaneIsExactTangentialIsLost)
{
  const auto model = bmr::MakeBlockMesh(Vector3(40.0, 40.0, 20.0), { 8, 8, 4 }, bmr::GridCells::Hexahedra);
  const auto & top = model.NodeSet("zmax");
  // The exposed surface moved by (0.7, -0.3, 2.5): only the normal part (0, 0, 2.5) is observable.
  const auto intraoperative = PlanePatch(-100.0, 100.0, -100.0, 100.0, 20.0 + 2.5);
  bmr::LoadReport report;
  const auto      load = bmr::DisplacementsFromSurface(model, top, intraoperative, {}, &report);
  ASSERT_EQ(load.nodes, top);
  for (const auto & u : load.displacements)
    EXPECT_LT((u - Vector3(0.0, 0.0, 2.5)).norm(), 1e-12);
  EXPECT_EQ(report.usedPoints, top.size());
  EXPECT_EQ(report.rejectedPoints, 0u);
  EXPECT_NEAR(report.maxCorrespondenceDistance, 2.5, 1e-12);
  EXPECT_NEAR(report.rmsCorrespondenceDistance, 2.5, 1e-12);
  EXPECT_TRUE(report.warnings.empty());
}

TEST(SurfaceLoadFromSurface, SmoothRadialFieldOnSphere)
{
  // Preoperative surface: an icosphere of radius R = 50 mm (nodes = its
  // vertices). Intraoperative: every vertex moved along the normal by
  // delta = 2 + 1.5 z / R mm. Closest-point correspondence misses the true
  // (normal) motion by a lateral shift of about delta times the tilt of the
  // moved surface: |grad delta| (<= 1.5 / R) from the varying delta, plus the
  // angle between a vertex normal and its facets' normals (< h / R for edge
  // length h) from the triangulation. Bound: max delta * (1.5 + h) / R.
  const double R = 50.0;
  const auto   sphere = bmr::MakeEllipsoidSurface(Vector3::Constant(R), 4);
  bmr::Model   model;
  model.nodes = sphere.vertices;
  auto   moved = sphere;
  auto   delta = [&](const Vector3 & x) { return 2.0 + 1.5 * x.z() / R; };
  for (auto & v : moved.vertices)
    v += delta(v) * v.normalized();
  double edge = 0.0;
  for (const auto & t : sphere.triangles)
    for (int k = 0; k < 3; ++k)
      edge = std::max(edge, (sphere.vertices[t[k]] - sphere.vertices[t[(k + 1) % 3]]).norm());
  std::vector<Index> exposed;
  for (std::size_t v = 0; v < sphere.vertices.size(); ++v)
    if (sphere.vertices[v].z() > 25.0)
      exposed.push_back(static_cast<Index>(v));
  bmr::LoadReport report;
  const auto      load = bmr::DisplacementsFromSurface(model, exposed, moved, {}, &report);
  ASSERT_EQ(load.nodes.size(), exposed.size());
  double largest = 0.0;
  for (std::size_t i = 0; i < exposed.size(); ++i)
  {
    const Vector3 & x = model.nodes[exposed[i]];
    largest = std::max(largest, (load.displacements[i] - delta(x) * x.normalized()).norm());
  }
  const double bound = 3.5 * (1.5 + edge) / R; // about 0.35 mm for h = 3.5 mm; measured 0.20 mm
  EXPECT_LT(largest, bound);
  EXPECT_GT(report.maxCorrespondenceDistance, 3.0);
}

TEST(SurfaceLoadFromSurface, RigidMotionKeepsOnlyTheNormalPart)
{
  // (1) Smooth case: an icosphere moved rigidly. A rotation about the centre
  // maps the sphere onto itself and is invisible; the correspondence of a
  // translation t is the closest point t + R (x - t) / |x - t| of the moved
  // sphere (about (t . n) n), up to the facet-tilt error |t| h / R.
  const double R = 50.0;
  const auto   sphere = bmr::MakeEllipsoidSurface(Vector3::Constant(R), 4);
  bmr::Model   ball;
  ball.nodes = sphere.vertices;
  const Eigen::Matrix3d rotation =
    Eigen::AngleAxisd(3.0 * kPi / 180.0, Vector3(1.0, 0.3, 0.0).normalized()).toRotationMatrix();
  const Vector3 translation(0.5, -0.4, -2.0);
  auto          moved = sphere;
  for (auto & v : moved.vertices)
    v = rotation * v + translation;
  double edge = 0.0;
  for (const auto & t : sphere.triangles)
    for (int k = 0; k < 3; ++k)
      edge = std::max(edge, (sphere.vertices[t[k]] - sphere.vertices[t[(k + 1) % 3]]).norm());
  std::vector<Index> cap;
  for (std::size_t v = 0; v < sphere.vertices.size(); ++v)
    if (sphere.vertices[v].z() > 30.0)
      cap.push_back(static_cast<Index>(v));
  const auto sphereLoad = bmr::DisplacementsFromSurface(ball, cap, moved);
  double     largest = 0.0;
  for (std::size_t i = 0; i < cap.size(); ++i)
  {
    const Vector3 & x = ball.nodes[cap[i]];
    const Vector3   closest = translation + R * (x - translation).normalized();
    largest = std::max(largest, (sphereLoad.displacements[i] - (closest - x)).norm());
  }
  EXPECT_LT(largest, translation.norm() * edge / R + 0.01); // about 0.15 mm

  // (2) Staircase boundary of a grid mesh moved rigidly: the target of every
  // exposed node lies on the moved surface (independent brute-force distance),
  // and is no farther than the node's true image, which is on that surface.
  const auto & model = EllipsoidModel();
  const auto   exposed = bmr::SurfaceNodesInSphere(model, model.BoundaryNodes(), Vector3(0.0, 0.0, 35.0), 20.0);
  bmr::ContactSurface boundary;
  boundary.name = "moved boundary";
  boundary.triangles = model.BoundaryTriangles();
  for (const auto & x : model.nodes)
    boundary.vertices.push_back(rotation * x + translation);
  const auto load = bmr::DisplacementsFromSurface(model, exposed, boundary);
  ASSERT_EQ(load.nodes, exposed);
  for (std::size_t i = 0; i < exposed.size(); ++i)
  {
    const Vector3 & x = model.nodes[exposed[i]];
    const Vector3   truth = rotation * x + translation - x;
    EXPECT_LE(load.displacements[i].norm(), truth.norm() + 1e-9);
    EXPECT_LT(BruteForceDistance(x + load.displacements[i], boundary), 1e-9);
  }
}

TEST(SurfaceLoadFromSurface, FarNodesRejectedWithWarning)
{
  const auto model = bmr::MakeBlockMesh(Vector3(40.0, 40.0, 20.0), { 8, 8, 4 }, bmr::GridCells::Hexahedra);
  const auto & top = model.NodeSet("zmax");
  // A small measured patch above one corner, 2 mm above the surface.
  const auto patch = PlanePatch(0.0, 10.0, 0.0, 10.0, 22.0);
  bmr::SurfaceLoadSettings settings;
  settings.maxDistance = 8.0;
  std::vector<Index> expectedUsed, expectedRejected;
  for (const Index n : top)
  {
    const Vector3 & x = model.nodes[n];
    const double    dx = std::max(0.0, x.x() - 10.0), dy = std::max(0.0, x.y() - 10.0);
    (std::sqrt(dx * dx + dy * dy + 4.0) <= 8.0 ? expectedUsed : expectedRejected).push_back(n);
  }
  ASSERT_FALSE(expectedRejected.empty());
  bmr::LoadReport report;
  const auto      load = bmr::DisplacementsFromSurface(model, top, patch, settings, &report);
  EXPECT_EQ(load.nodes, expectedUsed);
  EXPECT_EQ(report.rejectedPoints, expectedRejected.size());
  ASSERT_EQ(report.warnings.size(), 1u);
  EXPECT_CONTAINS(report.warnings[0], "node " + std::to_string(expectedRejected[0]) + " (");
  EXPECT_CONTAINS(report.warnings[0], "and " + std::to_string(expectedRejected.size() - 20) + " more");

  // Every node rejected: an error.
  const auto far = PlanePatch(0.0, 10.0, 0.0, 10.0, 60.0);
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::DisplacementsFromSurface(model, top, far, settings); }),
                  "every exposed node is farther than");
}

// ---------------------------------------------------------------------------
// Loads (b): sparse displacements interpolated with a polyharmonic spline
// ---------------------------------------------------------------------------

namespace
{
struct CapFixture
{
  std::vector<Index>   exposed;
  std::vector<Vector3> points;
};

// Exposed nodes: the cap of the ellipsoid model around its top; points: every
// stride-th exposed node (on the model surface).
CapFixture
MakeCap(std::size_t stride = 3)
{
  const auto & model = EllipsoidModel();
  CapFixture   cap;
  cap.exposed = bmr::SurfaceNodesInSphere(model, model.BoundaryNodes(), Vector3(0.0, 0.0, 35.0), 25.0);
  for (std::size_t i = 0; i < cap.exposed.size(); i += stride)
    cap.points.push_back(model.nodes[cap.exposed[i]]);
  return cap;
}
} // namespace

TEST(SurfaceLoadSparse, AffineFieldReproducedExactly)
{
  const auto & model = EllipsoidModel();
  const auto   cap = MakeCap();
  Eigen::Matrix3d gradient;
  gradient << 0.02, -0.01, 0.005, 0.003, 0.015, -0.02, 0.01, 0.0, -0.03;
  const Vector3 offset(1.0, -2.0, 3.0);
  auto          field = [&](const Vector3 & x) -> Vector3 { return offset + gradient * x; };
  std::vector<Vector3> displacements;
  for (const auto & p : cap.points)
    displacements.push_back(field(p));
  bmr::LoadReport report;
  const auto      load = bmr::DisplacementsFromSparsePoints(model, cap.exposed, cap.points, displacements, {}, &report);
  ASSERT_EQ(load.nodes, cap.exposed);
  double largest = 0.0;
  for (std::size_t i = 0; i < cap.exposed.size(); ++i)
    largest = std::max(largest, (load.displacements[i] - field(model.nodes[cap.exposed[i]])).norm());
  EXPECT_LT(largest, 1e-8);
  EXPECT_EQ(report.usedPoints, cap.points.size());
  EXPECT_LT(report.maxCorrespondenceDistance, 1e-9); // the points are model nodes
}

TEST(SurfaceLoadSparse, QuadraticFieldWithinTolerance)
{
  // Brain-shift-like sag: 5 mm downward at the centre, falling off
  // quadratically (second derivative 10 / 25^2 = 0.016 mm^-1), with a linear
  // lateral part. Points on a 5 mm spacing; error measured at the exposed nodes.
  auto field = [](const Vector3 & x) -> Vector3 {
    const double r2 = (x.x() * x.x() + x.y() * x.y()) / (25.0 * 25.0);
    return Vector3(0.4 * x.x() / 25.0, 0.0, -5.0 * (1.0 - r2));
  };
  auto errors = [&](const bmr::Model & model, const std::vector<Index> & exposed, const std::vector<Vector3> & points) {
    std::vector<Vector3> displacements;
    for (const auto & p : points)
      displacements.push_back(field(p));
    const auto load = bmr::DisplacementsFromSparsePoints(model, exposed, points, displacements);
    double     all = 0.0, inner = 0.0; // inner: |(x, y)| < 15 mm, away from the rim of the sampled patch
    for (std::size_t i = 0; i < exposed.size(); ++i)
    {
      const Vector3 & x = model.nodes[exposed[i]];
      const double    e = (load.displacements[i] - field(x)).norm();
      all = std::max(all, e);
      if (x.head<2>().norm() < 15.0)
        inner = std::max(inner, e);
    }
    return std::make_pair(inner, all);
  };

  // (1) A flat exposed surface (top face of a block, nodes every 2.5 mm, points every 5 mm):
  // like piecewise-linear interpolation, h^2 u'' / 8 = 0.05 mm inside; the
  // spline degrades towards the edge of the data (measured 0.011 and 0.17 mm).
  const auto   block = bmr::MakeBlockMesh(Vector3(50.0, 50.0, 20.0), { 20, 20, 4 }, bmr::GridCells::Hexahedra,
                                        bmr::Material{}, Vector3(-25.0, -25.0, 0.0));
  const auto & top = block.NodeSet("zmax");
  std::vector<Vector3> grid;
  for (const Index n : top)
  {
    const Vector3 & x = block.nodes[n];
    if (std::fmod(x.x() + 25.0, 5.0) < 1e-9 && std::fmod(x.y() + 25.0, 5.0) < 1e-9)
      grid.push_back(x);
  }
  const auto flat = errors(block, top, grid);
  EXPECT_LT(flat.first, 0.05);
  EXPECT_LT(flat.second, 0.25);

  // (2) The staircase top of a 5 mm grid mesh (points: every second exposed
  // node, fill distance 5 mm). The exposed nodes lie on steps 5 mm high, so
  // the 3D spline also interpolates across the steps: measured 0.36 mm inside
  // and 1.2 mm at the rim of the patch, asserted with a 25% margin.
  const auto & model = EllipsoidModel();
  const auto   cap = MakeCap(2);
  const auto   stairs = errors(model, cap.exposed, cap.points);
  EXPECT_LT(stairs.first, 0.45);
  EXPECT_LT(stairs.second, 1.5);
}

TEST(SurfaceLoadSparse, FarPointRejectedAndNamed)
{
  const auto & model = EllipsoidModel();
  const auto   cap = MakeCap();
  std::vector<Vector3> points = cap.points, displacements(points.size(), Vector3(0.0, 0.0, -3.0));
  const auto reference = bmr::DisplacementsFromSparsePoints(model, cap.exposed, points, displacements);
  // Point 3 moved 30 mm above the surface (the top of the body is at z ~ 35 mm).
  points.insert(points.begin() + 3, Vector3(0.0, 0.0, 70.0));
  displacements.insert(displacements.begin() + 3, Vector3(50.0, 50.0, 50.0));
  bmr::LoadReport report;
  const auto      load = bmr::DisplacementsFromSparsePoints(model, cap.exposed, points, displacements, {}, &report);
  EXPECT_EQ(report.rejectedPoints, 1u);
  EXPECT_EQ(report.usedPoints, points.size() - 1);
  ASSERT_FALSE(report.warnings.empty());
  EXPECT_CONTAINS(report.warnings[0], "point 3 at (0, 0, 70) mm (");
  for (std::size_t i = 0; i < load.displacements.size(); ++i)
    EXPECT_LT((load.displacements[i] - reference.displacements[i]).norm(), 1e-9);
}

TEST(SurfaceLoadSparse, CoplanarAndNearlyCoplanarPoints)
{
  const auto model = bmr::MakeBlockMesh(Vector3(40.0, 40.0, 20.0), { 8, 8, 4 }, bmr::GridCells::Hexahedra);
  const auto & top = model.NodeSet("zmax");
  Eigen::Matrix3d gradient;
  gradient << 0.02, -0.01, 0.3, 0.003, 0.015, -0.2, 0.01, 0.0, 0.5; // with gradients across the plane
  auto field = [&](const Vector3 & x) -> Vector3 { return Vector3(0.5, 0.2, -1.0) + gradient * x; };
  for (const double jitter : { 0.0, 1e-4 })
  {
    std::vector<Vector3> points, displacements;
    for (int k = 0; k < 12; ++k)
    {
      const Vector3 p(3.0 + 3.1 * (k % 4), 5.0 + 9.0 * (k / 4) + 0.3 * k, 20.0 + (k % 2 ? jitter : -jitter));
      points.push_back(p);
      displacements.push_back(field(p));
    }
    bmr::LoadReport report;
    const auto      load = bmr::DisplacementsFromSparsePoints(model, top, points, displacements, {}, &report);
    double          largest = 0.0;
    for (std::size_t i = 0; i < top.size(); ++i)
      largest = std::max(largest, (load.displacements[i] - field(model.nodes[top[i]])).norm());
    // The nodes lie in the points' plane: the in-plane affine field is reproduced,
    // the unobservable gradient across the plane does not matter there.
    EXPECT_LT(largest, 1e-8) << "jitter " << jitter;
  }
}

TEST(SurfaceLoadSparse, FewPointsGiveMeanTranslationAndBadInputIsAnError)
{
  const auto & model = EllipsoidModel();
  const auto   cap = MakeCap();
  const std::vector<Vector3> two{ cap.points[0], cap.points[1] };
  const std::vector<Vector3> twoDisplacements{ Vector3(1.0, 0.0, -2.0), Vector3(3.0, 0.0, -4.0) };
  bmr::LoadReport report;
  const auto      load = bmr::DisplacementsFromSparsePoints(model, cap.exposed, two, twoDisplacements, {}, &report);
  for (const auto & u : load.displacements)
    EXPECT_EQ(u, Vector3(2.0, 0.0, -3.0));
  ASSERT_EQ(report.warnings.size(), 1u);
  EXPECT_CONTAINS(report.warnings[0], "mean displacement");

  auto points = cap.points;
  std::vector<Vector3> displacements(points.size(), Vector3::Zero());
  displacements[2].y() = std::nan("");
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::DisplacementsFromSparsePoints(model, cap.exposed, points, displacements); }),
                  "measurement point 2 at");
  displacements[2].y() = 0.0;
  points[4].x() = std::nan("");
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::DisplacementsFromSparsePoints(model, cap.exposed, points, displacements); }),
                  "measurement point 4 at");
  const std::vector<Vector3> far{ Vector3(0.0, 0.0, 100.0) };
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::DisplacementsFromSparsePoints(model, cap.exposed, far, far); }),
                  "every measurement point is farther than");
}

namespace
{
class SurfaceLoadCsv : public bmr::test::TemporaryFolderTest
{
protected:
  std::string Write(const std::string & text)
  {
    const auto path = (m_Folder / "points.csv").string();
    std::ofstream(path) << text;
    return path;
  }
};
} // namespace

TEST_F(SurfaceLoadCsv, ReadsRowsAndNamesBadLines)
{
  const auto good = bmr::ReadSparseDisplacements(Write("# tracked points\nx, y, z, ux, uy, uz\n1,2,3,0.5,-0.5,1e-1\n\n-4.5,5,6,0,0,-2\n"));
  ASSERT_EQ(good.points.size(), 2u);
  EXPECT_EQ(good.points[1], Vector3(-4.5, 5.0, 6.0));
  EXPECT_EQ(good.displacements[0], Vector3(0.5, -0.5, 0.1));

  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::ReadSparseDisplacements(Write("x,y,z,dx,dy,dz\n1,2,3,4,5,6\n")); }),
                  "line 1: expected the header");
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::ReadSparseDisplacements(Write("x,y,z,ux,uy,uz\n1,2,3,4,5,6\n1,2,abc,4,5,6\n")); }),
                  "line 3: field z = 'abc' is not a finite number");
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::ReadSparseDisplacements(Write("x,y,z,ux,uy,uz\n\n1,2,3,4,5\n")); }),
                  "line 3: expected 6 comma-separated numbers");
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::ReadSparseDisplacements(Write("x,y,z,ux,uy,uz\n1,2,3,nan,5,6\n")); }),
                  "line 2: field ux = 'nan'");
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::ReadSparseDisplacements(Write("x,y,z,ux,uy,uz\n")); }), "no rows");
  EXPECT_CONTAINS(bmr::test::ErrorMessage([&] { bmr::ReadSparseDisplacements((m_Folder / "missing.csv").string()); }),
                  "cannot open");
}

namespace
{

/** A regular triangulated patch z = height(x, y) over [x0, x1] x [y0, y1], cells of `step` mm, normals up. */
template <typename Height>
bmr::ContactSurface
HeightPatch(double x0, double x1, double y0, double y1, double step, Height height)
{
  bmr::ContactSurface surface;
  const int           nx = static_cast<int>(std::lround((x1 - x0) / step));
  const int           ny = static_cast<int>(std::lround((y1 - y0) / step));
  for (int j = 0; j <= ny; ++j)
    for (int i = 0; i <= nx; ++i)
    {
      const double x = x0 + i * step, y = y0 + j * step;
      surface.vertices.emplace_back(x, y, height(x, y));
    }
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i)
    {
      const Index a = j * (nx + 1) + i, b = a + 1, c = a + nx + 1, d = c + 1;
      surface.triangles.push_back({ a, b, d });
      surface.triangles.push_back({ a, d, c });
    }
  return surface;
}

} // namespace

// A scanned surface that sags smoothly: the loads at the exposed nodes
// follow the sag to within the thin-plate interpolation of points one per
// 2 mm cell and the closest-point correspondence (bound 0.15 mm in depth).
TEST(SurfaceLoadBetweenSurfaces, SmoothSagIsFollowed)
{
  const auto   model = bmr::MakeBlockMesh(Vector3(40.0, 40.0, 20.0), { 8, 8, 4 }, bmr::GridCells::Hexahedra);
  const auto   sag = [](double x, double y) { return -3.0 * std::exp(-((x - 20) * (x - 20) + (y - 20) * (y - 20)) / 200.0); };
  const auto   preoperative = HeightPatch(-10.0, 50.0, -10.0, 50.0, 1.0, [](double, double) { return 20.0; });
  const auto   intraoperative = HeightPatch(-10.0, 50.0, -10.0, 50.0, 1.0, [&](double x, double y) { return 20.0 + sag(x, y); });
  const auto & top = model.NodeSet("zmax");
  bmr::LoadReport report;
  const auto load = bmr::DisplacementsBetweenSurfaces(model, top, preoperative, intraoperative, 5.0, 2.0, {}, &report);
  ASSERT_EQ(load.nodes.size(), top.size());
  for (std::size_t k = 0; k < load.nodes.size(); ++k)
  {
    const Vector3 & x = model.nodes[load.nodes[k]];
    // Closest points on a sloped surface: the motion along the normal, so a
    // lateral part of about sag x slope (at most 3 x 0.26 = 0.8 mm here).
    EXPECT_NEAR(load.displacements[k].z(), sag(x.x(), x.y()), 0.15) << bmr::FormatPoint(x);
    EXPECT_LT(std::hypot(load.displacements[k].x(), load.displacements[k].y()), 0.8) << bmr::FormatPoint(x);
  }
  // The only warning: the scanned points of a flat patch are coplanar (affine part across it taken as zero).
  ASSERT_EQ(report.warnings.size(), 1u);
  EXPECT_NE(report.warnings[0].find("coplanar"), std::string::npos) << report.warnings[0];
}

// A surface that sinks obliquely (along (0.3, 0, -1), as a brain sinks along
// gravity in a turned head): matched along that direction the loads are the
// motion itself, tangential part included (bound 0.15 mm, the interpolation's);
// closest points see only its normal part and miss the tangential 0.86 mm at
// the centre. A zero direction is an error.
TEST(SurfaceLoadBetweenSurfaces, MatchAlongADirectionKeepsTheTangentialMotion)
{
  const auto    model = bmr::MakeBlockMesh(Vector3(40.0, 40.0, 20.0), { 8, 8, 4 }, bmr::GridCells::Hexahedra);
  const Vector3 direction = Vector3(0.3, 0.0, -1.0).normalized();
  const auto    sink = [](double x, double y) { return 3.0 * std::exp(-((x - 20) * (x - 20) + (y - 20) * (y - 20)) / 200.0); };
  const auto    preoperative = HeightPatch(-10.0, 50.0, -10.0, 50.0, 1.0, [](double, double) { return 20.0; });
  auto          intraoperative = preoperative;
  for (Vector3 & vertex : intraoperative.vertices)
  {
    vertex += sink(vertex.x(), vertex.y()) * direction;
  }
  const auto &        top = model.NodeSet("zmax");
  bmr::SurfaceLoadSettings settings;
  settings.matchDirection = direction;
  const auto along = bmr::DisplacementsBetweenSurfaces(model, top, preoperative, intraoperative, 5.0, 2.0, settings);
  const auto closest = bmr::DisplacementsBetweenSurfaces(model, top, preoperative, intraoperative, 5.0, 2.0, {});
  ASSERT_EQ(along.nodes.size(), top.size());
  double closestAtCentre = 0.0;
  for (std::size_t k = 0; k < along.nodes.size(); ++k)
  {
    const Vector3 & x = model.nodes[along.nodes[k]];
    const Vector3   truth = sink(x.x(), x.y()) * direction;
    EXPECT_LT((along.displacements[k] - truth).norm(), 0.15) << bmr::FormatPoint(x);
    if ((x - Vector3(20.0, 20.0, 20.0)).norm() < 1e-9)
    {
      closestAtCentre = (closest.displacements[k] - truth).norm();
    }
  }
  EXPECT_GT(closestAtCentre, 0.7);
  settings.matchDirection = Vector3::Zero();
  EXPECT_THROW(bmr::DisplacementsBetweenSurfaces(model, top, preoperative, intraoperative, 5.0, 2.0, settings), bmr::Error);
}

// Hidden and outlying matches are left out: a second sheet 4 mm under the
// top (a sulcus floor, not seen from above), and a spike of the scan (one
// vertex thrown 6 mm up) whose matches differ from their neighbours'.
TEST(SurfaceLoadBetweenSurfaces, HiddenVerticesAndSpikesAreLeftOut)
{
  const auto model = bmr::MakeBlockMesh(Vector3(40.0, 40.0, 20.0), { 8, 8, 4 }, bmr::GridCells::Hexahedra);
  auto       preoperative = HeightPatch(-10.0, 50.0, -10.0, 50.0, 1.0, [](double, double) { return 20.0; });
  const auto floor = HeightPatch(10.0, 30.0, 10.0, 30.0, 1.0, [](double, double) { return 16.0; });
  const Index offset = static_cast<Index>(preoperative.vertices.size());
  preoperative.vertices.insert(preoperative.vertices.end(), floor.vertices.begin(), floor.vertices.end());
  for (auto triangle : floor.triangles)
  {
    for (auto & vertex : triangle)
      vertex += offset;
    preoperative.triangles.push_back(triangle);
  }
  const auto & top = model.NodeSet("zmax");
  const auto   isOutlierWarning = [](const std::string & warning) {
    return warning.find("differ from their neighbours") != std::string::npos;
  };
  // The top sunk by 2 mm: the hidden floor (whose closest points would say +2 mm) changes nothing.
  auto            intraoperative = HeightPatch(-10.0, 50.0, -10.0, 50.0, 1.0, [](double, double) { return 18.0; });
  bmr::LoadReport report;
  auto load = bmr::DisplacementsBetweenSurfaces(model, top, preoperative, intraoperative, 5.0, 1.0, {}, &report);
  ASSERT_EQ(load.nodes.size(), top.size());
  for (const auto & u : load.displacements)
    EXPECT_LT((u - Vector3(0.0, 0.0, -2.0)).norm(), 1e-6);
  EXPECT_EQ(std::count_if(report.warnings.begin(), report.warnings.end(), isOutlierWarning), 0);

  // A spike at (22, 22), between nodes: its matches that differ by more than
  // 1 mm are rejected and named; its milder flanks are kept by design (1 mm is
  // a scan's noise level) and pull the nearest node by under 0.5 mm (0.43 measured).
  intraoperative.vertices[32 * 61 + 32].z() += 6.0;
  load = bmr::DisplacementsBetweenSurfaces(model, top, preoperative, intraoperative, 5.0, 1.0, {}, &report);
  EXPECT_EQ(std::count_if(report.warnings.begin(), report.warnings.end(), isOutlierWarning), 1);
  EXPECT_GE(report.rejectedPoints, 1u);
  for (std::size_t k = 0; k < load.nodes.size(); ++k)
    EXPECT_LT((load.displacements[k] - Vector3(0.0, 0.0, -2.0)).norm(), 0.5) << bmr::FormatPoint(model.nodes[load.nodes[k]]);
}

// A sulcated surface (bumps 2 mm high every 8 mm) sunk by a smooth sag of up
// to 6 mm, more than its features: closest points from the preoperative
// crowns land on the flanks of other bumps, with jumps of several mm between
// neighbours. Refined from their neighbours' local fit and snapped back onto
// the displaced surface, the matches agree: under 10 % are left out, and the
// loads follow the sag in depth within 0.5 mm.
TEST(SurfaceLoadBetweenSurfaces, MatchesOnASulcatedSurfaceAgreeWithTheirNeighbours)
{
  const auto model = bmr::MakeBlockMesh(Vector3(40.0, 40.0, 20.0), { 8, 8, 4 }, bmr::GridCells::Hexahedra);
  const auto bumps = [](double x, double y) {
    return 20.0 + std::cos(2.0 * M_PI * x / 8.0) * std::cos(2.0 * M_PI * y / 8.0);
  };
  const auto sag = [](double x, double y) { return 6.0 * std::exp(-((x - 20) * (x - 20) + (y - 20) * (y - 20)) / 300.0); };
  const auto preoperative = HeightPatch(-10.0, 50.0, -10.0, 50.0, 0.5, bumps);
  auto       intraoperative = preoperative;
  for (Vector3 & vertex : intraoperative.vertices)
  {
    vertex.z() -= sag(vertex.x(), vertex.y());
  }
  const auto &    top = model.NodeSet("zmax");
  bmr::LoadReport report;
  const auto load = bmr::DisplacementsBetweenSurfaces(model, top, preoperative, intraoperative, 5.0, 2.0, {}, &report);
  ASSERT_EQ(load.nodes.size(), top.size());
  // 2 mm cells over the block's 40 x 40 mm top and the 5 mm reach beyond it.
  const std::size_t visible = 25 * 25;
  EXPECT_LT(report.rejectedPoints, visible / 10) << ::testing::PrintToString(report.warnings);
  for (std::size_t k = 0; k < load.nodes.size(); ++k)
  {
    const Vector3 & x = model.nodes[load.nodes[k]];
    EXPECT_NEAR(load.displacements[k].z(), -sag(x.x(), x.y()), 0.5) << bmr::FormatPoint(x);
  }
}
