// Which vector unit the photometric sweep was compiled for: NEON on ARM (never the scalar fallback), SSE2 on x86.
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "diekf/photometric_update.h"

namespace diekf {
namespace {

bool startsWith(const std::string& s, const std::string& prefix) { return s.rfind(prefix, 0) == 0; }

TEST(Simd, PhotometricSweepUsesTheTargetsVectorUnit) {
  const std::string simd = photometricSweepSimd();
  // Visible in the test log of every build (native, cross under qemu).
  std::printf("photometric sweep SIMD: %s\n", simd.c_str());
  RecordProperty("photometric_sweep_simd", simd);
  EXPECT_EQ(simd.find("scalar"), std::string::npos) << simd;
#if defined(__aarch64__)
  EXPECT_TRUE(startsWith(simd, "NEON (AArch64")) << simd;
#elif defined(__arm__)
  EXPECT_TRUE(startsWith(simd, "NEON (ARMv7")) << simd;
#elif defined(__x86_64__) || defined(__i386__)
  EXPECT_TRUE(startsWith(simd, "SSE2")) << simd;
#endif
}

}  // namespace
}  // namespace diekf
