#include "rsfm/track/patches.hpp"

#include <algorithm>

namespace rsfm {

const PatchObservation* PatchTracks::find(int k, int id) const {
  if (k < 0 || k >= numFrames()) return nullptr;
  const auto& f = frames[k];
  auto it = std::lower_bound(f.begin(), f.end(), id, [](const PatchObservation& p, int v) { return p.id < v; });
  return it != f.end() && it->id == id ? &*it : nullptr;
}

int trimLeadingEmptyFrames(PatchTracks* t) {
  const std::size_t n = leadingEmptyFrames(t->frames);
  if (n == 0 || n == t->frames.size()) return 0;
  t->frames.erase(t->frames.begin(), t->frames.begin() + static_cast<std::ptrdiff_t>(n));
  t->first_frame += static_cast<int>(n);
  return static_cast<int>(n);
}

}  // namespace rsfm
