// Renders a (distorted) pinhole camera looking at a textured plane: per-pixel ray table, exact ray-plane
// intersection, trilinear texture sampling by pixel footprint, motion blur by averaging sub-frame renders,
// then a sensor model (gain, vignetting, read + shot noise, 8-bit quantisation).
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include <opencv2/core.hpp>

#include "diekf/camera_model.h"
#include "diekf/sim/clutter.h"
#include "diekf/sim/realism.h"
#include "diekf/sim/texture.h"
#include "diekf/sim/trajectory.h"

namespace diekf {
namespace sim {

/// Camera pose in W: p_W = R_WC p_C + p_WC.
struct CameraPose {
  Eigen::Matrix3d R_WC = Eigen::Matrix3d::Identity();
  Eigen::Vector3d p_WC = Eigen::Vector3d::Zero();
};

struct SensorOptions {
  double vignetting = 0.35;        ///< brightness loss at the image corner (1 - v r^2, r = 1 at the corner)
  double read_noise_dn = 1.5;      ///< read noise, 1-sigma (grey levels)
  double shot_noise_dn = 0.04;     ///< shot-noise variance per grey level of signal (DN)
  /// Black level (pedestal, grey levels) added to the signal after the gain: a gain change (auto-exposure) then
  /// changes the image affinely, gain x signal + black level, not by a pure factor. 0: none.
  double black_level_dn = 0.0;
  /// Camera response (the gamma encoding of webcams' image processors): the signal s (grey levels, noise and
  /// black level included) is written as 255 (s / 255)^(1 / gamma). 1: linear (machine-vision cameras).
  double gamma = 1.0;
  bool noise = true;
  /// Camera-fixed patterns (not owned, width x height of the renderer, or null): the signal of pixel i is
  /// gain ((1 - v r^2) fixed_gain[i] radiance[i] + fixed_add[i]) before noise (shadow, projector dots, lens dirt).
  const float* fixed_gain = nullptr;
  const float* fixed_add = nullptr;    ///< grey levels at gain 1
  /// Per image row (height entries, or null): a factor on the signal of the row (the light's flicker as a
  /// rolling-shutter row integrates it).
  const float* row_gain = nullptr;
};

/// A band of image rows [row0, row1) rendered with its own sub-frame poses (rolling shutter: each band of
/// rows is exposed at its own time). Bands must cover the image rows in order without gaps or overlap.
/// `times` (s, one per pose, or empty) place moving objects (RenderEffects::clutter) at each sub-frame's time.
struct RowBand {
  int row0 = 0, row1 = 0;
  std::vector<CameraPose> poses;
  std::vector<double> times;
};

/// Optional image effects of the band renderer (all off by default).
struct RenderEffects {
  const SpecularPatches* specular = nullptr;  ///< view-dependent glossy ground patches (not owned)
  double defocus_sigma_px = 0.0;              ///< Gaussian blur of the radiance before the sensor (px, this resolution)
  /// Objects on the ground (movers and boxes, not owned): each ray's nearest hit of the ground and the objects
  /// is drawn; movers are placed at the band's sub-frame times (RowBand::times, required with movers).
  const Clutter* clutter = nullptr;
  /// Output (may be null): per pixel, the fraction of sub-frames that saw a mover / a box.
  ClutterMask* mask = nullptr;
};

/// Rolling-shutter bands for an image whose middle row is exposed around `t_mid_s`: row v is centred at
/// t_mid + rowTimeOffset(v, height, readout_s) and averages `n_sub` sub-frames spread over `exposure_s` around
/// it (the same sub-frame times as a global-shutter image). `rows_per_band` rows share the pose of their middle
/// row. With readout_s = 0 the result is one band whose poses are the global-shutter sub-frames. Each band's
/// `times` are its sub-frame times.
std::vector<RowBand> rollingShutterBands(const std::function<CameraPose(double)>& pose_at, double t_mid_s,
                                         int height, double readout_s, double exposure_s, int n_sub,
                                         int rows_per_band = 1);

class Renderer {
 public:
  /// Precomputes the ray table of `cam` (pixel centres at integer coordinates). `threads` >= 1.
  Renderer(const CameraModel& cam, int threads = 2);

  int width() const { return width_; }
  int height() const { return height_; }
  const CameraModel& camera() const { return cam_; }

  /// Mean radiance (grey levels, before gain/vignetting) over the given sub-frame poses into `out`
  /// (width x height floats). Rays that miss the plane get the texture mean.
  void renderRadiance(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex,
                      std::vector<float>* out) const;

  /// Applies gain, vignetting, noise (deterministic for `noise_seed`), rounding to 8 bits.
  cv::Mat applySensor(const std::vector<float>& radiance, double gain, const SensorOptions& opt,
                      std::uint64_t noise_seed) const;

  /// renderRadiance + applySensor, both split over the render threads.
  cv::Mat renderImage(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex, double gain,
                      const SensorOptions& opt, std::uint64_t noise_seed) const;

  /// Like renderImage, with each band of rows rendered from its own poses, and the optional effects
  /// (specular patches in the radiance, defocus blur between radiance and sensor). A single band over all
  /// rows without effects gives exactly renderImage's image.
  cv::Mat renderBands(const std::vector<RowBand>& bands, const Plane& plane, const Texture& tex, double gain,
                      const SensorOptions& opt, std::uint64_t noise_seed, const RenderEffects& fx = {}) const;
  /// The radiance of renderBands (before defocus and the sensor) into `out`.
  void renderRadianceBands(const std::vector<RowBand>& bands, const Plane& plane, const Texture& tex,
                           std::vector<float>* out, const RenderEffects& fx = {}) const;

  /// Largest image displacement (pixels) of ground points seen at `a` when viewed from `b` (sampled grid).
  double motionPixels(const CameraPose& a, const CameraPose& b, const Plane& plane) const;

  /// Relative response of pixel (u, v) to the same radiance: the vignetting `1 - vignetting r^2` of sensorRows.
  float vignetteGain(int u, int v, double vignetting) const {
    return 1.f - static_cast<float>(vignetting) * vignette_r2_[static_cast<std::size_t>(v) * width_ + u];
  }

  /// Undistorted normalised ray (x, y, 1) of pixel (u, v) from the table.
  Eigen::Vector3d ray(int u, int v) const;

 private:
  struct RayEntry {
    float x, y;          // normalised undistorted ray (x, y, 1)
    float footprint;     // |r| * angular size of the pixel (rad)
    float inv_norm;      // 1 / |r|
  };
  void sensorRows(const float* radiance, double gain, const SensorOptions& opt, std::uint64_t noise_seed,
                  cv::Mat* img, int row0, int row1) const;
  void renderRows(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex, float* out,
                  int row0, int row1) const;
  template <bool kSpecular>
  void renderRowsT(const std::vector<CameraPose>& poses, const Plane& plane, const Texture& tex,
                   const SpecularPatches* spec, float* out, int row0, int row1) const;
  template <bool kSpecular>
  void renderRowsClutter(const RowBand& band, const Plane& plane, const Texture& tex, const SpecularPatches* spec,
                         const Clutter& clutter, float* out, float* mask_mover, float* mask_box, int row0,
                         int row1) const;
  void renderBandRows(const std::vector<RowBand>& bands, const Plane& plane, const Texture& tex,
                      const SpecularPatches* spec, float* out, int row0, int row1, const Clutter* clutter = nullptr,
                      ClutterMask* mask = nullptr) const;
  void checkBands(const std::vector<RowBand>& bands) const;
  /// With fx.clutter: checks the bands' times, sizes the mask (fx.mask, else `own`) and returns it; else null.
  ClutterMask* prepareClutter(const std::vector<RowBand>& bands, const RenderEffects& fx, ClutterMask* own) const;

  CameraModel cam_;
  int width_ = 0, height_ = 0, threads_ = 1;
  std::vector<RayEntry> rays_;
  std::vector<float> vignette_r2_;  // squared normalised radius from the principal point (corner = 1)
  std::vector<float> noise_table_;  // unit Gaussian samples, reused with random offsets
  float ray_xmin_ = 0.f, ray_xmax_ = 0.f, ray_ymin_ = 0.f, ray_ymax_ = 0.f;  // extent of the normalised rays
};

}  // namespace sim
}  // namespace diekf
