#pragma once
// Runs the (noise level x trial) jobs of an experiment on a pool of threads. Results are written
// by job index, and each job's noise stream is seeded by (seed, trial, noise level value), so
// runs are reproducible whatever the thread count and whatever other levels run alongside.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "rsfm/sim/table1_scene.hpp"

namespace rsfm {

/// Seed of the noise of `trial` at `noise_px` (in 1/1000 px, not its position in the list).
inline std::uint64_t noiseSeed(std::uint64_t seed, int trial, double noise_px) {
  const auto key = static_cast<std::uint64_t>(std::llround(noise_px * 1000.0)) + 1;
  return mixSeed(seed, static_cast<std::uint64_t>(trial), key);
}

/// The checks every experiment makes of its trial count, noise levels and frame count; an empty
/// string when they are fine, else a one-line message.
inline std::string validateTrialsNoiseFrames(int trials, const std::vector<double>& noise_px, int frames) {
  if (trials < 1) return "--trials must be at least 1";
  if (noise_px.empty()) return "at least one noise level is required";
  for (double s : noise_px)
    if (!(s >= 0.0) || !std::isfinite(s)) return "noise levels must be finite and non-negative";
  if (frames < 1) return "--frames must be at least 1";
  return {};
}

/// Calls job(level, trial) for every level < levels and trial < trials on `threads` threads
/// (0: all cores); `progress(done, total)` is serialized.
inline void runJobs(int levels, int trials, int threads, const std::function<void(int, int)>& job,
                    const std::function<void(int, int)>& progress) {
  const int total = levels * trials;
  std::atomic<int> next{0}, done{0};
  std::mutex mu;
  int n = threads > 0 ? threads : static_cast<int>(std::thread::hardware_concurrency());
  n = std::clamp(n, 1, std::max(1, total));
  auto worker = [&] {
    for (int j; (j = next.fetch_add(1)) < total;) {
      job(j / trials, j % trials);
      const int d = ++done;
      if (progress) {
        std::lock_guard<std::mutex> lk(mu);
        progress(d, total);
      }
    }
  };
  std::vector<std::thread> pool;
  for (int k = 0; k < n; ++k) pool.emplace_back(worker);
  for (auto& th : pool) th.join();
}

}  // namespace rsfm
