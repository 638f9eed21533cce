// The model-building subcommands of biomech, end to end: from an MRI (a
// synthetic head, and Colin27 from Debian's mricron-data) to a scene that
// `biomech solve` runs, and every bad input named with nothing written.
//
// ITK headers first: ITK's bundled Eigen must come before the system Eigen.
#include "itkImage.h"
#include "itkImageFileWriter.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkTransformToDisplacementFieldFilter.h"
#include "itkBiomechanicalTransformIO.h"

#include "bmrMeshIO.h"
#include "bmrScene.h"

#include "bmrTemporaryFolderTest.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace
{

using ImageType = itk::Image<float, 3>;
using bmr::test::CommandResult;
using bmr::test::ReadText;

const fs::path Colin27Folder("/usr/share/mricron/templates");

/** A synthetic head: a 36 mm ball of "white matter" (intensity 110) with a
 *  "grey matter" shell (80) and a central "ventricle" (40), noise-free, in a
 *  64 x 60 x 56 image of 1 mm voxels whose origin is not zero. */
ImageType::Pointer
SyntheticHead(float outsideValue = 0.0f)
{
  auto                  image = ImageType::New();
  ImageType::RegionType region;
  region.SetSize({ { 64, 60, 56 } });
  image->SetRegions(region);
  const double origin[3] = { -31.5, -29.5, -27.5 };
  image->SetOrigin(origin);
  image->Allocate();
  for (itk::ImageRegionIteratorWithIndex<ImageType> it(image, region); !it.IsAtEnd(); ++it)
  {
    ImageType::PointType point;
    image->TransformIndexToPhysicalPoint(it.GetIndex(), point);
    const double radius = point.GetVectorFromOrigin().GetNorm();
    it.Set(radius > 18.0 ? outsideValue : radius > 14.0 ? 80.0f : radius > 5.0 ? 110.0f : 40.0f);
  }
  return image;
}

void
WriteTestImage(const ImageType * image, const fs::path & path)
{
  auto writer = itk::ImageFileWriter<ImageType>::New();
  writer->SetInput(image);
  writer->SetFileName(path.string());
  writer->Update();
}

/** Values of a CSV written by biomech (header line first), by row. */
std::vector<std::vector<double>>
ReadCsv(const fs::path & path)
{
  std::vector<std::vector<double>> rows;
  std::ifstream                    stream(path);
  std::string                      line;
  std::getline(stream, line); // header
  while (std::getline(stream, line))
  {
    std::vector<double> row;
    std::stringstream   fields(line);
    std::string         field;
    while (std::getline(fields, field, ','))
    {
      row.push_back(std::stod(field));
    }
    rows.push_back(row);
  }
  return rows;
}

class ModelCommandTest : public bmr::test::TemporaryFolderTest
{
protected:
  CommandResult Biomech(const std::string & arguments) const { return bmr::test::RunBiomech(m_Folder, arguments); }

  std::string Quoted(const fs::path & path) const { return "'" + path.string() + "'"; }

  /** The synthetic head and its mask (the ball) in the test folder. */
  void WriteSyntheticHead()
  {
    const ImageType::Pointer head = SyntheticHead(5.0f);
    WriteTestImage(head, m_Folder / "head.nii.gz");
    const ImageType::Pointer mask = SyntheticHead(0.0f);
    for (itk::ImageRegionIteratorWithIndex<ImageType> it(mask, mask->GetBufferedRegion()); !it.IsAtEnd(); ++it)
    {
      it.Set(it.Get() > 0.0f ? 1.0f : 0.0f);
    }
    WriteTestImage(mask, m_Folder / "mask.nii.gz");
  }

  /** Files in the folder, recursively (empty when it does not exist). */
  std::size_t FileCount(const fs::path & folder) const
  {
    std::size_t count = 0;
    if (fs::exists(folder))
    {
      for (const auto & entry : fs::recursive_directory_iterator(folder))
      {
        count += entry.is_regular_file() ? 1 : 0;
      }
    }
    return count;
  }
};

} // namespace

TEST_F(ModelCommandTest, Colin27GivesASolvableModelLoadedBySparseDisplacements)
{
  if (!fs::exists(Colin27Folder / "ch2.nii.gz"))
  {
    GTEST_SKIP() << "mricron-data is not installed (scripts/install-dependencies.sh installs it)";
  }
  // Measurements on the brain surface around a superior craniotomy: points of
  // the brain surface within 25 mm of its centre, pushed down by a smooth sag
  // of at most 4 mm (Colin27 in ITK's LPS space: +z is superior).
  const bmr::Vector3  centre(-11.0, 43.0, 84.0);
  const double        radius = 30.0;
  const CommandResult surfaces = Biomech("surfaces " + Quoted(Colin27Folder / "ch2bet.nii.gz") + " -o " +
                                         Quoted(m_Folder / "brain.vtp") + " --skull-output " +
                                         Quoted(m_Folder / "skull.vtp"));
  ASSERT_EQ(surfaces.exitCode, 0) << surfaces.err;
  const bmr::ContactSurface brain = bmr::ReadSurface((m_Folder / "brain.vtp").string());
  std::ofstream             csv(m_Folder / "measurements.csv");
  csv << "x,y,z,ux,uy,uz\n";
  std::size_t measurements = 0;
  double      deepest = 0.0;
  for (std::size_t vertex = 0; vertex < brain.vertices.size(); vertex += 37)
  {
    const bmr::Vector3 & x = brain.vertices[vertex];
    const double         r = (x - centre).norm();
    if (r < 25.0 && x.z() > 60.0)
    {
      const double sag = -4.0 * (1.0 - (r / radius) * (r / radius));
      csv << x.x() << "," << x.y() << "," << x.z() << ",0,0," << sag << "\n";
      deepest = std::min(deepest, sag);
      ++measurements;
    }
  }
  csv.close();
  ASSERT_GT(measurements, 20u);

  const fs::path      output = m_Folder / "model";
  const CommandResult model =
    Biomech("model " + Quoted(Colin27Folder / "ch2.nii.gz") + " --mask " + Quoted(Colin27Folder / "ch2bet.nii.gz") +
            " --craniotomy-centre -11 43 84 --craniotomy-radius 30 --sparse-displacements " +
            Quoted(m_Folder / "measurements.csv") + " --grid hexahedra --element-size 5 -o " + Quoted(output));
  ASSERT_EQ(model.exitCode, 0) << model.err;

  // The issue's size: 30,000 to 100,000 degrees of freedom; volume within 2% of the mask.
  const json report = json::parse(ReadText(output / "model-report.json"));
  const auto dofs = report["grid"]["dofs"].get<std::size_t>();
  EXPECT_GE(dofs, 30000u);
  EXPECT_LE(dofs, 100000u);
  EXPECT_LT(std::abs(report["grid"]["volume_error"].get<double>()), 0.02);
  EXPECT_EQ(report["classification"]["centroids"].size(), 3u);
  EXPECT_TRUE(report["classification"]["converged"].get<bool>());
  EXPECT_EQ(report["loads"]["used"].get<std::size_t>(), measurements);
  EXPECT_EQ(report["loads"]["rejected"].get<std::size_t>(), 0u);
  for (const char * step : { "read", "classify", "grid", "materials", "surfaces", "loads", "write", "total" })
  {
    EXPECT_TRUE(report["seconds"].contains(step)) << step;
  }

  // Every exposed node is loaded, with a displacement inside the measured
  // range (the thin-plate spline may overshoot a little between points:
  // 0.5 mm allowed, see bmrSurfacesLoadsTest for its accuracy).
  const auto loads = ReadCsv(output / "exposed-displacements.csv");
  EXPECT_EQ(loads.size(), report["regions"]["exposed_nodes"].get<std::size_t>());
  EXPECT_GT(loads.size(), 50u);
  for (const auto & row : loads)
  {
    ASSERT_EQ(row.size(), 4u);
    EXPECT_NEAR(row[1], 0.0, 0.5);
    EXPECT_NEAR(row[2], 0.0, 0.5);
    EXPECT_GE(row[3], deepest - 0.5);
    EXPECT_LE(row[3], 0.5);
  }

  // The scene solves; the exposed nodes end exactly where they were sent.
  const CommandResult solve = Biomech("solve " + Quoted(output / "scene.json") + " -d " + Quoted(output));
  ASSERT_EQ(solve.exitCode, 0) << solve.out << solve.err;
  const json solveReport = json::parse(ReadText(output / "brain-report.json"));
  EXPECT_TRUE(solveReport["converged"].get<bool>());
  EXPECT_GT(solveReport["max_displacement_mm"].get<double>(), 0.8 * -deepest);
  EXPECT_LT(solveReport["max_displacement_mm"].get<double>(), -deepest + 1.0);
  // The skull encloses the model, not just the mask: were it made from the
  // mask, the corners of the staircase grid would start outside it and about
  // 1,400 nodes would be pushed in (measured); pushing the top down brings
  // only a few nodes against the skull.
  EXPECT_LT(solveReport["contact_nodes"].get<int>(), 200);

  const bmr::Scene scene = bmr::ReadScene((output / "scene.json").string());
  ASSERT_EQ(scene.model.prescribedDisplacements.size(), 1u);
  const bmr::MeshData result = bmr::ReadMesh((output / "brain-result.vtu").string());
  const bmr::DataArray & displacement = result.pointData.at("displacement");
  const bmr::PrescribedDisplacement & load = scene.model.prescribedDisplacements[0];
  for (std::size_t k = 0; k < load.nodes.size(); ++k)
  {
    for (int c = 0; c < 3; ++c)
    {
      EXPECT_NEAR(displacement.values[3 * load.nodes[k] + c], load.displacements[k][c], 1e-9);
    }
  }

  // A solve that reports convergence to 0.01 mm is within 0.01 mm of the
  // solution (a solve to 1e-4 mm): with skull contact, the dynamic
  // relaxation's error estimate once stopped here 0.0155 mm away.
  const fs::path      tightFolder = m_Folder / "tight";
  const CommandResult tight = Biomech("solve " + Quoted(output / "scene.json") + " -d " + Quoted(tightFolder) +
                                      " --set tolerance=0.0001 --set max_steps=100000 --quiet");
  ASSERT_EQ(tight.exitCode, 0) << tight.out << tight.err;
  const bmr::DataArray & reference = bmr::ReadMesh((tightFolder / "brain-result.vtu").string()).pointData.at("displacement");
  ASSERT_EQ(reference.values.size(), displacement.values.size());
  double trueError = 0.0;
  for (std::size_t k = 0; k < reference.values.size(); ++k)
  {
    trueError = std::max(trueError, std::abs(reference.values[k] - displacement.values[k]));
  }
  RecordProperty("trueError", std::to_string(trueError));
  EXPECT_LE(trueError, 0.01) << "reported " << solveReport["estimated_error_mm"].get<double>() << " mm";
}

// Brain sag under 1 g after the CSF has drained (its buoyancy gone, the
// whole brain's weight on the skull), head upright: Colin27, 5 mm hexahedra,
// skull base fixed, skull contact. The solve converges; the brain sinks (the
// mean vertical displacement is downwards, the largest displacement is
// downwards at the top) by more than 1 mm and by less than a free column of
// parenchyma of the brain's height would under its own weight,
// rho g H^2 / (2 E), 37 mm for Colin27's 150 mm (the skull's support can
// only reduce the sag). Measured: 1,685 steps, largest 13.5 mm, mean -6.5 mm.
// Fluid-like CSF and partial drainage (the CSF's surface 50 mm below the top,
// the tissue below it buoyed: Miga et al. 1999) must sag less; the latter
// also less than a free column loaded on its top 50 mm only (20 mm).
// Measured: fluid-like 2,441 steps, 10.2 mm; drained to 50 mm 1,167 steps,
// largest 9.2 mm, mean -3.6 mm.
TEST_F(ModelCommandTest, Colin27SagsUnderGravityAgainstTheSkull)
{
  if (!fs::exists(Colin27Folder / "ch2.nii.gz"))
  {
    GTEST_SKIP() << "mricron-data is not installed";
  }
  struct Sag
  {
    double largest = 0.0;         // mm
    double largestVertical = 0.0; // mm, of the largest displacement
    double mean = 0.0;            // mm, mean vertical displacement of the nodes
    double height = 0.0;          // mm, the brain's extent along gravity
    double freeColumn = 0.0;      // mm, sag of a free column of the brain's height
  };
  // 1 g after CSF drainage (no buoyancy), head upright, skull contact, 5 mm
  // hexahedra, the skull following every fold: with the default skull (closed
  // by 1 mm) hexahedron 1454, a mixed cell that sticks out of the skull base
  // with 7 of its 8 nodes on the boundary, folds at 0.7-1 g
  // (docs/model-building.md, Limits).
  const auto sag = [&](const std::string & name, const std::string & csfOptions) {
    const fs::path      output = m_Folder / name;
    const CommandResult model =
      Biomech("model " + Quoted(Colin27Folder / "ch2.nii.gz") + " --mask " + Quoted(Colin27Folder / "ch2bet.nii.gz") +
              " --craniotomy-centre -11 43 84 --craniotomy-radius 30 --grid hexahedra --element-size 5 --gravity 0 0 -9810 --skull-closing 0 " +
              csfOptions + " --quiet -o " + Quoted(output));
    EXPECT_EQ(model.exitCode, 0) << model.err;
    const CommandResult solve = Biomech("solve " + Quoted(output / "scene.json") + " -d " + Quoted(output) + " --quiet");
    EXPECT_EQ(solve.exitCode, 0) << solve.out << solve.err;
    const json solveReport = json::parse(ReadText(output / "brain-report.json"));
    EXPECT_TRUE(solveReport["converged"].get<bool>()) << name;
    RecordProperty(name + "_steps", solveReport["steps"].get<int>());

    const bmr::MeshData    result = bmr::ReadMesh((output / "brain-result.vtu").string());
    const bmr::DataArray & displacement = result.pointData.at("displacement");
    double                 lowest = 1e9, highest = -1e9;
    Sag                    sag;
    const std::size_t      nodes = result.model.nodes.size();
    for (std::size_t n = 0; n < nodes; ++n)
    {
      lowest = std::min(lowest, result.model.nodes[n].z());
      highest = std::max(highest, result.model.nodes[n].z());
      const bmr::Vector3 u(displacement.values[3 * n], displacement.values[3 * n + 1], displacement.values[3 * n + 2]);
      sag.mean += u.z() / static_cast<double>(nodes);
      if (u.norm() > sag.largest)
      {
        sag.largest = u.norm();
        sag.largestVertical = u.z();
      }
    }
    sag.height = highest - lowest;
    const double height = sag.height * 1e-3;                                        // m
    sag.freeColumn = 1000.0 * 9.81 * height * height / (2.0 * 3000.0) * 1e3;       // mm
    RecordProperty(name + "_largest_mm", std::to_string(sag.largest));
    RecordProperty(name + "_mean_vertical_mm", std::to_string(sag.mean));
    return sag;
  };
  const Sag compressible = sag("csf-default", "");
  // Drained to 50 mm below the top: the tissue below the CSF's surface stays buoyed.
  const Sag partlyDrained = sag("csf-drained-50mm", "--csf-drained-depth 50");
  // Fluid-like CSF (nearly incompressible, still 10 Pa): the brain cannot squeeze it out of the closed skull.
  const Sag fluidLike = sag("csf-fluid-like", "--csf-poisson-ratio 0.49");
  const json report = json::parse(ReadText(m_Folder / "csf-fluid-like" / "model-report.json"));
  EXPECT_EQ(report["csf"]["poisson_ratio"].get<double>(), 0.49);
  EXPECT_EQ(report["csf"]["youngs_modulus_pa"].get<double>(), 10.0);
  for (const Sag & each : { compressible, fluidLike })
  {
    EXPECT_LT(each.mean, -0.5);
    EXPECT_LT(each.largestVertical, -0.9 * each.largest) << "the largest displacement is not downwards";
    EXPECT_GT(each.largest, 1.0);
    EXPECT_LT(each.largest, each.freeColumn);
  }
  // Fluid-like CSF carries part of the weight: the brain sags less (measured 10.2 against 13.5 mm).
  EXPECT_LT(fluidLike.largest, 0.9 * compressible.largest);

  // Partial drainage: the scene's CSF surface lies 50 mm below the brain's top.
  const json drainedReport = json::parse(ReadText(m_Folder / "csf-drained-50mm" / "model-report.json"));
  EXPECT_EQ(drainedReport["csf"]["drained_depth_mm"].get<double>(), 50.0);
  const bmr::Scene drained = bmr::ReadScene((m_Folder / "csf-drained-50mm" / "scene.json").string());
  ASSERT_TRUE(drained.model.fluidSurface.has_value());
  double top = -1e9;
  for (const bmr::Vector3 & node : drained.model.nodes)
  {
    top = std::max(top, node.z());
  }
  EXPECT_NEAR(drained.model.fluidSurface->z(), top - 50.0, 1e-9);
  // It sinks, less than the fully drained brain and less than a free column of
  // the brain's height H loaded only on its top D = 50 mm would:
  // rho g (D^2 / 2 + D (H - D)) / E.
  EXPECT_LT(partlyDrained.mean, -0.2);
  EXPECT_LT(partlyDrained.largestVertical, -0.9 * partlyDrained.largest) << "the largest displacement is not downwards";
  EXPECT_GT(partlyDrained.largest, 1.0);
  EXPECT_LT(partlyDrained.largest, 0.9 * compressible.largest);
  const double depth = 0.050, height = partlyDrained.height * 1e-3; // m
  EXPECT_LT(partlyDrained.largest, 1000.0 * 9.81 * (0.5 * depth * depth + depth * (height - depth)) / 3000.0 * 1e3);
}

TEST_F(ModelCommandTest, EveryGridKindGivesAParsableScene)
{
  WriteSyntheticHead();
  std::ofstream csv(m_Folder / "points.csv");
  csv << "x,y,z,ux,uy,uz\n0,0,18,0,0,-2\n5,0,17.3,0,0,-2\n0,5,17.3,0,0,-2\n-5,0,17.3,0,0,-2\n0,-5,17.3,0,0,-2\n";
  csv.close();
  for (const std::string kind : { "hexahedra", "tetrahedra", "mixed", "meshless" })
  {
    const fs::path      output = m_Folder / kind;
    const CommandResult run = Biomech("model " + Quoted(m_Folder / "head.nii.gz") + " --mask " +
                                      Quoted(m_Folder / "mask.nii.gz") + " --grid " + kind +
                                      " --element-size 4 --craniotomy-centre 0 0 18 --craniotomy-radius 10"
                                      " --sparse-displacements " + Quoted(m_Folder / "points.csv") +
                                      " --gravity 0 0 -9810 --quiet -o " + Quoted(output));
    ASSERT_EQ(run.exitCode, 0) << kind << ": " << run.err;
    const bmr::Scene scene = bmr::ReadScene((output / "scene.json").string());
    EXPECT_EQ(scene.model.discretization == bmr::Discretization::Meshless, kind == "meshless") << kind;
    EXPECT_EQ(fs::exists(output / "integration-points.vtu"), kind == "meshless") << kind;
    EXPECT_EQ(scene.model.bodyAcceleration, bmr::Vector3(0, 0, -9810)) << kind;
    // A uniform measured displacement loads every exposed node with it (a
    // point cloud measures the points' distance to the brain surface instead
    // of its cells' boundary).
    ASSERT_EQ(scene.model.prescribedDisplacements.size(), 1u) << kind;
    EXPECT_EQ(scene.model.prescribedDisplacements[0].nodes, scene.model.NodeSet("exposed")) << kind;
    for (const bmr::Vector3 & u : scene.model.prescribedDisplacements[0].displacements)
    {
      EXPECT_LT((u - bmr::Vector3(0, 0, -2)).norm(), 1e-8) << kind;
    }
    ASSERT_EQ(scene.model.contactSurfaces.size(), 1u) << kind;
    // Materials mix the three classes: CSF (10 Pa) at the centre, parenchyma (3000 Pa) elsewhere.
    double softest = std::numeric_limits<double>::max();
    double stiffest = 0.0;
    for (const bmr::Material & material : scene.model.materials)
    {
      softest = std::min(softest, material.youngsModulus);
      stiffest = std::max(stiffest, material.youngsModulus);
    }
    EXPECT_LT(softest, 1500.0) << kind;
    EXPECT_NEAR(stiffest, 3000.0, 1e-6) << kind;
    // The skull base is the lowest 10 mm of the surface.
    for (const bmr::Index node : scene.model.NodeSet("skull_base"))
    {
      EXPECT_LE(scene.model.nodes[node].z(), -18.0 + 10.0 + 1.0) << kind;
    }
  }
}

TEST_F(ModelCommandTest, StepsRunOneAtATime)
{
  WriteSyntheticHead();
  const CommandResult classify = Biomech("classify " + Quoted(m_Folder / "head.nii.gz") + " --mask " +
                                         Quoted(m_Folder / "mask.nii.gz") + " -o " + Quoted(m_Folder / "tissue"));
  ASSERT_EQ(classify.exitCode, 0) << classify.err;
  EXPECT_TRUE(fs::exists(m_Folder / "tissue-memberships.nii.gz"));
  EXPECT_TRUE(fs::exists(m_Folder / "tissue-labels.nii.gz"));
  // Three intensities inside the mask: the centroids are exactly 40, 80 and 110.
  EXPECT_NE(classify.out.find("centroids 40 80 110"), std::string::npos) << classify.out;

  const CommandResult grid = Biomech("grid " + Quoted(m_Folder / "mask.nii.gz") + " --grid hexahedra --element-size 4 " +
                                     "--memberships " + Quoted(m_Folder / "tissue-memberships.nii.gz") + " -o " +
                                     Quoted(m_Folder / "grid.vtu"));
  ASSERT_EQ(grid.exitCode, 0) << grid.err;
  const bmr::MeshData mesh = bmr::ReadMesh((m_Folder / "grid.vtu").string());
  ASSERT_TRUE(mesh.cellData.count("youngs_modulus"));

  std::ofstream csv(m_Folder / "points.csv");
  csv << "x,y,z,ux,uy,uz\n0,0,18,0,0,-2\n5,0,17.3,0,0,-2\n0,5,17.3,0,0,-2\n-5,0,17.3,0,0,-2\n0,-5,17.3,0,0,-2\n";
  csv.close();
  const CommandResult loads = Biomech("loads " + Quoted(m_Folder / "grid.vtu") +
                                      " --craniotomy-centre 0 0 18 --craniotomy-radius 8 --sparse-displacements " +
                                      Quoted(m_Folder / "points.csv") + " -o " + Quoted(m_Folder / "loads.csv"));
  ASSERT_EQ(loads.exitCode, 0) << loads.err;
  const auto rows = ReadCsv(m_Folder / "loads.csv");
  ASSERT_FALSE(rows.empty());
  for (const auto & row : rows)
  {
    // A uniform measured displacement is reproduced exactly (affine part of the spline).
    EXPECT_NEAR(row[3], -2.0, 1e-8);
  }

  const CommandResult surfaces = Biomech("surfaces " + Quoted(m_Folder / "mask.nii.gz") + " --skull-gap 2 -o " +
                                         Quoted(m_Folder / "brain.vtp") + " --skull-output " +
                                         Quoted(m_Folder / "skull.stl"));
  ASSERT_EQ(surfaces.exitCode, 0) << surfaces.err;
  const bmr::ContactSurface skull = bmr::ReadSurface((m_Folder / "skull.stl").string());
  for (const bmr::Vector3 & vertex : skull.vertices)
  {
    EXPECT_NEAR(vertex.norm(), 20.0, 0.6); // the 18 mm ball's boundary lies at 18 mm +- half a voxel, plus 2 mm
  }

  // A user-supplied skull replaces the computed one as the scene's contact surface.
  const CommandResult model = Biomech("model " + Quoted(m_Folder / "head.nii.gz") + " --mask " +
                                      Quoted(m_Folder / "mask.nii.gz") + " --skull-surface " +
                                      Quoted(m_Folder / "skull.stl") + " --gravity 0 0 -9810 --quiet -o " +
                                      Quoted(m_Folder / "model"));
  ASSERT_EQ(model.exitCode, 0) << model.err;
  const bmr::Scene scene = bmr::ReadScene((m_Folder / "model" / "scene.json").string());
  ASSERT_EQ(scene.model.contactSurfaces.size(), 1u);
  EXPECT_EQ(scene.model.contactSurfaces[0].triangles.size(), skull.triangles.size());
  EXPECT_EQ(scene.model.contactSurfaces[0].vertices.size(), skull.vertices.size());
}

TEST_F(ModelCommandTest, BadInputsExitOneNameTheProblemAndWriteNothing)
{
  WriteSyntheticHead();
  const std::string head = Quoted(m_Folder / "head.nii.gz");
  const std::string mask = Quoted(m_Folder / "mask.nii.gz");
  const std::string craniotomy = " --craniotomy-centre 0 0 18 --craniotomy-radius 10";

  // A mask on another grid.
  auto shifted = SyntheticHead(0.0f);
  const double origin[3] = { -30.0, -29.5, -27.5 };
  shifted->SetOrigin(origin);
  WriteTestImage(shifted, m_Folder / "shifted.nii.gz");
  // An empty mask.
  auto empty = SyntheticHead(0.0f);
  empty->FillBuffer(0.0f);
  WriteTestImage(empty, m_Folder / "empty.nii.gz");
  // An image with a NaN inside the brain (MetaImage: ITK's NIfTI reader does not return NaN voxels as NaN).
  auto withNaN = SyntheticHead(5.0f);
  withNaN->SetPixel({ { 32, 30, 28 } }, std::numeric_limits<float>::quiet_NaN());
  WriteTestImage(withNaN, m_Folder / "nan.mha");

  const std::vector<std::pair<std::string, std::string>> cases = {
    { "model " + head + " --mask " + Quoted(m_Folder / "shifted.nii.gz") + craniotomy, "not on the image grid" },
    { "model " + head + " --mask " + Quoted(m_Folder / "empty.nii.gz") + craniotomy, "mask" },
    { "model " + Quoted(m_Folder / "nan.mha") + " --mask " + mask + craniotomy, "NaN" },
    { "model " + head + " --mask " + mask + " --craniotomy-centre 0 0 60 --craniotomy-radius 10", "nearest" },
    { "model " + head + " --mask " + mask + craniotomy + " --element-size 0.5", "voxel" },
    { "model " + head + " --mask " + mask + craniotomy + " --element-size 30", "across" },
    { "model " + head + " --mask " + mask + " --classes 5" + craniotomy, "distinct" },
    { "model " + Quoted(m_Folder / "missing.nii.gz") + " --mask " + mask, "no such file" },
    { "model " + head + " --mask " + mask + " --sparse-displacements " + Quoted(m_Folder / "points.csv"),
      "craniotomy" },
    { "demo --csf-poisson-ratio 0.5", "--csf-poisson-ratio" },
    { "demo --bias-field 1.5", "--bias-field" },
    { "demo --intraoperative-contrast flair", "--intraoperative-contrast" },
    { "demo --noise-model poisson", "--noise-model" },
    { "demo --truth-skull-closing -1", "--truth-skull-closing" },
    { "demo --elastix-parameters " + Quoted(m_Folder / "missing.txt"), "--elastix-parameters" },
    { "model " + head + " --mask " + mask + craniotomy + " --csf-poisson-ratio 0.5", "--csf-poisson-ratio" },
    { "model " + head + " --mask " + mask + craniotomy + " --csf-modulus 0", "--csf-modulus" },
    { "model " + head + " --mask " + mask + craniotomy + " --csf-drained-depth 20", "--gravity" },
    { "model " + head + " --mask " + mask + craniotomy + " --gravity 0 0 -9810 --csf-drained-depth -1",
      "--csf-drained-depth" },
  };
  for (const auto & [arguments, expected] : cases)
  {
    const fs::path      output = m_Folder / "out";
    const CommandResult run = Biomech(arguments + " -o " + Quoted(output));
    EXPECT_EQ(run.exitCode, 1) << arguments << "\n" << run.err;
    EXPECT_NE(run.err.find("biomech: error:"), std::string::npos) << run.err;
    EXPECT_NE(run.err.find(expected), std::string::npos) << "expected '" << expected << "' in: " << run.err;
    EXPECT_EQ(FileCount(output), 0u) << arguments;
    fs::remove_all(output);
  }
}

// The demo's realistic-image, second-truth and peer options fail before the
// ground truth's solve, with the option or the missing program named, and
// write nothing.
TEST_F(ModelCommandTest, DemoNamesAResectionWithoutTumourAndAMissingElastix)
{
  if (!fs::exists(Colin27Folder / "ch2.nii.gz"))
  {
    GTEST_SKIP() << "Colin27 (mricron-data) is not installed";
  }
  const fs::path output = m_Folder / "out";
  CommandResult  run = Biomech("demo --resection-margin 3 -o " + Quoted(output));
  EXPECT_EQ(run.exitCode, 1) << run.err;
  EXPECT_NE(run.err.find("tumour"), std::string::npos) << run.err;
  EXPECT_EQ(FileCount(output), 0u);

  // A ground truth that does not converge within its step limit: named, and no report left behind.
  run = Biomech("demo --quiet --truth-element-size 8 --truth-max-steps 5 --no-baseline --overlays 0 -o " + Quoted(output));
  EXPECT_EQ(run.exitCode, 1) << run.err;
  EXPECT_NE(run.err.find("the ground-truth solve did not converge"), std::string::npos) << run.err;
  EXPECT_NE(run.err.find("after 5 steps"), std::string::npos) << run.err;
  EXPECT_EQ(FileCount(output), 0u);

  // A second ground truth written without its size: named before any solve.
  run = Biomech("demo --truth-check tetrahedra -o " + Quoted(output));
  EXPECT_EQ(run.exitCode, 1) << run.err;
  EXPECT_NE(run.err.find("--truth-check 'tetrahedra': write it as KIND:SIZE"), std::string::npos) << run.err;
  EXPECT_EQ(FileCount(output), 0u);

  const std::string path = std::getenv("PATH") != nullptr ? std::getenv("PATH") : "";
  ::setenv("PATH", (m_Folder / "empty-path").c_str(), 1);
  run = Biomech("demo --elastix -o " + Quoted(output));
  ::setenv("PATH", path.c_str(), 1);
  EXPECT_EQ(run.exitCode, 1) << run.err;
  EXPECT_NE(run.err.find("elastix is not on PATH"), std::string::npos) << run.err;
  EXPECT_EQ(FileCount(output), 0u);

  // elastix itself failing (a transform it does not know): named, with its log's last lines, on one line.
  std::ofstream(m_Folder / "bad-parameters.txt") << "(Transform \"NoSuchTransform\")\n";
  run = Biomech("demo --quiet --truth-element-size 8 --variant hexahedra:9 --no-baseline --overlays 0 --elastix-parameters " +
                Quoted(m_Folder / "bad-parameters.txt") + " -o " + Quoted(output));
  EXPECT_EQ(run.exitCode, 1) << run.err;
  EXPECT_NE(run.err.find("biomech: error: elastix failed"), std::string::npos) << run.err;
  EXPECT_NE(run.err.find("elastix-output.txt ends:"), std::string::npos) << run.err;
  EXPECT_EQ(run.err.find('\n'), run.err.size() - 1) << run.err;
}

namespace
{
// The cached truth's own backward map sampled on Colin27's grid, written as a
// peer's displacement field, and the peer's details.
void
WriteTruthAsPeer(const fs::path & truth, const fs::path & peerField, const fs::path & peerDetails)
{
  using FieldImage = itk::Image<itk::Vector<float, 3>, 3>;
  auto sample = itk::TransformToDisplacementFieldFilter<FieldImage, double>::New();
  const auto transform = itk::ReadBiomechanicalTransform((truth / "ground-truth-transform.h5").string());
  sample->SetTransform(dynamic_cast<const itk::Transform<double, 3, 3> *>(transform.GetPointer()));
  sample->SetReferenceImage(itk::ReadBiomechanicalImage<ImageType>((Colin27Folder / "ch2.nii.gz").string(), "Colin27"));
  sample->UseReferenceImageOn();
  sample->Update();
  itk::WriteBiomechanicalImage(sample->GetOutput(), peerField);
  std::ofstream(peerDetails) << R"({"tool": "the truth itself"})";
}
} // namespace

// The validation workflow's cached truths: `demo --truth-only` writes a truth
// that `demo --truth-from` registers exactly as one `demo` that solves it and
// registers it in the same process (here with a resection: the planned
// resection travels with the truth, the registration is given it, and the
// error near the cavity is measured the same way); a folder that is not such
// a truth, or scene options beside --truth-from, are named errors that write
// nothing.
TEST_F(ModelCommandTest, DemoRegistersACachedTruthAsTheWholeDemoDoes)
{
  if (!fs::exists(Colin27Folder / "ch2.nii.gz"))
  {
    GTEST_SKIP() << "Colin27 (mricron-data) is not installed";
  }
  const std::string scene =
    " --quiet --overlays 0 --truth-element-size 8 --tumour-centre -11 40 55 --tumour-radius 12 --resection-margin 5";
  const fs::path    truth = m_Folder / "truth", cached = m_Folder / "cached", whole = m_Folder / "whole";
  CommandResult     run = Biomech("demo" + scene + " --truth-only -o " + Quoted(truth));
  ASSERT_EQ(run.exitCode, 0) << run.err;
  const json truthReport = json::parse(ReadText(truth / "demo-report.json"));
  EXPECT_TRUE(truthReport["ground_truth"]["reusable"].get<bool>());
  ASSERT_EQ(truthReport["methods"].size(), 1u);
  EXPECT_EQ(truthReport["methods"][0]["name"], "no registration");
  for (const char * file : { "ground-truth-transform.h5", "ground-truth-forward-transform.h5", "tracked-points.csv",
                             "intraoperative-brain-on-preoperative-grid.nii.gz", "intraoperative.nii.gz",
                             "tumour-mask.nii.gz", "resection-mask.nii.gz" })
  {
    EXPECT_TRUE(fs::exists(truth / file)) << file;
  }

  run = Biomech("demo --quiet --overlays 0 --variant hexahedra:9 --no-baseline --truth-from " + Quoted(truth) + " -o " +
                Quoted(cached));
  ASSERT_EQ(run.exitCode, 0) << run.err;
  run = Biomech("demo" + scene + " --variant hexahedra:9 --no-baseline -o " + Quoted(whole));
  ASSERT_EQ(run.exitCode, 0) << run.err;
  const json cachedReport = json::parse(ReadText(cached / "demo-report.json"));
  const json wholeReport = json::parse(ReadText(whole / "demo-report.json"));
  EXPECT_EQ(cachedReport["ground_truth"]["nodes"], wholeReport["ground_truth"]["nodes"]);
  EXPECT_EQ(cachedReport["ground_truth"]["read_from"], truth.string());
  EXPECT_FALSE(cachedReport["ground_truth"]["reusable"].get<bool>());
  ASSERT_EQ(cachedReport["methods"].size(), 2u);
  ASSERT_EQ(wholeReport["methods"].size(), 2u);
  for (std::size_t k = 0; k < 2; ++k)
  {
    const json & a = cachedReport["methods"][k];
    const json & b = wholeReport["methods"][k];
    EXPECT_EQ(a["name"], b["name"]);
    for (const char * statistic : { "mean", "p95", "max" })
    {
      // The truth's transforms, images and points read back from their files: equal to 1e-4 mm.
      EXPECT_NEAR(a["displacement_error_mm"][statistic].get<double>(),
                  b["displacement_error_mm"][statistic].get<double>(), 1e-4)
        << a["name"] << " " << statistic;
    }
    EXPECT_NEAR(a["fraction_within_1_7_mm"].get<double>(), b["fraction_within_1_7_mm"].get<double>(), 1e-3) << a["name"];
    // Near the cavity (the brain within 10 mm of it): fewer samples, measured the same way.
    ASSERT_TRUE(a.contains("displacement_error_near_tumour_mm")) << a["name"];
    EXPECT_NEAR(a["displacement_error_near_tumour_mm"]["p95"].get<double>(),
                b["displacement_error_near_tumour_mm"]["p95"].get<double>(), 1e-4)
      << a["name"];
    EXPECT_GT(a["displacement_error_near_tumour_mm"]["samples"].get<std::size_t>(), 100u);
    EXPECT_LT(a["displacement_error_near_tumour_mm"]["samples"].get<std::size_t>(),
              a["displacement_error_mm"]["samples"].get<std::size_t>() / 5);
  }
  for (const json * report : { &cachedReport, &wholeReport })
  {
    EXPECT_EQ((*report)["near_tumour"]["structure"], "resection cavity");
    // The registration was given the planned resection (a 17 mm sphere: about 20,600 mm^3 of brain at most).
    const double resected = (*report)["methods"][1]["details"]["model"]["resected_volume_mm3"].get<double>();
    EXPECT_GT(resected, 10000.0);
    EXPECT_LT(resected, 4.0 / 3.0 * M_PI * 17.0 * 17.0 * 17.0);
  }
  // No registration errs near the cavity, where the walls sag, and leaves the cavity's surface farther from
  // where it is than the registration does.
  EXPECT_GT(cachedReport["methods"][0]["displacement_error_near_tumour_mm"]["p95"].get<double>(), 0.5);
  for (std::size_t k = 0; k < 2; ++k)
  {
    EXPECT_NEAR(cachedReport["methods"][k]["tumour_surface_distance_p95_mm"].get<double>(),
                wholeReport["methods"][k]["tumour_surface_distance_p95_mm"].get<double>(), 1e-6);
  }
  EXPECT_LT(cachedReport["methods"][1]["tumour_surface_distance_p95_mm"].get<double>(),
            cachedReport["methods"][0]["tumour_surface_distance_p95_mm"].get<double>());
  // The ventricles' surface (VentricleMask: Colin27's lateral ventricles, 21.5 mL measured; without the opening
  // the fissures and cisterns they touch make it 64 mL): the same in both runs, and the registration moves it
  // closer to where the truth puts it than no registration leaves it.
  for (const json * report : { &cachedReport, &wholeReport })
  {
    EXPECT_GT((*report)["ventricles"]["volume_mm3"].get<double>(), 15000.0);
    EXPECT_LT((*report)["ventricles"]["volume_mm3"].get<double>(), 30000.0);
  }
  EXPECT_TRUE(fs::exists(cached / "ventricle-mask.nii.gz"));
  for (std::size_t k = 0; k < 2; ++k)
  {
    EXPECT_NEAR(cachedReport["methods"][k]["ventricle_surface_distance_p95_mm"].get<double>(),
                wholeReport["methods"][k]["ventricle_surface_distance_p95_mm"].get<double>(), 1e-6);
  }
  EXPECT_LT(cachedReport["methods"][1]["ventricle_surface_distance_p95_mm"].get<double>(),
            cachedReport["methods"][0]["ventricle_surface_distance_p95_mm"].get<double>());
  // The registration really ran: it beats no registration.
  EXPECT_LT(cachedReport["methods"][1]["displacement_error_mm"]["p95"].get<double>(),
            cachedReport["methods"][0]["displacement_error_mm"]["p95"].get<double>());

  // A peer registration run elsewhere (--peer-field, as the study's ANTs and itk-elastix): given the truth's own
  // backward map sampled on the preoperative grid, where the errors are measured, it scores no error (single
  // precision), its time and details as given.
  const fs::path peerField = m_Folder / "truth-field.nii.gz", peerDetails = m_Folder / "peer.json";
  WriteTruthAsPeer(truth, peerField, peerDetails);
  const std::string peer = "demo --quiet --overlays 0 --variant none --no-baseline --truth-from " + Quoted(truth) +
                           " --peer-name exact --peer-seconds 1.5 --peer-details " + Quoted(peerDetails);
  run = Biomech(peer + " --peer-field " + Quoted(peerField) + " --peer-warped " + Quoted(truth / "intraoperative.nii.gz") +
                " -o " + Quoted(m_Folder / "peer"));
  ASSERT_EQ(run.exitCode, 0) << run.err;
  const json peerReport = json::parse(ReadText(m_Folder / "peer" / "demo-report.json"));
  ASSERT_EQ(peerReport["methods"].size(), 2u);
  const json & exact = peerReport["methods"][1];
  EXPECT_EQ(exact["name"], "exact");
  EXPECT_EQ(exact["seconds"].get<double>(), 1.5);
  EXPECT_EQ(exact["details"]["tool"], "the truth itself");
  EXPECT_LT(exact["displacement_error_mm"]["max"].get<double>(), 1e-3);
  EXPECT_GT(peerReport["methods"][0]["displacement_error_mm"]["p95"].get<double>(), 1.0);

  const fs::path output = m_Folder / "out";
  const std::vector<std::pair<std::string, std::string>> cases = {
    { peer + " --peer-field " + Quoted(truth / "intraoperative.nii.gz") + " --peer-warped " +
        Quoted(truth / "intraoperative.nii.gz"),
      "has 3 dimensions and 1 components per voxel; give a 3D image of 3-vectors" },
    { peer + " --peer-field " + Quoted(peerField) + " --peer-warped " + Quoted(Colin27Folder / "ch2.nii.gz"),
      "is not on the intraoperative image's grid" },
    { "demo --peer-field " + Quoted(peerField) + " --peer-warped " + Quoted(peerField) + " --peer-name x",
      "--truth-from" },
    { "demo --truth-from " + Quoted(cached), "not the report of a reusable ground truth" },
    { "demo --truth-from " + Quoted(m_Folder), "demo-report.json is missing; make the folder with `biomech demo --truth-only" },
    { "demo --truth-from " + Quoted(truth) + " --shift 5", "--shift" },
    { "demo --truth-only --variant hexahedra:5", "--variant" },
  };
  // The truth's own folder as the output: refused before anything is written there.
  run = Biomech("demo --truth-from " + Quoted(truth) + " -o " + Quoted(truth));
  EXPECT_EQ(run.exitCode, 1) << run.err;
  EXPECT_NE(run.err.find("is also the output folder"), std::string::npos) << run.err;
  EXPECT_TRUE(json::parse(ReadText(truth / "demo-report.json"))["ground_truth"]["reusable"].get<bool>());
  for (const auto & [arguments, expected] : cases)
  {
    run = Biomech(arguments + " -o " + Quoted(output));
    EXPECT_EQ(run.exitCode, 1) << arguments << "\n" << run.err;
    EXPECT_NE(run.err.find(expected), std::string::npos) << "expected '" << expected << "' in: " << run.err;
    EXPECT_EQ(FileCount(output), 0u) << arguments;
    fs::remove_all(output);
  }
}
