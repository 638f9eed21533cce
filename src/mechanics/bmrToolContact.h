// A rigid surgical tool moving along its trajectory: frictionless contact with
// separation (the projection of Joldes et al., MICCAI 2009, as for the skull,
// against a moving master), and the load the tissue puts on the tool. Private
// to the core.
#ifndef bmrToolContact_h
#define bmrToolContact_h

#include "bmrContact.h"
#include "bmrModel.h"

#include <memory>
#include <vector>

namespace bmr
{

/** What the tissue does to the tool in one step. */
struct ToolLoad
{
  Vector3     force = Vector3::Zero();  // N, on the tool
  Vector3     moment = Vector3::Zero(); // N mm, on the tool, about the tool frame's origin
  double      work = 0.0;               // N mm done on the tissue during the step
  std::size_t contactNodes = 0;
};

class ToolContact
{
public:
  ToolContact(const RigidTool & tool, std::vector<Index> slaveNodes, const std::vector<Vector3> & reference);
  ~ToolContact();
  ToolContact(const ToolContact &) = delete;
  ToolContact & operator=(const ToolContact &) = delete;

  /** Puts the tool where its trajectory has it at `time` (s). */
  void MoveTo(double time);
  const ToolPose & Pose() const { return m_Pose; }
  const RigidTool & Tool() const { return m_Tool; }

  /** Moves slave nodes that entered the tool onto its surface (u: 3 per
   *  node, mm; held components keep their value) and marks them in
   *  `inContact`. The force that moved node i by d_i in a central-difference
   *  step u+ = ... + alpha M^-1 (f_ext - f_int) is M d_i / alpha; the tool
   *  carries minus their sum (and moment), summed in node order so that the
   *  result does not depend on the thread count. `previous` (3 per node): the
   *  displacements of the last step, for the work of the contact forces. */
  ToolLoad Enforce(double *                    u,
                   const double *              previous,
                   const std::vector<char> &   dofConstrained,
                   std::vector<char> &         inContact,
                   const std::vector<double> & inverseMass,
                   double                      alpha,
                   int                         threads);

  /** Deepest slave node inside the tool (mm) at displacements u. */
  double MaxPenetration(const double * u) const;

  /** Distance (mm) of a point of the model's frame to the tool at its current pose; negative inside. */
  double Distance(const Vector3 & point) const;

  /** Slave nodes the last Enforce moved (in node order). */
  const std::vector<Index> & TouchingNodes() const { return m_Touching; }

private:
  Vector3 ToTool(const Vector3 & x) const { return m_Rotation.transpose() * (x - m_Pose.position); }
  Vector3 FromTool(const Vector3 & p) const { return m_Rotation * p + m_Pose.position; }
  /** Analytic shapes: signed distance in the tool frame and the closest surface point. */
  double SweptSphereDistance(const Vector3 & p, Vector3 & closest) const;

  RigidTool                     m_Tool;
  std::vector<Index>            m_SlaveNodes;
  std::vector<Vector3>          m_Reference;
  ToolPose                      m_Pose;
  Eigen::Matrix3d               m_Rotation = Eigen::Matrix3d::Identity();
  std::unique_ptr<RigidContact> m_Surface; // Shape::Surface
  std::vector<Vector3>          m_Corrections;
  std::vector<Index>            m_Touching;
};

} // namespace bmr

#endif
