// Frictionless rigid contact for the meshless discretization: the rigid
// surfaces' projections (RigidContact) act on the MLS-interpolated positions
// of the slave nodes, and the parameters change by the mass-weighted least
// amount that closes the gaps (a solve of the slaves' coupled system, then
// Kaczmarz sweeps to the tolerance). Private to the core; the solver holds
// one per meshless model with contact surfaces.
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
  ~MeshlessContact();

  /** EBCIEM's constrained dofs (null, empty: none): a slave whose support
   *  touches their support moves so as to keep every prescribed value. */
  void SetEssentialBoundary(const EssentialBoundary * essential, const std::vector<Index> & constrainedDofs);

  /** Moves the parameters u so that no slave's interpolated position lies
   *  beyond a surface; marks the slaves in contact in `inContact`.
   *  `dofConstrained`: nodally imposed dofs keep their parameter (without
   *  EBCIEM). Adds the Kaczmarz sweeps it ran to `sweeps`. */
  void Enforce(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass,
               const std::vector<char> & dofConstrained, double lengthScale, int threads, long long & sweeps);

  /** Forgets what the last solve left (the slaves' tracked motion, the last
   *  factorisation), so that each solve of a solver gives the same result. */
  void StartSolve();

  /** Every contact's slave nodes, ascending, once each. */
  const std::vector<Index> & SlaveNodes() const { return m_Slaves; }

private:
  void StartTrackingMotion(const double * u);
  void InterpolateMovedSlaves(const double * u, int threads);
  /** Adds the slaves found penetrating to the active set; true if any was new. */
  bool DetectPenetrations(std::vector<char> & inContact, const std::vector<char> & dofConstrained, int threads);
  template <typename Weight>
  void PrepareRows(const Weight & weight);
  /** Closes the active slaves' gaps by the least mass-weighted change at
   *  once (their coupled system, solved); leaves u as it was where that
   *  system is singular, for the sweeps alone. */
  template <typename Weight>
  void SolveActiveGaps(double * u, const Weight & weight, const std::vector<double> & inverseMass, double tolerance);
  /** Factorises the active system; false if it is singular. */
  bool Factorise();
  /** Conjugate gradients on the active system preconditioned by the last
   *  factorisation; false if they do not reach `tolerance` soon. */
  bool SolveWithEarlierFactorisation(Eigen::VectorXd & multipliers, double tolerance);
  /** The lower triangle of the active rows' system A P^T (m_System). */
  template <typename Weight>
  void AssembleActiveSystem(const Weight & weight);
  /** a_t . P_s per axis for every slave t whose support meets P_s's, s = m_Slaves[slave]. */
  template <typename Weight>
  void ComputeOverlaps(Index slave, const std::array<EssentialBoundary::Coupling, 3> * coupling, const Weight & weight);
  /** The gap n . c - n . Phi_s u of a slave in contact. */
  double Gap(Index node, const double * u) const;
  /** Adds multiplier P_a to u, P_a the direction of active row a (its
   *  mass-weighted n . phi_s, less EBCIEM's share): a sweep's correction,
   *  and the direct solve's change row by row. */
  template <typename Weight>
  void AddDirection(double * u, const Weight & weight, std::size_t a, double multiplier) const;
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
  struct ActiveSystem;
  std::unique_ptr<ActiveSystem> m_System; // the direct solve's matrix, factorisation and work arrays
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
