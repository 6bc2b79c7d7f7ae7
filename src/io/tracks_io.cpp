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
      fmt::format_to(std::back_inserter(buf), "{},{},{:.4f},{:.4f}\n", t.first_frame + k, p.id, p.px.x(), p.px.y());
      os << buf;
    }
}

std::string tracksToString(const Tracks& t) {
  std::ostringstream os;
  writeTracks(os, t);
  return os.str();
}


Tracks readTracks(const std::filesystem::path& file) {
  std::ifstream in = detail::openCsv(file, "tracks");
  Tracks t;
  std::string line;
  int ln = 0;
  detail::CsvHeader head;
  head.magic = "rsfm-tracks";
  bool columns = false;
  long long last_frame = 0;
  long long cur_frame = -1, cur_id = -1;
  size_t rows = 0;
  while (std::getline(in, line)) {
    ++ln;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    if (!columns) {
      if (line[0] == '#') {
        std::istringstream ss(line.substr(1));
        std::string key;
        ss >> key;
        if (!key.empty()) head.parse(key, ss, file, ln);  // other '#' lines are comments
        continue;
      }
      head.finish(file, ln);
      t.image = head.image;
      t.first_frame = head.first_frame;
      t.source = head.source;
      last_frame = head.last_frame;
      t.frames.resize(static_cast<size_t>(last_frame - t.first_frame + 1));
      if (line != "frame,track,x,y")
        throw inputError(file, ln, "expected the column header 'frame,track,x,y', got '" + line + "'");
      columns = true;
      continue;
    }
    const auto f = split(line, ',');
    if (f.size() != 4) throw inputError(file, ln, fmt::format("expected 4 fields (frame,track,x,y), got {}", f.size()));
    long long fr = 0, id = 0;
    double x = 0, y = 0;
    if (!parseInt(f[0], &fr)) throw inputError(file, ln, "frame is not an integer");
    if (!parseInt(f[1], &id)) throw inputError(file, ln, "track id is not an integer");
    if (!parseDouble(f[2], &x) || !parseDouble(f[3], &y)) throw inputError(file, ln, "x or y is not a number");
    if (!std::isfinite(x) || !std::isfinite(y)) throw inputError(file, ln, "x or y is not finite");
    if (fr < t.first_frame || fr > last_frame)
      throw inputError(file, ln, fmt::format("frame {} outside the declared range {}..{}", fr, t.first_frame, last_frame));
    if (id < 0 || id > 100000000) throw inputError(file, ln, fmt::format("track id {} out of range", id));
    if (fr < cur_frame) throw inputError(file, ln, fmt::format("frame {} after frame {}: rows must be in frame order", fr, cur_frame));
    if (fr == cur_frame && id <= cur_id)
      throw inputError(file, ln, fmt::format("track {} repeated or out of order in frame {}", id, fr));
    if (x < -t.image.width || x > 2.0 * t.image.width || y < -t.image.height || y > 2.0 * t.image.height)
      throw inputError(file, ln, fmt::format("position ({}, {}) far outside the {}x{} image", x, y, t.image.width, t.image.height));
    cur_frame = fr;
    cur_id = id;
    t.frames[static_cast<size_t>(fr - t.first_frame)].push_back({static_cast<int>(id), Eigen::Vector2d(x, y)});
    ++rows;
  }
  if (in.bad()) throw inputError(file, ln, "read error");
  if (!head.version) throw inputError(file, 0, "empty file (not an rsfm tracks file)");
  if (!columns) throw inputError(file, ln, "no column header 'frame,track,x,y'");
  if (rows == 0) throw inputError(file, ln, "no track rows");
  return t;
}

}  // namespace rsfm::io
