#pragma once
// Bad input (malformed file, missing frame, wrong size, NaN): one exception type whose message is
// one line naming the problem, "FILE:LINE: problem" where there is a line.
#include <filesystem>
#include <stdexcept>
#include <string>

namespace rsfm::io {

class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// "FILE:LINE: msg" (line <= 0: "FILE: msg").
inline InputError inputError(const std::filesystem::path& file, int line, const std::string& msg) {
  std::string s = file.string();
  if (line > 0) {
    s += ':';
    s += std::to_string(line);
  }
  s += ": ";
  s += msg;
  return InputError(s);
}

}  // namespace rsfm::io
