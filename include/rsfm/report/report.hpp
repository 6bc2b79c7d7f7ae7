#pragma once
// Pieces shared by the experiments' reports (docs/outputs.md).
#include <filesystem>
#include <string>
#include <vector>

namespace rsfm::io {
class AtomicFileSet;
}

namespace rsfm::report {

/// Fixed-point text of v with `prec` decimals; "NA" when v is not finite (never "nan").
std::string formatNumber(double v, int prec = 4);

/// Python interpreter for the plots: $RSFM_PYTHON, else /usr/bin/python3.
std::string pythonInterpreter();
/// Directory of the plot scripts: $RSFM_SCRIPTS_DIR when set; else the first share/rsfm/scripts
/// (holding plot_estimate.py) in the directory of the binary that holds this code (the
/// executable, or the Python module's shared object) or one of its five nearest ancestors: an
/// installed prefix (bin/rsfm -> share/rsfm/scripts) and the build tree (build/rsfm ->
/// build/share/rsfm/scripts, a link to the source tree's scripts/). "" when none is found.
std::string scriptsDirectory();

/// The figures one plot script makes (docs/outputs.md, "Figures"). A figure that cannot be made
/// is a warning, never a lost result: its files are left out and `why` says why in one line.
struct Figures {
  std::vector<std::string> written;  ///< file names made (e.g. "motion.png")
  std::vector<std::filesystem::path> files;  ///< where each of `written` is until committed
  std::vector<std::string> missing;  ///< file names that could not be made
  std::string why;                   ///< one line, when `missing` is not empty
  /// "figures not written (a.png, a.svg): why", or "" when every figure was made.
  std::string warning() const;
};

/// Runs scripts/<script> ARGS... with the plotting interpreter (MPLBACKEND=Agg); throws
/// std::runtime_error with a one-line message when it fails.
void runScript(const std::string& script, const std::vector<std::string>& args);

/// Runs scripts/<script> INPUTS... followed by the temporaries of DIR/NAME for each of `names`
/// (added to `files`). When the script fails or cannot be found, those temporaries are dropped
/// from `files` and the outcome says why; nothing is thrown.
Figures makeFigures(io::AtomicFileSet* files, const std::filesystem::path& dir, const std::string& script,
                    std::vector<std::string> inputs, const std::vector<std::string>& names);

/// Writes DIR/<stem>.csv, DIR/<stem>.md, DIR/<data_stem>.csv and the figure DIR/<figure_stem>.png
/// and .svg made by `script` from that data, all-or-nothing (AtomicFileSet); throws
/// std::runtime_error with a one-line message when a file cannot be written. A figure that
/// cannot be made is left out, and the returned outcome says why.
Figures writeFigureReport(const std::filesystem::path& dir, const std::string& stem, const std::string& csv,
                       const std::string& markdown, const std::string& data_stem, const std::string& data,
                       const std::string& figure_stem, const std::string& script);

}  // namespace rsfm::report
