#include "rsfm/vision/frame_source.hpp"

#include "rsfm/track/tracks.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "rsfm/io/input_error.hpp"

namespace rsfm::vision {

namespace fs = std::filesystem;
using io::inputError;

namespace {

bool isImageFile(const fs::path& p) {
  std::string e = p.extension().string();
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return std::tolower(c); });
  return e == ".png" || e == ".jpg" || e == ".jpeg" || e == ".pgm" || e == ".ppm" || e == ".pnm" ||
         e == ".bmp" || e == ".tif" || e == ".tiff" || e == ".webp";
}

std::string formatPattern(const std::string& pattern, int i) {
  std::vector<char> buf(pattern.size() + 64);
  std::snprintf(buf.data(), buf.size(), pattern.c_str(), i);  // NOLINT: validated pattern
  return buf.data();
}

/// A pattern must contain exactly one integer conversion (%d, %04d, ...).
bool validPattern(const std::string& p) {
  int conversions = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    if (p[i] != '%') continue;
    if (i + 1 < p.size() && p[i + 1] == '%') {
      ++i;
      continue;
    }
    size_t j = i + 1;
    while (j < p.size() && (std::isdigit(static_cast<unsigned char>(p[j])))) ++j;
    if (j >= p.size() || p[j] != 'd') return false;
    ++conversions;
    i = j;
  }
  return conversions == 1;
}

}  // namespace

FrameSource::FrameSource(const std::string& input) : input_(input) {
  // FFmpeg's own decoder chatter ("decode_slice_header error") is not ours to print; decode
  // failures are detected and reported by read(). A user's setting wins.
  ::setenv("OPENCV_FFMPEG_LOGLEVEL", "-8", 0);
  std::error_code ec;
  if (input.find('%') != std::string::npos) {
    kind_ = Kind::Pattern;
    if (!validPattern(input))
      throw io::InputError(input + ": an image-sequence pattern needs exactly one integer field such as %04d");
    int start = -1;
    for (int i = 0; i <= 1000 && start < 0; ++i)
      if (fs::exists(formatPattern(input, i), ec)) start = i;
    if (start < 0) throw inputError(input, 0, "no image matches the pattern (tried indices 0..1000)");
    int i = start;
    while (fs::exists(formatPattern(input, i), ec)) files_.push_back(formatPattern(input, i++));
    for (int gap = 1; gap <= 10; ++gap)
      if (fs::exists(formatPattern(input, i + gap), ec))
        throw inputError(formatPattern(input, i), 0,
                         fmt::format("missing frame: the sequence stops at index {} but index {} exists", i - 1, i + gap));
    count_ = static_cast<int>(files_.size());
    return;
  }
  if (!fs::exists(input, ec)) throw inputError(input, 0, "no such file or directory");
  if (fs::is_directory(input, ec)) {
    kind_ = Kind::Folder;
    for (const auto& e : fs::directory_iterator(input, ec))
      if (e.is_regular_file() && isImageFile(e.path())) files_.push_back(e.path());
    if (files_.empty()) throw inputError(input, 0, "folder contains no images (png, jpg, pgm, ppm, bmp, tif)");
    std::sort(files_.begin(), files_.end());
    count_ = static_cast<int>(files_.size());
    return;
  }
  if (input.size() > 3 && input.substr(input.size() - 3) == ".gz")
    throw inputError(input, 0, "compressed file: decompress it first (e.g. zcat FILE.gz > FILE)");
  if (isImageFile(input)) throw inputError(input, 0, "a single image is not a sequence (give a folder or a pattern)");
  kind_ = Kind::Video;
  cap_ = std::make_unique<cv::VideoCapture>(input, cv::CAP_FFMPEG);
  if (!cap_->isOpened()) throw inputError(input, 0, "cannot be opened as a video");
  const double n = cap_->get(cv::CAP_PROP_FRAME_COUNT);
  count_ = n > 0 ? static_cast<int>(n) : -1;
  const double fps = cap_->get(cv::CAP_PROP_FPS);
  if (fps > 0 && fps <= ImageInfo::kMaxFps) {
    fps_ = fps;
    fps_known_ = true;
  }
  if (cap_->get(cv::CAP_PROP_ORIENTATION_AUTO) != 0) {
    const double meta = cap_->get(cv::CAP_PROP_ORIENTATION_META);
    const int deg = std::isfinite(meta) ? ((static_cast<int>(std::lround(meta)) % 360) + 360) % 360 : 0;
    if (deg == 90 || deg == 180 || deg == 270) rotation_ = deg;
  }
}

FrameSource::~FrameSource() = default;
FrameSource::FrameSource(FrameSource&&) noexcept = default;
FrameSource& FrameSource::operator=(FrameSource&&) noexcept = default;

bool FrameSource::read(cv::Mat* img) {
  if (kind_ == Kind::Video) {
    if (!cap_->read(*img) || img->empty()) {
      // Containers often over-count by one; a failure well before the declared end is a
      // corrupt or truncated stream.
      if (count_ > 0 && index_ + 1 < count_ - 1)
        throw inputError(input_, 0,
                         index_ >= 0 ? fmt::format("frame {} cannot be decoded (the video declares {} frames: a corrupt or "
                                                   "truncated stream; --last {} keeps the frames before it)",
                                                   index_ + 1, count_, index_)
                                     : fmt::format("frame 0 cannot be decoded (the video declares {} frames)", count_));
      if (index_ < 0) throw inputError(input_, 0, "no frame can be decoded");
      return false;
    }
  } else {
    if (index_ + 1 >= static_cast<int>(files_.size())) return false;
    const fs::path& f = files_[index_ + 1];
    *img = cv::imread(f.string(), cv::IMREAD_UNCHANGED);
    if (img->empty()) throw inputError(f, 0, fmt::format("frame {} cannot be decoded as an image", index_ + 1));
  }
  ++index_;
  if (kind_ == Kind::Video) {
    const double ms = cap_->get(cv::CAP_PROP_POS_MSEC);
    time_s_ = std::isfinite(ms) ? ms / 1000.0 : std::nan("");
  } else {
    time_s_ = std::nan("");
  }
  if (index_ == 0) {
    size_ = img->size();
  } else if (img->size() != size_) {
    throw inputError(kind_ == Kind::Video ? fs::path(input_) : files_[index_], 0,
                     fmt::format("frame {} is {}x{}, the first frame is {}x{}", index_, img->cols, img->rows,
                                 size_.width, size_.height));
  }
  return true;
}

cv::Mat toGray8(const cv::Mat& frame, cv::Mat* buffer) {
  if (frame.channels() == 1 && frame.depth() == CV_8U) return frame;
  cv::Mat gray = frame;
  if (frame.channels() == 3) {
    cv::cvtColor(frame, *buffer, cv::COLOR_BGR2GRAY);
    gray = *buffer;
  } else if (frame.channels() == 4) {
    cv::cvtColor(frame, *buffer, cv::COLOR_BGRA2GRAY);
    gray = *buffer;
  }
  if (gray.depth() != CV_8U) {
    cv::Mat g8;
    gray.convertTo(g8, CV_8U, gray.depth() == CV_16U ? 1.0 / 256.0 : 1.0);
    *buffer = g8;
    gray = g8;
  }
  return gray;
}

cv::Mat toGray8(const cv::Mat& frame) {
  cv::Mat buffer;
  return toGray8(frame, &buffer);
}

SourceInfo forEachFrame(const std::string& input, FrameRange range, const std::function<void(const cv::Mat&)>& fn,
                  const std::function<void(int, int)>& progress, const MinFrameSize& min_size) {
  FrameSource src(input);
  cv::Mat img;
  int total = -1;
  if (src.countHint() > 0) {
    const int end = range.last >= 0 ? std::min(range.last, src.countHint() - 1) : src.countHint() - 1;
    total = end - range.first + 1;
  }
  int used = 0;
  std::vector<double> times;  // of every frame decoded, from the stream's first
  while (src.read(&img)) {
    times.push_back(src.timeSeconds());
    // Every frame has the first one's size (FrameSource::read): one check covers them all.
    if (src.index() == 0 && std::min(img.cols, img.rows) < min_size.min_side)
      throw io::InputError(fmt::format("{}: frames are {}x{} px; {} at least {}x{}", io::printable(input, 300), img.cols,
                                       img.rows, min_size.who, min_size.min_side, min_size.min_side));
    if (src.index() < range.first) continue;
    if (range.last >= 0 && src.index() > range.last) break;
    fn(img);
    ++used;
    if (progress) progress(used, total > 0 ? std::max(total, used) : -1);
    if (src.index() == range.last) break;  // no read past the range (a corrupt frame after it is not ours)
  }
  if (used == 0)
    throw io::InputError(fmt::format("{}: the frame range starts at {} but the input has {} frames", input, range.first,
                                     src.index() + 1));
  if (used < 2) throw io::InputError(fmt::format("{}: only one frame in range; tracking needs at least 2", input));
  if (range.last >= 0 && src.index() < range.last && used < range.last - range.first + 1)
    throw io::InputError(fmt::format("{}: the frame range ends at {} but the input has only {} frames", input, range.last,
                                     src.index() + 1));
  const double stated = src.fpsKnown() ? src.fps() : 0.0;
  SourceInfo info{stated, src.rotation(), {}, stated};
  double interval = 0;
  // Up to the last frame used (a frame read past the range is not ours).
  const int last_used = range.last >= 0 ? std::min(src.index(), range.last) : src.index();
  times.resize(static_cast<size_t>(last_used + 1));
  if (std::vector<int> all = droppedFrameOffsets(times, &interval); !all.empty())
    info.frame_offsets.assign(all.begin() + range.first, all.end());
  if (!info.frame_offsets.empty() && interval > 0 && 1.0 / interval <= ImageInfo::kMaxFps)
    info.fps = std::round(1e6 / interval) / 1e6;  // the timestamps' millisecond rounding: 30, not 30.000000000000007
  return info;
}

std::vector<int> droppedFrameOffsets(const std::vector<double>& times_s, double* interval_s) {
  if (interval_s) *interval_s = 0;
  if (times_s.size() < 2) return {};
  std::vector<double> gaps;
  for (std::size_t i = 1; i < times_s.size(); ++i) {
    const double g = times_s[i] - times_s[i - 1];
    if (!std::isfinite(g) || !(g > 0)) return {};
    gaps.push_back(g);
  }
  std::vector<double> sorted = gaps;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  const double m = sorted[sorted.size() / 2];
  if (interval_s) *interval_s = m;
  std::vector<int> offsets{0};
  bool dropped = false;
  for (double g : gaps) {
    const long steps = std::max(1L, std::lround(g / m));
    dropped = dropped || steps > 1;
    if (offsets.back() > std::numeric_limits<int>::max() - steps) return {};
    offsets.push_back(offsets.back() + static_cast<int>(steps));
  }
  // The interval over the whole span (the median gap carries the timestamps' rounding: 33 or
  // 34 ms for 30 frames/s in milliseconds).
  if (interval_s) *interval_s = (times_s.back() - times_s.front()) / offsets.back();
  return dropped ? offsets : std::vector<int>{};
}

}  // namespace rsfm::vision
