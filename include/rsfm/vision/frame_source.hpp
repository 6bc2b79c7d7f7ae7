#pragma once
// Frames from a video file, an image-sequence pattern (printf style, e.g. frames/img%04d.png) or
// a folder of images (in the order of the numbers in their names, docs/tracks.md "Image
// folders"). Errors are InputError naming the file (and frame).
#include <opencv2/core.hpp>
#include <opencv2/videoio.hpp>

#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace rsfm::vision {

/// Frame range of a run: frames first..last of the input (0-based, inclusive; last < 0: to the end).
struct FrameRange {
  int first = 0;
  int last = -1;
};

/// What FrameSource::time() counts.
enum class TimeKind {
  None,          ///< no time (a pattern; a folder whose names carry no one number)
  Seconds,       ///< seconds: a video's presentation times; image names in seconds (TUM: 1305031102.175304.png), milliseconds, microseconds or nanoseconds (EuRoC, ROS: 1403636579763555584.png) since 1970
  FrameNumbers,  ///< image names that number the frames (000123.png, frame_17.jpg): the unit is one frame
};

/// The order of image files in a folder and what their names say of time: when every name is
/// `<prefix><number><suffix>` with one prefix and one suffix (neither holding a digit), the files
/// are ordered by the number and `times` holds it (relative to the first file's; `origin_s` the
/// first's in seconds when the kind is Seconds); else they are ordered by name with runs of
/// digits compared as numbers (img2.png before img10.png) and the kind is None. A number with a
/// fractional part is seconds; integers are epochs when they all lie in one of [1e12, 1e13)
/// (milliseconds), [1e15, 1e16) (microseconds) or [1e17, 1e19] (nanoseconds), frame numbers below
/// 1e12, and no time otherwise (a date written as digits, 20230615123456: kind None, ordered by
/// the number, no frame gaps read); seconds beyond ImageInfo::kMaxTimeOrigin are no time either.
/// Two files with one number throw InputError naming both.
struct NamedFrames {
  std::vector<std::filesystem::path> files;
  TimeKind kind = TimeKind::None;
  std::vector<double> times;  ///< per file, from the first (seconds or frames); empty with None
  double origin_s = 0.0;      ///< the first file's time in seconds (Seconds only)
};
NamedFrames orderImageFiles(std::vector<std::filesystem::path> files);

class FrameSource {
 public:
  /// Opens `input`; throws io::InputError when it is missing, unreadable or not a video/images.
  explicit FrameSource(const std::string& input);
  ~FrameSource();
  FrameSource(FrameSource&&) noexcept;
  FrameSource& operator=(FrameSource&&) noexcept;

  /// Reads the next frame (BGR or gray as stored) into `img`; returns false at the end.
  /// Throws io::InputError on a frame that cannot be decoded or whose size differs from the first.
  bool read(cv::Mat* img);
  /// Index of the frame last returned by read() (0-based).
  int index() const { return index_; }
  /// Number of frames if known (video container's count or number of images), else -1.
  int countHint() const { return count_; }
  /// Frames per second: the video's when its container states one; for images named by their
  /// times, their average rate; else 30 (for writing videos).
  double fps() const { return fps_; }
  /// Whether fps() is the source's own rate (a video that states it), not the default.
  bool fpsKnown() const { return fps_known_; }
  const std::string& description() const { return input_; }
  /// Degrees clockwise (0, 90, 180, 270) by which the decoder turned the frames: a video's
  /// rotation metadata, which OpenCV's FFmpeg reader applies (CAP_PROP_ORIENTATION_META with
  /// CAP_PROP_ORIENTATION_AUTO); 0 for images.
  int rotation() const { return rotation_; }
  /// The time of the frame last returned by read(), from the stream's first frame, in the unit
  /// of timeKind(): a video's presentation time (seconds; NaN when the container gives none), a
  /// folder's number from its image names (orderImageFiles); NaN for a pattern.
  double time() const { return time_s_; }
  TimeKind timeKind() const { return time_kind_; }
  /// Whether the times come from the images' names (a folder; orderImageFiles), not a video.
  bool timesFromNames() const { return kind_ == Kind::Folder && time_kind_ != TimeKind::None; }
  /// The stream's first frame's time in seconds where the names give it (a folder of images
  /// named by their timestamps), else 0: the time `time()` counts from.
  double timeOrigin() const { return time_origin_; }

 private:
  enum class Kind { Video, Pattern, Folder } kind_ = Kind::Video;
  std::string input_;
  std::unique_ptr<cv::VideoCapture> cap_;
  std::vector<std::filesystem::path> files_;  // Folder and Pattern
  int index_ = -1;
  int count_ = -1;
  double fps_ = 30.0;
  bool fps_known_ = false;
  int rotation_ = 0;
  double time_s_ = 0.0;
  TimeKind time_kind_ = TimeKind::None;
  std::vector<double> file_times_;  // Folder: orderImageFiles' times
  double time_origin_ = 0.0;
  cv::Size size_;
};

/// 8-bit single-channel version of a frame (BGR, BGRA, gray; 16-bit scaled by 1/256).
cv::Mat toGray8(const cv::Mat& frame);
/// The same, converted into `buffer` (reused when it has the frame's size); returns the grey
/// image, which is `frame` itself (no copy) when the frame is already 8-bit grey.
cv::Mat toGray8(const cv::Mat& frame, cv::Mat* buffer);

/// The smallest frame a consumer works in (issue 17: 8x8 images and --window 100001 ended in
/// OpenCV assertions): `min_side` px on each side; `who` completes "FILE: frames are WxH px;
/// <who> at least NxN" (e.g. "tracking with a 11 px window ... needs").
struct MinFrameSize {
  int min_side = 0;
  std::string who;
};

/// What forEachFrame learnt of its source.
struct SourceInfo {
  /// The source's frame rate when it states one (FrameSource::fpsKnown), else 0; with frames
  /// dropped, 1 / the interval of droppedFrameOffsets (a container's average rate counts the
  /// drops: 28.5 for a 30 frames/s video missing 3 of 60).
  double fps = 0.0;
  int rotation = 0;  ///< FrameSource::rotation
  /// Empty when the frames up to the last one used follow one another at one interval; else, per
  /// frame used, its number counted by the timestamps from the stream's first frame (0) in frame
  /// intervals (droppedFrameOffsets over every frame decoded): a video that dropped frames. The
  /// range's first/last stay decoded frames' indices.
  std::vector<int> frame_offsets;
  /// The rate the source states (FrameSource::fpsKnown), else 0, whatever the timestamps say: for
  /// a consumer that keeps the decoded numbering (the patch tracker). For images named by their
  /// timestamps, the average rate (frames - 1 over the span), as a container states it.
  double stated_fps = 0.0;
  /// The stream's first frame's time in seconds (FrameSource::timeOrigin): the timestamps'
  /// origin, 0 but for images named by their timestamps.
  double time_origin_s = 0.0;
};

/// The frames a video dropped, from its frames' timestamps (seconds, in order): each frame's
/// offset from the first in frame intervals (the mean of the gaps between consecutive timestamps
/// that lie within the timestamps' resolution, or a quarter of the median gap, of the median
/// gap), each at least one more than the one before: one for a gap within the resolution of the
/// interval, else round(gap / interval). The resolution is the smallest step between distinct
/// gaps (1 ms for timestamps in milliseconds), at most half the median gap. Empty when
/// no frame is more than half an interval late (nothing dropped), or when a timestamp is missing,
/// not finite or not after the one before (nothing to go by). `interval_s` (may be null): the
/// interval, the timestamps' span over the offsets' (0 when there is none).
std::vector<int> droppedFrameOffsets(const std::vector<double>& times_s, double* interval_s = nullptr);

/// Calls `fn` on every frame of `input` in `range`, in order; `progress(done, total)` after each
/// (total = -1 when unknown). Throws io::InputError on bad input, frames smaller than `min_size`,
/// a range that starts after the end or ends after it, or fewer than 2 frames.
SourceInfo forEachFrame(const std::string& input, FrameRange range, const std::function<void(const cv::Mat&)>& fn,
                  const std::function<void(int, int)>& progress = {}, const MinFrameSize& min_size = {});

}  // namespace rsfm::vision
