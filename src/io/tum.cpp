#include "rsfm/io/tum.hpp"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <ostream>
#include <sstream>
#include <string>

#include "csv_fields.hpp"

namespace rsfm::io {
namespace {

std::string where(const std::filesystem::path& file, long long line) {
  return printable(file.string(), 300) + ":" + std::to_string(line) + ": ";
}

bool parseDouble(const std::string& tok, double* v) {
  if (tok.empty()) return false;
  const char* b = tok.c_str();
  char* e = nullptr;
  *v = std::strtod(b, &e);
  return e == b + tok.size();
}

}  // namespace

std::vector<TumPose> readTum(const std::filesystem::path& file) {
  std::error_code ec;
  if (std::filesystem::is_directory(file, ec)) throw inputError(file, 0, "is a directory, not a trajectory file");
  std::ifstream in(file, std::ios::binary);
  if (!in) throw inputError(file, 0, "cannot open trajectory file");
  return readTum(in, file);
}

std::vector<TumPose> readTum(std::istream& in, const std::filesystem::path& file) {
  static const char* kFields[8] = {"t", "tx", "ty", "tz", "qx", "qy", "qz", "qw"};
  std::vector<TumPose> poses;
  std::string line;
  long long n = 0;
  long long prev_line = 0;
  for (;;) {
    const detail::LineRead r = detail::boundedGetline(in, line);
    if (r == detail::LineRead::kEnd) break;
    ++n;
    if (r == detail::LineRead::kTooLong)
      throw InputError(where(file, n) + fmt::format("line longer than {} bytes: not a TUM trajectory", detail::kMaxLineBytes));
    const auto first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream ss(line);
    std::vector<std::string> tok;
    for (std::string s; ss >> s;) tok.push_back(s);
    if (tok.size() != 8)
      throw InputError(where(file, n) + fmt::format("expected 8 numbers 't tx ty tz qx qy qz qw', got {} field{}",
                                                    tok.size(), tok.size() == 1 ? "" : "s"));
    double v[8];
    for (int i = 0; i < 8; ++i) {
      if (!parseDouble(tok[i], &v[i]))
        throw InputError(where(file, n) + fmt::format("field {} ('{}') is not a number", kFields[i], printable(tok[i], 40)));
      if (!std::isfinite(v[i]))
        throw InputError(where(file, n) + fmt::format("field {} is not finite ({})", kFields[i], printable(tok[i], 40)));
    }
    TumPose p;
    p.t = v[0];
    p.p = Eigen::Vector3d(v[1], v[2], v[3]);
    p.q = Eigen::Quaterniond(v[7], v[4], v[5], v[6]);
    const double norm = p.q.norm();
    if (std::abs(1.0 - norm) > 1e-3)
      throw InputError(where(file, n) + fmt::format("quaternion norm {:.6g} is not 1 (|1 - |q|| > 1e-3)", norm));
    if (std::abs(norm - 1.0) > 1e-12) p.q.normalize();  // a unit q rsfm wrote reads back bit for bit (tests/fuzz)
    if (!poses.empty() && !(p.t > poses.back().t))
      throw InputError(where(file, n) + fmt::format("timestamp {} is not greater than the previous one ({} on line {})",
                                                    printable(tok[0], 40), poses.back().t, prev_line));
    poses.push_back(p);
    prev_line = n;
  }
  if (in.bad()) throw inputError(file, 0, "read error");
  if (poses.empty()) throw InputError(where(file, std::max(n, 1LL)) + "empty trajectory: no pose lines");
  return poses;
}

void writeTum(std::ostream& os, const std::vector<TumPose>& poses) {
  os << "# rsfm TUM trajectory: t tx ty tz qx qy qz qw; t = timestamp (seconds at the source's frame rate from its "
        "time origin, else the frame number; summary.json fps, time_origin_s); p = camera centre in the "
        "reference (frame 0) camera frame (x right, y down, z forward); q = Hamilton rotation "
        "camera -> reference\n";
  for (const TumPose& p : poses) {
    Eigen::Quaterniond q = std::abs(p.q.norm() - 1.0) > 1e-12 ? p.q.normalized() : p.q;
    if (q.w() < 0) q.coeffs() = -q.coeffs();
    // "+ 0.0" turns -0 into 0.
    os << fmt::format("{} {} {} {} {} {} {} {}\n", p.t + 0.0, p.p.x() + 0.0, p.p.y() + 0.0, p.p.z() + 0.0,
                      q.x() + 0.0, q.y() + 0.0, q.z() + 0.0, q.w() + 0.0);
  }
}

}  // namespace rsfm::io
