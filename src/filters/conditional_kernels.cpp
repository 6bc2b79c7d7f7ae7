// AVX2/FMA kernels of the conditional references (include/rsfm/filters/conditional_kernels.hpp).
// The build targets the x86-64 baseline: these functions alone are compiled for AVX2 and FMA
// ([[gnu::target]]) and are called only after conditionalKernelsEnabled() checked the CPU.
#include "rsfm/filters/conditional_kernels.hpp"

#include <stdexcept>

#include "rsfm/ekf.hpp"

#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#define RSFM_COND_AVX2 1
#endif

namespace rsfm::detail {

bool conditionalKernelsEnabled() { return Ekf::vectorKernelEnabled(); }

#ifdef RSFM_COND_AVX2
namespace {
/// Sum of a 4-vector's lanes.
[[gnu::target("avx2,fma")]] inline double hsum(__m256d v) {
  const __m128d s = _mm_add_pd(_mm256_castpd256_pd128(v), _mm256_extractf128_pd(v, 1));
  return _mm_cvtsd_f64(_mm_add_sd(s, _mm_unpackhi_pd(s, s)));
}
[[gnu::target("avx2,fma")]] inline double hsum(__m128d s) { return _mm_cvtsd_f64(_mm_add_sd(s, _mm_unpackhi_pd(s, s))); }
/// A row of 10: columns 0-3 and 4-7 as 4-vectors, 8-9 as a 2-vector.
struct Row10 {
  __m256d a, b;
  __m128d c;
};
[[gnu::target("avx2,fma")]] inline Row10 load10(const double* p) {
  return {_mm256_loadu_pd(p), _mm256_loadu_pd(p + 4), _mm_loadu_pd(p + 8)};
}
[[gnu::target("avx2,fma")]] inline void store10(double* p, const Row10& r) {
  _mm256_storeu_pd(p, r.a);
  _mm256_storeu_pd(p + 4, r.b);
  _mm_storeu_pd(p + 8, r.c);
}
/// r - s x (s broadcast in a 4-vector; fused multiply-adds)
[[gnu::target("avx2,fma")]] inline Row10 fnmadd(__m256d s, const Row10& x, const Row10& r) {
  return {_mm256_fnmadd_pd(s, x.a, r.a), _mm256_fnmadd_pd(s, x.b, r.b), _mm_fnmadd_pd(_mm256_castpd256_pd128(s), x.c, r.c)};
}
/// r + s x
[[gnu::target("avx2,fma")]] inline Row10 fmadd(__m256d s, const Row10& x, const Row10& r) {
  return {_mm256_fmadd_pd(s, x.a, r.a), _mm256_fmadd_pd(s, x.b, r.b), _mm_fmadd_pd(_mm256_castpd256_pd128(s), x.c, r.c)};
}
/// x . y
[[gnu::target("avx2,fma")]] inline double dot10(const Row10& x, const Row10& y) {
  return hsum(_mm256_fmadd_pd(x.a, y.a, _mm256_mul_pd(x.b, y.b))) + hsum(_mm_mul_pd(x.c, y.c));
}
}  // namespace

[[gnu::target("avx2,fma")]] void conditionalPredict10(double* G, Eigen::Matrix2d* C, const int* ids, int count,
                                                      const double* M, const double* Sig) {
  // M's rows (M is column-major 6 x 10: M(k, j) = M[k + 6 j]) and Sig's rows (Sig(k, j) = Sig[k + 6 j]).
  Row10 m[6];
  __m256d sa[6];
  __m128d sb[6];
  for (int k = 0; k < 6; ++k) {
    m[k] = {_mm256_setr_pd(M[k], M[k + 6], M[k + 12], M[k + 18]), _mm256_setr_pd(M[k + 24], M[k + 30], M[k + 36], M[k + 42]),
            _mm_setr_pd(M[k + 48], M[k + 54])};
    sa[k] = _mm256_setr_pd(Sig[k], Sig[k + 6], Sig[k + 12], Sig[k + 18]);
    sb[k] = _mm_setr_pd(Sig[k + 24], Sig[k + 30]);
  }
  for (int n = 0; n < count; ++n) {
    const int id = ids[n];
    double* g0 = G + 20 * static_cast<long>(id);
    double* g1 = g0 + 10;
    // The rows to update, and their first 6 columns before the step (G_iq: columns 0-3, 4-5).
    Row10 r0 = load10(g0), r1 = load10(g1);
    const __m256d q0a = r0.a, q1a = r1.a;
    const __m128d q0b = _mm256_castpd256_pd128(r0.b), q1b = _mm256_castpd256_pd128(r1.b);
    __m256d w0a = _mm256_setzero_pd(), w1a = _mm256_setzero_pd();  // G_iq Sig, columns 0-3
    __m128d w0b = _mm_setzero_pd(), w1b = _mm_setzero_pd();        // columns 4-5
    for (int k = 0; k < 6; ++k) {
      const __m256d b0 = _mm256_broadcast_sd(g0 + k), b1 = _mm256_broadcast_sd(g1 + k);
      r0 = fnmadd(b0, m[k], r0);
      r1 = fnmadd(b1, m[k], r1);
      w0a = _mm256_fmadd_pd(b0, sa[k], w0a);
      w0b = _mm_fmadd_pd(_mm256_castpd256_pd128(b0), sb[k], w0b);
      w1a = _mm256_fmadd_pd(b1, sa[k], w1a);
      w1b = _mm_fmadd_pd(_mm256_castpd256_pd128(b1), sb[k], w1b);
    }
    // The broadcasts above read G before any store: write back only now.
    store10(g0, r0);
    store10(g1, r1);
    // dC = (G_iq Sig) G_iq^T: rows of W dotted with rows of G_iq.
    Eigen::Matrix2d& Ci = C[id];
    Ci(0, 0) += hsum(_mm256_mul_pd(w0a, q0a)) + hsum(_mm_mul_pd(w0b, q0b));
    Ci(0, 1) += hsum(_mm256_mul_pd(w0a, q1a)) + hsum(_mm_mul_pd(w0b, q1b));
    Ci(1, 0) += hsum(_mm256_mul_pd(w1a, q0a)) + hsum(_mm_mul_pd(w1b, q0b));
    Ci(1, 1) += hsum(_mm256_mul_pd(w1a, q1a)) + hsum(_mm_mul_pd(w1b, q1b));
  }
}

[[gnu::target("avx2,fma")]] void conditionalAssemble10(double* J0, double* J1, const double* H0, const double* H1,
                                                       const double* Hu, const double* G) {
  // Hu column-major: Hu(0,0) = Hu[0], Hu(1,0) = Hu[1], Hu(0,1) = Hu[2], Hu(1,1) = Hu[3].
  const Row10 g0 = load10(G), g1 = load10(G + 10);
  store10(J0, fmadd(_mm256_broadcast_sd(Hu), g0, fmadd(_mm256_broadcast_sd(Hu + 2), g1, load10(H0))));
  store10(J1, fmadd(_mm256_broadcast_sd(Hu + 1), g0, fmadd(_mm256_broadcast_sd(Hu + 3), g1, load10(H1))));
}

[[gnu::target("avx2,fma")]] void conditionalGainUpdate10(double* G, const double* A0, const double* A1, const double* K,
                                                         const double* d, double* gd) {
  // K column-major: K(0,0) = K[0], K(1,0) = K[1], K(0,1) = K[2], K(1,1) = K[3].
  const Row10 a0 = load10(A0), a1 = load10(A1), dv = load10(d);
  const Row10 r0 = fnmadd(_mm256_broadcast_sd(K), a0, fnmadd(_mm256_broadcast_sd(K + 2), a1, load10(G)));
  const Row10 r1 = fnmadd(_mm256_broadcast_sd(K + 1), a0, fnmadd(_mm256_broadcast_sd(K + 3), a1, load10(G + 10)));
  store10(G, r0);
  store10(G + 10, r1);
  gd[0] = dot10(r0, dv);
  gd[1] = dot10(r1, dv);
}
#else
// Not x86-64 with GCC: conditionalKernelsEnabled() is false (Ekf::vectorKernelEnabled), so the
// filter never calls these.
namespace {
[[noreturn]] void noKernel() { throw std::logic_error("rsfm: the AVX2 conditional kernels are not built for this target"); }
}  // namespace
void conditionalPredict10(double*, Eigen::Matrix2d*, const int*, int, const double*, const double*) { noKernel(); }
void conditionalAssemble10(double*, double*, const double*, const double*, const double*, const double*) { noKernel(); }
void conditionalGainUpdate10(double*, const double*, const double*, const double*, const double*, double*) { noKernel(); }
#endif

}  // namespace rsfm::detail
