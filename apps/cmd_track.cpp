// `rsfm track INPUT --out DIR [--patches]`: KLT tracks or affine patches of a video, image pattern or
// folder (docs/tracks.md).
#include <fmt/format.h>

#include <cmath>
#include <memory>
#include <sstream>

#include "cli_common.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/patches_io.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "track_options.hpp"

namespace rsfm::cli {

void addTrackerOptions(CLI::App* app, TrackCli* t) {
  auto& o = t->tracker;
  app->add_option("--first", t->range.first, "first frame (0-based)")->capture_default_str();
  app->add_option("--last", t->range.last, "last frame (inclusive; -1: to the end)")->capture_default_str();
  app->add_option("--roi", t->roi, "region of interest in the first frame: polygon x,y,x,y,... (px)");
  app->add_option("--max-tracks", o.max_tracks, "tracks kept alive at most")->capture_default_str();
  app->add_option("--quality", o.quality, "Shi-Tomasi quality level")->capture_default_str();
  app->add_option("--min-distance", o.min_distance_px, "minimum corner distance (px)")->capture_default_str();
  app->add_option("--window", o.window_px, "Lucas-Kanade window (px)")->capture_default_str();
  app->add_option("--levels", o.pyramid_levels, "pyramid levels at least (more when the motion needs them)")->capture_default_str();
  app->add_option("--max-levels", o.max_pyramid_levels, "pyramid levels at most (the first step uses these)")->capture_default_str();
  app->add_option("--fb-max", o.fb_max_px, "forward-backward error limit (px)")->capture_default_str();
  app->add_flag("!--no-fb-check", o.fb_check, "no forward-backward check (faster; a track that slips at a fast step carries on)");
  app->add_option("--anchor-every", o.anchor_every, "align each track to its first appearance every this many frames")->capture_default_str();
  app->add_flag("!--no-anchor", o.anchor, "frame-to-frame tracking only (no re-alignment to each track's first appearance)");
  app->add_flag("!--no-exposure-compensation", o.exposure_compensation,
                "no exposure compensation (by default a step is repeated with the last frame brought to the next one's "
                "brightness when the tracks show a change of a grey level or more: auto-exposure, flicker; docs/tracks.md)");
}

void addPatchTrackerOptions(CLI::App* app, TrackCli* t) {
  auto& o = t->patches;
  app->add_option("--patch-radius", o.affine.radius, "affine patches: template half-size (px)")->capture_default_str();
  app->add_option("--max-patches", o.max_patches, "affine patches: patches kept alive at most")->capture_default_str();
  app->add_option("--patch-quality", o.quality, "affine patches: Shi-Tomasi quality level")->capture_default_str();
  app->add_option("--patch-max-rms", o.affine.max_rms, "affine patches: loss above this normalized residual")
      ->capture_default_str();
}

std::string finishTrackerOptions(TrackCli* t) {
  const auto& o = t->tracker;
  if (t->range.first < 0) return "--first must be >= 0";
  if (t->range.last >= 0 && t->range.last <= t->range.first) return "--last must be after --first (or -1)";
  if (o.max_tracks < 5) return "--max-tracks must be at least 5";
  if (!(o.quality > 0 && o.quality < 1)) return "--quality must be in (0, 1)";
  if (!(o.min_distance_px > 0)) return "--min-distance must be positive";
  if (o.window_px < 5 || o.window_px % 2 == 0) return "--window must be an odd number >= 5";
  if (o.pyramid_levels < 0 || o.pyramid_levels > 8) return "--levels must be in 0..8";
  if (o.max_pyramid_levels < o.pyramid_levels || o.max_pyramid_levels > 8) return "--max-levels must be in --levels..8";
  if (!(o.fb_max_px > 0)) return "--fb-max must be positive";
  if (!t->roi.empty()) {
    if (auto m = parsePolygon(t->roi, &t->tracker.roi); !m.empty()) return "--roi: " + m;
  }
  t->patches.roi = t->tracker.roi;
  const auto& p = t->patches;
  if (p.affine.radius < 3 || p.affine.radius > 60) return "--patch-radius must be in 3..60";
  if (p.max_patches < 3) return "--max-patches must be at least 3";
  if (!(p.quality > 0 && p.quality < 1)) return "--patch-quality must be in (0, 1)";
  if (!(p.affine.max_rms > 0)) return "--patch-max-rms must be positive";
  t->patches.affine.window_sigma = p.affine.radius;
  return "";
}

void addTrackCommands(CLI::App& app, std::vector<Command>& commands) {
  struct Cli {
    TrackCli t;
    std::string input;
    std::string out = "out/track";
    bool quiet = false;
    bool patches = false;
  };
  auto c = std::make_shared<Cli>();
  auto* tr = app.add_subcommand(
      "track", "KLT feature tracks (DIR/tracks.csv) or, with --patches, affine patches (DIR/patches.csv) of a video, "
               "image pattern or folder");
  tr->add_option("input", c->input, "video file, image pattern (frames/img%04d.png) or folder of images")->required();
  tr->add_option("--out", c->out, "output directory")->capture_default_str();
  addTrackerOptions(tr, &c->t);
  tr->add_flag("--patches", c->patches, "track affine patches (Calway's filter's input) -> DIR/patches.csv");
  addPatchTrackerOptions(tr, &c->t);
  tr->add_flag("--quiet", c->quiet, "no progress on stderr");
  commands.push_back({tr, [c]() -> int {
    if (auto m = finishTrackerOptions(&c->t); !m.empty()) return fail(kBadInput, m);
    io::OutputDir od;
    if (auto m = od.open(c->out, {inputPath(c->input)}); !m.empty()) return fail(kBadInput, m);
    const auto progress = c->quiet ? std::function<void(int, int)>{} : progressReporter("track", "frames");
    const auto out = od.path();
    if (c->patches) {
      PatchTracks pt;
      if (int rc = guarded([&] { pt = vision::trackPatchesInput(c->input, c->t.patches, c->t.range, progress); })) return rc;
      sayLeadingFramesLeftOut(c->quiet, c->t.range.first, pt.first_frame, "patches", "patches");
      if (int rc = guarded([&] {
            io::writeAllOrNothing({{out / "patches.csv", io::patchesToString(pt)}});
            od.commit();
          }))
        return rc;
      if (!c->quiet) {
        int ids = 0;
        for (const auto& f : pt.frames)
          for (const auto& p : f) ids = std::max(ids, p.id + 1);
        fmt::print(stderr, "track: {} frames, {} patches (radius {} px); wrote {}/patches.csv\n", pt.numFrames(), ids,
                   pt.radius, c->out);
      }
      return 0;
    }
    Tracks tracks;
    vision::TrackingStats stats;
    if (int rc = guarded([&] { tracks = vision::trackInput(c->input, c->t.tracker, c->t.range, progress, &stats); })) return rc;
    sayLeadingFramesLeftOut(c->quiet, c->t.range.first, tracks.first_frame, "corners", "tracks");
    sayExposureCompensated(c->quiet, stats.exposure_changes, stats.steps);
    sayDroppedFrames(c->quiet, stats.dropped_frames, tracks.image.fps);
    if (int rc = guarded([&] {
          io::writeAllOrNothing({{out / "tracks.csv", io::tracksToString(tracks)}});
          od.commit();
        }))
      return rc;
    const auto spans = trackSpans(tracks);
    if (!c->quiet)
      fmt::print(stderr, "track: {} frames, {} tracks; wrote {}/tracks.csv\n", tracks.numFrames(), spans.size(), c->out);
    return 0;
  }});
}

}  // namespace rsfm::cli
