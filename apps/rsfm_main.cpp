// rsfm: command-line interface. Each command family registers itself from apps/cmd_*.cpp.
// Exit codes (apps/cli_common.hpp): 0 success, 1 runtime failure, 2 bad input.
//
// Two executables are built from this file (issue 15): `rsfm` holds the commands that work on
// files of numbers (estimate, evaluate, experiment) and does not link OpenCV's video and image
// I/O, which loads ~240 shared libraries; the commands that open videos or images (track, run,
// render, bench) live in `rsfm-video` beside it (built with RSFM_VIDEO_COMMANDS), to which
// `rsfm` hands them over with execv (same arguments). docs/cli.md.
#include <CLI/CLI.hpp>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <string>
#include <unistd.h>
#include <vector>

#include "cli_common.hpp"
#include "rsfm/version.hpp"

namespace rsfm::cli::detail {
std::string& invocationStorage();
}

namespace {

#ifndef RSFM_VIDEO_COMMANDS
/// The commands of rsfm-video, with their one-line help for `rsfm --help`.
struct VideoCommand {
  const char* name;
  const char* help;
};
constexpr VideoCommand kVideoCommands[] = {
    {"track", "track features through a video or image sequence (rsfm-video)"},
    {"run", "track a video, find planes, estimate and report (the whole chain; rsfm-video)"},
    {"render", "render test sequences with known camera motion and planes (rsfm-video)"},
    {"bench", "benchmarks over many sequences (rsfm-video)"},
};

/// Replaces this process with rsfm-video (the same directory as this executable) and the same
/// arguments; returns only on failure, with the exit code.
int handOver(char** argv) {
  std::error_code ec;
  std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  const std::filesystem::path video = (ec ? std::filesystem::path(argv[0]) : self).parent_path() / "rsfm-video";
  ::execv(video.c_str(), argv);
  return rsfm::cli::fail(rsfm::cli::kRuntimeFailure, std::string("'") + argv[1] + "' is a command of rsfm-video, which could not be started (" +
                                                         video.string() + ": " + std::strerror(errno) + ")");
}
#endif

}  // namespace

int main(int argc, char** argv) {
  using namespace rsfm::cli;
#ifndef RSFM_VIDEO_COMMANDS
  if (argc > 1)
    for (const VideoCommand& v : kVideoCommands)
      if (std::strcmp(argv[1], v.name) == 0) return handOver(argv);
#endif
  {
    std::string& s = detail::invocationStorage();
    for (int i = 1; i < argc; ++i) s += std::string(" ") + argv[i];
  }
  CLI::App app{"rsfm: recursive estimation of camera motion, focal length and planar structure"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("rsfm ") + rsfm::kVersion);

  std::vector<Command> commands;
  addExperimentCommands(app, commands);
  addEstimateCommands(app, commands);
  addEvaluateCommands(app, commands);
#ifdef RSFM_VIDEO_COMMANDS
  addTrackCommands(app, commands);
  addRunCommands(app, commands);
  addRenderCommands(app, commands);
  addBenchCommands(app, commands);
#else
  for (const VideoCommand& v : kVideoCommands) app.add_subcommand(v.name, v.help);  // for --help (handed over above)
#endif

  // Name an unknown command word explicitly (CLI11 would only say a subcommand is required).
  {
    CLI::App* cur = &app;
    std::string path = "rsfm";
    for (int i = 1; i < argc; ++i) {
      const std::string word = argv[i];
      if (word.empty() || word[0] == '-') break;
      const auto subs = cur->get_subcommands([](CLI::App*) { return true; });
      if (subs.empty()) break;
      CLI::App* next = nullptr;
      std::string names;
      for (CLI::App* sc : subs) {
        names += (names.empty() ? "" : ", ") + sc->get_name();
        if (sc->get_name() == word) next = sc;
      }
      if (!next)
        return fail(kBadInput, "unknown command '" + word + "' for '" + path + "' (expected one of: " + names + ")");
      cur = next;
      path += " " + word;
    }
  }

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::string msg = e.what();
    if (const auto nl = msg.find('\n'); nl != std::string::npos) msg.resize(nl);
    return fail(kBadInput, msg + " (see rsfm --help)");
  }

  for (const Command& c : commands)
    if (c.app->parsed()) return c.run();
  return fail(kBadInput, "no command given (see rsfm --help)");
}
