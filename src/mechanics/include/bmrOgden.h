// Ogden-type hyperviscoelastic law of brain tissue (Miller & Chinzei,
// "Mechanical properties of brain tissue in tension", J. Biomech. 35 (2002)
// 483-490), used to re-evaluate stresses near a surgical tool from the
// deformation gradients a neo-Hookean solve computed. Plain C++17 + Eigen.
//
// The law
// -------
//   W = (2 / alpha^2) * integral_0^t mu(t - s) d/ds (l1^alpha + l2^alpha + l3^alpha - 3) ds
//       + kappa/2 (J - 1)^2
//   mu(t) = mu0 (1 - sum_k g_k (1 - exp(-t / tau_k)))
//
// * l_i = J^(-1/3) lambda_i are the isochoric principal stretches. Miller &
//   Chinzei take the tissue as incompressible (J = 1, l_i = lambda_i); the
//   isochoric split is the standard way to carry their W over to a
//   compressible F (Simo, CMAME 60 (1987) 153-173; Holzapfel, "Nonlinear
//   Solid Mechanics", 2000).
// * The volumetric term kappa/2 (J - 1)^2 is ours, not the paper's: it is the
//   project's neo-Hookean volumetric term (DESIGN.md sec. 3), so that the law
//   can be evaluated on the F of a compressible solve. kappa comes from the
//   Poisson ratio as for the neo-Hookean material, with mu0 as the shear
//   modulus: kappa = 2 mu0 (1 + nu) / (3 (1 - 2 nu)); nu = 0.49 gives
//   41.8 kPa. The volumetric part is elastic: only the isochoric part relaxes.
// * mu0 is the instantaneous small-strain shear modulus (uniaxial small-strain
//   modulus 3 mu0). Uniaxial incompressible stretch l gives the Cauchy stress
//   difference sigma_11 - sigma_22 = (2 mu0 / alpha)(l^alpha - l^(-alpha/2)).
//
// Parameters (defaults), Miller & Chinzei 2002, fitted to uniaxial tension of
// swine brain at strain rates 0.64 s^-1 and 0.0064 s^-1:
//   mu0 = 842 Pa, alpha = -4.7, g1 = 0.450, g2 = 0.365, tau1 = 0.5 s, tau2 = 50 s.
// The strain rates, journal, pages and DOI (10.1016/S0021-9290(01)00234-2)
// were checked against the paper's abstract; the parameter values are as
// commonly cited (the paper's full text could not be consulted).
//
// Viscoelasticity in three dimensions
// -----------------------------------
// The hereditary integral is applied to the isochoric second Piola-Kirchhoff
// stress (quasi-linear viscoelasticity in the Total Lagrangian form of Simo
// 1987 and Holzapfel 2000), with S0(t) the instantaneous isochoric stress of
// F(t) computed with mu0:
//   S_iso(t) = integral_0^t g(t - s) dS0/ds ds,  g(t) = mu(t) / mu0
//            = g_inf S0(t) + sum_k H_k(t),        g_inf = 1 - sum_k g_k,
//   H_k(t)   = g_k integral_0^t exp(-(t - s) / tau_k) dS0/ds ds.
// For a step of F held constant this is exactly sigma_elastic mu(t)/mu0, the
// paper's relaxation law. Under a ramp the stress measure that is convolved
// matters (a hereditary integral of the nominal or the Cauchy stress is an
// equally quasi-linear but different law), so curves at finite strain rates
// may differ somewhat from the paper's uniaxial predictions; this module
// was not compared against the paper's curves.
//
// Discretization: each step integrates the exponential kernel exactly with
// S0 taken as linear in time over the step (Taylor, Pister & Goudreau, IJNME
// 2 (1970) 45-59):
//   H_k <- exp(-dt/tau_k) H_k + g_k (tau_k/dt)(1 - exp(-dt/tau_k)) (S0_new - S0_old).
// It is unconditionally stable for any dt/tau_k and exact for piecewise-linear
// S0; for smoothly varying F the error is second order in dt (measured in
// test/bmrOgdenTest.cxx on Miller & Chinzei's ramps to a stretch of 1.3: the
// error falls 4.00x per halving of dt at 0.64 s^-1, and 3.4x -> 3.99x at
// 0.0064 s^-1, whose coarsest dt is 4.7 tau1; 20 steps per ramp give 7e-5
// and 4e-4 relative error). A jump of F between two calls is spread linearly
// over dt, a first-order error of about g_k dt / (2 tau_k); call Update(F, 0)
// to apply a true instantaneous jump.
#ifndef bmrOgden_h
#define bmrOgden_h

#include <Eigen/Core>

#include <cstddef>
#include <memory>
#include <vector>

namespace bmr
{

/** Parameters of the Ogden hyperviscoelastic law; defaults are Miller &
 *  Chinzei 2002 (tension). Units: Pa, s. */
struct OgdenViscoelasticMaterial
{
  double              mu0 = 842.0;     // Pa, instantaneous shear modulus
  double              alpha = -4.7;    // Ogden exponent; negative: stiffer in compression than in tension
  std::vector<double> g{ 0.450, 0.365 }; // Prony fractions of mu0 that relax
  std::vector<double> tau{ 0.5, 50.0 };  // s, relaxation times, one per g
  double              poissonRatio = 0.49; // sets kappa (the paper's tissue is incompressible)

  /** kappa = 2 mu0 (1 + nu) / (3 (1 - 2 nu)) (Pa), as for the neo-Hookean material. */
  double BulkModulus() const;
  /** mu(t) (Pa): the shear relaxation modulus at time t >= 0 after a step. */
  double RelaxationModulus(double time) const;
  /** g_inf = 1 - sum g_k = mu(infinity) / mu0. */
  double LongTermFraction() const;

  /** Throws bmr::Error naming the first bad parameter. */
  void Validate() const;
};

// Instantaneous (elastic, t = 0) response with modulus mu0. Principal
// stretches come from the eigen-decomposition of C = F^T F and the stress is
// assembled in spectral form, sum_i s_i N_i N_i^T, which never divides by
// stretch differences: equal stretches need no special case. F must be finite
// with J = det F > 0, else bmr::Error. The material is validated.

/** Strain energy density W (Pa = J/m^3) of the elastic law. */
double
OgdenElasticEnergyDensity(const OgdenViscoelasticMaterial & material, const Eigen::Matrix3d & F);

/** Second Piola-Kirchhoff stress (Pa), isochoric plus volumetric. */
Eigen::Matrix3d
OgdenElasticSecondPiola(const OgdenViscoelasticMaterial & material, const Eigen::Matrix3d & F);

/** Cauchy stress (Pa): sigma = F S F^T / J. */
Eigen::Matrix3d
OgdenElasticCauchy(const OgdenViscoelasticMaterial & material, const Eigen::Matrix3d & F);

/** Viscoelastic state of one integration point (cell): the previous
 *  instantaneous isochoric second Piola-Kirchhoff stress S0 and one 3x3
 *  history H_k per Prony term. Starts undeformed (F = I) at t = 0. Points that
 *  share a material share one read-only copy of it. */
class OgdenViscoelasticPoint
{
public:
  /** Validates the material (bmr::Error on a bad parameter). */
  explicit OgdenViscoelasticPoint(const OgdenViscoelasticMaterial & material);
  explicit OgdenViscoelasticPoint(std::shared_ptr<const OgdenViscoelasticMaterial> material);

  /** Advances the state by dt >= 0 (s) to the deformation gradient F and
   *  returns the Cauchy stress (Pa). dt = 0 applies F as an instantaneous
   *  jump. On error (J <= 0, non-finite F, bad dt) throws bmr::Error and leaves
   *  the state unchanged. */
  Eigen::Matrix3d Update(const Eigen::Matrix3d & F, double dt);

  /** Back to the undeformed state at t = 0 with no history. */
  void Reset();

  /** Time (s) summed over the updates since construction or Reset(). */
  double Time() const { return m_Time; }

  const OgdenViscoelasticMaterial & Material() const { return *m_Material; }

private:
  std::shared_ptr<const OgdenViscoelasticMaterial> m_Material;
  Eigen::Matrix3d                                  m_PreviousInstantaneous; // S0 at the last update
  std::vector<Eigen::Matrix3d>                     m_History;               // H_k
  double                                           m_Time = 0.0;
};

/** `count` undeformed points sharing one copy of the material. */
std::vector<OgdenViscoelasticPoint>
MakeOgdenViscoelasticPoints(const OgdenViscoelasticMaterial & material, std::size_t count);

/** Updates every point i with deformationGradients[i] over dt and writes its
 *  Cauchy stress to cauchyStress[i] (resized to match). OpenMP over cells
 *  (`threads` <= 0: OpenMP's default); each cell is independent, so the
 *  result is bitwise the same for any thread count. Every F is checked
 *  (finite, J > 0) before any point changes, so a bad input throws bmr::Error
 *  naming the first bad cell and leaves all points as they were. */
void
UpdateOgdenViscoelasticPoints(std::vector<OgdenViscoelasticPoint> &  points,
                              const std::vector<Eigen::Matrix3d> &   deformationGradients,
                              double                                 dt,
                              std::vector<Eigen::Matrix3d> &         cauchyStress,
                              int                                    threads = 0);

} // namespace bmr

#endif
