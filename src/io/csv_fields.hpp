#pragma once
// Field parsing shared by the CSV readers of rsfm/io (internal header).
#include <fmt/format.h>

#include <charconv>
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
  std::ifstream in(file);
  if (!in) throw inputError(file, 0, "cannot be opened");
  return in;
}

/// Writes the shared '#' header lines (the caller adds format-specific ones and the columns).
inline void writeCsvHeader(std::ostream& os, const char* magic, const ImageInfo& image, int first_frame, int frames,
                           std::string source) {
  os << "# " << magic << " 1\n";
  os << fmt::format("# image_size {} {}\n", image.width, image.height);
  os << fmt::format("# principal_point {} {}\n", image.cx, image.cy);
  os << fmt::format("# frames {} {}\n", first_frame, first_frame + frames - 1);
  for (char& c : source)
    if (c == '\n' || c == '\r') c = ' ';
  if (!source.empty()) os << "# source " << source << "\n";
}

/// The '#' header shared by tracks.csv and patches.csv: "# <magic> 1" first, then image_size,
/// principal_point, frames, source (other '#' lines are comments or format-specific keys).
struct CsvHeader {
  std::string magic;  ///< "rsfm-tracks" or "rsfm-patches"
  ImageInfo image;
  int first_frame = 0;
  long long last_frame = 0;
  std::string source;
  bool version = false, size = false, pp = false, frames = false;
  std::string name() const { return magic.substr(magic.find('-') + 1); }  ///< "tracks" / "patches"

  /// Handles one '#' line (text after '#', key already read from `ss`). Returns false when the
  /// key is not one of the shared ones (the caller may handle it). Throws InputError.
  bool parse(const std::string& key, std::istringstream& ss, const std::filesystem::path& file, int ln) {
    if (!version) {
      int v = 0;
      if (key != magic || !(ss >> v))
        throw inputError(file, ln, fmt::format("not an rsfm {} file (first line must be '# {} 1')", name(), magic));
      if (v != 1) throw inputError(file, ln, fmt::format("unsupported {} format version {} (this rsfm reads 1)", name(), v));
      version = true;
    } else if (key == "image_size") {
      if (!(ss >> image.width >> image.height) || image.width <= 0 || image.height <= 0)
        throw inputError(file, ln, "image_size needs two positive integers (width height)");
      size = true;
    } else if (key == "principal_point") {
      if (!(ss >> image.cx >> image.cy) || !std::isfinite(image.cx) || !std::isfinite(image.cy))
        throw inputError(file, ln, "principal_point needs two finite numbers (cx cy)");
      pp = true;
    } else if (key == "frames") {
      long long a = 0, b = 0;
      if (!(ss >> a >> b) || a < 0 || b < a) throw inputError(file, ln, "frames needs first <= last, both >= 0");
      first_frame = static_cast<int>(a);
      last_frame = b;
      frames = true;
    } else if (key == "source") {
      std::getline(ss >> std::ws, source);
    } else {
      return false;
    }
    return true;
  }

  /// At the first non-'#' line: the required keys must have come; defaults the principal point.
  void finish(const std::filesystem::path& file, int ln) {
    if (!version) throw inputError(file, ln, fmt::format("not an rsfm {} file (first line must be '# {} 1')", name(), magic));
    if (!size) throw inputError(file, ln, "missing '# image_size W H' header line");
    if (!frames) throw inputError(file, ln, "missing '# frames FIRST LAST' header line");
    if (!pp) image = ImageInfo::centred(image.width, image.height);
  }
};

/// The reading loop shared by tracks.csv and patches.csv (docs/tracks.md): '#' header lines
/// (the shared keys, then `extra_key(key, stream, line)` for a format's own, which returns false
/// for a comment), `begin(line)` once the header is complete, the column line `columns`, then per
/// row: the field count, the frame and the id (`id_name`: "track" / "patch"), `values(fields,
/// line)` (the format's own fields; throws), the frame within the declared range and rows in
/// frame order with increasing ids, and `store(frame, id)`. Every problem is an InputError
/// "FILE:LINE: ...".
template <class ExtraKey, class Begin, class Values, class Store>
void readRsfmCsv(const std::filesystem::path& file, CsvHeader& head, const std::string& columns, std::size_t fields,
                 const char* id_name, const ExtraKey& extra_key, const Begin& begin, const Values& values,
                 const Store& store) {
  std::ifstream in = openCsv(file, head.name().c_str());
  std::string line;
  int ln = 0;
  bool have_columns = false;
  long long cur_frame = -1, cur_id = -1;
  std::size_t rows = 0;
  while (std::getline(in, line)) {
    ++ln;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) continue;
    if (!have_columns) {
      if (line[0] == '#') {
        std::istringstream ss(line.substr(1));
        std::string key;
        ss >> key;
        if (!key.empty() && !head.parse(key, ss, file, ln)) extra_key(key, ss, ln);  // unknown keys are comments
        continue;
      }
      head.finish(file, ln);
      begin(ln);
      if (line != columns) throw inputError(file, ln, fmt::format("expected the column header '{}', got '{}'", columns, line));
      have_columns = true;
      continue;
    }
    const auto f = split(line, ',');
    if (f.size() != fields) throw inputError(file, ln, fmt::format("expected {} fields ({}), got {}", fields, columns, f.size()));
    long long fr = 0, id = 0;
    if (!parseInt(f[0], &fr)) throw inputError(file, ln, "frame is not an integer");
    if (!parseInt(f[1], &id)) throw inputError(file, ln, fmt::format("{} id is not an integer", id_name));
    values(f, ln);
    if (fr < head.first_frame || fr > head.last_frame)
      throw inputError(file, ln, fmt::format("frame {} outside the declared range {}..{}", fr, head.first_frame, head.last_frame));
    if (id < 0 || id > 100000000) throw inputError(file, ln, fmt::format("{} id {} out of range", id_name, id));
    if (fr < cur_frame) throw inputError(file, ln, fmt::format("frame {} after frame {}: rows must be in frame order", fr, cur_frame));
    if (fr == cur_frame && id <= cur_id)
      throw inputError(file, ln, fmt::format("{} {} repeated or out of order in frame {}", id_name, id, fr));
    cur_frame = fr;
    cur_id = id;
    store(fr, id, ln);
    ++rows;
  }
  if (in.bad()) throw inputError(file, ln, "read error");
  if (!head.version) throw inputError(file, 0, fmt::format("empty file (not an rsfm {} file)", head.name()));
  if (!have_columns) throw inputError(file, ln, fmt::format("no column header '{}'", columns));
  if (rows == 0) throw inputError(file, ln, fmt::format("no {} rows", id_name));
}

}  // namespace rsfm::io::detail
