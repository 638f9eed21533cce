// CalculiX harness, private: the proximal stabilisation's anchors and springs
// (CalculixSettings::stabilisationStiffness) and the *BOUNDARY lines that hold
// the anchors (bmrCalculixStabilisation.cxx).
#ifndef bmrCalculixStabilisation_h
#define bmrCalculixStabilisation_h

#include "bmrCalculix.h"

#include <array>
#include <iosfwd>
#include <string>
#include <vector>

namespace bmr
{

/** The springs' stiffness (N/mm) of a stage: stabilisationStiffness divided
 *  by stabilisationSoftening once per stage before it. */
double
StabilisationStiffness(const CalculixSettings & settings, int stage);

/** Per stage ("family") two anchor sets A and B of one anchor per sprung mesh
 *  node, numbered after the mesh nodes in blocks: stage 0 A, stage 0 B,
 *  stage 1 A, ... Each sprung component of a node has a SPRING2 to its
 *  anchor in every set; an anchor's other components are held at 0. */
class CalculixAnchors
{
public:
  /** `sprung[d][n]`: mesh node n is tied in component d (kept: mesh and
   *  settings must outlive the anchors). No anchors unless
   *  settings.stabilisationStiffness > 0. */
  CalculixAnchors(const CalculixMesh & mesh, const std::array<std::vector<char>, 3> & sprung,
                  const CalculixSettings & settings);

  bool Empty() const { return m_Nodes.empty(); }
  int  Families() const { return m_Families; }
  static std::string SetName(int family, int set);

  /** *NODE (at their nodes' positions) and one *NSET per anchor set. */
  void WriteNodes(std::ostream & stream) const;
  /** SPRING2 elements numbered after `lastElement`, one *SPRING per stage, set and component. */
  void WriteSprings(std::ostream & stream, std::size_t lastElement) const;
  /** Lines of a *BOUNDARY card: the components without a spring, at 0. */
  void WriteUnsprungHolds(std::ostream & stream) const;
  /** A *BOUNDARY card holding `set` of `family`: at the reference state
   *  (or, given `start`, per mesh node, displaced by it), or (fixed) where
   *  the step before left it. */
  void WriteHold(std::ostream & stream, int family, int set, bool fixed,
                 const std::vector<Vector3> * start = nullptr) const;

private:
  std::size_t Anchor(std::size_t i, int family, int set) const; // 1-based

  const CalculixMesh &             m_Mesh;
  std::array<std::vector<char>, 3> m_Sprung;
  std::vector<std::size_t>         m_Nodes; // the sprung mesh nodes
  int                              m_Families = 0;
  const CalculixSettings &         m_Settings;
};

} // namespace bmr

#endif
