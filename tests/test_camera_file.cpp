// Camera files (vision/camera_file.hpp): what calibration tools write is read; the malformed
// inputs on which OpenCV 4.6's FileStorage crashes, allocates without bound or loops forever are
// refused before it sees them (issue 17; tests/fuzz/corpus/camera/finding_*).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include <opencv2/calib3d.hpp>

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

TEST(CameraFile, ReadsRosCameraInfoAndKalibrAndEurocYaml) {
  using rsfm::vision::readCameraText;
  // ROS camera_calibration's camera_info (no %YAML:1.0, plain rows/cols/data maps).
  const auto ros = readCameraText(slurp(kCorpus / "ros_camera_info.yaml"), "ost.yaml");
  EXPECT_EQ(ros.width, 640);
  EXPECT_EQ(ros.height, 480);
  EXPECT_DOUBLE_EQ(ros.fx, 521.25);
  EXPECT_DOUBLE_EQ(ros.fy, 520.75);
  EXPECT_DOUBLE_EQ(ros.cy, 244.125);
  EXPECT_EQ(ros.distortion, (std::vector<double>{-0.125, 0.0625, 0.001, -0.002, 0.0}));
  // EuRoC's sensor.yaml: intrinsics [fu, fv, cu, cv] and radial-tangential [k1, k2, p1, p2] at the
  // top level, beside a 4 x 4 extrinsic spread over lines and a comment after a value.
  const auto euroc = readCameraText(slurp(kCorpus / "euroc_sensor.yaml"), "sensor.yaml");
  EXPECT_EQ(euroc.width, 752);
  EXPECT_DOUBLE_EQ(euroc.fx, 455.5);
  EXPECT_DOUBLE_EQ(euroc.fy, 454.25);
  EXPECT_DOUBLE_EQ(euroc.cx, 370.125);
  EXPECT_DOUBLE_EQ(euroc.cy, 245.5);
  EXPECT_EQ(euroc.distortion, (std::vector<double>{-0.275, 0.0725, 0.0002, 1.5e-05}));
  // Kalibr's camchain: the first camera (cam0), not the second; block-sequence extrinsics skipped.
  const auto kalibr = readCameraText(slurp(kCorpus / "kalibr_camchain.yaml"), "camchain.yaml");
  EXPECT_DOUBLE_EQ(kalibr.fx, 460.5);
  EXPECT_DOUBLE_EQ(kalibr.cy, 246.5);
  EXPECT_EQ(kalibr.distortion, (std::vector<double>{-0.25, 0.0625, 0.0005, -0.0005}));
  std::string camchain = slurp(kCorpus / "kalibr_camchain.yaml");
  const auto replaced = [](std::string t, const std::string& from, const std::string& to) {
    t.replace(t.find(from), from.size(), to);
    return t;
  };
  // A comment after a quoted value, and a '#' inside quotes, are read as YAML reads them.
  const auto quoted = readCameraText(
      replaced(slurp(kCorpus / "ros_camera_info.yaml"), "distortion_model: plumb_bob", "distortion_model: \"plumb_bob\"  # \"ROS\""),
      "ost.yaml");
  EXPECT_EQ(quoted.distortion.size(), 5u);
  EXPECT_NO_THROW(readCameraText(replaced(camchain, "rostopic: /cam0/image_raw", "rostopic: '/cam0 #1'"), "camchain.yaml"));
  // A file built to cost memory quadratic in its size (a long parent key copied into each of its
  // children's paths): refused at its first long key, at once (below).
  std::string bomb = "intrinsics: [1, 2, 3, 4]\n" + std::string(400000, 'a') + ":\n";
  for (int i = 0; i < 100000; ++i) bomb += " b: 1\n";
  // What rsfm cannot undistort, and broken files: refused, naming the file and the problem.
  const std::vector<std::pair<std::string, std::string>> bad = {
      {replaced(camchain, "distortion_model: radtan", "distortion_model: equidistant"), "distortion model 'equidistant'"},
      {replaced(camchain, "camera_model: pinhole", "camera_model: omni"), "camera model 'omni' is not a pinhole"},
      {replaced(camchain, "intrinsics: [460.5, 459.5, 362.5, 246.5]", "intrinsics: [460.5, 459.5, 362.5]"), "[fu, fv, cu, cv]"},
      {replaced(camchain, "intrinsics: [460.5, 459.5, 362.5, 246.5]", "intrinsics: [460.5, 400, 362.5, 246.5]"), "differ by more than 1 %"},
      {replaced(camchain, "intrinsics: [460.5, 459.5, 362.5, 246.5]", "intrinsics: [460.5, 459.5, 362.5, 246.5"), "never closed"},
      {replaced(camchain, "resolution: [752, 480]\n  rostopic: /cam0", "resolution: [752, x]\n  rostopic: /cam0"), "is not a number"},
      {replaced(slurp(kCorpus / "ros_camera_info.yaml"), "data: [521.25, 0, 322.5, 0, 520.75, 244.125, 0, 0, 1]",
                "data: [521.25, 0, 322.5, 0, 520.75, 244.125]"), "9 entries"},
      {replaced(slurp(kCorpus / "ros_camera_info.yaml"), "image_width: 640", "image_width: 200"), "outside the 200x480 image"},
      {bomb, "longer than"},
  };
  for (const auto& [text, expect] : bad) {
    try {
      readCameraText(text, "cam.yaml");
      ADD_FAILURE() << expect << ": accepted";
    } catch (const rsfm::io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("cam.yaml: "), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
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

TEST(CameraFile, TurnsWithAVideosRotation) {
  // A camera calibrated on its 640 x 480 frames, then a video of it with 90/180/270-degree
  // rotation metadata (OpenCV's reader turns the frames clockwise; 90: (x, y) -> (h - 1 - y, x)).
  // The turned calibration must project every point where the turned frame shows it: the points
  // projected with the original (tangential terms and unequal focal lengths included) and turned
  // as pixels, against the same points turned with the camera and projected with the turned one.
  rsfm::vision::CameraCalibration cal;
  cal.width = 640;
  cal.height = 480;
  cal.fx = 600;
  cal.fy = 610;
  cal.cx = 331.5;
  cal.cy = 228.25;
  cal.distortion = {-0.2, 0.05, 0.003, -0.002, 0.01};
  cal.source = "cal.yaml";
  auto project = [](const rsfm::vision::CameraCalibration& c, const std::vector<cv::Point3d>& X) {
    std::vector<cv::Point2d> out;
    cv::projectPoints(X, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cv::Matx33d(c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1),
                      c.distortion, out);
    return out;
  };
  std::vector<cv::Point3d> X;
  for (double x = -0.5; x <= 0.5; x += 0.25)
    for (double y = -0.35; y <= 0.35; y += 0.175) X.emplace_back(x, y, 1.0);
  const std::vector<cv::Point2d> seen = project(cal, X);
  for (const int deg : {90, 180, 270}) {
    const rsfm::vision::CameraCalibration t = rsfm::vision::rotateCalibration(cal, deg);
    EXPECT_EQ(t.width, deg == 180 ? 640 : 480);
    std::vector<cv::Point3d> Xt = X;  // the scene turned with the image: 90 cw, (x, y) -> (-y, x)
    std::vector<cv::Point2d> expect = seen;
    for (int q = 0; q < deg / 90; ++q)
      for (std::size_t i = 0; i < X.size(); ++i) {
        Xt[i] = cv::Point3d(-Xt[i].y, Xt[i].x, Xt[i].z);
        const int h = q % 2 == 0 ? cal.height : cal.width;  // the height of the frame being turned
        expect[i] = cv::Point2d(h - 1 - expect[i].y, expect[i].x);
      }
    const std::vector<cv::Point2d> got = project(t, Xt);
    double worst = 0;
    for (std::size_t i = 0; i < X.size(); ++i) worst = std::max(worst, cv::norm(got[i] - expect[i]));
    EXPECT_LT(worst, 1e-9) << deg << " degrees";
  }
  // The tracks' frames say which way: 480 x 640 tracks going left take the 90-degree turn;
  // tracks on their side that do not say are refused, naming the file and both sizes.
  rsfm::ImageInfo portrait = rsfm::ImageInfo::centred(480, 640);
  portrait.readout_direction = rsfm::ReadoutDirection::Left;
  EXPECT_EQ(rsfm::vision::calibrationForTracks(cal, portrait).cx, 480 - 1 - cal.cy);
  portrait.readout_direction = rsfm::ReadoutDirection::Down;
  try {
    rsfm::vision::calibrationForTracks(cal, portrait);
    ADD_FAILURE() << "tracks on their side taken without a direction";
  } catch (const rsfm::io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cal.yaml: the calibration is for 640x480 images, the tracks are 480x640"),
              std::string::npos)
        << e.what();
  }
  EXPECT_EQ(rsfm::vision::calibrationForTracks(cal, rsfm::ImageInfo::centred(640, 480)).cx, cal.cx);
  cal.distortion.resize(12, 0.0);
  cal.distortion[9] = 1e-3;  // a thin-prism term
  EXPECT_THROW(rsfm::vision::rotateCalibration(cal, 90), rsfm::io::InputError);
}
