// `rsfm evaluate`: an estimate against the truth (docs/evaluate.md).
#include <cmath>
#include <fmt/format.h>

#include <memory>
#include <string>

#include "cli_common.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/report/evaluation.hpp"

namespace rsfm::cli {

void addEvaluateCommands(CLI::App& app, std::vector<Command>& commands) {
  auto* ev = app.add_subcommand(
      "evaluate", "compare DIR/trajectory.tum and DIR/summary.json of an estimate with the truth (ATE, RPE, "
                  "plane normals, focal length)");
  struct EvalCli {
    std::string estimate, truth, out;
    rsfm::report::EvaluateOptions o;
  };
  auto st = std::make_shared<EvalCli>();
  ev->add_option("--estimate", st->estimate, "estimate directory (trajectory.tum, summary.json)")->required();
  ev->add_option("--truth", st->truth,
                 "truth directory (trajectory.tum, summary.json), or a TUM trajectory file in seconds (a dataset's "
                 "ground truth, e.g. TUM RGB-D's groundtruth.txt: camera poses only)")->required();
  ev->add_option("--out", st->out, "output directory for evaluation.json and evaluation.md (default: the estimate's)");
  ev->add_option("--rpe-delta", st->o.rpe_delta, "RPE frame distance (frames)")->capture_default_str();
  ev->add_option("--t-max-diff", st->o.t_max_diff,
                 "associate a truth pose with the estimate pose nearest in time within this (seconds; frames when "
                 "neither summary states fps), as evo's --t_max_diff")
      ->capture_default_str();
  commands.push_back({ev, [st]() -> int {
    if (st->o.rpe_delta < 1) return fail(kBadInput, fmt::format("--rpe-delta must be >= 1, got {}", st->o.rpe_delta));
    if (!(st->o.t_max_diff >= 0) || !std::isfinite(st->o.t_max_diff))
      return fail(kBadInput, fmt::format("--t-max-diff must be a finite number >= 0, got {}", st->o.t_max_diff));
    rsfm::report::Evaluation e;
    try {
      e = rsfm::report::evaluateDirectories(st->estimate, st->truth, st->o);
    } catch (const rsfm::io::InputError& err) {
      return fail(kBadInput, err.what());
    } catch (const std::exception& err) {
      return fail(kRuntimeFailure, err.what());
    }
    // --out: a directory of its own, replaced whole; default: evaluation.json and evaluation.md
    // added to the estimate's directory (each file all-or-nothing).
    rsfm::io::OutputDir od;
    if (!st->out.empty())
      if (auto msg = od.open(st->out, {st->estimate, st->truth}); !msg.empty()) return fail(kBadInput, msg);
    try {
      rsfm::report::writeEvaluation(e, st->out.empty() ? std::filesystem::path(st->estimate) : od.path(), invocation());
      if (!st->out.empty()) od.commit();
    } catch (const std::exception& err) {
      return fail(kRuntimeFailure, err.what());
    }
    fmt::print("{}", rsfm::report::evaluationTable(e));
    return 0;
  }});
}

}  // namespace rsfm::cli
