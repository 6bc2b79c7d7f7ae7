#pragma once
// A start for the plane filters from the plane finder's homographies (docs/estimate.md): for each
// focal length on a grid, every plane's reference -> frame-k homography is decomposed
// (cv::decomposeHomographyMat); the focal length whose decompositions agree best - one rotation
// for all planes (they move rigidly), the same normal at two frames - is kept, with the normals
// and the relative plane distances (d_j / d_0 from |t / d_j|) of that decomposition.
#include <Eigen/Core>

#include <string>
#include <vector>

#include "rsfm/track/tracks.hpp"
#include "rsfm/vision/plane_finder.hpp"

namespace rsfm::vision {

struct PlaneStart {
  bool ok = false;
  double focal_px = 0.0;                     ///< best focal length on the grid (0 if not ok)
  std::vector<Eigen::Vector3d> normals;      ///< per accepted plane (label order), reference camera frame
  std::vector<double> distance_ratios;       ///< d_j / d_0
  double score = 0.0;                        ///< disagreement at the best focal length (deg)
  /// The agreement was best at an end of the focal grid (0.3 .. 3 max(W, H)): no minimum was
  /// found, so the focal length is not determined by the homographies (it is still returned:
  /// on the ViSP cube's patch centres, 1152 px, where the KLT tracks give an interior 617 px).
  bool at_grid_end = false;
  std::string note;                          ///< why not ok
};

/// `focal_px` > 0: only that focal length is tried (known focal length). A best disagreement
/// whose mean over its m^2 terms (m normal changes, m(m-1) rotation differences) exceeds
/// `max_mean_disagreement_deg` is no start (ok = false, with the note): on opencv-doc's box.mp4
/// (2 planes) the decompositions disagree by 27 deg at best (6.7 per term), and the plane filter
/// started from them (normals with sd 0.1) diverged at frame 129; started frontal it gives 85.4
/// deg between the faces. Consistent starts: 1.0 per term (rendered box, ViSP cube), 2.9 (the
/// synthetic box tracks of tests/test_video.cpp, 0.5 px noise).
PlaneStart planeStart(const Tracks& tracks, const PlaneFinding& finding, double focal_px = 0.0,
                      double max_mean_disagreement_deg = 5.0);

}  // namespace rsfm::vision
