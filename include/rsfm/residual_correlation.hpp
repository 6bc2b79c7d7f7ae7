#pragma once
// Residuals correlated along tracks: how much they widen a least-squares estimate's covariance.
//
// A track's residuals are not independent from frame to frame (the tracker's drift, a camera
// model's systematic error seen by the same point at nearly the same place). For a parameter
// estimated from sums over many such series, the covariance computed as if every residual were
// independent is too small by the integrated autocorrelation time 1 + 2 sum_{lag >= 1} rho(lag)
// (the effective-sample-size argument; e.g. Priestley, "Spectral Analysis and Time Series",
// section 5.3). The refinement (pipeline/refine.cpp) and the recursive filter's reported sds
// (pipeline/track_filter.cpp, TrackFilterResult::sd_calibration) both use this one estimate.

#include <vector>

namespace rsfm {

/// The pooled autocorrelation of residuals along tracks, x and y separately, summed over lags
/// 1, 2, ... up to its first non-positive value (at most `max_lag`): returns 1 + 2 * that sum
/// (>= 1). `per[i]` holds track i's residuals in frame order, x and y interleaved
/// (x0, y0, x1, y1, ...), in any unit. 1 when there are no residuals.
double alongTrackCorrelationInflation(const std::vector<std::vector<double>>& per, int max_lag = 1000);

}  // namespace rsfm
