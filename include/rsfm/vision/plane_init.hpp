#pragma once
// Starts for the plane filters from the plane finder's homographies (docs/estimate.md, "Start"):
// for each focal length on a grid, every plane's reference -> frame-k homography is decomposed
// (cv::decomposeHomographyMat); the decompositions are combined, one per plane and frame, to agree
// best - one rotation for all planes (they move rigidly), the same normal at two frames. The
// result is a set of *hypotheses*, not one answer (issue 14 item 3): each local minimum of that
// disagreement over the focal grid, each branch of the planar two-fold ambiguity at it (the
// two decompositions with the plane in front, [AS99] §3.1), and the frontal start. None is
// refused by a disagreement threshold; pipeline/estimate.cpp scores them by the data (a bank of
// filters) and keeps the best.
#include <Eigen/Core>

#include <limits>
#include <string>
#include <vector>

#include "rsfm/track/tracks.hpp"
#include "rsfm/vision/plane_finder.hpp"

namespace rsfm::vision {

/// One start of the plane filters.
struct StartHypothesis {
  /// Every plane fronto-parallel at the filter's default focal guess and wide prior
  /// (TrackFilterOptions' guess widths): what the filter does without a start.
  bool frontal = false;
  double focal_px = 0.0;                 ///< the decomposition's focal length (frontal: 0 = the filter's guess)
  std::vector<Eigen::Vector3d> normals;  ///< per accepted plane (label order), reference camera frame, unit
  std::vector<double> distance_ratios;   ///< d_j / d_0
  /// Disagreement of the decompositions (deg, sum over the m^2 terms: m normal changes between
  /// the two frames, m(m-1) rotation differences between planes); frontal: NaN.
  double disagreement_deg = std::numeric_limits<double>::quiet_NaN();
  int focal_minimum = 0;  ///< rank of its focal-grid minimum (0: the lowest disagreement)
  int branch = 0;         ///< plane 0's decomposition at the pair frame (0, 1: the two in front)
  /// That minimum is at an end of the focal grid (0.3 .. 3 max(W, H)): no minimum was found
  /// there, so the homographies do not determine the focal length (on the ViSP cube's patch
  /// centres, 1152 px, where the KLT tracks give an interior 617 px).
  bool at_grid_end = false;
  /// The motion this decomposition measured, per moving frame (from the last frame before the
  /// pair frame whose plane motion was below 5 % of the pair frame's): plane 0's rotation angle
  /// (deg) and its translation relative to the depth at which the optical axis meets the plane
  /// (|t / d| n_z). The filter's process noise starts there (TrackFilterOptions::q_from_data).
  double rotation_deg_per_frame = 0.0, translation_rel_per_frame = 0.0;
  /// Filled by the scoring (rsfm::scoreStartHypotheses): per offered observation over the scored
  /// frames, the update's joint innovation chi-square of the accepted ones plus the gate's value
  /// for the others (lower = the data agree better; +inf: the filter stopped).
  double score = std::numeric_limits<double>::quiet_NaN();
  std::string stopped;  ///< why its scoring filter stopped (empty: it ran)
};

struct PlaneStart {
  /// At least one decomposition hypothesis exists (false: no plane decomposes in front of the
  /// camera at any focal length; the note says why and only the frontal start remains).
  bool ok = false;
  std::string note;                          ///< why not ok
  /// Every start considered: decompositions (lowest disagreement first), then the frontal one.
  /// Never empty after planeStart() (empty: no start was tried).
  std::vector<StartHypothesis> hypotheses;
  /// Index into hypotheses of the one used: planeStart() sets 0 (the lowest disagreement, or the
  /// frontal start when no decomposition exists); scoreStartHypotheses() the best-scored one.
  int chosen = 0;
  const StartHypothesis& used() const { return hypotheses.at(chosen); }
  /// Frames over which the hypotheses were scored (absolute numbers; -1: not scored).
  int scored_from = -1, scored_to = -1;
};

/// `focal_px` > 0: only that focal length is tried (known focal length). `max_focal_minima`:
/// the lowest local minima of the disagreement over the focal grid kept as hypotheses; each
/// contributes its best combination for each of plane 0's decompositions in front at the pair
/// frame (both branches of the two-fold ambiguity). The frontal hypothesis is always last.
PlaneStart planeStart(const Tracks& tracks, const PlaneFinding& finding, double focal_px = 0.0, int max_focal_minima = 2);

}  // namespace rsfm::vision
