#pragma once
// Where the scene starts to move (issue 14 item 1; docs/estimate.md section 0): the frames before
// are still (the camera and every object where they were in the first frame), and the pipeline
// takes its reference frame at the last of them.
#include <array>
#include <vector>

#include "rsfm/track/tracks.hpp"

namespace rsfm::vision {

struct StillStart {
  /// Frames after the first that are still: frames 0..still_frames show the first frame's scene
  /// from the first frame's camera, and the motion starts at frame still_frames + 1 (indices into
  /// the tracks' frames). 0: the first frame pair already moves, or nothing ever moves.
  int still_frames = 0;
  /// The tracking noise the test measured: per axis, the sd of the frame 0 -> 1 displacements
  /// around their least-median-of-squares homography (px; sqrt 2 x one observation's noise; 0
  /// when fewer than 8 tracks span the pair). A still pair's displacements are noise only, a
  /// moving pair's are a homography of the dominant surface plus noise and the other surfaces'
  /// parallax at that short baseline (an upper bound).
  double noise_px = 0.0;
  /// A track has moved once it is this far from its still position (px): max(still_px,
  /// 4 noise_px), which noise alone passes with probability exp(-8).
  double threshold_px = 0.0;
  /// At the first moving frame: the tracks that showed it (all the frame's tracks when the
  /// dominant surface moved; 0: nothing moved).
  int moving_tracks = 0;
  /// false: no frame moves.
  bool moves = false;
  /// Later still frames (indices into the tracks' frames, increasing): each belongs to a stretch
  /// of at least kMinHeldFrames frames in which nothing moved from the frame before the stretch
  /// (the same tests as the start's, against that frame's tracks), and shows that frame's scene
  /// from that frame's camera. A still camera's frames repeat its tracker's errors: they add no
  /// information, and an estimator that takes them as new observations grows sure of nothing.
  std::vector<int> held;
};

/// The held frames as stretches: [first, last] indices into the tracks' frames, one per run of
/// consecutive held frames.
std::vector<std::array<int, 2>> heldStretches(const StillStart& s);

/// Shortest later still stretch that is held (a third of a second at 30 fps): a slow motion
/// leaves a few frames still against the frame before them (0.6 px of dominant motion at
/// 0.1-0.2 px per frame: 3-6 frames), then moves on; those stay in.
inline constexpr int kMinHeldFrames = 10;

/// The still start of `tracks`. Frame k (k = 1, 2, ...) moves the scene when, over the tracks
/// alive in frames 0 and k,
///  (a) the dominant motion - their RANSAC homography from frame 0 to k - displaces them by a
///      median of more than still_px (and more than 4 x its own fit's noise at the median,
///      noise_px sqrt(8 / n) per axis): a camera that moves, turns or shakes, or an object that
///      fills most of the view; a homography averages the tracks' independent noise away, so
///      0.25 px of coherent motion shows under 0.5 px of noise; or
///  (b) at least `min_tracks` (a plane's worth, kHomographyTestTracks) are more than threshold_px
///      from their still positions: an object before a still background; a few tracks that jump
///      (a tracker's swaps) do not move the scene.
/// A track's still position is its mean over the still frames so far (frame 0 alone would give a
/// track whose frame-0 position is off by its noise a new chance to pass the threshold in every
/// frame).
/// still_frames = the last frame before the first such k that tested still (a frame with fewer
/// than 8 tracks shared with the still run cannot be tested, and is not taken as still). After it, the same tests against the last frame
/// that moved find the later still stretches (`held`). The tests' limit: an object before a
/// still background that moves less than threshold_px in kMinHeldFrames frames is taken as
/// still there (negligible with a tracker's usual noise, 0.25 px; at 0.5 px of noise per
/// observation the threshold is 2.5 px), and so is a camera whose dominant motion stays under
/// the test's 0.25-0.3 px for 10 frames (0.025 px per frame). noise_px comes from the first
/// pair even when it moves (then an upper bound: the other surfaces' parallax): it widens the
/// thresholds, never narrows them. `still_px` <= 0 turns the test off (still_frames
/// 0, moves true). Throws std::invalid_argument when still_px is NaN or min_tracks < 1.
StillStart findStillStart(const Tracks& tracks, double still_px, int min_tracks);

}  // namespace rsfm::vision
