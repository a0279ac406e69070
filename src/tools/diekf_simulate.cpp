// diekf_simulate: synthetic downward-camera + IMU sequences over a textured plane (see docs/simulator.md).
#include <iomanip>
#include <iostream>

#include "diekf/sim/simulator.h"

using namespace diekf::sim;

namespace {

void listPresets(const SimulationOptions& opt) {
  std::cout << "preset   texture       target RMS/max (m/s)  measured RMS/max (m/s)  height (m)   max tilt (deg)\n";
  for (const PresetSpec& p : presetSpecs()) {
    SimulationOptions o = opt;
    o.preset = p.name;
    const SpeedStats st = makeTrajectory(o).stats(100.0);
    std::cout << std::left << std::setw(9) << p.name << std::setw(14) << p.texture << std::right << std::fixed
              << std::setprecision(2) << std::setw(6) << p.rms_speed_mps << " / " << std::setw(4) << p.max_speed_mps
              << "          " << std::setw(6) << st.rms_mps << " / " << std::setw(4) << st.max_mps << "         "
              << std::setw(4) << st.min_height_m << "-" << std::setw(4) << st.max_height_m << "   " << std::setw(6)
              << std::setprecision(1) << st.max_tilt_deg << "\n";
  }
  std::cout << "(duration " << opt.duration_s << " s, seed " << opt.seed << ", incline " << opt.incline_deg << " deg)\n";
}

}  // namespace

int main(int argc, char** argv) {
  SimulationOptions opt;
  std::string err;
  const ParseResult r = parseSimulateArgs(std::vector<std::string>(argv + 1, argv + argc), &opt, &err);
  if (r == ParseResult::kHelp) {
    std::cout << simulateUsage();
    return 0;
  }
  if (r == ParseResult::kError) {
    std::cerr << "diekf_simulate: " << err << "\n";
    return 2;
  }
  try {
    if (r == ParseResult::kListPresets) {
      listPresets(opt);
      return 0;
    }
    const SimulationSummary s = runSimulation(opt, &std::cerr);
    std::cout << std::fixed << std::setprecision(3) << "preset " << opt.preset << ", " << opt.duration_s
              << " s, seed " << opt.seed << "\n"
              << "speed RMS " << s.speed.rms_mps << " m/s, max " << s.speed.max_mps << " m/s; height above plane "
              << s.speed.min_height_m << ".." << s.speed.max_height_m << " m; max tilt " << std::setprecision(1)
              << s.speed.max_tilt_deg << " deg\n"
              << "frames " << s.frames_written << " (dropped " << s.frames_dropped << ", mean sub-frames "
              << std::setprecision(2) << s.mean_subframes << "), IMU samples " << s.imu_samples << ", poses " << s.poses
              << "\n"
              << "wrote " << s.bag_path << " in " << std::setprecision(1) << s.wall_s << " s\n";
  } catch (const std::exception& e) {
    std::cerr << "diekf_simulate: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
