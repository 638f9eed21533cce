#include "bmrSolverImpl.h"

#include "bmrUnits.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace bmr
{

void
Solver::Impl::EnforceTools(double * u, const double * previous, std::vector<char> & inContact,
                           const std::vector<double> & inverseMass, double alpha, double time)
{
  for (std::size_t k = 0; k < tools.size(); ++k)
  {
    const std::vector<ToolPose> & trajectory = tools[k]->Tool().trajectory;
    const bool ramp = settings.integrator == Integrator::DynamicRelaxation;
    tools[k]->MoveTo(ramp ? trajectory.front().time + time * (trajectory.back().time - trajectory.front().time) : time);
    toolLoads[k] = tools[k]->Enforce(u, previous, dofConstrained, inContact, inverseMass, alpha, threads);
  }
}

void
Solver::Impl::RecordTools(std::vector<ToolHistory> & histories) const
{
  histories.resize(tools.size());
  for (std::size_t k = 0; k < tools.size(); ++k)
  {
    ToolHistory & history = histories[k];
    history.name = tools[k]->Tool().name;
    history.time.push_back(tools[k]->Pose().time);
    history.position.push_back(tools[k]->Pose().position);
    history.force.push_back(toolLoads[k].force);
    history.moment.push_back(toolLoads[k].moment);
    history.contactNodes.push_back(static_cast<int>(toolLoads[k].contactNodes));
    history.work += toolLoads[k].work * units::InternalEnergyToJoule;
    if (stressRegions[k])
    {
      history.correctedForce.push_back(correctedForces[k]);
      history.peakStress.push_back(stressRegions[k]->PeakVonMises());
    }
  }
}

void
Solver::Impl::EnforceContact(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass)
{
  if (meshless)
  {
    if (meshlessContact)
    {
      meshlessContact->Enforce(u, inContact, inverseMass, dofConstrained, lengthScale, threads, parts.contactSweeps);
    }
    return;
  }
  std::fill(inContact.begin(), inContact.end(), 0);
  // Only dynamic relaxation uses the corrections (ForgetProjectionVelocities).
  const bool relaxation = settings.integrator == Integrator::DynamicRelaxation;
  contactCorrections.resize(relaxation ? contacts.size() : 0);
  for (std::size_t k = 0; k < contacts.size(); ++k)
  {
    contacts[k]->Enforce(u, dofConstrained, inContact, threads, relaxation ? &contactCorrections[k] : nullptr);
  }
}

void
Solver::Impl::ForgetProjectionVelocities(const std::vector<double> & u, std::vector<double> & uPrevious) const
{
  // A projection moves a slave onto the surface within one step; in the
  // central-difference update that jump becomes a velocity along the
  // normal, which carries the node on by about beta times the jump each
  // step. A node judged 0.77 mm beyond the skull at a sharp fold of tiny
  // triangles (the frontal 15 mm scene of docs/model-building.md) went
  // 2.1 mm in three steps that way and inverted its cell. Dynamic
  // relaxation seeks only the steady state: the projected node keeps its
  // tangential velocity and loses the normal one.
  for (std::size_t k = 0; k < contactCorrections.size(); ++k)
  {
    const std::vector<Index> & slaves = contacts[k]->SlaveNodes();
    for (std::size_t i = 0; i < contactCorrections[k].size(); ++i)
    {
      const double length = contactCorrections[k][i].norm();
      if (!(length > 0.0))
      {
        continue;
      }
      const Vector3     normal = contactCorrections[k][i] / length;
      const std::size_t d = 3 * static_cast<std::size_t>(slaves[i]);
      const Vector3     velocity(u[d] - uPrevious[d], u[d + 1] - uPrevious[d + 1], u[d + 2] - uPrevious[d + 2]);
      const Vector3     normalVelocity = velocity.dot(normal) * normal;
      for (int j = 0; j < 3; ++j)
      {
        uPrevious[d + j] += normalVelocity[j];
      }
    }
  }
}

} // namespace bmr
