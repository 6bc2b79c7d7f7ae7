// `rsfm run`: track a video, then the estimate and report of `rsfm estimate` (apps/estimate_cli.hpp)
// with the overlay video. Part of rsfm-video, the binary that links OpenCV's video I/O.
#include "cli_common.hpp"
#include "estimate_cli.hpp"
#include "rsfm/clock.hpp"
#include "rsfm/io/atomic_file.hpp"
#include "rsfm/vision/overlay.hpp"
#include "track_options.hpp"

namespace rsfm::cli {

void addRunCommands(CLI::App& app, std::vector<Command>& commands) {
  {
    struct Cli {
      EstimateCli e;
      TrackCli t;
      std::string input;
      bool overlay = true;
    };
    auto c = std::make_shared<Cli>();
    c->e.out = "out/run";
    auto* rn = app.add_subcommand("run", "track a video, find planes, estimate and report (the whole chain)");
    rn->add_option("input", c->input, "video file, image pattern (frames/img%04d.png) or folder of images")->required();
    addEstimateOptions(rn, &c->e);
    addTrackerOptions(rn, &c->t);
    addPatchTrackerOptions(rn, &c->t);
    rn->add_flag("!--no-overlay", c->overlay, "skip overlay.mp4");
    commands.push_back({rn, [c]() -> int {
      const double t0 = steadySeconds();
      if (auto m = finishEstimateOptions(&c->e); !m.empty()) return fail(kBadInput, m);
      if (auto m = finishTrackerOptions(&c->t); !m.empty()) return fail(kBadInput, m);
      io::OutputDir od;
      if (auto m = od.open(c->e.out, {inputPath(c->input), c->e.camera_file}); !m.empty()) return fail(kBadInput, m);
      EstimateCli e = c->e;
      e.shown_out = e.out;
      e.out = od.path().string();
      auto finish = [&](int rc) { return rc == 0 ? guarded([&] { od.commit(); }) : rc; };
      const auto progress = c->e.quiet ? std::function<void(int, int)>{} : progressReporter("track", "frames");
      if (c->e.patches) {
        PatchTracks pt;
        if (int rc = guarded([&] { pt = vision::trackPatchesInput(c->input, c->t.patches, c->t.range, progress); })) return rc;
        sayLeadingFramesLeftOut(c->e.quiet, c->t.range.first, pt.first_frame, "patches", "patches");
        PatchOverlay overlay;
        if (c->overlay)
          overlay = [&](const PatchRunResult& res, const std::filesystem::path& tmp) {
            return vision::writePatchOverlay(c->input, c->t.range, pt, res, tmp);
          };
        return finish(patchEstimateAndReport(pt, e, overlay, t0, true));
      }
      Tracks tracks;
      vision::TrackingStats stats;
      if (int rc = guarded([&] { tracks = vision::trackInput(c->input, c->t.tracker, c->t.range, progress, &stats); })) return rc;
      sayLeadingFramesLeftOut(c->e.quiet, c->t.range.first, tracks.first_frame, "corners", "tracks");
      sayExposureCompensated(c->e.quiet, stats.exposure_changes, stats.steps);
      sayDroppedFrames(c->e.quiet, stats.dropped_frames, tracks.image.fps);
      const RunTracking tracking{steadySeconds() - t0, stats.steps, stats.exposure_changes, stats.dropped_frames};
      // The tracks are part of the report.
      TrackOverlay overlay;
      if (c->overlay)
        overlay = [&](const EstimateResult& r, const std::filesystem::path& tmp) {
          return vision::writeOverlay(c->input, c->t.range, tracks, r.labels(), r.main(), tmp);
        };
      return finish(estimateAndReport(tracks, e, overlay, t0, true, &tracking));
    }});
  }
}

}  // namespace rsfm::cli
