#pragma once
// Angle units, in one place.
#include <cmath>

namespace rsfm {

inline constexpr double kRadToDeg = 180.0 / M_PI;
inline constexpr double kDegToRad = M_PI / 180.0;

}  // namespace rsfm
