#include "rsfm/io/tracks_io.hpp"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <vector>

#include "csv_fields.hpp"

namespace rsfm::io {

using detail::parseDouble;
using detail::parseInt;
using detail::split;

void writeTracks(std::ostream& os, const Tracks& t) {
  detail::writeCsvHeader(os, "rsfm-tracks", t.image, t.first_frame, t.numFrames(), t.source);
  os << "frame,track,x,y\n";
  std::string buf;
  for (int k = 0; k < t.numFrames(); ++k)
    for (const auto& p : t.frames[k]) {
      buf.clear();
      // Shortest round-trip text: `rsfm estimate` on a run's tracks.csv gives the run's numbers.
      fmt::format_to(std::back_inserter(buf), "{},{},{},{}\n", t.first_frame + k, p.id, p.px.x(), p.px.y());
      os << buf;
    }
}

std::string tracksToString(const Tracks& t) {
  std::ostringstream os;
  writeTracks(os, t);
  return os.str();
}


Tracks readTracks(std::istream& in, const std::filesystem::path& file) {
  Tracks t;
  detail::CsvHeader head;
  head.magic = "rsfm-tracks";
  double x = 0, y = 0;
  struct Row {
    int frame;
    TrackPoint p;
  };
  std::vector<Row> rows;  // memory follows the rows, not the header's frame range
  detail::readRsfmCsv(
      in, file, head, "frame,track,x,y", 4, "track", [](const std::string&, std::istringstream&, int) {},
      [&](int) {
        t.image = head.image;
        t.first_frame = head.first_frame;
        t.source = head.source;
      },
      [&](const std::vector<std::string_view>& f, int ln) {
        if (!parseDouble(f[2], &x) || !parseDouble(f[3], &y)) throw inputError(file, ln, "x or y is not a number");
        if (!std::isfinite(x) || !std::isfinite(y)) throw inputError(file, ln, "x or y is not finite");
      },
      [&](long long fr, long long id, int ln) {
        if (x < -t.image.width || x > 2.0 * t.image.width || y < -t.image.height || y > 2.0 * t.image.height)
          throw inputError(file, ln, fmt::format("position ({}, {}) far outside the {}x{} image", x, y, t.image.width, t.image.height));
        rows.push_back({static_cast<int>(fr - t.first_frame), {static_cast<int>(id), Eigen::Vector2d(x, y)}});
      });
  t.frames.resize(static_cast<size_t>(head.last_frame - t.first_frame + 1));
  for (const Row& r : rows) t.frames[static_cast<size_t>(r.frame)].push_back(r.p);
  return t;
}

Tracks readTracks(const std::filesystem::path& file) {
  std::ifstream in = detail::openCsv(file, "tracks");
  return readTracks(in, file);
}

}  // namespace rsfm::io
