#pragma once
// Bad input (malformed file, missing frame, wrong size, NaN): one exception type whose message is
// one line naming the problem, "FILE:LINE: problem" where there is a line. Text taken from the
// input is never echoed raw: `printable()` escapes control and non-ASCII bytes and shortens it.
#include <cstddef>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <string_view>

namespace rsfm::io {

class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// `s` safe to print on one terminal line: bytes outside printable ASCII become \xNN, and text
/// longer than `max_chars` is cut with "..." (issue 17: raw ESC sequences and 20 MB lines were
/// echoed).
inline std::string printable(std::string_view s, std::size_t max_chars = 80) {
  static const char* hex = "0123456789abcdef";
  std::string out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (out.size() >= max_chars) {
      out += "...";
      break;
    }
    const auto c = static_cast<unsigned char>(s[i]);
    if (c >= 0x20 && c < 0x7f) {
      out += static_cast<char>(c);
    } else {
      out += "\\x";
      out += hex[c >> 4];
      out += hex[c & 15];
    }
  }
  return out;
}

/// "FILE:LINE: msg" (line <= 0: "FILE: msg"); the file name made printable.
inline InputError inputError(const std::filesystem::path& file, long long line, const std::string& msg) {
  std::string s = printable(file.string(), 300);
  if (line > 0) {
    s += ':';
    s += std::to_string(line);
  }
  s += ": ";
  s += msg;
  return InputError(s);
}

/// The first `max_bytes` + 1 bytes of `file` at most (one more than a format allows, so that the
/// caller can refuse an oversized file): no unbounded read of /dev/zero. Throws InputError
/// "FILE: <cannot_open>" when it cannot be opened, "FILE: read error" on a read error.
inline std::string readAtMost(const std::filesystem::path& file, std::size_t max_bytes, const std::string& cannot_open) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw inputError(file, 0, cannot_open);
  std::string text(max_bytes + 1, '\0');
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  if (in.bad()) throw inputError(file, 0, "read error");
  text.resize(static_cast<std::size_t>(in.gcount()));
  return text;
}

}  // namespace rsfm::io
