#include "rsfm/report/report.hpp"

#include <fmt/format.h>

#include <cmath>
#include <cstdlib>
#include <stdexcept>

#include "rsfm/io/atomic_file.hpp"

namespace rsfm::report {

using namespace rsfm::io;  // the file formats the reports write
namespace {

std::string shellQuote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

}  // namespace

std::string formatNumber(double v, int prec) {
  if (!std::isfinite(v)) return "NA";
  return fmt::format("{:.{}f}", v, prec);
}

std::string pythonInterpreter() {
  if (const char* p = std::getenv("RSFM_PYTHON"); p && *p) return p;
  return "/usr/bin/python3";
}

std::string scriptsDirectory() {
  if (const char* p = std::getenv("RSFM_SCRIPTS_DIR"); p && *p) return p;
  return RSFM_SCRIPTS_DIR;
}

void runScript(const std::string& script, const std::vector<std::string>& args) {
  const std::string path = scriptsDirectory() + "/" + script;
  std::string cmd = "MPLBACKEND=Agg ";
  cmd += shellQuote(pythonInterpreter());
  cmd += ' ';
  cmd += shellQuote(path);
  for (const auto& a : args) {
    cmd += ' ';
    cmd += shellQuote(a);
  }
  cmd += " 1>&2";
  const int rc = std::system(cmd.c_str());
  if (rc != 0)
    throw std::runtime_error("figure failed: " + path + " exited with status " + std::to_string(rc) +
                             " (needs python3-matplotlib; see scripts/install-deps.sh)");
}

void runPlotScript(const std::string& script, const std::filesystem::path& data,
                   const std::filesystem::path& png, const std::filesystem::path& svg) {
  runScript(script, {data.string(), png.string(), svg.string()});
}

void writeFigureReport(const std::filesystem::path& dir, const std::string& stem, const std::string& csv,
                       const std::string& markdown, const std::string& data_stem, const std::string& data,
                       const std::string& figure_stem, const std::string& script) {
  AtomicFileSet files;
  files.write(dir / (stem + ".csv"), csv);
  files.write(dir / (stem + ".md"), markdown);
  const auto data_tmp = files.write(dir / (data_stem + ".csv"), data);
  const auto png = files.temp(dir / (figure_stem + ".png"));
  const auto svg = files.temp(dir / (figure_stem + ".svg"));
  runPlotScript(script, data_tmp, png, svg);
  files.commit();
}

}  // namespace rsfm::report
