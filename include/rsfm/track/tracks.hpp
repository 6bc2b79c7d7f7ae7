#pragma once
// Feature tracks in pixels: what the tracker produces and the estimators consume (docs/tracks.md).
// Pixel convention: x right, y down, (0, 0) the centre of the top-left pixel (OpenCV's).
// No I/O here: the file format lives in rsfm/io/tracks_io.hpp.
#include <Eigen/Core>

#include <array>
#include <cstddef>

#include <string>
#include <vector>

namespace rsfm {

/// The way a rolling shutter's readout travels across the image (docs/estimate.md section 6): a
/// sensor reads its rows top to bottom (`Down`), but a video whose container asks for a rotation
/// (a phone held upright: 90 or 270 degrees) is decoded turned, so the sensor's rows are the
/// image's columns. Names: "down", "up", "right" (the left column first), "left".
enum class ReadoutDirection { Down, Up, Right, Left };
inline constexpr ReadoutDirection kReadoutDirections[] = {ReadoutDirection::Down, ReadoutDirection::Up,
                                                          ReadoutDirection::Right, ReadoutDirection::Left};
/// The name of `d` ("down", ...).
const char* readoutDirectionName(ReadoutDirection d);
/// The direction named `name`; false when it is none of the four.
bool parseReadoutDirection(const std::string& name, ReadoutDirection* d);
/// The direction of a sensor's rows after the decoder turned the frames clockwise by `degrees`
/// (0, 90, 180, 270; a video's rotation metadata, which OpenCV applies): 90 puts the first row
/// in the right column, so the readout goes left. Other angles: Down.
ReadoutDirection readoutDirectionAfterRotation(int degrees);

/// Image size and principal point (pixels), and the source's frame rate.
struct ImageInfo {
  int width = 0;
  int height = 0;
  double cx = 0.0;  ///< principal point x (default: (width - 1) / 2)
  double cy = 0.0;  ///< principal point y (default: (height - 1) / 2)
  /// Frames per second of the source (a video's rate; tracks.csv's '# fps'); 0 when unknown (an
  /// image sequence, a tracks file without the key). Timestamps: docs/outputs.md.
  double fps = 0.0;
  /// The rolling shutter's readout direction in this image (tracks.csv's '# readout_direction';
  /// absent: Down). The tracker sets it from a video's rotation.
  ReadoutDirection readout_direction = ReadoutDirection::Down;
  /// The time of the stream's first frame (frame number 0), seconds, when the source gives one
  /// (images named by their timestamps, docs/tracks.md "Image folders"; tracks.csv's
  /// '# time_origin'); 0 otherwise. Only with fps > 0.
  double time_origin = 0.0;
  /// The largest frame rate rsfm takes from a video or a file (frames per second).
  static constexpr double kMaxFps = 1000.0;
  /// The largest time origin rsfm takes (seconds; `rsfm evaluate` reads timestamps up to it).
  static constexpr double kMaxTimeOrigin = 1e11;
  /// A width x height image with the default principal point, the image centre.
  static ImageInfo centred(int width, int height) { return {width, height, (width - 1) / 2.0, (height - 1) / 2.0}; }
  /// Where the readout reaches the point `px`: its offset along readout_direction from the
  /// readout's middle, over the image's extent that way, in [-1/2, 1/2) (0 without a size).
  double readoutOffset(const Eigen::Vector2d& px) const;
  /// The timestamp of frame `frame` (frame numbers of the input, the first frame 0): seconds,
  /// time_origin + frame / fps, when the frame rate is known, else the frame number itself.
  double timestamp(int frame) const { return fps > 0 ? time_origin + frame / fps : static_cast<double>(frame); }
};

/// One tracked feature in one frame.
struct TrackPoint {
  int id = 0;                                    ///< track id, >= 0, unique within a frame
  Eigen::Vector2d px = Eigen::Vector2d::Zero();  ///< position in pixels
};

/// The point with track id `id` in `points` (sorted by id), or nullptr.
const TrackPoint* findById(const std::vector<TrackPoint>& points, int id);

/// Tracks of one sequence. frames[k] holds the points seen in frame first_frame + k, sorted by id.
struct Tracks {
  ImageInfo image;
  int first_frame = 0;
  std::vector<std::vector<TrackPoint>> frames;
  std::string source;  ///< what was tracked (informative)
  /// Empty: frames[k] is frame first_frame + k. Otherwise frames[k] is frame frame_numbers[k]
  /// (increasing): a sequence with frames left out (rsfm::estimate()'s still frames; a video
  /// that dropped frames, numbered by its timestamps: then the tracker leaves first_frame at
  /// frames[0]'s decoded index, which the overlay reads the video by; tracks.csv's
  /// '# dropped_frames').
  std::vector<int> frame_numbers;

  int numFrames() const { return static_cast<int>(frames.size()); }
  /// The frame number of frames[k].
  int frameNumber(int k) const { return frame_numbers.empty() ? first_frame + k : frame_numbers[static_cast<size_t>(k)]; }
  /// The frame numbers between frames[k] and frames[k + 1] that the tracks skip (a video's
  /// dropped frames, held still frames), as [first, last] stretches in increasing order.
  std::vector<std::array<int, 2>> skippedStretches() const;
  /// 1 + the largest track id (0 when empty).
  int idBound() const;
  /// Position of track `id` in frame index k (0-based within `frames`), or nullptr.
  const TrackPoint* find(int k, int id) const;
};

/// Runs of consecutive numbers in `sorted` (increasing) as [first, last] pairs: 3 4 5 9 -> [3, 5]
/// [9, 9] (held frames, frames with no observation).
std::vector<std::array<int, 2>> consecutiveStretches(const std::vector<int>& sorted);

/// Per-track summary: first and last frame index (0-based within Tracks::frames), length.
struct TrackSpan {
  int first = -1;
  int last = -1;
  int length() const { return first < 0 ? 0 : last - first + 1; }
};
std::vector<TrackSpan> trackSpans(const Tracks& t);

/// The number of frames before the first one with an observation (all of them when none has
/// one): a frames vector of Tracks or PatchTracks.
template <class Frames>
std::size_t leadingEmptyFrames(const Frames& frames) {
  std::size_t n = 0;
  while (n < frames.size() && frames[n].empty()) ++n;
  return n;
}

/// Removes each track's observations after frame index `last[id]` (ids with -1, or beyond the
/// vector: none removed); returns how many observations went. The plane finder's cuts
/// (vision::PlaneFinding::cut_after: where a track left its plane).
std::size_t dropObservationsAfter(Tracks* t, const std::vector<int>& last);

/// Leaves out the frames before the first one with a track (a video that fades in from black,
/// featureless frames: nothing to estimate from, and the reference frame needs tracks); returns
/// how many. first_frame (or frame_numbers) follows. A sequence without any track is left as is.
int trimLeadingEmptyFrames(Tracks* t);

/// The largest rolling-shutter readout taken, either way (frame intervals): a sensor reads its
/// rows within about one frame interval (the first-order correction's best fit can exceed it a
/// little: box.mp4's windows fit best at 1-1.5, docs/regimes.md). A known readout beyond it is
/// refused (EstimateOptions::rolling_shutter_readout, a camera file's); an estimate beyond it is
/// the data pulling the camera where no camera is, and the refinement holds the readout at 0.
inline constexpr double kMaxRollingShutterReadout = 2.0;

/// A rolling shutter's first-order correction (docs/estimate.md section 6, "A rolling shutter"):
/// a sensor that reads its rows one after another over `readout` frame intervals (0: a global
/// shutter; the middle row at the frame's time) sees a point moving at v px/frame at
/// x_gs + readout s v, s = ImageInfo::readoutOffset (with the readout down the image,
/// (y - (height - 1) / 2) / height). Each observation is moved back by that, v its
/// own track's velocity by central differences over the neighbouring frames (one-sided at a
/// track's ends; a track seen in one frame is left as it is), in the tracks' pixel frame (before
/// any undistortion: the row is the sensor's). Frame numbers, ids and the image are unchanged.
Tracks correctRollingShutter(const Tracks& t, double readout);

/// What a rolling shutter adds to the observation `p` of frame k per frame interval of readout:
/// s v (s = ImageInfo::readoutOffset), pixels, v its track's velocity as correctRollingShutter's
/// (zero for a track seen in one frame or an image without a height). The refinement's readout
/// parameter moves each prediction by readout times this (docs/estimate.md section 6).
Eigen::Vector2d rollingShutterShift(const Tracks& t, int k, const TrackPoint& p);

}  // namespace rsfm
