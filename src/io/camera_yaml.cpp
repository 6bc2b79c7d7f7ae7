#include "rsfm/io/camera_yaml.hpp"

#include <fmt/format.h>

namespace rsfm::io {

std::string cameraYaml(int width, int height, double focal, double cx, double cy, double k1, double k2,
                       const std::vector<std::string>& extra) {
  std::string s = "%YAML:1.0\n---\n";
  s += fmt::format("image_width: {}\nimage_height: {}\n", width, height);
  s += fmt::format(
      "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {:.17g}, 0., {:.17g}, 0., {:.17g}, {:.17g}, "
      "0., 0., 1. ]\n",
      focal, cx, focal, cy);
  s += fmt::format("distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ {:.17g}, {:.17g}, 0., 0., 0. ]\n",
                   k1, k2);
  for (const auto& e : extra) s += e + "\n";
  return s;
}

}  // namespace rsfm::io
