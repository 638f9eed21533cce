// The parts of the image grids (internal to the core library): the body of
// tissue voxels every grid kind starts from, and the makers of each kind.
// bmrImageGrids.cxx checks the input and dispatches; bmrHexahedralGrids.cxx
// makes the regular and mixed grids; bmrTetrahedralGrids.cxx holds all of
// CGAL's Mesh_3 (tetrahedra, and the meshless cloud's nodes), which is
// expensive to compile.
#ifndef bmrImageGridBody_h
#define bmrImageGridBody_h

#include "bmrImageGrids.h"

#include "bmrShape.h"

#include <Eigen/Dense>

#include <algorithm>
#include <numeric>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <iomanip>
#include <limits>
#include <map>
#include <queue>
#include <sstream>
#include <unordered_map>
#include <utility>
namespace bmr
{
namespace grids
{

constexpr double kPi = 3.14159265358979323846;

inline std::string
Number(double value)
{
  std::ostringstream text;
  text << std::setprecision(4) << value;
  return text.str();
}

/** The body's voxels, their bounding box and the checks common to every grid kind. */
struct Body
{
  const LabelVolume * labels = nullptr;
  std::array<int, 3>  lower{}, upper{}; // inclusive voxel index box of the tissue voxels
  std::size_t         voxels = 0;
  double              maskVolume = 0.0;
  bool                flipped = false; // det(direction) < 0: cells need a mirrored node order

  bool Inside(int i, int j, int k) const { return labels->At(i, j, k) > 0; }
  const ImageGeometry & Geometry() const { return labels->geometry; }
  /** Grid frame: mm along the image axes from voxel 0's centre (= CGAL's frame). */
  Vector3 ToPhysical(const Vector3 & g) const
  {
    const ImageGeometry & geometry = Geometry();
    return geometry.origin + geometry.direction * g;
  }
  /** 1 inside, 0 outside, trilinear between voxel centres (0 beyond the image). */
  double MaskValue(const Vector3 & g) const
  {
    const ImageGeometry & geometry = Geometry();
    const Vector3         index = g.cwiseQuotient(geometry.spacing);
    std::array<int, 3>    base{};
    std::array<double, 3> t{};
    for (int d = 0; d < 3; ++d)
    {
      const double floorIndex = std::floor(index[d]);
      base[d] = static_cast<int>(floorIndex);
      t[d] = index[d] - floorIndex;
    }
    double value = 0.0;
    for (int c = 0; c < 8; ++c)
    {
      const int i = base[0] + HexahedronCornerOffsets[c][0], j = base[1] + HexahedronCornerOffsets[c][1], k = base[2] + HexahedronCornerOffsets[c][2];
      if (i < 0 || j < 0 || k < 0 || i >= geometry.size[0] || j >= geometry.size[1] || k >= geometry.size[2] ||
          !Inside(i, j, k))
      {
        continue;
      }
      value += (HexahedronCornerOffsets[c][0] ? t[0] : 1.0 - t[0]) * (HexahedronCornerOffsets[c][1] ? t[1] : 1.0 - t[1]) *
               (HexahedronCornerOffsets[c][2] ? t[2] : 1.0 - t[2]);
    }
    return value;
  }
  bool NearestVoxelInside(const Vector3 & g) const
  {
    const ImageGeometry & geometry = Geometry();
    std::array<int, 3>    index{};
    for (int d = 0; d < 3; ++d)
    {
      index[d] = static_cast<int>(std::lround(g[d] / geometry.spacing[d]));
      if (index[d] < 0 || index[d] >= geometry.size[d])
      {
        return false;
      }
    }
    return Inside(index[0], index[1], index[2]);
  }
};

inline Material
Parenchyma()
{
  Material material;
  material.name = "parenchyma";
  material.youngsModulus = 3000.0;
  material.poissonRatio = 0.49;
  material.density = 1000.0;
  return material;
}

inline void
AddStandardNodeSets(Model & model)
{
  auto & all = model.nodeSets["all"];
  all.resize(model.nodes.size());
  for (std::size_t n = 0; n < all.size(); ++n)
  {
    all[n] = static_cast<Index>(n);
  }
  if (!model.cells.empty())
  {
    model.nodeSets["surface"] = model.BoundaryNodes();
  }
}

/** Regular hexahedra of size h conforming to the mask; mixed: boundary cubes
 *  split into tetrahedra whose surface nodes are snapped to the mask's
 *  boundary. With the standard node sets. */
ImageGrid
MakeHexahedralGrid(const Body & body, double h, bool mixed, std::vector<std::string> * warnings);

/** CGAL Mesh_3 tetrahedra of the labelled body, with the standard node sets. */
ImageGrid
MakeTetrahedralGrid(const Body & body, const ImageGridSettings & settings, std::vector<std::string> * warnings);

/** A meshless cloud: nodes and background integration points of the body. */
ImageGrid
MakeMeshlessGrid(const Body & body, const ImageGridSettings & settings, std::vector<std::string> * warnings);

} // namespace grids
} // namespace bmr

#endif
