// Essential boundary conditions of the meshless discretization imposed with
// EBCIEM (Joldes, Chowdhury, Wittek, Miller 2017): after each explicit step the
// nodal parameters are corrected so that the MLS-interpolated displacement,
// not the parameter, takes the prescribed value at every constrained node.
// Private to the core.
#ifndef bmrEssentialBoundary_h
#define bmrEssentialBoundary_h

#include "bmrMeshless.h"

#include <memory>
#include <vector>

namespace bmr
{

/** The correction is the mass-weighted least change of the parameters,
 *  du = M^-1 Phi_B^T (Phi_B M^-1 Phi_B^T)^-1 (u_target - Phi_B u): exactly what
 *  a Lagrange multiplier (the reaction) does within one central-difference
 *  step, so the steady state is the constrained equilibrium. The matrices
 *  depend only on the reference configuration and the masses: they are
 *  factorised once per solve. */
class EssentialBoundary
{
public:
  /** `nodeShapes`: shape functions at the model's nodes (rows = nodes).
   *  `constrainedDofs`: dofs 3 n + c, ascending. `mass`: per node. */
  EssentialBoundary(const ShapeFunctionTable & nodeShapes,
                    const std::vector<Index> & constrainedDofs,
                    const std::vector<double> & mass);
  ~EssentialBoundary();

  /** Corrects the parameters u (3 per node) so that the interpolated
   *  displacement at constrained dof k equals targets[k]. */
  void Impose(double * u, const std::vector<double> & targets) const;

  /** Point reactions (N), one per constrained dof, from the nodal residual
   *  r = f_int - f_ext at equilibrium (r = Phi_B^T lambda). */
  std::vector<double> Reactions(const double * residual) const;

private:
  struct Component;
  std::vector<std::unique_ptr<Component>> m_Components; // x, y, z
  std::vector<double>                     m_InverseMass;
  std::size_t                             m_ConstrainedCount = 0;
};

} // namespace bmr

#endif
