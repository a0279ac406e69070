#include "diekf/estimator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "diekf/feature_update.h"
#include "diekf/image_preprocessor.h"
#include "diekf/imu_filter.h"
#include "diekf/photometric_update.h"
#include "diekf/prediction.h"

namespace diekf {

const char* toString(FilterStatus status) {
  switch (status) {
    case FilterStatus::kInitializing:
      return "initializing";
    case FilterStatus::kTracking:
      return "tracking";
    case FilterStatus::kReset:
      return "reset";
  }
  return "unknown";
}

double FrameResult::sigma_distance_m() const {
  // d = 1/alpha  =>  sigma_d = sigma_alpha / alpha^2.
  const double var_alpha = std::max(0.0, covariance(ErrIdx::kAlpha, ErrIdx::kAlpha));
  return std::sqrt(var_alpha) / (state.alpha * state.alpha);
}

Vec3 FrameResult::sigma_velocity_mps() const {
  // v = vartheta / alpha  =>  dv = dvartheta / alpha - vartheta / alpha^2 dalpha.
  Eigen::Matrix<double, 3, 4> J;
  J.col(0) = -state.vartheta / (state.alpha * state.alpha);
  J.rightCols<3>() = Mat3::Identity() / state.alpha;
  const Eigen::Matrix4d S = covariance.topLeftCorner<4, 4>();
  const Mat3 C = J * S * J.transpose();
  return C.diagonal().cwiseMax(0.0).cwiseSqrt();
}

namespace {

/// Fixed-capacity ring buffer (no allocation after construction).
template <typename T>
class Ring {
 public:
  explicit Ring(size_t capacity) : data_(capacity) {}
  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  bool full() const { return size_ == data_.size(); }
  T& operator[](size_t i) { return data_[(head_ + i) % data_.size()]; }
  const T& operator[](size_t i) const { return data_[(head_ + i) % data_.size()]; }
  const T& back() const { return (*this)[size_ - 1]; }
  /// Appends; drops the oldest element when full.
  void push(const T& value) {
    if (full()) pop();
    data_[(head_ + size_) % data_.size()] = value;
    ++size_;
  }
  /// Slot for a new element at the back (caller fills it in place).
  T& emplaceSlot() {
    if (full()) pop();
    ++size_;
    return data_[(head_ + size_ - 1) % data_.size()];
  }
  void pop() {
    head_ = (head_ + 1) % data_.size();
    --size_;
  }
  void clear() { head_ = size_ = 0; }

 private:
  std::vector<T> data_;
  size_t head_ = 0, size_ = 0;
};

struct PendingImage {
  double t_s = 0.0;  // IMU clock
  cv::Mat gray;      // CV_8UC1 at calibration resolution (reused buffer)
};

constexpr size_t kImuBufferCapacity = 1024;  // filtered samples (about 10 s at 100 Hz)
constexpr size_t kResultCapacity = 64;       // unread results kept (oldest dropped): nobody reads, memory bounded
constexpr size_t kMessageCapacity = 160;     // chars reserved per result message (formatted without allocation)

}  // namespace

struct Estimator::Impl {
  Impl(const CameraModel& cam, const EstimatorParams& p)
      : camera(cam),
        params(p),
        imu_pre(cam.T_cam_imu, p.imu),
        img_pre(cam, preprocessParamsFor(p)),
        photometric(photometricParamsFor(p), p.preprocess),
        feature(p.feature, photometricParamsFor(p)),
        imu_buffer(kImuBufferCapacity),
        images(static_cast<size_t>(std::max(1, p.max_queued_images))),
        results(kResultCapacity) {
    // Result slots keep their message buffers: no allocation per frame for the usual messages.
    for (size_t i = 0; i < kResultCapacity; ++i) results.emplaceSlot().message.reserve(kMessageCapacity);
    results.clear();
    resetFilter();
  }

  static PreprocessParams preprocessParamsFor(const EstimatorParams& p) {
    PreprocessParams pp = p.preprocess;
    if (p.mode == UpdateMode::kFeature) {
      pp.working_width_px = p.feature.working_width_px;
      pp.working_height_px = 0;
    }
    return pp;
  }
  static PhotometricParams photometricParamsFor(const EstimatorParams& p) {
    PhotometricParams pp = p.photometric;
    if (p.mode == UpdateMode::kEkf) pp.max_passes = 1;
    return pp;
  }

  void warn(const std::string& text) {
    if (!warning.empty()) warning += "; ";
    warning += text;
  }

  /// Initial state and covariance from the parameters (gravity from the accelerometer when available).
  void resetFilter() {
    const InitParams& in = params.init;
    x = State();
    x.alpha = in.alpha0_inv_m;
    x.vartheta = in.vartheta0_inv_s;
    x.mu = UnitVector(in.mu0);
    x.g = UnitVector(in.g0);
    P.setZero();
    P(ErrIdx::kAlpha, ErrIdx::kAlpha) = in.sigma_alpha0_inv_m * in.sigma_alpha0_inv_m;
    P.block<3, 3>(ErrIdx::kVartheta, ErrIdx::kVartheta) =
        Mat3::Identity() * in.sigma_vartheta0_inv_s * in.sigma_vartheta0_inv_s;
    P.block<2, 2>(ErrIdx::kMu, ErrIdx::kMu) = Mat2::Identity() * in.sigma_mu0_rad * in.sigma_mu0_rad;
    P.block<2, 2>(ErrIdx::kG, ErrIdx::kG) = Mat2::Identity() * in.sigma_g0_rad * in.sigma_g0_rad;
    P.block<3, 3>(ErrIdx::kBa, ErrIdx::kBa) = Mat3::Identity() * in.sigma_ba0_mps2 * in.sigma_ba0_mps2;
    P.block<3, 3>(ErrIdx::kBw, ErrIdx::kBw) = Mat3::Identity() * in.sigma_bw0_radps * in.sigma_bw0_radps;
    have_reference = false;
    state_initialized = false;
    gyro_integral = Vec3::Zero();
    gyro_time_s = 0.0;
    bad_frames = 0;
    updates_since_reset = 0;
    converged = false;
  }

  /// Gravity direction from the mean specific force of the recent filtered samples (if the vehicle is near
  /// rest: |mean| within 10 % of g). Specific force at rest points up, gravity down: g = -f/|f|.
  bool gravityFromAccel(double up_to_t_s, UnitVector* g) const {
    Vec3 sum = Vec3::Zero();
    int n = 0;
    for (size_t i = imu_buffer.size(); i-- > 0;) {
      const ImuSample& s = imu_buffer[i];
      if (s.t_s > up_to_t_s) continue;
      if (up_to_t_s - s.t_s > 0.5) break;
      sum += s.accel_mps2;
      ++n;
    }
    if (n == 0) return false;
    const Vec3 f = sum / n;
    const double g0 = params.imu.gravity_mps2;
    if (!f.allFinite() || std::abs(f.norm() - g0) > 0.1 * g0) return false;
    *g = UnitVector(-f);
    return true;
  }

  /// Propagates the state from t_state to t_target with the filtered samples, splitting the last interval.
  /// Sample k (stamp t_k) is held over (t_{k-1}, t_k]. Accumulates the raw gyro integral for the update.
  void propagateTo(double t_target) {
    size_t i = 0;
    while (i < imu_buffer.size() && t_state_s >= imu_buffer[i].t_s) ++i;
    while (t_state_s < t_target && i < imu_buffer.size()) {
      const ImuSample& s = imu_buffer[i];
      const double t_end = std::min(s.t_s, t_target);
      const double dt = t_end - t_state_s;
      if (dt > 0.0) {
        predict(s.accel_mps2, s.gyro_radps, dt, params.imu, params.process, &x, &P);
        gyro_integral += s.gyro_radps * dt;
        gyro_time_s += dt;
        t_state_s = t_end;
      }
      if (s.t_s <= t_target) ++i;
    }
    t_state_s = t_target;
    // Drop samples no longer needed (keep the one that covers t_state onwards).
    while (imu_buffer.size() > 1 && imu_buffer[0].t_s <= t_state_s) imu_buffer.pop();
  }

  void checkDivergence(const UpdateStats& stats, std::string* reason) {
    const DivergenceParams& dv = params.divergence;
    if (!x.allFinite() || !P.allFinite()) {
      *reason = "non-finite state or covariance";
      return;
    }
    const double d = x.distance_m();
    if (!(d > dv.min_distance_m && d < dv.max_distance_m)) {
      std::ostringstream os;
      os << "distance " << d << " m outside [" << dv.min_distance_m << ", " << dv.max_distance_m << "] m";
      *reason = os.str();
      return;
    }
    const double sigma_d = std::sqrt(std::max(0.0, P(0, 0))) / (x.alpha * x.alpha);
    if (sigma_d > dv.max_sigma_distance_m) {
      std::ostringstream os;
      os << "distance 1-sigma " << sigma_d << " m above " << dv.max_sigma_distance_m << " m";
      *reason = os.str();
      return;
    }
    const bool bad_residual = stats.applied && params.mode != UpdateMode::kFeature &&
                              stats.rms_residual > dv.max_photometric_rms;
    bad_frames = (bad_residual || !stats.applied) ? bad_frames + 1 : 0;
    if (bad_frames >= dv.bad_frames_before_reset) {
      std::ostringstream os;
      os << bad_frames << " consecutive frames with a bad or skipped update";
      *reason = os.str();
    }
  }

  void processImage(PendingImage& img) {
    const auto t0 = std::chrono::steady_clock::now();
    FrameResult r;
    r.t_s = img.t_s;
    char msg[kMessageCapacity] = "";  // the result's message, formatted without allocation

    if (!state_initialized) {
      // The filter starts at the first image: gravity from the accelerometer, no propagation before.
      UnitVector g;
      if (params.init.g0_from_accel && gravityFromAccel(img.t_s, &g)) x.g = g;
      t_state_s = img.t_s;
      state_initialized = true;
      while (imu_buffer.size() > 1 && imu_buffer[1].t_s <= t_state_s) imu_buffer.pop();
    } else {
      propagateTo(img.t_s);
    }

    PreprocessedFrame& cur = frames[1 - ref_index];
    img_pre.process(img.gray, img.t_s, &cur);

    UpdateStats stats;
    if (have_reference) {
      const PreprocessedFrame& ref = frames[ref_index];
      const double dt = cur.t_s - ref.t_s;
      const Vec3 gyro_mean = gyro_time_s > 0.0 ? Vec3(gyro_integral / gyro_time_s) : Vec3::Zero();
      if (params.mode == UpdateMode::kFeature) {
        stats = feature.update(ref, cur, img_pre.workingK(), gyro_mean, dt, &x, &P);
      } else {
        stats = photometric.update(ref, cur, img_pre.workingK(), gyro_mean, dt, &x, &P);
      }
    }
    gyro_integral.setZero();
    gyro_time_s = 0.0;
    ref_index = 1 - ref_index;
    const bool had_reference = have_reference;
    have_reference = true;

    const auto t1 = std::chrono::steady_clock::now();
    r.update_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
    r.update_applied = stats.applied;
    r.passes = stats.passes;
    r.photometric_rms = stats.rms_residual;
    r.valid_ratio = stats.valid_ratio;
    if (stats.applied) ++updates_since_reset;

    std::string reason;
    checkDivergence(stats, &reason);
    if (!reason.empty()) {
      ++resets;
      warn("filter reset: " + reason);
      resetFilter();
      // Restart from this image: it becomes the new reference.
      UnitVector g;
      if (params.init.g0_from_accel && gravityFromAccel(img.t_s, &g)) x.g = g;
      t_state_s = img.t_s;
      state_initialized = true;
      have_reference = true;
      r.status = FilterStatus::kReset;
      std::snprintf(msg, sizeof(msg), "%s", reason.c_str());
    } else if (!converged) {
      const double relative_sigma_d = std::sqrt(std::max(0.0, P(0, 0))) / x.alpha;  // sigma_d / d
      converged = updates_since_reset > 0 && relative_sigma_d < params.init.tracking_max_relative_sigma_d;
      r.status = converged ? FilterStatus::kTracking : FilterStatus::kInitializing;
      if (!had_reference) {
        std::snprintf(msg, sizeof(msg), "first image: reference set");
      } else if (updates_since_reset == 0) {
        std::snprintf(msg, sizeof(msg), "waiting for a valid image update");
      } else if (!converged) {
        std::snprintf(msg, sizeof(msg), "converging: sigma_d/d = %g (tracking below %g)", relative_sigma_d,
                      params.init.tracking_max_relative_sigma_d);
      }
    } else {
      r.status = FilterStatus::kTracking;
      if (!stats.applied) {
        std::snprintf(msg, sizeof(msg), "update skipped: too few valid pixels or non-finite system");
      }
    }
    status = r.status;
    r.state = x;
    r.covariance = P;
    // Into a ring slot (the oldest unread result is dropped when full), reusing the slot's message buffer.
    FrameResult& slot = results.emplaceSlot();
    r.message.swap(slot.message);
    r.message.assign(msg);
    slot = std::move(r);
  }

  /// Processes every pending image whose stamp is covered by filtered IMU data.
  void processReady() {
    while (!images.empty()) {
      PendingImage& img = images[0];
      if (imu_buffer.empty() || imu_buffer.back().t_s < img.t_s) return;
      processImage(img);
      images.pop();
    }
  }

  CameraModel camera;
  EstimatorParams params;
  ImuPreprocessor imu_pre;
  ImagePreprocessor img_pre;
  PhotometricUpdate photometric;
  FeatureUpdate feature;

  Ring<ImuSample> imu_buffer;   // filtered samples in C, delay-compensated stamps
  Ring<PendingImage> images;    // images waiting for IMU coverage
  Ring<FrameResult> results;    // unread results
  PreprocessedFrame frames[2];
  int ref_index = 0;

  State x;
  ErrorCov P = ErrorCov::Zero();
  double t_state_s = 0.0;
  bool state_initialized = false;
  bool have_reference = false;
  FilterStatus status = FilterStatus::kInitializing;
  Vec3 gyro_integral = Vec3::Zero();
  double gyro_time_s = 0.0;
  int bad_frames = 0;
  int updates_since_reset = 0;
  bool converged = false;  // sigma_d / d has fallen below the tracking threshold since the last reset
  int resets = 0;

  bool have_raw_imu = false;
  double last_raw_imu_t_s = 0.0;
  double last_image_t_s = -1e300;
  std::string warning;
};

Estimator::Estimator(const CameraModel& camera, const EstimatorParams& params)
    : impl_(new Impl(camera, params)) {}

Estimator::~Estimator() = default;

bool Estimator::addImu(const ImuSample& raw) {
  Impl& m = *impl_;
  if (!std::isfinite(raw.t_s) || !raw.accel_mps2.allFinite() || !raw.gyro_radps.allFinite()) {
    m.warn("IMU sample with a non-finite value rejected");
    return false;
  }
  if (m.have_raw_imu) {
    const double dt = raw.t_s - m.last_raw_imu_t_s;
    if (dt < -1.0) {
      // Time jumped backwards (e.g. a looping bag): start again.
      std::ostringstream os;
      os << "time jumped back by " << -dt << " s: resetting";
      reset(os.str());
    } else if (dt <= 0.0) {
      m.warn(dt == 0.0 ? "duplicated IMU stamp rejected" : "out-of-order IMU sample rejected");
      return false;
    } else if (dt > m.params.max_imu_gap_s) {
      std::ostringstream os;
      os << "IMU gap of " << dt << " s";
      m.warn(os.str());
    }
  }
  m.have_raw_imu = true;
  m.last_raw_imu_t_s = raw.t_s;
  ImuSample filtered;
  if (m.imu_pre.push(raw, &filtered)) {
    if (!m.imu_buffer.empty() && filtered.t_s <= m.imu_buffer.back().t_s) return true;
    m.imu_buffer.push(filtered);
    m.processReady();
  }
  return true;
}

bool Estimator::addImage(double t_cam_s, const cv::Mat& image) {
  Impl& m = *impl_;
  const double t_s = t_cam_s + m.camera.timeshift_cam_imu_s;
  if (!std::isfinite(t_s)) {
    m.warn("image with a non-finite stamp rejected");
    return false;
  }
  if (image.empty() || image.cols != m.camera.K.width || image.rows != m.camera.K.height) {
    std::ostringstream os;
    os << "image of " << image.cols << "x" << image.rows << " px rejected: calibration is " << m.camera.K.width
       << "x" << m.camera.K.height << " px";
    m.warn(os.str());
    return false;
  }
  if (t_s <= m.last_image_t_s) {
    if (t_s < m.last_image_t_s - 1.0) {
      reset("image time jumped backwards: resetting");
    } else {
      m.warn(t_s == m.last_image_t_s ? "duplicated image stamp rejected" : "out-of-order image rejected");
      return false;
    }
  }
  const int depth = image.depth();
  const int channels = image.channels();
  const bool supported = (depth == CV_8U && (channels == 1 || channels == 3 || channels == 4)) ||
                         (depth == CV_16U && channels == 1);
  if (!supported) {
    m.warn("image of unsupported type rejected (expected 8-bit grey, 16-bit grey, BGR or BGRA)");
    return false;
  }
  if (m.images.full()) m.warn("image queue full (no IMU data covering the images): oldest image dropped");
  PendingImage& slot = m.images.emplaceSlot();
  slot.t_s = t_s;
  if (channels == 1 && depth == CV_8U) {
    image.copyTo(slot.gray);
  } else if (channels == 1) {
    image.convertTo(slot.gray, CV_8U, 1.0 / 256.0);
  } else if (channels == 3) {
    cv::cvtColor(image, slot.gray, cv::COLOR_BGR2GRAY);
  } else {
    cv::cvtColor(image, slot.gray, cv::COLOR_BGRA2GRAY);
  }
  m.last_image_t_s = t_s;
  m.processReady();
  return true;
}

bool Estimator::popResult(FrameResult* out) {
  Impl& m = *impl_;
  if (m.results.empty()) return false;
  *out = m.results[0];  // copy: the slot keeps its message buffer, `out` reuses its own
  m.results.pop();
  return true;
}

void Estimator::reset(const std::string& reason) {
  Impl& m = *impl_;
  m.warn("reset: " + reason);
  m.resetFilter();
  m.imu_pre.reset();
  m.imu_buffer.clear();
  m.images.clear();
  m.have_raw_imu = false;
  m.last_image_t_s = -1e300;
  m.status = FilterStatus::kInitializing;
  ++m.resets;
}

const State& Estimator::state() const { return impl_->x; }
const ErrorCov& Estimator::covariance() const { return impl_->P; }
FilterStatus Estimator::status() const { return impl_->status; }
double Estimator::stateTime() const { return impl_->t_state_s; }
const EstimatorParams& Estimator::params() const { return impl_->params; }
const PinholeK& Estimator::workingK() const { return impl_->img_pre.workingK(); }
const cv::Mat& Estimator::lastResidualImage() const { return impl_->photometric.residualImage(); }

std::string Estimator::takeWarning() {
  std::string w;
  w.swap(impl_->warning);
  return w;
}

}  // namespace diekf
