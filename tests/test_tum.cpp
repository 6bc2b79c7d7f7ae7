// TUM trajectory and summary.json I/O: round trips, and every malformed input names FILE:LINE.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "rsfm/io/summary.hpp"
#include "rsfm/io/tum.hpp"

namespace rsfm::io {
namespace {
namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() {
    path_ = fs::temp_directory_path() / ("rsfm_test_tum_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
                                         "_" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  fs::path file(const std::string& name, const std::string& text) const {
    std::ofstream(path_ / name, std::ios::binary) << text;
    return path_ / name;
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

TEST(Tum, RoundTripKeepsFullPrecision) {
  std::mt19937 rng(42);
  std::normal_distribution<double> n(0, 1);
  std::vector<TumPose> poses;
  for (int k = 0; k < 50; ++k) {
    TumPose p;
    p.t = k;
    p.p = Eigen::Vector3d(n(rng), n(rng), n(rng)) * 3.7;
    p.q = Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng)).normalized();  // w may be negative
    poses.push_back(p);
  }
  std::ostringstream os;
  writeTum(os, poses);
  TempDir d;
  const auto back = readTum(d.file("t.tum", os.str()));
  ASSERT_EQ(back.size(), poses.size());
  for (std::size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(back[i].t, poses[i].t);
    EXPECT_EQ(back[i].p, poses[i].p);  // shortest round-trip form: exact
    EXPECT_GE(back[i].q.w(), 0.0);
    Eigen::Quaterniond q = poses[i].q;
    if (q.w() < 0) q.coeffs() = -q.coeffs();
    EXPECT_LT((back[i].q.coeffs() - q.coeffs()).norm(), 1e-15);
  }
}

TEST(Tum, CommentsBlankLinesAndCrlfAreAccepted) {
  TempDir d;
  const auto p = readTum(d.file("t.tum", "# header\n\n0 0 0 0 0 0 0 1\r\n  # indented comment\n1 1 2 3 0 0 0.7071067811865476 0.7071067811865476\n"));
  ASSERT_EQ(p.size(), 2u);
  EXPECT_EQ(p[1].p, Eigen::Vector3d(1, 2, 3));
  EXPECT_NEAR(p[1].q.z(), std::sqrt(0.5), 1e-15);
}

struct BadCase {
  const char* name;
  const char* text;
  int line;
  const char* words;
};

TEST(Tum, EveryMalformedInputNamesFileAndLine) {
  const BadCase cases[] = {
      {"too_few_fields", "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", 2, "expected 8 numbers"},
      {"too_many_fields", "0 0 0 0 0 0 0 1 5\n", 1, "expected 8 numbers"},
      {"not_a_number", "# c\n0 0 0 0 0 0 0 1\n1 0 x 0 0 0 0 1\n", 3, "field ty ('x') is not a number"},
      {"trailing_garbage", "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1abc\n", 2, "field qw ('1abc') is not a number"},
      {"nan", "0 0 0 0 0 0 0 1\n1 nan 0 0 0 0 0 1\n", 2, "field tx is not finite"},
      {"inf", "0 0 0 0 0 0 0 1\n1 0 0 -inf 0 0 0 1\n", 2, "field tz is not finite"},
      {"non_unit_quaternion", "0 0 0 0 0 0 0 1\n\n1 0 0 0 0 0 0 1.01\n", 3, "quaternion norm 1.01 is not 1"},
      {"zero_quaternion", "0 0 0 0 0 0 0 0\n", 1, "quaternion norm 0 is not 1"},
      {"equal_timestamps", "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", 3, "not greater than the previous one"},
      {"decreasing_timestamps", "0 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", 3, "not greater"},
      {"empty_file", "", 1, "empty trajectory"},
      {"only_comments", "# a\n# b\n\n", 3, "empty trajectory"},
  };
  TempDir d;
  for (const BadCase& c : cases) {
    const fs::path f = d.file(std::string(c.name) + ".tum", c.text);
    try {
      readTum(f);
      ADD_FAILURE() << c.name << ": no error";
    } catch (const InputError& e) {
      const std::string what = e.what();
      const std::string prefix = f.string() + ":" + std::to_string(c.line) + ": ";
      EXPECT_EQ(what.rfind(prefix, 0), 0u) << c.name << ": " << what;
      EXPECT_NE(what.find(c.words), std::string::npos) << c.name << ": " << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << c.name;
    }
  }
}

TEST(Tum, MissingFileIsAnInputError) {
  TempDir d;
  EXPECT_THROW(readTum(d.path() / "nope.tum"), InputError);
  static_assert(std::is_base_of_v<std::runtime_error, InputError>);
}

Summary sampleSummary() {
  Summary s;
  s.frames = 150;
  s.width = 640;
  s.height = 480;
  s.principal_point_px = {319.5, 239.5};
  s.focal_px = 520;
  s.planes = {Eigen::Vector3d(0.1, 0.9, 0.3).normalized(), Eigen::Vector3d(-0.6, 0.2, 0.7).normalized()};
  s.plane_distances = {1.25, 2.5};
  s.plane_names = {"floor", "box_front"};
  s.plane_visible_frames = {150, 150};
  s.scene_size = 1.46;
  return s;
}

TEST(Summary, RoundTrip) {
  const Summary s = sampleSummary();
  TempDir d;
  const Summary r = readSummary(d.file("summary.json", summaryToJson(s)));
  EXPECT_EQ(r.frames, s.frames);
  EXPECT_EQ(r.width, s.width);
  EXPECT_EQ(r.height, s.height);
  EXPECT_EQ(r.principal_point_px, s.principal_point_px);
  EXPECT_EQ(r.focal_px, s.focal_px);
  ASSERT_EQ(r.planes.size(), 2u);
  for (int i = 0; i < 2; ++i) EXPECT_LT((r.planes[i] - s.planes[i]).norm(), 1e-15);
  EXPECT_EQ(r.plane_distances, s.plane_distances);
  EXPECT_EQ(r.plane_names, s.plane_names);
  EXPECT_EQ(r.scene_size, s.scene_size);
  EXPECT_TRUE(r.plane_tracks.empty());
}

TEST(Summary, ErrorsNameTheFile) {
  TempDir d;
  const std::string good = summaryToJson(sampleSummary());
  // JSON syntax error on line 3.
  {
    const fs::path f = d.file("a.json", "{\n \"format\": \"rsfm-summary\",\n \"version\": ,\n}\n");
    try {
      readSummary(f);
      ADD_FAILURE();
    } catch (const InputError& e) {
      EXPECT_EQ(std::string(e.what()).rfind(f.string() + ":3: invalid JSON", 0), 0u) << e.what();
    }
  }
  struct C {
    std::string from, to, words;
  };
  const C cases[] = {{"\"focal_px\": 520", "\"focal_px\": -1", "focal_px"},
                     {"\"frames\": 150", "\"frame\": 150", "missing key \"frames\""},
                     {"\"rsfm-summary\"", "\"other\"", "format"},
                     {"1.25", "1.25, 3", "\"plane_distances\" has 3 entries"}};
  for (const C& c : cases) {
    std::string text = good;
    const auto pos = text.find(c.from);
    ASSERT_NE(pos, std::string::npos) << c.from;
    text.replace(pos, c.from.size(), c.to);
    const fs::path f = d.file("b.json", text);
    try {
      readSummary(f);
      ADD_FAILURE() << c.to;
    } catch (const InputError& e) {
      const std::string w = e.what();
      EXPECT_EQ(w.rfind(f.string() + ": ", 0), 0u) << w;
      EXPECT_NE(w.find(c.words), std::string::npos) << w;
    }
  }
}

}  // namespace
}  // namespace rsfm::io
