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
    EnforceMeshlessContact(u, inContact, inverseMass);
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

void
Solver::Impl::EnforceMeshlessContact(double * u, std::vector<char> & inContact, const std::vector<double> & inverseMass)
{
  // Contact acts on the MLS-interpolated positions of the slave nodes. A
  // slave in contact contributes one constraint, n . (Phi_s u) = n . c, with c
  // its projection onto the surface and n the surface normal there: the
  // linearised gap, so the tangential motion stays free (frictionless).
  // Holding all three components at c instead can, in principle, let the
  // corrections carry tangential forces that depend on the masses (not seen
  // on a flat plane: MeshlessContact.SlidingIsUnresisted passes with both).
  // The shape functions do not interpolate: where nodes are close together a
  // node's own parameter barely moves its interpolated position, and adding
  // each slave's correction to its own parameter (a Jacobi iteration on the
  // shape-function matrix) pumps neighbouring parameters apart in opposite
  // directions, a mode with almost no stiffness that never settles (seen on
  // Colin27). Instead the parameters change by the mass-weighted least amount
  // that meets every constraint, as EBCIEM does for prescribed displacements:
  // Kaczmarz sweeps over the slaves in contact, which converge whatever the
  // coupling. A slave once in contact keeps its constraint for the rest of
  // the step (a neighbour's correction must not release it and make the
  // contact set flicker from step to step); slaves pushed into the surface by
  // the corrections join the set, and the sweeps repeat.
  // With EBCIEM the steady state must meet the prescribed values and the
  // contacts together. Projecting onto each in turn converges to that
  // (alternating projections) but slowly where a slave's support touches a
  // constrained node's: on the meshless Colin27 scene 9 of EBCIEM's
  // projections a step, 22 % of the solve, for 3 such slaves among 80.
  // Such a slave's correction moves instead along its shape functions minus
  // what EBCIEM would take back (EssentialBoundary::CouplingOf), which keeps
  // every prescribed value: the sweeps then converge to the same least
  // change with no projection in between.
  constexpr int kDetections = 8;
  constexpr int kSweeps = 64;
  if (contacts.empty())
  {
    return;
  }
  // Nodal imposition keeps constrained parameters fixed; EBCIEM restores the
  // constrained interpolated values instead.
  const auto weight = [&](Index dof) { return essential || !dofConstrained[dof] ? inverseMass[dof] : 0.0; };
  projectedBuffer.resize(3 * model.nodes.size(), 0.0);
  contactNormals.resize(model.nodes.size(), Vector3::Zero());
  contactTargets.resize(model.nodes.size(), 0.0);
  std::fill(inContact.begin(), inContact.end(), 0);
  activeSlaves.clear();
  const Index  slaveCount = static_cast<Index>(contactSlaves.size());
  const double tolerance = 1e-9 * lengthScale;
  const std::size_t dofCount = 3 * model.nodes.size();
  if (parameterSnapshot.size() != dofCount)
  {
    // Slaves far from every surface need no interpolation (most of them, most
    // steps): a slave's interpolated position moves by at most
    // sum_K |phi_K| times the largest parameter change, so it is
    // interpolated again only once the parameters' accumulated largest
    // change could carry it across its clearance. On the meshless Colin27
    // scene (12,054 slaves) 93 % of the interpolations are skipped: 3.0 s of
    // the solve before, 1.4 s with this pass over the parameters.
    parameterSnapshot.assign(u, u + dofCount);
    parameterMotion = 0.0;
    slaveMotionMark.assign(contactSlaves.size(), 0.0);
    slaveClearance.assign(model.nodes.size(), 0.0);
    slaveShapeSum.resize(contactSlaves.size());
    for (std::size_t s = 0; s < contactSlaves.size(); ++s)
    {
      const Index node = contactSlaves[s];
      double      sum = 0.0;
      for (Index k = nodeShapes.offsets[node]; k < nodeShapes.offsets[node + 1]; ++k)
      {
        sum += std::abs(nodeShapes.values[k]);
      }
      slaveShapeSum[s] = sum;
    }
  }
  for (int detection = 0; detection < kDetections; ++detection)
  {
    double largestChange = 0.0;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(max : largestChange)
    for (std::size_t d = 0; d < dofCount; ++d)
    {
      largestChange = std::max(largestChange, std::abs(u[d] - parameterSnapshot[d]));
      parameterSnapshot[d] = u[d];
    }
    parameterMotion += largestChange;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (Index s = 0; s < slaveCount; ++s)
    {
      const Index node = contactSlaves[s];
      if (slaveShapeSum[s] * (parameterMotion - slaveMotionMark[s]) < slaveClearance[node])
      {
        continue; // its position in the buffer is where the clearance was measured
      }
      slaveMotionMark[s] = parameterMotion;
      const Vector3 value = nodeShapes.Interpolate(node, u);
      for (int i = 0; i < 3; ++i)
      {
        projectedBuffer[3 * node + i] = value[i];
      }
    }
    penetrating.assign(model.nodes.size(), 0);
    bool added = false;
    for (const Index node : contactSlaves)
    {
      slaveClearance[node] = std::numeric_limits<double>::infinity();
    }
    for (auto & contact : contacts)
    {
      contact->Enforce(projectedBuffer.data(), dofConstrained, penetrating, threads, nullptr, &slaveNormals,
                       &surfaceClearances);
      const std::vector<Index> & slaves = contact->SlaveNodes();
      for (std::size_t k = 0; k < slaves.size(); ++k)
      {
        slaveClearance[slaves[k]] = std::min(slaveClearance[slaves[k]], surfaceClearances[k]);
      }
      for (std::size_t k = 0; k < slaves.size(); ++k)
      {
        const Index     node = slaves[k];
        const Vector3 & normal = slaveNormals[k];
        if (!penetrating[node] || !(normal.norm() > 0.0)) // penetrating another surface
        {
          continue;
        }
        contactNormals[node] = normal;
        contactTargets[node] = normal.dot(Vector3(projectedBuffer[3 * node], projectedBuffer[3 * node + 1],
                                                  projectedBuffer[3 * node + 2]));
        if (!inContact[node])
        {
          inContact[node] = 1;
          activeSlaves.push_back(node);
          added = true;
        }
      }
    }
    if (!added && detection > 0)
    {
      break;
    }
    std::sort(activeSlaves.begin(), activeSlaves.end());
    activeNorms.assign(activeSlaves.size(), 0.0);
    activeCouplings.assign(activeSlaves.size(), nullptr);
    for (std::size_t a = 0; a < activeSlaves.size(); ++a)
    {
      const Index     node = activeSlaves[a];
      const Vector3 & n = contactNormals[node];
      bool            coupled = false;
      for (Index k = nodeShapes.offsets[node]; k < nodeShapes.offsets[node + 1]; ++k)
      {
        const double phi = nodeShapes.values[k];
        for (int i = 0; i < 3; ++i)
        {
          const Index d = 3 * nodeShapes.nodes[k] + i;
          activeNorms[a] += phi * phi * n[i] * n[i] * weight(d);
          coupled = coupled || (essential && essentialSupport[d]);
        }
      }
      if (coupled)
      {
        activeCouplings[a] = &essential->CouplingOf(node);
        const double plain = activeNorms[a];
        for (int i = 0; i < 3; ++i)
        {
          activeNorms[a] -= n[i] * n[i] * (*activeCouplings[a])[i].projected;
        }
        if (activeNorms[a] <= 1e-9 * plain) // the row lies in the span of the prescribed rows
        {
          activeNorms[a] = 0.0;
        }
      }
    }
    // Kaczmarz sweeps until the gaps close.
    for (int sweep = 0; sweep < kSweeps; ++sweep)
    {
      ++parts.contactSweeps;
      double largest = 0.0;
      for (std::size_t a = 0; a < activeSlaves.size(); ++a)
      {
        const Index     node = activeSlaves[a];
        const Vector3 & n = contactNormals[node];
        const double    gap = contactTargets[node] - n.dot(nodeShapes.Interpolate(node, u));
        largest = std::max(largest, std::abs(gap));
        if (!(activeNorms[a] > 0.0))
        {
          continue;
        }
        const double multiplier = gap / activeNorms[a];
        for (Index k = nodeShapes.offsets[node]; k < nodeShapes.offsets[node + 1]; ++k)
        {
          for (int i = 0; i < 3; ++i)
          {
            const Index d = 3 * nodeShapes.nodes[k] + i;
            u[d] += multiplier * nodeShapes.values[k] * n[i] * weight(d);
          }
        }
        if (activeCouplings[a])
        {
          for (int i = 0; i < 3; ++i)
          {
            const EssentialBoundary::Coupling & coupling = (*activeCouplings[a])[i];
            for (std::size_t j = 0; j < coupling.nodes.size(); ++j)
            {
              u[3 * coupling.nodes[j] + i] -= multiplier * n[i] * coupling.values[j];
            }
          }
        }
      }
      if (largest <= tolerance)
      {
        break;
      }
    }
  }
}

} // namespace bmr
