// Fuzz target: tracks.csv (io::readTracks). Round trip: what rsfm writes of what it read, it
// reads back identically (writeTracks(readTracks(writeTracks(t))) == writeTracks(t)).
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>

#include "fuzz_common.hpp"
#include "rsfm/io/tracks_io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace rsfm;
  std::istringstream in(std::string(reinterpret_cast<const char*>(data), size));
  Tracks t;
  try {
    t = io::readTracks(in, "fuzz.csv");
  } catch (const io::InputError& e) {
    fuzz::checkMessage(e.what());
    return 0;
  }
  const std::string once = io::tracksToString(t);
  std::istringstream again(once);
  Tracks t2;
  try {
    t2 = io::readTracks(again, "written.csv");
  } catch (const io::InputError& e) {
    fuzz::finding(std::string("rsfm cannot read back what it wrote: ") + e.what());
  }
  fuzz::check(t2.numFrames() == t.numFrames() && t2.first_frame == t.first_frame && t2.image.width == t.image.width &&
                  t2.image.height == t.image.height && t2.image.cx == t.image.cx && t2.image.cy == t.image.cy,
              "header changed in the round trip");
  for (int k = 0; k < t.numFrames(); ++k) {
    fuzz::check(t.frames[k].size() == t2.frames[k].size(), "rows changed in the round trip");
    for (std::size_t i = 0; i < t.frames[k].size(); ++i)
      fuzz::check(t.frames[k][i].id == t2.frames[k][i].id && (t.frames[k][i].px - t2.frames[k][i].px).cwiseAbs().maxCoeff() <= 5.001e-5,
                  "a row changed by more than the written precision (1e-4 px)");
  }
  fuzz::check(io::tracksToString(t2) == once, "writing what was read back gives other text");
  return 0;
}
