#pragma once
// Parsing a JSON document a user gave us: a syntax error becomes io::InputError
// "SOURCE:LINE: invalid JSON: ..." (the line of the offending byte).
#include <nlohmann/json.hpp>
#include <string>

#include "rsfm/io/input_error.hpp"

namespace rsfm::io {

nlohmann::json parseJsonText(const std::string& text, const std::string& source);

/// A number for a summary: null when it is not finite (docs/outputs.md: a quantity that could not
/// be computed is null, never NaN or inf, which JSON cannot hold).
nlohmann::json finiteOrNull(double v);

/// A supported focal-length interval [lo, hi] in pixels for a summary: an unbounded side (lo <= 0,
/// hi infinite: the data do not limit it) is null.
nlohmann::json focalIntervalJson(double lo, double hi);
/// A summary's `focal_interval_px` in words, e.g. "192-1920 px", "at least 192 px", "any focal
/// length"; `dash` separates the bounds (HTML: "&ndash;"). Empty when `iv` is not a 2-array.
std::string focalIntervalText(const nlohmann::json& iv, const char* dash = "-");
/// A bound of `focal_interval_px` as a number: null is 0 (lower) or +infinity (upper).
double focalIntervalBound(const nlohmann::json& iv, int side);

}  // namespace rsfm::io
