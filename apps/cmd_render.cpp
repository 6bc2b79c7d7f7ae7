// `rsfm render SCENE` and `rsfm render regime NAME`: rendered sequences with known truth
// (docs/render.md, docs/regimes.md).
#include <fmt/format.h>

#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "cli_common.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/render/regime_suite.hpp"
#include "rsfm/render/scene_render.hpp"

namespace rsfm::cli {

namespace {

/// Renders `o` into `out` with progress and notes on stderr unless quiet; returns the exit code.
int renderTo(const render::RenderOptions& o, const std::string& out, bool quiet, const std::string& extra_json = {}) {
  if (auto msg = render::validate(o); !msg.empty()) return fail(kBadInput, msg);
  io::OutputDir od;
  if (auto msg = od.open(out); !msg.empty()) return fail(kBadInput, msg);
  auto progress = quiet ? std::function<void(int, int)>{} : progressReporter("render", "frames");
  auto note = [quiet](const std::string& m) {
    if (!quiet) fmt::print(stderr, "{}\n", m);
  };
  render::RenderResult res;
  try {
    res = render::writeSequence(o, od.path(), progress, note, extra_json);
    od.commit();
  } catch (const std::invalid_argument& e) {
    return fail(kBadInput, e.what());
  } catch (const std::exception& e) {
    return fail(o.texture.empty() ? kRuntimeFailure : kBadInput, e.what());
  }
  if (!quiet)
    fmt::print(stderr, "render: {} frames in {:.1f} s; wrote {}, {}/truth/trajectory.tum, summary.json, render.json\n",
               res.frames, res.seconds, (std::filesystem::path(out) / res.video.filename()).string(), out);
  return 0;
}

struct SceneCli {
  render::RenderOptions o;
  std::string out;
  std::string motion = "orbit";
  bool no_floor = false;
  bool quiet = false;
  std::vector<double> elevation;         // first, last frame (deg)
  std::vector<double> principal_offset;  // dx, dy (px)
  double approach = 0;                   // 0: the motion's default
};

void addSceneOptions(CLI::App* c, SceneCli* st) {
  st->elevation = {st->o.elevation0_deg, st->o.elevation1_deg};
  st->principal_offset = {0, 0};
  c->add_option("--out", st->out, "output directory")->required();
  c->add_option("--frames", st->o.frames, "number of frames")->capture_default_str();
  c->add_option("--focal-px", st->o.focal_px, "focal length in pixels")->capture_default_str();
  c->add_option("--width", st->o.width, "image width (px, even)")->capture_default_str();
  c->add_option("--height", st->o.height, "image height (px, even)")->capture_default_str();
  c->add_option("--principal-offset", st->principal_offset,
                "principal point minus the image centre, DX,DY px (each within 5 % of the width)")
      ->delimiter(',')
      ->expected(2)
      ->capture_default_str();
  c->add_option("--k1", st->o.k1, "radial distortion k1 (OpenCV's convention)")->capture_default_str();
  c->add_option("--k2", st->o.k2, "radial distortion k2 (OpenCV's convention)")->capture_default_str();
  c->add_option("--motion", st->motion, "orbit | translate | rotate (about the centre of projection) | forward | none")
      ->capture_default_str();
  c->add_option("--orbit-deg", st->o.orbit_deg,
                "sweep over the moving frames (deg): orbit azimuth, rotate pan, angle a translation subtends")
      ->capture_default_str();
  c->add_option("--deg-per-frame", st->o.deg_per_frame, "> 0: sweep = this x (moving frames - 1) instead of --orbit-deg")
      ->capture_default_str();
  c->add_option("--elevation", st->elevation, "orbit elevation above the floor at the first and last frame (deg)")
      ->delimiter(',')
      ->expected(2)
      ->capture_default_str();
  c->add_option("--approach", st->approach,
                "distance at the last moving frame relative to the first (default 1; forward: 0.6)");
  c->add_option("--still-start", st->o.still_start, "frames held at the first pose before the motion starts")
      ->capture_default_str();
  c->add_option("--still-middle", st->o.still_middle, "frames held halfway through the motion")->capture_default_str();
  c->add_option("--jitter-deg", st->o.jitter_deg, "hand-held jitter: sd of a random rotation per frame (deg)")
      ->capture_default_str();
  c->add_option("--noise", st->o.noise_sigma, "sensor noise standard deviation (8-bit grey levels)")->capture_default_str();
  c->add_option("--blur", st->o.blur, "motion blur: exposure as a fraction of the frame interval [0, 1]")
      ->capture_default_str();
  c->add_option("--readout", st->o.readout,
                "rolling shutter: first row to last row, as a fraction of the frame interval [0, 1] (0: global shutter)")
      ->capture_default_str();
  c->add_option("--jpeg-quality", st->o.jpeg_quality, "JPEG-compress every frame at this quality (1-100; 0: none)")
      ->capture_default_str();
  c->add_option("--texture", st->o.texture,
                "an image for every face, or 'procedural' (default: photographs from visp-images-data)");
  c->add_option("--seed", st->o.seed, "seed of the wobble, the jitter, the noise and procedural textures")
      ->capture_default_str();
  c->add_option("--fps", st->o.fps, "video frame rate")->capture_default_str();
  c->add_flag("--no-floor", st->no_floor, "box and lowtex scenes: leave out the floor");
  c->add_flag("--quiet", st->quiet, "no progress on stderr");
}

/// Fills the options that need translating; returns an error message or "".
std::string finishSceneOptions(SceneCli* st) {
  st->o.floor = !st->no_floor;
  st->o.elevation0_deg = st->elevation[0];
  st->o.elevation1_deg = st->elevation[1];
  st->o.principal_offset_px = {st->principal_offset[0], st->principal_offset[1]};
  if (!render::parseMotionKind(st->motion, &st->o.motion))
    return "--motion must be one of " + render::motionKindNames() + ", got '" + st->motion + "'";
  if (st->approach != 0) st->o.approach = st->approach;
  return {};
}

}  // namespace

void addRenderCommands(CLI::App& app, std::vector<Command>& commands) {
  auto* render = app.add_subcommand("render", "render test sequences with known camera motion and planes");
  render->require_subcommand(1);
  const std::vector<std::pair<render::SceneKind, std::string>> scenes{
      {render::SceneKind::Box, "a textured box on a textured floor"},
      {render::SceneKind::Corner, "a room corner: the floor and two textured walls, the camera inside"},
      {render::SceneKind::Poster, "one textured poster on a plain wall (a single plane)"},
      {render::SceneKind::Object, "a textured box moved before a still camera and a still textured wall"},
      {render::SceneKind::LowTexture, "the box on the floor, flat-shaded with a few textured patches"}};
  for (const auto& [kind, what] : scenes) {
    auto* c = render->add_subcommand(std::string(render::toString(kind)), what + ": DIR/video.mp4, DIR/truth/");
    auto st = std::make_shared<SceneCli>();
    st->o.scene = kind;
    addSceneOptions(c, st.get());
    commands.push_back({c, [st]() -> int {
      if (auto msg = finishSceneOptions(st.get()); !msg.empty()) return fail(kBadInput, msg);
      return renderTo(st->o, st->out, st->quiet);
    }});
  }
  {
    struct RegimeCli {
      std::string name, out, suite;
      bool list = false, quiet = false;
    };
    auto st = std::make_shared<RegimeCli>();
    auto* c = render->add_subcommand("regime", "one named sequence of the regime suite (docs/regimes.md)");
    c->add_option("name", st->name, "sequence name (--list shows them)");
    c->add_option("--out", st->out, "output directory");
    c->add_option("--suite", st->suite, "suite file (default: the built-in bench/regimes.json)");
    c->add_flag("--list", st->list, "list the suite's sequences and exit");
    c->add_flag("--quiet", st->quiet, "no progress on stderr");
    commands.push_back({c, [st]() -> int {
      render::RegimeSuite suite;
      if (int rc = guarded([&] { suite = st->suite.empty() ? render::builtinRegimeSuite() : render::readRegimeSuite(st->suite); }))
        return rc;
      if (st->list) {
        for (const auto& r : suite.sequences) fmt::print("{:<24} {}\n", r.name, r.why);
        return 0;
      }
      if (st->name.empty()) return fail(kBadInput, "a sequence name is required (rsfm render regime --list)");
      if (st->out.empty()) return fail(kBadInput, "--out is required");
      const render::Regime* regime = suite.find(st->name);
      if (!regime)
        return fail(kBadInput, fmt::format("unknown regime '{}' in {} (one of: {})", st->name, suite.source, suite.names()));
      nlohmann::json extra = {{"regime", regime->name}, {"why", regime->why}, {"axes", regime->axes},
                              {"suite", suite.source}};
      return renderTo(regime->options, st->out, st->quiet, extra.dump());
    }});
  }
}

}  // namespace rsfm::cli
