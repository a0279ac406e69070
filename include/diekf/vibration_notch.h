// Notch filters that follow the propellers' vibration tones in the raw IMU stream (ImuPreprocessor, before the
// low-pass). At IMU rates below twice the vibration's frequencies the tones fold into the low band (a 165 Hz tone
// sampled at 200 Hz arrives at 35 Hz), where the low-pass attenuates them too little; their frequencies are
// found in the stream's own spectrum and notched out (docs/algorithm.md section 4, "Notches").
//
// Every `hop` samples the power spectrum of the last `window` accelerometer samples (Hann window, the three
// axes summed) is searched between `min_hz` and the Nyquist frequency for tones standing `peak_ratio` times above
// the band's median power; up to `max_notches` of them, strongest first, get a second-order notch (unit gain at
// 0 Hz) of quality `q` on all six channels. A notch whose tone is gone is removed. Fixed-size storage after
// construction: no allocation per sample.
#pragma once

#include <array>
#include <vector>

#include <Eigen/Core>

#include "diekf/biquad.h"

namespace diekf {

class VibrationNotch {
 public:
  using Vec6 = Biquad6::Vec6;
  static constexpr int kMaxNotches = 4;

  struct Options {
    double min_hz = 20.0;     ///< lowest tone notched (the low-pass's cutoff: the motion's band lies below), Hz
    int max_notches = 2;      ///< tones notched at once, 1..kMaxNotches
    int window = 256;         ///< samples per spectrum (power of two, >= 32)
    int hop = 64;             ///< samples between two spectra
    double q = 3.0;           ///< notch quality: -3 dB width f0 / q
    double peak_ratio = 20.0; ///< a tone's power over the band's median power
  };

  /// Throws std::invalid_argument on a rate <= 0, min_hz outside (0, rate / 2) or bad options (bandFits false).
  VibrationNotch(double rate_hz, const Options& options);
  /// Whether the searched band (min_hz up to Nyquist) holds at least five bins of the window at this rate.
  static bool bandFits(double rate_hz, const Options& options);

  /// One raw sample (specific force, body rate; any frame): the sample with the tones notched out.
  Vec6 apply(const Vec6& in);
  /// Forgets the spectrum and the notches.
  void reset();

  int activeNotches() const;
  /// Centre frequency of notch i (0 <= i < activeNotches()), Hz.
  double frequencyHz(int i) const;
  /// Group delay of the active notches at 0 Hz, in samples (sum over them).
  double delaySamples() const;

 private:
  struct Notch {
    bool active = false;
    double f_hz = 0.0;
    Biquad6 section;
  };
  void analyse();
  void fft();  // re_, im_ in place
  void place(Notch* n, double f_hz, const Vec6& x);

  double rate_hz_;
  Options opt_;
  std::vector<Eigen::Vector3d> ring_;  // last `window` accelerometer samples
  std::vector<double> hann_, cos_, sin_, power_, sorted_, re_, im_;
  std::vector<int> bitrev_;
  int k_lo_ = 1, k_hi_ = 1;  // searched bins [k_lo_, k_hi_]
  long count_ = 0;           // samples seen since the start
  int since_analysis_ = 0;
  Vec6 last_in_ = Vec6::Zero();
  std::array<Notch, kMaxNotches> notches_;
};

}  // namespace diekf
