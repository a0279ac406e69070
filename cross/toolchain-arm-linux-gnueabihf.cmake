# CMake toolchain file: 32-bit ARM Linux, hard float (armhf: Odroid XU4, Cortex-A15/A7), Debian's cross compiler
# (crossbuild-essential-armhf) and a sysroot of Debian armhf packages in DIEKF_SYSROOT (see
# cross/toolchain-common.cmake). Debian's armhf compiler targets ARMv7 with VFPv3-D16 and no NEON;
# cmake/arm_neon.cmake adds -mfpu=neon-vfpv4 (Cortex-A7/A15 have NEON and VFPv4).
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR armv7l)
set(DIEKF_CROSS_TRIPLET arm-linux-gnueabihf)
set(DIEKF_CROSS_QEMU qemu-arm)
include(${CMAKE_CURRENT_LIST_DIR}/toolchain-common.cmake)
