// The collapse barrier every law carries (private to the core): a pressure
// that resists a unit's volume falling below half its reference volume.
#ifndef bmrCollapseBarrier_h
#define bmrCollapseBarrier_h

#include <algorithm>
#include <cmath>

namespace bmr
{

// Volume ratio below which a cell or integration point resists further collapse.
constexpr double kCollapseVolumeRatio = 0.5;

// Pressure of the collapse barrier at the unit's own volume ratio J: 0 for
// J >= Jc = kCollapseVolumeRatio, -Kc (Jc / J - 1)^2 below (C1 at Jc, unbounded
// as J -> 0). Why: the volumetric term kappa (J - 1) resists collapse with at
// most kappa (4 Pa for CSF of 10 Pa, nu 0.1; 170 Pa for fluid-like CSF), and an
// ANP tetrahedron's own J is not constrained at all, only its nodes' averages;
// so a soft cell squeezed by the tissue around it is crushed until it inverts
// (20-25 mm shifts of Colin27). Physically the fluid has drained and the walls
// of the space meet: below half its volume the cell takes the bulk modulus Kc
// of the tissue around it (SolverSettings::collapseBulkModulus).
inline double
CollapsePressure(double J, double collapseModulus)
{
  const double closing = std::max(0.0, kCollapseVolumeRatio / J - 1.0);
  return -collapseModulus * closing * closing;
}

// The barrier's energy per reference volume: the integral of -CollapsePressure from J to Jc.
inline double
CollapseEnergy(double J, double collapseModulus)
{
  constexpr double Jc = kCollapseVolumeRatio;
  return J >= Jc ? 0.0 : collapseModulus * (Jc * Jc / J - J + 2.0 * Jc * std::log(J / Jc));
}

} // namespace bmr

#endif
