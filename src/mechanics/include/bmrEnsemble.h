// An ensemble of solves around one model: the uncertain mechanical inputs
// (gravity's size, Young's moduli, Poisson's ratio, the gap to a rigid
// contact surface) drawn per member from stated distributions, and the
// spread of the members' displacements per node. The ITK face is
// itk::BiomechanicalUncertaintyFilter; the registration's ensemble
// (bmrBrainShiftUncertainty.h) adds the measurements' noise and the exposed
// region. docs/registration.md, Uncertainty, says why each distribution.
#ifndef bmrEnsemble_h
#define bmrEnsemble_h

#include "bmrModel.h"

#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

namespace bmr
{

/** The ensemble's size and the mechanical inputs' distributions; a member
 *  draws each one independently (one random stream, seeded, so the ensemble
 *  repeats exactly). A spread of 0 (or an empty range) turns that input off. */
struct EnsembleSettings
{
  /** Ensemble members (at least 2). */
  int           members = 0;
  std::uint64_t seed = 1;
  /** Gravity's size as a fraction of the nominal gravity: uniform in
   *  [gravityLow, gravityHigh]; equal: not perturbed. */
  double gravityLow = 1.0;
  double gravityHigh = 1.0;
  /** Young's moduli: every material's scaled by exp(N(0, youngsModulusSpread^2));
   *  one factor per member for all materials (the stiffness of the whole
   *  brain is what the literature's ranges vary, e.g. Miller's 3 kPa within a
   *  factor of 2). 0: not perturbed. */
  double youngsModulusSpread = 0.3;
  /** Young's moduli per tissue class: each class of the model's tissue
   *  mixture (Model::tissueMixture: e.g. CSF, grey and white matter, the
   *  tumour) scaled by its own factor exp(N(0, tissueModulusSpread^2)) on top
   *  of the common one, and the materials mixed again from the classes
   *  (RemixTissueModuli): how stiff the tissues are against each other, e.g.
   *  grey against white matter or a tumour against the brain. 0: not
   *  perturbed (the default; a model without a mixture cannot draw it). */
  double tissueModulusSpread = 0.0;
  /** Poisson's ratio of the nearly incompressible tissues (the materials with
   *  nu > 0.4; the soft CSF keeps its own): shifted by one offset per member,
   *  so that the parenchyma's nu is uniform in [poissonLow, poissonHigh].
   *  Both 0: not perturbed. */
  double poissonLow = 0.45;
  double poissonHigh = 0.499;
  /** The gap between the body and its rigid contact surfaces: widened by a
   *  normal deviate of this standard deviation (mm) as the surface's contact
   *  offset (ContactSurface::offset, the level set of its distance behind
   *  it); negative: narrowed, at most to a tenth of the nominal gap (the
   *  drawer's contactGap), by moving the surface's vertices towards the body
   *  (docs/solver.md, contact offset, says why each). 0: not perturbed. */
  double skullGapSpread = 0.0;
};

/** Throws bmr::Error ("uncertainty: ...") naming the setting that is out of range. */
void
CheckEnsembleSettings(const EnsembleSettings & settings);

/** What one member drew. */
struct EnsembleDraw
{
  double gravityFactor = 1.0; // of the nominal gravity
  double modulusFactor = 1.0;
  double poissonOffset = 0.0;
  double skullOffset = 0.0; // mm, outward: a wider gap
  /** Per class of the model's tissue mixture (empty: not drawn). */
  std::vector<double> tissueFactors;
};

/** A member's draws and how its solve ended. */
struct EnsembleMember : EnsembleDraw
{
  bool        converged = false;
  bool        failed = false; // the solve threw (e.g. an inverted cell)
  int         steps = 0;
  std::string message;
};

/** Materials with a Poisson's ratio above this are the nearly incompressible
 *  tissues whose ratio the ensemble draws (the soft CSF keeps its own). */
constexpr double kIncompressibleFrom = 0.4;

/** The members' draws in order from one seeded stream: per member the
 *  modulus, gravity, Poisson's ratio, gap and the classes' moduli, each only
 *  when its distribution is on. A caller that draws more per member (the
 *  registration's noise and exposed radius) draws it from the same stream
 *  after Next(). */
class EnsembleDrawer
{
public:
  /** `nominal`: the model whose largest Poisson's ratio the offsets are
   *  measured from; `contactGap`: its gap to the contact surface (mm), which
   *  a narrower draw keeps at least a tenth of. Checks the settings, that
   *  a gap spread comes with a positive gap and a spread of the classes'
   *  moduli with a tissue mixture. */
  EnsembleDrawer(const EnsembleSettings & settings, const Model & nominal, double contactGap);

  EnsembleDraw
  Next();
  /** A standard normal deviate from the stream. */
  double
  StandardNormal()
  {
    return m_Standard(m_Random);
  }
  std::mt19937_64 &
  Random()
  {
    return m_Random;
  }

private:
  EnsembleSettings                       m_Settings;
  double                                 m_NominalPoisson;
  double                                 m_ContactGap;
  std::size_t                            m_TissueClasses;
  std::mt19937_64                        m_Random;
  std::normal_distribution<double>       m_Standard{ 0.0, 1.0 }; // times each spread
  std::uniform_real_distribution<double> m_Gravity;
  std::uniform_real_distribution<double> m_Poisson;
};

/** The model with the draw's materials (moduli scaled by the common
 *  factor, the nearly incompressible tissues' Poisson's ratio shifted,
 *  within [0.4, 0.4999]) and body acceleration (its factor times `gravity`).
 *  The classes' factors are not applied here: the mixing rule is the
 *  material mapping's (RemixTissueModuli, before this). */
Model
DrawnModel(const Model & model, const EnsembleDraw & draw, const Vector3 & gravity);

/** Whether the draw leaves the model's reference configuration as it is (its
 *  precomputation still fits). */
inline bool
KeepsMaterials(const EnsembleDraw & draw)
{
  return draw.modulusFactor == 1.0 && draw.poissonOffset == 0.0 && draw.tissueFactors.empty();
}

/** `surface` moved `depth` (mm) towards the body along its area-weighted
 *  vertex normals: a narrower gap. Towards the body a closed surface crosses
 *  itself only in pockets narrower than twice the depth (a skull made at a
 *  1.5 mm gap after a 1 mm closing has none narrower than 3 mm, and the depth
 *  stays below 0.9 of the gap). */
ContactSurface
NarrowedContactSurface(const ContactSurface & surface, double depth);

/** Linear-interpolation percentile (q in [0, 1]) of `values`, which it sorts; 0 when empty. */
double
Percentile(std::vector<double> & values, double q);

/** Per node the mean of the members `used` and the 95th percentile over them
 *  of |u_i - u_mean| (mm). */
struct EnsembleSpread
{
  std::vector<Vector3> mean;
  std::vector<double>  p95;
};

EnsembleSpread
SpreadOfMembers(const std::vector<std::vector<Vector3>> & displacements, const std::vector<std::size_t> & used);

/** Calls solve(member, memberThreads) for members 0..count-1 on `threads`
 *  OpenMP threads (0: OpenMP's default), dynamically scheduled: one thread a
 *  member when there are at least as many members as threads, else the
 *  threads shared among them. `solve` must not throw (it records a
 *  failure). */
void
ForEachMember(int count, int threads, const std::function<void(int member, int memberThreads)> & solve);

} // namespace bmr

#endif
