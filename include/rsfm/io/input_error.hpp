#pragma once
// Bad input read from a file: what() is one line, "FILE:LINE: problem" when the problem has a
// line (or "FILE: problem" when it concerns the whole file). The CLI turns it into
// `rsfm: error: <what()>` and exit code 2.
#include <stdexcept>
#include <string>

namespace rsfm::io {

class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace rsfm::io
