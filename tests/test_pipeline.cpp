// The pipeline is a library call (pipeline/estimate.hpp): rsfm::estimate() on a tracks file's
// tracks gives exactly the numbers `rsfm estimate` writes for that file, and every option the CLI
// passes takes effect (--normal-sd0 and --beta-sd0 were once overwritten by the start).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "rsfm/report/estimate_report.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "rsfm/io/tum.hpp"
#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/sim/box_scene.hpp"

namespace rsfm {
namespace {
namespace fs = std::filesystem;

/// Tracks of the synthetic box scene (two faces) with 0.5 px noise, written to DIR/tracks.csv.
fs::path writeBoxTracks(const fs::path& dir) {
  std::mt19937_64 rng(5);
  BoxSceneOptions bo;
  bo.frames = 60;
  const BoxScene scene = makeBoxScene(bo, rng);
  Tracks t;
  const double s = bo.scale_px, c = (bo.image_px - 1) / 2.0;
  t.image = {static_cast<int>(bo.image_px), static_cast<int>(bo.image_px), c, c};
  t.frames.resize(bo.frames + 1);
  std::normal_distribution<double> g(0.0, 0.5);
  for (int k = 0; k <= bo.frames; ++k)
    for (int i = 0; i < static_cast<int>(scene.points.size()); ++i)
      t.frames[k].push_back({i, scene.uv[k][i] * s + Eigen::Vector2d(c, c) + Eigen::Vector2d(g(rng), g(rng))});
  fs::create_directories(dir);
  std::ofstream(dir / "tracks.csv") << io::tracksToString(t);
  return dir / "tracks.csv";
}

struct Cli {
  int code = -1;
  std::string tum;  ///< trajectory.tum's text
  nlohmann::json summary;
};

Cli runCli(const fs::path& tracks, const fs::path& out, const std::string& extra) {
  Cli c;
  const std::string cmd = std::string(RSFM_CLI) + " estimate --tracks " + tracks.string() + " --out " + out.string() +
                          " --no-plots --quiet " + extra;
  c.code = std::system(cmd.c_str());
  if (c.code != 0) return c;
  std::ifstream t(out / "trajectory.tum");
  c.tum.assign(std::istreambuf_iterator<char>(t), {});
  std::ifstream in(out / "summary.json");
  in >> c.summary;
  return c;
}

void expectSame(const EstimateResult& lib, const Cli& cli) {
  ASSERT_EQ(cli.code, 0);
  const TrackFilterResult& r = lib.main();  // the refinement's when it ran
  ASSERT_TRUE(r.ok());
  // The same trajectory text (the TUM writer prints doubles in their shortest exact form).
  std::vector<io::TumPose> poses;
  for (const auto& f : r.frames) {
    io::TumPose tp;
    tp.t = f.frame;
    report::poseOf(f, &tp.p, &tp.q);
    poses.push_back(tp);
  }
  std::ostringstream os;
  io::writeTum(os, poses);
  EXPECT_EQ(cli.tum, os.str());
  if (lib.refined.ok && !lib.refined.focal_determined)
    EXPECT_TRUE(cli.summary["focal_px"].is_null());  // reported not determined, with its interval
  else
    EXPECT_EQ(cli.summary["focal_px"].get<double>(), r.scale_px / r.frames.back().beta);
  EXPECT_EQ(cli.summary["planes"].size(), r.frames.back().N.size());
}

TEST(Pipeline, LibraryCallGivesTheCliNumbers) {
  const fs::path dir = fs::temp_directory_path() / ("rsfm_test_pipeline_" + std::to_string(::getpid()));
  const fs::path file = writeBoxTracks(dir);
  const Tracks tracks = io::readTracks(file);  // what the CLI reads (the file's rounding included)
  {
    const EstimateResult lib = estimate(tracks, EstimateOptions{});
    EXPECT_TRUE(lib.start.ok) << lib.start.note;
    EXPECT_TRUE(lib.refined.ok) << lib.refined.message;
    const Cli cli = runCli(file, dir / "default", "");
    expectSame(lib, cli);
    // Each stage's wall clock: every stage that ran took time, and together they fit in the
    // run's seconds (which also hold reading the tracks).
    EXPECT_GT(lib.seconds.plane_finding, 0.0);
    EXPECT_GT(lib.seconds.start, 0.0);
    EXPECT_GT(lib.seconds.filter, 0.0);
    EXPECT_GT(lib.seconds.refinement, 0.0);
    EXPECT_GE(lib.seconds.refinement, lib.refined.seconds);
    ASSERT_TRUE(cli.summary.contains("stage_seconds"));
    double sum = 0;
    for (const char* k : {"plane_finding", "start", "filter", "refinement"}) {
      ASSERT_TRUE(cli.summary["stage_seconds"][k].is_number()) << k;
      EXPECT_GT(cli.summary["stage_seconds"][k].get<double>(), 0.0) << k;
      sum += cli.summary["stage_seconds"][k].get<double>();
    }
    EXPECT_FALSE(cli.summary["stage_seconds"].contains("tracking"));  // rsfm run's only
    // The process noise came from the data and adapted (summary.json process_noise).
    const auto& pn = cli.summary["process_noise"];
    EXPECT_TRUE(pn["from_data"].get<bool>() && pn["adapted"].get<bool>()) << pn.dump();
    EXPECT_GT(pn["initial_omega_sd_deg"].get<double>(), 0.0);
    // It adapted: the sd used changed over the frames (fixed noise gives min == max).
    EXPECT_LT(pn["omega_sd_deg"]["min"].get<double>(), pn["omega_sd_deg"]["max"].get<double>()) << pn.dump();
    EXPECT_LE(sum, cli.summary["seconds"].get<double>());
    // A determined problem: the refinement converged before its iteration limit.
    EXPECT_FALSE(lib.refined.at_iteration_limit);
    EXPECT_FALSE(cli.summary["refinement"]["at_iteration_limit"].get<bool>());
    // The filter's measurement noise: the --sigma-px floor or the measured tracking noise, if
    // larger; these tracks have 0.5 px per axis, the floor's value.
    const auto& mn = cli.summary["measurement_noise"];
    EXPECT_EQ(mn["sigma_px"].get<double>(), lib.filter_used.sigma_px) << mn.dump();
    EXPECT_NEAR(mn["sigma_px"].get<double>(), 0.5, 0.05) << mn.dump();
    EXPECT_EQ(mn["floor_px"].get<double>(), TrackFilterOptions{}.sigma_px);
    EXPECT_EQ(mn["from_tracking_noise"].get<bool>(), lib.filter_used.sigma_px > TrackFilterOptions{}.sigma_px);
    // Each plane's first frame (every plane of the reference frame: the reference frame) and each
    // candidate's search frames (summary.json plane_finding).
    const auto& pf = cli.summary["plane_finding"];
    ASSERT_EQ(pf["planes_estimated_from_frame"].size(), static_cast<size_t>(lib.online.planes));
    const int reference = cli.summary["still_start"]["reference_frame"].get<int>();
    for (const auto& k : pf["planes_estimated_from_frame"]) EXPECT_EQ(k.get<int>(), reference);
    for (const auto& c : pf["candidates"]) {
      EXPECT_EQ(c["reference_frame"].get<int>(), reference) << c.dump();
      EXPECT_EQ(c["pair_frame"].get<int>(), pf["pair_frame"].get<int>()) << c.dump();
    }
  }
  {
    // Options that change the start-dependent defaults and the filter.
    EstimateOptions o;
    o.filter.normal_sd0 = 0.3;
    o.filter.beta_sd0 = 0.2;
    o.filter.passes = 3;
    o.filter.filter.iterations = 2;
    o.filter.filter.q_motion[3] = o.filter.filter.q_motion[4] = o.filter.filter.q_motion[5] = 4e-4;
    o.filter.q_from_data = false;  // what --q-omega means: fixed process noise
    o.finder.noise_px = 0.8;       // a given tracking noise: the filter's sd is raised to it
    o.refine.enabled = false;
    const EstimateResult lib = estimate(tracks, o);
    EXPECT_FALSE(lib.refined.ok);
    EXPECT_EQ(lib.filter_used.sigma_px, 0.8);
    const Cli cli = runCli(file, dir / "options",
                           "--normal-sd0 0.3 --beta-sd0 0.2 --passes 3 --iterations 2 --q-omega 4e-4 --tracking-noise-px 0.8 "
                           "--refine none");
    expectSame(lib, cli);
    EXPECT_EQ(cli.summary["measurement_noise"]["sigma_px"].get<double>(), 0.8);
    EXPECT_TRUE(cli.summary["measurement_noise"]["from_tracking_noise"].get<bool>());
    // --q-omega fixes the process noise: not from the data, not adapted, at the value given.
    EXPECT_FALSE(cli.summary["process_noise"]["adapted"].get<bool>());
    EXPECT_FALSE(cli.summary["process_noise"]["from_data"].get<bool>());
    EXPECT_EQ(cli.summary["process_noise"]["omega_sd_deg"]["min"], cli.summary["process_noise"]["omega_sd_deg"]["max"]);
    EXPECT_NEAR(cli.summary["process_noise"]["initial_omega_sd_deg"].get<double>(), std::sqrt(4e-4) * 180.0 / M_PI, 1e-9);
    // And they took effect: not the default run's numbers.
    EstimateOptions d;
    d.refine.enabled = false;
    const EstimateResult def = estimate(tracks, d);
    EXPECT_NE(def.online.frames.back().beta, lib.online.frames.back().beta);
    EXPECT_EQ(lib.filter_used.normal_sd0.value(), 0.3);
    EXPECT_EQ(def.filter_used.normal_sd0.value(), 0.1);  // after the homography start
  }
  {
    EstimateOptions o;
    o.filter.model = TrackModel::Plane;
    o.homography_start = false;
    const EstimateResult lib = estimate(tracks, o);
    EXPECT_FALSE(lib.start_tried);
    EXPECT_FALSE(lib.filter_used.normal_sd0.has_value());  // frontal start: the filter's 1.0
    expectSame(lib, runCli(file, dir / "plane", "--model plane --no-init"));
  }
  fs::remove_all(dir);
}

TEST(Pipeline, NoPlaneIsBadInput) {
  Tracks t;
  t.image = {320, 240, 159.5, 119.5};
  t.frames.resize(5);
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(10, 230);
  for (int k = 0; k < 5; ++k)
    for (int i = 0; i < 30; ++i) t.frames[k].push_back({i, Eigen::Vector2d(u(rng), u(rng))});  // noise, no plane
  EXPECT_THROW(estimate(t, EstimateOptions{}), NoPlaneFound);
}

}  // namespace
}  // namespace rsfm
