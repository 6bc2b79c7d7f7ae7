#include "rsfm/render/regime_suite.hpp"

#include <fmt/format.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <stdexcept>

#include "rsfm/io/input_error.hpp"
#include "rsfm/io/json_text.hpp"

namespace rsfm::render {

namespace detail {
// Generated at configure time from bench/regimes.json (CMakeLists.txt).
extern const char* const kBuiltinRegimes;
}  // namespace detail

namespace {

using json = nlohmann::json;

double num(const json& v, const std::string& key) {
  if (!v.is_number()) throw std::invalid_argument("\"" + key + "\" must be a number");
  return v.get<double>();
}

int integer(const json& v, const std::string& key) {
  if (!v.is_number_integer()) throw std::invalid_argument("\"" + key + "\" must be an integer");
  const auto x = v.get<long long>();
  if (x < -1000000000LL || x > 1000000000LL) throw std::invalid_argument("\"" + key + "\" is out of range");
  return static_cast<int>(x);
}

}  // namespace

RenderOptions optionsFromJson(const std::string& text) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    throw std::invalid_argument(std::string("options are not valid JSON: ") + e.what());
  }
  if (!j.is_object()) throw std::invalid_argument("options must be a JSON object");
  RenderOptions o;
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& k = it.key();
    const json& v = it.value();
    if (k == "scene") {
      if (!v.is_string() || !parseSceneKind(v.get<std::string>(), &o.scene))
        throw std::invalid_argument("\"scene\" must be one of " + sceneKindNames());
    } else if (k == "motion") {
      if (!v.is_string() || !parseMotionKind(v.get<std::string>(), &o.motion))
        throw std::invalid_argument("\"motion\" must be one of " + motionKindNames());
    } else if (k == "frames") {
      o.frames = integer(v, k);
    } else if (k == "focal_px") {
      o.focal_px = num(v, k);
    } else if (k == "width") {
      o.width = integer(v, k);
    } else if (k == "height") {
      o.height = integer(v, k);
    } else if (k == "principal_offset_px") {
      if (!v.is_array() || v.size() != 2) throw std::invalid_argument("\"principal_offset_px\" must be [dx, dy]");
      o.principal_offset_px = {num(v[0], k), num(v[1], k)};
    } else if (k == "k1") {
      o.k1 = num(v, k);
    } else if (k == "k2") {
      o.k2 = num(v, k);
    } else if (k == "orbit_deg") {
      o.orbit_deg = num(v, k);
    } else if (k == "deg_per_frame") {
      o.deg_per_frame = num(v, k);
    } else if (k == "elevation_deg") {
      if (!v.is_array() || v.size() != 2) throw std::invalid_argument("\"elevation_deg\" must be [first, last]");
      o.elevation0_deg = num(v[0], k);
      o.elevation1_deg = num(v[1], k);
    } else if (k == "approach") {
      if (v.is_null())
        o.approach.reset();
      else
        o.approach = num(v, k);
    } else if (k == "still_start") {
      o.still_start = integer(v, k);
    } else if (k == "still_middle") {
      o.still_middle = integer(v, k);
    } else if (k == "jitter_deg") {
      o.jitter_deg = num(v, k);
    } else if (k == "noise") {
      o.noise_sigma = num(v, k);
    } else if (k == "blur") {
      o.blur = num(v, k);
    } else if (k == "readout") {
      o.readout = num(v, k);
    } else if (k == "jpeg_quality") {
      o.jpeg_quality = integer(v, k);
    } else if (k == "texture") {
      if (!v.is_string()) throw std::invalid_argument("\"texture\" must be a string");
      o.texture = v.get<std::string>();
    } else if (k == "seed") {
      if (!v.is_number_unsigned()) throw std::invalid_argument("\"seed\" must be a non-negative integer");
      o.seed = v.get<std::uint64_t>();
    } else if (k == "floor") {
      if (!v.is_boolean()) throw std::invalid_argument("\"floor\" must be true or false");
      o.floor = v.get<bool>();
    } else if (k == "fps") {
      o.fps = num(v, k);
    } else {
      throw std::invalid_argument("unknown option \"" + k + "\"");
    }
  }
  return o;
}

const Regime* RegimeSuite::find(const std::string& name) const {
  for (const Regime& r : sequences)
    if (r.name == name) return &r;
  return nullptr;
}

std::string RegimeSuite::names() const {
  std::string s;
  for (const Regime& r : sequences) s += (s.empty() ? "" : ", ") + r.name;
  return s;
}

RegimeSuite parseRegimeSuite(const std::string& text, const std::string& source) {
  auto bad = [&](const std::string& m) -> void { throw io::InputError(source + ": " + m); };
  const json j = io::parseJsonText(text, source);
  RegimeSuite suite;
  suite.source = source;
  if (!j.is_object()) bad("top level must be a JSON object");
  if (!j.contains("format") || j["format"] != "rsfm-regimes") bad("\"format\" must be \"rsfm-regimes\"");
  if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<long long>() != 1)
    bad("unsupported \"version\" (expected 1)");
  if (!j.contains("sequences") || !j["sequences"].is_array() || j["sequences"].empty())
    bad("\"sequences\" must be a non-empty array");
  std::set<std::string> names;
  for (const json& e : j["sequences"]) {
    if (!e.is_object() || !e.contains("name") || !e["name"].is_string()) bad("every sequence needs a \"name\" string");
    Regime r;
    r.name = e["name"].get<std::string>();
    if (r.name.empty() || r.name.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789-") != std::string::npos)
      bad("sequence name \"" + r.name + "\" must be non-empty and use only a-z, 0-9 and -");
    if (!names.insert(r.name).second) bad("sequence \"" + r.name + "\" appears twice");
    for (auto it = e.begin(); it != e.end(); ++it)
      if (it.key() != "name" && it.key() != "why" && it.key() != "axes" && it.key() != "options")
        bad("sequence \"" + r.name + "\": unknown key \"" + it.key() + "\"");
    if (e.contains("why")) {
      if (!e["why"].is_string()) bad("sequence \"" + r.name + "\": \"why\" must be a string");
      r.why = e["why"].get<std::string>();
    }
    if (e.contains("axes")) {
      if (!e["axes"].is_array()) bad("sequence \"" + r.name + "\": \"axes\" must be an array of strings");
      for (const json& a : e["axes"]) {
        if (!a.is_string()) bad("sequence \"" + r.name + "\": \"axes\" must be an array of strings");
        r.axes.push_back(a.get<std::string>());
      }
    }
    if (!e.contains("options") || !e["options"].is_object()) bad("sequence \"" + r.name + "\": \"options\" must be an object");
    if (!e["options"].contains("seed")) bad("sequence \"" + r.name + "\": \"options\" needs a fixed \"seed\"");
    try {
      r.options = optionsFromJson(e["options"].dump());
    } catch (const std::invalid_argument& ex) {
      bad("sequence \"" + r.name + "\": " + ex.what());
    }
    if (auto m = validate(r.options); !m.empty()) bad("sequence \"" + r.name + "\": " + m);
    r.options_json = optionsToJson(r.options);
    suite.sequences.push_back(std::move(r));
  }
  return suite;
}

RegimeSuite readRegimeSuite(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw io::InputError(path + ": cannot open the suite file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parseRegimeSuite(ss.str(), path);
}

const std::string& builtinRegimeSuiteText() {
  static const std::string text(detail::kBuiltinRegimes);
  return text;
}

const RegimeSuite& builtinRegimeSuite() {
  static const RegimeSuite suite = parseRegimeSuite(builtinRegimeSuiteText(), "built-in bench/regimes.json");
  return suite;
}

}  // namespace rsfm::render
