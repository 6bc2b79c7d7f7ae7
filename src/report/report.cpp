#include "rsfm/report/report.hpp"

#include <fmt/format.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <dlfcn.h>
#include <stdexcept>

#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/input_error.hpp"

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
  // The binary holding this function: the executable (static libraries) or a shared object.
  Dl_info info{};
  if (::dladdr(reinterpret_cast<void*>(&scriptsDirectory), &info) == 0 || !info.dli_fname) return {};
  std::error_code ec;
  std::filesystem::path bin = std::filesystem::canonical(info.dli_fname, ec);
  if (ec) bin = std::filesystem::canonical("/proc/self/exe", ec);
  if (ec) return {};
  std::filesystem::path dir = bin.parent_path();
  for (int up = 0; up <= 5 && !dir.empty(); ++up) {
    const std::filesystem::path cand = dir / "share" / "rsfm" / "scripts";
    if (std::filesystem::is_regular_file(cand / "plot_estimate.py", ec)) return cand.string();
    if (dir == dir.parent_path()) break;
    dir = dir.parent_path();
  }
  return {};
}

std::string Figures::warning() const {
  if (missing.empty()) return {};
  std::string names;
  for (const auto& m : missing) names += (names.empty() ? "" : ", ") + m;
  return fmt::format("figures not written ({}): {}", names, why);
}

Figures makeFigures(io::AtomicFileSet* files, const std::filesystem::path& dir, const std::string& script,
                    std::vector<std::string> inputs, const std::vector<std::string>& names) {
  Figures out;
  std::vector<std::filesystem::path> temps;
  try {
    for (const auto& n : names) temps.push_back(files->temp(dir / n));
    for (const auto& t : temps) inputs.push_back(t.string());
    runScript(script, inputs);
    // A script that exits 0 without writing a figure leaves its placeholder empty: missing too.
    for (size_t i = 0; i < names.size(); ++i) {
      std::error_code ec;
      if (std::filesystem::file_size(temps[i], ec) > 0 && !ec) {
        out.written.push_back(names[i]);
        out.files.push_back(temps[i]);
      } else {
        files->drop(temps[i]);
        out.missing.push_back(names[i]);
      }
    }
    if (!out.missing.empty()) out.why = script + " exited without writing them";
  } catch (const std::exception& e) {
    for (const auto& t : temps) files->drop(t);
    out.written.clear();
    out.files.clear();
    out.missing = names;
    out.why = io::printable(e.what(), 300);
  }
  return out;
}

void runScript(const std::string& script, const std::vector<std::string>& args) {
  const std::string dir = scriptsDirectory();
  if (dir.empty())
    throw std::runtime_error(
        "the plot scripts were not found (no share/rsfm/scripts beside the binary or above it; set RSFM_SCRIPTS_DIR)");
  const std::string path = dir + "/" + script;
  if (std::error_code ec; !std::filesystem::is_regular_file(path, ec))
    throw std::runtime_error("the plot script " + path + " is missing");
  std::string cmd = "MPLBACKEND=Agg ";
  cmd += shellQuote(pythonInterpreter());
  cmd += ' ';
  cmd += shellQuote(path);
  for (const auto& a : args) {
    cmd += ' ';
    cmd += shellQuote(a);
  }
  cmd += " 2>&1";
  // The script's output is captured, not echoed: a failure becomes one line (its last line, e.g.
  // "OSError: [Errno 28] No space left on device"), issue 17. popen, unlike system(), leaves
  // SIGINT/SIGTERM to rsfm's handlers (io::OutputDir), so an interrupt still cleans up.
  std::FILE* pipe = ::popen(cmd.c_str(), "r");
  if (!pipe) throw std::runtime_error("figure failed: cannot start " + pythonInterpreter());
  std::string out;
  char buf[4096];
  for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, pipe)) > 0;) {
    out.append(buf, n);
    if (out.size() > (1u << 16)) out.erase(0, out.size() - (1u << 15));  // the tail is what matters
  }
  const int status = ::pclose(pipe);
  if (status == 0) return;
  std::string last;
  std::size_t end = out.find_last_not_of(" \t\r\n");
  if (end != std::string::npos) {
    const std::size_t begin = out.find_last_of('\n', end);
    last = out.substr(begin == std::string::npos ? 0 : begin + 1, end + 1 - (begin == std::string::npos ? 0 : begin + 1));
  }
  const bool missing = last.find("No module named") != std::string::npos || status == 127 << 8;
  throw std::runtime_error(fmt::format("figure failed: {}: {}{}", script,
                                       last.empty() ? fmt::format("exited with status {}", status) : io::printable(last, 200),
                                       missing ? " (needs python3 with python3-matplotlib; see scripts/install-deps.sh)" : ""));
}

Figures writeFigureReport(const std::filesystem::path& dir, const std::string& stem, const std::string& csv,
                          const std::string& markdown, const std::string& data_stem, const std::string& data,
                          const std::string& figure_stem, const std::string& script) {
  AtomicFileSet files;
  files.write(dir / (stem + ".csv"), csv);
  files.write(dir / (stem + ".md"), markdown);
  const auto data_tmp = files.write(dir / (data_stem + ".csv"), data);
  Figures fig = makeFigures(&files, dir, script, {data_tmp.string()}, {figure_stem + ".png", figure_stem + ".svg"});
  files.commit();
  return fig;
}

}  // namespace rsfm::report
