#pragma once
// The estimation pipeline on tracks (docs/estimate.md): what `rsfm estimate` and `rsfm run` run,
// as library calls. The CLI only parses options into these structs and writes the results' files
// (io/estimate_report.hpp, io/patch_report.hpp); a program calling estimate() on the same tracks
// with the same options gets the same numbers (tests/test_pipeline.cpp).
//
//  estimate():        plane finding (vision/plane_finder.hpp) -> the homography start
//                     (vision/plane_init.hpp) -> the recursive filter (pipeline/track_filter.hpp).
//  estimatePatches(): the focal start from homographies of the patch centres -> Calway's patch
//                     filter (pipeline/patch_pipeline.hpp).
// Uses OpenCV through the vision front end: lives in rsfm_pipeline, not in rsfm_core.
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>

#include "rsfm/pipeline/motion_check.hpp"
#include "rsfm/pipeline/patch_pipeline.hpp"
#include "rsfm/pipeline/refine.hpp"
#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/track/patches.hpp"
#include "rsfm/track/tracks.hpp"
#include "rsfm/vision/camera_file.hpp"
#include "rsfm/vision/plane_finder.hpp"
#include "rsfm/vision/plane_init.hpp"
#include "rsfm/vision/still_start.hpp"

namespace rsfm {

struct EstimateOptions {
  /// The recursive filter: model (point | plane | planes), known or initial focal length, tracking
  /// noise, process noise, passes... Its beta_sd0 and normal_sd0, when unset, follow the start:
  /// 0.1 after a homography start, TrackFilterOptions' guess values without one.
  TrackFilterOptions filter;
  /// Plane finding. The `plane` model keeps the dominant plane only (max_planes = 1) unless
  /// manual polygons (rois) are given.
  vision::PlaneFinderOptions finder;
  /// Plane models: start the focal length (unless known), the normals and the relative distances
  /// from the plane finder's homographies. false: every plane frontal at filter.focal0_px.
  bool homography_start = true;
  /// The final refinement (pipeline/refine.hpp; plane models only): on by default.
  RefineOptions refine;
  /// A calibrated camera (vision/camera_file.hpp): the tracks are undistorted with it before
  /// anything else, its focal length is known (filter.focal_px must then be 0) and its principal
  /// point and distortion are held in the refinement.
  std::optional<vision::CameraCalibration> camera;
  /// A rolling shutter's known readout time, in frame intervals (the time from the first row to
  /// the last; docs/estimate.md section 6, "A rolling shutter"): the tracks are moved to a global
  /// shutter's positions with their own velocities (correctRollingShutter, rsfm/track/tracks.hpp)
  /// before anything else, and the refinement does not estimate it (0: a known global shutter).
  /// At most kMaxRollingShutterReadout either way. Unset (the default): the refinement estimates
  /// it (RefineOptions::estimate_readout).
  std::optional<double> rolling_shutter_readout;
  /// The way the readout travels across the image (ImageInfo::readout_direction): unset, the
  /// tracks' own (down, or from a video's rotation metadata, which the decoder applied: a phone
  /// video held upright reads its rows along the image's columns).
  std::optional<ReadoutDirection> readout_direction;
  /// A known principal point (px): the tracks' image's is replaced by it and held.
  std::optional<Eigen::Vector2d> principal_point;
  /// The still start (issue 14 item 1, vision/still_start.hpp, docs/estimate.md section 0):
  /// frames are still until the tracks' dominant homography moves them by more than still_px
  /// (and its fit's noise) or a plane's worth of tracks (kHomographyTestTracks) are more than
  /// max(still_px, 4 x the measured tracking noise) from their still positions; the reference
  /// frame is the last still one and the frames before it carry its pose. Later stretches of at
  /// least vision::kMinHeldFrames still frames are left out of every stage and carry the pose of
  /// the frame before them. 0.25 px is PatchPipelineOptions::still_px's value: the ViSP cube's
  /// KLT tracks jitter by 0.02 px over its 16 still frames, its first moving frame moved 0.3 px.
  /// <= 0: the first frame is the reference and nothing is held.
  double still_px = 0.25;
  /// Planes model: planes that come into view later join the filter (findLatePlanes,
  /// docs/estimate.md section 1, "Planes added mid-run"). false: only the reference frame's.
  bool late_planes = true;
};

/// Planes that come into view after the reference frame (docs/estimate.md section 1): when the
/// tracks on the planes found so far thin out (fewer than 2 x kHomographyTestTracks alive after
/// frame K_end), the finder searches the tracks no plane holds, with the reference frame K
/// before K_end where most of them are alive at both K and K_end, and its pair frames at or
/// before K_end: the new planes' homographies are seen while the planes in hand are still
/// tracked, so the filter can place them (TrackFilterOptions::late_planes). Repeated from the
/// new K_end until the planes are tracked to the end or none is found. Accepted planes get the
/// next labels in `pf` (their candidates appended, first_frame set, H and support empty: the
/// homographies were from frame K). Returns the filter's list, frame indices of `tracks`.
std::vector<TrackFilterOptions::LatePlane> findLatePlanes(const Tracks& tracks, vision::PlaneFinding* pf,
                                                         const vision::PlaneFinderOptions& options);

struct EstimateResult {
  /// The still frames: the stages below ran on the tracks from frame still.still_frames (the
  /// reference frame, an index into the input's frames) on, without the later still frames
  /// (still.held); both kinds were put back into `online` and `refined` as copies of the record
  /// of the frame before them (TrackFrame::still; before the reference frame, the reference's),
  /// so both cover every input frame. Labels cover every input id (a track that ended before the
  /// reference frame: -2).
  vision::StillStart still;
  /// Input frame numbers of the frames after the reference frame and before the last observed
  /// one with no observation at all (nothing tracked there; a video's dropped frames are absent
  /// from the tracks instead): left out of every stage like a held frame, put back with
  /// TrackFrame::unobserved (no pose in trajectory.tum or poses.csv).
  std::vector<int> unobserved_frames;
  vision::PlaneFinding planes;      ///< label per track, every candidate plane, the pair frame and cut_after (indexes from the reference frame)
  /// Observations left out after the frame where their track left its plane (planes.cut_after:
  /// an occlusion edge it slid along, a slip; docs/estimate.md section 1, "Tracks that leave their plane").
  std::size_t observations_cut = 0;
  vision::PlaneStart start;         ///< the homography start (ok = false: not tried, or refused: note says why)
  bool start_tried = false;
  TrackFilterOptions filter_used;   ///< the filter's options after the start (and a known camera)
  ImageInfo image;                  ///< the image geometry used (a known principal point)
  /// The calibration used (EstimateOptions::camera; turned to the tracks' frames when their video
  /// was turned: vision::calibrationForTracks).
  std::optional<vision::CameraCalibration> camera;
  TrackFilterResult online;         ///< the recursive filter's per-frame estimates (online.ok(): every frame)
  RefineResult refined;             ///< the refinement (refined.ok: the main result; else the online one stands)
  /// Wall-clock seconds of each stage (steady clock; summary.json's `stage_seconds`).
  struct StageSeconds {
    double plane_finding = 0.0;  ///< vision::findPlanes
    double start = 0.0;          ///< the homography start (0: not tried)
    double filter = 0.0;         ///< the recursive filter, every pass
    double refinement = 0.0;     ///< the bundle adjustment and its uncertainty (0: not run)
  } seconds;
  /// Per track id of the input: the index (into the input's frames) of the last frame whose
  /// observation of it the estimate used, labels.csv's `last_frame_used`: up to where it left its
  /// plane (planes.cut_after), up to the last estimated frame (an estimate that ended early), and
  /// not in a held still stretch (left out of every stage). -1: on no plane (labels() < 0), or
  /// never used.
  std::vector<int> last_used;
  /// The main result: the refinement's when it succeeded, else the filter's.
  const TrackFilterResult& main() const { return refined.ok ? refined.state : online; }
  /// Labels after the refinement's relabelling (the plane finder's when it did not run).
  const std::vector<int>& labels() const { return refined.ok ? refined.labels : planes.labels; }
};

/// The filter's options for one start hypothesis (vision/plane_init.hpp) of a run of `m` planes:
/// a decomposition sets the focal guess (unless the focal length is known or guessed in `base`),
/// the normals, the relative distances, the prior widths after a homography start (0.1,
/// unless given; beta's stays the guess's TrackFilterOptions::kGuessBetaSd0 when the focal
/// length is at an end of the grid, StartHypothesis::at_grid_end) and the motion it measured (where the process noise starts,
/// TrackFilterOptions::q_from_data); the frontal hypothesis leaves `base`'s own guesses.
TrackFilterOptions startOptions(const TrackFilterOptions& base, const vision::StartHypothesis& h, int m);

/// Start hypotheses chosen by the data (issue 14 item 3, docs/estimate.md "Start"): a bank of
/// filters, one per hypothesis (startOptions(), one pass over the sequence each), each scored by
/// how well it explains the observations - per frame the update's joint innovation chi-square
/// r^T S^-1 r of the accepted observations (the one-frame MAP cost: misfit to the data plus
/// distance from the prediction) and the gate's value for every other offered observation (gated,
/// or its prediction failed: a truncated, robust cost), per offered observation, over the second
/// half of the frames, when the priors' widths (frontal sd 1, decompositions 0.1) no longer
/// matter. A start stuck on a wrong branch or focal length keeps a structure no rigid motion
/// fits. A filter that stops (or throws) scores +inf with the reason in `stopped`. Sets every
/// hypothesis's score, `start->chosen` (lowest score; ties: the earlier hypothesis) and the
/// scored frames.
void scoreStartHypotheses(const Tracks& tracks, const std::vector<int>& labels, const TrackFilterOptions& base, int m,
                          vision::PlaneStart* start);

/// No plane with enough tracks: bad input a user can act on (options, or another video).
class NoPlaneFound : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// The rolling shutter's known readout of a run (docs/estimate.md section 6): the one given
/// (rolling_shutter_readout), else the calibration file's (camera->rolling_shutter_readout), else
/// none (the refinement estimates it). Throws std::invalid_argument when both are given and differ,
/// or when it is beyond kMaxRollingShutterReadout.
std::optional<double> knownReadout(const EstimateOptions& options);

/// Runs the pipeline. `note` receives one-line progress notes (the planes found, the start; a
/// line starting "warning: " is a warning), `progress` the filter's frames. Throws NoPlaneFound,
/// std::invalid_argument for options out of range or too few tracks; a filter that stops on
/// numerical trouble is reported in result.online.stopped, not thrown.
EstimateResult estimate(const Tracks& tracks, const EstimateOptions& options,
                        const std::function<void(const std::string&)>& note = {},
                        const std::function<void(int, int)>& progress = {});

struct PatchEstimateOptions {
  PatchPipelineOptions patch;         ///< the patch filter (its beta_sd0, unset, follows the start)
  vision::PlaneFinderOptions finder;  ///< for the focal start (min_plane_tracks capped at 8)
  /// Start the focal length (unless known or given as focal0_px) from homographies of the patch
  /// centres; every patch still starts fronto-parallel.
  bool homography_start = true;
  /// The motion check (issue 17): the plane pipeline (estimate() above, its refinement's tests)
  /// on the patch centres tells whether the camera translates and rotates at all. Calway's
  /// filter assumes both; on a camera that only turns its normals are not determined and its
  /// focal length was 170 sigma off (and followed its start), on a nearly affine one its focal
  /// length and tilts are not determined.
  bool motion_check = true;
};

struct PatchEstimateResult {
  vision::PlaneStart start;  ///< the focal start (ok = false: not tried or failed, note says why)
  bool start_tried = false;
  PatchPipelineOptions patch_used;
  PatchRunResult run;        ///< run.ok(): every frame
  PatchMotionCheck motion;   ///< the motion check (motion.checked: it ran and concluded)
};

PatchEstimateResult estimatePatches(const PatchTracks& tracks, const PatchEstimateOptions& options,
                                    const std::function<void(const std::string&)>& note = {},
                                    const std::function<void(int, int)>& progress = {});

/// The warning printed when the homography start's focal length is at an end of its grid.
extern const char* const kFocalGridEndWarning;

}  // namespace rsfm
