#pragma once
// Shared by the fuzz targets (tests/fuzz/README.md). Each target feeds its bytes to one reader a
// user feeds files to; bad input must end in rsfm::io::InputError (a one-line message, no raw
// control bytes), anything else (another exception, a sanitizer report, a failed round trip) is
// a finding and aborts.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "rsfm/io/input_error.hpp"

namespace rsfm::fuzz {

[[noreturn]] inline void finding(const std::string& what) {
  std::fprintf(stderr, "fuzz finding: %s\n", rsfm::io::printable(what, 2000).c_str());
  std::abort();
}

inline void check(bool ok, const std::string& what) {
  if (!ok) finding(what);
}

/// The contract of an InputError's message: one printable line.
inline void checkMessage(const std::string& msg) {
  check(!msg.empty(), "empty error message");
  for (unsigned char c : msg)
    if (c < 0x20 || c == 0x7f) finding("control byte in an error message: " + msg);
}

}  // namespace rsfm::fuzz
