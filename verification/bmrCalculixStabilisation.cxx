#include "bmrCalculixStabilisation.h"
#include "bmrCalculixContact.h"

#include <cmath>
#include <ostream>

namespace bmr
{

double
StabilisationStiffness(const CalculixSettings & settings, int stage)
{
  return settings.stabilisationStiffness / std::pow(settings.stabilisationSoftening, stage);
}

CalculixAnchors::CalculixAnchors(const CalculixMesh & mesh, const std::array<std::vector<char>, 3> & sprung,
                                 const CalculixSettings & settings)
  : m_Mesh(mesh)
  , m_Sprung(sprung)
  , m_Settings(settings)
{
  if (!(settings.stabilisationStiffness > 0.0))
  {
    return;
  }
  m_Families = settings.stabilisationStages;
  for (std::size_t node = 0; node < mesh.nodes.size(); ++node)
  {
    if (m_Sprung[0][node] || m_Sprung[1][node] || m_Sprung[2][node])
    {
      m_Nodes.push_back(node);
    }
  }
}

std::string
CalculixAnchors::SetName(int family, int set)
{
  return "BMRANCHOR" + std::to_string(family) + "AB"[set];
}

std::size_t
CalculixAnchors::Anchor(std::size_t i, int family, int set) const
{
  return m_Mesh.nodes.size() + (2 * static_cast<std::size_t>(family) + set) * m_Nodes.size() + i + 1;
}

void
CalculixAnchors::WriteNodes(std::ostream & stream) const
{
  if (Empty())
  {
    return;
  }
  stream << "*NODE, NSET=BMRANCHORS\n";
  for (int block = 0; block < 2 * m_Families; ++block)
  {
    for (std::size_t i = 0; i < m_Nodes.size(); ++i)
    {
      const Vector3 & p = m_Mesh.nodes[m_Nodes[i]];
      stream << Anchor(i, block / 2, block % 2) << ", " << FormatDouble(p.x()) << ", " << FormatDouble(p.y()) << ", "
             << FormatDouble(p.z()) << "\n";
    }
  }
  for (int block = 0; block < 2 * m_Families; ++block)
  {
    stream << "*NSET, NSET=" << SetName(block / 2, block % 2) << "\n";
    for (std::size_t i = 0; i < m_Nodes.size(); ++i)
    {
      stream << Anchor(i, block / 2, block % 2) << "\n";
    }
  }
}

void
CalculixAnchors::WriteSprings(std::ostream & stream, std::size_t lastElement) const
{
  std::size_t element = lastElement;
  for (int block = 0; block < 2 * m_Families; ++block)
  {
    const int family = block / 2;
    const int set = block % 2;
    for (int d = 0; d < 3; ++d)
    {
      const std::string name = "BMRSPRING" + std::to_string(family) + "AB"[set] + std::to_string(d + 1);
      bool              any = false;
      for (std::size_t i = 0; i < m_Nodes.size(); ++i)
      {
        if (m_Sprung[d][m_Nodes[i]])
        {
          stream << (any ? "" : "*ELEMENT, TYPE=SPRING2, ELSET=" + name + "\n") << ++element << ", " << m_Nodes[i] + 1
                 << ", " << Anchor(i, family, set) << "\n";
          any = true;
        }
      }
      if (any)
      {
        stream << "*SPRING, ELSET=" << name << "\n"
               << d + 1 << ", " << d + 1 << "\n"
               << FormatDouble(StabilisationStiffness(m_Settings, family)) << "\n";
      }
    }
  }
}

void
CalculixAnchors::WriteUnsprungHolds(std::ostream & stream) const
{
  for (std::size_t i = 0; i < m_Nodes.size(); ++i)
  {
    for (int d = 0; d < 3; ++d)
    {
      if (!m_Sprung[d][m_Nodes[i]])
      {
        for (int block = 0; block < 2 * m_Families; ++block)
        {
          stream << Anchor(i, block / 2, block % 2) << ", " << d + 1 << ", " << d + 1 << ", 0\n";
        }
      }
    }
  }
}

void
CalculixAnchors::WriteHold(std::ostream & stream, int family, int set, bool fixed,
                           const std::vector<Vector3> * start) const
{
  stream << (fixed ? "*BOUNDARY, FIXED\n" : "*BOUNDARY\n");
  for (std::size_t i = 0; i < m_Nodes.size(); ++i)
  {
    for (int d = 0; d < 3; ++d)
    {
      if (!m_Sprung[d][m_Nodes[i]])
      {
        continue;
      }
      stream << Anchor(i, family, set) << ", " << d + 1 << ", " << d + 1;
      if (!fixed)
      {
        stream << ", " << (start ? FormatDouble((*start)[m_Nodes[i]][d]) : std::string("0"));
      }
      stream << "\n";
    }
  }
}

} // namespace bmr
