// The force models' entry to the laws (private to the core). The kernels are
// templates on kSecondInvariant, chosen once per pass outside the loop over
// cells, and call ScaledMooneyRivlinFirstPiola<kSecondInvariant>: a model
// whose materials are all neo-Hookean runs the neo-Hookean kernel unchanged
// (no second-invariant table is kept). Elsewhere (energies, stresses for
// output) one function per quantity takes the unit's moduli, secondModulus
// = 0 for the neo-Hookean law.
#ifndef bmrConstitutiveLaw_h
#define bmrConstitutiveLaw_h

#include "bmrMooneyRivlin.h"
#include "bmrNeoHookean.h"

#include <cstddef>
#include <vector>

namespace bmr
{

/** One unit's moduli (internal units): the small-strain shear modulus mu,
 *  secondModulus = 2 C01 (0: neo-Hookean), kappa and the collapse barrier's. */
struct UnitModuli
{
  double mu;
  double secondModulus;
  double kappa;
  double collapseModulus;
};

/** First Piola-Kirchhoff stress of the law (arguments as FirstPiola's). */
inline Eigen::Matrix3d
FirstPiolaOfLaw(const Eigen::Matrix3d & F, const Eigen::Matrix3d & cof, double J, double volumeRatio,
                const UnitModuli & moduli)
{
  if (moduli.secondModulus == 0.0)
  {
    return FirstPiola(F, cof, J, volumeRatio, moduli.mu, moduli.kappa, moduli.collapseModulus);
  }
  return ToEigen(ScaledMooneyRivlinFirstPiola<true>(ToPlain(F), ToPlain(cof), J, moduli.kappa * (volumeRatio - 1.0),
                                                    moduli.mu, moduli.secondModulus, moduli.collapseModulus, 1.0));
}

inline double
StrainEnergyDensityOfLaw(const Eigen::Matrix3d & F, double J, double volumeRatio, const UnitModuli & moduli)
{
  if (moduli.secondModulus == 0.0)
  {
    return StrainEnergyDensity(F, J, volumeRatio, moduli.mu, moduli.kappa, moduli.collapseModulus);
  }
  return MooneyRivlinStrainEnergyDensity(F, J, volumeRatio, moduli.mu, moduli.secondModulus, moduli.kappa,
                                         moduli.collapseModulus);
}

/** The modulus per unit of the law's second invariant (internal units); empty
 *  when no unit has one, which selects the neo-Hookean kernels. */
template <typename MaterialOfUnit>
std::vector<double>
SecondInvariantModuli(std::size_t count, MaterialOfUnit && materialOf, double toInternal)
{
  std::vector<double> moduli(count, 0.0);
  bool                any = false;
  for (std::size_t k = 0; k < count; ++k)
  {
    moduli[k] = materialOf(k).SecondInvariantModulus() * toInternal;
    any = any || moduli[k] != 0.0;
  }
  return any ? moduli : std::vector<double>{};
}

} // namespace bmr

#endif
