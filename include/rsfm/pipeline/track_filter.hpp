#pragma once
// Running the recursive filters on real feature tracks (docs/estimate.md). No I/O, no OpenCV.
//
// Pixels -> A&P normalized coordinates: u = (x - c_x) / s, v = (y - c_y) / s (docs/conventions.md),
// with s = TrackFilterOptions::scale_px (default max(width, height) / 2), so f_px = s / beta.
// The reference frame is the first frame of the tracks. Tracks labelled l >= 0 are points of
// plane l; -1 (outliers) and -2 (unused) never enter the filter. Tracks that end stop
// contributing; tracks that start later join the plane models with a reference position
// transferred through the current plane and motion estimate (PlaneModel::transferToReference);
// each point's innovation is chi-square gated (FilterOptions::update.gate_probability).
// Scale gauge: N_Z of plane 0 is fixed at its initial value beta0 / depth0 (the main plane meets
// the optical axis depth0 / beta0 beyond the image plane), so translations are in those units.
#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "rsfm/filters/recursive_filter.hpp"
#include "rsfm/track/tracks.hpp"

namespace rsfm {

enum class TrackModel { Point, Plane, Planes };
const char* toString(TrackModel m);
bool parseTrackModel(const std::string& s, TrackModel* m);

struct TrackFilterOptions {
  TrackModel model = TrackModel::Planes;
  double scale_px = 0.0;     ///< s, pixels per normalized unit (<= 0: max(width, height) / 2)
  double focal_px = 0.0;     ///< known focal length (px): beta fixed at s / focal_px (<= 0: estimated)
  double focal0_px = 0.0;    ///< initial focal guess (px) (<= 0: max(width, height), ~53 deg across)
  /// Initial standard deviation of beta, relative to beta0. Unset: 0.3 for a guessed focal
  /// length (also after a homography start whose focal length is at an end of its grid), 0.1
  /// after a homography start (startOptions(), pipeline/estimate.hpp).
  std::optional<double> beta_sd0;
  /// The measurement noise sd per axis (px). runTrackFilter uses it as given; estimate() takes
  /// it as a floor and raises it to the measured tracking noise (docs/estimate.md section 3).
  double sigma_px = 0.5;
  /// Initial sd of N_X, N_Y (and of N_Z of planes > 0), relative to N_Z0. Unset: 1.0 for planes
  /// started frontal, 0.1 after a homography start.
  std::optional<double> normal_sd0;
  /// The values used when beta_sd0 / normal_sd0 are unset and no start set them.
  static constexpr double kGuessBetaSd0 = 0.3, kFrontalNormalSd0 = 1.0;
  /// A plane that joins mid-run starts with the sd of its triangulated fit, doubled, and this
  /// relative sd of |N| per component on top (as a homography start's normal_sd0).
  static constexpr double kLatePlaneSd0 = 0.1;
  /// Scale gauge and start: every plane starts frontal, meeting the optical axis depth0 / beta0
  /// beyond the image plane (N = (0, 0, beta0 / depth0)); plane 0's N_Z stays fixed there.
  double depth0 = 10.0;
  /// Optional start for the plane models (e.g. from homography decompositions,
  /// vision/plane_init.hpp): unit normal n_j of each plane in the reference camera frame and its
  /// distance relative to plane 0's (d_j / d_0). Plane 0 is placed where the gauge puts it (its
  /// axis depth depth0 / beta0), the others at their relative distances:
  /// N_j = n_j / (d_j - n_jZ / beta0) (docs/conventions.md). Empty: every plane frontal.
  /// Plane models: per-frame translation process noise as a standard deviation relative to the
  /// main plane's starting depth (depth0 / beta0): q = (q_trans_rel depth)^2 for t_X, t_Y and
  /// (q_trans_rel depth beta0)^2 for t_Z beta. The filter's units follow the gauge, so an absolute
  /// Q would mean different motions for different depth0; Q must cover one frame's motion
  /// (docs/filter.md). <= 0: use filter.q_motion as given. Used when q_from_data is false, and
  /// as Q0's floor when no start measured the motion.
  double q_trans_rel = 0.01;
  /// The motion's process noise from the data (issue 14 item 4; docs/estimate.md section 3): Q0
  /// from the motion the start measured and the tracks' own image motion, then adapted online
  /// to the motion the filter measures (FilterOptions::Adaptation, on). Each omega component's
  /// sd is max(start_rotation_deg_per_frame, D / f0 rad) and the translation's sd
  /// max(start_translation_rel_per_frame, D / f0) of the main plane's starting depth (depth0 /
  /// beta0, as q_trans_rel; both are relative to the depth from the centre of projection,
  /// (depth0 + 1) / beta0, so Q0 is 0.91 of the motion at depth0 10), with D the
  /// 90th percentile over the frames of the median displacement between consecutive frames of
  /// the tracks that enter the filter (at least sigma_px; D / f0 is the rotation, and the
  /// translation relative to depth, that move the image by D px) and f0 the starting focal
  /// length. The image motion alone underestimates a camera that turns to keep the scene in
  /// view (its rotation and translation cancel in the image: box-short-10deg moves 20 px per
  /// frame for 10 deg), hence the start's; without a start's motion (frontal start) the given
  /// q_trans_rel and filter.q_motion's omega stay Q0's floor. false: q_trans_rel and filter.q_motion's omega as
  /// given, fixed (filter.adapt off). q_motion's beta entry is used as given either way.
  bool q_from_data = true;
  /// The start's measured motion per moving frame (vision::StartHypothesis; set by
  /// rsfm::startOptions; 0: no start measured it): rotation (deg) and translation relative to
  /// the main plane's depth on the optical axis from the centre of projection.
  double start_rotation_deg_per_frame = 0.0, start_translation_rel_per_frame = 0.0;
  std::vector<Eigen::Vector3d> initial_normals;
  std::vector<double> initial_distance_ratios;
  double depth_sd0 = 0.5;    ///< point model: initial sd of each depth alpha, relative to alpha0 = depth0 / beta0
  int max_point_tracks = 60; ///< point model: reference tracks used at most (O(N^3) per frame)
  /// Passes over the sequence (plane models). Pass p > 1 restarts from the reference frame with
  /// the previous pass's final beta and plane(s) as the initial state (same initial covariance):
  /// only the linearization point changes, which removes most of the bias of a poor start
  /// (docs/estimate.md). 1 = purely recursive.
  int passes = 2;
  bool add_new_tracks = true;  ///< plane models: later tracks join by transfer
  /// Planes model: planes that enter the filter after the reference frame (docs/estimate.md
  /// section 3, "Planes added mid-run"). Their labels are the highest (after every reference
  /// plane's) and in this order. Plane `label` is triangulated at frame index `init_frame` from
  /// its member tracks' positions there and at `first_frame` (index), through the filter's two
  /// poses; failing that (too few tracks in front of both cameras, too little parallax) at each
  /// later frame, until its tracks are gone. It then joins the state (N appended, its prior
  /// uncorrelated with the rest) and its tracks join as later tracks do (transferred).
  struct LatePlane {
    int label = -1;
    int first_frame = 0;  ///< frame index of its search's reference frame
    int init_frame = 0;   ///< frame index from which it is triangulated (its search's pair frame)
  };
  std::vector<LatePlane> late_planes;
  /// Plane models: at most this many tracks per plane in the filter at a time (the longest-lived
  /// reference tracks; later tracks join while a plane has fewer live ones). <= 0: all. Beyond a
  /// few dozen well-spread points a plane gains little accuracy, while every extra point adds
  /// to the overconfidence of updates linearized at a poor early estimate (docs/estimate.md).
  int max_tracks_per_plane = 40;
  int min_track_frames = 3;  ///< tracks seen in fewer frames are left out
  /// Filter tuning; defaults differ from FilterOptions' in `reference` (Refine: real first-frame
  /// positions are noisy) and iterate_after_frames (10: with iterations > 1, the first frames
  /// keep the plain update, docs/filter.md).
  FilterOptions filter = defaultFilter();
  static FilterOptions defaultFilter();
};

/// State after one frame.
struct TrackFrame {
  int frame = 0;                                   ///< absolute frame number
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  ///< reference -> camera k (A&P)
  Eigen::Vector3d t = Eigen::Vector3d::Zero();      ///< (t_X, t_Y, t_Z), scene units (A&P)
  double beta = 0.0, var_beta = 0.0;
  /// The filter's covariance of its motion state (t_X, t_Y, t_Z beta, omega): omega is the
  /// rotation error about R (rad), so the bottom-right block is the uncertainty of R. Zero in the
  /// reference frame and in refined records.
  Eigen::Matrix<double, 6, 6> cov_motion = Eigen::Matrix<double, 6, 6>::Zero();
  std::vector<Eigen::Vector3d> N;                  ///< plane models: N per plane (reference frame)
  std::vector<Eigen::Matrix3d> cov_N;
  std::vector<Eigen::Vector3d> cov_beta_N;  ///< cov(beta, N) per plane
  /// cov(N_a, N_b) (3 x 3, rows N_a) for each pair a < b of planes in the order (0, 1), (0, 2),
  /// (1, 2), (0, 3), ... (planePairIndex: a plane that joins adds its pairs at the end): the
  /// angles between planes need them (planeAngle). Zero for a pair with a plane the record
  /// repeats from where it joined (TrackFilterResult::plane_first_frame).
  std::vector<Eigen::Matrix3d> cov_N_pair;
  int observed = 0;   ///< observations offered
  int used = 0;       ///< accepted by the gate
  int gated = 0;      ///< rejected by the gate
  double nis_per_dof = 0.0;
  double rms_px = 0.0;  ///< posterior reprojection RMS of the accepted observations (px)
  std::uint32_t health = kHealthy;
  double q_scale = 1.0;  ///< motion process noise multiplier of this step (FilterOptions::mismatch_retries)
  /// The process noise this step's prediction used (adaptation and mismatch retries included):
  /// each omega component's sd (deg per frame) and the translation's sd (t_X; relative to the
  /// main plane's starting depth, depth0 / beta0, per frame).
  double q_omega_sd_deg = 0.0, q_trans_sd_rel = 0.0;
  /// A still frame (EstimateOptions::still_px): no filter step; a copy of the record of the
  /// frame before it (of the reference frame's before the reference frame) with its own frame
  /// number and no observations.
  bool still = false;
  /// An input frame with no observation at all (a stretch where nothing was tracked;
  /// EstimateResult::unobserved_frames): put back like a still frame (and
  /// `still` set) so that every input frame has a record, but nothing says where the camera was:
  /// trajectory.tum and poses.csv have no line for it.
  bool unobserved = false;
};

struct TrackFilterResult {
  std::vector<TrackFrame> frames;   ///< frames[still_frames] is the reference frame (prior)
  /// Still frames before the reference frame (EstimateOptions::still_px): copies of the reference
  /// frame's record with their own frame numbers - the reference pose (R = I, t = 0), its
  /// structure, no observations (TrackFrame::still). 0 from runTrackFilter itself.
  int still_frames = 0;
  double scale_px = 0.0;
  int planes = 0;
  std::vector<int> plane_tracks;     ///< tracks that entered the filter, per plane (point: one entry)
  std::vector<int> plane_new_tracks; ///< of which joined after the reference frame
  std::vector<double> plane_rms_px;  ///< posterior reprojection RMS per plane over all frames (px)
  /// Later tracks whose transfer to the reference frame failed, per plane: tracks born after the
  /// reference frame, and a late plane's tracks when it joined (or rejoined a plane) the filter.
  std::vector<int> transfer_failed;
  /// Planes model: the state's plane of each label (labels of TrackFilterOptions::late_planes
  /// in the order they joined; -1: a late plane that never could be triangulated, its tracks
  /// unused). Plane j's entries everywhere in this result (N per frame, plane_tracks, ...) are
  /// the state's plane j.
  std::vector<int> plane_of_label;
  /// Per plane: the frame index from which the filter estimates it (0: a reference-frame plane).
  /// frames[k].N[j] for k before it repeats its value at that frame (not an estimate: the plane
  /// was not yet in the state).
  std::vector<int> plane_first_frame;
  /// Whether frames[k] holds an estimate of plane j (not a repeat of its value where it joined).
  bool planeEstimatedAt(int j, int k) const {
    return j >= static_cast<int>(plane_first_frame.size()) || plane_first_frame[static_cast<std::size_t>(j)] <= k;
  }
  std::string stopped;               ///< empty unless the filter failed (numerical trouble, beta <= 0, the gate): why
  /// Non-empty when the tracks on the planes ran out before the last frame (after at least 10
  /// frames): the result covers the frames before it and is valid (ok()); this says where and why.
  std::string ended;
  int passes = 1;                    ///< passes completed (the result is the last one's)
  /// Non-empty when a later pass stopped (a numerical failure, beta <= 0): which, where and why;
  /// the result is then the pass before it, complete and valid (ok()).
  std::string pass_stopped;
  std::vector<double> pass_focal_px; ///< final focal length of each pass
  std::vector<std::vector<Eigen::Vector3d>> pass_N;  ///< final planes of each pass
  /// The motion's process noise (TrackFilterOptions::q_from_data): the tracks' per-frame image
  /// motion D (px, 0 when not from the data), and Q0 as sds (omega per component, deg per
  /// frame; translation relative to the starting depth depth0 / beta0 per frame); from data: Q0 came from the
  /// data (TrackFilterOptions::q_from_data); adapted: the online adaptation ran.
  double image_motion_px = 0.0, q0_omega_sd_deg = 0.0, q0_trans_sd_rel = 0.0;
  /// TrackFilterOptions' start motion the noise started from (0: none).
  double start_rotation_deg_per_frame = 0.0, start_translation_rel_per_frame = 0.0;
  bool q_from_data = false, q_adapted = false;
  /// The reported covariances (var_beta, cov_N, cov_beta_N of every frame after the reference
  /// frame) are the filter's own times `variance_factor`: its covariance assumes independent
  /// measurement errors of sd `filter_sigma_px` (px), while its posterior residuals along the
  /// tracks (last pass) have sd `residual_sd_px` (2 per accepted observation less each frame's 6
  /// motion parameters as degrees of freedom) and are correlated from frame to frame:
  /// variance_factor = correlation_inflation * max(1, (residual_sd_px / filter_sigma_px)^2),
  /// correlation_inflation = 1 + 2 sum rho (rsfm/residual_correlation.hpp). Not applied (factor
  /// 1) without residuals. docs/estimate.md section 3, "The reported sds".
  struct SdCalibration {
    bool applied = false;
    double filter_sigma_px = 0.0, residual_sd_px = 0.0, correlation_inflation = 1.0, variance_factor = 1.0;
  } sd_calibration;
  bool ok() const { return stopped.empty(); }
};

/// Runs the chosen filter. Throws std::invalid_argument for options out of range or when fewer
/// than the model's minimum points (point 7, plane 5 per plane) are labelled in the reference frame.
TrackFilterResult runTrackFilter(const Tracks& tracks, const std::vector<int>& labels, const TrackFilterOptions& options,
                                 const std::function<void(int, int)>& progress = {});

}  // namespace rsfm

namespace rsfm {

/// Plane N . X = 1 (A&P reference frame, origin on the image plane) in the reference camera's
/// COP-centred frame (Y = X + e_z / beta): n . Y = d with n = +-N/|N| chosen so that d > 0 (n
/// points from the camera towards the plane), d = (1 + N_Z / beta) / |N|.
struct MetricPlane {
  Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
  double d = 0.0;
  double sd_angle_deg = 0.0;  ///< sqrt of the trace of cov(n) (first order), degrees
  double sd_d = 0.0;          ///< first-order standard deviation of d
};
/// `cov` is the 4x4 covariance of (beta, N_X, N_Y, N_Z) (zero: no uncertainty). `J` (optional)
/// receives the Jacobian of (n, d) (rows n_x, n_y, n_z, d) with respect to (beta, N), the one
/// behind the sds (the sign choice included).
MetricPlane metricPlane(const Eigen::Vector3d& N, double beta, const Eigen::Matrix4d& cov = Eigen::Matrix4d::Zero(),
                        Eigen::Matrix4d* J = nullptr);
/// The 4x4 covariance of (beta, N_X, N_Y, N_Z) of plane j in a frame's record (zero blocks for a
/// plane the record does not hold): metricPlane's `cov`.
Eigen::Matrix4d covBetaN(const TrackFrame& f, int j);

/// Index of the pair (a, b), a < b, in TrackFrame::cov_N_pair.
inline int planePairIndex(int a, int b) { return b * (b - 1) / 2 + a; }

/// The angle between two planes of a record with its first-order sd and a 95 % interval
/// (summary.json `angles_between_planes_deg`, docs/estimate.md section 4 "Angles between
/// planes"). The angle is between the normals' lines, in [0, 90] deg (normalAngle); its sd is
/// the delta method's, sqrt(g C g^T) with g normalAngle's gradient and C the joint 6 x 6
/// covariance of (N_a, N_b) (cov_N, cov_N_pair). The interval is angle +- 1.96 sd cut to
/// [0, 90], except near parallel planes, where the linearization fails (the angle is a cone's
/// apex there): when the 95 % disc of the normals' relative error, radius 2.448 sd_rel
/// (sqrt(chi2_2(0.95)), sd_rel = sqrt(trace cov(n_b - n_a)) on the tangent plane), reaches the
/// parallel, the interval is [0, angle + 2.448 sd_rel] (the angle changes by at most that
/// error's size). Without the pair's covariance (cov_N_pair too short, or not finite): has_sd
/// false, sd_deg 0 and the interval [0, 90].
struct PlaneAngle {
  int a = 0, b = 0;
  double angle_deg = 0.0;
  bool has_sd = false;
  double sd_deg = 0.0;
  double lo_deg = 0.0, hi_deg = 90.0;  ///< the 95 % interval
};
PlaneAngle planeAngle(const TrackFrame& f, int a, int b);

/// Wald statistics of one frame's motion against its covariance `cov` over the motion state
/// (t_X, t_Y, t_Z beta, omega; TrackFrame::cov_motion, RefineResult::cov_motion), the tests for
/// a rotation and a translation of docs/estimate.md sections 3 and 4: `rotation` = r^T C_r^-1 r
/// with r the rotation vector of R (reference -> frame) and C_r the omega block; `translation` =
/// c^T C_c^-1 c with c the frame's centre of projection in the reference frame (camera.hpp,
/// copCentredPose) and C_c = J cov J^T, J its Jacobian with respect to the motion state by
/// central differences. `t_state` = (t_X, t_Y, t_Z beta) (scene units). A statistic whose
/// covariance is not positive definite is 0 (no evidence).
struct MotionWald {
  double rotation = 0.0, translation = 0.0;
};
MotionWald motionWald(const Eigen::Matrix3d& R, const Eigen::Vector3d& t_state, double beta, const Eigen::Matrix<double, 6, 6>& cov);

/// The filter alone's verdict on what its data determine, for a run without a refinement
/// (`--refine none`, a refinement that failed or could not start): the refinement's limits
/// (rsfm/determinacy.hpp: focal sd <= 5 % of itself, a normal's sd <= 5 deg) applied to the last
/// frame's calibrated covariance (TrackFilterResult::SdCalibration), and the refinement's tests
/// for a rotation and a translation: without a rotation (a camera that only translates) the
/// focal length and the planes' tilts are one null direction, and without a translation (a
/// camera turning about its centre) the planes show no structure, whatever the sds say (an EKF
/// settles somewhere along the null direction with a small covariance). Each is significant when
/// some frame's rotation vector r from the reference, or centre of projection c, has
/// r^T C_r^-1 r (c^T C_c^-1 c, C_c through the centre's Jacobian) above chi2(3) at
/// 0.1 % / (frames - 1) (Bonferroni, the refinement's Wald tests; TrackFrame::cov_motion). The
/// sds leave out the filter's linearization error otherwise
/// (docs/estimate.md section 3, "The reported sds"), so this verdict can call determined what the
/// refinement would not.
struct FilterDeterminacy {
  bool focal_determined = true;  ///< not determined: no interval is supported (the why gives the linear one)
  /// Per plane of the last frame; a plane is not determined with the focal length (its tilt
  /// follows it).
  std::vector<bool> plane_determined;
  double wald_rotation_chi2 = 0.0;     ///< the largest frame's r^T C_r^-1 r
  double wald_translation_chi2 = 0.0;  ///< the largest frame's c^T C_c^-1 c
  bool rotates = true;                 ///< the rotation's exceeds the quantile (true with the focal length known)
  bool translates = true;              ///< the translation's exceeds the quantile
  std::string why;                     ///< what is not determined and why ("" when everything is)
};
/// `known_focal`: the focal length was given and held (always determined).
FilterDeterminacy filterDeterminacy(const TrackFilterResult& result, bool known_focal);

}  // namespace rsfm
