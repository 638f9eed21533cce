// Essential boundary conditions of the meshless discretization imposed with
// EBCIEM (Joldes, Chowdhury, Wittek, Miller 2017): after each explicit step the
// nodal parameters are corrected so that the MLS-interpolated displacement,
// not the parameter, takes the prescribed value at every constrained node.
// Private to the core.
#ifndef bmrEssentialBoundary_h
#define bmrEssentialBoundary_h

#include "bmrMeshless.h"

#include <array>
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
   *  displacement at constrained dof k equals targets[k]. The three axes'
   *  solves are independent and write their own components of u, so up to
   *  three threads share them; the result does not depend on `threads`. */
  void Impose(double * u, const std::vector<double> & targets, int threads) const;

  /** What EBCIEM's projection would take back from a change of the
   *  parameters along one node's shape functions, per axis i:
   *  z_i = M^-1 A_i^T G_i^-1 A_i M^-1 phi_s (A_i: the rows constrained in i,
   *  G_i = A_i M^-1 A_i^T). A change M^-1 phi_s e_i - z_i e_i moves the
   *  node's interpolated value and keeps every constrained value, so
   *  constraints on the node (contact) can be met without undoing the
   *  prescribed values, and without alternating with Impose.
   *  `projected` = phi_s . z_i, what the change loses of its effect on the
   *  node itself. Empty `nodes` where the node's support does not touch the
   *  constrained rows of axis i. Computed on first use and kept (three
   *  solves); not thread-safe. */
  struct Coupling
  {
    std::vector<Index>  nodes;  // ascending
    std::vector<double> values; // z_i at those nodes
    double              projected = 0.0;
  };
  const std::array<Coupling, 3> & CouplingOf(Index node) const;

  /** Point reactions (N), one per constrained dof, from the nodal residual
   *  r = f_int - f_ext at equilibrium (r = Phi_B^T lambda). */
  std::vector<double> Reactions(const double * residual) const;

private:
  struct Component;
  std::vector<std::unique_ptr<Component>> m_Components; // x, y, z
  std::vector<double>                     m_InverseMass;
  const ShapeFunctionTable &              m_NodeShapes;
  mutable std::vector<std::unique_ptr<std::array<Coupling, 3>>> m_Couplings; // per node, on first use
  std::size_t                             m_ConstrainedCount = 0;
};

} // namespace bmr

#endif
