#include "bmrToolStress.h"

#include "bmrConstitutiveLaw.h"
#include "bmrUnits.h"

#include <algorithm>
#include <cmath>

namespace bmr
{

namespace
{

/** Trajectory times at which to look for region cells: the poses and enough in between. */
std::vector<double>
SampleTimes(const RigidTool & tool, double spacing)
{
  const std::vector<ToolPose> & poses = tool.trajectory;
  std::vector<double>           times{ poses.front().time };
  // Rotation moves a point of the tool by at most angle x its distance from the origin.
  double extent = tool.shape == RigidTool::Shape::Surface ? 0.0 : tool.length + tool.radius + 0.5 * tool.width;
  for (const Vector3 & vertex : tool.surface.vertices)
  {
    extent = std::max(extent, vertex.norm());
  }
  for (std::size_t k = 1; k < poses.size(); ++k)
  {
    const double moved = (poses[k].position - poses[k - 1].position).norm() +
                         (poses[k].rotation - poses[k - 1].rotation).norm() * extent;
    const int samples = std::max(1, static_cast<int>(std::ceil(moved / spacing)));
    for (int s = 1; s <= samples; ++s)
    {
      times.push_back(poses[k - 1].time + (poses[k].time - poses[k - 1].time) * s / samples);
    }
  }
  return times;
}

} // namespace

ToolStressRegion::ToolStressRegion(const Model & model, ToolContact & contact)
  : m_Model(model)
{
  const RigidTool & tool = contact.Tool();
  const double      radius = tool.stressRegionRadius;
  std::vector<char> selected(model.cells.size(), 0);
  std::vector<Vector3> centroids(model.cells.size());
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    const Cell & cell = model.cells[c];
    Vector3      sum = Vector3::Zero();
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      sum += model.nodes[static_cast<std::size_t>(cell.nodes[static_cast<std::size_t>(a)])];
    }
    centroids[c] = sum / NodesPerCell(cell.type);
  }
  for (const double time : SampleTimes(tool, 0.25 * radius))
  {
    contact.MoveTo(time);
    for (std::size_t c = 0; c < model.cells.size(); ++c)
    {
      selected[c] = selected[c] || contact.Distance(centroids[c]) <= radius;
    }
  }
  contact.MoveTo(tool.trajectory.front().time);

  // Shape-function gradients at the cell centre (the one-point hexahedron's
  // integration point; constant in a tetrahedron).
  for (std::size_t c = 0; c < model.cells.size(); ++c)
  {
    if (!selected[c])
    {
      continue;
    }
    const Cell &                 cell = model.cells[c];
    Eigen::Matrix<double, 3, 8>  gradients = Eigen::Matrix<double, 3, 8>::Zero();
    const auto                   X = [&](int a) { return model.nodes[static_cast<std::size_t>(cell.nodes[static_cast<std::size_t>(a)])]; };
    if (cell.type == CellType::Hexahedron)
    {
      static const double corner[8][3] = { { -1, -1, -1 }, { 1, -1, -1 }, { 1, 1, -1 }, { -1, 1, -1 },
                                           { -1, -1, 1 },  { 1, -1, 1 },  { 1, 1, 1 },  { -1, 1, 1 } };
      Eigen::Matrix<double, 3, 8> natural;
      for (int a = 0; a < 8; ++a)
      {
        natural.col(a) = Vector3(corner[a][0], corner[a][1], corner[a][2]) / 8.0;
      }
      Eigen::Matrix3d jacobian = Eigen::Matrix3d::Zero(); // dX/dxi
      for (int a = 0; a < 8; ++a)
      {
        jacobian += X(a) * natural.col(a).transpose();
      }
      gradients = jacobian.inverse().transpose() * natural;
    }
    else
    {
      Eigen::Matrix3d edges;
      edges << X(1) - X(0), X(2) - X(0), X(3) - X(0);
      const Eigen::Matrix3d inverse = edges.inverse(); // rows: gradients of N1, N2, N3
      for (int a = 1; a < 4; ++a)
      {
        gradients.col(a) = inverse.row(a - 1).transpose();
      }
      gradients.col(0) = -(gradients.col(1) + gradients.col(2) + gradients.col(3));
    }
    m_Cells.push_back(static_cast<Index>(c));
    m_Gradients.push_back(gradients);
    m_Volumes.push_back(CellVolume(model, static_cast<Index>(c)));
  }
  m_Points = MakeOgdenViscoelasticPoints(tool.stressMaterial, m_Cells.size());
  m_F.assign(m_Cells.size(), Eigen::Matrix3d::Identity());
  m_Touching.assign(model.nodes.size(), 0);
}

Vector3
ToolStressRegion::Update(const double * u, double dt, const std::vector<Index> & touching, int threads)
{
  const auto count = static_cast<Index>(m_Cells.size());
#pragma omp parallel for num_threads(threads) schedule(static)
  for (Index r = 0; r < count; ++r)
  {
    const Cell &    cell = m_Model.cells[static_cast<std::size_t>(m_Cells[static_cast<std::size_t>(r)])];
    Eigen::Matrix3d F = Eigen::Matrix3d::Zero();
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      const std::size_t node = static_cast<std::size_t>(cell.nodes[static_cast<std::size_t>(a)]);
      const Vector3     x = m_Model.nodes[node] + Vector3(u[3 * node], u[3 * node + 1], u[3 * node + 2]);
      F += x * m_Gradients[static_cast<std::size_t>(r)].col(a).transpose();
    }
    m_F[static_cast<std::size_t>(r)] = F;
  }
  UpdateOgdenViscoelasticPoints(m_Points, m_F, dt, m_Ogden, threads);
  m_NeoHookean.resize(m_Cells.size());
  for (const Index node : touching)
  {
    m_Touching[static_cast<std::size_t>(node)] = 1;
  }
  // The neo-Hookean stress of the same F, and the nodal-force difference at
  // touching nodes, summed in cell order (deterministic).
  Vector3 difference = Vector3::Zero();
  for (std::size_t r = 0; r < m_Cells.size(); ++r)
  {
    const Cell &          cell = m_Model.cells[static_cast<std::size_t>(m_Cells[r])];
    const Material &      material = m_Model.materials[static_cast<std::size_t>(cell.material)];
    const Eigen::Matrix3d F = m_F[r];
    const double          J = F.determinant();
    const Eigen::Matrix3d cofactor = Cofactor(F);
    // No collapse barrier (0): tissue at a tool keeps most of its volume, and the Ogden law has none.
    // The solve's own law (neo-Hookean or Mooney-Rivlin).
    const Eigen::Matrix3d neoHookean = FirstPiolaOfLaw(
      F, cofactor, J, J, { material.ShearModulus(), material.SecondInvariantModulus(), material.BulkModulus(), 0.0 }); // Pa
    m_NeoHookean[r] = neoHookean * F.transpose() / J;
    const Eigen::Matrix3d ogden = J * m_Ogden[r] * cofactor / J; // P = J sigma F^-T, F^-T = cof / J
    for (int a = 0; a < NodesPerCell(cell.type); ++a)
    {
      const std::size_t node = static_cast<std::size_t>(cell.nodes[static_cast<std::size_t>(a)]);
      if (m_Touching[node])
      {
        difference += m_Volumes[r] * (ogden - neoHookean) * m_Gradients[r].col(a) * units::PascalToInternal;
      }
    }
  }
  for (const Index node : touching)
  {
    m_Touching[static_cast<std::size_t>(node)] = 0;
  }
  // The tool carries minus the nodal internal force at the nodes it holds.
  return -difference;
}

double
ToolStressRegion::PeakVonMises() const
{
  double peak = 0.0;
  for (const Eigen::Matrix3d & sigma : m_Ogden)
  {
    const Eigen::Matrix3d deviator = sigma - sigma.trace() / 3.0 * Eigen::Matrix3d::Identity();
    peak = std::max(peak, std::sqrt(1.5 * deviator.squaredNorm()));
  }
  return peak;
}

} // namespace bmr
