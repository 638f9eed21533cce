// Simple structured meshes for verification, benchmarks and the brain-sized
// demo scene. Patient-specific grids from images come from the ITK layer.
#ifndef bmrMeshGenerators_h
#define bmrMeshGenerators_h

#include "bmrModel.h"

#include <array>
#include <cstdint>

namespace bmr
{

enum class GridCells
{
  Hexahedra,  // one 8-node hexahedron per grid cell
  Tetrahedra, // each grid cell split into 6 tetrahedra (Kuhn split, conforming)
  Mixed       // hexahedra where x < origin.x + size.x / 2, tetrahedra elsewhere
};

/** Box [origin, origin + size] (mm) with divisions[d] cells along axis d, one
 *  material (index 0). Node sets "xmin", "xmax", "ymin", "ymax", "zmin",
 *  "zmax" (nodes on each face) and "all". */
Model
MakeBlockMesh(const Vector3 &             size,
              const std::array<int, 3> & divisions,
              GridCells                   cells,
              const Material &            material = Material{},
              const Vector3 &             origin = Vector3::Zero());

/** Moves every node not on the box boundary by a random vector of at most
 *  `fraction` of the smallest grid spacing in each component (deterministic
 *  for a given seed). Keeps every cell valid for fraction <= 0.25. */
void
DistortInteriorNodes(Model & model, double fraction, std::uint32_t seed = 1);

/** Ellipsoid with the given semi-axes (mm), centred at the origin, meshed on a
 *  regular grid of spacing h: grid cells whose centre lies inside become cells
 *  (hexahedra or 6 tetrahedra each). Node sets: "surface" (boundary nodes) and
 *  "all". A brain is roughly semi-axes (70, 85, 60) mm.
 *  With `subdivisions` s > 1 each of those cells is split into s^3 cells of
 *  spacing h / s: meshes of one h bound the same body at every s and their
 *  nodes nest (a convergence study's reference and its coarser meshes). */
Model
MakeEllipsoidMesh(const Vector3 &  semiAxes,
                  double           spacing,
                  GridCells        cells,
                  const Material & material = Material{},
                  int              subdivisions = 1);

/** Closed triangulated ellipsoid surface (outward normals), e.g. a rigid skull
 *  around MakeEllipsoidMesh's body; `subdivisions` refines an icosahedron. */
ContactSurface
MakeEllipsoidSurface(const Vector3 & semiAxes, int subdivisions, const Vector3 & centre = Vector3::Zero());

} // namespace bmr

#endif
