#include "rsfm/io/summary.hpp"
#include "rsfm/track/tracks.hpp"

#include "rsfm/io/json_text.hpp"

#include <fmt/format.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>

namespace rsfm::io {
namespace {

using json = nlohmann::json;

[[noreturn]] void bad(const std::filesystem::path& f, const std::string& msg) { throw inputError(f, 0, msg); }

double number(const std::filesystem::path& f, const json& j, const std::string& what) {
  if (!j.is_number()) bad(f, what + " must be a number");
  const double v = j.get<double>();
  if (!std::isfinite(v)) bad(f, what + " must be finite");
  return v;
}

/// An int, refused (not truncated) outside int's range (issue 17: 2^32 + 1 was read as 1).
int integer(const std::filesystem::path& f, const json& j, const std::string& what) {
  if (!j.is_number_integer()) bad(f, what + " must be an integer");
  const bool fits = j.is_number_unsigned() ? j.get<std::uint64_t>() <= static_cast<std::uint64_t>(std::numeric_limits<int>::max())
                                           : (j.get<std::int64_t>() >= std::numeric_limits<int>::min() &&
                                              j.get<std::int64_t>() <= std::numeric_limits<int>::max());
  if (!fits) bad(f, what + " is out of range (beyond a 32-bit integer)");
  return j.get<int>();
}

const json& required(const std::filesystem::path& f, const json& o, const char* key) {
  if (!o.contains(key)) bad(f, fmt::format("missing key \"{}\"", key));
  return o.at(key);
}

}  // namespace

Summary readSummary(const std::filesystem::path& file) {
  std::error_code ec;
  if (std::filesystem::is_directory(file, ec)) bad(file, "is a directory, not a summary file");
  // A summary is a few kB; reading stops past kMaxSummaryBytes.
  const std::string text = readAtMost(file, kMaxSummaryBytes, "cannot open summary file");
  if (text.size() > kMaxSummaryBytes) bad(file, fmt::format("larger than {} MiB: not an rsfm summary", kMaxSummaryBytes >> 20));
  return readSummaryText(text, file);
}

Summary readSummaryText(const std::string& text, const std::filesystem::path& file) {
  const json j = parseJsonText(text, file.string());
  if (!j.is_object()) bad(file, "top level must be a JSON object");
  Summary s;
  const json& fmt_ = required(file, j, "format");
  if (!fmt_.is_string() || fmt_.get<std::string>() != "rsfm-summary") bad(file, "\"format\" must be \"rsfm-summary\"");
  if (integer(file, required(file, j, "version"), "\"version\"") != 1) bad(file, "unsupported \"version\" (expected 1)");
  s.frames = integer(file, required(file, j, "frames"), "\"frames\"");
  if (s.frames <= 0) bad(file, "\"frames\" must be positive");
  const json& img = required(file, j, "image");
  if (!img.is_object()) bad(file, "\"image\" must be an object {\"width\":W,\"height\":H}");
  s.width = integer(file, required(file, img, "width"), "\"image.width\"");
  s.height = integer(file, required(file, img, "height"), "\"image.height\"");
  if (s.width <= 0 || s.height <= 0) bad(file, "image width and height must be positive");
  const json& pp = required(file, j, "principal_point_px");
  if (!pp.is_array() || pp.size() != 2) bad(file, "\"principal_point_px\" must be [cx, cy]");
  s.principal_point_px = {number(file, pp[0], "\"principal_point_px\"[0]"), number(file, pp[1], "\"principal_point_px\"[1]")};
  const json& f = required(file, j, "focal_px");
  if (!f.is_null()) {
    s.focal_px = number(file, f, "\"focal_px\"");
    if (!(*s.focal_px > 0)) bad(file, "\"focal_px\" must be positive (or null)");
  }
  if (j.contains("planes")) {
    const json& pl = j.at("planes");
    if (!pl.is_array()) bad(file, "\"planes\" must be an array of [nx, ny, nz]");
    for (std::size_t i = 0; i < pl.size(); ++i) {
      const std::string what = fmt::format("\"planes\"[{}]", i);
      if (!pl[i].is_array() || pl[i].size() != 3) bad(file, what + " must be [nx, ny, nz]");
      Eigen::Vector3d n(number(file, pl[i][0], what), number(file, pl[i][1], what), number(file, pl[i][2], what));
      if (std::abs(n.norm() - 1.0) > 1e-3) bad(file, fmt::format("{} is not a unit vector (norm {:.6g})", what, n.norm()));
      // Normalized unless already unit to 1e-12: a normal rsfm wrote reads back bit for bit
      // (normalizing a unit vector again can move its last digits: tests/fuzz).
      s.planes.push_back(std::abs(n.norm() - 1.0) > 1e-12 ? n.normalized() : n);
    }
  }
  auto numberArray = [&](const char* key, auto* out, bool ints) {
    if (!j.contains(key)) return;
    const json& a = j.at(key);
    if (!a.is_array()) bad(file, fmt::format("\"{}\" must be an array", key));
    if (a.size() != s.planes.size())
      bad(file, fmt::format("\"{}\" has {} entries but \"planes\" has {}", key, a.size(), s.planes.size()));
    for (std::size_t i = 0; i < a.size(); ++i) {
      const std::string what = fmt::format("\"{}\"[{}]", key, i);
      if (ints)
        out->push_back(static_cast<typename std::remove_reference_t<decltype(*out)>::value_type>(integer(file, a[i], what)));
      else
        out->push_back(static_cast<typename std::remove_reference_t<decltype(*out)>::value_type>(number(file, a[i], what)));
    }
  };
  numberArray("plane_distances", &s.plane_distances, false);
  if (!s.planes.empty() && s.plane_distances.empty()) bad(file, "missing key \"plane_distances\"");
  for (std::size_t i = 0; i < s.plane_distances.size(); ++i)
    if (!(s.plane_distances[i] > 0)) bad(file, fmt::format("\"plane_distances\"[{}] must be positive", i));
  numberArray("plane_tracks", &s.plane_tracks, true);
  numberArray("plane_reprojection_rms_px", &s.plane_reprojection_rms_px, false);
  numberArray("plane_visible_frames", &s.plane_visible_frames, true);
  if (j.contains("plane_names")) {
    const json& a = j.at("plane_names");
    if (!a.is_array() || a.size() != s.planes.size())
      bad(file, "\"plane_names\" must be an array with one name per plane");
    for (const json& n : a) {
      if (!n.is_string()) bad(file, "\"plane_names\" entries must be strings");
      if (n.get_ref<const std::string&>().size() > 1000) bad(file, "\"plane_names\" entries must be at most 1000 bytes");
      s.plane_names.push_back(n.get<std::string>());
    }
  }
  if (j.contains("scene_size") && !j.at("scene_size").is_null()) {
    s.scene_size = number(file, j.at("scene_size"), "\"scene_size\"");
    if (!(*s.scene_size > 0)) bad(file, "\"scene_size\" must be positive");
  }
  if (j.contains("fps") && !j.at("fps").is_null()) {
    s.fps = number(file, j.at("fps"), "\"fps\"");
    if (!(*s.fps > 0) || *s.fps > ImageInfo::kMaxFps)
      bad(file, fmt::format("\"fps\" must be above 0 and at most {} (frames per second)", ImageInfo::kMaxFps));
  }
  if (j.contains("time_origin_s") && !j.at("time_origin_s").is_null()) {
    s.time_origin = number(file, j.at("time_origin_s"), "\"time_origin_s\"");
    if (!(s.time_origin >= 0) || s.time_origin > ImageInfo::kMaxTimeOrigin)
      bad(file, fmt::format("\"time_origin_s\" must be from 0 to {:g} (seconds)", ImageInfo::kMaxTimeOrigin));
    if (!s.fps && s.time_origin != 0) bad(file, "\"time_origin_s\" needs \"fps\" (timestamps in seconds from it)");
  }
  if (j.contains("radial_distortion") && !j.at("radial_distortion").is_null()) {
    const json& d = j.at("radial_distortion");
    if (!d.is_array() || d.size() != 2) bad(file, "\"radial_distortion\" must be [k1, k2]");
    s.distortion = Eigen::Vector2d(number(file, d[0], "\"radial_distortion\"[0]"), number(file, d[1], "\"radial_distortion\"[1]"));
  }
  if (j.contains("determinable") && !j.at("determinable").is_null()) {
    const json& d = j.at("determinable");
    if (!d.is_object()) bad(file, "\"determinable\" must be an object");
    Determinable det;
    for (const char* key : {"focal", "structure"}) {
      const json& b = required(file, d, key);
      if (!b.is_boolean()) bad(file, fmt::format("\"determinable.{}\" must be true or false", key));
      (std::string(key) == "focal" ? det.focal : det.structure) = b.get<bool>();
    }
    if (d.contains("why")) {
      if (!d.at("why").is_string()) bad(file, "\"determinable.why\" must be a string");
      det.why = d.at("why").get<std::string>();
    }
    if (d.contains("crb_focal_rel_sd") && !d.at("crb_focal_rel_sd").is_null())
      det.crb_focal_rel_sd = number(file, d.at("crb_focal_rel_sd"), "\"determinable.crb_focal_rel_sd\"");
    if (d.contains("crb_normal_sd_deg") && !d.at("crb_normal_sd_deg").is_null()) {
      const json& a = d.at("crb_normal_sd_deg");
      if (!a.is_array() || a.size() != s.planes.size())
        bad(file, "\"determinable.crb_normal_sd_deg\" must have one entry (number or null) per plane");
      for (const json& v : a)
        det.crb_normal_sd_deg.push_back(v.is_null() ? std::optional<double>()
                                                    : std::optional<double>(number(file, v, "\"determinable.crb_normal_sd_deg\"")));
    }
    s.determinable = det;
  }
  return s;
}

std::string summaryToJson(const Summary& s) {
  nlohmann::ordered_json o;  // keeps the schema's key order
  o["format"] = "rsfm-summary";
  o["version"] = 1;
  o["frames"] = s.frames;
  o["image"] = {{"width", s.width}, {"height", s.height}};
  o["principal_point_px"] = {s.principal_point_px.x(), s.principal_point_px.y()};
  o["focal_px"] = s.focal_px ? nlohmann::ordered_json(*s.focal_px) : nlohmann::ordered_json(nullptr);
  o["planes"] = nlohmann::ordered_json::array();
  for (const auto& n : s.planes) o["planes"].push_back({n.x(), n.y(), n.z()});
  o["plane_distances"] = s.plane_distances;
  if (!s.plane_tracks.empty()) o["plane_tracks"] = s.plane_tracks;
  if (!s.plane_reprojection_rms_px.empty()) o["plane_reprojection_rms_px"] = s.plane_reprojection_rms_px;
  if (!s.plane_names.empty()) o["plane_names"] = s.plane_names;
  if (!s.plane_visible_frames.empty()) o["plane_visible_frames"] = s.plane_visible_frames;
  if (s.scene_size) o["scene_size"] = *s.scene_size;
  if (s.fps) {
    o["fps"] = *s.fps;
    o["timestamps"] = "seconds";
    if (s.time_origin != 0) o["time_origin_s"] = s.time_origin;
  }
  if (s.distortion) o["radial_distortion"] = {s.distortion->x(), s.distortion->y()};
  if (s.determinable) {
    const Determinable& d = *s.determinable;
    nlohmann::ordered_json dj;
    dj["focal"] = d.focal;
    dj["structure"] = d.structure;
    dj["why"] = d.why;
    dj["crb_focal_rel_sd"] = d.crb_focal_rel_sd ? nlohmann::ordered_json(*d.crb_focal_rel_sd) : nlohmann::ordered_json(nullptr);
    nlohmann::ordered_json a = nlohmann::ordered_json::array();
    for (const auto& v : d.crb_normal_sd_deg) a.push_back(v ? nlohmann::ordered_json(*v) : nlohmann::ordered_json(nullptr));
    // One entry per plane, or null when not analysed (the reader accepts nothing else).
    dj["crb_normal_sd_deg"] = d.crb_normal_sd_deg.empty() ? nlohmann::ordered_json(nullptr) : a;
    o["determinable"] = dj;
  }
  return o.dump(2) + "\n";
}

}  // namespace rsfm::io
