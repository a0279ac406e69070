// ImagePreprocessor::process per frame: 752x480 raw textured image (MYNT EYE S calibration) to working sizes
// 90x58 (the paper's), 180x116 and 376x240.
#include <benchmark/benchmark.h>

#include <cmath>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "diekf/image_preprocessor.h"
#include "../src/core/dot_detector.h"
#include "../src/core/dot_gain.h"
#include "../test/core/opencv_resample_route.h"

namespace {

diekf::CameraModel myntCamera() {
  diekf::CameraModel cam;
  cam.K = diekf::PinholeK{364.91, 364.97, 379.91, 245.53, 752, 480};
  cam.distortion = diekf::DistortionModel::kRadTan;
  cam.distortion_coeffs = diekf::Vec4(-0.3178, 0.0962, -0.00011, 0.00033);
  return cam;
}

cv::Mat texturedRaw(int w, int h) {
  cv::Mat img(h, w, CV_8UC1);
  cv::RNG rng(7);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double v = 128.0 + 50.0 * std::sin(0.031 * x + 0.017 * y) * std::cos(0.023 * y - 0.011 * x) +
                       30.0 * std::sin(0.21 * x) * std::sin(0.17 * y) + rng.gaussian(10.0);
      img.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(v);
    }
  }
  return img;
}

/// Times ImagePreprocessor::process with `params` on the textured 752x480 raw image (with the projector dots'
/// fill over `fill` and their division by `inv_gain_q12` when not empty).
void timePreprocess(benchmark::State& state, const diekf::PreprocessParams& params, const cv::Mat& fill = cv::Mat(),
                    const cv::Mat& inv_gain_q12 = cv::Mat()) {
  diekf::ImagePreprocessor pre(myntCamera(), params);
  pre.setDotGain(inv_gain_q12);
  pre.setDotFill(fill);
  const cv::Mat raw = texturedRaw(752, 480);
  diekf::PreprocessedFrame frame;
  pre.process(raw, 0.0, &frame);  // first call allocates the outputs
  double t = 0.0;
  for (auto _ : state) {
    pre.process(raw, t, &frame);
    t += 1.0 / 30.0;
    benchmark::DoNotOptimize(frame.intensity.data);
    benchmark::ClobberMemory();
  }
  state.counters["px"] = static_cast<double>(frame.intensity.total());
  if (!fill.empty()) state.counters["filled_pct"] = 100.0 * pre.dotFillShare();
  if (!inv_gain_q12.empty()) state.counters["divided_pct"] = 100.0 * pre.dotGainShare();
}

/// 1500-ish discs of radius 3 px over `share` of the 752 x 480 image (nonzero: the discs).
cv::Mat discMask(double share) {
  cv::Mat mask(480, 752, CV_8UC1, cv::Scalar(0));
  cv::RNG rng(3);
  while (cv::countNonZero(mask) < share * mask.total()) {
    const cv::Point c(rng.uniform(0, 752), rng.uniform(0, 480));
    for (int y = std::max(0, c.y - 3); y <= std::min(479, c.y + 3); ++y)
      for (int x = std::max(0, c.x - 3); x <= std::min(751, c.x + 3); ++x)
        if ((x - c.x) * (x - c.x) + (y - c.y) * (y - c.y) <= 9) mask.at<uint8_t>(y, x) = 255;
  }
  return mask;
}

void BM_PreprocessFrame(benchmark::State& state) {
  diekf::PreprocessParams params;
  params.working_width_px = static_cast<int>(state.range(0));
  params.working_height_px = static_cast<int>(state.range(1));
  timePreprocess(state, params);
}

BENCHMARK(BM_PreprocessFrame)
    ->Args({90, 58})
    ->Args({180, 116})
    ->Args({376, 240})
    ->Unit(benchmark::kMillisecond);

// The same at 180x116 with the raw images opened first (preprocess/dot_removal_px: the projector dots' removal),
// for the element sides the dot detector chooses from (docs/noise_model.md section 11).
void BM_PreprocessFrameOpened(benchmark::State& state) {
  diekf::PreprocessParams params;
  params.working_width_px = 180;
  params.working_height_px = 116;
  params.dot_removal_px = static_cast<int>(state.range(0));
  timePreprocess(state, params);
}

BENCHMARK(BM_PreprocessFrameOpened)->Arg(5)->Arg(9)->Arg(11)->Arg(13)->Arg(17)->Unit(benchmark::kMillisecond);

// The same with the projector dots filled instead (fixed_pattern/dot_fill): 1500 dots of radius 3 px (discs), the
// mask the detector grows over the simulator's dots, on 15-19 % of the image; argument: the mask's share in %.
void BM_PreprocessFrameFilled(benchmark::State& state) {
  diekf::PreprocessParams params;
  params.working_width_px = 180;
  params.working_height_px = 116;
  timePreprocess(state, params, discMask(static_cast<double>(state.range(0)) / 100.0));
}

BENCHMARK(BM_PreprocessFrameFilled)->Arg(10)->Arg(17)->Arg(25)->Unit(benchmark::kMillisecond);

// Once the dots' gain is learned (fixed_pattern/dot_gain): the raw image divided by it, and only the dots' cores
// filled (the discs' centres, 3 % of the image, as on the simulator's grass flight 4 with 1500 dots); argument: the
// fill mask's share in % before (the divided region is it grown by two pixels, as DotGainLearner's).
void BM_PreprocessFrameDivided(benchmark::State& state) {
  diekf::PreprocessParams params;
  params.working_width_px = 180;
  params.working_height_px = 116;
  const cv::Mat mask = discMask(static_cast<double>(state.range(0)) / 100.0);
  cv::Mat region, core;
  cv::dilate(mask, region, cv::Mat(), cv::Point(-1, -1), 2);
  cv::erode(mask, core, cv::Mat(), cv::Point(-1, -1), 2);
  cv::Mat inv(480, 752, CV_16UC1, cv::Scalar(4096));
  inv.setTo(3000, region);
  timePreprocess(state, params, core, inv);
}

BENCHMARK(BM_PreprocessFrameDivided)->Arg(17)->Unit(benchmark::kMillisecond);

// One image pair of the dots' gain learning (DotGainLearner::observe, while the gain is learned: the first seconds
// after the filter has converged on a flight with a projector): the region of BM_PreprocessFrameDivided, the ground
// moved by (2.3, -1.4) px between the two images. The learner starts again (untimed) before its pixels have their
// kMinSamples, so every call is a pair of the learning: the region's rim samples, its inside finds no known gain
// where it lands (on a flight the rings are learned one after the other).
void BM_DotGainObserve(benchmark::State& state) {
  using diekf::internal::DotGainLearner;
  const cv::Mat mask = discMask(static_cast<double>(state.range(0)) / 100.0);
  DotGainLearner learner;
  const cv::Mat cur = texturedRaw(752, 480), ref = texturedRaw(752, 480);
  auto begin = [&] {
    learner.start(mask);
    diekf::Vec2* t = learner.gridTargets();
    for (int j = 0; j < learner.gridRows(); ++j)
      for (int i = 0; i < learner.gridCols(); ++i)
        t[j * learner.gridCols() + i] =
            diekf::Vec2(i * DotGainLearner::kGridPx + 2.3, j * DotGainLearner::kGridPx - 1.4);
  };
  begin();
  for (auto _ : state) {
    if (learner.pairs() == DotGainLearner::kMinSamples - 1) {
      state.PauseTiming();
      begin();
      state.ResumeTiming();
    }
    learner.observe(cur.data, ref.data);
    benchmark::ClobberMemory();
  }
  state.counters["region_pct"] = 100.0 * learner.regionShare();
}

BENCHMARK(BM_DotGainObserve)->Arg(17)->Unit(benchmark::kMillisecond);

// One sampled raw image of the projector-dot detector (DotDetector::addImage, 752x480, 5 px element, three contrast
// levels: the openings, the speck and blob tests, the masks over the samples; images are sampled in the first
// seconds of motion only). The detector is armed again (untimed) before it reaches its last sample.
void BM_DotDetectorAddImage(benchmark::State& state) {
  using diekf::internal::DotDetector;
  const cv::Mat raw = texturedRaw(752, 480);
  DotDetector detector;
  detector.configure(752, 480, 5, 0.5, 0.01, 3);
  for (auto _ : state) {
    if (detector.samples() >= DotDetector::kMaxSamples - 1) {
      state.PauseTiming();
      detector.configure(752, 480, 5, 0.5, 0.01, 3);
      state.ResumeTiming();
    }
    detector.addImage(raw);
    detector.notePosition(false);
    benchmark::ClobberMemory();
  }
}

BENCHMARK(BM_DotDetectorAddImage)->Unit(benchmark::kMillisecond);

}  // namespace

namespace {

// The library routes the hand-written resampling was measured against (docs/performance.md, "Resampling: hand-
// written tables or OpenCV"): resize(INTER_AREA) and remap in either order, i.e. the resampling alone, without
// the blur, normalisation and gradients that BM_PreprocessFrame includes. Single-threaded like the preprocessor
// (OpenCV's own threads off for the case: with them the CPU column would count the calling thread only).
template <class Route>
void BM_OpenCvResample(benchmark::State& state) {
  const int threads = cv::getNumThreads();
  cv::setNumThreads(0);
  diekf::PreprocessParams params;
  params.working_width_px = static_cast<int>(state.range(0));
  params.working_height_px = static_cast<int>(state.range(1));
  const diekf::CameraModel cam = myntCamera();
  diekf::ImagePreprocessor pre(cam, params);
  Route route(cam, pre.workingK());
  const cv::Mat raw = texturedRaw(752, 480);
  cv::Mat out;
  route.run(raw, &out);
  for (auto _ : state) {
    route.run(raw, &out);
    benchmark::DoNotOptimize(out.data);
    benchmark::ClobberMemory();
  }
  state.counters["px"] = static_cast<double>(out.total());
  cv::setNumThreads(threads);
}

BENCHMARK_TEMPLATE(BM_OpenCvResample, diekf::testing_routes::OpenCvAreaThenRemap)
    ->Args({90, 58})
    ->Args({180, 116})
    ->Args({376, 240})
    ->Unit(benchmark::kMillisecond);
BENCHMARK_TEMPLATE(BM_OpenCvResample, diekf::testing_routes::OpenCvRemapThenArea)
    ->Args({90, 58})
    ->Args({180, 116})
    ->Args({376, 240})
    ->Unit(benchmark::kMillisecond);

}  // namespace
