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
  os << "# rsfm-patches 1\n";
  os << fmt::format("# image_size {} {}\n", t.image.width, t.image.height);
  os << fmt::format("# principal_point {} {}\n", t.image.cx, t.image.cy);
  os << fmt::format("# frames {} {}\n", t.first_frame, t.first_frame + t.numFrames() - 1);
  os << fmt::format("# radius {}\n", t.radius);
  std::string src = t.source;
  for (char& c : src)
    if (c == '\n' || c == '\r') c = ' ';
  if (!src.empty()) os << "# source " << src << "\n";
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
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) throw inputError(file, 0, "no such file");
  if (std::filesystem::is_directory(file, ec)) throw inputError(file, 0, "is a directory, not a patches file");
  std::ifstream in(file);
  if (!in) throw inputError(file, 0, "cannot be opened");
  PatchTracks t;
  std::string line;
  int ln = 0;
  bool version = false, size = false, pp = false, frames = false, radius = false, columns = false;
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
        if (key.empty()) continue;
        if (!version) {
          int v = 0;
          if (key != "rsfm-patches" || !(ss >> v))
            throw inputError(file, ln, "not an rsfm patches file (first line must be '# rsfm-patches 1')");
          if (v != 1) throw inputError(file, ln, fmt::format("unsupported patches format version {} (this rsfm reads 1)", v));
          version = true;
        } else if (key == "image_size") {
          if (!(ss >> t.image.width >> t.image.height) || t.image.width <= 0 || t.image.height <= 0)
            throw inputError(file, ln, "image_size needs two positive integers (width height)");
          size = true;
        } else if (key == "principal_point") {
          if (!(ss >> t.image.cx >> t.image.cy) || !std::isfinite(t.image.cx) || !std::isfinite(t.image.cy))
            throw inputError(file, ln, "principal_point needs two finite numbers (cx cy)");
          pp = true;
        } else if (key == "frames") {
          long long a = 0, b = 0;
          if (!(ss >> a >> b) || a < 0 || b < a) throw inputError(file, ln, "frames needs first <= last, both >= 0");
          t.first_frame = static_cast<int>(a);
          last_frame = b;
          t.frames.resize(static_cast<size_t>(b - a + 1));
          frames = true;
        } else if (key == "radius") {
          if (!(ss >> t.radius) || t.radius < 1) throw inputError(file, ln, "radius needs a positive integer");
          radius = true;
        } else if (key == "source") {
          std::getline(ss >> std::ws, t.source);
        }
        continue;
      }
      if (!version) throw inputError(file, ln, "not an rsfm patches file (first line must be '# rsfm-patches 1')");
      if (!size) throw inputError(file, ln, "missing '# image_size W H' header line");
      if (!frames) throw inputError(file, ln, "missing '# frames FIRST LAST' header line");
      if (!radius) throw inputError(file, ln, "missing '# radius R' header line");
      if (!pp) {
        t.image.cx = (t.image.width - 1) / 2.0;
        t.image.cy = (t.image.height - 1) / 2.0;
      }
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
  if (!version) throw inputError(file, 0, "empty file (not an rsfm patches file)");
  if (!columns) throw inputError(file, ln, fmt::format("no column header '{}'", kColumns));
  if (rows == 0) throw inputError(file, ln, "no patch rows");
  return t;
}

}  // namespace rsfm::io
