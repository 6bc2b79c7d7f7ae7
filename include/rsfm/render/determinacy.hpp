#pragma once
// Which quantities a rendered sequence determines (docs/render.md, "Determinacy").
//
// From the truth alone: points are laid on a grid over each truth plane's textured faces where the
// first frame sees them, followed through every frame while in view and unoccluded, and the plane
// model's batch problem (per-frame motion, beta, the planes, every point's reference position) is
// set up at the truth with the tracks' noise `track_sd_px` (rsfm::planeBatchBound). Its inverse
// information at the truth is the Cramer-Rao bound: the smallest sd any unbiased estimator can
// reach from such tracks. A quantity is determined when it is estimable (its gradient orthogonal
// to the information's null space: pure rotation leaves the planes in it, pure translation the
// focal length and the planes' tilt) and its bound is within the limits of rsfm/determinacy.hpp.
// A sequence in which nothing moves determines nothing.
#include <string>

#include "rsfm/io/summary.hpp"

namespace rsfm::render {

class Scene;

struct DeterminacyOptions {
  double track_sd_px = 0.5;  ///< assumed tracking noise (px): KLT on these renderings measures 0.1-0.3 px
  int points_per_plane = 40; ///< grid points kept per plane (at most)
  double margin_px = 8;      ///< points this close to the image border count as out of view
};

struct Determinacy {
  io::Determinable summary;   ///< what goes into truth/summary.json
  bool moves = false;         ///< some frame's pose differs from frame 0's
  int points = 0;             ///< tracks in the bound
  int observations = 0;       ///< their observations over all frames
  bool full_rank = false;     ///< the information matrix has full rank
  int null_dim = -1;          ///< dimension of its null space (-1: not computed)
  std::string batch_message;  ///< the batch solver's line
};

Determinacy analyseDeterminacy(const Scene& scene, const DeterminacyOptions& o = {});

/// The analysis as a JSON object (render.json's "determinacy").
std::string determinacyToJson(const Determinacy& d);

}  // namespace rsfm::render
