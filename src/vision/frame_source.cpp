#include "rsfm/vision/frame_source.hpp"

#include "rsfm/track/tracks.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <numeric>
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

/// An image name's stem split as <prefix><digits[.digits]><suffix> (e.g. "frame_", "0017", "", ""), neither
/// prefix nor suffix holding a digit; false when the stem has no such one number.
struct NameNumber {
  std::string prefix, integer, fraction, suffix;  // fraction: the digits after '.', may be empty
};
bool splitNameNumber(const std::string& stem, NameNumber* n) {
  const auto digit = [](char c) { return c >= '0' && c <= '9'; };
  const std::size_t a = std::find_if(stem.begin(), stem.end(), digit) - stem.begin();
  if (a == stem.size()) return false;
  std::size_t b = a;
  while (b < stem.size() && digit(stem[b])) ++b;
  std::size_t e = b;
  if (b + 1 < stem.size() && stem[b] == '.' && digit(stem[b + 1])) {
    e = b + 1;
    while (e < stem.size() && digit(stem[e])) ++e;
  }
  if (std::any_of(stem.begin() + static_cast<long>(e), stem.end(), digit)) return false;
  n->prefix = stem.substr(0, a);
  n->integer = stem.substr(a, b - a);
  n->fraction = e > b ? stem.substr(b + 1, e - b - 1) : std::string();
  n->suffix = stem.substr(e);
  return true;
}

/// Compares two runs of decimal digits as numbers (any length: leading zeros skipped, then the
/// length, then the digits).
int compareDigits(const std::string& a, const std::string& b) {
  const std::size_t za = std::min(a.find_first_not_of('0'), a.size()), zb = std::min(b.find_first_not_of('0'), b.size());
  const std::size_t la = a.size() - za, lb = b.size() - zb;
  if (la != lb) return la < lb ? -1 : 1;
  const int c = a.compare(za, la, b, zb, lb);
  return c < 0 ? -1 : (c > 0 ? 1 : 0);
}

/// Natural order: runs of digits compared as numbers, the rest as characters; equal so far, the
/// plain comparison decides (img01 and img1 keep one order).
bool naturalLess(const std::string& a, const std::string& b) {
  const auto digit = [](char c) { return c >= '0' && c <= '9'; };
  std::size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (digit(a[i]) && digit(b[j])) {
      std::size_t i2 = i, j2 = j;
      while (i2 < a.size() && digit(a[i2])) ++i2;
      while (j2 < b.size() && digit(b[j2])) ++j2;
      if (const int c = compareDigits(a.substr(i, i2 - i), b.substr(j, j2 - j)); c != 0) return c < 0;
      i = i2;
      j = j2;
    } else {
      if (a[i] != b[j]) return a[i] < b[j];
      ++i;
      ++j;
    }
  }
  if ((i < a.size()) != (j < b.size())) return j < b.size();
  return a < b;
}

}  // namespace

NamedFrames orderImageFiles(std::vector<fs::path> files) {
  NamedFrames out;
  std::vector<NameNumber> nums(files.size());
  bool numbered = !files.empty();
  for (std::size_t i = 0; i < files.size() && numbered; ++i)
    numbered = splitNameNumber(files[i].stem().string(), &nums[i]) && nums[i].prefix == nums[0].prefix &&
               nums[i].suffix == nums[0].suffix && files[i].extension() == files[0].extension();
  if (!numbered) {
    std::sort(files.begin(), files.end(), [](const fs::path& a, const fs::path& b) { return naturalLess(a.filename().string(), b.filename().string()); });
    out.files = std::move(files);
    return out;
  }
  std::vector<std::size_t> order(files.size());
  std::iota(order.begin(), order.end(), 0);
  // By the number: the integer parts as numbers, then the fractions digit by digit.
  const auto cmp = [&](std::size_t x, std::size_t y) {
    if (const int c = compareDigits(nums[x].integer, nums[y].integer); c != 0) return c;
    std::string fx = nums[x].fraction, fy = nums[y].fraction;
    const std::size_t w = std::max(fx.size(), fy.size());
    fx.resize(w, '0');
    fy.resize(w, '0');
    const int c = fx.compare(fy);
    return c < 0 ? -1 : (c > 0 ? 1 : 0);
  };
  std::sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) { return cmp(x, y) < 0; });
  for (std::size_t i = 1; i < order.size(); ++i)
    if (cmp(order[i - 1], order[i]) == 0)
      throw io::InputError(fmt::format("{} and {}: two images with one number in their names (which comes first?)",
                                       io::printable(files[order[i - 1]].string(), 300),
                                       io::printable(files[order[i]].string(), 300)));
  for (std::size_t i : order) out.files.push_back(files[i]);
  const bool fractional = std::any_of(nums.begin(), nums.end(), [](const NameNumber& n) { return !n.fraction.empty(); });
  // Long double carries a 19-digit integer exactly (64-bit mantissa): nanoseconds since 1970.
  const auto value = [&](std::size_t i) {
    return std::strtold((nums[i].integer + (nums[i].fraction.empty() ? "" : "." + nums[i].fraction)).c_str(), nullptr);
  };
  const long double first = value(order[0]), last = value(order.back());
  // Integers: epochs (since 1970, between 2001 and 2286) when first and last lie in one range:
  // 13 digits milliseconds, 16 microseconds, 19 nanoseconds (EuRoC's, ROS's); frame numbers
  // below 10^12 (no frame counter reaches it); anything else no time (a date written as digits,
  // 20230615123456: its steps across a minute or an hour are no frame gaps), ordered only.
  const auto within = [&](long double lo, long double hi) { return first >= lo && last < hi; };
  const long double unit = fractional               ? 1.0L
                           : within(1e17L, 1e19L)   ? 1e-9L
                           : within(1e15L, 1e16L)   ? 1e-6L
                           : within(1e12L, 1e13L)   ? 1e-3L
                                                    : 0.0L;
  if (unit == 0.0L) {
    if (last >= 1e12L) return out;  // no time: kind None, ordered by the number
    out.kind = TimeKind::FrameNumbers;
    for (std::size_t i : order) out.times.push_back(static_cast<double>(value(i) - first));
    return out;
  }
  // Seconds beyond what a timestamp can be (a date written as digits, 20230615123456.789; an
  // epoch in milliseconds with a fraction): the names give the order, not a time.
  if (!(first * unit <= ImageInfo::kMaxTimeOrigin)) {
    out.kind = TimeKind::None;
    return out;
  }
  out.kind = TimeKind::Seconds;
  for (std::size_t i : order) out.times.push_back(static_cast<double>((value(i) - first) * unit));
  out.origin_s = static_cast<double>(first * unit);
  return out;
}

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
    NamedFrames named = orderImageFiles(std::move(files_));
    files_ = std::move(named.files);
    time_kind_ = named.kind;
    file_times_ = std::move(named.times);
    time_origin_ = named.origin_s;
    // Images named by their times: their average rate for the videos rsfm writes of them (the
    // overlay), not 30; still not a rate the source states (fpsKnown).
    if (time_kind_ == TimeKind::Seconds && file_times_.size() > 1 && file_times_.back() > 0 &&
        (file_times_.size() - 1) / file_times_.back() <= ImageInfo::kMaxFps)
      fps_ = static_cast<double>(file_times_.size() - 1) / file_times_.back();
    count_ = static_cast<int>(files_.size());
    return;
  }
  if (input.size() > 3 && input.substr(input.size() - 3) == ".gz")
    throw inputError(input, 0, "compressed file: decompress it first (e.g. zcat FILE.gz > FILE)");
  if (isImageFile(input)) throw inputError(input, 0, "a single image is not a sequence (give a folder or a pattern)");
  kind_ = Kind::Video;
  time_kind_ = TimeKind::Seconds;
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
    time_s_ = static_cast<std::size_t>(index_) < file_times_.size() ? file_times_[static_cast<std::size_t>(index_)] : std::nan("");
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
    times.push_back(src.time());
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
  SourceInfo info{stated, src.rotation(), {}, stated, src.timeOrigin()};
  double interval = 0;
  // Up to the last frame used (a frame read past the range is not ours).
  const int last_used = range.last >= 0 ? std::min(src.index(), range.last) : src.index();
  times.resize(static_cast<size_t>(last_used + 1));
  if (std::vector<int> all = droppedFrameOffsets(times, &interval); !all.empty())
    info.frame_offsets.assign(all.begin() + range.first, all.end());
  // The rate: a video's timestamps give it when frames were dropped (the container's average
  // counts the drops); images named in seconds give it always (nothing else states one). Image
  // names that number the frames give no rate.
  const bool named_seconds = src.timesFromNames() && src.timeKind() == TimeKind::Seconds;
  const auto rounded = [](double rate) { return std::round(rate * 1e6) / 1e6; };  // 30, not 30.000000000000007
  if ((named_seconds || !info.frame_offsets.empty()) && src.timeKind() == TimeKind::Seconds && interval > 0 &&
      1.0 / interval <= ImageInfo::kMaxFps)
    info.fps = rounded(1.0 / interval);
  if (named_seconds && info.fps > 0 && last_used > 0 && times[static_cast<size_t>(last_used)] > times[0])
    info.stated_fps = rounded(last_used / (times[static_cast<size_t>(last_used)] - times[0]));
  if (info.fps == 0) info.time_origin_s = 0;  // an origin only for timestamps in seconds
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
  std::sort(sorted.begin(), sorted.end());
  const double m0 = sorted[sorted.size() / 2];  // the median gap
  // The timestamps' resolution q: the smallest step between distinct gap values (1 ms for
  // images named in milliseconds or a container counting them), at most half the median gap;
  // ~0 for timestamps that jitter continuously.
  double q = 0;
  for (std::size_t i = 1; i < sorted.size(); ++i)
    if (const double d = sorted[i] - sorted[i - 1]; d > 1e-9 * m0) q = q == 0 ? d : std::min(q, d);
  q = std::min(q, 0.5 * m0) * (1 + 1e-9);
  // The interval: the mean of the gaps near the median (the median alone carries the rounding:
  // 400 frames/s in milliseconds has gaps of 2 and 3 ms, and a median of 2 ms made every 3 ms gap
  // a dropped frame).
  double sum = 0;
  int near = 0;
  for (double g : gaps)
    if (std::abs(g - m0) <= std::max(q, 0.25 * m0)) sum += g, ++near;
  const double m = sum / near;  // near >= 1: the median itself
  if (interval_s) *interval_s = m;
  std::vector<int> offsets{0};
  bool dropped = false;
  for (double g : gaps) {
    // A gap within the resolution of the interval is one step; the others round.
    const long steps = std::abs(g - m) <= q ? 1L : std::max(1L, std::lround(g / m));
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
