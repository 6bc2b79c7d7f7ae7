// Shared pieces of the rsfm command line: exit codes, the one-line error contract, progress.
// Exit codes: 0 success, 1 runtime failure (numerical trouble, plotting failed), 2 bad input
// (unknown subcommand or option, invalid value, malformed file, unwritable output).
#pragma once

#include <CLI/CLI.hpp>

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "rsfm/report/report.hpp"

namespace rsfm::cli {

constexpr int kBadInput = 2;
constexpr int kRuntimeFailure = 1;

/// Prints `rsfm: error: MSG` on one line of stderr and returns `code`.
int fail(int code, const std::string& msg);

/// Runs `f`: an io::InputError becomes `rsfm: error: ...` with kBadInput, any other exception the
/// same with kRuntimeFailure. Returns 0 when `f` returned normally.
int guarded(const std::function<void()>& f);

/// Progress on stderr: a rewritten line on a terminal, else one line per 10 %.
/// `unit` names what is counted ("trials", "frames").
std::function<void(int, int)> progressReporter(std::string name, std::string unit = "trials");

/// `rsfm track` / `run`: when the tracker left out the frames from `range_first` to `first` - 1
/// (nothing to track there: trimLeadingEmptyFrames), says so on stderr unless `quiet`.
/// `features` names what was missing ("corners", "patches"), `tracks` what starts at `first`.
void sayLeadingFramesLeftOut(bool quiet, int range_first, int first, const char* features, const char* tracks);

/// `rsfm track` / `run`: when the tracker took `changed` of its `steps` again for a change of
/// exposure (TrackerOptions::exposure_compensation), says so on stderr unless `quiet`.
void sayExposureCompensated(bool quiet, long changed, long steps);
/// Says (stderr) that the video dropped frames (TrackingStats::dropped_frames), if it did.
void sayDroppedFrames(bool quiet, long dropped, double fps);

/// A registered command: the CLI11 subcommand and what runs when it was parsed.
struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;
};

/// A figure that could not be made is a warning, printed also with --quiet; the numbers are
/// written regardless (docs/outputs.md, "Figures").
void warnFigures(const report::Figures& f);
/// ", a.png, a.svg" for the figures made (the end of a "wrote ..." line).
std::string wroteFigures(const report::Figures& f);

/// The whole command line as typed (recorded in reports).
const std::string& invocation();

/// The file or folder a video / image-sequence input names (a pattern's folder): an output
/// directory must not hold it (io::OutputDir replaces its directory whole).
inline std::filesystem::path inputPath(const std::string& input) {
  if (input.find('%') == std::string::npos) return input;
  const std::filesystem::path dir = std::filesystem::path(input).parent_path();
  return dir.empty() ? std::filesystem::path(".") : dir;
}

// One registration function per command family (apps/cmd_*.cpp).
void addExperimentCommands(CLI::App& app, std::vector<Command>& commands);
void addTrackCommands(CLI::App& app, std::vector<Command>& commands);
void addEstimateCommands(CLI::App& app, std::vector<Command>& commands);
void addRunCommands(CLI::App& app, std::vector<Command>& commands);
void addRenderCommands(CLI::App& app, std::vector<Command>& commands);
void addEvaluateCommands(CLI::App& app, std::vector<Command>& commands);
void addBenchCommands(CLI::App& app, std::vector<Command>& commands);

}  // namespace rsfm::cli
