// Tracks in, planes and focal length out: rsfm as a library (docs/install.md).
//   planes_from_tracks TRACKS.csv
// Reads a tracks.csv (docs/tracks.md), runs the pipeline of `rsfm estimate` with its default
// options (rsfm::estimate, pipeline/estimate.hpp) and prints the focal length and each plane's
// unit normal in the first camera frame, or says what the data do not determine.
#include <cstdio>
#include <exception>

#include "rsfm/io/input_error.hpp"
#include "rsfm/io/tracks_io.hpp"
#include "rsfm/pipeline/estimate.hpp"
#include "rsfm/version.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s TRACKS.csv\n", argv[0]);
    return 2;
  }
  try {
    const rsfm::Tracks tracks = rsfm::io::readTracks(argv[1]);
    const rsfm::EstimateResult r = rsfm::estimate(tracks, rsfm::EstimateOptions{});
    if (!r.online.ok()) {
      std::fprintf(stderr, "the filter stopped: %s\n", r.online.stopped.c_str());
      return 1;
    }
    const rsfm::TrackFilterResult& res = r.main();
    const rsfm::TrackFrame& last = res.frames.back();
    std::printf("rsfm %s: %d frames, %s\n", rsfm::kVersion, static_cast<int>(res.frames.size()),
                r.refined.ok ? "refined" : "online");
    if (r.refined.ok && !r.refined.focal_determined)
      std::printf("focal length: not determined by these tracks\n");
    else
      std::printf("focal length: %.1f px\n", res.scale_px / last.beta);
    for (size_t j = 0; j < last.N.size(); ++j) {
      const rsfm::MetricPlane p = rsfm::metricPlane(last.N[j], last.beta);
      std::printf("plane %zu: normal (%.4f, %.4f, %.4f)\n", j, p.n.x(), p.n.y(), p.n.z());
    }
    return 0;
  } catch (const rsfm::io::InputError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
