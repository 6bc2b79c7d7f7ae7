// All-or-nothing outputs (issue 17 item 4; include/rsfm/io/atomic_file.hpp).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "rsfm/io/atomic_file.hpp"
#include "rsfm/io/json_text.hpp"

namespace fs = std::filesystem;
using rsfm::io::AtomicFileSet;
using rsfm::io::OutputDir;

namespace {

struct TempRoot {
  fs::path dir;
  TempRoot() {
    std::string t = (fs::temp_directory_path() / "rsfm-outputs-XXXXXX").string();
    dir = ::mkdtemp(t.data());
  }
  ~TempRoot() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void put(const fs::path& p, const std::string& s) { std::ofstream(p) << s; }

/// Entries of `dir` whose names contain `part`.
int entriesWith(const fs::path& dir, const std::string& part) {
  int n = 0;
  for (const auto& e : fs::directory_iterator(dir)) n += e.path().filename().string().find(part) != std::string::npos;
  return n;
}

}  // namespace

TEST(OutputDir, NewTargetAppearsOnlyAtCommitWithTheMarker) {
  TempRoot root;
  const fs::path target = root.dir / "a" / "b" / "run";
  OutputDir od;
  ASSERT_EQ(od.open(target), "");
  EXPECT_FALSE(fs::exists(target));
  EXPECT_EQ(od.path().parent_path(), target.parent_path());
  struct stat st {};
  ASSERT_EQ(::stat(od.path().c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0700u) << "the staging directory is private";
  put(od.path() / "summary.json", "{}");
  od.commit();
  EXPECT_EQ(slurp(target / "summary.json"), "{}");
  EXPECT_TRUE(fs::exists(target / OutputDir::kMarker));
  EXPECT_EQ(entriesWith(target.parent_path(), ".rsfm-"), 0) << "no staging directory left";
}

TEST(OutputDir, AnEarlierRunIsReplacedWhole) {
  TempRoot root;
  const fs::path target = root.dir / "run";
  {
    OutputDir od;
    ASSERT_EQ(od.open(target), "");
    put(od.path() / "tracks.csv", "old");
    put(od.path() / "evaluation.json", "old");
    od.commit();
  }
  OutputDir od;
  ASSERT_EQ(od.open(target), "");
  put(od.path() / "summary.json", "new");
  od.commit();
  EXPECT_EQ(slurp(target / "summary.json"), "new");
  EXPECT_FALSE(fs::exists(target / "tracks.csv")) << "an earlier run's file beside the new one";
  EXPECT_FALSE(fs::exists(target / "evaluation.json"));
  EXPECT_EQ(entriesWith(root.dir, ".rsfm-"), 0);
}

TEST(OutputDir, WithoutCommitTheTargetStaysAsItWasAndNothingIsLeft) {
  TempRoot root;
  const fs::path target = root.dir / "run";
  {
    OutputDir od;
    ASSERT_EQ(od.open(target), "");
    put(od.path() / "summary.json", "good");
    od.commit();
  }
  {
    OutputDir od;
    ASSERT_EQ(od.open(target), "");
    put(od.path() / "summary.json", "half-written");
  }  // an error: no commit
  EXPECT_EQ(slurp(target / "summary.json"), "good");
  EXPECT_EQ(entriesWith(root.dir, ".rsfm-"), 0);
  // A failing command leaves no directory it created.
  {
    OutputDir od;
    ASSERT_EQ(od.open(root.dir / "x" / "y" / "run"), "");
  }
  EXPECT_FALSE(fs::exists(root.dir / "x"));
}

TEST(OutputDir, RefusesFilesItDidNotWriteAndPlainFiles) {
  TempRoot root;
  const fs::path home = root.dir / "home";
  fs::create_directories(home);
  put(home / "precious.txt", "keep");
  OutputDir od;
  const std::string why = od.open(home);
  EXPECT_NE(why.find("not an earlier rsfm output"), std::string::npos) << why;
  EXPECT_EQ(slurp(home / "precious.txt"), "keep");
  EXPECT_EQ(entriesWith(root.dir, ".rsfm-"), 0);
  put(root.dir / "afile", "x");
  OutputDir od2;
  EXPECT_NE(od2.open(root.dir / "afile").find("not a directory"), std::string::npos);
  OutputDir od3;
  EXPECT_NE(od3.open("/").find("root"), std::string::npos);
  // An empty directory is taken.
  fs::create_directories(root.dir / "empty");
  OutputDir od4;
  EXPECT_EQ(od4.open(root.dir / "empty"), "");
}

TEST(OutputDir, ASymlinkedTargetReplacesTheDirectoryItNames) {
  TempRoot root;
  fs::create_directories(root.dir / "real");
  fs::create_directory_symlink(root.dir / "real", root.dir / "link");
  OutputDir od;
  ASSERT_EQ(od.open(root.dir / "link"), "");
  put(od.path() / "summary.json", "x");
  od.commit();
  EXPECT_TRUE(fs::is_symlink(root.dir / "link"));
  EXPECT_EQ(slurp(root.dir / "real" / "summary.json"), "x");
}

TEST(AtomicFileSet, TemporariesAreFreshFilesAndAPlantedLinkIsReplacedNotFollowed) {
  TempRoot root;
  put(root.dir / "victim", "precious");
  fs::create_symlink(root.dir / "victim", root.dir / "evaluation.json");
  AtomicFileSet files;
  const fs::path a = files.write(root.dir / "evaluation.json", "{}");
  const fs::path b = files.temp(root.dir / "evaluation.json");
  EXPECT_NE(a, b);
  EXPECT_EQ(a.extension(), ".json");
  EXPECT_FALSE(fs::is_symlink(a));
  files.abort();
  EXPECT_FALSE(fs::exists(a));
  EXPECT_FALSE(fs::exists(b));
  AtomicFileSet again;
  again.write(root.dir / "evaluation.json", "{}");
  again.commit();
  EXPECT_EQ(slurp(root.dir / "victim"), "precious");
  EXPECT_FALSE(fs::is_symlink(root.dir / "evaluation.json"));
  EXPECT_EQ(slurp(root.dir / "evaluation.json"), "{}");
}

TEST(OutputDir, AnOutputFromBeforeTheMarkerIsRecognisedByItsFiles) {
  TempRoot root;
  for (const auto& [name, text] : {std::pair<std::string, std::string>{"summary.json", "{\n  \"format\": \"rsfm-summary\",\n}"},
                                   {"tracks.csv", "# rsfm-tracks 1\n# image_size 640 480\n"}}) {
    const fs::path d = root.dir / ("old-" + name);
    fs::create_directories(d);
    put(d / name, text);
    put(d / "motion.png", "png");
    OutputDir od;
    EXPECT_EQ(od.open(d), "") << name;
  }
  // A rendering from before the marker: truth/summary.json and the video.
  const fs::path r = root.dir / "rendered";
  fs::create_directories(r / "truth");
  put(r / "truth" / "summary.json", "{\n  \"format\": \"rsfm-summary\",\n}");
  put(r / "video.mp4", "mp4");
  OutputDir odr;
  EXPECT_EQ(odr.open(r), "");
  const fs::path d = root.dir / "lookalike";
  fs::create_directories(d);
  put(d / "summary.json", "{\"format\": \"someone-else\"}");
  OutputDir od;
  EXPECT_NE(od.open(d), "") << "a summary.json that is not rsfm's";
}

namespace rsfm {
namespace {

TEST(SummaryFields, AnUnboundedFocalIntervalSideIsNull) {
  // docs/outputs.md: focal_interval_px [lo, hi], a side the data do not limit null.
  const nlohmann::json any = io::focalIntervalJson(0.0, INFINITY);
  EXPECT_EQ(any.dump(), "[null,null]");
  EXPECT_EQ(io::focalIntervalText(any), "any focal length");
  EXPECT_EQ(io::focalIntervalBound(any, 0), 0.0);
  EXPECT_TRUE(std::isinf(io::focalIntervalBound(any, 1)));
  const nlohmann::json above = io::focalIntervalJson(192.0, INFINITY);
  EXPECT_EQ(above.dump(), "[192.0,null]");
  EXPECT_EQ(io::focalIntervalText(above), "at least 192 px");
  const nlohmann::json both = io::focalIntervalJson(313.2, 674.4);
  EXPECT_EQ(io::focalIntervalText(both, "&ndash;"), "313&ndash;674 px");
  EXPECT_EQ(io::focalIntervalBound(both, 1), 674.4);
  EXPECT_EQ(io::focalIntervalText(nlohmann::json::array({1.0})), "");
}

}  // namespace
}  // namespace rsfm
