#include "rsfm/io/patches_io.hpp"

#include <fmt/format.h>

#include <Eigen/LU>
#include <charconv>
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
  // The warp's translation is derived from the values as written (rounded to 1e-4 px and 1e-7),
  // so that reading the file back and writing it again gives the same text (tests/fuzz).
  auto written = [](double v, int decimals) {
    char s[64];
    const auto r = std::to_chars(s, s + sizeof s, v, std::chars_format::fixed, decimals);
    double back = v;
    std::from_chars(s, r.ptr, back);
    return back;
  };
  for (int k = 0; k < t.numFrames(); ++k)
    for (const auto& p : t.frames[k]) {
      const Eigen::Vector2d q0(written(p.px0.x(), 4), written(p.px0.y(), 4)), q(written(p.px.x(), 4), written(p.px.y(), 4));
      Eigen::Matrix2d A;
      A << written(p.A(0, 0), 7), written(p.A(0, 1), 7), written(p.A(1, 0), 7), written(p.A(1, 1), 7);
      const Eigen::Vector2d tr = q - A * q0;
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

PatchTracks readPatches(std::istream& in, const std::filesystem::path& file) {
  PatchTracks t;
  std::vector<std::pair<int, PatchObservation>> rows;  // memory follows the rows, not the header
  detail::CsvHeader head;
  head.magic = "rsfm-patches";
  bool radius = false;
  std::map<long long, Eigen::Vector2d> first_centre;
  double v[11];
  detail::readRsfmCsv(
      in, file, head, kColumns, 13, "patch",
      [&](const std::string& key, std::istringstream& ss, int ln) {
        if (key != "radius") return;
        std::array<long long, 1> r{};
        if (!detail::headerNumbers(ss, &r) || r[0] < 1 || r[0] > detail::kMaxImageSide)
          throw inputError(file, ln, "radius needs a positive integer (px)");
        t.radius = static_cast<int>(r[0]);
        radius = true;
      },
      [&](int ln) {
        if (!radius) throw inputError(file, ln, "missing '# radius R' header line");
        if (2 * t.radius + 1 > std::max(head.image.width, head.image.height))
          throw inputError(file, ln, fmt::format("radius {} px: a patch wider than the {}x{} image", t.radius, head.image.width,
                                                 head.image.height));
        t.image = head.image;
        t.first_frame = head.first_frame;
        t.source = head.source;
      },
      [&](const std::vector<std::string_view>& f, int ln) {
        static const char* names[11] = {"x0", "y0", "x", "y", "a11", "a12", "a21", "a22", "tx", "ty", "rms"};
        for (int j = 0; j < 11; ++j) {
          if (!parseDouble(f[2 + j], &v[j])) throw inputError(file, ln, fmt::format("{} is not a number", names[j]));
          if (!std::isfinite(v[j])) throw inputError(file, ln, fmt::format("{} is not finite", names[j]));
        }
      },
      [&](long long fr, long long id, int ln) {
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
        rows.emplace_back(static_cast<int>(fr - t.first_frame), p);
      });
  t.frames.resize(static_cast<size_t>(head.last_frame - t.first_frame + 1));
  for (const auto& [k, p] : rows) t.frames[static_cast<size_t>(k)].push_back(p);
  return t;
}

PatchTracks readPatches(const std::filesystem::path& file) {
  std::ifstream in = detail::openCsv(file, "patches");
  return readPatches(in, file);
}

}  // namespace rsfm::io
