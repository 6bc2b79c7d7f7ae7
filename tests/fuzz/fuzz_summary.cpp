// Fuzz target: summary.json (io::readSummaryText). Round trip: summaryToJson of what was read
// reads back to the same summary and the same text.
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_common.hpp"
#include "rsfm/io/summary.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace rsfm;
  const std::string text(reinterpret_cast<const char*>(data), size);
  io::Summary s;
  try {
    s = io::readSummaryText(text, "fuzz.json");
  } catch (const io::InputError& e) {
    fuzz::checkMessage(e.what());
    return 0;
  }
  const std::string once = io::summaryToJson(s);
  io::Summary s2;
  try {
    s2 = io::readSummaryText(once, "written.json");
  } catch (const io::InputError& e) {
    fuzz::finding(std::string("rsfm cannot read back what it wrote: ") + e.what());
  }
  fuzz::check(s2.frames == s.frames && s2.width == s.width && s2.height == s.height &&
                  s2.principal_point_px == s.principal_point_px && s2.focal_px == s.focal_px &&
                  s2.plane_distances == s.plane_distances && s2.plane_tracks == s.plane_tracks &&
                  s2.plane_names == s.plane_names && s2.scene_size == s.scene_size && s2.distortion == s.distortion &&
                  s2.planes.size() == s.planes.size() && s2.determinable.has_value() == s.determinable.has_value(),
              "a field changed in the round trip");
  for (std::size_t i = 0; i < s.planes.size(); ++i) fuzz::check(s2.planes[i] == s.planes[i], "a normal changed in the round trip");
  fuzz::check(io::summaryToJson(s2) == once, "writing what was read back gives other text");
  return 0;
}
