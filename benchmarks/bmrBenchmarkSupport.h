// Helpers shared by the benchmark drivers: number formatting, the machine's
// description and load, and the marked section of docs/benchmarks.md that the image
// benchmark (bmrImageBenchmark) owns, so that each driver rewrites only its
// own part of the report.
#ifndef bmrBenchmarkSupport_h
#define bmrBenchmarkSupport_h

#include <fstream>
#include <iomanip>
#include <sstream>
#include <string>

namespace bmr
{
namespace benchmark
{

inline std::string
ReadTextFile(const std::string & path)
{
  std::ifstream      stream(path);
  std::ostringstream text;
  text << stream.rdbuf();
  return text.str();
}

/** `value` with `digits` digits after the point. */
inline std::string
Fixed(double value, int digits)
{
  std::ostringstream text;
  text << std::fixed << std::setprecision(digits) << value;
  return text.str();
}

/** `value` in scientific notation with `digits` digits after the point. */
inline std::string
Sci(double value, int digits = 2)
{
  std::ostringstream text;
  text << std::scientific << std::setprecision(digits) << value;
  return text.str();
}

inline std::string
CpuModel()
{
  std::istringstream cpuinfo(ReadTextFile("/proc/cpuinfo"));
  std::string        line;
  while (std::getline(cpuinfo, line))
  {
    if (line.rfind("model name", 0) == 0)
    {
      const auto colon = line.find(':');
      return colon == std::string::npos ? line : line.substr(colon + 2);
    }
  }
  return "unknown";
}

inline std::string
LoadAverage()
{
  std::istringstream loadavg(ReadTextFile("/proc/loadavg"));
  std::string        one, five, fifteen;
  loadavg >> one >> five >> fifteen;
  return one + " " + five + " " + fifteen;
}

/** Markers of the image benchmark's section of docs/benchmarks.md. */
constexpr const char * ImageSectionBegin = "<!-- image-benchmark: written by bmrImageBenchmark -->";
constexpr const char * ImageSectionEnd = "<!-- image-benchmark: end -->";

/** The sections scripts write on the page, each between `<!-- NAME:begin -->` and
 *  `<!-- NAME:end -->` (scripts/docsection.py): the surgical simulation
 *  (scripts/benchmark-simulation.py) and issue 20's targets on Colin27
 *  (scripts/benchmark-registration.py, scripts/benchmark-model-building.py) and the
 *  update latency on a prepared bundle (scripts/benchmark-update.py) with its solves
 *  by part (scripts/benchmark-solve-parts.py), the uncertainty map's cost
 *  (scripts/benchmark-uncertainty.py) and the steps on the real brains
 *  (scripts/benchmark-real-brain-steps.py); and the notes written by hand after a
 *  run of the update latency, the solve parts and the uncertainty map's cost. */
constexpr const char * ScriptSections[] = { "simulation-benchmark", "colin27-meshless", "colin27-registration",
                                             "update-latency", "update-latency-note", "solve-parts",
                                             "solve-parts-note", "uncertainty-cost", "uncertainty-cost-note",
                                             "real-brain-steps" };

/** The section of `report` between two markers (included), or "" when it has none. */
inline std::string
MarkedSection(const std::string & report, const char * beginMarker, const char * endMarker)
{
  const auto begin = report.find(beginMarker);
  const auto end = report.find(endMarker);
  if (begin == std::string::npos || end == std::string::npos || end < begin)
  {
    return "";
  }
  return report.substr(begin, end + std::string(endMarker).size() - begin) + "\n";
}

/** The image benchmark's section of `report` (markers included), or "" when it has none. */
inline std::string
ImageSection(const std::string & report)
{
  return MarkedSection(report, ImageSectionBegin, ImageSectionEnd);
}

/** `report` with its image section replaced by `section` (appended when it has none). */
inline std::string
WithImageSection(const std::string & report, const std::string & section)
{
  const std::string old = ImageSection(report);
  if (old.empty())
  {
    return report + (report.empty() || report.back() == '\n' ? "\n" : "\n\n") + section;
  }
  std::string result = report;
  result.replace(report.find(ImageSectionBegin), old.size(), section);
  return result;
}

} // namespace benchmark
} // namespace bmr

#endif
