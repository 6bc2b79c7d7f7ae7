#include "rsfm/io/patches_io.hpp"

#include <fmt/format.h>

#include <Eigen/LU>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

#include "csv_fields.hpp"

namespace rsfm::io {

using detail::parseDouble;
using detail::parseInt;
using detail::split;

namespace {
constexpr const char* kColumns = "frame,patch,x0,y0,x,y,a11,a12,a21,a22,tx,ty,rms";
}

void writePatches(std::ostream& os, const PatchTracks& t) {
  detail::writeCsvHeader(os, "rsfm-patches", t.image, t.first_frame, t.numFrames(), t.source);
  os << fmt::format("# radius {}\n", t.radius);
  os << kColumns << "\n";
  std::string buf;
  for (int k = 0; k < t.numFrames(); ++k)
    for (const auto& p : t.frames[k]) {
      const Eigen::Vector2d tr = p.translation();
      buf.clear();
      fmt::format_to(std::back_inserter(buf), "{},{},{:.4f},{:.4f},{:.4f},{:.4f},{:.7f},{:.7f},{:.7f},{:.7f},{:.4f},{:.4f},{:.4f}\n",
                     t.first_frame + k, p.id, p.px0.x(), p.px0.y(), p.px.x(), p.px.y(), p.A(0, 0), p.A(0, 1), p.A(1, 0),
                     p.A(1, 1), tr.x(), tr.y(), p.rms);
      os << buf;
    }
}

std::string patchesToString(const PatchTracks& t) {
  std::ostringstream os;
  writePatches(os, t);
  return os.str();
}

PatchTracks readPatches(const std::filesystem::path& file) {
  std::ifstream in = detail::openCsv(file, "patches");
  PatchTracks t;
  std::string line;
  int ln = 0;
  detail::CsvHeader head;
  head.magic = "rsfm-patches";
  bool radius = false, columns = false;
  long long last_frame = 0, cur_frame = -1, cur_id = -1;
  size_t rows = 0;
  std::map<long long, Eigen::Vector2d> first_centre;
  while (std::getline(in, line)) {
    ++ln;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    if (!columns) {
      if (line[0] == '#') {
        std::istringstream ss(line.substr(1));
        std::string key;
        ss >> key;
        if (key.empty() || head.parse(key, ss, file, ln)) continue;
        if (key == "radius") {
          if (!(ss >> t.radius) || t.radius < 1) throw inputError(file, ln, "radius needs a positive integer");
          radius = true;
        }
        continue;
      }
      head.finish(file, ln);
      if (!radius) throw inputError(file, ln, "missing '# radius R' header line");
      t.image = head.image;
      t.first_frame = head.first_frame;
      t.source = head.source;
      last_frame = head.last_frame;
      t.frames.resize(static_cast<size_t>(last_frame - t.first_frame + 1));
      if (line != kColumns) throw inputError(file, ln, fmt::format("expected the column header '{}', got '{}'", kColumns, line));
      columns = true;
      continue;
    }
    const auto f = split(line, ',');
    if (f.size() != 13) throw inputError(file, ln, fmt::format("expected 13 fields ({}), got {}", kColumns, f.size()));
    long long fr = 0, id = 0;
    if (!parseInt(f[0], &fr)) throw inputError(file, ln, "frame is not an integer");
    if (!parseInt(f[1], &id)) throw inputError(file, ln, "patch id is not an integer");
    double v[11];
    static const char* names[11] = {"x0", "y0", "x", "y", "a11", "a12", "a21", "a22", "tx", "ty", "rms"};
    for (int j = 0; j < 11; ++j) {
      if (!parseDouble(f[2 + j], &v[j])) throw inputError(file, ln, fmt::format("{} is not a number", names[j]));
      if (!std::isfinite(v[j])) throw inputError(file, ln, fmt::format("{} is not finite", names[j]));
    }
    if (fr < t.first_frame || fr > last_frame)
      throw inputError(file, ln, fmt::format("frame {} outside the declared range {}..{}", fr, t.first_frame, last_frame));
    if (id < 0 || id > 100000000) throw inputError(file, ln, fmt::format("patch id {} out of range", id));
    if (fr < cur_frame) throw inputError(file, ln, fmt::format("frame {} after frame {}: rows must be in frame order", fr, cur_frame));
    if (fr == cur_frame && id <= cur_id)
      throw inputError(file, ln, fmt::format("patch {} repeated or out of order in frame {}", id, fr));
    PatchObservation p;
    p.id = static_cast<int>(id);
    p.px0 = {v[0], v[1]};
    p.px = {v[2], v[3]};
    p.A << v[4], v[5], v[6], v[7];
    p.rms = v[10];
    for (const Eigen::Vector2d& q : {p.px0, p.px})
      if (q.x() < -t.image.width || q.x() > 2.0 * t.image.width || q.y() < -t.image.height || q.y() > 2.0 * t.image.height)
        throw inputError(file, ln, fmt::format("position ({}, {}) far outside the {}x{} image", q.x(), q.y(), t.image.width,
                                               t.image.height));
    if (!(p.A.determinant() > 0.0)) throw inputError(file, ln, "the affine map A has a non-positive determinant");
    auto [it, fresh] = first_centre.emplace(id, p.px0);
    if (!fresh && (it->second - p.px0).norm() > 1e-3)
      throw inputError(file, ln, fmt::format("patch {}'s first-frame centre changed", id));
    if ((p.translation() - Eigen::Vector2d(v[8], v[9])).norm() > 0.01)
      throw inputError(file, ln, "tx, ty disagree with (x, y) - A (x0, y0)");
    cur_frame = fr;
    cur_id = id;
    t.frames[static_cast<size_t>(fr - t.first_frame)].push_back(p);
    ++rows;
  }
  if (in.bad()) throw inputError(file, ln, "read error");
  if (!head.version) throw inputError(file, 0, "empty file (not an rsfm patches file)");
  if (!columns) throw inputError(file, ln, fmt::format("no column header '{}'", kColumns));
  if (rows == 0) throw inputError(file, ln, "no patch rows");
  return t;
}

}  // namespace rsfm::io
