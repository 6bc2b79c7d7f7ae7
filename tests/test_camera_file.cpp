// Camera files (vision/camera_file.hpp): what calibration tools write is read; the malformed
// inputs on which OpenCV 4.6's FileStorage crashes, allocates without bound or loops forever are
// refused before it sees them (issue 17; tests/fuzz/corpus/camera/finding_*).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "rsfm/io/camera_yaml.hpp"
#include "rsfm/io/input_error.hpp"
#include "rsfm/vision/camera_file.hpp"

namespace {

const std::filesystem::path kCorpus = std::filesystem::path(RSFM_SOURCE_DIR) / "tests/fuzz/corpus/camera";

std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

TEST(CameraFile, ReadsWhatCalibrationToolsAndRsfmWrite) {
  using rsfm::vision::readCameraText;
  const auto sample = readCameraText(slurp(kCorpus / "opencv_calibration_sample.yaml"), "sample.yaml");
  EXPECT_DOUBLE_EQ(sample.focal(), 530.0);
  ASSERT_EQ(sample.distortion.size(), 5u);  // a 5 x 1 matrix over two lines
  EXPECT_DOUBLE_EQ(sample.distortion[4], -1.1e-2);
  EXPECT_DOUBLE_EQ(readCameraText(slurp(kCorpus / "camera.xml"), "camera.xml").cx, 320.0);
  const std::string own = rsfm::io::cameraYaml(640, 480, 612.5, 319.5, 239.5, -0.1, 0.02,
                                               {"source: \"estimated by rsfm's refinement (docs/estimate.md)\"",
                                                "focal_determined: 1", "principal_point_sd_px: [ 1.5, 2 ]"});
  const auto c = readCameraText(own, "camera.yaml");
  EXPECT_EQ(c.width, 640);
  EXPECT_DOUBLE_EQ(c.focal(), 612.5);
  EXPECT_DOUBLE_EQ(c.distortion[0], -0.1);
  EXPECT_FALSE(c.rolling_shutter_readout);  // a calibration says nothing of its shutter
  // rsfm's camera.yaml with a determined readout (and one not determined, as a comment only).
  const auto rs = readCameraText(rsfm::io::cameraYaml(640, 480, 612.5, 319.5, 239.5, -0.1, 0.02,
                                                      {"rolling_shutter_readout: 0.97", "rolling_shutter_readout_sd: 0.08",
                                                       "# rolling shutter readout 0.4 +- 0.3: not determined"}),
                                 "camera.yaml");
  ASSERT_TRUE(rs.rolling_shutter_readout);
  EXPECT_DOUBLE_EQ(*rs.rolling_shutter_readout, 0.97);
  const auto comment = readCameraText(
      rsfm::io::cameraYaml(640, 480, 612.5, 319.5, 239.5, -0.1, 0.02, {"# rolling shutter readout 0.4 +- 0.3: not determined"}),
      "camera.yaml");
  EXPECT_FALSE(comment.rolling_shutter_readout);
  // Beyond 2 frame intervals, or not a number: refused, naming the file.
  for (const char* bad : {"rolling_shutter_readout: 2.5", "rolling_shutter_readout: abc"}) {
    try {
      readCameraText(rsfm::io::cameraYaml(640, 480, 612.5, 319.5, 239.5, -0.1, 0.02, {bad}), "cam.yaml");
      ADD_FAILURE() << bad << " accepted";
    } catch (const rsfm::io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("cam.yaml: "), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("rolling_shutter_readout"), std::string::npos) << e.what();
    }
  }
}

TEST(CameraFile, RefusesWhatOpenCvsParserCannotSurvive) {
  for (const char* name : {"finding_opencv_yaml_hang.yaml", "finding_opencv_xml_truncated_decl.xml",
                           "finding_opencv_xml_segv.xml", "finding_opencv_xml_split_tag.xml", "finding_huge_matrix.yaml", "finding_opencv_length_error.yaml"}) {
    try {
      rsfm::vision::readCameraText(slurp(kCorpus / name), name);
      ADD_FAILURE() << name << " was accepted";
    } catch (const rsfm::io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
}
