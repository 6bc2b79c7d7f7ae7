#include "rsfm/track/tracks.hpp"

#include <algorithm>

namespace rsfm {

int Tracks::idBound() const {
  int b = 0;
  for (const auto& f : frames)
    for (const auto& p : f) b = std::max(b, p.id + 1);
  return b;
}

const TrackPoint* findById(const std::vector<TrackPoint>& points, int id) {
  auto it = std::lower_bound(points.begin(), points.end(), id, [](const TrackPoint& p, int v) { return p.id < v; });
  return (it != points.end() && it->id == id) ? &*it : nullptr;
}

const TrackPoint* Tracks::find(int k, int id) const {
  return (k < 0 || k >= numFrames()) ? nullptr : findById(frames[k], id);
}

std::vector<TrackSpan> trackSpans(const Tracks& t) {
  std::vector<TrackSpan> s(t.idBound());
  for (int k = 0; k < t.numFrames(); ++k)
    for (const auto& p : t.frames[k]) {
      if (s[p.id].first < 0) s[p.id].first = k;
      s[p.id].last = k;
    }
  return s;
}

std::vector<std::array<int, 2>> Tracks::skippedStretches() const {
  std::vector<std::array<int, 2>> out;
  for (int k = 0; k + 1 < numFrames(); ++k)
    if (frameNumber(k + 1) > frameNumber(k) + 1) out.push_back({frameNumber(k) + 1, frameNumber(k + 1) - 1});
  return out;
}

std::vector<std::array<int, 2>> consecutiveStretches(const std::vector<int>& sorted) {
  std::vector<std::array<int, 2>> out;
  for (std::size_t i = 0; i < sorted.size();) {
    std::size_t j = i;
    while (j + 1 < sorted.size() && sorted[j + 1] == sorted[j] + 1) ++j;
    out.push_back({sorted[i], sorted[j]});
    i = j + 1;
  }
  return out;
}

std::size_t dropObservationsAfter(Tracks* t, const std::vector<int>& last) {
  std::size_t dropped = 0;
  for (std::size_t k = 0; k < t->frames.size(); ++k) {
    std::vector<TrackPoint>& f = t->frames[k];
    const auto end = std::remove_if(f.begin(), f.end(), [&](const TrackPoint& p) {
      const int l = p.id >= 0 && static_cast<std::size_t>(p.id) < last.size() ? last[static_cast<std::size_t>(p.id)] : -1;
      return l >= 0 && static_cast<int>(k) > l;
    });
    dropped += static_cast<std::size_t>(f.end() - end);
    f.erase(end, f.end());
  }
  return dropped;
}

int trimLeadingEmptyFrames(Tracks* t) {
  const std::size_t n = leadingEmptyFrames(t->frames);
  if (n == 0 || n == t->frames.size()) return 0;
  const auto k = static_cast<std::ptrdiff_t>(n);
  t->frames.erase(t->frames.begin(), t->frames.begin() + k);
  if (t->frame_numbers.empty()) t->first_frame += static_cast<int>(n);
  else t->frame_numbers.erase(t->frame_numbers.begin(), t->frame_numbers.begin() + k), t->first_frame = t->frame_numbers.front();
  return static_cast<int>(n);
}

const char* readoutDirectionName(ReadoutDirection d) {
  switch (d) {
    case ReadoutDirection::Up: return "up";
    case ReadoutDirection::Right: return "right";
    case ReadoutDirection::Left: return "left";
    case ReadoutDirection::Down: break;
  }
  return "down";
}

bool parseReadoutDirection(const std::string& name, ReadoutDirection* d) {
  for (ReadoutDirection c : kReadoutDirections)
    if (name == readoutDirectionName(c)) {
      *d = c;
      return true;
    }
  return false;
}

ReadoutDirection readoutDirectionAfterRotation(int degrees) {
  // Turned clockwise by 90, (x, y) -> (h - 1 - y, x): row 0 becomes the right column.
  switch (((degrees % 360) + 360) % 360) {
    case 90: return ReadoutDirection::Left;
    case 180: return ReadoutDirection::Up;
    case 270: return ReadoutDirection::Right;
    default: return ReadoutDirection::Down;
  }
}

double ImageInfo::readoutOffset(const Eigen::Vector2d& px) const {
  const bool rows = readout_direction == ReadoutDirection::Down || readout_direction == ReadoutDirection::Up;
  const double extent = rows ? height : width;
  if (extent <= 0) return 0.0;
  const double s = ((rows ? px.y() : px.x()) - (extent - 1.0) / 2.0) / extent;
  return readout_direction == ReadoutDirection::Down || readout_direction == ReadoutDirection::Right ? s : -s;
}

Eigen::Vector2d rollingShutterShift(const Tracks& t, int k, const TrackPoint& p) {
  if (t.image.height <= 0 || t.image.width <= 0) return Eigen::Vector2d::Zero();
  const TrackPoint* a = t.find(k - 1, p.id);
  const TrackPoint* b = t.find(k + 1, p.id);
  const TrackPoint& lo = a ? *a : p;
  const TrackPoint& hi = b ? *b : p;
  const int dk = t.frameNumber(b ? k + 1 : k) - t.frameNumber(a ? k - 1 : k);
  if (dk <= 0) return Eigen::Vector2d::Zero();  // seen in this frame only: no velocity
  return t.image.readoutOffset(p.px) * (hi.px - lo.px) / dk;
}

Tracks correctRollingShutter(const Tracks& t, double readout) {
  Tracks out = t;
  if (readout == 0.0 || t.image.height <= 0 || t.image.width <= 0) return out;
  for (int k = 0; k < t.numFrames(); ++k)
    for (std::size_t i = 0; i < t.frames[k].size(); ++i)
      out.frames[k][i].px -= readout * rollingShutterShift(t, k, t.frames[k][i]);
  return out;
}

}  // namespace rsfm
