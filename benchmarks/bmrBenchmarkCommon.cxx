// Helpers shared by the parts of bmrBenchmark: timing, medians and number
// formats, other processes' CPU use (contention), cell keys, atomic writes, the log.
#include "bmrBenchmarkDriver.h"
#include "bmrMeshIO.h"
#include "bmrModel.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <thread>

#include <sys/resource.h>
#include <unistd.h>

namespace bmr
{
namespace benchmark
{

double
Seconds(Clock::time_point start)
{
  return std::chrono::duration<double>(Clock::now() - start).count();
}

double
Median(std::vector<double> values)
{
  if (values.empty())
  {
    return 0.0;
  }
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

void
Log(const std::string & line)
{
  std::cerr << "[bmrBenchmark] " << line << std::endl;
}

// ---------------------------------------------------------------------------
// Contention: how much CPU other processes used while a case ran.
// ---------------------------------------------------------------------------
namespace
{

CpuSample
ReadCpu()
{
  std::ifstream      stat("/proc/stat");
  std::string        label;
  CpuSample          sample;
  unsigned long long value = 0;
  stat >> label;
  const double tick = static_cast<double>(sysconf(_SC_CLK_TCK));
  for (int field = 0; field < 8 && stat >> value; ++field) // user nice system idle iowait irq softirq steal
  {
    (field == 3 || field == 4 ? sample.idleSeconds : sample.busySeconds) += value / tick;
  }
  return sample;
}

double
OwnCpuSeconds()
{
  double total = 0.0;
  for (const int who : { RUSAGE_SELF, RUSAGE_CHILDREN })
  {
    rusage usage{};
    getrusage(who, &usage);
    total += usage.ru_utime.tv_sec + 1e-6 * usage.ru_utime.tv_usec + usage.ru_stime.tv_sec + 1e-6 * usage.ru_stime.tv_usec;
  }
  return total;
}

} // namespace

void
ContentionMeter::Start()
{
  m_Cpu = ReadCpu();
  m_Own = OwnCpuSeconds();
  m_Start = Clock::now();
}

double
ContentionMeter::OtherCores() const
{
  const double wall = Seconds(m_Start);
  const double busy = ReadCpu().busySeconds - m_Cpu.busySeconds;
  const double own = OwnCpuSeconds() - m_Own;
  return wall > 0.0 ? std::max(0.0, (busy - own) / wall) : 0.0;
}

double
WaitForQuiet(double maxSeconds, double threshold)
{
  const auto start = Clock::now();
  double     others = 0.0;
  do
  {
    ContentionMeter meter;
    meter.Start();
    std::this_thread::sleep_for(std::chrono::seconds(3));
    others = meter.OtherCores();
    if (others < threshold)
    {
      break;
    }
  } while (Seconds(start) < maxSeconds);
  return others;
}

bmr::GridCells
CellsFromKey(const std::string & key)
{
  if (key == "hex")
  {
    return bmr::GridCells::Hexahedra;
  }
  if (key == "tet")
  {
    return bmr::GridCells::Tetrahedra;
  }
  throw bmr::Error("bmrBenchmark: cells must be 'hex' or 'tet', not '" + key + "'");
}

void
WriteCreatingFolder(const std::string & path, const std::string & text)
{
  const std::filesystem::path target(path);
  if (target.has_parent_path())
  {
    std::filesystem::create_directories(target.parent_path());
  }
  WriteTextFileAtomically(path, text);
}

Json
RunChild(const std::string & self, const std::string & arguments)
{
  const std::string command = "'" + self + "' --child " + arguments;
  FILE *            pipe = ::popen(command.c_str(), "r");
  if (!pipe)
  {
    throw bmr::Error("bmrBenchmark: could not start " + command);
  }
  std::string output;
  char        buffer[4096];
  while (std::fgets(buffer, sizeof buffer, pipe))
  {
    output += buffer;
  }
  const int   status = ::pclose(pipe);
  const auto  at = output.rfind("BMR_RESULT ");
  if (status != 0 || at == std::string::npos)
  {
    throw bmr::Error("bmrBenchmark: child '" + arguments + "' failed (status " + std::to_string(status) +
                     "). Output:\n" + output);
  }
  return Json::parse(output.substr(at + 11));
}

double
PeakMemoryMiB(int who)
{
  rusage usage{};
  getrusage(who, &usage);
  return usage.ru_maxrss / 1024.0; // Linux: kB
}

} // namespace benchmark
} // namespace bmr
