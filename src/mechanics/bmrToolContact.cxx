#include "bmrToolContact.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>

namespace bmr
{

namespace
{
constexpr int kProjectionPasses = 4;

Eigen::Matrix3d
RotationMatrix(const Vector3 & rotation)
{
  const double angle = rotation.norm();
  return angle > 0.0 ? Eigen::AngleAxisd(angle, rotation / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
}
} // namespace

ToolContact::ToolContact(const RigidTool & tool, std::vector<Index> slaveNodes, const std::vector<Vector3> & reference)
  : m_Tool(tool)
  , m_SlaveNodes(std::move(slaveNodes))
{
  for (const Index node : m_SlaveNodes)
  {
    m_Reference.push_back(reference[static_cast<std::size_t>(node)]);
  }
  if (tool.shape == RigidTool::Shape::Surface)
  {
    ContactSurface surface = tool.surface;
    surface.name = "tool '" + tool.name + "'";
    surface.bodySide = ContactSurface::Side::Outside;
    m_Surface = std::make_unique<RigidContact>(surface, m_SlaveNodes, reference);
    if (!m_Surface->IsClosed())
    {
      throw Error("the surface of tool '" + tool.name +
                  "' is not closed: a tool must be a closed surface (every edge shared by two triangles).");
    }
  }
  MoveTo(tool.trajectory.front().time);
  // A tool that starts inside the body would throw its nodes out in the first step.
  const std::vector<double> zero(3 * reference.size(), 0.0);
  const double              depth = MaxPenetration(zero.data());
  if (depth > 1e-9)
  {
    throw Error("tool '" + tool.name + "' starts " + std::to_string(depth) +
                " mm inside the body; start its trajectory outside (or touching) the body.");
  }
}

ToolContact::~ToolContact() = default;

void
ToolContact::MoveTo(double time)
{
  m_Pose = ToolPoseAt(m_Tool, time);
  m_Rotation = RotationMatrix(m_Pose.rotation);
  if (m_Surface)
  {
    m_Surface->SetPose(m_Rotation, m_Pose.position);
  }
}

double
ToolContact::SweptSphereDistance(const Vector3 & p, Vector3 & closest) const
{
  // The probe is a sphere swept along the segment (0, 0, 0)-(0, 0, length), the
  // spatula one swept over the rectangle |x| <= width/2, y = 0, 0 <= z <= length.
  const double halfWidth = m_Tool.shape == RigidTool::Shape::Spatula ? 0.5 * m_Tool.width : 0.0;
  const Vector3 core(std::clamp(p.x(), -halfWidth, halfWidth), 0.0, std::clamp(p.z(), 0.0, m_Tool.length));
  const Vector3 offset(p.x() - core.x(), p.y(), p.z() - core.z());
  const double  distance = offset.norm();
  // On the core itself the direction is undefined: push out along the blade's normal (y).
  const Vector3 direction = distance > 0.0 ? Vector3(offset / distance) : Vector3::UnitY();
  closest = core + m_Tool.radius * direction;
  return distance - m_Tool.radius;
}

ToolLoad
ToolContact::Enforce(double *                    u,
                     const double *              previous,
                     const std::vector<char> &   dofConstrained,
                     std::vector<char> &         inContact,
                     const std::vector<double> & inverseMass,
                     double                      alpha,
                     int                         threads)
{
  const auto count = static_cast<Index>(m_SlaveNodes.size());
  if (m_Surface)
  {
    m_Surface->Enforce(u, dofConstrained, inContact, threads, &m_Corrections);
  }
  else
  {
    m_Corrections.assign(m_SlaveNodes.size(), Vector3::Zero());
#pragma omp parallel for num_threads(threads) schedule(static)
    for (Index i = 0; i < count; ++i)
    {
      const Index  node = m_SlaveNodes[static_cast<std::size_t>(i)];
      const char * held = &dofConstrained[3 * static_cast<std::size_t>(node)];
      if (held[0] && held[1] && held[2])
      {
        continue;
      }
      double *      un = u + 3 * static_cast<std::size_t>(node);
      const Vector3 start(un[0], un[1], un[2]);
      Vector3       closest;
      if (SweptSphereDistance(ToTool(m_Reference[static_cast<std::size_t>(i)] + start), closest) >= 0.0)
      {
        continue;
      }
      // Held components keep their value: alternate projection and restoring them (as RigidContact does).
      Vector3 displacement = start;
      for (int pass = 0; pass < kProjectionPasses; ++pass)
      {
        displacement = FromTool(closest) - m_Reference[static_cast<std::size_t>(i)];
        for (int k = 0; k < 3; ++k)
        {
          if (held[k])
          {
            displacement[k] = start[k];
          }
        }
        if (!(held[0] || held[1] || held[2]) ||
            SweptSphereDistance(ToTool(m_Reference[static_cast<std::size_t>(i)] + displacement), closest) >= 0.0)
        {
          break;
        }
      }
      un[0] = displacement.x();
      un[1] = displacement.y();
      un[2] = displacement.z();
      m_Corrections[static_cast<std::size_t>(i)] = displacement - start;
      inContact[static_cast<std::size_t>(node)] = 1;
    }
  }
  ToolLoad load;
  m_Touching.clear();
  for (std::size_t i = 0; i < m_SlaveNodes.size(); ++i)
  {
    const Vector3 & correction = m_Corrections[i];
    if (correction.isZero(0.0))
    {
      continue;
    }
    m_Touching.push_back(m_SlaveNodes[i]);
    const std::size_t node = static_cast<std::size_t>(m_SlaveNodes[i]);
    Vector3           onNode;
    for (int k = 0; k < 3; ++k)
    {
      onNode[k] = correction[k] / (alpha * inverseMass[3 * node + static_cast<std::size_t>(k)]);
    }
    const Vector3 position(m_Reference[i] + Vector3(u[3 * node], u[3 * node + 1], u[3 * node + 2]));
    load.force -= onNode;
    load.moment -= (position - m_Pose.position).cross(onNode);
    // The force acts over the step in which the node moved from its previous position.
    const Vector3 moved(u[3 * node] - previous[3 * node], u[3 * node + 1] - previous[3 * node + 1],
                        u[3 * node + 2] - previous[3 * node + 2]);
    load.work += onNode.dot(moved);
    ++load.contactNodes;
  }
  return load;
}

double
ToolContact::Distance(const Vector3 & point) const
{
  if (m_Surface)
  {
    return m_Surface->SignedDistance(point);
  }
  Vector3 closest;
  return SweptSphereDistance(ToTool(point), closest);
}

double
ToolContact::MaxPenetration(const double * u) const
{
  if (m_Surface)
  {
    return m_Surface->MaxPenetration(u);
  }
  double deepest = 0.0;
  for (std::size_t i = 0; i < m_SlaveNodes.size(); ++i)
  {
    const double * un = u + 3 * static_cast<std::size_t>(m_SlaveNodes[i]);
    Vector3        closest;
    deepest = std::max(deepest, -SweptSphereDistance(ToTool(m_Reference[i] + Vector3(un[0], un[1], un[2])), closest));
  }
  return deepest;
}

} // namespace bmr
