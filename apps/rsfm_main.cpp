// rsfm: command-line interface. Each command family registers itself from apps/cmd_*.cpp.
// Exit codes (apps/cli_common.hpp): 0 success, 1 runtime failure, 2 bad input.
#include <CLI/CLI.hpp>

#include <string>
#include <vector>

#include "cli_common.hpp"

namespace rsfm::cli::detail {
std::string& invocationStorage();
}

int main(int argc, char** argv) {
  using namespace rsfm::cli;
  {
    std::string& s = detail::invocationStorage();
    for (int i = 1; i < argc; ++i) s += std::string(" ") + argv[i];
  }
  CLI::App app{"rsfm: recursive estimation of camera motion, focal length and planar structure"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "rsfm 0.1.0");

  std::vector<Command> commands;
  addExperimentCommands(app, commands);
  addTrackCommands(app, commands);
  addEstimateCommands(app, commands);
  addRenderCommands(app, commands);
  addEvaluateCommands(app, commands);
  addBenchCommands(app, commands);

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
