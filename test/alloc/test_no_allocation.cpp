// No heap allocation in the Estimator's per-frame path after warm-up.
//
// This binary interposes the C allocation functions (malloc, calloc, realloc, posix_memalign, aligned_alloc,
// memalign, valloc, pvalloc) and the replaceable operator new family: the executable's definitions take
// precedence over glibc's for every library in the process (OpenCV, libstdc++, yaml-cpp, ...). They forward to
// glibc's __libc_* entry points and count calls while counting is switched on. The Estimator then processes a
// periodic flight (test/core/periodic_flight.h): 2 s of warm-up (first frames allocate the image buffers, result
// slots etc.), then 3 s of frames (IMU samples, images, result pops) with counting on: the count must be zero.
#include <gtest/gtest.h>

#include <atomic>
#include <cerrno>
#include <cstddef>
#include <cstdlib>
#include <new>
#include <vector>

#include "../core/periodic_flight.h"
#include "diekf/estimator.h"

extern "C" {
void* __libc_malloc(size_t size);
void* __libc_calloc(size_t n, size_t size);
void* __libc_realloc(void* p, size_t size);
void* __libc_memalign(size_t alignment, size_t size);
void __libc_free(void* p);
}

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};
inline void count() {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
}
}  // namespace

extern "C" {
void* malloc(size_t size) {
  count();
  return __libc_malloc(size);
}
void* calloc(size_t n, size_t size) {
  count();
  return __libc_calloc(n, size);
}
void* realloc(void* p, size_t size) {
  count();
  return __libc_realloc(p, size);
}
void* memalign(size_t alignment, size_t size) {
  count();
  return __libc_memalign(alignment, size);
}
void* aligned_alloc(size_t alignment, size_t size) {
  count();
  return __libc_memalign(alignment, size);
}
int posix_memalign(void** out, size_t alignment, size_t size) {
  count();
  void* p = __libc_memalign(alignment, size);
  if (p == nullptr && size != 0) return ENOMEM;
  *out = p;
  return 0;
}
void* valloc(size_t size) {
  count();
  return __libc_memalign(4096, size);
}
void* pvalloc(size_t size) {
  count();
  return __libc_memalign(4096, (size + 4095) & ~static_cast<size_t>(4095));
}
}

// operator new: counted here and allocated with glibc directly (not through the malloc above: one count each).
namespace {
void* newImpl(std::size_t size, std::size_t alignment) {
  count();
  if (size == 0) size = 1;
  void* p = alignment > alignof(std::max_align_t) ? __libc_memalign(alignment, size) : __libc_malloc(size);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}
}  // namespace
void* operator new(std::size_t size) { return newImpl(size, 0); }
void* operator new[](std::size_t size) { return newImpl(size, 0); }
void* operator new(std::size_t size, std::align_val_t a) { return newImpl(size, static_cast<std::size_t>(a)); }
void* operator new[](std::size_t size, std::align_val_t a) { return newImpl(size, static_cast<std::size_t>(a)); }
void* operator new(std::size_t size, const std::nothrow_t&) noexcept {
  count();
  return __libc_malloc(size == 0 ? 1 : size);
}
void* operator new[](std::size_t size, const std::nothrow_t&) noexcept {
  count();
  return __libc_malloc(size == 0 ? 1 : size);
}
void operator delete(void* p) noexcept { __libc_free(p); }
void operator delete[](void* p) noexcept { __libc_free(p); }
void operator delete(void* p, std::size_t) noexcept { __libc_free(p); }
void operator delete[](void* p, std::size_t) noexcept { __libc_free(p); }
void operator delete(void* p, std::align_val_t) noexcept { __libc_free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { __libc_free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { __libc_free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { __libc_free(p); }

namespace diekf {
namespace {

using test_util::PeriodicFlight;

const PeriodicFlight& flight() {
  static const PeriodicFlight f(30);
  return f;
}

/// Counting really sees allocations from this binary and from the shared libraries.
TEST(AllocationCounter, SeesNewMallocAndOpenCv) {
  g_allocations = 0;
  g_counting = true;
  {
    auto* v = new std::vector<int>(1000);
    void* p = std::malloc(64);
    cv::Mat m(100, 100, CV_8UC1);  // cv::fastMalloc inside libopencv_core
    std::free(p);
    delete v;
  }
  g_counting = false;
  EXPECT_GE(g_allocations.load(), 3);
}

struct Counts {
  long allocations = 0;
  int results = 0;
  int applied = 0;
  int tracking = 0;
};

/// Feeds `frames` camera frames (IMU up to 50 ms past each image, then the image, then pops the results into
/// `result`), counting allocations when `count_them`.
Counts run(Estimator* est, long* frame, long* imu, int frames, bool count_them, FrameResult* result) {
  Counts c;
  g_allocations = 0;
  g_counting = count_them;
  for (int i = 0; i < frames; ++i, ++*frame) {
    const double t_img = *frame / PeriodicFlight::kCameraRateHz;
    for (; *imu / PeriodicFlight::kImuRateHz <= t_img + 0.05; ++*imu) {
      est->addImu(flight().imu(*imu / PeriodicFlight::kImuRateHz));
    }
    est->addImage(t_img, flight().image(*frame));
    while (est->popResult(result)) {
      ++c.results;
      if (result->update_applied) ++c.applied;
      if (result->status == FilterStatus::kTracking) ++c.tracking;
    }
  }
  g_counting = false;
  c.allocations = g_allocations.load();
  return c;
}

class NoAllocation : public ::testing::TestWithParam<UpdateMode> {};

TEST_P(NoAllocation, PerFramePathAfterWarmUp) {
  EstimatorParams params;
  params.mode = GetParam();
  params.init.alpha0_inv_m = 1.0;  // start near the truth (d = 1 m): this test is about memory, not convergence
  Estimator est(flight().camera(), params);
  FrameResult result;
  long frame = 0, imu = 0;
  const Counts warm = run(&est, &frame, &imu, 60, false, &result);
  ASSERT_GT(warm.results, 50);
  est.takeWarning();
  const Counts c = run(&est, &frame, &imu, 90, true, &result);
  EXPECT_EQ(c.allocations, 0) << "heap allocations in 90 frames after warm-up";
  // The frames were really processed, with updates.
  EXPECT_EQ(c.results, 90);
  EXPECT_GT(c.applied, 80);
  EXPECT_TRUE(est.state().allFinite());
  const std::string warning = est.takeWarning();
  EXPECT_TRUE(warning.empty()) << warning;
}

// The camera-fixed pattern's whole per-frame path (docs/noise_model.md section 11): learning, the fields
// recomputed at every learning frame, the corrected images, the reference corrected again, the confidence
// combined with the outlier weights.
TEST(NoAllocationFixedPattern, LearningAndCorrectingAfterWarmUp) {
  EstimatorParams params;
  params.init.alpha0_inv_m = 1.0;
  params.fixed_pattern.startup_samples = 1.0;
  params.fixed_pattern.min_ground_patches = 0.0;  // the periodic flight holds its position: no patches counted
  params.fixed_pattern.refresh_frames = 1;
  params.fixed_pattern.significance_sigma = 0.0;  // every deviation is corrected: the correction really runs
  // (so the learned pattern holds the whole contrast: the projector-dot opening is switched on as well and runs
  // on every image after warm-up)
  Estimator est(flight().camera(), params);
  FrameResult result;
  long frame = 0, imu = 0;
  run(&est, &frame, &imu, 60, false, &result);
  ASSERT_TRUE(result.fixed_pattern_active);
  est.takeWarning();
  const Counts c = run(&est, &frame, &imu, 90, true, &result);
  EXPECT_EQ(c.allocations, 0) << "heap allocations in 90 frames after warm-up";
  EXPECT_EQ(c.results, 90);
  EXPECT_GT(c.applied, 80);
  EXPECT_TRUE(result.fixed_pattern_active);
  EXPECT_EQ(result.dot_removal_px, params.fixed_pattern.auto_dot_removal_px);
  EXPECT_TRUE(est.state().allFinite());
}

INSTANTIATE_TEST_SUITE_P(PhotometricModes, NoAllocation, ::testing::Values(UpdateMode::kIterated, UpdateMode::kEkf));

}  // namespace
}  // namespace diekf

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
