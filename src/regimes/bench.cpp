#include "rsfm/regimes/bench.hpp"
#include "rsfm/clock.hpp"
#include "../io/csv_fields.hpp"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <set>
#include <sstream>
#include <thread>

#include "rsfm/eval/trajectory_metrics.hpp"
#include "rsfm/report/evaluation.hpp"
#include "rsfm/io/input_error.hpp"
#include "rsfm/io/json_text.hpp"
#include "rsfm/io/summary.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "rsfm/render/regime_suite.hpp"
#include "rsfm/render/truth_check.hpp"

extern char** environ;

namespace rsfm::regimes {

namespace detail {
// Generated at configure time from bench/reference/colmap/NAME/{summary.json,trajectory.tum}.
struct EmbeddedFile {
  const char* reference;
  const char* file;
  const char* text;
};
extern const EmbeddedFile kColmapReferences[];
extern const int kColmapReferenceCount;
}  // namespace detail

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const char* kBoxGz = "/usr/share/doc/opencv-doc/opencv4/html/box.mp4.gz";
const char* kCubePattern = "/usr/share/visp-images-data/ViSP-images/cube/image.%04d.pgm";
constexpr int kBoxWindows = 10, kBoxWindowStep = 2, kBoxWindowFrames = 150;
// chi-square quantile of 2 dof at 0.95 (5.991): a 2-D normal error is inside the 95 % region when
// |e| <= sqrt(5.991 / 2) sd_total, sd_total = sqrt(trace) as reported in plane_normal_sd_deg.
constexpr double kNormal95 = 1.7308;
constexpr double kFocal95 = 1.96;


std::uint64_t fnv1a(const std::string& s) {
  std::uint64_t h = 1469598103934665603ULL;
  for (unsigned char c : s) {
    h ^= c;
    h *= 1099511628211ULL;
  }
  return h;
}

std::string readText(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Runs argv with stdout and stderr appended to `log`; returns the exit code (128 + signal when
/// killed) and the wall time.
int runProcess(const std::vector<std::string>& argv, const fs::path& log, double* seconds) {
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  posix_spawn_file_actions_adddup2(&fa, STDOUT_FILENO, STDERR_FILENO);
  posix_spawn_file_actions_addopen(&fa, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const double t0 = steadySeconds();
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, argv[0].c_str(), &fa, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  if (rc != 0) throw std::runtime_error(fmt::format("cannot start {}: {}", argv[0], std::strerror(rc)));
  int status = 0;
  while (waitpid(pid, &status, 0) < 0)
    if (errno != EINTR) throw std::runtime_error("waitpid failed");
  *seconds = steadySeconds() - t0;
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
  return 255;
}

/// The last "rsfm: error:" line of a log, else its "warning:" lines joined.
std::string messageOf(const fs::path& log) {
  std::ifstream in(log);
  std::string line, error, warnings;
  while (std::getline(in, line)) {
    if (line.rfind("rsfm: error: ", 0) == 0) error = line.substr(13);
    if (line.rfind("warning: ", 0) == 0) warnings += (warnings.empty() ? "" : "; ") + line.substr(9);
  }
  return error.empty() ? warnings : error;
}

fs::path defaultCache() {
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return fs::path(x) / "rsfm" / "regimes";
  if (const char* h = std::getenv("HOME"); h && *h) return fs::path(h) / ".cache" / "rsfm" / "regimes";
  return fs::temp_directory_path() / "rsfm-regimes-cache";
}

fs::path selfExe() {
  std::error_code ec;
  const fs::path p = fs::read_symlink("/proc/self/exe", ec);
  if (ec) throw std::runtime_error("cannot find this executable (/proc/self/exe): " + ec.message());
  return p;
}

std::optional<double> optNum(const json& j, const char* key) {
  if (j.contains(key) && j[key].is_number()) return j[key].get<double>();
  return std::nullopt;
}

/// One estimate (the main one, or summary.json's "online" section) against the truth.
struct ViewScore {
  std::optional<double> focal_err_pct;
  std::optional<bool> focal_in_95;
  std::optional<double> worst_normal_err_deg;
  int normals_in_95 = 0;
  int reported_undetermined = 0;  ///< determinable quantities the estimate marks not determined
};

ViewScore scoreView(const json& v, const io::Summary& truth, bool focal_determinable, bool structure_determinable,
                    const std::vector<Eigen::Vector3d>& est_planes, const std::vector<double>& est_distances, double scale) {
  ViewScore out;
  // Focal length: the reported 95 % interval is f +- 1.96 sd, or the interval given when not determined.
  const bool focal_marked = v.contains("focal_determined") && v["focal_determined"] == false;
  const std::optional<double> f = v.contains("focal_px") && v["focal_px"].is_number() ? optNum(v, "focal_px") : optNum(v, "focal_estimate_px");
  if (truth.focal_px && f) out.focal_err_pct = 100.0 * (*f - *truth.focal_px) / *truth.focal_px;
  if (truth.focal_px && focal_determinable) {
    if (focal_marked) {
      ++out.reported_undetermined;
      if (v.contains("focal_interval_px"))
        out.focal_in_95 = *truth.focal_px >= io::focalIntervalBound(v["focal_interval_px"], 0) &&
                          *truth.focal_px <= io::focalIntervalBound(v["focal_interval_px"], 1);
    } else if (f && v.contains("focal_sd_px") && v["focal_sd_px"].is_number()) {
      out.focal_in_95 = std::abs(*f - *truth.focal_px) <= kFocal95 * v["focal_sd_px"].get<double>();
    }
  }
  // Normals: a plane reported not determined covers any direction.
  const eval::PlaneMatch pm = eval::matchPlanes(truth.planes, truth.plane_distances, est_planes, est_distances, scale);
  std::vector<double> sd;
  if (v.contains("plane_normal_sd_deg"))
    for (const auto& x : v["plane_normal_sd_deg"]) sd.push_back(x.is_number() ? x.get<double>() : -1);
  for (std::size_t i = 0; i < truth.planes.size(); ++i) {
    const int e = pm.estimate_of_truth[i];
    if (e < 0) continue;
    const double err = pm.angle_deg[i];
    out.worst_normal_err_deg = std::max(out.worst_normal_err_deg.value_or(0.0), err);
    const bool marked = v.contains("plane_determined") && e < static_cast<int>(v["plane_determined"].size()) &&
                        v["plane_determined"][e] == false;
    if (marked && structure_determinable) ++out.reported_undetermined;
    if (marked || (e < static_cast<int>(sd.size()) && sd[e] >= 0 && err <= kNormal95 * sd[e])) ++out.normals_in_95;
  }
  return out;
}

/// summary.json `s`'s entry of angles_between_planes_deg for planes (a, b), a < b (null: none).
const json* angleEntry(const json& s, int a, int b) {
  if (!s.contains("angles_between_planes_deg")) return nullptr;
  for (const auto& e : s["angles_between_planes_deg"])
    if (e["planes"][0].get<int>() == a && e["planes"][1].get<int>() == b) return &e;
  return nullptr;
}

/// Row's face-angle coverage (Row::face_angle_pairs, face_angles_in_95): the angle entry `e`'s
/// reported 95 % interval against the true angle `truth_deg`; an entry without an interval (not
/// determined) is not counted.
void countAngleInterval(Row& row, const json& e, double truth_deg) {
  if (!(e.contains("interval_deg") && e["interval_deg"].is_array())) return;
  ++row.face_angle_pairs;
  row.face_angles_in_95 += e["interval_deg"][0].get<double>() <= truth_deg && truth_deg <= e["interval_deg"][1].get<double>();
}

/// Fills the rsfm-estimate part of a row from DIR/summary.json and, with a truth directory, the
/// evaluation against it.
void scoreEstimate(Row& row, const fs::path& est_dir, const fs::path* truth_dir) {
  const fs::path sp = est_dir / "summary.json";
  json s;
  try {
    s = json::parse(readText(sp));
  } catch (const std::exception& e) {
    row.message += (row.message.empty() ? "" : "; ") + std::string("summary.json unreadable: ") + e.what();
    return;
  }
  row.focal_est = s.contains("focal_px") && s["focal_px"].is_number() ? optNum(s, "focal_px") : optNum(s, "focal_estimate_px");
  row.focal_sd = optNum(s, "focal_sd_px");
  // Reported not determined, on every row (box.mp4's windows have no truth).
  row.focal_marked = s.contains("focal_determined") && s["focal_determined"] == false;
  if (s.contains("focal_interval_px") && s["focal_interval_px"].is_array() && s["focal_interval_px"].size() == 2) {
    const json& iv = s["focal_interval_px"];
    row.focal_interval_lo = iv[0].is_number() ? std::optional<double>(iv[0].get<double>()) : std::nullopt;
    row.focal_interval_hi = iv[1].is_number() ? std::optional<double>(iv[1].get<double>()) : std::nullopt;
  }
  if (s.contains("radial_distortion") && s["radial_distortion"].is_array()) row.k1_est = s["radial_distortion"][0].get<double>();
  if (s.contains("camera") && s["camera"].is_object()) {
    row.readout_est = optNum(s["camera"], "readout");
    row.readout_sd = optNum(s["camera"], "readout_sd");
  }
  if (s.contains("planes") && s["planes"].is_array()) row.planes_found = static_cast<int>(s["planes"].size());
  {
    std::ifstream in(est_dir / "trajectory.tum");
    std::string line;
    while (std::getline(in, line))
      if (!line.empty() && line[0] != '#') ++row.frames_processed;
  }
  // The angle between the two planes with the most tracks (real rows; also shown for rendered).
  if (row.planes_found >= 2 && s.contains("plane_tracks") && s.contains("angles_between_planes_deg")) {
    std::vector<std::pair<int, int>> order;
    for (int i = 0; i < row.planes_found; ++i) order.emplace_back(-s["plane_tracks"][i].get<int>(), i);
    std::sort(order.begin(), order.end());
    const int a = std::min(order[0].second, order[1].second), b = std::max(order[0].second, order[1].second);
    const json* e = angleEntry(s, a, b);
    if (e && !(e->contains("determined") && !(*e)["determined"].get<bool>())) {
      row.face_angle_deg = (*e)["angle_deg"].get<double>();
      if (e->contains("sd_deg") && (*e)["sd_deg"].is_number()) row.face_angle_sd_deg = (*e)["sd_deg"].get<double>();
      if (row.sequence.rfind("box.mp4@", 0) == 0) countAngleInterval(row, *e, 90.0);  // two faces of a box
    }
  }
  if (!truth_dir) return;
  io::Summary truth, est;
  try {
    truth = io::readSummary(*truth_dir / "summary.json");
    est = io::readSummary(sp);
  } catch (const std::exception& e) {
    row.message += (row.message.empty() ? "" : "; ") + std::string(e.what());
    return;
  }
  row.focal_true = truth.focal_px;
  row.planes_true = static_cast<int>(truth.planes.size());
  if (truth.determinable) {
    row.focal_determinable = truth.determinable->focal;
    row.structure_determinable = truth.determinable->structure;
  }
  // Planes: the evaluator's matching (distances break ties between parallel planes), with the
  // Sim(3) scale when the trajectories align.
  double scale = 1;
  try {
    const report::Evaluation ev = report::evaluateDirectories(est_dir, *truth_dir, {});
    scale = ev.ate.alignment.T.s;
    row.ate_pct = 100.0 * ev.ate.stats.rmse / ev.scale_ref;
    if (ev.rpe.pairs > 0) {
      row.rpe_trans_pct = 100.0 * ev.rpe.translation.rmse / ev.scale_ref;
      row.rpe_rot_deg = ev.rpe.rotation_deg.rmse;
    }
  } catch (const std::exception& e) {
    row.message += (row.message.empty() ? "" : "; ") + std::string("evaluate: ") + e.what();
  }
  {
    const ViewScore v = scoreView(s, truth, row.focal_determinable, row.structure_determinable, est.planes,
                                  est.plane_distances, scale);
    row.focal_err_pct = v.focal_err_pct;
    row.focal_in_95 = v.focal_in_95;
    row.worst_normal_err_deg = v.worst_normal_err_deg;
    row.normals_in_95 = v.normals_in_95;
    row.reported_undetermined = v.reported_undetermined;
  }
  if (s.contains("online") && s["online"].is_object()) {
    // The recursive filter's own estimate (kept beside the refinement's).
    const json& o = s["online"];
    std::vector<Eigen::Vector3d> planes;
    std::vector<double> dist;
    for (const auto& n : o["planes"]) planes.emplace_back(n[0].get<double>(), n[1].get<double>(), n[2].get<double>());
    for (const auto& d : o["plane_distances"]) dist.push_back(d.get<double>());
    const ViewScore reported = scoreView(o, truth, row.focal_determinable, row.structure_determinable, planes, dist, scale);
    row.online_reported_focal_in_95 = reported.focal_in_95;
    row.online_reported_normals_in_95 = reported.normals_in_95;
    // The filter alone: its own (calibrated) sds, nothing marked.
    json own = o;
    if (o.contains("filter_focal_sd_px")) {
      own["focal_sd_px"] = o["filter_focal_sd_px"];
      own["plane_normal_sd_deg"] = o["filter_plane_normal_sd_deg"];
      for (const char* k : {"focal_determined", "plane_determined", "focal_interval_px"}) own.erase(k);
    }
    const ViewScore v = scoreView(own, truth, row.focal_determinable, row.structure_determinable, planes, dist, scale);
    row.online_focal_err_pct = v.focal_err_pct;
    row.online_focal_in_95 = v.focal_in_95;
    row.online_worst_normal_err_deg = v.worst_normal_err_deg;
    row.online_normals_in_95 = v.normals_in_95;
  } else {
    row.online_focal_err_pct = row.focal_err_pct;
    row.online_focal_in_95 = row.focal_in_95;
    row.online_worst_normal_err_deg = row.worst_normal_err_deg;
    row.online_normals_in_95 = row.normals_in_95;
    row.online_reported_focal_in_95 = row.focal_in_95;
    row.online_reported_normals_in_95 = row.normals_in_95;
  }
  const eval::PlaneMatch pm = eval::matchPlanes(truth.planes, truth.plane_distances, est.planes, est.plane_distances, scale);
  std::vector<int> matched;
  for (std::size_t i = 0; i < truth.planes.size(); ++i)
    if (pm.estimate_of_truth[i] >= 0) {
      matched.push_back(static_cast<int>(i));
      ++row.planes_matched;
    }
  for (std::size_t x = 0; x < matched.size(); ++x)
    for (std::size_t y = x + 1; y < matched.size(); ++y) {
      const int i = matched[x], j = matched[y];
      const double at = eval::angleDeg(truth.planes[i], truth.planes[j]);
      const double ae = eval::angleDeg(est.planes[pm.estimate_of_truth[i]], est.planes[pm.estimate_of_truth[j]]);
      row.face_angle_err_deg = std::max(row.face_angle_err_deg.value_or(0.0), std::abs(ae - at));
      // The reported 95 % interval of that angle (between lines, 0-90 deg) against the truth's.
      const int p = std::min(pm.estimate_of_truth[i], pm.estimate_of_truth[j]), q = std::max(pm.estimate_of_truth[i], pm.estimate_of_truth[j]);
      if (const json* e = angleEntry(s, p, q)) countAngleInterval(row, *e, std::min(at, 180.0 - at));
    }
  // Undeterminable quantities: explicitly marked as not determined, or given as numbers.
  if (row.focal_determinable && row.structure_determinable) {
    row.undetermined = "-";
  } else {
    bool marked = true;
    if (!row.focal_determinable)
      marked &= !row.focal_est || (s.contains("focal_determined") && s["focal_determined"] == false);
    if (!row.structure_determinable)
      marked &= est.planes.empty() || (s.contains("structure_determined") && s["structure_determined"] == false);
    row.undetermined = marked ? "marked" : "confident";
  }
}

struct Task {
  std::string name;
  std::function<void()> run;
};

}  // namespace

void checkBenchOptions(const BenchOptions& o) {
  const render::RegimeSuite suite = o.suite.empty() ? render::builtinRegimeSuite() : render::readRegimeSuite(o.suite);
  for (const std::string& n : o.only)
    if (!suite.find(n) && n != "box-mp4" && n != "cube")
      throw io::InputError(fmt::format("--only: unknown sequence '{}' (one of the suite's, box-mp4 or cube)", n));
  if (o.jobs < 0 || o.jobs > 64) throw io::InputError("--jobs must be in [0, 64]");
  if (!o.rsfm.empty() && ::access(o.rsfm.c_str(), X_OK) != 0)
    throw io::InputError("--rsfm " + o.rsfm + ": not an executable file");
  if (!o.reference_dir.empty() && !std::filesystem::is_directory(o.reference_dir))
    throw io::InputError("--reference " + o.reference_dir + ": no such directory");
}

BenchResult runBench(const BenchOptions& opt, const std::function<void(const std::string&)>& progress) {
  checkBenchOptions(opt);
  const double t_start = steadySeconds();
  BenchResult result;
  std::mutex mu;
  auto say = [&](const std::string& m) {
    std::lock_guard<std::mutex> l(mu);
    if (progress) progress(m);
  };
  const render::RegimeSuite suite =
      opt.suite.empty() ? render::builtinRegimeSuite() : render::readRegimeSuite(opt.suite);
  std::set<std::string> only(opt.only.begin(), opt.only.end());
  auto selected = [&](const std::string& n) { return only.empty() || only.count(n); };
  const fs::path cache = opt.cache.empty() ? defaultCache() : opt.cache;
  const fs::path runs = opt.out / "runs", logs = opt.out / "logs";
  std::error_code ec;
  for (const fs::path& d : {cache, runs, logs}) {
    fs::create_directories(d, ec);
    if (ec) throw std::runtime_error("cannot create " + d.string() + ": " + ec.message());
  }
  const std::string rsfm = opt.rsfm.empty() ? selfExe().string() : opt.rsfm;
  // COLMAP references: written out from the binary unless a directory was given.
  fs::path refdir = opt.reference_dir;
  if (refdir.empty()) {
    refdir = opt.out / "reference" / "colmap";
    for (int i = 0; i < detail::kColmapReferenceCount; ++i) {
      const auto& f = detail::kColmapReferences[i];
      fs::create_directories(refdir / f.reference, ec);
      std::ofstream(refdir / f.reference / f.file, std::ios::binary) << f.text;
    }
  }

  std::vector<Row> rows;
  std::vector<Task> tasks;
  std::map<std::string, fs::path> truth_of;  // regime -> cached truth dir (for the COLMAP rows)
  const int total_rendered = static_cast<int>(std::count_if(suite.sequences.begin(), suite.sequences.end(),
                                                            [&](const render::Regime& r) { return selected(r.name); }));
  std::atomic<int> done{0};
  auto runRsfm = [&](Row& row, const std::vector<std::string>& input_args, const std::string& name) {
    const fs::path out = runs / name, log = logs / (name + ".log");
    fs::remove_all(out, ec);
    fs::remove(log, ec);
    std::vector<std::string> argv{rsfm, "run"};
    argv.insert(argv.end(), input_args.begin(), input_args.end());
    argv.insert(argv.end(), {"--out", out.string(), "--no-overlay", "--no-plots"});
    argv.insert(argv.end(), opt.run_args.begin(), opt.run_args.end());
    row.exit_code = runProcess(argv, log, &row.seconds);
    row.message = messageOf(log);
    return out;
  };
  for (const render::Regime& reg : suite.sequences) {
    if (!selected(reg.name)) continue;
    const std::string key =
        fmt::format("{:016x}", fnv1a(reg.options_json + fmt::format("|renderer {}", render::kRendererVersion)));
    const fs::path dir = cache / (reg.name + "-" + key);
    truth_of[reg.name] = dir / "truth";
    rows.push_back({});
    const std::size_t idx = rows.size() - 1;
    tasks.push_back({reg.name, [&, reg, dir, idx] {
      Row& row = rows[idx];
      row.sequence = reg.name;
      row.kind = "rendered";
      for (const auto& a : reg.axes) row.axes += (row.axes.empty() ? "" : ";") + a;
      row.frames = reg.options.frames;
      std::error_code e2;
      std::string rendered = "cached";
      if (!fs::exists(dir / "truth" / "render.json", e2)) {
        const fs::path tmp = cache / fmt::format(".tmp-{}-{}", reg.name, ::getpid());
        fs::remove_all(tmp, e2);
        fs::create_directories(tmp, e2);
        json extra = {{"regime", reg.name}, {"why", reg.why}, {"axes", reg.axes}, {"suite", suite.source}};
        const double t0 = steadySeconds();
        render::writeSequence(reg.options, tmp, {}, {}, extra.dump());
        fs::remove_all(dir, e2);
        fs::rename(tmp, dir);
        rendered = fmt::format("rendered in {:.1f} s", steadySeconds() - t0);
      }
      const fs::path video = fs::exists(dir / "video.mp4") ? dir / "video.mp4" : dir / "video.avi";
      // The truth against tracked corners of the decoded video (render/truth_check.hpp).
      render::Scene scene(reg.options);
      {
        const int a0 = reg.options.still_start, last = reg.options.frames - 1, mid = reg.options.frames / 2;
        const std::vector<std::pair<int, int>> pairs{{a0, std::min(a0 + 1, last)}, {mid, std::min(mid + 1, last)}};
        std::map<int, cv::Mat> grey;
        for (const auto& [a, b] : pairs) grey[a], grey[b];
        cv::VideoCapture cap(video.string());
        cv::Mat f;
        for (int k = 0; k <= grey.rbegin()->first && cap.read(f); ++k)
          if (grey.count(k)) cv::cvtColor(f, grey[k], cv::COLOR_BGR2GRAY);
        std::vector<double> med;
        for (const auto& [a, b] : pairs) {
          if (grey[a].empty() || grey[b].empty()) continue;
          const render::TruthCheck c = render::trackAgainstTruth(scene, grey[a], grey[b], a, b);
          if (c.tracks > 0) med.push_back(c.median_px);
        }
        if (!med.empty()) row.truth_check_px = *std::max_element(med.begin(), med.end());
      }
      const fs::path out = runRsfm(row, {video.string()}, reg.name);
      const fs::path truth = dir / "truth";
      row.k1_true = reg.options.k1;  // the render's own (cached truths from before it was written lack it)
      row.readout_true = reg.options.readout;
      // rsfm's own tracks against the truth, over their whole lives.
      if (std::error_code e3; row.exit_code == 0 && fs::exists(out / "tracks.csv", e3)) {
        try {
          const render::TracksTruthError te = render::tracksAgainstTruth(scene, io::readTracks(out / "tracks.csv"));
          if (te.observations > 0) {
            row.track_err_median_px = te.median_px;
            row.track_err_p95_px = te.p95_px;
            row.track_err_radial_px = te.radial_mean_px;
            row.track_err_radial_median_px = te.radial_median_px;
            row.track_err_by_age = te.by_age;
          }
        } catch (const std::exception& e) {  // a row note, like the other scoring steps' failures
          row.message += (row.message.empty() ? "" : "; ") + std::string("tracks against the truth: ") + e.what();
        }
      }
      if (row.exit_code == 0) {
        scoreEstimate(row, out, &truth);
      } else {
        try {
          const io::Summary t = io::readSummary(truth / "summary.json");
          row.focal_true = t.focal_px;
          row.planes_true = static_cast<int>(t.planes.size());
          if (t.determinable) {
            row.focal_determinable = t.determinable->focal;
            row.structure_determinable = t.determinable->structure;
          }
        } catch (const std::exception&) {
        }
        row.undetermined = row.focal_determinable && row.structure_determinable ? "-" : "no output";
      }
      say(fmt::format("regimes: [{}/{}] {}: {}; run exit {} in {:.1f} s{}{}", ++done, total_rendered, reg.name, rendered,
                      row.exit_code, row.seconds,
                      row.focal_err_pct ? fmt::format(", focal {:+.1f} %{}", *row.focal_err_pct, row.focal_marked ? " (reported not determined)" : "") : "",
                      row.exit_code ? ": " + row.message : ""));
    }});
  }
  // Real rows: box.mp4 windows, the ViSP cube against COLMAP.
  const bool want_box = opt.real && selected("box-mp4"), want_cube = opt.real && selected("cube");
  fs::path box_mp4;
  if (want_box) {
    if (!fs::exists(kBoxGz)) {
      result.notes.push_back(fmt::format("box.mp4 rows skipped: {} not installed (apt-get install opencv-doc)", kBoxGz));
    } else {
      box_mp4 = cache / "real" / "box.mp4";
      if (!fs::exists(box_mp4)) {
        fs::create_directories(box_mp4.parent_path(), ec);
        double s = 0;
        const fs::path tmp = box_mp4.string() + ".tmp";
        const int rc = runProcess({"/bin/sh", "-c", fmt::format("gzip -dc '{}' > '{}'", kBoxGz, tmp.string())},
                                  logs / "box-mp4-gunzip.log", &s);
        if (rc != 0) throw std::runtime_error("cannot decompress " + std::string(kBoxGz));
        fs::rename(tmp, box_mp4);
      }
      for (int w = 0; w < kBoxWindows; ++w) {
        const int first = w * kBoxWindowStep, last = first + kBoxWindowFrames - 1;
        rows.push_back({});
        const std::size_t idx = rows.size() - 1;
        tasks.push_back({"box", [&, first, last, idx] {
          Row& row = rows[idx];
          row.sequence = fmt::format("box.mp4@{}", first);
          row.kind = "real";
          row.axes = "real:box.mp4";
          row.frames = kBoxWindowFrames;
          const fs::path out = runRsfm(row, {box_mp4.string(), "--first", std::to_string(first), "--last", std::to_string(last)},
                                       fmt::format("box-mp4-{:02d}", first));
          if (row.exit_code == 0) scoreEstimate(row, out, nullptr);
          say(fmt::format("regimes: box.mp4 frames {}-{}: exit {} in {:.1f} s{}", first, last, row.exit_code, row.seconds,
                          row.face_angle_deg ? fmt::format(", face angle {:.1f} deg", *row.face_angle_deg) : ""));
        }});
      }
    }
  }
  if (want_cube) {
    const fs::path ref = refdir / "cube";
    if (!fs::exists(fs::path(kCubePattern).parent_path())) {
      result.notes.push_back("ViSP cube row skipped: visp-images-data not installed");
    } else if (!fs::exists(ref / "summary.json")) {
      result.notes.push_back("ViSP cube row skipped: no COLMAP reference " + ref.string());
    } else {
      rows.push_back({});
      const std::size_t idx = rows.size() - 1;
      tasks.push_back({"cube", [&, ref, idx] {
        Row& row = rows[idx];
        row.sequence = "visp-cube";
        row.kind = "real";
        row.axes = "real:visp-cube;reference:colmap";
        row.frames = 80;
        const fs::path out = runRsfm(row, {kCubePattern}, "visp-cube");
        if (row.exit_code == 0) scoreEstimate(row, out, &ref);
        try {
          if (const io::Summary rs = io::readSummary(ref / "summary.json"); rs.distortion) row.k1_true = rs.distortion->x();
        } catch (const std::exception&) {
        }
        say(fmt::format("regimes: ViSP cube: exit {} in {:.1f} s{}", row.exit_code, row.seconds,
                        row.focal_err_pct ? fmt::format(", focal {:+.1f} % from COLMAP's", *row.focal_err_pct) : ""));
      }});
    }
  }

  // Run the tasks on `jobs` workers.
  const int jobs = opt.jobs > 0 ? opt.jobs : std::max(1u, std::thread::hardware_concurrency());
  std::atomic<std::size_t> next{0};
  std::vector<std::string> errors;
  auto worker = [&] {
    for (std::size_t i = next++; i < tasks.size(); i = next++) {
      try {
        tasks[i].run();
      } catch (const std::exception& e) {
        std::lock_guard<std::mutex> l(mu);
        errors.push_back(tasks[i].name + ": " + e.what());
      }
    }
  };
  std::vector<std::thread> pool;
  for (int j = 0; j < jobs; ++j) pool.emplace_back(worker);
  for (auto& t : pool) t.join();
  if (!errors.empty()) throw std::runtime_error("bench failed on " + errors.front());

  // COLMAP's own results against the truth of the rendered sequences it was run on.
  for (const auto& entry : fs::directory_iterator(refdir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name == "cube" || !truth_of.count(name)) continue;
    const fs::path truth = truth_of[name];
    if (!fs::exists(truth / "summary.json")) continue;
    Row row;
    row.sequence = "colmap:" + name;
    row.kind = "colmap";
    row.axes = "reference:colmap";
    try {
      const json r = json::parse(readText(entry.path() / "summary.json"));
      const io::Summary t = io::readSummary(truth / "summary.json");
      row.frames = t.frames;
      if (r["frames"].get<int>() != t.frames || r["image"]["width"].get<int>() != t.width)
        row.message = "stale: the reference's frames or image size differ from the rendered sequence's";
      if (r.contains("colmap")) {
        row.k1_est = optNum(r["colmap"], "k1");
        if (auto s = optNum(r["colmap"]["seconds"], "total")) row.seconds = *s;
      }
      scoreEstimate(row, entry.path(), &truth);
      row.k1_true = t.distortion ? t.distortion->x() : 0.0;
      row.undetermined = "";
    } catch (const std::exception& e) {
      row.message = e.what();
    }
    rows.push_back(row);
  }
  result.rows = std::move(rows);
  result.seconds = steadySeconds() - t_start;
  return result;
}

// ---------------------------------------------------------------------------------------------
namespace {

std::string fmtOpt(const std::optional<double>& v, const char* f = "{:.2f}") {
  return v ? fmt::format(fmt::runtime(f), *v) : std::string();
}
std::string fmtBool(const std::optional<bool>& v) { return v ? (*v ? "yes" : "no") : std::string(); }

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string csvField(std::string s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c == '\n' ? ' ' : c);
  return q + "\"";
}

/// Aggregates over the rendered rows.
struct Aggregate {
  int sequences = 0, to_end = 0;
  int cover_pairs = 0, covered = 0;   // (sequence, determinable quantity) pairs; truth inside the 95 % interval
  int focal_pairs = 0, focal_cov = 0, normal_pairs = 0, normal_cov = 0;
  int online_focal_cov = 0, online_normal_cov = 0, reported_undetermined = 0;
  int online_reported_focal_cov = 0, online_reported_normal_cov = 0;  // the online section's sds as reported
  int planes_true = 0, planes_found = 0;  // truth planes, and those matched by an estimated plane
  int face_pairs = 0, face_cov = 0;       // determined angles between matched planes; truth inside their 95 % interval
  std::vector<double> focal_err, normal_err, face_err, ate, online_focal_err, online_normal_err;
  int undet = 0, undet_marked = 0, undet_confident = 0, undet_none = 0;
  int readout_rows = 0, readout_in_95 = 0;  // rendered rows with an estimated readout; the render's inside 1.96 sds
};

Aggregate aggregate(const std::vector<Row>& rows) {
  Aggregate a;
  for (const Row& r : rows) {
    if (r.kind != "rendered") continue;
    ++a.sequences;
    if (r.exit_code == 0 && r.frames_processed == r.frames) ++a.to_end;
    if (r.focal_determinable && r.focal_true) {
      ++a.focal_pairs;
      a.focal_cov += r.focal_in_95.value_or(false);
      a.online_focal_cov += r.online_focal_in_95.value_or(false);
      a.online_reported_focal_cov += r.online_reported_focal_in_95.value_or(false);
      // The error of a focal length reported as a number; one reported not determined is counted
      // under reported_undetermined (its interval under coverage), not as an error.
      if (r.focal_err_pct && !r.focal_marked) a.focal_err.push_back(std::abs(*r.focal_err_pct));
      if (r.online_focal_err_pct) a.online_focal_err.push_back(std::abs(*r.online_focal_err_pct));
    }
    a.reported_undetermined += r.reported_undetermined;
    a.planes_true += r.planes_true;
    a.planes_found += r.planes_matched;
    if (r.structure_determinable) {
      a.normal_pairs += r.planes_matched;
      a.normal_cov += r.normals_in_95;
      a.online_normal_cov += r.online_normals_in_95;
      a.online_reported_normal_cov += r.online_reported_normals_in_95;
      if (r.worst_normal_err_deg) a.normal_err.push_back(*r.worst_normal_err_deg);
      if (r.online_worst_normal_err_deg) a.online_normal_err.push_back(*r.online_worst_normal_err_deg);
      if (r.face_angle_err_deg) a.face_err.push_back(*r.face_angle_err_deg);
      a.face_pairs += r.face_angle_pairs;
      a.face_cov += r.face_angles_in_95;
    }
    if (r.ate_pct && r.structure_determinable) a.ate.push_back(*r.ate_pct);
    if (r.readout_est && r.readout_sd) {
      ++a.readout_rows;
      a.readout_in_95 += std::abs(*r.readout_est - r.readout_true.value_or(0.0)) <= 1.96 * *r.readout_sd;
    }
    if (r.undetermined != "-" && !r.undetermined.empty()) {
      ++a.undet;
      a.undet_marked += r.undetermined == "marked";
      a.undet_confident += r.undetermined == "confident";
      a.undet_none += r.undetermined == "no output";
    }
  }
  a.cover_pairs = a.focal_pairs + a.normal_pairs;
  a.covered = a.focal_cov + a.normal_cov;
  return a;
}

const char* kCsvHeader =
    "sequence,kind,axes,frames,exit_code,message,frames_processed,seconds,fps,truth_check_px,focal_true_px,"
    "focal_est_px,focal_sd_px,focal_err_pct,focal_in_95,focal_determinable,focal_reported_undetermined,planes_true,planes_found,planes_matched,"
    "worst_normal_err_deg,normals_in_95,structure_determinable,face_angle_err_deg,face_angle_deg,face_angle_sd_deg,"
    "face_angles_in_95,face_angle_pairs,ate_pct,"
    "rpe_trans_pct,rpe_rot_deg,undetermined,reported_undetermined,online_focal_err_pct,online_focal_in_95,"
    "online_worst_normal_err_deg,online_normals_in_95,k1_true,k1_est,track_err_median_px,track_err_p95_px,track_err_radial_px,"
    "readout_est,readout_sd,readout_true";

}  // namespace

std::string scoreboardCsv(const BenchResult& res) {
  std::string s = std::string(kCsvHeader) + "\n";
  for (const Row& r : res.rows) {
    const std::string fps =
        r.seconds > 0 && r.kind != "colmap" && r.exit_code == 0 ? fmt::format("{:.1f}", r.frames / r.seconds) : std::string();
    s += fmt::format("{},{},{},{},{},{},{},{:.2f},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                     csvField(r.sequence), r.kind, csvField(r.axes), r.frames, r.exit_code, csvField(r.message),
                     r.frames_processed, r.seconds, fps, fmtOpt(r.truth_check_px, "{:.3f}"),
                     fmtOpt(r.focal_true, "{:.1f}"), fmtOpt(r.focal_est, "{:.1f}"), fmtOpt(r.focal_sd, "{:.2f}"),
                     fmtOpt(r.focal_err_pct, "{:.2f}"), fmtBool(r.focal_in_95), r.focal_determinable ? "yes" : "no",
                     r.focal_marked ? "yes" : "no", r.planes_true, r.planes_found, r.planes_matched, fmtOpt(r.worst_normal_err_deg, "{:.2f}"),
                     r.normals_in_95, r.structure_determinable ? "yes" : "no", fmtOpt(r.face_angle_err_deg, "{:.2f}"),
                     fmtOpt(r.face_angle_deg, "{:.2f}"), fmtOpt(r.face_angle_sd_deg, "{:.2f}"), r.face_angles_in_95,
                     r.face_angle_pairs, fmtOpt(r.ate_pct, "{:.2f}"), fmtOpt(r.rpe_trans_pct, "{:.3f}"),
                     fmtOpt(r.rpe_rot_deg, "{:.3f}"), r.undetermined, r.reported_undetermined,
                     fmtOpt(r.online_focal_err_pct, "{:.2f}"), fmtBool(r.online_focal_in_95),
                     fmtOpt(r.online_worst_normal_err_deg, "{:.2f}"), r.online_normals_in_95, fmtOpt(r.k1_true, "{:.4f}"),
                     fmtOpt(r.k1_est, "{:.4f}"), fmtOpt(r.track_err_median_px, "{:.3f}"), fmtOpt(r.track_err_p95_px, "{:.3f}"),
                     fmtOpt(r.track_err_radial_px, "{:+.4f}"), fmtOpt(r.readout_est, "{:.3f}"), fmtOpt(r.readout_sd, "{:.3f}"),
                     fmtOpt(r.readout_true, "{:.3f}"));
  }
  // Aggregate rows (docs/regimes.md): shares in the boolean columns, medians / worst in the error columns.
  const Aggregate a = aggregate(res.rows);
  auto share = [](int k, int n) { return n ? fmt::format("{:.3f}", static_cast<double>(k) / n) : std::string(); };
  auto med = [](const std::vector<double>& v) { return v.empty() ? std::string() : fmt::format("{:.2f}", median(v)); };
  auto worst = [](const std::vector<double>& v) {
    return v.empty() ? std::string() : fmt::format("{:.2f}", *std::max_element(v.begin(), v.end()));
  };
  // Each aggregate row is written by column name, in the header's order.
  const std::vector<std::string_view> columns = io::detail::split(kCsvHeader, ',');
  auto row = [&](const std::string& name, const std::string& message, const std::map<std::string_view, std::string>& values) {
    std::string line;
    for (std::size_t c = 0; c < columns.size(); ++c) {
      std::string v;
      if (columns[c] == "sequence") v = name;
      else if (columns[c] == "kind") v = "aggregate";
      else if (columns[c] == "axes") v = "rendered";
      else if (columns[c] == "frames") v = std::to_string(a.sequences);
      else if (columns[c] == "message") v = csvField(message);
      else if (auto it = values.find(columns[c]); it != values.end()) v = it->second;
      line += (c ? "," : "") + v;
    }
    s += line + "\n";
  };
  row("aggregate:share", fmt::format("run to the end {}/{}; truth in 95 % {}/{}", a.to_end, a.sequences, a.covered, a.cover_pairs),
      {{"frames_processed", share(a.to_end, a.sequences)},
       {"focal_in_95", share(a.focal_cov, a.focal_pairs)},
       {"normals_in_95", share(a.normal_cov, a.normal_pairs)},
       {"online_focal_in_95", share(a.online_focal_cov, a.focal_pairs)},
       {"online_normals_in_95", share(a.online_normal_cov, a.normal_pairs)},
       {"face_angles_in_95", share(a.face_cov, a.face_pairs)}});
  // The median and the worst rows: one statistic of the same error columns.
  auto errorRow = [&](const std::string& name, const std::string& message, const auto& stat) {
    row(name, message,
        {{"focal_err_pct", stat(a.focal_err)},
         {"worst_normal_err_deg", stat(a.normal_err)},
         {"face_angle_err_deg", stat(a.face_err)},
         {"ate_pct", stat(a.ate)},
         {"online_focal_err_pct", stat(a.online_focal_err)},
         {"online_worst_normal_err_deg", stat(a.online_normal_err)}});
  };
  errorRow("aggregate:median", "median of |error| over sequences", med);
  errorRow("aggregate:worst", "worst |error| over sequences", worst);
  return s;
}

std::string scoreboardMarkdown(const BenchResult& res, const std::string& invocation) {
  const Aggregate a = aggregate(res.rows);
  std::string s = "# Regime scoreboard\n\n";
  s += fmt::format("`{}` ({:.0f} s). Columns: docs/regimes.md.\n\n", invocation, res.seconds);
  for (const auto& n : res.notes) s += "- note: " + n + "\n";
  auto pct = [](int k, int n) { return n ? fmt::format("{}/{} ({:.0f} %)", k, n, 100.0 * k / n) : std::string("-"); };
  auto medw = [](const std::vector<double>& v, const char* unit) {
    return v.empty() ? std::string("-")
                     : fmt::format("median {:.2f}{}, worst {:.2f}{} (n = {})", median(v), unit,
                                   *std::max_element(v.begin(), v.end()), unit, v.size());
  };
  s += "## Aggregate (rendered sequences)\n\n| measure | value |\n|---|---|\n";
  s += fmt::format("| sequences run to the end | {} |\n", pct(a.to_end, a.sequences));
  s += fmt::format("| truth inside the reported 95 % interval, all (sequence, quantity) pairs | {} |\n", pct(a.covered, a.cover_pairs));
  s += fmt::format("| &nbsp; focal length | {} (filter alone: {}; online figures against the refinement: {}) |\n",
                   pct(a.focal_cov, a.focal_pairs), pct(a.online_focal_cov, a.focal_pairs),
                   pct(a.online_reported_focal_cov, a.focal_pairs));
  s += fmt::format("| &nbsp; plane normals | {} (filter alone: {}; online figures against the refinement: {}) |\n",
                   pct(a.normal_cov, a.normal_pairs), pct(a.online_normal_cov, a.normal_pairs),
                   pct(a.online_reported_normal_cov, a.normal_pairs));
  s += fmt::format("| &nbsp; angles between matched planes (determined; not in the total above) | {} |\n", pct(a.face_cov, a.face_pairs));
  s += fmt::format("| truth planes found (matched by an estimated plane) | {} |\n", pct(a.planes_found, a.planes_true));
  s += fmt::format("| determinable quantities reported not determined | {} |\n", a.reported_undetermined);
  s += fmt::format("| focal error, determinable sequences | {} |\n", medw(a.focal_err, " %"));
  s += fmt::format("| &nbsp; the filter alone | {} |\n", medw(a.online_focal_err, " %"));
  s += fmt::format("| worst normal error per sequence | {} |\n", medw(a.normal_err, " deg"));
  s += fmt::format("| &nbsp; the filter alone | {} |\n", medw(a.online_normal_err, " deg"));
  s += fmt::format("| face angle error | {} |\n", medw(a.face_err, " deg"));
  s += fmt::format("| ATE (% of scene size) | {} |\n", medw(a.ate, " %"));
  s += fmt::format("| rolling shutter readout estimated: the render's inside its 95 % interval | {} |\n",
                   pct(a.readout_in_95, a.readout_rows));
  s += fmt::format("| sequences with an undeterminable quantity: marked / no output / confident | {} / {} / {} of {} |\n\n",
                   a.undet_marked, a.undet_none, a.undet_confident, a.undet);
  s += "## Rendered sequences\n\n";
  s += "| sequence | exit | frames | fps | truth px | tracks vs truth px (median / p95 / radial) | focal err % (sd %) | in 95 | "
       "planes found/true | worst normal deg | normals in 95 | face angle err deg | ATE % | RPE deg | undetermined | message |\n";
  s += "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const Row& r : res.rows) {
    if (r.kind != "rendered") continue;
    const std::string fsd = r.focal_sd && r.focal_true ? fmt::format(" ({:.2f})", 100 * *r.focal_sd / *r.focal_true) : "";
    s += fmt::format("| {} | {} | {}/{} | {} | {} | {} | {}{}{} | {} | {}/{} | {} | {}/{} | {} | {} | {} | {} | {} |\n", r.sequence,
                     r.exit_code, r.frames_processed, r.frames,
                     r.seconds > 0 && r.exit_code == 0 ? fmt::format("{:.0f}", r.frames / r.seconds) : "",
                     fmtOpt(r.truth_check_px, "{:.2f}"),
                     r.track_err_median_px ? fmt::format("{:.3f} / {:.3f} / {:+.4f}", *r.track_err_median_px, *r.track_err_p95_px,
                                                         *r.track_err_radial_px)
                                           : std::string(),
                     fmtOpt(r.focal_err_pct, "{:+.2f}"), fsd,
                     r.focal_marked ? " (reported n.d.)" : (r.focal_determinable ? "" : " (n.d.)"), fmtBool(r.focal_in_95),
                     r.planes_found, r.planes_true, fmtOpt(r.worst_normal_err_deg, "{:.2f}"), r.normals_in_95,
                     r.planes_matched, fmtOpt(r.face_angle_err_deg, "{:.2f}"), fmtOpt(r.ate_pct, "{:.2f}"),
                     fmtOpt(r.rpe_rot_deg, "{:.3f}"), r.undetermined, r.message);
  }
  // Real rows.
  std::vector<const Row*> box;
  for (const Row& r : res.rows)
    if (r.sequence.rfind("box.mp4@", 0) == 0) box.push_back(&r);
  if (!box.empty()) {
    s += "\n## opencv-doc box.mp4: ten 150-frame windows, default options\n\n";
    s += "| window | exit | planes | face angle deg | face angle sd deg | focal px | focal sd px | message |\n"
         "|---|---|---|---|---|---|---|---|\n";
    std::vector<double> focal, angle;
    int two = 0, angle_pairs = 0, angle_in = 0;
    for (const Row* r : box) {
      s += fmt::format("| {} | {} | {} | {} | {} | {} | {} | {} |\n", r->sequence, r->exit_code, r->planes_found,
                       fmtOpt(r->face_angle_deg, "{:.1f}"), fmtOpt(r->face_angle_sd_deg, "{:.1f}"), fmtOpt(r->focal_est, "{:.1f}"),
                       fmtOpt(r->focal_sd, "{:.1f}"), r->message);
      angle_pairs += r->face_angle_pairs;
      angle_in += r->face_angles_in_95;
      if (r->focal_est) focal.push_back(*r->focal_est);
      if (r->face_angle_deg) angle.push_back(*r->face_angle_deg);
      two += r->planes_found >= 2;
    }
    if (!focal.empty()) {
      const double m = median(focal);
      const auto [lo, hi] = std::minmax_element(focal.begin(), focal.end());
      int consistent = 0;
      for (const Row* r : box)
        if (r->focal_sd ? r->focal_est && std::abs(*r->focal_est - m) <= kFocal95 * *r->focal_sd
                        : (r->focal_interval_lo || r->focal_interval_hi) && m >= r->focal_interval_lo.value_or(-INFINITY) &&
                              m <= r->focal_interval_hi.value_or(INFINITY))
          ++consistent;  // a window whose focal length is not determined: the interval it supports
      s += fmt::format("\nTwo faces found in {}/{} windows. Focal length: median {:.1f} px, spread (max - min) {:.1f} px = "
                       "{:.1f} % of the median; the median lies inside {}/{} windows' own 95 % intervals.",
                       two, box.size(), m, *hi - *lo, 100 * (*hi - *lo) / m, consistent, box.size());
    }
    if (!angle.empty()) {
      const auto [lo, hi] = std::minmax_element(angle.begin(), angle.end());
      double worst90 = 0;
      for (double x : angle) worst90 = std::max(worst90, std::abs(x - 90));
      s += fmt::format(" Face angle: {:.1f}-{:.1f} deg (spread {:.1f} deg, worst |angle - 90| {:.1f} deg); 90 deg inside {}/{} "
                       "windows' own 95 % intervals.\n",
                       *lo, *hi, *hi - *lo, worst90, angle_in, angle_pairs);
    } else {
      s += "\n";
    }
  }
  bool head = false;
  for (const Row& r : res.rows) {
    if (r.kind == "real" && r.sequence.rfind("box.mp4@", 0) == 0) continue;
    if (r.kind != "real" && r.kind != "colmap") continue;
    if (!head) {
      s += "\n## Against COLMAP (the ViSP cube: rsfm against COLMAP's reference; colmap:NAME: COLMAP against the "
           "rendered truth)\n\n";
      s += "| sequence | exit | frames | focal est px | focal ref px | focal err % | in 95 | k1 est | k1 ref | normal err deg | "
           "ATE % | RPE deg | seconds | message |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
      head = true;
    }
    s += fmt::format("| {} | {} | {}/{} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.0f} | {} |\n", r.sequence, r.exit_code,
                     r.frames_processed, r.frames, fmtOpt(r.focal_est, "{:.1f}"), fmtOpt(r.focal_true, "{:.1f}"),
                     fmtOpt(r.focal_err_pct, "{:+.2f}"), fmtBool(r.focal_in_95), fmtOpt(r.k1_est, "{:.3f}"),
                     fmtOpt(r.k1_true, "{:.3f}"), fmtOpt(r.worst_normal_err_deg, "{:.2f}"), fmtOpt(r.ate_pct, "{:.2f}"),
                     fmtOpt(r.rpe_rot_deg, "{:.3f}"), r.seconds, r.message);
  }
  return s;
}

std::string scoreboardJson(const BenchResult& res, const std::string& invocation) {
  nlohmann::ordered_json j;
  j["format"] = "rsfm-scoreboard";
  j["version"] = 1;
  j["command"] = invocation;
  j["seconds"] = res.seconds;
  j["notes"] = res.notes;
  const Aggregate a = aggregate(res.rows);
  auto ratio = [](int k, int n) { return n ? nlohmann::ordered_json(static_cast<double>(k) / n) : nlohmann::ordered_json(nullptr); };
  auto stat = [](const std::vector<double>& v) {
    if (v.empty()) return nlohmann::ordered_json(nullptr);
    return nlohmann::ordered_json{{"median", median(v)}, {"worst", *std::max_element(v.begin(), v.end())}, {"n", v.size()}};
  };
  j["aggregate"] = {{"sequences", a.sequences},
                    {"run_to_end", ratio(a.to_end, a.sequences)},
                    {"truth_in_95", ratio(a.covered, a.cover_pairs)},
                    {"focal_in_95", ratio(a.focal_cov, a.focal_pairs)},
                    {"normals_in_95", ratio(a.normal_cov, a.normal_pairs)},
                    {"online_focal_in_95", ratio(a.online_focal_cov, a.focal_pairs)},
                    {"online_normals_in_95", ratio(a.online_normal_cov, a.normal_pairs)},
                    {"online_reported_focal_in_95", ratio(a.online_reported_focal_cov, a.focal_pairs)},
                    {"online_reported_normals_in_95", ratio(a.online_reported_normal_cov, a.normal_pairs)},
                    {"face_angles_in_95", ratio(a.face_cov, a.face_pairs)},
                    {"online_focal_err_pct", stat(a.online_focal_err)},
                    {"online_worst_normal_err_deg", stat(a.online_normal_err)},
                    {"reported_undetermined", a.reported_undetermined},
                    {"planes_found", ratio(a.planes_found, a.planes_true)},
                    {"focal_err_pct", stat(a.focal_err)},
                    {"worst_normal_err_deg", stat(a.normal_err)},
                    {"face_angle_err_deg", stat(a.face_err)},
                    {"ate_pct", stat(a.ate)},
                    {"undeterminable", {{"sequences", a.undet}, {"marked", a.undet_marked}, {"no_output", a.undet_none},
                                        {"confident", a.undet_confident}}}};
  auto opt = [](const std::optional<double>& v) { return v ? nlohmann::ordered_json(*v) : nlohmann::ordered_json(nullptr); };
  auto byAge = [](const std::vector<render::TracksTruthError::AgeBucket>& v) {
    nlohmann::ordered_json a = nlohmann::ordered_json::array();
    for (const auto& b : v)
      a.push_back({{"first_age", b.first_age},
                   {"last_age", b.last_age >= 0 ? nlohmann::ordered_json(b.last_age) : nlohmann::ordered_json(nullptr)},
                   {"observations", b.observations},
                   {"median_px", b.median_px},
                   {"p95_px", b.p95_px},
                   {"radial_median_px", b.radial_median_px}});
    return a;
  };
  j["rows"] = nlohmann::ordered_json::array();
  for (const Row& r : res.rows)
    j["rows"].push_back({{"sequence", r.sequence},
                         {"kind", r.kind},
                         {"axes", r.axes},
                         {"frames", r.frames},
                         {"exit_code", r.exit_code},
                         {"message", r.message},
                         {"frames_processed", r.frames_processed},
                         {"seconds", r.seconds},
                         {"truth_check_px", opt(r.truth_check_px)},
                         {"focal_true_px", opt(r.focal_true)},
                         {"focal_est_px", opt(r.focal_est)},
                         {"focal_sd_px", opt(r.focal_sd)},
                         {"focal_err_pct", opt(r.focal_err_pct)},
                         {"focal_in_95", r.focal_in_95 ? nlohmann::ordered_json(*r.focal_in_95) : nlohmann::ordered_json(nullptr)},
                         {"focal_determinable", r.focal_determinable},
                         {"focal_reported_undetermined", r.focal_marked},
                         {"planes_true", r.planes_true},
                         {"planes_found", r.planes_found},
                         {"planes_matched", r.planes_matched},
                         {"worst_normal_err_deg", opt(r.worst_normal_err_deg)},
                         {"normals_in_95", r.normals_in_95},
                         {"structure_determinable", r.structure_determinable},
                         {"face_angle_err_deg", opt(r.face_angle_err_deg)},
                         {"face_angle_deg", opt(r.face_angle_deg)},
                         {"face_angle_sd_deg", opt(r.face_angle_sd_deg)},
                         {"face_angles_in_95", r.face_angles_in_95},
                         {"face_angle_pairs", r.face_angle_pairs},
                         {"ate_pct", opt(r.ate_pct)},
                         {"rpe_trans_pct", opt(r.rpe_trans_pct)},
                         {"rpe_rot_deg", opt(r.rpe_rot_deg)},
                         {"undetermined", r.undetermined},
                         {"reported_undetermined", r.reported_undetermined},
                         {"online_focal_err_pct", opt(r.online_focal_err_pct)},
                         {"online_focal_in_95", r.online_focal_in_95 ? nlohmann::ordered_json(*r.online_focal_in_95) : nlohmann::ordered_json(nullptr)},
                         {"online_worst_normal_err_deg", opt(r.online_worst_normal_err_deg)},
                         {"online_normals_in_95", r.online_normals_in_95},
                         {"k1_true", opt(r.k1_true)},
                         {"k1_est", opt(r.k1_est)},
                         {"track_err_median_px", opt(r.track_err_median_px)},
                         {"track_err_p95_px", opt(r.track_err_p95_px)},
                         {"track_err_radial_px", opt(r.track_err_radial_px)},
                         {"readout_est", opt(r.readout_est)},
                         {"readout_sd", opt(r.readout_sd)},
                         {"readout_true", opt(r.readout_true)},
                         {"track_err_radial_median_px", opt(r.track_err_radial_median_px)},
                         {"track_err_by_age", byAge(r.track_err_by_age)}});
  return j.dump(2) + "\n";
}

}  // namespace rsfm::regimes
