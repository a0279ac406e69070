// diekf_import: recorded datasets (mynteye folder, EuRoC MAV) -> the project's bag layout.
#include <iostream>

#include "diekf/sim/importers.h"

using namespace diekf::sim;

int main(int argc, char** argv) {
  ImportOptions opt;
  std::string err;
  const int r = parseImportArgs(std::vector<std::string>(argv + 1, argv + argc), &opt, &err);
  if (r == 1) {
    std::cout << importUsage();
    return 0;
  }
  if (r < 0) {
    std::cerr << "diekf_import: " << err << "\n";
    return 2;
  }
  try {
    const ImportSummary s = runImport(opt);
    for (const std::string& n : s.notes) std::cerr << "diekf_import: note: " << n << "\n";
    std::cout << "wrote " << s.bag_path << ": " << s.images << " images, " << s.imu << " IMU samples, " << s.poses
              << " poses\n";
  } catch (const std::exception& e) {
    std::cerr << "diekf_import: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
