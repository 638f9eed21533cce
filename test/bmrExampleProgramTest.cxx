// The C++ pipeline example (examples/BrainShiftRegistrationExample.cxx) run
// end to end on Colin27 (Debian's mricron-data): its summary's numbers against
// what the loading implies, and a bad input named with nothing written.
#include "bmrTemporaryFolderTest.h"
#include "itk_zlib.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <sys/wait.h>

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace
{

using bmr::test::CommandResult;
using bmr::test::ReadText;

const fs::path Colin27Folder("/usr/share/mricron/templates");
const fs::path SparseDisplacements = fs::path(BMR_SOURCE_DIR) / "examples" / "data" / "colin27-superior-craniotomy.csv";

/** A gzip file's content, uncompressed ("" if it cannot be read). */
std::string
Gunzipped(const fs::path & path)
{
  std::string content;
  gzFile      file = gzopen(path.string().c_str(), "rb");
  if (file == nullptr)
  {
    return content;
  }
  char buffer[1 << 16];
  int  count = 0;
  while ((count = gzread(file, buffer, sizeof buffer)) > 0)
  {
    content.append(buffer, static_cast<std::size_t>(count));
  }
  gzclose(file);
  return content;
}

std::string
Quoted(const fs::path & path)
{
  return "'" + path.string() + "'";
}

class ExampleProgramTest : public bmr::test::TemporaryFolderTest
{
protected:
  /** Runs the example with ARGUMENTS (already quoted), output captured through
   *  files in the test folder, as bmr::test::RunBiomech does for biomech. Idle
   *  OpenMP threads sleep (ctest runs two tests at once on two cores). */
  CommandResult RunExample(const std::string & arguments) const
  {
    const fs::path    outPath = m_Folder / "stdout.txt";
    const fs::path    errPath = m_Folder / "stderr.txt";
    const std::string command = std::string("OMP_WAIT_POLICY=\"${OMP_WAIT_POLICY:-PASSIVE}\" '") +
                                BMR_EXAMPLE_EXECUTABLE + "' " + arguments + " > " + Quoted(outPath) + " 2> " +
                                Quoted(errPath) + " < /dev/null";
    const int     status = std::system(command.c_str());
    CommandResult result;
    result.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    result.out = ReadText(outPath);
    result.err = ReadText(errPath);
    fs::remove(outPath);
    fs::remove(errPath);
    return result;
  }

  /** The Colin27 craniotomy of scripts/run-demo.sh: centre (-11, 43, 84), radius 30 mm. */
  std::string Colin27Arguments(const fs::path & image, const fs::path & outputFolder) const
  {
    return Quoted(image) + " " + Quoted(Colin27Folder / "ch2bet.nii.gz") + " " + Quoted(SparseDisplacements) +
           " -11 43 84 30 " + Quoted(outputFolder);
  }
};

TEST_F(ExampleProgramTest, RegistersColin27WithTheSparseCraniotomyLoad)
{
  if (!fs::exists(Colin27Folder / "ch2.nii.gz") || !fs::exists(Colin27Folder / "ch2bet.nii.gz"))
  {
    GTEST_SKIP() << "Colin27 (" << (Colin27Folder / "ch2.nii.gz").string()
                 << ") is not installed: run scripts/install-dependencies.sh (Debian package mricron-data)";
  }
  const fs::path output = m_Folder / "out";
  // 7 mm hexahedra (about 6,400 nodes) keep the run near 10 s.
  const CommandResult run = RunExample(Colin27Arguments(Colin27Folder / "ch2.nii.gz", output) + " 7");
  ASSERT_EQ(run.exitCode, 0) << run.out << run.err;
  ASSERT_TRUE(fs::exists(output / "summary.json")) << run.out;
  EXPECT_GT(fs::file_size(output / "warped.nii.gz"), 0u);
  EXPECT_GT(fs::file_size(output / "transform.h5"), 0u);
  const json summary = json::parse(ReadText(output / "summary.json"));

  EXPECT_GT(summary["nodes"].get<int>(), 1000);
  EXPECT_GT(summary["cells"].get<int>(), 1000);
  EXPECT_GT(summary["loaded_nodes"].get<int>(), 0);

  // Converged to the 0.01 mm the example asks for.
  EXPECT_TRUE(summary["converged"].get<bool>());
  EXPECT_LE(summary["estimated_error_mm"].get<double>(), 0.01);

  // The load is a sag 5 (1 - (r/30)^2) mm whose peak, 5 mm, is at the centre of
  // the craniotomy. The loaded nodes take the thin-plate-spline interpolation of
  // the 61 measurements exactly, and the brain beneath them, pushed by them,
  // moves less; so the largest displacement is the load's largest value at an
  // exposed node. That is within 0.5 mm (10%) of the peak: a node lies within
  // half a 7 mm cell of the centre (sag >= 5 (1 - (3.5/30)^2) = 4.93 mm), and the
  // staircase nodes lie up to half a cell off the measured surface, where the
  // interpolant may overshoot by a few tenths. Measured: 5.03 mm (4.86 mm with 6 mm cells).
  EXPECT_NEAR(summary["max_displacement_mm"].get<double>(), 5.0, 0.5);

  // The fitter refines until the largest residual at the nodes is 0.1 mm.
  EXPECT_LE(summary["fit_max_residual_mm"].get<double>(), 0.1);
  EXPECT_LE(summary["fit_rms_residual_mm"].get<double>(), summary["fit_max_residual_mm"].get<double>());

  // Warped against original: identical images would give 0. An edge moves with
  // the tissue, at most the largest displacement (about 5 mm), so the 95th
  // percentile stays below it. Measured: 3.6 mm. Only the superior part of the
  // brain moves much, so most edges stay within the 1.7 mm threshold (0.89).
  const double p95 = summary["hausdorff_p95_mm"].get<double>();
  EXPECT_GT(p95, 0.0);
  EXPECT_LT(p95, 5.0);
  EXPECT_GT(summary["fraction_within_threshold"].get<double>(), 0.5);
  EXPECT_LT(summary["fraction_within_threshold"].get<double>(), 1.0);

  // The example's chain of filters (classifier, grid, material mapping, loads,
  // deformation, fitter, warp) is `biomech register`'s on the same inputs:
  // the same solve to the last digit and the same warped image, byte for byte.
  const fs::path      registered = m_Folder / "register";
  const CommandResult reg = bmr::test::RunBiomech(
    m_Folder, "register " + Quoted(Colin27Folder / "ch2.nii.gz") + " --mask " + Quoted(Colin27Folder / "ch2bet.nii.gz") +
                " --sparse-displacements " + Quoted(SparseDisplacements) +
                " --craniotomy-centre -11 43 84 --craniotomy-radius 30 --element-size 7 --quiet -o " +
                Quoted(registered));
  ASSERT_EQ(reg.exitCode, 0) << reg.err;
  const json report = json::parse(ReadText(registered / "registration-report.json"));
  EXPECT_EQ(report["solve"]["steps"].get<int>(), summary["solve_steps"].get<int>());
  EXPECT_EQ(report["solve"]["estimated_error_mm"].get<double>(), summary["estimated_error_mm"].get<double>());
  EXPECT_EQ(report["solve"]["max_displacement_mm"].get<double>(), summary["max_displacement_mm"].get<double>());
  EXPECT_EQ(report["model"]["loaded_nodes"].get<int>(), summary["loaded_nodes"].get<int>());
  EXPECT_EQ(report["fit"]["max_residual_mm"].get<double>(), summary["fit_max_residual_mm"].get<double>());
  // The same NIfTI file once uncompressed: the example writes with ITK's own
  // compression, biomech at zlib's fastest level (itk::WriteBiomechanicalImage).
  // Compared as a whole, not with EXPECT_EQ, whose diff of two 30 MB strings
  // would not fit in memory.
  const std::string example = Gunzipped(output / "warped.nii.gz");
  EXPECT_GT(example.size(), 1000000u);
  EXPECT_TRUE(Gunzipped(registered / "warped.nii.gz") == example)
    << "the example's warped image differs from biomech register's";
}

TEST_F(ExampleProgramTest, MissingImageIsNamedAndNothingIsWritten)
{
  const fs::path      missing = m_Folder / "no-such-image.nii.gz";
  const fs::path      output = m_Folder / "out";
  const CommandResult run = RunExample(Colin27Arguments(missing, output));
  EXPECT_EQ(run.exitCode, 1) << run.out << run.err;
  EXPECT_CONTAINS(run.err, "BrainShiftRegistrationExample: error:");
  EXPECT_CONTAINS(run.err, missing.string());
  EXPECT_FALSE(fs::exists(output / "summary.json"));
  EXPECT_FALSE(fs::exists(output / "warped.nii.gz"));
}

} // namespace
