#pragma once
// AVX2/FMA kernels of the conditional references' per-point algebra (ReferenceModel::Conditional,
// docs/filter.md) for the one-plane model's state width, 10: the process step on a point's gain
// and the gain's update. Chosen at run time where the CPU has AVX2 and FMA and the vector
// kernels are allowed (Ekf::useVectorKernel); RecursiveFilter runs its Eigen loops otherwise.
// The results equal the Eigen loops' up to rounding (fused multiply-adds, summation order).
// No OpenCV, no I/O.
#include <Eigen/Core>

namespace rsfm::detail {

/// The state width the kernels are written for (PlaneModel: 7 motion and focal + 3 plane).
constexpr int kConditionalKernelWidth = 10;

/// True when the kernels below may run: an x86-64 CPU with AVX2 and FMA, vector kernels allowed.
bool conditionalKernelsEnabled();

/// The process step of the listed points (RecursiveFilter::conditionalPredictMotion):
///   G_i <- G_i - G_iq M,  C_i <- C_i + G_iq Sig G_iq^T,
/// G_iq the first 6 columns of G_i. `G`: row-major gains, point i's two rows of 10 at G + 20 i;
/// `C`: the points' 2 x 2 covariances (indexed by point); `M` (6 x 10) and `Sig` (6 x 6)
/// column-major.
void conditionalPredict10(double* G, Eigen::Matrix2d* C, const int* ids, int count, const double* M, const double* Sig);

/// One block's total Jacobian (RecursiveFilter::conditionalAssemble): J = H + Hu G, J's rows
/// written at J0 and J1, H's (the compact Jacobian's, whose 3 structure columns are the state's
/// 7-9) read at H0 and H1, Hu column-major 2 x 2, G the point's two rows of 10.
void conditionalAssemble10(double* J0, double* J1, const double* H0, const double* H1, const double* Hu, const double* G);

/// One point's gain update (RecursiveFilter::conditionalUpdateBlocks): G <- G - K A with A's
/// rows at A0 and A1 (10 each) and K column-major 2 x 2; then gd = G d (d: 10).
void conditionalGainUpdate10(double* G, const double* A0, const double* A1, const double* K, const double* d, double* gd);

}  // namespace rsfm::detail
