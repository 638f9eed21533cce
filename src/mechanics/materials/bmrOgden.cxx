// Ogden-type hyperviscoelastic law of brain tissue (Miller & Chinzei 2002);
// see src/mechanics/include/bmrOgden.h for the law, its sources and its discretization.
#include "bmrOgden.h"

#include "bmrModel.h" // bmr::Error
#include "bmrThreads.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>
#include <utility>

namespace bmr
{
namespace
{

std::string
Number(double value)
{
  std::ostringstream text;
  text.precision(std::numeric_limits<double>::max_digits10);
  text << value;
  return text.str();
}

// Why no stress can be computed from F, or empty (no allocation) when it can.
std::string
DeformationGradientProblem(const Eigen::Matrix3d & F)
{
  if (!F.allFinite())
    return "the deformation gradient has a NaN or infinite entry; check the solve that produced it.";
  const double J = F.determinant();
  if (!(J > 0.0))
    return "the deformation gradient has J = det F = " + Number(J) +
           " <= 0 (inverted or collapsed material); the Ogden stress needs J > 0: check the mesh and the solve.";
  return {};
}

// The elastic response at one F: instantaneous isochoric second Piola stress
// (with mu0) and the volumetric Kirchhoff pressure J kappa (J - 1), from the
// spectral decomposition C = sum_i c_i N_i N_i^T (c_i = lambda_i^2).
struct OgdenElasticState
{
  Eigen::Matrix3d isochoricSecondPiola;
  Eigen::Matrix3d inverseC;
  double          J = 1.0;
  double          pressure = 0.0; // kappa (J - 1), the volumetric Cauchy stress
  double          isochoricEnergy = 0.0;
};

OgdenElasticState
EvaluateElastic(const OgdenViscoelasticMaterial & material, double kappa, const Eigen::Matrix3d & F)
{
  const std::string problem = DeformationGradientProblem(F);
  if (!problem.empty())
    throw Error("Ogden law: " + problem);
  OgdenElasticState state;
  state.J = F.determinant();

  // The iterative solver (not computeDirect) keeps eigenvectors orthonormal
  // for equal or nearly equal stretches; the spectral sums below are then
  // accurate because they never divide by stretch differences.
  const Eigen::Matrix3d                                C = F.transpose() * F;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(C);
  if (eigen.info() != Eigen::Success)
    throw Error("Ogden law: the eigen-decomposition of C = F^T F failed; check the deformation gradient.");
  const Eigen::Vector3d & c = eigen.eigenvalues();
  const Eigen::Matrix3d & N = eigen.eigenvectors();

  // Isochoric stretches to the power alpha: (J^(-2/3) c_i)^(alpha/2).
  const double    cubeRoot = std::cbrt(state.J);
  const double    isochoricScale = 1.0 / (cubeRoot * cubeRoot);
  Eigen::Vector3d powered;
  for (int i = 0; i < 3; ++i)
    powered[i] = std::pow(isochoricScale * c[i], 0.5 * material.alpha);
  const double sum = powered.sum();

  // Principal isochoric Kirchhoff stress tau_i = (2 mu0/alpha)(lbar_i^alpha - sum/3),
  // second Piola s_i = tau_i / c_i.
  const double    factor = 2.0 * material.mu0 / material.alpha;
  Eigen::Vector3d secondPiola;
  for (int i = 0; i < 3; ++i)
    secondPiola[i] = factor * (powered[i] - sum / 3.0) / c[i];
  state.isochoricSecondPiola = N * secondPiola.asDiagonal() * N.transpose();
  state.inverseC = N * c.cwiseInverse().asDiagonal() * N.transpose();
  state.pressure = kappa * (state.J - 1.0);
  state.isochoricEnergy = 2.0 * material.mu0 / (material.alpha * material.alpha) * (sum - 3.0);
  return state;
}

Eigen::Matrix3d
CauchyFromIsochoric(const Eigen::Matrix3d & F, const Eigen::Matrix3d & isochoricSecondPiola, double J, double pressure)
{
  // The volumetric part J kappa (J-1) C^-1 pushes forward to kappa (J-1) I
  // exactly; adding it in Cauchy form avoids the round-off of F C^-1 F^T.
  return F * isochoricSecondPiola * F.transpose() / J + pressure * Eigen::Matrix3d::Identity();
}

} // namespace

double
OgdenViscoelasticMaterial::BulkModulus() const
{
  return 2.0 * mu0 * (1.0 + poissonRatio) / (3.0 * (1.0 - 2.0 * poissonRatio));
}

double
OgdenViscoelasticMaterial::RelaxationModulus(double time) const
{
  double relaxed = 0.0;
  for (std::size_t k = 0; k < g.size(); ++k)
    relaxed += g[k] * -std::expm1(-time / tau[k]);
  return mu0 * (1.0 - relaxed);
}

double
OgdenViscoelasticMaterial::LongTermFraction() const
{
  double sum = 0.0;
  for (double fraction : g)
    sum += fraction;
  return 1.0 - sum;
}

void
OgdenViscoelasticMaterial::Validate() const
{
  const std::string prefix = "Ogden material: ";
  if (!std::isfinite(mu0) || mu0 <= 0.0)
    throw Error(prefix + "mu0 = " + Number(mu0) +
                " Pa; the instantaneous shear modulus must be positive and finite (Miller & Chinzei 2002: 842 Pa).");
  if (!std::isfinite(alpha) || alpha == 0.0)
    throw Error(prefix + "alpha = " + Number(alpha) +
                "; the Ogden exponent must be finite and nonzero (Miller & Chinzei 2002: -4.7).");
  if (g.size() != tau.size())
    throw Error(prefix + "g has " + std::to_string(g.size()) + " Prony terms but tau has " +
                std::to_string(tau.size()) + "; give one relaxation time tau per fraction g.");
  double sum = 0.0;
  for (std::size_t k = 0; k < g.size(); ++k)
  {
    const std::string term = "[" + std::to_string(k) + "]";
    if (!std::isfinite(g[k]) || g[k] < 0.0)
      throw Error(prefix + "g" + term + " = " + Number(g[k]) + "; a Prony fraction must be finite and >= 0.");
    if (!std::isfinite(tau[k]) || tau[k] <= 0.0)
      throw Error(prefix + "tau" + term + " = " + Number(tau[k]) +
                  " s; a relaxation time must be positive and finite.");
    sum += g[k];
  }
  if (!(sum < 1.0))
    throw Error(prefix + "the sum of g is " + Number(sum) +
                " >= 1, which leaves no long-term stiffness (mu(infinity) <= 0); make the fractions sum to less than 1.");
  if (!std::isfinite(poissonRatio) || poissonRatio <= -1.0 || poissonRatio >= 0.5)
    throw Error(prefix + "poissonRatio = " + Number(poissonRatio) +
                "; it sets the bulk modulus and must lie in (-1, 0.5) (default 0.49, nearly incompressible).");
}

double
OgdenElasticEnergyDensity(const OgdenViscoelasticMaterial & material, const Eigen::Matrix3d & F)
{
  material.Validate();
  const double            kappa = material.BulkModulus();
  const OgdenElasticState state = EvaluateElastic(material, kappa, F);
  return state.isochoricEnergy + 0.5 * kappa * (state.J - 1.0) * (state.J - 1.0);
}

Eigen::Matrix3d
OgdenElasticSecondPiola(const OgdenViscoelasticMaterial & material, const Eigen::Matrix3d & F)
{
  material.Validate();
  const OgdenElasticState state = EvaluateElastic(material, material.BulkModulus(), F);
  return state.isochoricSecondPiola + state.J * state.pressure * state.inverseC;
}

Eigen::Matrix3d
OgdenElasticCauchy(const OgdenViscoelasticMaterial & material, const Eigen::Matrix3d & F)
{
  material.Validate();
  const OgdenElasticState state = EvaluateElastic(material, material.BulkModulus(), F);
  return CauchyFromIsochoric(F, state.isochoricSecondPiola, state.J, state.pressure);
}

OgdenViscoelasticPoint::OgdenViscoelasticPoint(const OgdenViscoelasticMaterial & material)
  : OgdenViscoelasticPoint(std::make_shared<const OgdenViscoelasticMaterial>(material))
{}

OgdenViscoelasticPoint::OgdenViscoelasticPoint(std::shared_ptr<const OgdenViscoelasticMaterial> material)
  : m_Material(std::move(material))
{
  if (!m_Material)
    throw Error("Ogden viscoelastic point: no material given; pass an OgdenViscoelasticMaterial.");
  m_Material->Validate();
  m_History.resize(m_Material->g.size());
  Reset();
}

void
OgdenViscoelasticPoint::Reset()
{
  m_PreviousInstantaneous.setZero();
  for (Eigen::Matrix3d & history : m_History)
    history.setZero();
  m_Time = 0.0;
}

Eigen::Matrix3d
OgdenViscoelasticPoint::Update(const Eigen::Matrix3d & F, double dt)
{
  if (!std::isfinite(dt) || dt < 0.0)
    throw Error("Ogden viscoelastic point: time step dt = " + Number(dt) +
                " s; give a finite dt >= 0 (0 applies the deformation as an instantaneous jump).");
  const OgdenViscoelasticMaterial & material = *m_Material;
  // Everything that can throw happens before the state changes.
  const OgdenElasticState state = EvaluateElastic(material, material.BulkModulus(), F);

  const Eigen::Matrix3d increment = state.isochoricSecondPiola - m_PreviousInstantaneous;
  Eigen::Matrix3d       isochoric = material.LongTermFraction() * state.isochoricSecondPiola;
  for (std::size_t k = 0; k < m_History.size(); ++k)
  {
    // Exact integral of exp(-(t - s)/tau) dS0/ds over the step for S0 linear
    // in time: decay = exp(-x), weight = (1 - exp(-x)) / x, x = dt/tau (-> 1 as dt -> 0).
    const double x = dt / material.tau[k];
    const double decay = std::exp(-x);
    const double weight = x > 0.0 ? -std::expm1(-x) / x : 1.0;
    m_History[k] = decay * m_History[k] + (material.g[k] * weight) * increment;
    isochoric += m_History[k];
  }
  m_PreviousInstantaneous = state.isochoricSecondPiola;
  m_Time += dt;
  return CauchyFromIsochoric(F, isochoric, state.J, state.pressure);
}

std::vector<OgdenViscoelasticPoint>
MakeOgdenViscoelasticPoints(const OgdenViscoelasticMaterial & material, std::size_t count)
{
  const OgdenViscoelasticPoint prototype(material);
  return std::vector<OgdenViscoelasticPoint>(count, prototype);
}

void
UpdateOgdenViscoelasticPoints(std::vector<OgdenViscoelasticPoint> & points,
                              const std::vector<Eigen::Matrix3d> &  deformationGradients,
                              double                                dt,
                              std::vector<Eigen::Matrix3d> &        cauchyStress,
                              int                                   threads)
{
  if (deformationGradients.size() != points.size())
    throw Error("Ogden batch update: " + std::to_string(deformationGradients.size()) +
                " deformation gradients for " + std::to_string(points.size()) +
                " points; give one deformation gradient per point.");
  if (!std::isfinite(dt) || dt < 0.0)
    throw Error("Ogden batch update: time step dt = " + Number(dt) + " s; give a finite dt >= 0.");
  // Check every input first, so that a bad cell leaves no point half-updated.
  for (std::size_t i = 0; i < points.size(); ++i)
  {
    const std::string problem = DeformationGradientProblem(deformationGradients[i]);
    if (!problem.empty())
      throw Error("Ogden batch update, cell " + std::to_string(i) + ": " + problem);
  }

  cauchyStress.resize(points.size());
  const std::ptrdiff_t count = static_cast<std::ptrdiff_t>(points.size());
  std::ptrdiff_t       firstFailure = count;
  std::string          failure;
#pragma omp parallel for schedule(static) num_threads(ThreadCount(threads))
  for (std::ptrdiff_t i = 0; i < count; ++i)
  {
    // Inputs are checked above; this only guards against an exception
    // escaping the parallel region (undefined behaviour).
    try
    {
      cauchyStress[i] = points[i].Update(deformationGradients[i], dt);
    }
    catch (const std::exception & error)
    {
#pragma omp critical(bmrOgdenBatchFailure)
      if (i < firstFailure)
      {
        firstFailure = i;
        failure = error.what();
      }
    }
  }
  if (firstFailure < count)
    throw Error("Ogden batch update, cell " + std::to_string(firstFailure) + ": " + failure +
                " Other cells were updated: Reset() the points before reusing them.");
}

} // namespace bmr
