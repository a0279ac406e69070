# NEON for the SIMD code on 32-bit ARM (included by CMakeLists.txt and cross/CMakeLists.txt).
#
# The photometric sweep and the preprocessing use OpenCV's universal intrinsics, which compile to NEON only when
# the compiler targets NEON. AArch64 always has it. ARMv7 (armhf: the Odroid XU4's Cortex-A15/A7) has it as an
# option, and the armhf compilers of Debian and Ubuntu default to VFPv3-D16 without NEON, so the intrinsics would
# silently become plain C++ emulation. On such a compiler this adds -mfpu=neon-vfpv4 (Cortex-A7/A15/A17 and
# later; VFPv4 brings fused multiply-add). DIEKF_ARM_NEON=OFF keeps the compiler's default and accepts the scalar
# fallback (for ARMv7 cores without NEON); src/core/photometric_update.cpp refuses to compile without NEON on ARM
# otherwise.
include(CheckCXXSourceCompiles)
include(CheckCXXCompilerFlag)

check_cxx_source_compiles("
#if !defined(__arm__) || defined(__aarch64__)
#error not 32-bit ARM
#endif
int main() { return 0; }" DIEKF_TARGET_ARM32)

if(DIEKF_TARGET_ARM32)
  option(DIEKF_ARM_NEON "32-bit ARM: compile the SIMD code for NEON (-mfpu=neon-vfpv4 if not already on)" ON)
  if(DIEKF_ARM_NEON)
    check_cxx_source_compiles("
#if !defined(__ARM_NEON) && !defined(__ARM_NEON__)
#error no NEON
#endif
int main() { return 0; }" DIEKF_ARM32_NEON_BY_DEFAULT)
    if(NOT DIEKF_ARM32_NEON_BY_DEFAULT)
      check_cxx_compiler_flag(-mfpu=neon-vfpv4 DIEKF_HAVE_MFPU_NEON_VFPV4)
      if(NOT DIEKF_HAVE_MFPU_NEON_VFPV4)
        message(FATAL_ERROR "32-bit ARM: the compiler does not take -mfpu=neon-vfpv4; pass a NEON -mfpu in "
                            "CMAKE_CXX_FLAGS, or -DDIEKF_ARM_NEON=OFF for the scalar fallback")
      endif()
      add_compile_options(-mfpu=neon-vfpv4)
      message(STATUS "diekf: 32-bit ARM, NEON enabled with -mfpu=neon-vfpv4")
    else()
      message(STATUS "diekf: 32-bit ARM, NEON enabled by the compiler's defaults")
    endif()
  else()
    add_definitions(-DDIEKF_ALLOW_SCALAR_SIMD)
    message(WARNING "diekf: DIEKF_ARM_NEON=OFF: the SIMD code falls back to plain C++ (several times slower)")
  endif()
endif()
