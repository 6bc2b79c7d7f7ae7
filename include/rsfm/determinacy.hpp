#pragma once
// When a quantity counts as determined by the data (docs/render.md, "Determinacy").
//
// One definition for the renderer's truth (the Cramer-Rao bound of the plane model's batch problem
// at the truth, render/determinacy.hpp) and for what the estimator reports: a quantity is
// determined when its covariance has full rank and its standard deviation is at most the limit
// below. Above it, the data support only a wide interval, which is reported instead of a number.
namespace rsfm {

/// The focal length: relative sd sd(f)/f at most 5 % (a 95 % interval within about +-10 %).
inline constexpr double kDeterminedFocalRelSd = 0.05;
/// A plane's normal: sd of its direction (sqrt of the trace of its 2x2 tangent covariance) at most 5 deg.
inline constexpr double kDeterminedNormalSdDeg = 5.0;
/// The principal point: sd of each coordinate at most 1 % of the image's larger side.
inline constexpr double kDeterminedPrincipalPointSdFraction = 0.01;
/// A radial distortion coefficient (k1, k2): sd at most 0.02.
inline constexpr double kDeterminedDistortionSd = 0.02;
/// A rolling shutter's readout (frame intervals, first row to last): sd at most 0.25, a 95 %
/// interval within about +-0.5 frame intervals, which tells a global shutter (0) from a sensor
/// that reads its rows over the frame interval (1: webcams, phones).
inline constexpr double kDeterminedReadoutSd = 0.25;

}  // namespace rsfm
