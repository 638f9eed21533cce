// The solver's Total Lagrangian precomputation as an object of its own
// (SolverPrecomputation): made once, stored, and handed to every Solver of
// the same model. The force models list their members once
// (VisitMembers) for writing, reading and nothing else.
#include "bmrSolverImpl.h"

#include "bmrBinaryStream.h"
#include "bmrFingerprint.h"

#include <omp.h>

#include <cstring>
#include <sstream>

namespace bmr
{

namespace
{

constexpr char        kPrecomputationMagic[8] = { 'B', 'M', 'R', 'P', 'R', 'E', 'C', 'O' };
// 2: the materials' laws (the second-invariant moduli); 1 (every material neo-Hookean) is still read.
constexpr std::uint32_t kPrecomputationVersion = 2;

/** Throws the reader's error unless every index lies in [0, bound). */
template <typename Container>
void
CheckIndices(BinaryReader & in, const Container & indices, Index bound, const char * what)
{
  for (const auto & entry : indices)
  {
    if constexpr (std::is_integral_v<std::decay_t<decltype(entry)>>)
    {
      if (entry < 0 || entry >= bound)
      {
        in.Fail(std::string(what) + " holds index " + std::to_string(entry) + " of " + std::to_string(bound));
      }
    }
    else
    {
      CheckIndices(in, entry, bound, what);
    }
  }
}

void
CheckSize(BinaryReader & in, std::size_t size, std::size_t expected, const char * what)
{
  if (size != expected)
  {
    in.Fail(std::string(what) + " has " + std::to_string(size) + " values, not " + std::to_string(expected));
  }
}

/** Offsets that rise from 0 to `end` (none at all: nothing scheduled). */
void
CheckOffsets(BinaryReader & in, const std::vector<Index> & offsets, Index end, const char * what)
{
  if (offsets.empty())
  {
    if (end != 0)
    {
      in.Fail(std::string(what) + " are missing");
    }
    return;
  }
  for (std::size_t k = 0; k + 1 < offsets.size(); ++k)
  {
    if (offsets[k] > offsets[k + 1])
    {
      in.Fail(std::string(what) + " fall at " + std::to_string(k));
    }
  }
  if (offsets.front() != 0 || offsets.back() != end)
  {
    in.Fail(std::string(what) + " do not run from 0 to " + std::to_string(end));
  }
}

/** The intervals that offsets mark. */
Index
Intervals(const std::vector<Index> & offsets)
{
  return offsets.empty() ? 0 : static_cast<Index>(offsets.size()) - 1;
}

} // namespace

std::uint64_t
ReferenceConfigurationKey(const Model & model)
{
  Fingerprint key;
  key.Add(model.discretization);
  key.Add(model.nodes.size());
  for (const Vector3 & node : model.nodes)
  {
    key.Add(node);
  }
  key.Add(model.cells.size());
  for (const Cell & cell : model.cells)
  {
    key.Add(cell.type);
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      key.Add(cell.nodes[a]);
    }
    key.Add(cell.material);
  }
  key.Add(model.materials.size());
  for (const Material & material : model.materials)
  {
    key.Add(material.youngsModulus);
    key.Add(material.poissonRatio);
    key.Add(material.density);
    if (material.law != MaterialLaw::NeoHookean) // neo-Hookean models keep the keys of format version 1
    {
      key.Add(material.law);
      for (const MaterialParameter & parameter : MaterialParameters())
      {
        key.Add(material.*parameter.value);
      }
    }
  }
  if (model.discretization == Discretization::Meshless)
  {
    const MeshlessDiscretization & meshless = model.meshless;
    key.Add(meshless.shapeFunctions.basis);
    key.Add(meshless.shapeFunctions.dilatation);
    key.Add(meshless.shapeFunctions.quadraticRegularization);
    key.Add(meshless.integrationPoints.size());
    for (std::size_t p = 0; p < meshless.integrationPoints.size(); ++p)
    {
      key.Add(meshless.integrationPoints[p]);
      key.Add(meshless.integrationWeights[p]);
      key.Add(meshless.integrationMaterials[p]);
    }
  }
  return key.Value();
}

// ---------------------------------------------------------------------------
// The force models' copies and files
// ---------------------------------------------------------------------------

std::unique_ptr<ForceModel>
FiniteElementForceModel::Clone(int threads) const
{
  auto copy = std::make_unique<FiniteElementForceModel>(*this);
  copy->m_Threads = std::max(1, threads);
  return copy;
}

void
FiniteElementForceModel::Write(BinaryWriter & out) const
{
  VisitMembers(*this, out);
}

std::unique_ptr<FiniteElementForceModel>
FiniteElementForceModel::Read(BinaryReader & in, bool laws)
{
  std::unique_ptr<FiniteElementForceModel> model(new FiniteElementForceModel());
  VisitMembers(*model, in, laws);
  const FiniteElementForceModel & m = *model;
  const std::size_t hexCount = m.m_HexNodes.size();
  const std::size_t tetCount = m.m_TetNodes.size();
  const std::size_t cellCount = hexCount + tetCount;
  CheckIndices(in, m.m_HexNodes, m.m_NodeCount, "the hexahedra's nodes");
  CheckIndices(in, m.m_TetNodes, m.m_NodeCount, "the tetrahedra's nodes");
  CheckSize(in, m.m_HexB.size(), 24 * hexCount, "the hexahedra's gradients");
  CheckSize(in, m.m_HexXH.size(), 12 * hexCount, "the hexahedra's hourglass basis");
  CheckSize(in, m.m_HexHourglassStiffness.size(), m.m_HourglassControl ? hexCount : m.m_HexHourglassStiffness.size(),
            "the hourglass stiffnesses");
  CheckSize(in, m.m_TetB.size(), 12 * tetCount, "the tetrahedra's gradients");
  CheckSize(in, m.m_TetAveraged.size(), tetCount, "the tetrahedra's averaging flags");
  CheckSize(in, m.m_NodalPressure.size(), static_cast<std::size_t>(m.m_NodeCount), "the nodal pressures");
  if (model->UsesAverageNodalPressure())
  {
    CheckSize(in, m.m_TetJacobian.size(), tetCount, "the tetrahedra's Jacobians");
    CheckSize(in, m.m_NodeTetOffsets.size(), static_cast<std::size_t>(m.m_NodeCount) + 1, "the nodes' tetrahedron offsets");
    CheckOffsets(in, m.m_NodeTetOffsets, static_cast<Index>(m.m_NodeTets.size()), "the nodes' tetrahedron offsets");
    CheckIndices(in, m.m_NodeTets, static_cast<Index>(tetCount), "the nodes' tetrahedra");
    CheckSize(in, m.m_NodeTetWeights.size(), m.m_NodeTets.size(), "the nodes' tetrahedron weights");
    CheckSize(in, m.m_NodalVolume.size(), static_cast<std::size_t>(m.m_NodeCount), "the nodal volumes");
    CheckSize(in, m.m_NodalBulkModulus.size(), static_cast<std::size_t>(m.m_NodeCount), "the nodal bulk moduli");
  }
  for (const auto * perCell : { &m.m_Volume, &m.m_Mu, &m.m_Kappa, &m.m_Collapse, &m.m_Density, &m.m_WaveBound,
                                &m.m_CollapseWaveBound })
  {
    CheckSize(in, perCell->size(), cellCount, "a per-cell table");
  }
  if (!m.m_SecondModulus.empty())
  {
    CheckSize(in, m.m_SecondModulus.size(), cellCount, "the second-invariant moduli");
  }
  CheckSize(in, m.m_ModelCell.size(), cellCount, "the kernel's cells");
  CheckIndices(in, m.m_ModelCell, static_cast<Index>(m.m_CellTypes.size()), "the kernel's cells");
  CheckOffsets(in, m.m_HexBlockOffsets, static_cast<Index>(hexCount), "the hexahedral blocks");
  CheckOffsets(in, m.m_TetBlockOffsets, static_cast<Index>(tetCount), "the tetrahedral blocks");
  CheckOffsets(in, m.m_HexColourOffsets, Intervals(m.m_HexBlockOffsets), "the hexahedral colours");
  CheckOffsets(in, m.m_TetColourOffsets, Intervals(m.m_TetBlockOffsets), "the tetrahedral colours");
  CheckSize(in, m.m_FirstTouchOffsets.size(),
            static_cast<std::size_t>(Intervals(m.m_HexBlockOffsets) + Intervals(m.m_TetBlockOffsets) + 1),
            "the blocks' first touches");
  CheckOffsets(in, m.m_FirstTouchOffsets, static_cast<Index>(m.m_FirstTouchNodes.size()), "the blocks' first touches");
  CheckIndices(in, m.m_FirstTouchNodes, m.m_NodeCount, "the blocks' first touches");
  CheckIndices(in, m.m_UntouchedNodes, m.m_NodeCount, "the untouched nodes");
  return model;
}

std::unique_ptr<ForceModel>
MeshlessForceModel::Clone(int threads) const
{
  auto copy = std::make_unique<MeshlessForceModel>(*this);
  copy->m_Threads = std::max(1, threads);
  return copy;
}

void
MeshlessForceModel::Write(BinaryWriter & out) const
{
  VisitMembers(*this, out);
}

std::unique_ptr<MeshlessForceModel>
MeshlessForceModel::Read(BinaryReader & in, bool laws)
{
  std::unique_ptr<MeshlessForceModel> model(new MeshlessForceModel());
  VisitMembers(*model, in, laws);
  const MeshlessForceModel & m = *model;
  const std::size_t pointCount = m.m_Positions.size();
  const auto        nodeCount = static_cast<std::size_t>(m.m_NodeCount);
  for (const auto * perPoint : { &m.m_Weight, &m.m_Mu, &m.m_Kappa, &m.m_Collapse, &m.m_Density, &m.m_WaveBound })
  {
    CheckSize(in, perPoint->size(), pointCount, "a per-point table");
  }
  CheckSize(in, m.m_KernelPoint.size(), pointCount, "the kernel's points");
  CheckIndices(in, m.m_KernelPoint, static_cast<Index>(pointCount), "the kernel's points");
  CheckSize(in, m.m_KernelIndexOfPoint.size(), pointCount, "the points' kernel index");
  CheckIndices(in, m.m_KernelIndexOfPoint, static_cast<Index>(pointCount), "the points' kernel index");
  CheckSize(in, m.m_KernelOffsets.size(), pointCount + 1, "the kernel's rows");
  CheckOffsets(in, m.m_KernelOffsets, static_cast<Index>(m.m_KernelNodes.size()), "the kernel's rows");
  CheckIndices(in, m.m_KernelNodes, m.m_NodeCount, "the kernel's nodes");
  CheckSize(in, m.m_KernelGradients.size(), 3 * m.m_KernelNodes.size() + 1, "the kernel's gradients");
  CheckSize(in, m.m_KernelMaterial.size(), 4 * pointCount, "the kernel's materials");
  if (!m.m_KernelSecondModulus.empty())
  {
    CheckSize(in, m.m_KernelSecondModulus.size(), pointCount, "the second-invariant moduli");
  }
  CheckOffsets(in, m.m_KernelBlockOffsets, static_cast<Index>(pointCount), "the kernel's blocks");
  CheckOffsets(in, m.m_KernelColourOffsets, Intervals(m.m_KernelBlockOffsets), "the kernel's colours");
  if (!m.m_Numbering.IsPermutation(m.m_NodeCount))
  {
    in.Fail("the kernel's numbering of the nodes is not a permutation of them");
  }
  model->m_PaddedDisplacements.assign(4 * nodeCount, 0.0);
  model->m_PaddedForces.assign(4 * nodeCount, 0.0);
  return model;
}

std::unique_ptr<ForceModel>
MakeForceModel(const Model & model, const SolverSettings & settings, int threads, ShapeFunctionTable & nodeShapes)
{
  if (model.discretization != Discretization::Meshless)
  {
    return std::make_unique<FiniteElementForceModel>(model, settings, threads);
  }
  const auto shapeFunctions = MovingLeastSquares::ForModel(model);
  auto       forces = std::make_unique<MeshlessForceModel>(
    model, shapeFunctions->Evaluate(model.meshless.integrationPoints, true, threads, "integration point"), settings,
    threads);
  nodeShapes = shapeFunctions->Evaluate(model.nodes, false, threads, "node");
  return forces;
}

// ---------------------------------------------------------------------------
// SolverPrecomputation
// ---------------------------------------------------------------------------

SolverPrecomputation::SolverPrecomputation(const Model & model, const SolverSettings & settings)
  : m_Impl(std::make_unique<Impl>())
{
  model.Validate();
  const int threads = settings.threads > 0 ? settings.threads : omp_get_max_threads();
  Impl &    state = *m_Impl;
  state.modelKey = ReferenceConfigurationKey(model);
  state.nodeCount = static_cast<Index>(model.nodes.size());
  state.meshless = model.discretization == Discretization::Meshless;
  state.tetrahedron = settings.tetrahedron;
  state.hourglassCoefficient = settings.hourglassCoefficient;
  state.collapseBulkModulus = settings.collapseBulkModulus;
  state.forces = MakeForceModel(model, settings, threads, state.nodeShapes);
}

SolverPrecomputation::SolverPrecomputation(std::unique_ptr<Impl> impl)
  : m_Impl(std::move(impl))
{}

SolverPrecomputation::~SolverPrecomputation() = default;
SolverPrecomputation::SolverPrecomputation(SolverPrecomputation &&) noexcept = default;
SolverPrecomputation & SolverPrecomputation::operator=(SolverPrecomputation &&) noexcept = default;

std::string
SolverPrecomputation::Mismatch(const Model & model, const SolverSettings & settings) const
{
  const Impl &       state = *m_Impl;
  std::ostringstream words;
  if (state.meshless != (model.discretization == Discretization::Meshless))
  {
    words << "for a " << (state.meshless ? "meshless" : "finite-element") << " model, not a "
          << (state.meshless ? "finite-element" : "meshless") << " one";
  }
  else if (state.nodeCount != static_cast<Index>(model.nodes.size()) || state.modelKey != ReferenceConfigurationKey(model))
  {
    words << "for another model (" << state.nodeCount << " nodes; this one has " << model.nodes.size()
          << (state.nodeCount == static_cast<Index>(model.nodes.size()) ? ", placed, connected or of materials otherwise"
                                                                        : "")
          << ")";
  }
  else if (!state.meshless && state.tetrahedron != settings.tetrahedron)
  {
    words << "with the " << (state.tetrahedron == TetrahedronFormulation::Linear ? "linear" : "ANP")
          << " tetrahedron formulation, not the " << (settings.tetrahedron == TetrahedronFormulation::Linear ? "linear" : "ANP");
  }
  else if (!state.meshless && state.hourglassCoefficient != settings.hourglassCoefficient)
  {
    words << "with hourglass coefficient " << state.hourglassCoefficient << ", not " << settings.hourglassCoefficient;
  }
  else if (state.collapseBulkModulus != settings.collapseBulkModulus)
  {
    words << "with collapse bulk modulus " << state.collapseBulkModulus << " Pa, not " << settings.collapseBulkModulus
          << " Pa";
  }
  return words.str();
}

SolverSettings
SolverPrecomputation::Settings() const
{
  SolverSettings settings;
  settings.tetrahedron = m_Impl->tetrahedron;
  settings.hourglassCoefficient = m_Impl->hourglassCoefficient;
  settings.collapseBulkModulus = m_Impl->collapseBulkModulus;
  return settings;
}

void
SolverPrecomputation::Write(BinaryWriter & out) const
{
  const Impl & state = *m_Impl;
  for (const char c : kPrecomputationMagic)
  {
    out.Value(c);
  }
  out.Value(kPrecomputationVersion);
  out(state.modelKey);
  out(state.nodeCount);
  out(state.meshless);
  out(state.tetrahedron);
  out(state.hourglassCoefficient);
  out(state.collapseBulkModulus);
  state.forces->Write(out);
  out(state.nodeShapes.offsets);
  out(state.nodeShapes.nodes);
  out(state.nodeShapes.values);
  out(state.nodeShapes.gradients);
}

SolverPrecomputation
SolverPrecomputation::Read(BinaryReader & in)
{
  for (const char c : kPrecomputationMagic)
  {
    if (in.Value<char>() != c)
    {
      in.Fail("not a solver precomputation");
    }
  }
  const auto version = in.Value<std::uint32_t>();
  if (version != kPrecomputationVersion && version != 1)
  {
    in.Fail("format version " + std::to_string(version) + ", this module reads 1 and " +
            std::to_string(kPrecomputationVersion));
  }
  auto state = std::make_unique<Impl>();
  in(state->modelKey);
  in(state->nodeCount);
  in(state->meshless);
  in(state->tetrahedron);
  in(state->hourglassCoefficient);
  in(state->collapseBulkModulus);
  if (state->meshless)
  {
    state->forces = MeshlessForceModel::Read(in, version >= 2);
  }
  else
  {
    state->forces = FiniteElementForceModel::Read(in, version >= 2);
  }
  if (state->forces->NodeCount() != state->nodeCount)
  {
    in.Fail("the force model has " + std::to_string(state->forces->NodeCount()) + " nodes, not " +
            std::to_string(state->nodeCount));
  }
  ShapeFunctionTable & shapes = state->nodeShapes;
  in(shapes.offsets);
  in(shapes.nodes);
  in(shapes.values);
  in(shapes.gradients);
  if (state->meshless)
  {
    CheckSize(in, shapes.offsets.size(), static_cast<std::size_t>(state->nodeCount) + 1, "the nodes' shape-function rows");
    CheckOffsets(in, shapes.offsets, static_cast<Index>(shapes.nodes.size()), "the nodes' shape-function rows");
    CheckIndices(in, shapes.nodes, state->nodeCount, "the nodes' shape functions");
    CheckSize(in, shapes.values.size(), shapes.nodes.size(), "the nodes' shape-function values");
  }
  if (!in.AtEnd())
  {
    in.Fail("bytes after the end");
  }
  return SolverPrecomputation(std::move(state));
}

} // namespace bmr
