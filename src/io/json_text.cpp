#include "rsfm/io/json_text.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace rsfm::io {

nlohmann::json parseJsonText(const std::string& text, const std::string& source) {
  try {
    return nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& e) {
    int line = 1;
    for (std::size_t i = 0; i < std::min<std::size_t>(e.byte > 0 ? e.byte - 1 : 0, text.size()); ++i)
      if (text[i] == '\n') ++line;
    std::string msg = e.what();
    if (auto p = msg.find("syntax error"); p != std::string::npos) msg = msg.substr(p);
    throw InputError(fmt::format("{}:{}: invalid JSON: {}", printable(source, 300), line, printable(msg, 200)));
  } catch (const nlohmann::json::exception& e) {
    // e.g. out_of_range.406 "number overflow parsing '1e999'" (issue 17: was a raw exception)
    std::string msg = e.what();
    if (auto p = msg.find("] "); p != std::string::npos) msg = msg.substr(p + 2);
    throw InputError(fmt::format("{}: invalid JSON: {}", printable(source, 300), printable(msg, 200)));
  }
}

nlohmann::json finiteOrNull(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

nlohmann::json focalIntervalJson(double lo, double hi) {
  return nlohmann::json::array({lo > 0 && std::isfinite(lo) ? nlohmann::json(lo) : nlohmann::json(nullptr), finiteOrNull(hi)});
}

double focalIntervalBound(const nlohmann::json& iv, int side) {
  if (!iv.is_array() || iv.size() != 2 || !iv[side].is_number()) return side == 0 ? 0.0 : INFINITY;
  return iv[side].get<double>();
}

std::string focalIntervalText(const nlohmann::json& iv, const char* dash) {
  if (!iv.is_array() || iv.size() != 2) return "";
  const bool has_lo = iv[0].is_number(), has_hi = iv[1].is_number();
  if (has_lo && has_hi) return fmt::format("{:.0f}{}{:.0f} px", iv[0].get<double>(), dash, iv[1].get<double>());
  if (has_lo) return fmt::format("at least {:.0f} px", iv[0].get<double>());
  if (has_hi) return fmt::format("at most {:.0f} px", iv[1].get<double>());
  return "any focal length";
}

}  // namespace rsfm::io
