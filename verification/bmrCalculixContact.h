// CalculiX harness, private: the rigid contact surfaces' part of the mesh and
// the deck (bmrCalculixContact.cxx), and the number format both parts write.
#ifndef bmrCalculixContact_h
#define bmrCalculixContact_h

#include "bmrCalculix.h"

#include <iosfwd>
#include <string>

namespace bmr
{

/** Shortest round-trip text that fits CalculiX's 20-character fields. */
std::string
FormatDouble(double value);

/** Appends the model's contact surfaces to the mesh: mesh.contactPairs, their
 *  wedges' nodes after the mesh's nodes (mesh.firstRigidNode). Call once the
 *  cells and mid-edge nodes are in the mesh. Throws bmr::Error for a surface
 *  without slave faces or with a degenerate triangle. */
void
AddCalculixContactPairs(const Model & model, CalculixMesh & mesh);

/** The masters' wedges, the surfaces (the slave as element faces) and the
 *  frictionless node-to-face penalty interaction (model definition, before the step). */
void
WriteCalculixContactPairs(std::ostream & stream, const Model & model, const CalculixMesh & mesh,
                          const CalculixSettings & settings);

} // namespace bmr

#endif
