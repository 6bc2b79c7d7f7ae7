// The Python module `rsfm` (issue 16; python/README.md): thin bindings over the library's entry
// points (pipeline/estimate.hpp, vision/klt_tracker.hpp) and the plane filter
// (filters/recursive_filter.hpp + models/plane_model.hpp).
//
// The options of estimate() and run() are the command line's: keyword arguments are turned into
// the CLI's arguments (focal_px=612 -> --focal-px 612) and parsed by the CLI's own code
// (apps/cmd_estimate.cpp addEstimateOptions/finishEstimateOptions, apps/cmd_track.cpp), so an
// option exists in one place, with one default and one error message. The summary returned is
// built by the code that writes `rsfm estimate`'s summary.json (apps/estimate_cli.hpp
// EstimateRunReport), so both give the same numbers (python/tests/test_rsfm.py).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <fmt/format.h>

#include <algorithm>
#include <numeric>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "cli_common.hpp"
#include "estimate_cli.hpp"
#include "rsfm/filters/recursive_filter.hpp"
#include "rsfm/io/input_error.hpp"
#include "rsfm/io/patches_io.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/report/estimate_report.hpp"
#include "rsfm/report/patch_report.hpp"
#include "rsfm/vision/patch_tracker.hpp"
#include "rsfm/version.hpp"
#include "rsfm/vision/klt_tracker.hpp"
#include "track_options.hpp"

namespace py = pybind11;
using namespace rsfm;

namespace {

/// Bad input (a file, an option): rsfm.InputError, a ValueError.
PyObject* g_input_error = nullptr;

[[noreturn]] void inputError(const std::string& m) { throw io::InputError(m); }

/// Keyword arguments -> the CLI's arguments: name -> --name-with-dashes; True -> the flag,
/// False -> nothing (a flag's default is off: `no_plots=True` is --no-plots); a sequence ->
/// comma-joined ("X,Y"); anything else -> str(value) (floats round-trip).
std::vector<std::string> cliArguments(const py::kwargs& kw, CLI::App* app, const std::vector<std::string>& refused) {
  std::vector<std::string> args;
  for (const auto& [k, v] : kw) {
    const std::string key = py::str(k);
    std::string name = "--" + key;
    std::replace(name.begin(), name.end(), '_', '-');
    if (std::find(refused.begin(), refused.end(), name) != refused.end())
      inputError(fmt::format("'{}' is not an option here: the Python module writes no files", key));
    const CLI::Option* opt = app->get_option_no_throw(name);
    if (!opt) inputError(fmt::format("unknown option '{}' (rsfm.options() lists them)", key));
    // Python's bool and numpy's bool_ are flags.
    const std::string type = py::str(py::type::of(v).attr("__name__"));
    if (py::isinstance<py::bool_>(v) || type == "bool_") {
      if (py::reinterpret_borrow<py::object>(v).attr("__bool__")().cast<bool>()) {
        if (opt->get_expected_min() > 0) inputError(fmt::format("option '{}' takes a value, not True", key));
        args.push_back(name);
      }
      continue;
    }
    if (opt->get_expected_min() == 0) inputError(fmt::format("option '{}' is a flag: give True or False", key));
    // str() of a Python or numpy number is its shortest round-trip text (repr of numpy 2's
    // scalars is not: "np.float64(612.0)").
    auto scalar = [&](const py::handle& x) -> std::string {
      if (py::isinstance<py::float_>(x) || py::str(py::type::of(x).attr("__name__")).cast<std::string>().rfind("float", 0) == 0)
        return py::str(py::float_(py::reinterpret_borrow<py::object>(x)));
      if (py::isinstance<py::sequence>(x) && !py::isinstance<py::str>(x))
        inputError(fmt::format("option '{}': a sequence of numbers or words, not of sequences", key));
      return py::str(x);
    };
    std::string value;
    if (py::isinstance<py::str>(v)) {
      value = v.cast<std::string>();
    } else if (py::isinstance<py::sequence>(v) || py::hasattr(v, "tolist")) {
      const py::object list = py::hasattr(v, "tolist") ? v.attr("tolist")() : py::reinterpret_borrow<py::object>(v);
      if (!py::isinstance<py::sequence>(list) || py::isinstance<py::str>(list)) {
        value = scalar(list);
      } else {
        for (const auto& item : list.cast<py::sequence>()) value += (value.empty() ? "" : ",") + scalar(item);
      }
    } else {
      value = scalar(v);
    }
    args.push_back(name);
    args.push_back(value);
  }
  return args;
}

void parseInto(CLI::App* app, const std::string& command, std::vector<std::string> args) {
  std::reverse(args.begin(), args.end());  // CLI11 takes them last first
  try {
    app->parse(args);
  } catch (const CLI::ParseError& e) {
    inputError(std::string(e.what()));
  }
  (void)command;
}

/// The estimate options from keyword arguments, through the CLI's parser and checks.
cli::EstimateCli estimateOptions(const py::kwargs& kw, CLI::App* app) {
  cli::EstimateCli e;
  cli::addEstimateOptions(app, &e);
  parseInto(app, "estimate", cliArguments(kw, app, {"--out", "--no-plots"}));
  if (auto m = cli::finishEstimateOptions(&e); !m.empty()) inputError(m);
  return e;
}

/// The array's header (read_tracks' second value gives it back): image size, principal point,
/// frame rate, time origin and the frame numbers the source dropped (docs/tracks.md).
struct ArrayHeader {
  std::optional<std::vector<int>> image_size;
  std::optional<std::vector<double>> principal_point;
  std::optional<double> fps, time_origin;
  std::optional<std::vector<int>> dropped_frames;
  bool any() const { return image_size || principal_point || fps || time_origin || dropped_frames; }
};

/// (M, 4) rows frame, track, x, y -> Tracks, through the tracks.csv reader (docs/tracks.md), so
/// an array is checked as a file is (one id per frame, ranges, ...).
Tracks tracksFromArray(const Eigen::MatrixXd& a, const ArrayHeader& head) {
  const std::vector<int>& image_size = *head.image_size;
  const auto& principal_point = head.principal_point;
  const auto& fps = head.fps;
  if (a.cols() != 4) inputError(fmt::format("tracks array: {} columns, expected 4 (frame, track, x, y)", a.cols()));
  if (a.rows() == 0) inputError("tracks array: no rows");
  if (image_size.size() != 2) inputError("image_size must be (width, height)");
  std::vector<Eigen::Index> order(a.rows());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](Eigen::Index i, Eigen::Index j) { return a(i, 0) < a(j, 0); });
  if (principal_point && principal_point->size() != 2) inputError("image_principal_point must be (x, y)");
  const double w = image_size[0], h = image_size[1];
  const double cx = principal_point ? (*principal_point)[0] : (w - 1) / 2, cy = principal_point ? (*principal_point)[1] : (h - 1) / 2;
  std::string csv = fmt::format("# rsfm-tracks 1\n# image_size {} {}\n# principal_point {:.17g} {:.17g}\n{}{}# frames {:.17g} {:.17g}\n"
                                "# source numpy array\n",
                                image_size[0], image_size[1], cx, cy, fps ? fmt::format("# fps {:.17g}\n", *fps) : "",
                                head.time_origin ? fmt::format("# time_origin {:.17g}\n", *head.time_origin) : "",
                                a(order.front(), 0), a(order.back(), 0));
  if (head.dropped_frames) {  // the reader checks them (inside the range, no row on one)
    std::vector<int> sorted = *head.dropped_frames;
    std::sort(sorted.begin(), sorted.end());
    csv += io::droppedFramesLines(consecutiveStretches(sorted));
  }
  csv += "frame,track,x,y\n";
  const long header_lines = std::count(csv.begin(), csv.end(), '\n');
  for (Eigen::Index i : order) csv += fmt::format("{:.17g},{:.17g},{:.17g},{:.17g}\n", a(i, 0), a(i, 1), a(i, 2), a(i, 3));
  std::istringstream in(csv);
  return io::readTracks(in, fmt::format("tracks array (rows sorted by frame; line L is sorted row L - {})", header_lines));
}

/// A tracks file's header as the keyword arguments that give it to estimate() with its rows.
py::dict headerDict(const Tracks& t) {
  py::dict d;
  d["image_size"] = py::make_tuple(t.image.width, t.image.height);
  d["image_principal_point"] = py::make_tuple(t.image.cx, t.image.cy);
  d["fps"] = t.image.fps > 0 ? py::cast(t.image.fps) : py::none();
  d["time_origin"] = t.image.fps > 0 && t.image.time_origin != 0 ? py::cast(t.image.time_origin) : py::none();
  std::vector<int> dropped;
  for (const auto& [a, b] : t.skippedStretches())
    for (int f = a; f <= b; ++f) dropped.push_back(f);
  d["dropped_frames"] = py::cast(dropped);
  d["readout_direction"] = readoutDirectionName(t.image.readout_direction);
  return d;
}

Tracks tracksOf(const py::object& tracks, const ArrayHeader& h) {
  if (py::isinstance<py::str>(tracks) || py::hasattr(tracks, "__fspath__")) {
    if (h.any())
      inputError("image_size, image_principal_point, fps, time_origin and dropped_frames are for an array of tracks: a tracks "
                 "file states them");
    return io::readTracks(std::string(py::str(py::module_::import("os").attr("fspath")(tracks))));
  }
  if (!h.image_size) inputError("an array of tracks needs image_size=(width, height)");
  return tracksFromArray(tracks.cast<Eigen::MatrixXd>(), h);
}

/// Tracks as rows (frame, track, x, y): what estimate() takes.
Eigen::MatrixXd trackRows(const Tracks& t) {
  long rows = 0;
  for (const auto& f : t.frames) rows += static_cast<long>(f.size());
  Eigen::MatrixXd a(rows, 4);
  long i = 0;
  for (int k = 0; k < t.numFrames(); ++k)
    for (const auto& p : t.frames[static_cast<size_t>(k)]) a.row(i++) << t.frameNumber(k), p.id, p.px.x(), p.px.y();
  return a;
}

py::object jsonToPython(const nlohmann::json& j) { return py::module_::import("json").attr("loads")(j.dump()); }

/// TUM rows (t, tx, ty, tz, qx, qy, qz, qw): the camera in the reference frame (docs/outputs.md).
Eigen::MatrixXd tumRows(const std::vector<io::TumPose>& poses) {
  Eigen::MatrixXd out(static_cast<Eigen::Index>(poses.size()), 8);
  for (size_t k = 0; k < poses.size(); ++k) {
    const auto& p = poses[k];
    out.row(static_cast<Eigen::Index>(k)) << p.t, p.p.x(), p.p.y(), p.p.z(), p.q.x(), p.q.y(), p.q.z(), p.q.w();
  }
  return out;
}

py::dict resultDict(const Tracks& tracks, const EstimateResult& r, const cli::EstimateCli& e) {
  if (!r.online.ok()) throw std::runtime_error("the filter stopped at " + r.online.stopped);
  cli::EstimateRunReport run(tracks, r, e);
  const nlohmann::json summary = report::estimateSummary(run.rep);
  py::dict d;
  d["summary"] = jsonToPython(summary);
  d["focal_px"] = jsonToPython(summary["focal_px"]);
  d["focal_sd_px"] = summary.contains("focal_sd_px") ? jsonToPython(summary["focal_sd_px"]) : py::none();
  // The final planes (the main result's): unit normals (m, 3) in the reference camera frame,
  // their sds (deg; NaN where a plane is not determined), distances and their sds.
  {
    const auto& pl = summary["planes"];
    Eigen::MatrixXd normals(static_cast<Eigen::Index>(pl.size()), 3);
    for (size_t j = 0; j < pl.size(); ++j)
      for (int c = 0; c < 3; ++c) normals(static_cast<Eigen::Index>(j), c) = pl[j][static_cast<size_t>(c)].get<double>();
    d["planes"] = normals;
    auto column = [&](const char* key) {
      Eigen::VectorXd v = Eigen::VectorXd::Constant(static_cast<Eigen::Index>(pl.size()), NAN);
      if (summary.contains(key) && summary[key].is_array())
        for (size_t j = 0; j < pl.size() && j < summary[key].size(); ++j)
          if (summary[key][j].is_number()) v[static_cast<Eigen::Index>(j)] = summary[key][j].get<double>();
      return v;
    };
    d["plane_normal_sd_deg"] = column("plane_normal_sd_deg");
    d["plane_distances"] = column("plane_distances");
    d["plane_distance_sd"] = column("plane_distance_sd");
  }
  d["trajectory"] = tumRows(report::trajectoryPoses(r.main(), tracks.image));
  d["trajectory_online"] = tumRows(report::trajectoryPoses(r.online, tracks.image));
  d["refined"] = r.refined.ok;
  // Per frame, the online filter: frame, focal (px), its sd, and each plane's unit normal in the
  // reference camera frame (n . Y = d, pointing from the camera to the plane).
  const auto& fr = r.online.frames;
  const Eigen::Index F = static_cast<Eigen::Index>(fr.size());
  Eigen::VectorXd frame(F), focal(F), focal_sd(F);
  const int m = r.online.planes;
  py::array_t<double> normals({static_cast<py::ssize_t>(F), static_cast<py::ssize_t>(std::max(m, 0)), py::ssize_t{3}});
  auto nv = normals.mutable_unchecked<3>();
  for (Eigen::Index k = 0; k < F; ++k) {
    const TrackFrame& f = fr[static_cast<size_t>(k)];
    frame[k] = f.frame;
    focal[k] = r.online.scale_px / f.beta;
    focal_sd[k] = r.online.scale_px * std::sqrt(std::max(0.0, f.var_beta)) / (f.beta * f.beta);
    for (int j = 0; j < m; ++j) {
      const Eigen::Vector3d n = j < static_cast<int>(f.N.size()) ? metricPlane(f.N[j], f.beta).n : Eigen::Vector3d::Constant(NAN);
      for (int c = 0; c < 3; ++c) nv(k, j, c) = n[c];
    }
  }
  py::dict online;
  online["frame"] = frame;
  online["focal_px"] = focal;
  online["focal_sd_px"] = focal_sd;
  online["normals"] = normals;
  d["online"] = online;
  // Labels per track id: plane index, -1 outlier, -2 unused.
  const auto& lab = r.labels();
  d["labels"] = py::array_t<int>(static_cast<py::ssize_t>(lab.size()), lab.data());
  // Per track id: the frame number of the last observation the estimate used (labels.csv's
  // last_frame_used), -1 none.
  std::vector<int> used(r.last_used.size(), -1);
  for (std::size_t id = 0; id < used.size(); ++id)
    if (r.last_used[id] >= 0) used[id] = tracks.frameNumber(r.last_used[id]);
  d["last_frame_used"] = py::array_t<int>(static_cast<py::ssize_t>(used.size()), used.data());
  return d;
}

/// The patch pipeline's result: what `rsfm estimate --patches` writes, as Python objects.
py::dict patchResultDict(const PatchTracks& tracks, const PatchEstimateResult& pr) {
  if (!pr.run.ok()) throw std::runtime_error("the patch filter stopped at " + pr.run.stopped);
  cli::PatchRunReport run(tracks, pr);
  const nlohmann::json summary = report::patchSummary(run.rep);
  py::dict d;
  d["summary"] = jsonToPython(summary);
  d["focal_px"] = jsonToPython(summary["focal_px"]);
  d["focal_sd_px"] = summary.contains("focal_sd_px") ? jsonToPython(summary["focal_sd_px"]) : py::none();
  d["trajectory"] = tumRows(report::patchTrajectory(pr.run, tracks.image));
  // Per frame and live patch (patch_normals.csv): frame, patch id, centre x, y (px), the unit
  // normal in the first camera frame (pointing from the camera to the patch), its sd (deg; NaN
  // when the structure is not determined).
  const bool determined = !summary.contains("structure_determined") || summary["structure_determined"].get<bool>();
  long rows = 0;
  for (const auto& f : pr.run.frames) rows += static_cast<long>(f.patches.size());
  Eigen::MatrixXd pn(rows, 8);
  long i = 0;
  for (const auto& f : pr.run.frames)
    for (const auto& p : f.patches) {
      const Eigen::Vector3d n0 = f.R.transpose() * p.normal;
      pn.row(i++) << f.frame, p.id, p.px.x(), p.px.y(), n0.x(), n0.y(), n0.z(), determined ? p.normal_sd_deg : NAN;
    }
  d["patch_normals"] = pn;
  return d;
}

std::function<void(const std::string&)> noteTo(bool quiet) {
  if (quiet) return {};
  return [](const std::string& m) { fmt::print(stderr, "{}\n", m); };
}

py::dict estimatePy(const py::object& tracks, const std::optional<std::vector<int>>& image_size,
                    const std::optional<std::vector<double>>& principal_point, std::optional<double> fps,
                    std::optional<double> time_origin, const std::optional<std::vector<int>>& dropped_frames,
                    const py::kwargs& kw) {
  CLI::App app{"rsfm.estimate"};
  const cli::EstimateCli e = estimateOptions(kw, &app);
  const Tracks t = tracksOf(tracks, {image_size, principal_point, fps, time_origin, dropped_frames});
  EstimateResult r;
  {
    py::gil_scoped_release release;
    r = estimate(t, e.est, noteTo(e.quiet), cli::estimateProgress(e));
  }
  py::dict d = resultDict(t, r, e);
  return d;
}

py::dict estimatePatchesPy(const py::object& patches, const py::kwargs& kw) {
  CLI::App app{"rsfm.estimate_patches"};
  cli::EstimateCli e = estimateOptions(kw, &app);
  if (!e.patches && kw.contains("model")) inputError("estimate_patches() runs the patch model: leave out model=");
  e.model = "patches";
  if (auto m = cli::finishEstimateOptions(&e); !m.empty()) inputError(m);
  const PatchTracks t = io::readPatches(std::string(py::str(py::module_::import("os").attr("fspath")(patches))));
  PatchEstimateResult pr;
  {
    py::gil_scoped_release release;
    pr = estimatePatches(t, e.pat, noteTo(e.quiet), cli::estimateProgress(e));
  }
  return patchResultDict(t, pr);
}

py::dict runPy(const std::string& video, const py::kwargs& kw) {
  CLI::App app{"rsfm.run"};
  cli::TrackCli tc;
  cli::addTrackerOptions(&app, &tc);
  cli::addPatchTrackerOptions(&app, &tc);
  const cli::EstimateCli e = estimateOptions(kw, &app);
  if (auto m = cli::finishTrackerOptions(&tc); !m.empty()) inputError(m);
  if (e.patches) {
    PatchTracks pt;
    PatchEstimateResult pr;
    {
      py::gil_scoped_release release;
      pt = vision::trackPatchesInput(video, tc.patches, tc.range,
                                     e.quiet ? std::function<void(int, int)>{} : cli::progressReporter("track", "frames"));
      pr = estimatePatches(pt, e.pat, noteTo(e.quiet), cli::estimateProgress(e));
    }
    py::dict d = patchResultDict(pt, pr);
    d["image_size"] = py::make_tuple(pt.image.width, pt.image.height);
    return d;
  }
  Tracks t;
  EstimateResult r;
  {
    py::gil_scoped_release release;
    t = vision::trackInput(video, tc.tracker, tc.range, e.quiet ? std::function<void(int, int)>{} : cli::progressReporter("track", "frames"));
    r = estimate(t, e.est, noteTo(e.quiet), cli::estimateProgress(e));
  }
  py::dict d = resultDict(t, r, e);
  d["tracks"] = trackRows(t);
  d["tracks_header"] = headerDict(t);
  d["image_size"] = py::make_tuple(t.image.width, t.image.height);
  d["readout_direction"] = readoutDirectionName(t.image.readout_direction);
  return d;
}

/// The options of `rsfm estimate` (or `run`) with their defaults, as {python_name: default text}.
py::dict optionsPy(const std::string& command) {
  CLI::App app{"rsfm"};
  cli::EstimateCli e;
  cli::TrackCli tc;
  cli::addEstimateOptions(&app, &e);
  if (command == "run") {
    cli::addTrackerOptions(&app, &tc);
    cli::addPatchTrackerOptions(&app, &tc);
  } else if (command != "estimate") {
    inputError("options(): command must be 'estimate' or 'run'");
  }
  py::dict d;
  for (const CLI::Option* o : app.get_options()) {
    if (o->get_lnames().empty()) continue;
    std::string name = o->get_lnames().front();
    if (name == "help" || name == "out" || name == "no-plots") continue;
    std::replace(name.begin(), name.end(), '-', '_');
    d[py::str(name)] = py::make_tuple(o->get_default_str(), o->get_description());
  }
  return d;
}

/// The plane filter, one frame at a time (Alon & Sclaroff's model; docs/filter.md). Normalized
/// image coordinates (u, v) = ((x - c_x) / s, (y - c_y) / s) and the A&P state
/// (t_X, t_Y, t_Z beta, omega, beta, N_1, ..., N_m) (docs/conventions.md).
class PlaneFilterPy {
 public:
  PlaneFilterPy(const Eigen::MatrixXd& reference_uv, std::optional<std::vector<int>> labels, int planes, double beta0,
                double beta_sd0, double depth0, double normal_sd0, std::optional<double> sigma_uv,
                std::optional<Eigen::VectorXd> q_motion, std::optional<Eigen::MatrixXd> normals0) {
    if (reference_uv.cols() != 2) inputError("reference_uv must be (N, 2)");
    const int N = static_cast<int>(reference_uv.rows());
    if (planes < 1) inputError("planes must be >= 1");
    std::vector<int> lab = labels ? *labels : std::vector<int>(static_cast<size_t>(N), 0);
    if (static_cast<int>(lab.size()) != N) inputError("labels must have one entry per reference point");
    for (int l : lab)
      if (l < 0 || l >= planes) inputError(fmt::format("label {} outside 0..{}", l, planes - 1));
    if (!(beta0 > 0) || !(depth0 > 0) || !(beta_sd0 >= 0) || !(normal_sd0 >= 0))
      inputError("beta0 and depth0 must be > 0, beta_sd0 and normal_sd0 >= 0");
    std::vector<Eigen::Vector2d> ref(static_cast<size_t>(N));
    for (int i = 0; i < N; ++i) ref[static_cast<size_t>(i)] = reference_uv.row(i).transpose();
    FilterOptions fo = TrackFilterOptions::defaultFilter();
    // q_motion is the process noise, fixed: the pipeline's adaptation starts from the motion its
    // start measured (TrackFilterOptions::q_from_data), which a step-by-step filter does not have.
    fo.adapt.enabled = false;
    if (sigma_uv) fo.sigma_uv = *sigma_uv;
    if (q_motion) {
      if (q_motion->size() != 7) inputError("q_motion must have 7 entries (t_X, t_Y, t_Z beta, omega_X, omega_Y, omega_Z, beta)");
      fo.q_motion = *q_motion;
    }
    const int n = 7 + 3 * planes;
    Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
    Eigen::MatrixXd P0 = Eigen::MatrixXd::Zero(n, n);
    std::vector<bool> fixed(static_cast<size_t>(n), false);
    x0[idx::kBeta] = beta0;
    P0(idx::kBeta, idx::kBeta) = std::pow(beta_sd0 * beta0, 2);
    fixed[idx::kBeta] = beta_sd0 == 0;
    const double nz0 = beta0 / depth0;  // every plane frontal at depth0 / beta0 beyond the image plane
    if (normals0 && (normals0->rows() != planes || normals0->cols() != 3))
      inputError(fmt::format("normals0 must be ({}, 3)", planes));
    for (int j = 0; j < planes; ++j) {
      const int b = PlaneModel::planeIndex(j);
      x0[b + 2] = nz0;
      if (normals0) {
        // n . Y = d (COP-centred) through the point depth0 / beta0 beyond the image-plane origin on
        // the optical axis: N = n / (d - n_Z / beta0) ([AS99] eq. 9 with Y = X + e_z / beta).
        const Eigen::Vector3d nj = normals0->row(j).transpose().normalized();
        if (!(nj.z() > 0.05)) inputError("normals0: each normal must face the camera (n_Z > 0.05)");
        const double dj = nj.z() * (depth0 / beta0 + 1.0 / beta0);
        x0.segment<3>(b) = nj / (dj - nj.z() / beta0);
      }
      const double v = std::pow(normal_sd0 * std::max(x0.segment<3>(b).norm(), nz0), 2);
      P0(b, b) = P0(b + 1, b + 1) = v;
      P0(b + 2, b + 2) = j == 0 ? 0.0 : v;
    }
    fixed[static_cast<size_t>(PlaneModel::planeIndex(0) + 2)] = true;  // scale gauge: N_Z of plane 0
    filter_.emplace(PlaneModel(ref, lab, planes), Ekf(x0, P0, fixed), fo);
    points_ = N;
  }

  py::dict step(const std::vector<int>& ids, const Eigen::MatrixXd& uv) {
    if (uv.cols() != 2 || uv.rows() != static_cast<Eigen::Index>(ids.size()))
      inputError("step(ids, uv): uv must be (len(ids), 2)");
    obs_.clear();
    for (size_t i = 0; i < ids.size(); ++i) {
      if (ids[i] < 0 || ids[i] >= points_) inputError(fmt::format("point id {} outside 0..{}", ids[i], points_ - 1));
      obs_.push_back({ids[i], uv.row(static_cast<Eigen::Index>(i)).transpose()});
    }
    const FrameStats& fs = filter_->step(obs_);
    ++frames_;
    py::dict d;
    d["applied"] = fs.update.applied;
    d["used"] = fs.update.used;
    d["gated"] = fs.update.gated;
    d["invalid"] = fs.invalid;
    d["nis"] = fs.update.nis;
    d["nis_dof"] = fs.update.nis_dof;
    d["healthy"] = fs.health == kHealthy;
    return d;
  }

  Eigen::VectorXd state() const { return filter_->ekf().x(); }
  Eigen::MatrixXd covariance() const { return filter_->ekf().P(); }
  Eigen::Matrix3d rotation() const { return filter_->rotation(); }
  Eigen::Vector3d translation() const { return filter_->translation(); }
  double beta() const { return filter_->beta(); }
  Eigen::MatrixXd normals() const {
    const int m = filter_->model().numPlanes();
    Eigen::MatrixXd out(m, 3);
    for (int j = 0; j < m; ++j) out.row(j) = filter_->ekf().x().segment<3>(PlaneModel::planeIndex(j)).transpose();
    return out;
  }
  int frames() const { return frames_; }

 private:
  std::optional<RecursiveFilter<PlaneModel>> filter_;
  std::vector<Observation> obs_;  // kept: a warm filter allocates nothing per frame here
  int points_ = 0;
  int frames_ = 0;
};

}  // namespace

PYBIND11_MODULE(_rsfm, m) {
  m.doc() = "rsfm: camera motion, focal length and planar structure from tracked features (python/README.md)";
  m.attr("__version__") = kVersion;
  static py::exception<io::InputError> input_error(m, "InputError", PyExc_ValueError);
  g_input_error = input_error.ptr();
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const io::InputError& e) {
      PyErr_SetString(g_input_error, e.what());
    } catch (const NoPlaneFound& e) {
      PyErr_SetString(g_input_error, e.what());
    } catch (const std::invalid_argument& e) {
      PyErr_SetString(g_input_error, e.what());
    }
  });

  m.def("estimate", &estimatePy, py::arg("tracks"), py::kw_only(), py::arg("image_size") = py::none(),
        py::arg("image_principal_point") = py::none(), py::arg("fps") = py::none(), py::arg("time_origin") = py::none(),
        py::arg("dropped_frames") = py::none(),
        R"doc(The pipeline of `rsfm estimate` (plane finding, the homography start, the filter, the final
refinement) on tracks.

tracks: a tracks.csv path (docs/tracks.md), or an (M, 4) array of rows (frame, track, x, y) in
    pixels, with image_size=(width, height) (and image_principal_point=(x, y), the tracks' image
    centre, default the middle; fps, the source's frame rate, makes the timestamps seconds;
    time_origin, the time of frame 0 in seconds (with fps); dropped_frames, the frame numbers the
    source dropped, which no row names; read_tracks() gives all of them back as a dict:
    estimate(rows, **header)).
    (principal_point=(x, y) is the CLI's --principal-point: a known principal point, held.)
**options: the command line's options, dashes as underscores (model="plane", focal_px=612,
    refine="none", quiet=True, ...; rsfm.options("estimate") lists them with their defaults).

Returns a dict: "summary" (what summary.json holds), "focal_px" (None when the data do not
determine it) and "focal_sd_px", "planes" (m, 3) unit normals in the reference camera frame with
"plane_normal_sd_deg", "plane_distances", "plane_distance_sd" (NaN where not determined),
"trajectory" (F, 8) TUM rows (t, tx, ty, tz, qx, qy, qz, qw) of
the main result (the refinement's when it ran; t in seconds at the source's frame rate when known,
else frame numbers), "trajectory_online" (the filter's), "refined",
"online" (per frame: "frame", "focal_px", "focal_sd_px", "normals" (F, m, 3) unit normals in the
reference camera frame), "labels" (per track id: plane, -1 outlier, -2 unused).
Raises rsfm.InputError for bad input or options, RuntimeError when the filter stops.)doc");
  m.def("estimate_patches", &estimatePatchesPy, py::arg("patches"),
        R"doc(The patch pipeline of `rsfm estimate --patches` (Calway's filter over tracked affine
patches, with the motion check) on a patches.csv path (docs/tracks.md).

**options: the command line's estimate options (rsfm.options("estimate")).
Returns a dict: "summary" (what summary.json holds), "focal_px" (None when not determined),
"focal_sd_px", "trajectory" (F, 8) TUM rows, "patch_normals" (rows: frame, patch, x, y, nx, ny,
nz in the first camera frame, normal sd in deg; NaN sd when the structure is not determined).)doc");
  m.def("run", &runPy, py::arg("video"),
        R"doc(`rsfm run` without files: tracks `video` (a video file, an image pattern such as
frames/img%04d.png, or a folder of images), then estimate() on the tracks.

**options: those of `rsfm run` (tracker and estimate options; rsfm.options("run")).
Returns estimate()'s dict plus "tracks" ((M, 4) rows frame, track, x, y), "tracks_header" (read_tracks()'
header: estimate(r["tracks"], **r["tracks_header"]) estimates them again), "image_size" and
"readout_direction" (the rolling shutter's across the image: "left" for a video turned 90 degrees
by its rotation metadata; give it back as readout_direction= with the rows); with
model="patches", estimate_patches()'s dict plus "image_size".)doc");
  m.def("options", &optionsPy, py::arg("command") = "estimate",
        "The options of estimate() ('estimate') or run() ('run'): {name: (default, help)}.");
  m.def(
      "read_tracks",
      [](const std::string& path) {
        const Tracks t = io::readTracks(path);
        return py::make_tuple(trackRows(t), headerDict(t));
      },
      py::arg("path"),
      "Reads a tracks.csv (docs/tracks.md): returns (rows, header): rows (M, 4) frame, track, x, y; header a dict of "
      "estimate()'s keyword arguments for an array, image_size (width, height), image_principal_point (c_x, c_y), fps "
      "(None: not known), time_origin (None: none), dropped_frames (frame numbers) and readout_direction, so that "
      "estimate(rows, **header) is estimate(path).");

  py::class_<PlaneFilterPy>(m, "PlaneFilter", R"doc(The plane filter (Alon & Sclaroff's model, docs/filter.md), one frame at a time.

Coordinates are A&P normalized image units: u = (x - c_x) / s, v = (y - c_y) / s for a scale s
(e.g. the image's larger side); beta = 1/f in those units. The state is (t_X, t_Y, t_Z beta,
omega_X, omega_Y, omega_Z, beta, N_1, ..., N_m): each plane N . X = 1 in the reference frame
(docs/conventions.md). Plane 0's N_Z is held (the scale gauge).)doc")
      .def(py::init<const Eigen::MatrixXd&, std::optional<std::vector<int>>, int, double, double, double, double,
                    std::optional<double>, std::optional<Eigen::VectorXd>, std::optional<Eigen::MatrixXd>>(),
           py::arg("reference_uv"), py::kw_only(), py::arg("labels") = py::none(), py::arg("planes") = 1,
           py::arg("beta0") = 1.0, py::arg("beta_sd0") = 0.5, py::arg("depth0") = 4.0, py::arg("normal_sd0") = 0.5,
           py::arg("sigma_uv") = py::none(), py::arg("q_motion") = py::none(), py::arg("normals0") = py::none(),
           R"doc(reference_uv: (N, 2) the points' positions in the reference frame (normalized).
labels: the plane of each point (default all 0); planes: their number.
beta0, beta_sd0: the start of beta = 1/f and its relative sd (0: beta known and held).
depth0, normal_sd0: every plane starts through the point depth0 / beta0 beyond the image plane on
    the optical axis, frontal or with the unit normal of normals0 ((m, 3), reference camera
    frame, n_Z > 0), its N with relative sd normal_sd0. Plane 0's N_Z is then the scale gauge.
sigma_uv: the observation sd (normalized units); q_motion: the 7 per-frame process variances,
    fixed (default: FilterOptions'; the pipeline's own filter sets them from the motion its start
    measured and adapts them, which this step-by-step filter does not).)doc")
      .def("step", &PlaneFilterPy::step, py::arg("ids"), py::arg("uv"),
           "One frame: ids (K,) point indices, uv (K, 2) their normalized positions. Returns the frame's statistics "
           "(applied, used, gated, invalid, nis, nis_dof, healthy).")
      .def_property_readonly("state", &PlaneFilterPy::state, "The state vector (7 + 3m).")
      .def_property_readonly("covariance", &PlaneFilterPy::covariance, "The state covariance.")
      .def_property_readonly("rotation", &PlaneFilterPy::rotation, "R: reference frame -> current camera.")
      .def_property_readonly("translation", &PlaneFilterPy::translation, "(t_X, t_Y, t_Z) in scene units.")
      .def_property_readonly("beta", &PlaneFilterPy::beta, "beta = 1/f (normalized units).")
      .def_property_readonly("normals", &PlaneFilterPy::normals, "(m, 3): each plane's N (N . X = 1, reference frame).")
      .def_property_readonly("frames", &PlaneFilterPy::frames, "Frames fed so far.");
}
