#pragma once
// Field parsing shared by the CSV readers of rsfm/io (internal header).
#include <fmt/format.h>

#include <array>
#include <charconv>
#include <limits>
#include <type_traits>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <ostream>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "rsfm/io/input_error.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm::io::detail {

inline bool parseInt(std::string_view s, long long* v) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\r')) s.remove_suffix(1);
  if (s.empty()) return false;
  auto r = std::from_chars(s.data(), s.data() + s.size(), *v);
  return r.ec == std::errc() && r.ptr == s.data() + s.size();
}

inline bool parseDouble(std::string_view s, double* v) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\r')) s.remove_suffix(1);
  if (s.empty()) return false;
  auto r = std::from_chars(s.data(), s.data() + s.size(), *v);
  return r.ec == std::errc() && r.ptr == s.data() + s.size();
}

inline std::vector<std::string_view> split(std::string_view s, char sep) {
  std::vector<std::string_view> out;
  size_t b = 0;
  for (size_t i = 0; i <= s.size(); ++i)
    if (i == s.size() || s[i] == sep) {
      out.push_back(s.substr(b, i - b));
      b = i + 1;
    }
  return out;
}


/// Opens a tracks/patches file for reading; InputError when missing, a directory or unreadable.
inline std::ifstream openCsv(const std::filesystem::path& file, const char* what) {
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) throw inputError(file, 0, "no such file");
  if (std::filesystem::is_directory(file, ec)) throw inputError(file, 0, fmt::format("is a directory, not a {} file", what));
  std::ifstream in(file, std::ios::binary);
  if (!in) throw inputError(file, 0, "cannot be opened");
  return in;
}

/// The longest line a reader accepts (bytes, without the newline). The longest legitimate line
/// of rsfm's text formats is a '# source PATH' header, and a path is at most PATH_MAX = 4096
/// bytes; anything longer is not one of these files (issue 17: /dev/zero grew without bound).
inline constexpr std::size_t kMaxLineBytes = 8192;

enum class LineRead { kLine, kEnd, kTooLong };

/// std::getline with a length limit: reads up to '\n' (dropped, as is a '\r' before it) into
/// `line`; kTooLong as soon as the line exceeds `max_bytes` (the rest is not read).
inline LineRead boundedGetline(std::istream& in, std::string& line, std::size_t max_bytes = kMaxLineBytes) {
  line.clear();
  std::streambuf* sb = in.rdbuf();
  if (!sb) return LineRead::kEnd;
  bool any = false;
  for (;;) {
    const int c = sb->sbumpc();
    if (c == std::char_traits<char>::eof()) {
      in.setstate(std::ios::eofbit);
      if (!line.empty() && line.back() == '\r') line.pop_back();
      return any ? LineRead::kLine : LineRead::kEnd;
    }
    any = true;
    if (c == '\n') break;
    if (line.size() >= max_bytes) return LineRead::kTooLong;
    line.push_back(static_cast<char>(c));
  }
  if (!line.empty() && line.back() == '\r') line.pop_back();
  return LineRead::kLine;
}

/// Image sizes a header may declare: at most 2^20 px a side and 2^30 px in all, OpenCV's own
/// limits for an image it decodes (CV_IO_MAX_IMAGE_WIDTH/HEIGHT/PIXELS): no video rsfm can
/// track is larger (issue 17: image_size 1e8 1e8 was accepted).
inline constexpr long long kMaxImageSide = 1LL << 20;
inline constexpr long long kMaxImagePixels = 1LL << 30;

/// Frame numbers are int end to end (tracks, filters, TUM timestamps): larger ones are refused.
inline constexpr long long kMaxFrame = std::numeric_limits<int>::max();

/// The numbers of a '#' header line after its key: exactly `n` of them, nothing after.
template <class T, std::size_t n>
bool headerNumbers(std::istringstream& ss, std::array<T, n>* out) {
  std::string tok;
  for (std::size_t i = 0; i < n; ++i) {
    if (!(ss >> tok)) return false;
    bool ok;
    if constexpr (std::is_integral_v<T>) {
      long long v = 0;
      ok = parseInt(tok, &v);
      (*out)[i] = static_cast<T>(v);
    } else {
      double v = 0;
      ok = parseDouble(tok, &v) && std::isfinite(v);
      (*out)[i] = v;
    }
    if (!ok) return false;
  }
  return !(ss >> tok);
}

/// Writes the shared '#' header lines (the caller adds format-specific ones and the columns).
inline void writeCsvHeader(std::ostream& os, const char* magic, const ImageInfo& image, int first_frame, int frames,
                           std::string source) {
  os << "# " << magic << " 1\n";
  os << fmt::format("# image_size {} {}\n", image.width, image.height);
  os << fmt::format("# principal_point {} {}\n", image.cx, image.cy);
  if (image.fps > 0) os << fmt::format("# fps {}\n", image.fps);
  if (image.fps > 0 && image.time_origin != 0) os << fmt::format("# time_origin {}\n", image.time_origin);
  if (image.readout_direction != ReadoutDirection::Down)
    os << "# readout_direction " << readoutDirectionName(image.readout_direction) << "\n";
  os << fmt::format("# frames {} {}\n", first_frame, first_frame + frames - 1);
  for (char& c : source)
    if (c == '\n' || c == '\r') c = ' ';
  if (!source.empty()) os << "# source " << source << "\n";
}

/// The '#' header shared by tracks.csv and patches.csv: "# <magic> 1" first, then image_size,
/// principal_point, optional fps and readout_direction, frames, source (other '#' lines are comments or format-specific keys).
struct CsvHeader {
  std::string magic;  ///< "rsfm-tracks" or "rsfm-patches"
  ImageInfo image;
  int first_frame = 0;
  long long last_frame = 0;
  std::string source;
  bool version = false, size = false, pp = false, frames = false;
  int time_origin_line = 0;  ///< the '# time_origin' line (0: none), checked against '# fps' at the end
  /// Frames of the range the file says are absent (tracks.csv's '# dropped_frames'): the reader
  /// that set it checks the range against the rows itself, net of them.
  bool has_absent_frames = false;
  std::string name() const { return magic.substr(magic.find('-') + 1); }  ///< "tracks" / "patches"

  /// Handles one '#' line (text after '#', key already read from `ss`). Returns false when the
  /// key is not one of the shared ones (the caller may handle it). Throws InputError.
  bool parse(const std::string& key, std::istringstream& ss, const std::filesystem::path& file, int ln) {
    if (!version) {
      std::array<long long, 1> v{};
      if (key != magic || !headerNumbers(ss, &v))
        throw inputError(file, ln, fmt::format("not an rsfm {} file (first line must be '# {} 1')", name(), magic));
      if (v[0] != 1) throw inputError(file, ln, fmt::format("unsupported {} format version {} (this rsfm reads 1)", name(), v[0]));
      version = true;
    } else if (key == "image_size") {
      std::array<long long, 2> v{};
      if (!headerNumbers(ss, &v) || v[0] <= 0 || v[1] <= 0)
        throw inputError(file, ln, "image_size needs two positive integers (width height)");
      if (v[0] > kMaxImageSide || v[1] > kMaxImageSide || v[0] * v[1] > kMaxImagePixels)
        throw inputError(file, ln, fmt::format("image_size {}x{} is larger than any image OpenCV decodes (2^20 px a side, "
                                               "2^30 px in all)", v[0], v[1]));
      image.width = static_cast<int>(v[0]);
      image.height = static_cast<int>(v[1]);
      size = true;
    } else if (key == "principal_point") {
      std::array<double, 2> v{};
      if (!headerNumbers(ss, &v)) throw inputError(file, ln, "principal_point needs two finite numbers (cx cy)");
      image.cx = v[0];
      image.cy = v[1];
      pp = true;
    } else if (key == "frames") {
      std::array<long long, 2> v{};
      if (!headerNumbers(ss, &v) || v[0] < 0 || v[1] < v[0])
        throw inputError(file, ln, "frames needs two integers FIRST <= LAST, both >= 0");
      if (v[1] > kMaxFrame)
        throw inputError(file, ln, fmt::format("frame numbers above {} are not supported (got {})", kMaxFrame, v[1]));
      first_frame = static_cast<int>(v[0]);
      last_frame = v[1];
      frames = true;
    } else if (key == "fps") {
      std::array<double, 1> v{};
      if (!headerNumbers(ss, &v) || !(v[0] > 0) || v[0] > ImageInfo::kMaxFps)
        throw inputError(file, ln, fmt::format("fps needs one number above 0 and at most {} (frames per second)",
                                               ImageInfo::kMaxFps));
      image.fps = v[0];
    } else if (key == "time_origin") {
      std::array<double, 1> v{};
      if (!headerNumbers(ss, &v) || v[0] < 0 || v[0] > ImageInfo::kMaxTimeOrigin)
        throw inputError(file, ln, fmt::format("time_origin needs one number from 0 to {:g} (seconds of frame 0)",
                                               ImageInfo::kMaxTimeOrigin));
      image.time_origin = v[0];
      time_origin_line = ln;
    } else if (key == "readout_direction") {
      std::string name, extra;
      if (!(ss >> name) || (ss >> extra) || !parseReadoutDirection(name, &image.readout_direction))
        throw inputError(file, ln, "readout_direction needs one of down, up, right, left");
    } else if (key == "source") {
      std::getline(ss >> std::ws, source);
    } else {
      return false;
    }
    return true;
  }

  /// At the first non-'#' line: the required keys must have come; defaults the principal point.
  void finish(const std::filesystem::path& file, int ln) {
    if (pp && (std::abs(image.cx) > 2.0 * kMaxImageSide || std::abs(image.cy) > 2.0 * kMaxImageSide))
      throw inputError(file, ln, fmt::format("principal_point ({}, {}) is far outside any image", image.cx, image.cy));
    if (!version) throw inputError(file, ln, fmt::format("not an rsfm {} file (first line must be '# {} 1')", name(), magic));
    if (!size) throw inputError(file, ln, "missing '# image_size W H' header line");
    if (!frames) throw inputError(file, ln, "missing '# frames FIRST LAST' header line");
    if (time_origin_line > 0 && !(image.fps > 0))
      throw inputError(file, time_origin_line, "time_origin needs '# fps' (timestamps in seconds from it)");
    if (!pp) {
      image.cx = (image.width - 1) / 2.0;
      image.cy = (image.height - 1) / 2.0;
    }
  }
};

/// The reading loop shared by tracks.csv and patches.csv (docs/tracks.md), on `in` (named `file`
/// in messages): '#' header lines (the shared keys, then `extra_key(key, stream, line)` for a
/// format's own, which returns false for a comment), `begin(line)` once the header is complete,
/// the column line `columns`, then per row: the field count, the frame and the id (`id_name`:
/// "track" / "patch"), `values(fields, line)` (the format's own fields; throws), the frame within
/// the declared range and rows in frame order with increasing ids, and `store(frame, id, line)`.
/// After the last row, the limits that follow from the data present (issue 17): the declared
/// frame range may not exceed the number of rows (memory follows the file, not its header), and
/// ids stay below max(2^20, 16 x rows). Every problem is an InputError "FILE:LINE: ...".
template <class ExtraKey, class Begin, class Values, class Store>
void readRsfmCsv(std::istream& in, const std::filesystem::path& file, CsvHeader& head, const std::string& columns,
                 std::size_t fields, const char* id_name, const ExtraKey& extra_key, const Begin& begin, const Values& values,
                 const Store& store) {
  std::string line;
  long long ln = 0;
  bool have_columns = false;
  long long cur_frame = -1, cur_id = -1, max_id = -1, max_id_line = 0;
  long long rows = 0;
  for (;;) {
    const LineRead r = boundedGetline(in, line);
    if (r == LineRead::kEnd) break;
    ++ln;
    if (ln > std::numeric_limits<int>::max()) throw inputError(file, ln, "more lines than this reader counts (2^31)");
    if (r == LineRead::kTooLong)
      throw inputError(file, ln, fmt::format("line longer than {} bytes: not an rsfm {} file", kMaxLineBytes, head.name()));
    if (line.empty()) continue;
    if (!have_columns) {
      if (line[0] == '#') {
        std::istringstream ss(line.substr(1));
        std::string key;
        ss >> key;
        if (!key.empty() && !head.parse(key, ss, file, static_cast<int>(ln)))
          extra_key(key, ss, static_cast<int>(ln));  // unknown keys are comments
        continue;
      }
      head.finish(file, static_cast<int>(ln));
      begin(static_cast<int>(ln));
      if (line != columns)
        throw inputError(file, ln, fmt::format("expected the column header '{}', got '{}'", columns, printable(line)));
      have_columns = true;
      continue;
    }
    const auto f = split(line, ',');
    if (f.size() != fields) throw inputError(file, ln, fmt::format("expected {} fields ({}), got {}", fields, columns, f.size()));
    long long fr = 0, id = 0;
    if (!parseInt(f[0], &fr)) throw inputError(file, ln, "frame is not an integer");
    if (!parseInt(f[1], &id)) throw inputError(file, ln, fmt::format("{} id is not an integer", id_name));
    values(f, static_cast<int>(ln));
    if (fr < head.first_frame || fr > head.last_frame)
      throw inputError(file, ln, fmt::format("frame {} outside the declared range {}..{}", fr, head.first_frame, head.last_frame));
    if (id < 0 || id > std::numeric_limits<int>::max() - 1) throw inputError(file, ln, fmt::format("{} id {} out of range", id_name, id));
    if (fr < cur_frame) throw inputError(file, ln, fmt::format("frame {} after frame {}: rows must be in frame order", fr, cur_frame));
    if (fr == cur_frame && id <= cur_id)
      throw inputError(file, ln, fmt::format("{} {} repeated or out of order in frame {}", id_name, id, fr));
    cur_frame = fr;
    cur_id = id;
    if (id > max_id) {
      max_id = id;
      max_id_line = ln;
    }
    store(fr, id, static_cast<int>(ln));
    ++rows;
  }
  if (in.bad()) throw inputError(file, ln, "read error");
  if (!head.version) throw inputError(file, 0, fmt::format("empty file (not an rsfm {} file)", head.name()));
  if (!have_columns) throw inputError(file, ln, fmt::format("no column header '{}'", columns));
  if (rows == 0) throw inputError(file, ln, fmt::format("no {} rows", id_name));
  const long long declared = head.last_frame - head.first_frame + 1;
  if (declared > rows && !head.has_absent_frames)
    throw inputError(file, 0, fmt::format("the header declares {} frames ({}..{}) but the file has only {} row{}: most frames "
                                          "would be empty (a wrong '# frames' line?)",
                                          declared, head.first_frame, head.last_frame, rows, rows == 1 ? "" : "s"));
  const long long id_limit = std::max<long long>(1LL << 20, 16 * rows);
  if (max_id >= id_limit)
    throw inputError(file, max_id_line, fmt::format("{} id {} too large for a file of {} rows (ids must stay below "
                                                    "max(2^20, 16 x rows) = {})", id_name, max_id, rows, id_limit));
}

}  // namespace rsfm::io::detail
