#pragma once
// Wall-clock seconds for the run-time records (summary.json's `seconds` and `stage_seconds`, the
// refinement's and the bench's timings): std::chrono::steady_clock, so only differences mean
// anything. No I/O.
#include <chrono>

namespace rsfm {

/// Seconds on the monotonic clock since an unspecified origin.
inline double steadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace rsfm
