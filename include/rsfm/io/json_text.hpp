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

}  // namespace rsfm::io
