# CMake toolchain file: 64-bit ARM Linux (arm64: Odroid N2/N2+/C4/M1, Cortex-A73/A53/A55), Debian's cross compiler
# (crossbuild-essential-arm64) and a sysroot of Debian arm64 packages in DIEKF_SYSROOT (`make cross-check` builds
# one without touching the host's packages; see cross/toolchain-common.cmake). NEON is part of AArch64.
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(DIEKF_CROSS_TRIPLET aarch64-linux-gnu)
set(DIEKF_CROSS_QEMU qemu-aarch64)
include(${CMAKE_CURRENT_LIST_DIR}/toolchain-common.cmake)
