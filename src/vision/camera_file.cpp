#include "rsfm/vision/camera_file.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <string_view>
#include <vector>
#include <cctype>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "rsfm/io/input_error.hpp"

namespace rsfm::vision {

bool CameraCalibration::distorted() const {
  return std::any_of(distortion.begin(), distortion.end(), [](double d) { return d != 0.0; });
}

namespace {

[[noreturn]] void bad(const std::filesystem::path& f, const std::string& m) { throw io::InputError(f.string() + ": " + m); }

cv::Mat matrixNode(const cv::FileStorage& fs, const char* name, const std::filesystem::path& f) {
  const cv::FileNode n = fs[name];
  if (n.empty()) bad(f, fmt::format("missing node \"{}\"", name));
  // The declared size first: OpenCV allocates rows x cols before it reads the data (tests/fuzz:
  // a 48 GB allocation). rsfm's matrices have at most 14 entries.
  const cv::FileNode r = n["rows"], c = n["cols"];
  if (!n.isMap() || !r.isInt() || !c.isInt() || static_cast<int>(r) < 1 || static_cast<int>(c) < 1 ||
      static_cast<long long>(static_cast<int>(r)) * static_cast<int>(c) > 16)
    bad(f, fmt::format("\"{}\" is not a small matrix (an opencv-matrix with rows, cols and data)", name));
  cv::Mat m;
  try {
    n >> m;
  } catch (const cv::Exception&) {
    bad(f, fmt::format("\"{}\" is not a matrix", name));
  }
  if (m.empty()) bad(f, fmt::format("\"{}\" is not a matrix", name));
  m.convertTo(m, CV_64F);
  return m;
}

double realNode(const cv::FileStorage& fs, const char* name, const std::filesystem::path& f) {
  const cv::FileNode n = fs[name];
  if (n.empty() || !(n.isInt() || n.isReal())) bad(f, fmt::format("missing or non-numeric node \"{}\"", name));
  return static_cast<double>(n);
}

/// An image side: an integer from 1 to 65536 (`what` names it in the message).
int positiveSide(double v, const std::string& what, const std::filesystem::path& f) {
  if (!(v >= 1 && v <= 65536) || v != std::floor(v)) bad(f, fmt::format("{} must be a positive integer, got {}", what, v));
  return static_cast<int>(v);
}

int intNode(const cv::FileStorage& fs, const char* name, const std::filesystem::path& f) {
  return positiveSide(realNode(fs, name, f), fmt::format("\"{}\"", name), f);
}

CameraCalibration fromStorage(const cv::FileStorage& fs, const std::filesystem::path& file);

/// The camera matrix's entries (row by row) into `c`, checked: positive, square pixels within
/// 1 %, no skew, the principal point inside the image (c's size set before).
void setCameraMatrix(CameraCalibration* c, const std::array<double, 9>& k, const std::string& what, const std::filesystem::path& file) {
  for (double v : k)
    if (!std::isfinite(v)) bad(file, what + " has a non-finite entry");
  c->fx = k[0];
  c->fy = k[4];
  c->cx = k[2];
  c->cy = k[5];
  if (!(c->fx > 0) || !(c->fy > 0)) bad(file, fmt::format("focal lengths must be positive, got fx {}, fy {}", c->fx, c->fy));
  if (std::abs(c->fx - c->fy) > 0.01 * c->focal())
    bad(file, fmt::format("fx {} and fy {} differ by more than 1 %: rsfm models square pixels", c->fx, c->fy));
  if (std::abs(k[1]) > 1e-6 * c->fx || k[3] != 0 || k[6] != 0 || k[7] != 0 || k[8] != 1)
    bad(file, what + " must be [fx 0 cx; 0 fy cy; 0 0 1] (no skew)");
  if (!(c->cx >= 0 && c->cx <= c->width - 1 && c->cy >= 0 && c->cy <= c->height - 1))
    bad(file, fmt::format("principal point ({}, {}) outside the {}x{} image", c->cx, c->cy, c->width, c->height));
}

/// OpenCV-ordered distortion coefficients (k1, k2, p1, p2[, k3, ...]) into `c`, checked.
void setDistortion(CameraCalibration* c, const std::vector<double>& d, const std::string& what, const std::filesystem::path& file) {
  const std::size_t n = d.size();
  if (n != 4 && n != 5 && n != 8 && n != 12 && n != 14)
    bad(file, fmt::format("{} must have 4, 5, 8, 12 or 14 entries, got {}", what, n));
  for (double v : d)
    if (!std::isfinite(v)) bad(file, what + " has a non-finite entry");
  c->distortion = d;
}

/// The YAML that ROS's camera_calibration (camera_info: `camera_matrix: {rows, cols, data}`,
/// `distortion_model`, `distortion_coefficients: {..., data}`, `image_width`, `image_height`) and
/// Kalibr / EuRoC (`camera_model`, `intrinsics: [fu, fv, cu, cv]`, `distortion_model`,
/// `distortion_coeffs` or `distortion_coefficients: [k1, k2, p1, p2]`, `resolution: [w, h]`,
/// at the top level (EuRoC's sensor.yaml) or under the first camera (Kalibr's camchain
/// `cam0:`)) write, read without OpenCV's parser (which takes neither: no `%YAML:1.0`, no
/// `!!opencv-matrix`). Block mappings by indentation, `key: value` scalars, flow sequences of
/// numbers over one or more lines; `- ` items, anchors and other YAML are skipped or refused.
struct PlainYaml {
  std::vector<std::pair<std::string, std::string>> scalars;           // dotted path -> text
  std::vector<std::pair<std::string, std::vector<double>>> sequences;  // dotted path -> numbers
  const std::string* scalar(const std::string& k) const {
    for (const auto& [key, v] : scalars)
      if (key == k) return &v;
    return nullptr;
  }
  const std::vector<double>* sequence(const std::string& k) const {
    for (const auto& [key, v] : sequences)
      if (key == k) return &v;
    return nullptr;
  }
};

/// The whole of `tok` as a finite number (strtod's syntax); false otherwise.
bool finiteNumber(const std::string& tok, double* v) {
  char* end = nullptr;
  *v = std::strtod(tok.c_str(), &end);
  return !tok.empty() && end == tok.c_str() + tok.size() && std::isfinite(*v);
}

PlainYaml parsePlainYaml(const std::string& text, const std::filesystem::path& file) {
  PlainYaml y;
  std::vector<std::pair<std::size_t, std::string>> parents;  // (indent, key) of open mappings
  std::string seq_key, seq_text;
  bool in_seq = false;
  std::size_t pos = 0, ln = 0, seq_line = 0;
  const auto numbers = [&](const std::string& body, std::size_t line) {
    std::vector<double> out;
    std::size_t i = 0;
    while (i < body.size()) {
      while (i < body.size() && (body[i] == ' ' || body[i] == '\t' || body[i] == ',')) ++i;
      if (i >= body.size()) break;
      const std::size_t j = body.find_first_of(" \t,", i);
      const std::string tok = body.substr(i, j == std::string::npos ? std::string::npos : j - i);
      double v = 0;
      if (!finiteNumber(tok, &v)) bad(file, fmt::format("line {}: '{}' in a sequence is not a number", line, io::printable(tok, 40)));
      out.push_back(v);
      if (out.size() > 64) bad(file, fmt::format("line {}: a sequence of more than 64 numbers: not a camera", line));
      i = j == std::string::npos ? body.size() : j;
    }
    return out;
  };
  while (pos <= text.size()) {
    std::size_t end = text.find('\n', pos);
    if (end == std::string::npos) end = text.size();
    std::string line = text.substr(pos, end - pos);
    pos = end + 1;
    ++ln;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.size() > 4096) bad(file, fmt::format("line {}: longer than 4096 bytes: not a camera file", ln));
    {  // A comment: '#' at the start or after a blank, outside quotes.
      char quote = 0;
      for (std::size_t i = 0; i < line.size(); ++i) {
        const char ch = line[i];
        if (quote) {
          if (ch == quote) quote = 0;
        } else if (ch == '"' || ch == '\'') {
          quote = ch;
        } else if (ch == '#' && (i == 0 || line[i - 1] == ' ' || line[i - 1] == '\t')) {
          line.erase(i);
          break;
        }
      }
    }
    while (!line.empty() && (line.back() == ' ' || line.back() == '\t')) line.pop_back();
    const std::size_t indent = line.find_first_not_of(' ');
    if (indent == std::string::npos) continue;
    std::string body = line.substr(indent);
    if (in_seq) {
      if (body.find(':') != std::string::npos) bad(file, fmt::format("line {}: a sequence '[' is never closed", seq_line));
      const auto close = body.find(']');
      seq_text += ' ';
      seq_text.append(body, 0, close == std::string::npos ? body.size() : close);
      if (close != std::string::npos) {
        if (body.find_first_not_of(" \t", close + 1) != std::string::npos) bad(file, fmt::format("line {}: text after ']'", ln));
        y.sequences.emplace_back(seq_key, numbers(seq_text, ln));
        in_seq = false;
      }
      continue;
    }
    if (body == "---" || body == "..." || body.rfind("%YAML", 0) == 0 || body.rfind("- ", 0) == 0 || body == "-") continue;
    const std::size_t colon = body.find(':');
    if (colon == std::string::npos || colon == 0)
      bad(file, fmt::format("line {}: '{}' is not 'key: value'", ln, io::printable(body, 40)));
    const std::string key = body.substr(0, colon);
    // Bounded: a calibration has a few dozen short keys; the paths below copy their parents'.
    if (key.size() > 64) bad(file, fmt::format("line {}: a key longer than 64 characters: not a camera file", ln));
    if (y.scalars.size() + y.sequences.size() >= 1000) bad(file, fmt::format("line {}: more than 1000 keys: not a camera file", ln));
    while (!parents.empty() && parents.back().first >= indent) parents.pop_back();
    std::string path;
    for (const auto& p : parents) path += p.second + ".";
    path += key;
    std::string value = body.substr(colon + 1);
    const std::size_t vb = value.find_first_not_of(" \t");
    value = vb == std::string::npos ? std::string() : value.substr(vb);
    if (value.empty()) {
      if (parents.size() >= 8) bad(file, fmt::format("line {}: mappings nested deeper than 8", ln));
      parents.emplace_back(indent, key);
    } else if (value[0] == '[') {
      const auto close = value.find(']');
      if (close == std::string::npos) {
        in_seq = true;
        seq_line = ln;
        seq_key = path;
        seq_text = value.substr(1);
      } else {
        if (value.find_first_not_of(" \t", close + 1) != std::string::npos) bad(file, fmt::format("line {}: text after ']'", ln));
        y.sequences.emplace_back(path, numbers(value.substr(1, close - 1), ln));
      }
    } else {
      if (value.size() >= 2 && (value[0] == '"' || value[0] == '\'') && value.back() == value[0]) value = value.substr(1, value.size() - 2);
      y.scalars.emplace_back(path, value);
    }
  }
  if (in_seq) bad(file, fmt::format("line {}: a sequence '[' is never closed", seq_line));
  return y;
}

double plainNumber(const PlainYaml& y, const std::string& key, const std::filesystem::path& file) {
  const std::string* v = y.scalar(key);
  if (!v) bad(file, fmt::format("missing \"{}\"", key));
  double d = 0;
  if (!finiteNumber(*v, &d)) bad(file, fmt::format("\"{}\" is not a number: '{}'", key, io::printable(*v, 40)));
  return d;
}

/// A distortion model rsfm can undistort with OpenCV's (radial-tangential); a fisheye's is refused.
void checkDistortionModel(const std::string* model, const std::filesystem::path& file) {
  if (!model) return;
  static const char* const kPlain[] = {"plumb_bob", "rational_polynomial", "radtan", "radial-tangential", "none", ""};
  for (const char* m : kPlain)
    if (*model == m) return;
  bad(file, fmt::format("distortion model '{}' is not OpenCV's radial-tangential (plumb_bob, radtan): rsfm cannot undistort "
                        "it; undistort the images first (a fisheye: cv::fisheye)",
                        io::printable(*model, 40)));
}

/// ROS camera_info or Kalibr / EuRoC YAML; nullopt when `text` is neither (OpenCV's reader then).
std::optional<CameraCalibration> fromPlainYaml(const std::string& text, const std::filesystem::path& file) {
  // Only text that is not OpenCV's: no `!!opencv-matrix` and no `%YAML:` directive.
  if (text.find("!!opencv") != std::string::npos || text.find("%YAML:") != std::string::npos) return std::nullopt;
  const bool ros_like = text.find("camera_matrix:") != std::string::npos;
  const bool kalibr_like = text.find("intrinsics:") != std::string::npos;
  if (!ros_like && !kalibr_like) return std::nullopt;
  const PlainYaml y = parsePlainYaml(text, file);
  CameraCalibration c;
  c.source = file.string();
  if (const std::vector<double>* k = y.sequence("camera_matrix.data")) {  // ROS camera_info
    c.width = positiveSide(plainNumber(y, "image_width", file), "\"image_width\"", file);
    c.height = positiveSide(plainNumber(y, "image_height", file), "\"image_height\"", file);
    if (k->size() != 9) bad(file, fmt::format("\"camera_matrix\" data must have 9 entries, got {}", k->size()));
    std::array<double, 9> m{};
    std::copy(k->begin(), k->end(), m.begin());
    setCameraMatrix(&c, m, "\"camera_matrix\"", file);
    checkDistortionModel(y.scalar("distortion_model"), file);
    if (const std::vector<double>* d = y.sequence("distortion_coefficients.data"); d && !d->empty())
      setDistortion(&c, *d, "\"distortion_coefficients\"", file);
    return c;
  }
  // Kalibr / EuRoC: the top level, or the first mapping that holds `intrinsics` (camchain's cam0).
  std::string prefix;
  bool found = y.sequence("intrinsics") != nullptr;
  for (std::size_t i = 0; i < y.sequences.size() && !found; ++i) {
    const std::string& key = y.sequences[i].first;
    const std::string tail = ".intrinsics";
    if (key.size() > tail.size() && key.compare(key.size() - tail.size(), tail.size(), tail) == 0) {
      prefix = key.substr(0, key.size() - tail.size() + 1);
      found = true;
    }
  }
  if (!found) {
    if (ros_like) bad(file, "\"camera_matrix\" has no data sequence (ROS camera_info: rows, cols, data)");
    return std::nullopt;
  }
  if (const std::string* model = y.scalar(prefix + "camera_model"); model && *model != "pinhole")
    bad(file, fmt::format("camera model '{}' is not a pinhole: rsfm cannot undistort it", io::printable(*model, 40)));
  const std::vector<double>& in = *y.sequence(prefix + "intrinsics");
  if (in.size() != 4) bad(file, fmt::format("\"intrinsics\" must be [fu, fv, cu, cv], got {} numbers", in.size()));
  const std::vector<double>* res = y.sequence(prefix + "resolution");
  if (!res || res->size() != 2) bad(file, "missing \"resolution\": [width, height]");
  c.width = positiveSide((*res)[0], "\"resolution\" width", file);
  c.height = positiveSide((*res)[1], "\"resolution\" height", file);
  setCameraMatrix(&c, {in[0], 0, in[2], 0, in[1], in[3], 0, 0, 1}, "\"intrinsics\"", file);
  checkDistortionModel(y.scalar(prefix + "distortion_model"), file);
  const std::vector<double>* d = y.sequence(prefix + "distortion_coeffs");
  if (!d) d = y.sequence(prefix + "distortion_coefficients");
  if (d && !d->empty()) setDistortion(&c, *d, "the distortion coefficients", file);
  return c;
}

/// Checks YAML text line by line against what calibration files hold (cv::calibrateCamera tools,
/// camera.yaml) before OpenCV's parser sees it: OpenCV 4.6's YAML FileStorage loops forever on
/// some malformed input (`%YAML:1.0`, `----x`, `o`, ` ` at the end: tests/fuzz). Accepted:
/// a `%YAML` directive, `---`, comments, `key: value` lines (key [A-Za-z_][A-Za-z0-9_]*, value
/// empty, a tag `!!name`, a number, a word, a double-quoted string, or a flow sequence `[ ... ]`
/// of numbers that may span lines). Returns "" or the problem with its line.
std::string yamlProblem(const std::string& t) {
  auto isNumberChar = [](char c) {
    return std::isdigit(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '+' || c == 'e' || c == 'E';
  };
  // A flow sequence's items: numbers (or .nan/.inf), commas, spaces; `]` ends it.
  auto sequence = [&](std::string_view v, bool* open) {
    for (std::size_t i = 0; i < v.size(); ++i) {
      const char c = v[i];
      if (c == ']') {
        *open = false;
        return v.substr(i + 1).find_first_not_of(" \t") == std::string_view::npos;
      }
      if (!(isNumberChar(c) || c == ',' || c == ' ' || c == '\t' || std::isalpha(static_cast<unsigned char>(c)))) return false;
    }
    return true;
  };
  std::size_t ln = 0, pos = 0;
  bool in_sequence = false, seen_key = false;
  while (pos <= t.size()) {
    std::size_t end = t.find('\n', pos);
    if (end == std::string::npos) end = t.size();
    std::string_view line(t.data() + pos, end - pos);
    pos = end + 1;
    ++ln;
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const auto b = line.find_first_not_of(" \t");
    if (b == std::string_view::npos) continue;
    const std::string_view body = line.substr(b);
    const std::string where = fmt::format("line {}: '{}'", ln, io::printable(body, 40));
    if (in_sequence) {
      if (!sequence(body, &in_sequence)) return where;
      continue;
    }
    if (body[0] == '#') continue;
    if (!seen_key && body.rfind("%YAML", 0) == 0) continue;
    if (body == "---" || body == "...") continue;
    std::size_t k = 0;
    while (k < body.size() && (std::isalnum(static_cast<unsigned char>(body[k])) || body[k] == '_')) ++k;
    if (k == 0 || std::isdigit(static_cast<unsigned char>(body[0])) || k >= body.size() || body[k] != ':') return where;
    seen_key = true;
    std::string_view v = body.substr(k + 1);
    const auto vb = v.find_first_not_of(" \t");
    if (vb == std::string_view::npos) continue;  // a map follows
    v = v.substr(vb);
    while (!v.empty() && (v.back() == ' ' || v.back() == '\t')) v.remove_suffix(1);
    if (v.rfind("!!", 0) == 0) {
      if (v.find_first_of(" \t[]{}") != std::string_view::npos) return where;
    } else if (v[0] == '"') {
      if (v.size() < 2 || v.back() != '"' || v.substr(1, v.size() - 2).find('"') != std::string_view::npos) return where;
    } else if (v[0] == '[') {
      in_sequence = true;
      if (!sequence(v.substr(1), &in_sequence)) return where;
    } else {
      for (char c : v)
        if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '+' || c == '_')) return where;
    }
  }
  if (in_sequence) return "a sequence '[' is never closed";
  return "";
}

/// Checks that XML text is well formed at the tag level before OpenCV's parser sees it: every
/// tag `<name attr="value" ...>`, `</name>` or `<name .../>` complete and nested, `<?...?>` and
/// `<!--...-->` closed. OpenCV 4.6's XML FileStorage dereferences null on a truncated tag such
/// as `<?xml vn=` (tests/fuzz/corpus/camera/finding_opencv_xml_*). Returns "" or the problem.
std::string xmlProblem(const std::string& t) {
  auto nameChar = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == ':' || c == '.'; };
  std::vector<std::string> open;
  std::size_t i = 0;
  const std::size_t n = t.size();
  while (i < n) {
    if (t[i] != '<') {
      ++i;
      continue;
    }
    if (t.compare(i, 4, "<!--") == 0) {
      const auto e = t.find("-->", i + 4);
      if (e == std::string::npos) return "unclosed comment";
      i = e + 3;
      continue;
    }
    // A tag on one line: OpenCV's XML parser dereferences null on line breaks inside a tag too
    // (`<?xml vn=` CR LF ... `"1.0"?>`, tests/fuzz); calibration files never split a tag.
    if (const auto gt = t.find('>', i); gt != std::string::npos && t.find_first_of("\r\n", i) < gt)
      return fmt::format("a tag split over lines at byte {}", i);
    const bool decl = t.compare(i, 2, "<?") == 0, close = t.compare(i, 2, "</") == 0;
    std::size_t j = i + (decl || close ? 2 : 1);
    const std::size_t name0 = j;
    while (j < n && nameChar(t[j])) ++j;
    if (j == name0) return fmt::format("a tag without a name at byte {}", i);
    const std::string name = t.substr(name0, j - name0);
    for (;;) {  // attributes: name = "value" | 'value'
      while (j < n && std::isspace(static_cast<unsigned char>(t[j]))) ++j;
      if (j >= n) return fmt::format("unclosed tag <{}>", io::printable(name, 40));
      if (nameChar(t[j])) {
        while (j < n && nameChar(t[j])) ++j;
        while (j < n && std::isspace(static_cast<unsigned char>(t[j]))) ++j;
        if (j >= n || t[j] != '=') return fmt::format("an attribute without a value in <{}>", io::printable(name, 40));
        ++j;
        while (j < n && std::isspace(static_cast<unsigned char>(t[j]))) ++j;
        if (j >= n || (t[j] != '"' && t[j] != '\'')) return fmt::format("an unquoted attribute value in <{}>", io::printable(name, 40));
        const auto e = t.find(t[j], j + 1);
        if (e == std::string::npos) return fmt::format("an unclosed attribute value in <{}>", io::printable(name, 40));
        j = e + 1;
        continue;
      }
      break;
    }
    if (decl) {
      if (t.compare(j, 2, "?>") != 0) return fmt::format("unclosed declaration <?{}", io::printable(name, 40));
      i = j + 2;
    } else if (close) {
      if (j >= n || t[j] != '>') return fmt::format("unclosed tag </{}", io::printable(name, 40));
      if (open.empty() || open.back() != name) return fmt::format("</{}> does not close the open tag", io::printable(name, 40));
      open.pop_back();
      i = j + 1;
    } else if (t.compare(j, 2, "/>") == 0) {
      i = j + 2;
    } else if (j < n && t[j] == '>') {
      open.push_back(name);
      if (open.size() > 64) return "tags nested deeper than 64";
      i = j + 1;
    } else {
      return fmt::format("unclosed tag <{}>", io::printable(name, 40));
    }
  }
  if (!open.empty()) return fmt::format("<{}> is never closed", io::printable(open.back(), 40));
  return "";
}

}  // namespace

CameraCalibration readCameraFile(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) bad(file, "no such file");
  return readCameraText(io::readAtMost(file, kMaxCameraFileBytes, "cannot be opened"), file);
}

CameraCalibration readCameraText(const std::string& text, const std::filesystem::path& file) {
  if (text.size() > kMaxCameraFileBytes) bad(file, fmt::format("larger than {} kB: not a camera file", kMaxCameraFileBytes >> 10));
  // A calibration is text: control bytes are refused before OpenCV's parser sees them (OpenCV
  // 4.6's FileStorage crashes on some, e.g. NUL bytes in an XML declaration: tests/fuzz).
  for (std::size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if ((c < 0x20 && c != '\t' && c != '\n' && c != '\r') || c == 0x7f)
      bad(file, fmt::format("not a text file (control byte 0x{:02x} at byte {})", c, i));
  }
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first != std::string::npos && text[first] != '<' && text[first] != '{')
    if (std::optional<CameraCalibration> c = fromPlainYaml(text, file)) return *c;
  if (first != std::string::npos && text[first] == '<') {
    if (const std::string why = xmlProblem(text); !why.empty()) bad(file, "malformed XML: " + why);
  } else if (first != std::string::npos && text[first] == '{') {
    if (!nlohmann::json::accept(text)) bad(file, "malformed JSON");
  } else if (const std::string why = yamlProblem(text); !why.empty()) {
    bad(file, "not a camera file in the YAML rsfm reads: " + why);
  }
  cv::FileStorage fs;
  try {
    if (text.empty() || !fs.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY))
      bad(file, "not an OpenCV FileStorage YAML/XML file");
  } catch (const io::InputError&) {
    throw;
  } catch (const std::exception&) {  // cv::Exception, and std::length_error from OpenCV 4.6's parser (tests/fuzz)
    bad(file, "not an OpenCV FileStorage YAML/XML file (parse error)");
  }
  try {
    return fromStorage(fs, file);
  } catch (const io::InputError&) {
    throw;
  } catch (const std::exception&) {
    bad(file, "malformed OpenCV FileStorage content");
  }
}

namespace {

CameraCalibration fromStorage(const cv::FileStorage& fs, const std::filesystem::path& file) {
  CameraCalibration c;
  c.source = file.string();
  c.width = intNode(fs, "image_width", file);
  c.height = intNode(fs, "image_height", file);
  const cv::Mat K = matrixNode(fs, "camera_matrix", file);
  if (K.rows != 3 || K.cols != 3) bad(file, fmt::format("\"camera_matrix\" must be 3x3, got {}x{}", K.rows, K.cols));
  std::array<double, 9> k{};
  for (int i = 0; i < 9; ++i) k[static_cast<std::size_t>(i)] = K.at<double>(i / 3, i % 3);
  setCameraMatrix(&c, k, "\"camera_matrix\"", file);
  if (!fs["distortion_coefficients"].empty()) {
    const cv::Mat D = matrixNode(fs, "distortion_coefficients", file);
    if (!(D.rows == 1 || D.cols == 1))
      bad(file, fmt::format("\"distortion_coefficients\" must be one row or column, got {}x{}", D.rows, D.cols));
    std::vector<double> d;
    for (int i = 0; i < static_cast<int>(D.total()); ++i) d.push_back(D.at<double>(i));
    setDistortion(&c, d, "\"distortion_coefficients\"", file);
  }
  if (!fs["rolling_shutter_readout"].empty()) {
    const double tau = realNode(fs, "rolling_shutter_readout", file);
    if (!std::isfinite(tau) || std::abs(tau) > kMaxRollingShutterReadout)
      bad(file, fmt::format("\"rolling_shutter_readout\" {} frame intervals: outside -{} to {}", tau, kMaxRollingShutterReadout,
                            kMaxRollingShutterReadout));
    c.rolling_shutter_readout = tau;
  }
  return c;
}

}  // namespace

CameraCalibration rotateCalibration(const CameraCalibration& cal, int degrees) {
  const int d = ((degrees % 360) + 360) % 360;
  if (d == 0) return cal;
  if (d != 90 && d != 180 && d != 270)
    throw io::InputError(fmt::format("{}: a calibration turns by 90, 180 or 270 degrees, not {}", cal.source, degrees));
  for (std::size_t i = 8; i < cal.distortion.size(); ++i)
    if (cal.distortion[i] != 0.0)
      throw io::InputError(fmt::format("{}: its thin-prism or tilt distortion terms cannot be turned to the video's rotation; "
                                       "calibrate with the frames as the video is decoded",
                                       cal.source));
  CameraCalibration c = cal;
  double p1 = cal.distortion.size() > 2 ? cal.distortion[2] : 0.0, p2 = cal.distortion.size() > 3 ? cal.distortion[3] : 0.0;
  // In normalized coordinates 90 degrees clockwise (y down) is (x, y) -> (-y, x); the tangential
  // term D(x) turns as R D(R^-1 x'), which is Brown's form again with (p1, p2) -> (p2, -p1).
  for (int q = 0; q < d / 90; ++q) {
    const CameraCalibration b = c;
    c.width = b.height;
    c.height = b.width;
    c.fx = b.fy;
    c.fy = b.fx;
    c.cx = b.height - 1 - b.cy;
    c.cy = b.cx;
    const double t = p1;
    p1 = p2;
    p2 = 0.0 - t;  // not -0.0 when t is 0
  }
  if (c.distortion.size() > 2) c.distortion[2] = p1;
  if (c.distortion.size() > 3) c.distortion[3] = p2;
  c.source = fmt::format("{} (turned {} degrees clockwise, as the video)", cal.source, d);
  return c;
}

CameraCalibration calibrationForTracks(const CameraCalibration& cal, const ImageInfo& image) {
  if (image.width == cal.width && image.height == cal.height) return cal;
  const bool turned = image.width == cal.height && image.height == cal.width;
  if (turned && image.readout_direction == ReadoutDirection::Left) return rotateCalibration(cal, 90);
  if (turned && image.readout_direction == ReadoutDirection::Right) return rotateCalibration(cal, 270);
  throw io::InputError(fmt::format("{}: the calibration is for {}x{} images, the tracks are {}x{}{}", cal.source, cal.width,
                                   cal.height, image.width, image.height,
                                   turned ? " (on their side, but the tracks do not say which way the video was turned: "
                                            "their readout_direction is neither left nor right)"
                                          : ""));
}

Tracks undistortTracks(const Tracks& tracks, const CameraCalibration& cal) {
  if (tracks.image.width != cal.width || tracks.image.height != cal.height)
    throw io::InputError(fmt::format("{}: the calibration is for {}x{} images, the tracks are {}x{}", cal.source, cal.width,
                                     cal.height, tracks.image.width, tracks.image.height));
  Tracks out = tracks;
  out.image.cx = cal.cx;
  out.image.cy = cal.cy;
  if (!cal.distorted()) return out;
  const cv::Matx33d K(cal.fx, 0, cal.cx, 0, cal.fy, cal.cy, 0, 0, 1);
  const cv::Matx33d P(cal.focal(), 0, cal.cx, 0, cal.focal(), cal.cy, 0, 0, 1);
  for (auto& frame : out.frames) {
    if (frame.empty()) continue;
    std::vector<cv::Point2d> in, und;
    for (const auto& p : frame) in.emplace_back(p.px.x(), p.px.y());
    cv::undistortPoints(in, und, K, cal.distortion, cv::noArray(), P,
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-10));
    for (std::size_t i = 0; i < frame.size(); ++i) frame[i].px = Eigen::Vector2d(und[i].x, und[i].y);
  }
  return out;
}

}  // namespace rsfm::vision
