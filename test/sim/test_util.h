// Helpers for the simulator tests: unique temporary directories removed at scope exit.
#pragma once

#include <atomic>
#include <filesystem>
#include <random>
#include <string>

namespace diekf {
namespace sim {
namespace simtest {

class TempDir {
 public:
  TempDir() {
    std::random_device rd;
    path_ = std::filesystem::temp_directory_path() / ("diekf_sim_test_" + std::to_string(rd()) + std::to_string(rd()));
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string str() const { return path_.string(); }
  std::filesystem::path path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace simtest
}  // namespace sim
}  // namespace diekf
