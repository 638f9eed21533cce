// The one place where user units become the solver's internal units.
//
// User-facing: lengths mm, moduli and stresses Pa, density kg/m^3, time s,
// accelerations mm/s^2, forces N, energies J.
// Internal (consistent mm-N-s-tonne system): lengths mm, stresses MPa (N/mm^2),
// density t/mm^3, forces N, energies N*mm.
#ifndef bmrUnits_h
#define bmrUnits_h

namespace bmr
{
namespace units
{
constexpr double PascalToInternal = 1e-6;            // Pa -> N/mm^2
constexpr double InternalToPascal = 1e6;             // N/mm^2 -> Pa
constexpr double DensityToInternal = 1e-12;          // kg/m^3 -> t/mm^3
constexpr double InternalEnergyToJoule = 1e-3;       // N*mm -> J
constexpr double StandardGravity = 9810.0;           // g -> mm/s^2
} // namespace units
} // namespace bmr

#endif
