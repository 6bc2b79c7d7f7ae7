#pragma once
// The motion check of the patch pipeline (pipeline/estimate.hpp, PatchEstimateOptions::
// motion_check; issue 17): whether the camera translates and rotates at all, from the plane
// pipeline's refinement on the patch centres. No OpenCV: the reports include it.
#include <array>
#include <optional>
#include <string>

namespace rsfm {

/// What the motion check found (PatchEstimateOptions::motion_check).
struct PatchMotionCheck {
  bool checked = false;              ///< false: not run or not conclusive (note says why)
  std::string note;
  bool translates = true;            ///< RefineResult::translation_significant
  bool focal_determined = true;      ///< RefineResult::focal_determined (a rotation, or a known focal length)
  double focal_px = 0, focal_sd_px = 0;  ///< the check's refined focal length (determined only)
  std::optional<std::array<double, 2>> focal_interval_px;  ///< supported interval when not determined
  double rotation_lr = 0, translation_lr = 0;  ///< the likelihood ratios (RefineResult)
  std::string why;                   ///< one line: what is not determined and why
  bool structureDetermined() const { return !checked || (translates && focal_determined); }
};

}  // namespace rsfm
