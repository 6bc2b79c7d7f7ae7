#include "cli_common.hpp"

#include "rsfm/io/input_error.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cstdio>

namespace rsfm::cli {

int guarded(const std::function<void()>& f) {
  try {
    f();
  } catch (const io::InputError& e) {
    return fail(kBadInput, e.what());
  } catch (const std::exception& e) {
    return fail(kRuntimeFailure, e.what());
  }
  return 0;
}

int fail(int code, const std::string& msg) {
  fmt::print(stderr, "rsfm: error: {}\n", msg);
  return code;
}

std::function<void(int, int)> progressReporter(std::string name, std::string unit) {
  const bool tty = ::isatty(STDERR_FILENO);
  return [tty, name = std::move(name), unit = std::move(unit), last = -1](int done, int total) mutable {
    const int pct = total > 0 ? 100 * done / total : 100;
    if (tty) {
      fmt::print(stderr, "\r{}: {}/{} {} ({}%)", name, done, total, unit, pct);
      if (done == total) fmt::print(stderr, "\n");
    } else if (pct / 10 != last / 10 || done == total) {
      fmt::print(stderr, "{}: {}/{} {} ({}%)\n", name, done, total, unit, pct);
    }
    last = pct;
  };
}

namespace detail {
std::string& invocationStorage() {
  static std::string s = "rsfm";
  return s;
}
}  // namespace detail

const std::string& invocation() { return detail::invocationStorage(); }

}  // namespace rsfm::cli
