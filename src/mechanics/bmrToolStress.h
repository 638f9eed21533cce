// Stresses near a tool: the cells around a tool's path re-evaluated every
// step with Miller and Chinzei's Ogden-type hyperviscoelastic law
// (bmrOgden.h) from the deformation gradients of the neo-Hookean solve, and
// the tool force corrected by the difference of their nodal forces. Nothing is
// computed outside the region, and nothing feeds back into the motion.
// Private to the core.
#ifndef bmrToolStress_h
#define bmrToolStress_h

#include "bmrModel.h"
#include "bmrOgden.h"
#include "bmrToolContact.h"

#include <vector>

namespace bmr
{

class ToolStressRegion
{
public:
  /** The cells whose reference centroid comes within tool.stressRegionRadius
   *  of the tool anywhere along its trajectory (sampled so that the tool
   *  moves at most a quarter of the radius between samples). Moves `contact`
   *  along the trajectory to find them. */
  ToolStressRegion(const Model & model, ToolContact & contact);

  /** Advances every region cell by dt (s) to the displacements u (mm, 3 per
   *  node) and returns the correction of the force on the tool (N): minus
   *  the difference between the Ogden and the neo-Hookean nodal forces of the
   *  region's cells at `touching` nodes. */
  Vector3 Update(const double * u, double dt, const std::vector<Index> & touching, int threads);

  const std::vector<Index> &           Cells() const { return m_Cells; }
  const std::vector<Eigen::Matrix3d> & OgdenStress() const { return m_Ogden; }      // Pa, Cauchy, per region cell
  const std::vector<Eigen::Matrix3d> & NeoHookeanStress() const { return m_NeoHookean; } // Pa, Cauchy, same F
  /** Largest von Mises stress (Pa) of the Ogden stresses of the last update. */
  double PeakVonMises() const;

private:
  const Model &                       m_Model;
  std::vector<Index>                  m_Cells;
  std::vector<Eigen::Matrix<double, 3, 8>> m_Gradients; // dN_a/dX per node (columns), first 4 for tetrahedra
  std::vector<double>                 m_Volumes;        // mm^3
  std::vector<OgdenViscoelasticPoint> m_Points;
  std::vector<Eigen::Matrix3d>        m_F, m_Ogden, m_NeoHookean;
  std::vector<char>                   m_Touching;       // per node, reused
};

} // namespace bmr

#endif
