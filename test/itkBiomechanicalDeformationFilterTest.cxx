// itk::BiomechanicalDeformationFilter: the solver as an ITK pipeline filter,
// and the filters before it: itk::BiomechanicalMaterialMappingFilter (the
// model's materials), itk::BiomechanicalRegionsFilter (fixed, exposed and
// contact nodes) and itk::BiomechanicalLoadsFilter (its prescribed
// displacements from intraoperative measurements); and the whole
// registration composed from the filters against `biomech register`.
// It must give bitwise the solver's results (hexahedra, ANP tetrahedra,
// meshless), follow ITK's pipeline conventions (progress, abort, no second
// solve without a change, a solve again after one), report failures and
// non-convergence as stated, and compose with the grid, surface and fitter
// filters.
// Over 800 lines on purpose: one translation unit instantiates the filters'
// slow templates once for all their tests.
//
// ITK headers first: ITK's bundled Eigen must come before the system Eigen.
#include "itkBiomechanicalDeformationFilter.h"
#include "itkBiomechanicalGridImageFilter.h"
#include "itkBiomechanicalLoadsFilter.h"
#include "itkBrainSurfaceMeshSource.h"
#include "itkCommand.h"
#include "itkBiomechanicalMaterialMappingFilter.h"
#include "itkBiomechanicalRegionsFilter.h"
#include "itkBinaryThresholdImageFilter.h"
#include "itkTransformWarpImageFilter.h"
#include "itkDisplacementPointSetToBSplineTransformFilter.h"
#include "itkFuzzyCMeansClassifierImageFilter.h"
#include "itkImage.h"
#include "itkImageRegionIteratorWithIndex.h"
#include "itkDefaultDynamicMeshTraits.h"
#include "itkTriangleCell.h"

#include "bmrMaterialMapping.h"
#include "bmrMeshless.h"
#include "bmrTestUtilities.h"

#include "bmrColin27.h"
#include "bmrMeshIO.h"
#include "bmrTemporaryFolderTest.h"
#include "itkBiomechanicalImageIO.h"
#include "itkBiomechanicalTransformIO.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <string>
#include <vector>

namespace
{
using namespace bmr;
using namespace bmr::test;

using FilterType = itk::BiomechanicalDeformationFilter<>;
using PointSetType = FilterType::DisplacementPointSetType;

/** A 10 x 8 x 6 mm block, bottom fixed, top pressed down 1 mm: the kind of
 *  grid given; the top's load is left out (the filter's point-set input
 *  carries it). */
Model
PressedBlock(const std::string & kind, const std::array<int, 3> & divisions = { 5, 4, 3 })
{
  const Material material = MakeMaterial(3000.0, 0.45);
  Model          model = MakeBlockMesh(Vector3(10.0, 8.0, 6.0), divisions,
                              kind == "tetrahedra" ? GridCells::Tetrahedra : GridCells::Hexahedra, material);
  if (kind == "meshless")
  {
    MakeMeshlessFromCells(model, {}, {}, 1);
  }
  model.fixedConstraints.push_back({ "zmin", { true, true, true } });
  return model;
}

PrescribedDisplacement
TopLoad(const Model & model)
{
  PrescribedDisplacement load;
  load.nodes = model.NodeSet("zmax");
  load.displacements.assign(load.nodes.size(), Vector3(0.2, 0.0, -1.0));
  return load;
}

PointSetType::Pointer
PointSetOf(const Model & model, const PrescribedDisplacement & load)
{
  std::vector<Vector3> points;
  for (const Index node : load.nodes)
  {
    points.push_back(model.nodes[node]);
  }
  return itk::MakeDisplacementPointSet<PointSetType>(points, load.displacements);
}

SolverSettings
Settings()
{
  SolverSettings settings;
  settings.tolerance = 1e-6;
  return settings;
}

class BiomechanicalDeformationFilterKinds : public testing::TestWithParam<std::string>
{};

// The filter's output is the solver's result, bit for bit, whatever the discretization.
TEST_P(BiomechanicalDeformationFilterKinds, MatchesTheSolverBitwise)
{
  const Model                  model = PressedBlock(GetParam());
  const PrescribedDisplacement load = TopLoad(model);

  Model withLoad = model;
  withLoad.prescribedDisplacements.push_back(load);
  SolverSettings settings = Settings();
  settings.threads = 2;
  const SolveResult expected = Solver(withLoad, settings).Solve();
  ASSERT_TRUE(expected.converged) << expected.message;

  auto filter = FilterType::New();
  filter->SetModel(model);
  filter->SetPrescribedDisplacements(PointSetOf(model, load));
  filter->SetSolverSettings(Settings());
  filter->SetNumberOfWorkUnits(2);
  filter->Update();
  const PointSetType * output = filter->GetOutput();
  ASSERT_EQ(output->GetNumberOfPoints(), model.nodes.size());
  EXPECT_TRUE(filter->GetConverged());
  EXPECT_EQ(filter->GetSolveResult().steps, expected.steps);
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    const auto point = output->GetPoints()->ElementAt(n);
    const auto displacement = output->GetPointData()->ElementAt(n);
    for (unsigned int d = 0; d < 3; ++d)
    {
      EXPECT_EQ(point[d], model.nodes[n][d]);
      EXPECT_EQ(displacement[d], expected.displacements[n][d]) << "node " << n << " component " << d;
    }
  }

  if (GetParam() == "meshless")
  {
    // Anywhere in the body: at the nodes it gives the output again.
    std::vector<FilterType::PointType> at(3);
    std::vector<Vector3>               expectedAt(3);
    for (std::size_t k = 0; k < at.size(); ++k)
    {
      const Index node = static_cast<Index>(7 * k + 3);
      for (unsigned int d = 0; d < 3; ++d)
      {
        at[k][d] = model.nodes[node][d];
      }
      expectedAt[k] = expected.displacements[node];
    }
    const std::vector<FilterType::VectorType> values = filter->EvaluateDisplacements(at);
    for (std::size_t k = 0; k < at.size(); ++k)
    {
      for (unsigned int d = 0; d < 3; ++d)
      {
        EXPECT_NEAR(values[k][d], expectedAt[k][d], 1e-12);
      }
    }
  }
  else
  {
    EXPECT_THROW(filter->EvaluateDisplacements({ FilterType::PointType() }), itk::ExceptionObject);
  }
}

INSTANTIATE_TEST_SUITE_P(Grids, BiomechanicalDeformationFilterKinds,
                         testing::Values("hexahedra", "tetrahedra", "meshless"),
                         [](const testing::TestParamInfo<std::string> & info) { return info.param; });

// Pipeline conventions: one solve per change, progress reported, abort honoured.
TEST(BiomechanicalDeformationFilter, SolvesOncePerChangeReportsProgressAndAborts)
{
  const Model model = PressedBlock("hexahedra", { 15, 12, 9 }); // enough steps for several reports
  auto        filter = FilterType::New();
  filter->SetModel(model);
  filter->SetPrescribedDisplacements(PointSetOf(model, TopLoad(model)));
  filter->SetTolerance(1e-9);
  int   starts = 0, reports = 0;
  float lastProgress = -1.0f;
  bool  progressFell = false;
  filter->AddObserver(itk::StartEvent(), [&](const itk::EventObject &) { ++starts; });
  filter->AddObserver(itk::ProgressEvent(), [&](const itk::EventObject &) {
    ++reports;
    progressFell = progressFell || filter->GetProgress() < lastProgress;
    lastProgress = filter->GetProgress();
  });
  filter->Update();
  const int steps = filter->GetSolveResult().steps;
  ASSERT_GT(steps, 400) << "too few steps to see progress reports";
  EXPECT_EQ(starts, 1);
  EXPECT_GE(reports, steps / 200); // every 200 steps, and the end
  EXPECT_FALSE(progressFell);
  EXPECT_EQ(lastProgress, 1.0f);

  filter->Update();
  EXPECT_EQ(starts, 1) << "a second Update() without a change solved again";
  filter->SetTolerance(1e-9);
  filter->Update();
  EXPECT_EQ(starts, 1) << "setting the same tolerance is no change";
  filter->SetTolerance(1e-7);
  filter->Update();
  EXPECT_EQ(starts, 2) << "a new tolerance must solve again";
  EXPECT_LT(filter->GetSolveResult().steps, steps);
  // A changed input solves again.
  filter->SetPrescribedDisplacements(PointSetOf(model, TopLoad(model)));
  filter->Update();
  EXPECT_EQ(starts, 3);

  // Abort at the first report: ProcessAborted, and no partial output.
  auto aborting = FilterType::New();
  aborting->SetModel(model);
  aborting->SetPrescribedDisplacements(PointSetOf(model, TopLoad(model)));
  aborting->SetTolerance(1e-9);
  aborting->AddObserver(itk::ProgressEvent(), [&](const itk::EventObject &) { aborting->AbortGenerateDataOn(); });
  EXPECT_THROW(aborting->Update(), itk::ProcessAborted);
  EXPECT_EQ(aborting->GetOutput()->GetNumberOfPoints(), 0u);
}

TEST(BiomechanicalDeformationFilter, FailuresThrowNonConvergenceIsReported)
{
  const Model model = PressedBlock("tetrahedra");

  // No model.
  auto empty = FilterType::New();
  EXPECT_THROW(empty->Update(), itk::ExceptionObject);

  // A prescribed point that is not a node is named.
  PrescribedDisplacement load = TopLoad(model);
  auto                   offNode = PointSetOf(model, load);
  auto                   moved = offNode->GetPoints()->ElementAt(2);
  moved[0] += 0.5;
  offNode->GetPoints()->SetElement(2, moved);
  auto filter = FilterType::New();
  filter->SetModel(model);
  filter->SetPrescribedDisplacements(offNode);
  try
  {
    filter->Update();
    ADD_FAILURE() << "a point 0.5 mm off a node was accepted";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("point 2"), std::string::npos) << error.GetDescription();
    EXPECT_NE(std::string(error.GetDescription()).find("not a model node"), std::string::npos);
  }

  // Pressing the top through the bottom inverts an element: the exception names it.
  load.displacements.assign(load.nodes.size(), Vector3(0.0, 0.0, -12.0));
  filter->SetPrescribedDisplacements(PointSetOf(model, load));
  try
  {
    filter->Update();
    ADD_FAILURE() << "a 200 % compression solved";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("inverted"), std::string::npos) << error.GetDescription();
    // The solver's message as it is, for callers to pass on (no "ITK ERROR: Class(0x...)" prefix).
    EXPECT_EQ(std::string(error.GetDescription()).find("ITK ERROR"), std::string::npos) << error.GetDescription();
  }

  // Too few steps: not an exception, reported.
  filter->SetPrescribedDisplacements(PointSetOf(model, TopLoad(model)));
  filter->SetMaximumNumberOfSteps(30);
  filter->SetTolerance(1e-9);
  filter->Update();
  EXPECT_FALSE(filter->GetConverged());
  EXPECT_NE(filter->GetStopConditionDescription().find("NOT CONVERGED"), std::string::npos)
    << filter->GetStopConditionDescription();
  EXPECT_EQ(filter->GetOutput()->GetNumberOfPoints(), model.nodes.size());
}

// The filters compose: label image -> grid -> (model) -> deformation, with the
// skull from the surface source as contact -> B-spline fit. The filter's
// result is the solver's on the model it assembles from its inputs.
TEST(BiomechanicalDeformationFilter, ComposesWithGridSurfaceAndFitterFilters)
{
  using LabelImageType = itk::Image<unsigned char, 3>;
  auto         image = LabelImageType::New();
  const double spacing[3] = { 1.0, 1.0, 1.0 };
  const double origin[3] = { -20.0, -20.0, -20.0 };
  image->SetRegions(LabelImageType::SizeType{ { 41, 41, 41 } });
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->Allocate();
  itk::ImageRegionIteratorWithIndex<LabelImageType> it(image, image->GetBufferedRegion());
  for (; !it.IsAtEnd(); ++it)
  {
    LabelImageType::PointType x;
    image->TransformIndexToPhysicalPoint(it.GetIndex(), x);
    it.Set(x.GetVectorFromOrigin().GetNorm() <= 14.0 ? 1 : 0);
  }

  auto grid = itk::BiomechanicalGridImageFilter<LabelImageType>::New();
  grid->SetInput(image);
  grid->SetGridKind(bmr::ImageGridKind::Tetrahedra);
  grid->SetElementSize(5.0);
  auto skull = itk::BrainSurfaceMeshSource<LabelImageType>::New();
  skull->SetInput(image);
  skull->SetSkullGap(1.0);

  // The ball's top cap is pressed down 2 mm; its bottom node is held.
  grid->Update();
  Model model = grid->GetModel();
  ASSERT_GT(model.nodes.size(), 50u);
  std::vector<Vector3> capPoints, capDisplacements;
  Index                bottom = 0;
  for (std::size_t n = 0; n < model.nodes.size(); ++n)
  {
    if (model.nodes[n].z() > 12.0)
    {
      capPoints.push_back(model.nodes[n]);
      capDisplacements.emplace_back(0.0, 0.0, -2.0);
    }
    bottom = model.nodes[n].z() < model.nodes[bottom].z() ? static_cast<Index>(n) : bottom;
  }
  ASSERT_GE(capPoints.size(), 3u);
  // Fixed nodes come with the model: the grid's model plus a node set, as material mapping would add data.
  model.nodeSets["bottom"] = { bottom };
  model.fixedConstraints.push_back({ "bottom", { true, true, true } });
  auto modelWithSupport = itk::BiomechanicalModelObject::New();
  modelWithSupport->SetModel(model);

  auto deformation = FilterType::New();
  deformation->SetModelInput(modelWithSupport);
  deformation->SetPrescribedDisplacements(itk::MakeDisplacementPointSet<PointSetType>(capPoints, capDisplacements));
  deformation->SetContactSurface(skull->GetSkullOutput());
  deformation->SetTolerance(1e-4);
  deformation->SetNumberOfWorkUnits(1);
  int skullRuns = 0, deformationRuns = 0;
  skull->AddObserver(itk::StartEvent(), [&](const itk::EventObject &) { ++skullRuns; });
  deformation->AddObserver(itk::StartEvent(), [&](const itk::EventObject &) { ++deformationRuns; });

  auto fitter = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>::New();
  fitter->SetInput(deformation->GetOutput());
  fitter->SetReferenceImage(image);
  fitter->SetTolerance(0.05);
  skull->Update(); // as a pipeline that times its stages does
  fitter->Update();
  // A mesh source runs once: its meshes are marked as produced (buffered =
  // requested region), or every downstream update would run it again (the
  // skull surface once took 1.8 s a second time in each registration).
  EXPECT_EQ(skullRuns, 1);
  deformation->SetTolerance(2e-4);
  deformation->Update();
  EXPECT_EQ(deformationRuns, 2);
  EXPECT_EQ(skullRuns, 1);
  deformation->SetTolerance(1e-4);
  deformation->Update();
  int gridRuns = 0;
  grid->AddObserver(itk::StartEvent(), [&](const itk::EventObject &) { ++gridRuns; });
  grid->GetOutput()->Update();
  EXPECT_EQ(gridRuns, 0);
  ASSERT_TRUE(deformation->GetConverged()) << deformation->GetStopConditionDescription();
  const auto & components = deformation->GetSolveResult().activeComponents;
  EXPECT_NE(std::find(components.begin(), components.end(), "contact"), components.end());
  EXPECT_LT(fitter->GetReport().maximumResidual, 0.05);

  // The same model solved directly.
  Model direct = model;
  PrescribedDisplacement cap;
  for (std::size_t k = 0; k < capPoints.size(); ++k)
  {
    for (std::size_t n = 0; n < direct.nodes.size(); ++n)
    {
      if (direct.nodes[n] == capPoints[k])
      {
        cap.nodes.push_back(static_cast<Index>(n));
      }
    }
  }
  cap.displacements = capDisplacements;
  direct.prescribedDisplacements.push_back(cap);
  skull->Update();
  ContactSurface contact = skull->GetSkullSurface();
  contact.name = "contact-surface-input";
  contact.slaveNodeSet = "";
  direct.contactSurfaces.push_back(contact);
  SolverSettings settings;
  settings.tolerance = 1e-4;
  settings.threads = 1;
  const SolveResult expected = Solver(direct, settings).Solve();
  ASSERT_EQ(deformation->GetOutput()->GetNumberOfPoints(), direct.nodes.size());
  for (std::size_t n = 0; n < direct.nodes.size(); ++n)
  {
    const auto displacement = deformation->GetOutput()->GetPointData()->ElementAt(n);
    for (unsigned int d = 0; d < 3; ++d)
    {
      EXPECT_EQ(displacement[d], expected.displacements[n][d]) << "node " << n;
    }
  }
  // The grid's model output is its model.
  EXPECT_EQ(grid->GetModelOutput()->GetModel().nodes, grid->GetModel().nodes);
}

// Image to displacements as one ITK pipeline: classifier -> grid (model) ->
// material mapping -> deformation. The mapping equals the core's on the same
// memberships, bitwise; the deformation sees the mapped materials.
TEST(BiomechanicalMaterialMappingFilter, ClassifierGridMappingAndDeformationCompose)
{
  using ImageType = itk::Image<float, 3>;
  using MaskType = itk::Image<unsigned char, 3>;
  auto         image = ImageType::New();
  auto         mask = MaskType::New();
  const double spacing[3] = { 1.0, 1.0, 1.0 };
  const double origin[3] = { -20.0, -20.0, -20.0 };
  image->SetRegions(ImageType::SizeType{ { 41, 41, 41 } });
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->Allocate();
  mask->CopyInformation(image);
  mask->SetRegions(image->GetLargestPossibleRegion());
  mask->Allocate();
  // A ball of radius 14 mm: dark (CSF-like) below z = -4 mm, bright above.
  itk::ImageRegionIteratorWithIndex<ImageType> it(image, image->GetBufferedRegion());
  for (; !it.IsAtEnd(); ++it)
  {
    ImageType::PointType x;
    image->TransformIndexToPhysicalPoint(it.GetIndex(), x);
    const bool inside = x.GetVectorFromOrigin().GetNorm() <= 14.0;
    it.Set(inside ? (x[2] < -4.0 ? 20.0f : 100.0f) : 0.0f);
    mask->SetPixel(it.GetIndex(), inside ? 1 : 0);
  }

  auto classifier = itk::FuzzyCMeansClassifierImageFilter<ImageType, MaskType>::New();
  classifier->SetInput(image);
  classifier->SetMaskImage(mask);
  classifier->SetNumberOfClasses(2);
  auto grid = itk::BiomechanicalGridImageFilter<MaskType>::New();
  grid->SetInput(mask);
  grid->SetGridKind(bmr::ImageGridKind::Hexahedra);
  grid->SetElementSize(4.0);
  auto mapping = itk::BiomechanicalMaterialMappingFilter<>::New();
  mapping->SetModelInput(grid->GetModelOutput());
  mapping->SetMemberships(classifier->GetOutput());
  mapping->Update();
  const Model & mapped = mapping->GetOutput()->GetModel();

  // The core on the same memberships.
  Model direct = grid->GetModel();
  MapMaterialsFromMemberships(direct, itk::MakeBiomechanicalVolume<float>(classifier->GetOutput()),
                              [] {
                                MaterialMappingSettings settings;
                                settings.classMaterials = DefaultClassMaterials(2);
                                return settings;
                              }());
  ASSERT_EQ(mapped.cells.size(), direct.cells.size());
  ASSERT_EQ(mapped.materials.size(), direct.materials.size());
  EXPECT_GT(mapped.materials.size(), 2u) << "boundary cells between the classes mix them";
  for (std::size_t m = 0; m < mapped.materials.size(); ++m)
  {
    EXPECT_EQ(mapped.materials[m].youngsModulus, direct.materials[m].youngsModulus);
    EXPECT_EQ(mapped.materials[m].poissonRatio, direct.materials[m].poissonRatio);
  }
  for (std::size_t c = 0; c < mapped.cells.size(); ++c)
  {
    EXPECT_EQ(mapped.cells[c].material, direct.cells[c].material);
  }
  // Bad input is named: no memberships; class materials that do not match the classes.
  auto missing = itk::BiomechanicalMaterialMappingFilter<>::New();
  missing->SetModelInput(grid->GetModelOutput());
  EXPECT_THROW(missing->Update(), itk::ExceptionObject);
  auto wrongCount = itk::BiomechanicalMaterialMappingFilter<>::New();
  wrongCount->SetModelInput(grid->GetModelOutput());
  wrongCount->SetMemberships(classifier->GetOutput());
  wrongCount->SetClassMaterials(DefaultClassMaterials(3));
  try
  {
    wrongCount->Update();
    ADD_FAILURE() << "3 class materials for 2 classes were accepted";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("3 class materials for a membership image of 2"),
              std::string::npos)
      << error.GetDescription();
  }

  // The dark lower part is CSF (10 Pa), the bright upper part parenchyma (3000 Pa).
  double lowest = 1e9, highest = 0.0;
  for (const Cell & cell : mapped.cells)
  {
    lowest = std::min(lowest, mapped.materials[cell.material].youngsModulus);
    highest = std::max(highest, mapped.materials[cell.material].youngsModulus);
  }
  EXPECT_EQ(lowest, CsfMaterial().youngsModulus);
  EXPECT_EQ(highest, ParenchymaMaterial().youngsModulus);

  // The mapped model into the deformation filter: bottom held, top pressed.
  Model supported = mapped;
  supported.nodeSets["low"] = {};
  std::vector<Vector3> top, push;
  for (std::size_t n = 0; n < supported.nodes.size(); ++n)
  {
    if (supported.nodes[n].z() < -11.0)
    {
      supported.nodeSets["low"].push_back(static_cast<Index>(n));
    }
    if (supported.nodes[n].z() > 11.0)
    {
      top.push_back(supported.nodes[n]);
      push.emplace_back(0.0, 0.0, -1.0);
    }
  }
  ASSERT_FALSE(supported.nodeSets["low"].empty());
  ASSERT_FALSE(top.empty());
  supported.fixedConstraints.push_back({ "low", { true, true, true } });
  auto deformation = FilterType::New();
  deformation->SetModel(supported);
  deformation->SetPrescribedDisplacements(itk::MakeDisplacementPointSet<PointSetType>(top, push));
  deformation->SetTolerance(1e-3);
  deformation->Update();
  EXPECT_TRUE(deformation->GetConverged()) << deformation->GetStopConditionDescription();
  // The soft CSF below takes most of the 1 mm: the middle of the ball, at its
  // lower (CSF) part, moves more than it would in a uniform ball (half of it).
  double middle = 0.0;
  for (std::size_t n = 0; n < supported.nodes.size(); ++n)
  {
    if (std::abs(supported.nodes[n].z()) < 1.0 && supported.nodes[n].head<2>().norm() < 3.0)
    {
      middle = std::min(middle, deformation->GetOutput()->GetPointData()->ElementAt(n)[2]);
    }
  }
  EXPECT_LT(middle, -0.6);
}

using SurfaceMeshType = FilterType::SurfaceMeshType;

/** The core's surface as an itk::Mesh of triangles. */
SurfaceMeshType::Pointer
MeshOf(const ContactSurface & surface)
{
  auto mesh = SurfaceMeshType::New();
  for (std::size_t v = 0; v < surface.vertices.size(); ++v)
  {
    SurfaceMeshType::PointType point;
    for (unsigned int d = 0; d < 3; ++d)
    {
      point[d] = surface.vertices[v][d];
    }
    mesh->SetPoint(v, point);
  }
  using TriangleType = itk::TriangleCell<SurfaceMeshType::CellType>;
  for (std::size_t t = 0; t < surface.triangles.size(); ++t)
  {
    SurfaceMeshType::CellAutoPointer cell;
    cell.TakeOwnership(new TriangleType);
    for (int v = 0; v < 3; ++v)
    {
      cell->SetPointId(v, static_cast<SurfaceMeshType::PointIdentifier>(surface.triangles[t][v]));
    }
    mesh->SetCell(t, cell);
  }
  return mesh;
}

// An itk::Mesh as the core's surface: vertices in the points' order whether
// the identifiers are dense (vector containers) or not (map containers), and
// a cell that names a missing point is an error that says so.
TEST(BiomechanicalModelObject, ContactSurfaceFromMeshNumbersPointsInOrderAndNamesAMissingPoint)
{
  ContactSurface tetrahedron; // a tetrahedron's boundary, every face outward
  tetrahedron.vertices = { Vector3(0, 0, 0), Vector3(1, 0, 0), Vector3(0, 1, 0), Vector3(0, 0, 1) };
  tetrahedron.triangles = { { 0, 2, 1 }, { 0, 1, 3 }, { 0, 3, 2 }, { 1, 2, 3 } };
  const ContactSurface dense = itk::MakeContactSurfaceFromMesh(MeshOf(tetrahedron).GetPointer(), "dense mesh");
  EXPECT_EQ(dense.vertices, tetrahedron.vertices);
  EXPECT_EQ(dense.triangles, tetrahedron.triangles);

  using SparseMeshType = itk::Mesh<double, 3, itk::DefaultDynamicMeshTraits<double, 3, 3, double, double>>;
  using SparseTriangle = itk::TriangleCell<SparseMeshType::CellType>;
  const std::vector<SparseMeshType::PointIdentifier> ids{ 1000, 20, 300, 4 }; // a map container lists them sorted
  auto sparse = SparseMeshType::New();
  for (std::size_t v = 0; v < ids.size(); ++v)
  {
    SparseMeshType::PointType point;
    for (unsigned int d = 0; d < 3; ++d)
    {
      point[d] = tetrahedron.vertices[v][d];
    }
    sparse->SetPoint(ids[v], point);
  }
  for (std::size_t t = 0; t < tetrahedron.triangles.size(); ++t)
  {
    SparseMeshType::CellAutoPointer cell;
    cell.TakeOwnership(new SparseTriangle);
    for (int v = 0; v < 3; ++v)
    {
      cell->SetPointId(v, ids[static_cast<std::size_t>(tetrahedron.triangles[t][v])]);
    }
    sparse->SetCell(t, cell);
  }
  const ContactSurface fromSparse = itk::MakeContactSurfaceFromMesh(sparse.GetPointer(), "sparse mesh");
  ASSERT_EQ(fromSparse.vertices.size(), 4u);
  ASSERT_EQ(fromSparse.triangles.size(), tetrahedron.triangles.size());
  for (std::size_t t = 0; t < tetrahedron.triangles.size(); ++t)
  {
    for (int v = 0; v < 3; ++v)
    {
      EXPECT_EQ(fromSparse.vertices[static_cast<std::size_t>(fromSparse.triangles[t][v])],
                tetrahedron.vertices[static_cast<std::size_t>(tetrahedron.triangles[t][v])]);
    }
  }

  auto broken = MeshOf(tetrahedron);
  SurfaceMeshType::CellAutoPointer cell;
  cell.TakeOwnership(new itk::TriangleCell<SurfaceMeshType::CellType>);
  cell->SetPointId(0, 0);
  cell->SetPointId(1, 1);
  cell->SetPointId(2, 9);
  broken->SetCell(tetrahedron.triangles.size(), cell);
  try
  {
    itk::MakeContactSurfaceFromMesh(broken.GetPointer(), "broken mesh");
    FAIL() << "a cell that names a missing point was accepted";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("of the broken mesh refers to point 9"), std::string::npos)
      << error.GetDescription();
  }
}

// The model object carries the model and its precomputation down the
// pipeline: SetModel marks it modified, Graft shares the precomputation (a
// bundle's, made before surgery) instead of making another, Initialize
// empties it.
TEST(BiomechanicalModelObject, CarriesTheModelAndItsPrecomputationThroughGraftAndInitialize)
{
  const Model model = PressedBlock("hexahedra");
  auto        object = itk::BiomechanicalModelObject::New();
  const auto  created = object->GetMTime();
  object->SetModel(model);
  EXPECT_GT(object->GetMTime(), created);
  EXPECT_EQ(object->GetModel().nodes, model.nodes);
  EXPECT_EQ(object->GetPrecomputation(), nullptr);
  const auto precomputation = std::make_shared<const SolverPrecomputation>(model, Settings());
  const auto modelled = object->GetMTime();
  object->SetPrecomputation(precomputation);
  EXPECT_GT(object->GetMTime(), modelled);

  auto copy = itk::BiomechanicalModelObject::New();
  copy->Graft(object);
  EXPECT_EQ(copy->GetPrecomputation(), precomputation);
  EXPECT_EQ(copy->GetModel().nodes, model.nodes);
  EXPECT_EQ(copy->GetModel().cells.size(), model.cells.size());
  copy->Initialize();
  EXPECT_TRUE(copy->GetModel().nodes.empty());
  EXPECT_EQ(copy->GetPrecomputation(), nullptr);
  EXPECT_EQ(object->GetPrecomputation(), precomputation); // the original keeps its own
  EXPECT_EQ(object->GetModel().nodes.size(), model.nodes.size());
}

// A precomputation that does not fit the object's model (here a node moved
// after it was made) fails the deformation filter's solve with the solver's
// words, not a solve of the wrong reference configuration.
TEST(BiomechanicalModelObject, APrecomputationOfAnotherModelFailsTheSolveNamingIt)
{
  const Model model = PressedBlock("hexahedra");
  Model       moved = model;
  moved.nodes[0].x() += 0.1;
  auto object = itk::BiomechanicalModelObject::New();
  object->SetModel(moved);
  object->SetPrecomputation(std::make_shared<const SolverPrecomputation>(model, Settings()));
  auto filter = FilterType::New();
  filter->SetModelInput(object);
  filter->SetPrescribedDisplacements(PointSetOf(moved, TopLoad(moved)));
  filter->SetSolverSettings(Settings());
  try
  {
    filter->Update();
    FAIL() << "the solve ran with a precomputation of another model";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_CONTAINS(std::string(error.GetDescription()), "another model");
  }
  object->SetPrecomputation(std::make_shared<const SolverPrecomputation>(moved, Settings()));
  filter->Update();
  EXPECT_TRUE(filter->GetConverged());
}

// Loads from measurements as a filter: the core's loads, bitwise, as a point
// set the deformation filter takes.
TEST(BiomechanicalLoadsFilter, SparsePointsAndASurfaceLoadTheExposedNodes)
{
  using LoadsType = itk::BiomechanicalLoadsFilter<>;
  Model model = PressedBlock("hexahedra");
  model.nodeSets["exposed"] = model.NodeSet("zmax");
  const std::vector<Index> & exposed = model.nodeSets["exposed"];

  // (b) Sparse points on the top with an affine displacement: reproduced exactly.
  const auto affine = [](const Vector3 & x) { return Vector3(0.01 * x.y(), -0.02 * x.x(), -0.5 - 0.03 * x.x()); };
  std::vector<Vector3> points, displacements;
  for (const Vector3 & x : { Vector3(1, 1, 6), Vector3(9, 1, 6), Vector3(1, 7, 6), Vector3(9, 7, 6), Vector3(5, 4, 6) })
  {
    points.push_back(x);
    displacements.push_back(affine(x));
  }
  auto loads = LoadsType::New();
  loads->SetModelInput([&] {
    auto object = itk::BiomechanicalModelObject::New();
    object->SetModel(model);
    return object;
  }());
  loads->SetSparseDisplacements(itk::MakeDisplacementPointSet<PointSetType>(points, displacements));
  loads->Update();
  const PrescribedDisplacement direct = DisplacementsFromSparsePoints(model, exposed, points, displacements);
  const PointSetType *         output = loads->GetOutput();
  ASSERT_EQ(output->GetNumberOfPoints(), direct.nodes.size());
  EXPECT_EQ(loads->GetLoadReport().usedPoints, points.size());
  for (std::size_t k = 0; k < direct.nodes.size(); ++k)
  {
    const Vector3 & node = model.nodes[direct.nodes[k]];
    for (unsigned int d = 0; d < 3; ++d)
    {
      EXPECT_EQ(output->GetPoints()->ElementAt(k)[d], node[d]);
      EXPECT_EQ(output->GetPointData()->ElementAt(k)[d], direct.displacements[k][d]);
      EXPECT_NEAR(output->GetPointData()->ElementAt(k)[d], affine(node)[d], 1e-8);
    }
  }

  // Into the deformation filter: the top nodes end where the loads send them.
  auto deformation = FilterType::New();
  deformation->SetModel(model);
  deformation->SetPrescribedDisplacements(loads->GetOutput());
  deformation->Update();
  EXPECT_TRUE(deformation->GetConverged());
  for (const Index node : exposed)
  {
    EXPECT_NEAR(deformation->GetOutput()->GetPointData()->ElementAt(node)[2], affine(model.nodes[node]).z(), 1e-9);
  }

  // (a) A plane 0.8 mm below the top: every exposed node moves 0.8 mm down.
  ContactSurface plane = MakePlane(Vector3(5.0, 4.0, 5.2), Vector3::UnitZ(), 40.0);
  auto           closest = LoadsType::New();
  closest->SetModelInput(deformation->GetModelInput());
  closest->SetIntraoperativeSurface(MeshOf(plane));
  closest->Update();
  ASSERT_EQ(closest->GetOutput()->GetNumberOfPoints(), exposed.size());
  for (std::size_t k = 0; k < exposed.size(); ++k)
  {
    EXPECT_NEAR(closest->GetOutput()->GetPointData()->ElementAt(k)[2], -0.8, 1e-12);
    EXPECT_NEAR(closest->GetOutput()->GetPointData()->ElementAt(k)[0], 0.0, 1e-12);
  }

  // Bad input: both measurements, none, no exposed node set.
  closest->SetSparseDisplacements(itk::MakeDisplacementPointSet<PointSetType>(points, displacements));
  EXPECT_THROW(closest->Update(), itk::ExceptionObject);
  auto none = LoadsType::New();
  none->SetModelInput(deformation->GetModelInput());
  EXPECT_THROW(none->Update(), itk::ExceptionObject);
  auto noSet = LoadsType::New();
  noSet->SetModelInput(deformation->GetModelInput());
  noSet->SetExposedNodeSet("opening");
  noSet->SetIntraoperativeSurface(MeshOf(plane));
  try
  {
    noSet->Update();
    ADD_FAILURE() << "a missing node set was accepted";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("'opening'"), std::string::npos) << error.GetDescription();
  }
}

/** The regions filter on a 10 x 8 x 6 mm block: the bottom layer fixed, a
 *  sphere on the top exposed, every other surface node a contact slave; bad
 *  regions are named. */
TEST(BiomechanicalRegionsFilter, FixedExposedAndContactNodesPartitionTheSurface)
{
  Model block = PressedBlock("hexahedra");
  block.fixedConstraints.clear();
  block.nodeSets["surface"] = block.BoundaryNodes();
  auto input = itk::BiomechanicalModelObject::New();
  input->SetModel(block);

  using RegionsType = itk::BiomechanicalRegionsFilter<>;
  auto              regions = RegionsType::New();
  regions->SetModelInput(input);
  SkullBaseSettings base;
  base.height = 1.0; // the bottom layer (z = 0; the next is at 2 mm)
  regions->SetSkullBase(base);
  const Vector3 top(5.0, 4.0, 6.0);
  regions->SetCraniotomyCentre(top);
  regions->SetCraniotomyRadius(3.0);
  regions->Update();
  const Model & model = regions->GetOutput()->GetModel();

  const std::vector<Index> & fixed = model.NodeSet("skull_base");
  const std::vector<Index> & exposed = model.NodeSet("exposed");
  const std::vector<Index> & contact = model.NodeSet("contact");
  EXPECT_EQ(fixed, block.NodeSet("zmin"));
  ASSERT_EQ(model.fixedConstraints.size(), 1u);
  EXPECT_EQ(model.fixedConstraints[0].nodeSet, "skull_base");
  std::vector<Index> expectedExposed;
  for (const Index node : block.NodeSet("surface"))
  {
    if ((block.nodes[node] - top).norm() <= 3.0)
    {
      expectedExposed.push_back(node);
    }
  }
  std::sort(expectedExposed.begin(), expectedExposed.end());
  EXPECT_EQ(exposed, expectedExposed);
  EXPECT_GE(exposed.size(), 5u);
  // Every surface node is in exactly one of the three sets.
  std::vector<int> count(model.nodes.size(), 0);
  for (const auto * set : { &fixed, &exposed, &contact })
  {
    for (const Index node : *set)
    {
      ++count[node];
    }
  }
  for (const Index node : block.NodeSet("surface"))
  {
    EXPECT_EQ(count[node], 1) << "surface node " << node;
  }
  EXPECT_EQ(fixed.size() + exposed.size() + contact.size(), block.NodeSet("surface").size());

  // Without contact there is no contact set; without a craniotomy no exposed set.
  regions->SetContact(false);
  regions->SetCraniotomyRadius(0.0);
  regions->Update();
  EXPECT_EQ(regions->GetOutput()->GetModel().nodeSets.count("contact"), 0u);
  EXPECT_EQ(regions->GetOutput()->GetModel().nodeSets.count("exposed"), 0u);

  const auto expectError = [&](const std::string & expected) {
    try
    {
      regions->Update();
      ADD_FAILURE() << "no error; expected one naming '" << expected << "'";
    }
    catch (const itk::ExceptionObject & error)
    {
      EXPECT_NE(std::string(error.GetDescription()).find(expected), std::string::npos) << error.GetDescription();
    }
  };
  // A sphere and a mask: the one craniotomy check.
  auto mask = itk::Image<unsigned char, 3>::New();
  itk::Image<unsigned char, 3>::RegionType region;
  region.SetSize({ { 12, 10, 8 } });
  mask->SetRegions(region);
  mask->Allocate(true);
  regions->SetCraniotomyMask(mask);
  regions->SetCraniotomyRadius(3.0);
  expectError("not both");
  // A sphere far from the body.
  auto far = RegionsType::New();
  far->SetModelInput(input);
  far->SetCraniotomyCentre(Vector3(50.0, 50.0, 50.0));
  far->SetCraniotomyRadius(3.0);
  try
  {
    far->Update();
    ADD_FAILURE() << "a sphere off the body was accepted";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("selects no surface node"), std::string::npos)
      << error.GetDescription();
  }
  // A model without its surface node set.
  Model bare = block;
  bare.nodeSets.erase("surface");
  auto bareInput = itk::BiomechanicalModelObject::New();
  bareInput->SetModel(bare);
  auto noSurface = RegionsType::New();
  noSurface->SetModelInput(bareInput);
  try
  {
    noSurface->Update();
    ADD_FAILURE() << "a model without surface nodes was accepted";
  }
  catch (const itk::ExceptionObject & error)
  {
    EXPECT_NE(std::string(error.GetDescription()).find("'surface'"), std::string::npos) << error.GetDescription();
  }
}

// ---------------------------------------------------------------------------
// The whole registration as an ITK pipeline of the module's filters.
// ---------------------------------------------------------------------------

class ImageFileTest : public TemporaryFolderTest
{};

/** Images written as .nii.gz are ordinary gzip files that ITK reads back
 *  exactly (values, origin, spacing, direction), as are .nii, .nrrd (3D
 *  Slicer's format) and .mha; a failed write leaves no file behind, not even
 *  the uncompressed one. */
TEST_F(ImageFileTest, WrittenImagesReadBackExactlyAndFailuresLeaveNothing)
{
  using ImageType = itk::Image<float, 3>;
  auto                  image = ImageType::New();
  ImageType::RegionType region;
  region.SetSize({ { 7, 5, 4 } });
  image->SetRegions(region);
  const double spacing[3] = { 0.9, 1.1, 2.5 };
  const double origin[3] = { -110.0, 35.5, 1000.0 };
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  ImageType::DirectionType direction;
  direction.SetIdentity();
  direction(0, 0) = direction(1, 1) = std::cos(0.3);
  direction(0, 1) = -std::sin(0.3);
  direction(1, 0) = std::sin(0.3);
  image->SetDirection(direction);
  image->Allocate();
  float value = -3.25f;
  for (itk::ImageRegionIteratorWithIndex<ImageType> it(image, region); !it.IsAtEnd(); ++it, value += 0.37f)
  {
    it.Set(value);
  }
  for (const std::string name : { "image.nii.gz", "image.nii", "image.nrrd", "image.mha" })
  {
    const auto path = m_Folder / name;
    itk::WriteBiomechanicalImage(image.GetPointer(), path);
    const ImageType::Pointer back = itk::ReadBiomechanicalImage<ImageType>(path.string(), name);
    ASSERT_EQ(back->GetLargestPossibleRegion().GetSize(), region.GetSize()) << name;
    for (itk::ImageRegionIteratorWithIndex<ImageType> it(image, region); !it.IsAtEnd(); ++it)
    {
      ASSERT_EQ(back->GetPixel(it.GetIndex()), it.Get()) << name;
    }
    for (unsigned int d = 0; d < 3; ++d)
    {
      EXPECT_NEAR(back->GetOrigin()[d], image->GetOrigin()[d], 1e-4) << name;
      EXPECT_NEAR(back->GetSpacing()[d], image->GetSpacing()[d], 1e-6) << name;
      for (unsigned int e = 0; e < 3; ++e)
      {
        EXPECT_NEAR(back->GetDirection()(d, e), direction(d, e), 1e-6) << name;
      }
    }
  }
  std::ifstream gz(m_Folder / "image.nii.gz", std::ios::binary);
  unsigned char magic[2] = { 0, 0 };
  gz.read(reinterpret_cast<char *>(magic), 2);
  EXPECT_EQ(magic[0], 0x1f);
  EXPECT_EQ(magic[1], 0x8b);

  // A write that fails at the end (a folder in the way of the result)
  // throws, names the image, and leaves only what was there before: neither
  // the compressed nor the uncompressed temporary file.
  const auto blocked = m_Folder / "blocked.nii.gz";
  std::filesystem::create_directories(blocked / "inside");
  const std::size_t before = std::distance(std::filesystem::directory_iterator(m_Folder), {});
  const std::string message = ErrorMessage([&] { itk::WriteBiomechanicalImage(image.GetPointer(), blocked); });
  EXPECT_CONTAINS(message, "blocked.nii.gz");
  EXPECT_TRUE(std::filesystem::is_directory(blocked / "inside"));
  EXPECT_EQ(static_cast<std::size_t>(std::distance(std::filesystem::directory_iterator(m_Folder), {})), before);
}

class BrainShiftPipelineTest : public TemporaryFolderTest
{};

/** A user's pipeline, composed here filter by filter as
 *  examples/BrainShiftRegistrationExample.cxx does, gives on the same inputs
 *  what `biomech register` gives (bmr::RegisterBrainShift): the same nodal
 *  displacements (to 1e-9 mm), the same B-spline transform and the same
 *  warped image. Colin27, 8 mm hexahedra, the example's sparse displacements. */
TEST_F(BrainShiftPipelineTest, FiltersComposedByHandMatchTheRegisterCommand)
{
  if (!bmr_test::HaveColin27())
  {
    GTEST_SKIP() << "Colin27 (mricron-data) is not installed";
  }
  using ImageType = bmr::RegistrationImage;
  using MaskImageType = bmr::RegistrationLabelImage;
  const std::filesystem::path image = bmr_test::Colin27Folder / "ch2.nii.gz";
  const std::filesystem::path brain = bmr_test::Colin27Folder / "ch2bet.nii.gz";
  const std::filesystem::path csv = std::filesystem::path(BMR_SOURCE_DIR) / "examples" / "data" /
                                    "colin27-superior-craniotomy.csv";
  const Vector3               craniotomyCentre(-11.0, 43.0, 84.0);
  const double                craniotomyRadius = 30.0, elementSize = 8.0;

  const std::filesystem::path output = m_Folder / "register";
  std::ostringstream          arguments;
  arguments << "register '" << image.string() << "' --mask '" << brain.string() << "' --craniotomy-centre "
            << craniotomyCentre.x() << " " << craniotomyCentre.y() << " " << craniotomyCentre.z()
            << " --craniotomy-radius " << craniotomyRadius << " --sparse-displacements '" << csv.string()
            << "' --element-size " << elementSize << " -o '" << output.string() << "'";
  const auto run = RunBiomech(m_Folder, arguments.str());
  ASSERT_EQ(run.exitCode, 0) << run.err;

  // The same registration from the filters.
  const ImageType::Pointer preoperative = itk::ReadBiomechanicalImage<ImageType>(image.string(), "Colin27");
  auto threshold = itk::BinaryThresholdImageFilter<ImageType, MaskImageType>::New();
  threshold->SetInput(itk::ReadBiomechanicalImage<ImageType>(brain.string(), "mask"));
  threshold->SetLowerThreshold(std::numeric_limits<float>::min()); // voxels > 0 are brain
  threshold->SetInsideValue(1);
  threshold->SetOutsideValue(0);
  threshold->Update();
  const MaskImageType::Pointer mask = threshold->GetOutput();

  auto classifier = itk::FuzzyCMeansClassifierImageFilter<ImageType, MaskImageType>::New();
  classifier->SetInput(preoperative);
  classifier->SetMaskImage(mask);
  classifier->SetNumberOfClasses(3);
  auto grid = itk::BiomechanicalGridImageFilter<MaskImageType>::New();
  grid->SetInput(mask);
  grid->SetElementSize(elementSize);
  grid->Update();
  auto mapping = itk::BiomechanicalMaterialMappingFilter<>::New();
  mapping->SetModelInput(grid->GetModelOutput());
  mapping->SetMemberships(classifier->GetOutput());
  auto surfaces = itk::BrainSurfaceMeshSource<MaskImageType>::New();
  surfaces->SetInput(itk::MakeImageFromBiomechanicalVolume<MaskImageType>(
    RasterizeCells(grid->GetModel(), itk::MakeBiomechanicalGeometry(mask.GetPointer()))));
  auto regions = itk::BiomechanicalRegionsFilter<MaskImageType>::New();
  regions->SetModelInput(mapping->GetOutput());
  regions->SetCraniotomyCentre(craniotomyCentre);
  regions->SetCraniotomyRadius(craniotomyRadius);
  const SparseDisplacements measured = ReadSparseDisplacements(csv.string());
  auto                      loads = itk::BiomechanicalLoadsFilter<PointSetType>::New();
  loads->SetModelInput(regions->GetOutput());
  loads->SetSparseDisplacements(itk::MakeDisplacementPointSet<PointSetType>(measured.points, measured.displacements));
  auto deformation = FilterType::New();
  deformation->SetModelInput(regions->GetOutput());
  deformation->SetPrescribedDisplacements(loads->GetOutput());
  deformation->SetContactSurface(surfaces->GetSkullOutput());
  deformation->SetTolerance(0.01);
  auto fitter = itk::DisplacementPointSetToBSplineTransformFilter<PointSetType>::New();
  fitter->SetInput(deformation->GetOutput());
  fitter->SetReferenceImage(preoperative);
  auto warp = itk::TransformWarpImageFilter<ImageType>::New();
  warp->SetInput(preoperative);
  fitter->Update();
  warp->SetTransform(fitter->GetTransform());
  warp->Update();
  ASSERT_TRUE(deformation->GetConverged());

  // Nodal displacements: the command's model-result.vtu against the deformation filter's output.
  const MeshData result = ReadMesh((output / "model-result.vtu").string());
  const auto *   points = deformation->GetOutput()->GetPoints();
  const auto *   data = deformation->GetOutput()->GetPointData();
  ASSERT_EQ(result.model.nodes.size(), points->Size());
  const DataArray & written = result.pointData.at("displacement");
  double            positionDifference = 0.0, displacementDifference = 0.0, largest = 0.0;
  for (std::size_t n = 0; n < points->Size(); ++n)
  {
    for (unsigned int d = 0; d < 3; ++d)
    {
      positionDifference = std::max(positionDifference, std::abs(result.model.nodes[n][d] - points->ElementAt(n)[d]));
      displacementDifference = std::max(displacementDifference, std::abs(written.values[3 * n + d] - data->ElementAt(n)[d]));
      largest = std::max(largest, std::abs(data->ElementAt(n)[d]));
    }
  }
  EXPECT_LE(positionDifference, 1e-9);
  // Contact's in/out decisions amplify last-bit differences between the
  // program's and the library's copies of inline code (docs/solver.md).
  RecordProperty("displacement_difference_mm", Sci(displacementDifference));
  EXPECT_LE(displacementDifference, 1e-9);
  EXPECT_GT(largest, 3.0); // the measured sag peaks at 5 mm

  // The transform: the same B-spline grid and coefficients.
  const auto written_transform = itk::ReadBiomechanicalTransform((output / "transform.h5").string());
  const auto * bspline = dynamic_cast<const itk::BSplineTransform<double, 3, 3> *>(written_transform.GetPointer());
  ASSERT_NE(bspline, nullptr);
  const auto & fixed = fitter->GetTransform()->GetFixedParameters();
  const auto & parameters = fitter->GetTransform()->GetParameters();
  ASSERT_EQ(bspline->GetFixedParameters().size(), fixed.size());
  ASSERT_EQ(bspline->GetParameters().size(), parameters.size());
  for (unsigned int k = 0; k < fixed.size(); ++k)
  {
    EXPECT_NEAR(bspline->GetFixedParameters()[k], fixed[k], 1e-9) << k;
  }
  double coefficientDifference = 0.0;
  for (unsigned int k = 0; k < parameters.size(); ++k)
  {
    coefficientDifference = std::max(coefficientDifference, std::abs(bspline->GetParameters()[k] - parameters[k]));
  }
  EXPECT_LE(coefficientDifference, 1e-9);

  // The warped image, voxel by voxel.
  const ImageType::Pointer warped = itk::ReadBiomechanicalImage<ImageType>((output / "warped.nii.gz").string(), "warped");
  ASSERT_EQ(warped->GetBufferedRegion(), warp->GetOutput()->GetBufferedRegion());
  const std::size_t voxels = warped->GetBufferedRegion().GetNumberOfPixels();
  double            intensityDifference = 0.0;
  for (std::size_t v = 0; v < voxels; ++v)
  {
    intensityDifference = std::max(
      intensityDifference, std::abs(double(warped->GetBufferPointer()[v]) - double(warp->GetOutput()->GetBufferPointer()[v])));
  }
  EXPECT_LE(intensityDifference, 1e-3);
}

} // namespace
