// `rsfm bench regimes`: the regime suite's scoreboard (docs/regimes.md).
#include <fmt/format.h>

#include <memory>
#include <sstream>

#include "cli_common.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/regimes/bench.hpp"

namespace rsfm::cli {

void addBenchCommands(CLI::App& app, std::vector<Command>& commands) {
  auto* bench = app.add_subcommand("bench", "benchmarks over many sequences");
  bench->require_subcommand(1);
  struct Cli {
    regimes::BenchOptions o;
    std::string out, cache, only;
    bool no_real = false, quiet = false;
  };
  auto st = std::make_shared<Cli>();
  auto* c = bench->add_subcommand(
      "regimes", "render the regime suite (cached), run `rsfm run` with default options on each, score against the truth: "
                 "DIR/scoreboard.csv, .md, .json");
  c->add_option("--out", st->out, "output directory")->required();
  c->add_option("--suite", st->o.suite, "suite file (default: the built-in bench/regimes.json)");
  c->add_option("--cache", st->cache, "rendered sequences (default: $XDG_CACHE_HOME/rsfm/regimes or ~/.cache/rsfm/regimes)");
  c->add_option("--only", st->only, "comma-separated sequence names (the suite's, box-mp4, cube); default: all");
  c->add_option("--jobs", st->o.jobs, "concurrent jobs (0: the number of cores)")->capture_default_str();
  c->add_flag("--no-real", st->no_real, "leave out the real rows (box.mp4 windows, the ViSP cube)");
  c->add_option("--rsfm", st->o.rsfm, "the rsfm binary to score (default: this one)");
  c->add_option("--reference", st->o.reference_dir,
                "folder of COLMAP references NAME/{summary.json,trajectory.tum} (default: the built-in ones)");
  c->add_option("--run-arg", st->o.run_args,
                "an extra `rsfm run` argument (repeatable; the scoreboard is defined with none)")
      ->allow_extra_args(false);
  c->add_flag("--quiet", st->quiet, "no progress on stderr");
  commands.push_back({c, [st]() -> int {
    regimes::BenchOptions o = st->o;
    o.out = st->out;
    o.cache = st->cache;
    o.real = !st->no_real;
    {
      std::stringstream ss(st->only);
      std::string n;
      while (std::getline(ss, n, ','))
        if (!n.empty()) o.only.push_back(n);
    }
    if (int rc = guarded([&] { regimes::checkBenchOptions(o); })) return rc;
    // The output directory is replaced whole (io::OutputDir): no earlier run's files beside this one's.
    io::OutputDir od;
    if (auto m = od.open(o.out); !m.empty()) return fail(kBadInput, m);
    o.out = od.path();
    regimes::BenchResult res;
    const bool quiet = st->quiet;
    if (int rc = guarded([&] {
          res = regimes::runBench(o, [quiet](const std::string& m) {
            if (!quiet) fmt::print(stderr, "{}\n", m);
          });
        }))
      return rc;
    if (int rc = guarded([&] {
          io::writeAllOrNothing({{o.out / "scoreboard.csv", regimes::scoreboardCsv(res)},
                                 {o.out / "scoreboard.md", regimes::scoreboardMarkdown(res, invocation())},
                                 {o.out / "scoreboard.json", regimes::scoreboardJson(res, invocation())}});
          od.commit();
        }))
      return rc;
    if (!quiet)
      fmt::print(stderr, "bench: {} rows in {:.0f} s; wrote {}/scoreboard.csv, scoreboard.md, scoreboard.json\n",
                 res.rows.size(), res.seconds, st->out);
    return 0;
  }});
}

}  // namespace rsfm::cli
