#include "rsfm/track/patches.hpp"

#include <algorithm>

namespace rsfm {

const PatchObservation* PatchTracks::find(int k, int id) const {
  if (k < 0 || k >= numFrames()) return nullptr;
  const auto& f = frames[k];
  auto it = std::lower_bound(f.begin(), f.end(), id, [](const PatchObservation& p, int v) { return p.id < v; });
  return it != f.end() && it->id == id ? &*it : nullptr;
}

}  // namespace rsfm
