#pragma once
// The final refinement (issue 13; docs/estimate.md, "Refinement"): a bundle adjustment of the plane
// model over all frames, started from the recursive filter, and the uncertainty of its result.
//
// Unknowns (rsfm::solvePlaneBatch, the experiments' batch): per frame the motion (R, t), beta,
// every plane N (plane 0's N_Z held: the filter's scale gauge), every track's reference-frame
// position (tracks born later anchored by their own observations), and the image-side camera
// (models/radial_camera.hpp): the principal point and OpenCV's k1, k2, each estimated unless
// known, and a rolling shutter's readout (docs/estimate.md section 6). Residuals in pixels
// (through s), under a Huber loss whose scale is `loss_sigmas` times the residuals' robust sd
// (1.4826 MAD) at the start. Stages: (1) the camera held (principal point at the tracks', no
// distortion) from the filter's estimate; (2) the camera's free components
// released from there; an implausible camera (the principal point beyond `max_principal_offset`, a
// distortion that folds the image) is held again and reported not determined; (3) a track whose
// residual RMS under that model exceeds `outlier_sigmas` robust sds is relabelled an outlier (-1)
// and the problem solved again without it; its camera passes the test of stage 2 (a component that
// fails is held at the nominal camera and the problem solved once more).
//
// Uncertainty: the Cramer-Rao bound at the solution (rsfm::planeBatchBound, with its null space),
// with the noise set to the inlier residuals' actual spread sqrt(sum r^2 / (m - n)), inflated for
// their correlation along tracks (RefineResult::correlation_inflation), and for beta, the planes
// and the camera widened where the track-clustered covariance of the tracks' own scores is larger
// (and for beta and the planes the region-clustered one) ([W80], [CGM11];
// RefineOptions::track_clustered_sd, spatial_grid, docs/estimate.md section 4). A quantity is
// determined when it is estimable and its sd is within the limits of rsfm/determinacy.hpp; an
// undetermined focal length is reported with the interval the data support instead of a number.
// No I/O, no OpenCV.
#include <Eigen/Core>

#include <array>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "rsfm/pipeline/track_filter.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm {

struct RefineOptions {
  bool enabled = true;                 ///< false: no refinement (--refine none)
  bool estimate_principal_point = true;  ///< false: held at the tracks' principal point (known)
  bool estimate_distortion = true;     ///< false: k1 = k2 = 0 held (known, or the tracks undistorted)
  double loss_sigmas = 3.0;            ///< Huber scale, in robust sds of the start's residuals
  double outlier_sigmas = 3.0;         ///< a track whose RMS residual exceeds this many robust sds is an outlier
  int max_iterations = 50;             ///< trust-region (dogleg) iterations per solve
  /// Tracks in the refinement: longest first, a track taken while some frame of its life has
  /// fewer than this many taken tracks on its plane (<= 0: all). Beyond a few dozen well-spread
  /// points per plane and frame the estimate gains little, while the cost grows with the square
  /// of the points seen together (the reduced system over the reference positions).
  int tracks_per_plane_and_frame = 0;
  /// Plausibility of the camera: a principal point estimated farther than this fraction of the
  /// image's larger side from its centre (real cameras' lie within a few %), or a distortion that
  /// is not monotonic out to the image's corners, is the data pulling the camera somewhere no
  /// camera is (a scene not quite planar, tracker drift): it is held (centre, k = 0), reported
  /// not determined, and the problem solved again.
  double max_principal_offset = 0.10;
  /// Priors when estimated (what is known of cameras before the data speak): the principal point
  /// about the image centre with this sd (fraction of the larger side), k1 and k2 about 0. They
  /// keep what the data barely see from wandering, and their spread enters the focal length's sd
  /// (a principal point the data cannot place makes the focal length less certain, not free).
  double principal_point_prior_sd = 0.03;
  double distortion_prior_sd = 0.25;
  /// A rolling shutter's readout (frame intervals, first row to last; docs/estimate.md section 6)
  /// as a camera parameter: every prediction moves by readout x (y - mid) / height x its track's
  /// velocity (rollingShutterShift), released with the camera in stage 2, held at 0 when
  /// implausible (beyond kMaxRollingShutterReadout either way). false: a global shutter (or a
  /// known readout, the tracks already corrected: EstimateOptions::rolling_shutter_readout).
  bool estimate_readout = true;
  /// Its prior about 0 (a global shutter), sd in frame intervals: weak against a moving scene's
  /// ~10^4 observations (sds of 0.06-0.16 on box.mp4's windows), it bounds the readout where
  /// nothing moves.
  double readout_prior_sd = 1.0;
  /// A principal point the data do not determine (its sd above determinacy.hpp's limit after the
  /// outlier stage) is held at the nominal centre and the rest solved again, its prior sd kept in
  /// the bound (docs/estimate.md section 4): the estimate then does not depend on where the
  /// optimizer stopped in a flat valley. false: it stays at that point, reported not determined.
  bool hold_undetermined_principal_point = true;
  /// Check the reported sds of the focal length, the planes and the camera against the tracks'
  /// own scores (the track-clustered sandwich covariance, PlaneBatchBoundOptions::track_clustered)
  /// and widen each where it is larger. false: the inflated bound alone (for comparison).
  bool track_clustered_sd = true;
  /// With track_clustered_sd: also cluster the tracks by region (per plane, a grid of this many
  /// cells a side over its tracks' reference positions; PlaneBatchBoundOptions::spatial_grid) and
  /// widen the focal length's and the planes' bound to that sandwich too (0: tracks only). 3: per
  /// plane 9 regions, enough clusters for a sandwich of its 3 normal components and the focal
  /// length, regions large enough to share an error (docs/estimate.md section 4).
  int spatial_grid = 3;
  /// With a `note` given to refine(): a line on the solve under way once this many seconds have
  /// passed since the refinement started or since the last such line (the 1200-frame orbit's
  /// refinement took 15-30 s in silence). <= 0: after every iteration (tests).
  double progress_seconds = 3.0;
};

/// The online estimate's final figures against the refinement's (docs/estimate.md section 3,
/// "The reported sds"). Given the data, the refined estimate x_r has error ~ (0, sd_r^2) and
/// the online estimate x_o = x_r + (x_o - x_r): its error has RMS sqrt((x_o - x_r)^2 +
/// sd_r^2), whatever the filter's own covariance says (an EKF linearized at its early
/// estimates can stop many of its sds away from the truth). A quantity the refinement reports
/// not determined is not determined online either. `checked` false: no refinement (the
/// filter's own, residual-calibrated sds stand, TrackFilterResult::SdCalibration).
struct OnlineAccuracy {
  bool checked = false;
  bool focal_determined = true;
  double focal_sd_px = 0.0;             ///< sqrt((f_o - f_r)^2 + sd_r^2); 0 with the focal length known
  std::vector<bool> plane_determined;   ///< per plane
  std::vector<double> normal_sd_deg;    ///< sqrt(angle(n_o, n_r)^2 + sd_r^2), the sds as metricPlane's
  std::vector<double> distance_sd;      ///< sqrt((d_o - d_r)^2 + sd_r^2), trajectory units
};

struct RefineResult {
  bool ok = false;           ///< a refined estimate exists (else the online estimate stands; message says why)
  std::string message;
  OnlineAccuracy online_accuracy;  ///< the online estimate's final figures against this one (set by estimate())
  /// The refined sequence in the filter's form: one TrackFrame per frame with the refined R, t,
  /// beta and N (the same in every frame), their covariances from the bound, the frame's
  /// observations in `used` and its residual RMS in `rms_px`.
  TrackFilterResult state;
  std::vector<Eigen::Matrix<double, 6, 6>> cov_motion;  ///< per frame: (t_X, t_Y, t_Z beta, omega) covariance (zero for frame 0)
  Eigen::Vector4d camera = Eigen::Vector4d::Zero();     ///< (dc_x, dc_y, k1, k2) (models/radial_camera.hpp)
  Eigen::Matrix4d cov_camera = Eigen::Matrix4d::Zero();
  std::array<bool, 4> camera_free{false, false, false, false};
  std::array<bool, 4> camera_determined{false, false, false, false};
  Eigen::Vector2d principal_point_px = Eigen::Vector2d::Zero();  ///< nominal + s dc
  /// A rolling shutter's readout (frame intervals; RefineOptions::estimate_readout): estimated
  /// (readout_free), its sd from the bound, and whether that is within kDeterminedReadoutSd.
  bool readout_free = false, readout_determined = false;
  double readout = 0.0, readout_sd = 0.0;
  double sigma_px = 0.0;      ///< the inlier residuals' spread sqrt(sum r^2 / (m - n))
  /// Variance inflation for the residuals' correlation along each track (1 + 2 sum of the pooled
  /// autocorrelation up to its first non-positive lag): tracker errors drift smoothly, so a
  /// track's observations are not independent. Every covariance is sigma_px^2 times this.
  double correlation_inflation = 1.0;
  /// The track-clustered check of those covariances (PlaneBatchBoundOptions::track_clustered,
  /// docs/estimate.md section 4): the factor by which it widened the focal length's sd, and per
  /// plane the largest factor on its N components (1: the inflated bound already covered what
  /// the tracks' scores show).
  double clustered_focal_factor = 1.0;
  double clustered_focal_ratio = 0.0;  ///< its variance ratio (clustered / inflated bound) before max(1, .)
  std::vector<double> clustered_plane_factor;
  /// Per plane: the further factor on its normal's sd from the delete-one-track jackknife, the
  /// sandwich corrected for the leverage of the plane's tracks (PlaneBatchBound::jackknife_N,
  /// docs/estimate.md section 4; 1: not widened). Infinite (null in summary.json) when one track
  /// alone decides a direction of the plane: the plane is then not determined.
  std::vector<double> jackknife_plane_factor;
  /// When the focal length is not determined and its profile was run: per plane, the largest
  /// angle (deg) between the estimate's normal and the profile's over the focal lengths the data
  /// support; added to the normal's variance as a 95 % half-width (docs/estimate.md section 4).
  /// Empty when no profile was run.
  std::vector<double> plane_profile_spread_deg;
  double robust_sigma_px = 0.0;  ///< 1.4826 MAD of the final residuals
  std::vector<int> labels;    ///< per track id after relabelling (outliers -1)
  int relabelled = 0;         ///< tracks relabelled outliers
  /// Per plane: its tracks in the refinement and how many of them were relabelled outliers (more
  /// than half: the plane is reported not determined, its tracks were not one surface).
  std::vector<int> plane_tracks, plane_relabelled;
  /// Per plane: tracks left out of the refinement because their reference position lies within 3
  /// measurement sds of the plane's horizon line in the reference image (a plane seen edge-on
  /// from the reference camera, one that nearly contains its centre: the depth along such a
  /// reference ray turns on a fraction of a pixel), and, when that leaves the plane fewer than 5,
  /// the rest of its tracks. docs/estimate.md section 4, "Planes seen edge-on from the reference
  /// frame".
  std::vector<int> plane_horizon_tracks;
  int tracks = 0, observations = 0;
  int null_dim = 0;           ///< of the information matrix, weak directions included (PlaneBatchBound::null_dim)
  std::vector<int> undetermined_frames;  ///< frames whose pose the observations do not determine
  /// Likelihood ratio of the plane model against pure rotation about the centre of projection
  /// (the same camera), in units of the inflated noise variance, and whether it is significant
  /// (chi2 with the plane model's extra parameters, 0.1 %). Not significant: the camera only turns,
  /// and no plane is determined.
  double rotation_lr = 0.0;
  bool translation_significant = true;
  /// The same against a translation-only fit (no rotation in any frame): not significant, and the
  /// focal length and the planes' tilt are not determined (the affine ambiguity).
  double translation_lr = 0.0;
  /// The largest per-frame Wald chi2 (3 dof) of the translation and of the rotation from the
  /// reference; above 1000 the likelihood ratio test is skipped (infinite in the fields above).
  double wald_translation_chi2 = 0.0, wald_rotation_chi2 = 0.0;
  bool focal_determined = false;
  /// When not determined: what the data support (the linear 95 % interval of beta at the
  /// optimum, widened by the focal length's profile over 0.3-3 x the larger image side;
  /// docs/estimate.md, section 4).
  std::optional<std::array<double, 2>> focal_interval_px;
  /// The profile's best-fitting focal length on its grid (the estimate itself unless another
  /// fits better; 0 when no profile was computed).
  double focal_profile_best_px = 0.0;
  std::vector<bool> plane_determined;
  std::string why;            ///< one line on what is not determined and why (empty when all is)
  /// The final solve stopped at RefineOptions::max_iterations with its cost still falling (a
  /// flat valley: the data hardly constrain some direction). Said in `why`; the figures are
  /// where it stopped.
  bool at_iteration_limit = false;
  /// The final solve stopped where its steps could not be evaluated, the cost still falling
  /// (PlaneBatchResult::stalled; Ceres counts it converged). Said in `why`; the figures are where
  /// it stopped.
  bool stalled = false;
  int iterations = 0;
  double initial_rms_px = 0.0, final_rms_px = 0.0;
  double seconds = 0.0;
};

/// Refines `online` (the filter's run on `tracks` with `labels` and options `filter`).
/// `note` (optional) receives progress lines ("refine: 6 s: ..."), RefineOptions::progress_seconds apart.
RefineResult refine(const Tracks& tracks, const std::vector<int>& labels, const TrackFilterResult& online,
                    const TrackFilterOptions& filter, const RefineOptions& options = {},
                    const std::function<void(const std::string&)>& note = {});

}  // namespace rsfm
