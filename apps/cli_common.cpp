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
  // One line, always (issue 17): OpenCV's messages end in a newline, others may carry control
  // bytes from a file; whitespace runs become one space, other control bytes are escaped.
  std::string one;
  for (char c : msg) {
    if (c == '\n' || c == '\r' || c == '\t' || c == ' ') {
      if (!one.empty() && one.back() != ' ') one += ' ';
    } else {
      one += c;
    }
  }
  while (!one.empty() && one.back() == ' ') one.pop_back();
  std::string safe;
  for (char c : one) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20 || u == 0x7f) safe += fmt::format("\\x{:02x}", u);
    else safe += c;
  }
  fmt::print(stderr, "rsfm: error: {}\n", safe);
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

void sayLeadingFramesLeftOut(bool quiet, int range_first, int first, const char* features, const char* tracks) {
  if (first > range_first && !quiet)
    fmt::print(stderr, "track: frames {}-{} have no {} (black or featureless): the {} start at frame {}\n", range_first, first - 1,
               features, tracks, first);
}

void sayExposureCompensated(bool quiet, long changed, long steps) {
  if (changed > 0 && !quiet)
    fmt::print(stderr,
               "track: the exposure changed by a grey level or more in {} of {} steps; they were tracked with the "
               "last frame brought to the new brightness\n",
               changed, steps);
}

void sayDroppedFrames(bool quiet, long dropped, double fps) {
  if (dropped > 0 && !quiet)
    fmt::print(stderr,
               "track: {} frame(s) missing ({}): the frames keep the numbers their times give, the missing ones are absent\n",
               dropped,
               fps > 0 ? fmt::format("the timestamps jump by more than one interval at {:.3f} frames/s", fps)
                       : std::string("the images' numbers skip them"));
}

void warnFigures(const report::Figures& f) {
  if (const std::string w = f.warning(); !w.empty()) fmt::print(stderr, "rsfm: warning: {}\n", w);
}

std::string wroteFigures(const report::Figures& f) {
  std::string out;
  for (const auto& n : f.written) out += ", " + n;
  return out;
}

}  // namespace rsfm::cli
