// `rsfm render box`: a rendered sequence with known truth (docs/render.md).
#include <fmt/format.h>

#include <memory>
#include <string>

#include "cli_common.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/render/box_render.hpp"

namespace rsfm::cli {

void addRenderCommands(CLI::App& app, std::vector<Command>& commands) {
  auto* render = app.add_subcommand("render", "render test sequences with known camera motion and planes");
  render->require_subcommand(1);
  auto* box = render->add_subcommand(
      "box", "a textured box on a textured floor seen from a hand-held-like orbit: DIR/video.mp4, DIR/truth/");
  struct BoxCli {
    rsfm::render::BoxRenderOptions o;
    std::string out;
    bool no_floor = false;
    bool quiet = false;
    std::vector<double> elevation;  // first, last frame (deg)
  };
  auto st = std::make_shared<BoxCli>();
  st->elevation = {st->o.elevation0_deg, st->o.elevation1_deg};
  box->add_option("--out", st->out, "output directory")->required();
  box->add_option("--frames", st->o.frames, "number of frames")->capture_default_str();
  box->add_option("--focal-px", st->o.focal_px, "focal length in pixels")->capture_default_str();
  box->add_option("--width", st->o.width, "image width (px, even)")->capture_default_str();
  box->add_option("--height", st->o.height, "image height (px, even)")->capture_default_str();
  box->add_option("--texture", st->o.texture,
                  "an image for every face, or 'procedural' (default: photographs from visp-images-data)");
  box->add_option("--seed", st->o.seed, "seed of the hand-held wobble, the noise and procedural textures")
      ->capture_default_str();
  box->add_option("--noise", st->o.noise_sigma, "sensor noise standard deviation (8-bit grey levels)")
      ->capture_default_str();
  box->add_option("--orbit-deg", st->o.orbit_deg, "azimuth swept about the box (deg)")->capture_default_str();
  box->add_option("--elevation", st->elevation, "orbit elevation above the floor at the first and last frame (deg)")
      ->delimiter(',')
      ->expected(2)
      ->capture_default_str();
  box->add_option("--approach", st->o.approach, "orbit radius at the last frame relative to the first")
      ->capture_default_str();
  box->add_option("--fps", st->o.fps, "video frame rate")->capture_default_str();
  box->add_flag("--no-floor", st->no_floor, "leave out the floor (box only)");
  box->add_flag("--quiet", st->quiet, "no progress on stderr");
  commands.push_back({box, [st]() -> int {
    st->o.floor = !st->no_floor;
    st->o.elevation0_deg = st->elevation[0];
    st->o.elevation1_deg = st->elevation[1];
    if (auto msg = rsfm::render::validate(st->o); !msg.empty()) return fail(kBadInput, msg);
    if (auto msg = rsfm::io::ensureWritableDirectory(st->out); !msg.empty()) return fail(kBadInput, msg);
    const bool quiet = st->quiet;
    auto progress = quiet ? std::function<void(int, int)>{} : progressReporter("render", "frames");
    auto note = [quiet](const std::string& m) {
      if (!quiet) fmt::print(stderr, "{}\n", m);
    };
    rsfm::render::RenderResult res;
    try {
      res = rsfm::render::writeBoxSequence(st->o, st->out, progress, note);
    } catch (const std::invalid_argument& e) {
      return fail(kBadInput, e.what());
    } catch (const std::exception& e) {
      return fail(st->o.texture.empty() ? kRuntimeFailure : kBadInput, e.what());
    }
    if (!quiet)
      fmt::print(stderr, "render: {} frames in {:.1f} s; wrote {}, {}/truth/trajectory.tum, {}/truth/summary.json\n",
                 res.frames, res.seconds, res.video.string(), st->out, st->out);
    return 0;
  }});
}

}  // namespace rsfm::cli
