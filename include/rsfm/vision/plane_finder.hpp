#pragma once
// Assigning tracks to planes (docs/estimate.md §1): RANSAC homographies from the reference
// frame (the first frame of the tracks) to a later frame over the tracks alive in both, the
// dominant plane first, then further planes from the remaining tracks; each plane is checked on
// every frame; planes that do not move (static background) or move with another rigid motion than
// the main plane are rejected, and their tracks, like tracks that fit no plane, are outliers.
// Tracks born after the reference frame join the plane whose homographies carry them.
#include <opencv2/core.hpp>

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "rsfm/track/tracks.hpp"

namespace rsfm::vision {

/// Tracks that let a homography test its members (issue 14 item 2): 4 fix it, twice that give
/// 16 equations for its 8 unknowns, so 8 residual degrees of freedom in which a track off the
/// plane shows. The finder's per-frame fits and the joining of later tracks need this many
/// members in view, and a plane needs this many reference tracks. Whether so few determine the
/// plane's normal under the measured tracking noise is the refinement's verdict
/// (RefineResult::plane_determined), not the finder's.
inline constexpr int kHomographyTestTracks = 8;

struct PlaneFinderOptions {
  int max_planes = 3;                ///< planes kept at most
  int min_plane_tracks = kHomographyTestTracks;  ///< a plane needs at least this many reference tracks
  // The four pixel tolerances below are used as given unless the tracking noise needs wider
  // ones and the search with those finds more planes, or twice the tracks on as many
  // (planeTolerances, findPlanes; docs/estimate.md section 1).
  double ransac_px = 2.0;            ///< homography inlier threshold at the pair frame (px)
  double verify_px = 3.0;            ///< a member may stray at most this far from its plane's
                                     ///< least-squares homography in any frame (px); a later
                                     ///< track joins only after moving this far itself
  double min_alive_fraction = 0.5;   ///< the pair frame: last frame with this fraction alive
  double static_px = 2.0;            ///< planes whose members move less than this (median, px) are static
  double motion_px = 2.0;            ///< plane+parallax epipolar distance limit for "same motion" (px)
  /// Tracking noise per axis (px) that may widen the tolerances; < 0: measured from the tracks
  /// (trackNoisePx); 0: the tolerances as given.
  double noise_px = -1.0;
  double same_motion_fraction = 0.6; ///< fraction of a plane's parallax tracks that must agree
  int min_new_track_frames = 5;      ///< later tracks shorter than this are left out
  bool reject_static = true;         ///< reject planes that do not move in the image
  /// The pair frames are chosen at or before this frame index (<= 0: any). The search for
  /// planes that join mid-run uses it: their homographies must be seen while the planes already
  /// in the filter are still tracked (pipeline/estimate.hpp).
  int last_pair_frame = 0;
  /// Manual override: one polygon per plane in reference-frame pixels. Reference tracks inside
  /// polygon j belong to plane j (first polygon wins); no RANSAC search, no motion test.
  std::vector<std::vector<cv::Point2f>> rois;
  unsigned seed = 1;                 ///< RANSAC seed (cv::theRNG)
};

/// The pixel tolerances a search used: the options' floors widened by the tracking noise.
struct PlaneTolerances {
  double noise_px = -1;  ///< tracking noise per axis (px) they were derived from (<= 0: none)
  double ransac_px = 0, verify_px = 0, static_px = 0, motion_px = 0;
  /// A track whose largest displacement from its first position stays below this moved by the
  /// noise alone: static_px's option, or the noise's per-frame quantile (as verify_px's) if larger.
  double still_px = 0;
};

/// White tracking noise per axis (px), from the tracks' second differences over three consecutive
/// frames after each frame's affine fit is removed (docs/estimate.md section 1); -1 when fewer
/// than 100 residuals. Slow drift of a track does not show in it.
double trackNoisePx(const Tracks& tracks);

/// The tolerances for tracks with `noise_px` per axis over `frames` frames: each option's value,
/// or the noise's quantile if larger (a member's residual is a Rayleigh magnitude of sd sqrt 2 x
/// noise: its 99.9 % quantile at the pair frame, the largest of `frames` with probability 0.99
/// for the per-frame tests, twice the median for "static").
PlaneTolerances planeTolerances(const PlaneFinderOptions& options, double noise_px, int frames);

/// Why a candidate plane was kept or not.
/// Planes that came into view later (pipeline/estimate.hpp findLatePlanes): NotTriangulated,
/// its tracks never gave the filter the parallax to place it (they are outliers); Rejoined, it
/// is a plane the filter already has, seen again: its tracks joined that plane (its label).
enum class PlaneVerdict { Accepted, Static, OtherMotion, TooFew, NotTriangulated, Rejoined };
const char* toString(PlaneVerdict v);

struct FoundPlane {
  PlaneVerdict verdict = PlaneVerdict::Accepted;
  int label = -1;                     ///< index among accepted planes (-1 if rejected)
  std::vector<int> members;           ///< track ids (reference and later tracks)
  std::vector<cv::Matx33d> H;         ///< reference -> frame k homography (k = 0..F-1; empty if unknown)
  std::vector<int> support;           ///< members that determined H[k] (0: fit failed, H[k] = H[k-1])
  double median_motion_px = 0.0;      ///< largest median member displacement from the reference
  double same_motion_fraction = -1;   ///< plane+parallax agreement with the main plane (-1: main/untested)
  int pair_frame = -1;                ///< the frame of the RANSAC pair it was found at (-1: manual ROI)
  int first_frame = 0;                ///< its reference frame: 0, or a later one for a plane that came into view later
  /// Members that leave the plane (an occlusion edge they slide along, a tracker's slip): (track
  /// id, the last frame of its part on the plane); members not listed count over their whole life.
  std::vector<std::pair<int, int>> cuts;
  std::vector<int> pair_inliers;      ///< its RANSAC inliers at the pair frame, before the per-frame test
};

struct PlaneFinding {
  /// Label per track id: plane 0..m-1 (accepted planes, largest first), -1 outlier (fits no
  /// accepted plane or belongs to a rejected one), -2 not used (too short to judge).
  std::vector<int> labels;
  /// Per track id: the last frame index of a member's observations on its plane, where it left
  /// it (an occlusion edge it slid along, a slip); its later observations are left out. -1: its
  /// whole life (and every track not on a plane). Empty: none cut.
  std::vector<int> cut_after;
  std::vector<FoundPlane> candidates;  ///< every candidate plane, accepted and rejected
  int pair_frame = -1;                 ///< frame index of the RANSAC pair (reference, pair_frame)
  PlaneTolerances tolerances;          ///< the pixel tolerances used (noise_px: the measured noise)
  bool widened = false;                ///< the noise's wider tolerances were used: with them more
                                       ///< planes, or twice the tracks on as many, were found
  /// The pair frames tried, in order (issue 14 item 2): the share-of-live-tracks frame, then the
  /// frames of the moving tracks' largest median motion and of 3/4, 1/2, 1/4 of it. pair_frame is
  /// the first with the most accepted planes, among frames that find again the planes of the
  /// frame they would replace (see loses_plane); once max_planes are accepted, no further frame
  /// is tried. Empty with ROIs.
  struct PairTry {
    int frame = -1;
    int planes = 0;            ///< accepted planes (at most max_planes)
    int tracks_in_planes = 0;  ///< their reference tracks
    /// More planes than the frame that had won, but not its planes found again (one of them that
    /// can be seen there has at most half of its live tracks in one plane): not chosen.
    bool loses_plane = false;
  };
  std::vector<PairTry> pair_frame_tries;
  int numPlanes() const;
  int count(int label) const;
  /// Tracks on a plane (label >= 0) used up to where they left it (cut_after >= 0): the count
  /// the "planes:" lines and summary.json's plane_finding.tracks_cut report.
  int tracksCut() const;
};

/// Plane+parallax test (Irani & Anandan [IA96]) of a second plane against the main one: points
/// moving rigidly with it satisfy x' ~ H1 x + parallax along lines through one epipole e'. RANSAC
/// over pairs of the points for e'; returns the fraction of the points with parallax (off H1 x by
/// at least 2 tol_px) within tol_px of their epipolar line (-1 when fewer than 5 show parallax).
/// Pixels, reference frame -> pair frame.
double sameMotionFraction(const cv::Matx33d& H1, const std::vector<cv::Point2d>& x, const std::vector<cv::Point2d>& xp,
                          double tol_px, unsigned seed);

/// The same test across planes (docs/estimate.md section 1 step 4): a rigid scene's planes
/// share one epipole, while sameMotionFraction fits each plane its own, which a small group's
/// nearly parallel parallax vectors always allow (a far epipole). Over the epipoles through pairs
/// of both planes' parallax points (RANSAC), those that the plane `by` (by_x -> by_xp) accepts
/// (min_fraction of its parallax points within tol_px of their lines): the largest fraction of
/// the parallax points of x -> xp within tol_px of their lines. -1 when either has fewer than 5
/// parallax points or no sampled epipole is accepted by `by`.
double epipoleAgreement(const cv::Matx33d& H1, const std::vector<cv::Point2d>& by_x, const std::vector<cv::Point2d>& by_xp,
                        const std::vector<cv::Point2d>& x, const std::vector<cv::Point2d>& xp, double tol_px,
                        double min_fraction, unsigned seed);

/// Whether a search's accepted planes `found` find again the accepted planes `won` of the search
/// they would replace (the pair frame's choice, docs/estimate.md section 1 step 1): each plane of
/// `won` with at least min_plane_tracks members alive (`alive(id)`: the track is seen at the new
/// search's pair frame) must have more than half of those live members in one plane of `found`.
/// A plane with fewer alive cannot be found there and is not asked for.
bool findsPlanesAgain(const std::vector<FoundPlane>& won, const std::vector<FoundPlane>& found,
                      const std::function<bool(int)>& alive, int min_plane_tracks);

/// Finds planes in `tracks`. Throws std::invalid_argument on options out of range.
PlaneFinding findPlanes(const Tracks& tracks, const PlaneFinderOptions& options = {});

}  // namespace rsfm::vision
