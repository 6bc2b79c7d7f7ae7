#pragma once
// Pieces shared by the experiments' reports (docs/outputs.md).
#include <filesystem>
#include <string>
#include <vector>

namespace rsfm::report {

/// Fixed-point text of v with `prec` decimals; "NA" when v is not finite (never "nan").
std::string formatNumber(double v, int prec = 4);

/// Python interpreter for the plots: $RSFM_PYTHON, else /usr/bin/python3.
std::string pythonInterpreter();
/// Directory of the plot scripts: $RSFM_SCRIPTS_DIR, else the source tree's scripts/.
std::string scriptsDirectory();

/// Runs scripts/<script> ARGS... with the plotting interpreter (MPLBACKEND=Agg); throws
/// std::runtime_error with a one-line message when it fails.
void runScript(const std::string& script, const std::vector<std::string>& args);
/// Runs scripts/<script> DATA PNG SVG with the plotting interpreter (MPLBACKEND=Agg); throws
/// std::runtime_error with a one-line message when it fails.
void runPlotScript(const std::string& script, const std::filesystem::path& data,
                   const std::filesystem::path& png, const std::filesystem::path& svg);

/// Writes DIR/<stem>.csv, DIR/<stem>.md, DIR/<data_stem>.csv and the figure DIR/<figure_stem>.png
/// and .svg made by `script` from that data, all-or-nothing (AtomicFileSet); throws
/// std::runtime_error with a one-line message.
void writeFigureReport(const std::filesystem::path& dir, const std::string& stem, const std::string& csv,
                       const std::string& markdown, const std::string& data_stem, const std::string& data,
                       const std::string& figure_stem, const std::string& script);

}  // namespace rsfm::report
