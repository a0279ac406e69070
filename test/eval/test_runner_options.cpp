// Runner command line and --set overrides.
#include <map>

#include <gtest/gtest.h>

#include "diekf/eval/param_overlay.h"
#include "diekf/eval/runner_options.h"

namespace diekf {
namespace eval {
namespace {

RunnerOptions parse(std::vector<const char*> args) {
  args.insert(args.begin(), "diekf_bag_runner");
  return parseRunnerOptions(static_cast<int>(args.size()), args.data());
}

TEST(RunnerOptions, FullCommandLine) {
  const RunnerOptions o = parse({"--bag", "f.bag", "--camchain", "c.yaml", "--imu", "i.yaml", "--config", "p.yaml",
                                 "--mode", "ekf", "--image-topic", "/img", "--imu-topic=/imu", "--width", "120",
                                 "--set", "photometric/max_passes=5", "--set", "a=b", "--output", "out",
                                 "--gt-velocity-window", "0.05", "--quiet", "--frames-csv", "--export-sequence",
                                 "seq"});
  EXPECT_EQ(o.bag, "f.bag");
  EXPECT_EQ(o.camchain, "c.yaml");
  EXPECT_EQ(o.imu, "i.yaml");
  EXPECT_EQ(o.config, "p.yaml");
  EXPECT_EQ(o.mode, "ekf");
  EXPECT_EQ(o.image_topic, "/img");
  EXPECT_EQ(o.imu_topic, "/imu");
  EXPECT_EQ(o.width_px, 120);
  ASSERT_EQ(o.sets.size(), 2u);
  EXPECT_EQ(o.sets[0], "photometric/max_passes=5");
  EXPECT_EQ(o.output, "out");
  EXPECT_DOUBLE_EQ(o.gt_velocity_window_s, 0.05);
  EXPECT_TRUE(o.quiet);
  EXPECT_TRUE(o.frames_csv);
  EXPECT_EQ(o.export_sequence, "seq");
  EXPECT_DOUBLE_EQ(o.eval_start_delay_s, 3.0);
  EXPECT_FALSE(parse({"--bag", "b", "--camchain", "c", "--output", "o"}).frames_csv);
  EXPECT_TRUE(parse({"--bag", "b", "--camchain", "c", "--output", "o"}).export_sequence.empty());
}

TEST(RunnerOptions, ErrorsAreUsageErrors) {
  EXPECT_THROW(parse({"--camchain", "c", "--output", "o"}), UsageError);            // no --bag
  EXPECT_THROW(parse({"--bag", "b", "--output", "o"}), UsageError);                 // no --camchain
  EXPECT_THROW(parse({"--bag", "b", "--camchain", "c"}), UsageError);               // no --output
  EXPECT_THROW(parse({"--bag", "b", "--camchain", "c", "--output", "o", "--mode", "ukf"}), UsageError);
  EXPECT_THROW(parse({"--bag", "b", "--camchain", "c", "--output", "o", "--width", "9x"}), UsageError);
  EXPECT_THROW(parse({"--bag", "b", "--camchain", "c", "--output", "o", "--frobnicate"}), UsageError);
  EXPECT_THROW(parse({"--bag", "b", "--camchain", "c", "--output"}), UsageError);   // value missing
  EXPECT_THROW(parse({"--bag", "b", "--camchain", "c", "--output", "o", "--set", "novalue"}), UsageError);
  EXPECT_TRUE(parse({"--help"}).help);
  EXPECT_NE(runnerUsage().find("--bag"), std::string::npos);
}

TEST(RunnerOptions, SequenceName) {
  EXPECT_EQ(sequenceNameFromBag("data/flight3.bag"), "flight3");
  EXPECT_EQ(sequenceNameFromBag("results/flight6/sequence.bag"), "flight6");
}

class MapSource : public ParamSource {
 public:
  std::map<std::string, double> values;
  bool get(const std::string& key, double* v) const override {
    const auto it = values.find(key);
    if (it == values.end()) return false;
    *v = it->second;
    return true;
  }
  bool get(const std::string& key, int* v) const override {
    double d;
    if (!get(key, &d)) return false;
    *v = static_cast<int>(d);
    return true;
  }
  bool get(const std::string&, bool*) const override { return false; }
  bool get(const std::string&, std::string*) const override { return false; }
  bool get(const std::string&, std::vector<double>*) const override { return false; }
  std::string origin() const override { return "map"; }
};

TEST(ParamOverlay, OverridesWinAndFallBackToBase) {
  MapSource base;
  base.values["a/x"] = 1.5;
  base.values["a/n"] = 4;
  ParamOverlay overlay(&base);
  overlay.addAssignment("a/x = 2.5");
  overlay.addAssignment("flag=false");
  overlay.addAssignment("v=[0.2, -0.1,0.97]");
  overlay.addAssignment("typo=1");
  double x = 0;
  ASSERT_TRUE(overlay.get("a/x", &x));
  EXPECT_DOUBLE_EQ(x, 2.5);
  int n = 0;
  ASSERT_TRUE(overlay.get("a/n", &n));
  EXPECT_EQ(n, 4);
  bool flag = true;
  ASSERT_TRUE(overlay.get("flag", &flag));
  EXPECT_FALSE(flag);
  std::vector<double> v;
  ASSERT_TRUE(overlay.get("v", &v));
  ASSERT_EQ(v.size(), 3u);
  EXPECT_DOUBLE_EQ(v[1], -0.1);
  EXPECT_FALSE(overlay.get("absent", &x));
  EXPECT_EQ(overlay.unusedOverrides(), std::vector<std::string>{"typo"});
  EXPECT_NE(overlay.origin().find("map"), std::string::npos);
}

TEST(ParamOverlay, WrongTypesThrowNamingTheKey) {
  ParamOverlay overlay(nullptr);
  overlay.addAssignment("k=abc");
  double d;
  int i;
  bool b;
  try {
    overlay.get("k", &d);
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("k=abc"), std::string::npos);
  }
  EXPECT_THROW(overlay.get("k", &i), std::runtime_error);
  EXPECT_THROW(overlay.get("k", &b), std::runtime_error);
  overlay.set("i", "2.5");
  EXPECT_THROW(overlay.get("i", &i), std::runtime_error);
  EXPECT_THROW(overlay.addAssignment("=3"), std::invalid_argument);
  EXPECT_THROW(overlay.addAssignment("nothing"), std::invalid_argument);
}

// The runners' overrides (diekf_bag_runner and diekf_replay share them): --set first, then --mode, then --width,
// which goes to the working width of the mode in use; unknown keys are named, all of them.
TEST(ApplyCommandLine, SetThenModeThenWidth) {
  EstimatorParams p;
  applyCommandLine({"photometric/max_passes=2", "preprocess/working_width_px=64"}, "", 0, &p);
  EXPECT_EQ(p.photometric.max_passes, 2);
  EXPECT_EQ(p.preprocess.working_width_px, 64);
  applyCommandLine({}, "", 120, &p);
  EXPECT_EQ(p.preprocess.working_width_px, 120);
  const int feature_width = p.feature.working_width_px;
  applyCommandLine({}, "lk", 80, &p);
  EXPECT_EQ(p.mode, UpdateMode::kFeature);
  EXPECT_EQ(p.feature.working_width_px, 80);
  EXPECT_NE(feature_width, 80);
  EXPECT_EQ(p.preprocess.working_width_px, 120);
  try {
    applyCommandLine({"no_such/key=1", "photometric/max_passes=3", "also/unknown=2"}, "", 0, &p);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("no_such/key"), std::string::npos) << what;
    EXPECT_NE(what.find("also/unknown"), std::string::npos) << what;
  }
  EXPECT_THROW(applyCommandLine({}, "no_such_mode", 0, &p), std::exception);
}

}  // namespace
}  // namespace eval
}  // namespace diekf
