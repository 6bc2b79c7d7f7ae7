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

}  // namespace rsfm::io
