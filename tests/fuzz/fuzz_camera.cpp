// Fuzz target: camera files (vision::readCameraText, OpenCV FileStorage YAML/XML/JSON). Round
// trip: the camera.yaml rsfm writes of a camera it read (square pixels, radial k1, k2) reads back
// to the same camera.
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_common.hpp"
#include "rsfm/vision/camera_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace rsfm;
  const std::string text(reinterpret_cast<const char*>(data), size);
  vision::CameraCalibration c;
  try {
    c = vision::readCameraText(text, "fuzz.yaml");
  } catch (const io::InputError& e) {
    fuzz::checkMessage(e.what());
    return 0;
  }
  const double k1 = c.distortion.size() > 0 ? c.distortion[0] : 0.0, k2 = c.distortion.size() > 1 ? c.distortion[1] : 0.0;
  const std::string yaml = io::cameraYaml(c.width, c.height, c.focal(), c.cx, c.cy, k1, k2);
  vision::CameraCalibration c2;
  try {
    c2 = vision::readCameraText(yaml, "camera.yaml");
  } catch (const io::InputError& e) {
    fuzz::finding(std::string("rsfm cannot read back the camera.yaml it wrote: ") + e.what());
  }
  fuzz::check(c2.width == c.width && c2.height == c.height && c2.fx == c.focal() && c2.fy == c.focal() && c2.cx == c.cx &&
                  c2.cy == c.cy && c2.distortion.size() == 5 && c2.distortion[0] == k1 && c2.distortion[1] == k2,
              "the camera changed in the round trip");
  return 0;
}
