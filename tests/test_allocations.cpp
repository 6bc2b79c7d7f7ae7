// Issue 15: a warm filter step allocates nothing. This binary replaces malloc and friends with
// counting forwards to glibc's (__libc_malloc ...), so every heap allocation made by the code
// under test (operator new, Eigen's aligned_malloc, std::vector) is seen; counting is switched on
// only around the steps measured. Kept out of rsfm_tests so the replacement touches nothing else,
// and not built under the sanitizers (which replace malloc themselves).
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <random>

#include "rsfm/batch/plane_batch.hpp"
#include "rsfm/filters/recursive_filter.hpp"
#include "rsfm/models/plane_model.hpp"
#include "rsfm/models/point_model.hpp"
#include "rsfm/pipeline/track_filter.hpp"

extern "C" {
void* __libc_malloc(size_t);
void* __libc_calloc(size_t, size_t);
void* __libc_realloc(void*, size_t);
void* __libc_memalign(size_t, size_t);
}

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};
inline void count() {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
}
}  // namespace

extern "C" {
void* malloc(size_t n) {
  count();
  return __libc_malloc(n);
}
void* calloc(size_t a, size_t b) {
  count();
  return __libc_calloc(a, b);
}
void* realloc(void* p, size_t n) {
  count();
  return __libc_realloc(p, n);
}
void* aligned_alloc(size_t al, size_t n) {
  count();
  return __libc_memalign(al, n);
}
void* memalign(size_t al, size_t n) {
  count();
  return __libc_memalign(al, n);
}
int posix_memalign(void** out, size_t al, size_t n) {
  count();
  *out = __libc_memalign(al, n);
  return *out ? 0 : 12;  // ENOMEM
}
}

namespace rsfm {
namespace {

/// Allocations made by f().
template <class F>
long allocationsOf(F&& f) {
  g_allocations = 0;
  g_counting = true;
  f();
  g_counting = false;
  return g_allocations.load();
}

TEST(Allocations, TheCounterSeesAllocations) {
  // The counter itself must work, or the tests below could not fail.
  const long n = allocationsOf([] {
    std::vector<double> v(100);
    Eigen::MatrixXd M(30, 30);
    asm volatile("" : : "r"(v.data()), "r"(M.data()) : "memory");
  });
  EXPECT_GE(n, 2);
}

/// Exact observations of a slowly translating and rotating camera over one plane (the model's own
/// prediction at the true state), `obs_per_frame[k]` of them in frame k.
struct PlaneScene {
  std::vector<Eigen::Vector2d> ref;
  Eigen::VectorXd x0;
  Eigen::MatrixXd P0;
  std::vector<bool> fixed;
  std::vector<std::vector<Observation>> frames;
};

PlaneScene planeScene(int n, int frames) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(-0.6, 0.6);
  std::normal_distribution<double> noise(0.0, 1e-3);
  PlaneScene s;
  for (int i = 0; i < n; ++i) s.ref.emplace_back(U(rng), U(rng));
  const PlaneModel model(s.ref, std::vector<int>(n, 0));
  Eigen::VectorXd xt = Eigen::VectorXd::Zero(10);
  xt[idx::kBeta] = 0.8;
  xt.tail<3>() << 0.3, -0.2, 0.5;
  for (int k = 1; k <= frames; ++k) {
    xt.head<3>() << 0.004 * k, -0.002 * k, 0.001 * k * xt[idx::kBeta];
    const Eigen::Matrix3d Rg = Eigen::AngleAxisd(0.003 * k, Eigen::Vector3d(0.2, 1.0, 0.1).normalized()).toRotationMatrix();
    std::vector<Observation> obs;
    for (int i = 0; i < n; ++i) {
      if ((i + k) % 7 == 0) continue;  // a varying subset: the frame size changes
      Eigen::Vector2d h;
      if (model.measure(xt, Rg, i, &h, nullptr) == MeasureStatus::Ok) obs.push_back({i, h + Eigen::Vector2d(noise(rng), noise(rng))});
    }
    s.frames.push_back(obs);
  }
  s.x0 = Eigen::VectorXd::Zero(10);
  s.x0[idx::kBeta] = 0.8;
  s.x0.tail<3>() << 0.3, -0.2, 0.5;
  s.P0 = Eigen::MatrixXd::Identity(10, 10) * 1e-2;
  s.fixed.assign(10, false);
  s.fixed[9] = true;  // the gauge
  return s;
}

void expectNoAllocationsOnceWarm(const FilterOptions& options, const char* what) {
  SCOPED_TRACE(what);
  const PlaneScene s = planeScene(300, 30);
  RecursiveFilter<PlaneModel> f(PlaneModel(s.ref, std::vector<int>(s.ref.size(), 0)), Ekf(s.x0, s.P0, s.fixed), options);
  // Warm-up: the largest frame sizes the work space.
  for (int k = 0; k < 10; ++k) ASSERT_TRUE(f.step(s.frames[k]).update.applied);
  int applied = 0;
  const long n = allocationsOf([&] {
    for (int k = 10; k < 30; ++k) applied += f.step(s.frames[k]).update.applied ? 1 : 0;
  });
  EXPECT_EQ(applied, 20);
  EXPECT_EQ(n, 0) << "heap allocations in 20 warm steps";
}

TEST(Allocations, WarmPlaneFilterStepAllocatesNothing) {
  FilterOptions plain;
  plain.sigma_uv = 1e-3;
  expectNoAllocationsOnceWarm(plain, "the library's defaults (exact references)");
  FilterOptions pipeline = TrackFilterOptions::defaultFilter();
  pipeline.sigma_uv = 1e-3;
  expectNoAllocationsOnceWarm(pipeline, "rsfm estimate's defaults (refined references, mismatch retries)");
}

TEST(Allocations, WarmPointFilterStepAllocatesNothing) {
  const int n = 60;
  const PlaneScene s = planeScene(n, 20);
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(7 + n);
  x0[idx::kBeta] = 0.8;
  x0.tail(n).setConstant(1.5);
  Eigen::MatrixXd P0 = Eigen::MatrixXd::Identity(7 + n, 7 + n) * 1e-2;
  std::vector<bool> fixed(7 + n, false);
  fixed[7] = true;
  FilterOptions o;
  o.sigma_uv = 1e-3;
  o.update.gate_probability = 0.0;  // the point model's start is far from this scene's depths
  RecursiveFilter<PointModel> f(PointModel(s.ref), Ekf(x0, P0, fixed), o);
  for (int k = 0; k < 5; ++k) ASSERT_TRUE(f.step(s.frames[k]).update.applied);
  int applied = 0;
  const long a = allocationsOf([&] {
    for (int k = 5; k < 20; ++k) applied += f.step(s.frames[k]).update.applied ? 1 : 0;
  });
  EXPECT_EQ(applied, 15);
  EXPECT_EQ(a, 0) << "heap allocations in 15 warm steps";
}

TEST(Allocations, TheBatchBoundAllocatesNothingPerObservation) {
  // The refinement's bound (planeBatchBound) with 40 and with 80 points over the same 12 frames:
  // its heap allocations are per problem and per frame (the frame's blocks), so 440 more
  // observations add at most the few reallocations of vectors that grow with the frame's width.
  // Checked with the default options and with the refinement's (the motions' covariance, the
  // track-clustered and spatial sds, which pass over the observations once more).
  auto count = [](int n, const PlaneBatchBoundOptions& o) {
    const int F = 12;
    const PlaneScene s = planeScene(n, F);
    PlaneBatchData data;
    data.frames.emplace_back();
    for (int i = 0; i < n; ++i) data.frames[0].push_back({i, s.ref[i]});
    for (const auto& f : s.frames) data.frames.push_back(f);
    data.labels.assign(n, 0);
    data.sigma_uv = 1e-3;
    PlaneBatchState at;  // the scene's truth (planeScene's state, as the batch's)
    at.R.push_back(Eigen::Matrix3d::Identity());
    at.t.push_back(Eigen::Vector3d::Zero());
    for (int k = 1; k <= F; ++k) {
      at.R.push_back(Eigen::AngleAxisd(0.003 * k, Eigen::Vector3d(0.2, 1.0, 0.1).normalized()).toRotationMatrix());
      at.t.emplace_back(0.004 * k, -0.002 * k, 0.001 * k * 0.8);
    }
    at.beta = 0.8;
    at.N = {Eigen::Vector3d(0.3, -0.2, 0.5)};
    at.ref = s.ref;
    PlaneBatchBound b;
    const long a = allocationsOf([&] { b = planeBatchBound(data, at, o); });
    EXPECT_TRUE(b.ok) << b.message;
    EXPECT_EQ(b.null_dim, 0);
    long observations = 0;
    for (const auto& f : data.frames) observations += static_cast<long>(f.size());
    return std::make_pair(a, observations);
  };
  PlaneBatchBoundOptions refinement;
  refinement.motion_covariance = true;
  refinement.skip_undetermined_frames = true;
  refinement.track_clustered = true;
  refinement.spatial_grid = 4;
  for (const PlaneBatchBoundOptions& o : {PlaneBatchBoundOptions{}, refinement}) {
    const auto [a40, obs40] = count(40, o);
    const auto [a80, obs80] = count(80, o);
    EXPECT_GE(obs80 - obs40, 400);
    EXPECT_GT(a40, 0);  // the counter sees the bound's per-problem allocations
    EXPECT_LE(a80 - a40, 12) << a40 << " allocations with 40 points (" << obs40 << " observations), " << a80
                             << " with 80 (" << obs80 << ")";
  }
}

}  // namespace
}  // namespace rsfm
