// Fuzz target: TUM trajectories (io::readTum). Round trip: what rsfm writes of what it read, it
// reads back identically (the sign of q may flip: the writer makes qw >= 0).
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>

#include "fuzz_common.hpp"
#include "rsfm/io/tum.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace rsfm;
  std::istringstream in(std::string(reinterpret_cast<const char*>(data), size));
  std::vector<io::TumPose> p;
  try {
    p = io::readTum(in, "fuzz.tum");
  } catch (const io::InputError& e) {
    fuzz::checkMessage(e.what());
    return 0;
  }
  std::ostringstream os;
  io::writeTum(os, p);
  std::istringstream again(os.str());
  std::vector<io::TumPose> p2;
  try {
    p2 = io::readTum(again, "written.tum");
  } catch (const io::InputError& e) {
    fuzz::finding(std::string("rsfm cannot read back what it wrote: ") + e.what());
  }
  fuzz::check(p2.size() == p.size(), "pose count changed in the round trip");
  for (std::size_t i = 0; i < p.size(); ++i) {
    fuzz::check(p2[i].t == p[i].t && p2[i].p == p[i].p, "a timestamp or position changed in the round trip");
    fuzz::check(p2[i].q.coeffs() == p[i].q.coeffs() || p2[i].q.coeffs() == -p[i].q.coeffs(),
                "a rotation changed in the round trip");
  }
  std::ostringstream os2;
  io::writeTum(os2, p2);
  fuzz::check(os2.str() == os.str(), "writing what was read back gives other text");
  return 0;
}
