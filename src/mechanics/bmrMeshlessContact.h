// Frictionless rigid contact for the meshless discretization: the rigid
// surfaces' projections (RigidContact) act on the MLS-interpolated positions
// of the slave nodes, and the parameters change by the mass-weighted least
// amount that closes the gaps (Kaczmarz sweeps, as EBCIEM does for prescribed
// displacements). Private to the core; the solver holds one per meshless
// model with contact surfaces.
#ifndef bmrMeshlessContact_h
#define bmrMeshlessContact_h

#include "bmrContact.h"
#include "bmrEssentialBoundary.h"
#include "bmrMeshless.h"

#include <array>
#include <memory>
#include <vector>

namespace bmr
{

class MeshlessContact
{
public:
  /** `contacts` and `nodeShapes` (shape functions at the nodes) are the
   *  solver's and must outlive this; the slaves are every contact's, once. */
  MeshlessContact(const std::vector<std::unique_ptr<RigidContact>> & contacts, const ShapeFunctionTable & nodeShapes,
                  Index nodeCount);

  /** EBCIEM's constrained dofs (null, empty: none): a slave whose support
   *  touches their support moves so as to keep every prescribed value. */
  void SetEssentialBoundary(const EssentialBoundary * essential, const std::vector<Index> & constrainedDofs);

  /** Moves the parameters u so that no slave's interpolated position lies
   *  beyond a surface; marks the slaves in contact in `inContact`.
   *  `dofConstrained`: nodally imposed dofs keep their parameter (without
   *  EBCIEM). Adds the Kaczmarz sweeps it ran to `sweeps`. */
  void Enforce(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass,
               const std::vector<char> & dofConstrained, double lengthScale, int threads, long long & sweeps);

  /** Every contact's slave nodes, ascending, once each. */
  const std::vector<Index> & SlaveNodes() const { return m_Slaves; }

private:
  void StartTrackingMotion(const double * u);
  void InterpolateMovedSlaves(const double * u, int threads);
  /** Adds the slaves found penetrating to the active set; true if any was new. */
  bool DetectPenetrations(std::vector<char> & inContact, const std::vector<char> & dofConstrained, int threads);
  template <typename Weight>
  void PrepareRows(const Weight & weight);
  template <typename Weight>
  void Sweep(double * u, const Weight & weight, double tolerance, long long & sweeps) const;

  const std::vector<std::unique_ptr<RigidContact>> & m_Contacts;
  const ShapeFunctionTable &                         m_NodeShapes;
  std::vector<Index>                                 m_Slaves;
  const EssentialBoundary *                          m_Essential = nullptr;
  std::vector<char>                                  m_EssentialSupport; // per dof: in the support of a constrained dof

  // Per step: interpolated positions projected onto the surfaces, the slaves
  // penetrating at the last detection with the surface normals there (per
  // contact), per node in contact its normal and target n . u, those slaves
  // (ascending) and, per slave, sum_K phi_K^2 (n . M_K^-1 n) over its movable
  // parameters, less EBCIEM's share (m_Couplings, null where none).
  std::vector<double>                                             m_Projected;
  std::vector<char>                                               m_Penetrating;
  std::vector<Vector3>                                            m_SlaveNormals;
  std::vector<Vector3>                                            m_Normals;
  std::vector<double>                                             m_Targets;
  std::vector<Index>                                              m_Active;
  std::vector<double>                                             m_RowNorms;
  std::vector<const std::array<EssentialBoundary::Coupling, 3> *> m_Couplings;
  // Which slaves to interpolate: the parameters at the last detection, the
  // sum of their largest changes since the first step, per slave that sum
  // when it was last interpolated and sum_K |phi_K|, and per node its
  // clearance from the surfaces there (mm).
  std::vector<double> m_ParameterSnapshot;
  double              m_ParameterMotion = 0.0;
  std::vector<double> m_SlaveMotionMark;
  std::vector<double> m_SlaveShapeSum;
  std::vector<double> m_Clearance;
  std::vector<double> m_SurfaceClearances; // per slave of one contact, from RigidContact::Enforce
};

} // namespace bmr

#endif
