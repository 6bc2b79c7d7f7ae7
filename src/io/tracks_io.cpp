#include "rsfm/io/tracks_io.hpp"

#include <fmt/format.h>

#include <algorithm>
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

namespace {
/// '# dropped_frames' stretches per line (the reader's lines are at most 8192 bytes).
constexpr int kDroppedStretchesPerLine = 200;
}  // namespace

std::string droppedFramesLines(const std::vector<std::array<int, 2>>& stretches) {
  std::string out;
  for (std::size_t i = 0; i < stretches.size(); ++i) {
    if (i % kDroppedStretchesPerLine == 0) out += i == 0 ? "# dropped_frames" : "\n# dropped_frames";
    const auto [a, b] = stretches[i];
    out += a == b ? fmt::format(" {}", a) : fmt::format(" {}-{}", a, b);
  }
  if (!out.empty()) out += "\n";
  return out;
}

void writeTracks(std::ostream& os, const Tracks& t) {
  const int n = t.numFrames();
  const int first = n > 0 ? t.frameNumber(0) : t.first_frame;
  const int last = n > 0 ? t.frameNumber(n - 1) : t.first_frame - 1;
  detail::writeCsvHeader(os, "rsfm-tracks", t.image, first, last - first + 1, t.source);
  os << droppedFramesLines(t.skippedStretches());  // a video's dropped frames
  os << "frame,track,x,y\n";
  std::string buf;
  for (int k = 0; k < n; ++k)
    for (const auto& p : t.frames[k]) {
      buf.clear();
      // Shortest round-trip text: `rsfm estimate` on a run's tracks.csv gives the run's numbers.
      fmt::format_to(std::back_inserter(buf), "{},{},{},{}\n", t.frameNumber(k), p.id, p.px.x(), p.px.y());
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
    int line;
  };
  std::vector<Row> rows;  // memory follows the rows, not the header's frame range
  struct Dropped {
    long long a, b;
    int line;
  };
  std::vector<Dropped> dropped;  // '# dropped_frames' stretches
  detail::readRsfmCsv(
      in, file, head, "frame,track,x,y", 4, "track",
      [&](const std::string& key, std::istringstream& ss, int ln) {
        if (key != "dropped_frames") return;  // other keys are comments
        auto bad = [&] { return inputError(file, ln, "dropped_frames needs frame numbers N or stretches A-B (A <= B)"); };
        std::string tok;
        bool any = false;
        while (ss >> tok) {
          const auto dash = tok.find('-', 1);
          long long a = 0, b = 0;
          const bool ok = dash == std::string::npos
                              ? detail::parseInt(tok, &a) && (b = a, true)
                              : detail::parseInt(std::string_view(tok).substr(0, dash), &a) &&
                                    detail::parseInt(std::string_view(tok).substr(dash + 1), &b);
          if (!ok || a < 0 || b < a) throw bad();
          dropped.push_back({a, b, ln});
          head.has_absent_frames = true;
          any = true;
        }
        if (!any) throw bad();
      },
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
        rows.push_back({static_cast<int>(fr - t.first_frame), {static_cast<int>(id), Eigen::Vector2d(x, y)}, ln});
      });
  const long long range = head.last_frame - t.first_frame + 1;
  if (dropped.empty()) {
    t.frames.resize(static_cast<size_t>(range));
    for (const Row& r : rows) t.frames[static_cast<size_t>(r.frame)].push_back(r.p);
    return t;
  }
  // Frames the video dropped: absent from the tracks (frame_numbers skips them). The stretches
  // merged (memory and time follow the rows and the stretches, not the range).
  for (const Dropped& d : dropped)
    if (d.a <= t.first_frame || d.b >= head.last_frame)
      throw inputError(file, d.line,
                       fmt::format("dropped frames {}-{} are not inside the frame range's ends ({} {})", d.a, d.b,
                                   t.first_frame, head.last_frame));
  std::sort(dropped.begin(), dropped.end(), [](const Dropped& x, const Dropped& y) { return x.a < y.a; });
  std::vector<Dropped> merged;
  for (const Dropped& d : dropped)
    if (!merged.empty() && d.a <= merged.back().b + 1) merged.back().b = std::max(merged.back().b, d.b);
    else merged.push_back(d);
  long long absent = 0;
  for (const Dropped& d : merged) absent += d.b - d.a + 1;
  if (range - absent > static_cast<long long>(rows.size()))
    throw inputError(file, 0, fmt::format("the header declares {} frames ({}..{}, {} of them dropped) but the file has only {} "
                                          "row{}: most frames would be empty (a wrong '# frames' line?)",
                                          range, t.first_frame, head.last_frame, absent, rows.size(), rows.size() == 1 ? "" : "s"));
  long long f = t.first_frame;
  for (const Dropped& d : merged) {
    for (; f < d.a; ++f) t.frame_numbers.push_back(static_cast<int>(f));
    f = d.b + 1;
  }
  for (; f <= head.last_frame; ++f) t.frame_numbers.push_back(static_cast<int>(f));
  t.frames.resize(t.frame_numbers.size());
  std::size_t k = 0;  // rows come in ascending frame order
  for (const Row& r : rows) {
    const int fr = t.first_frame + r.frame;
    while (k < t.frame_numbers.size() && t.frame_numbers[k] < fr) ++k;
    if (k == t.frame_numbers.size() || t.frame_numbers[k] != fr)
      throw inputError(file, r.line, fmt::format("frame {} is listed in dropped_frames", fr));
    t.frames[k].push_back(r.p);
  }
  return t;
}

Tracks readTracks(const std::filesystem::path& file) {
  std::ifstream in = detail::openCsv(file, "tracks");
  return readTracks(in, file);
}

}  // namespace rsfm::io
