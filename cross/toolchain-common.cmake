# Shared part of the cross toolchain files (cross/toolchain-*.cmake set DIEKF_CROSS_TRIPLET and DIEKF_CROSS_QEMU).
#
# DIEKF_SYSROOT (cache variable or environment variable): a folder with the target's libraries and headers in
# Debian's multiarch layout (usr/lib/<triplet>, usr/include), e.g. Debian packages unpacked with dpkg-deb -x
# (cross/cross_check.sh does this), or a copy of the board's / and /usr. Without it, the libraries are expected
# in the host's own multiarch folders (/usr/lib/<triplet>).
#
# Tests run under qemu-user (CMAKE_CROSSCOMPILING_EMULATOR; ctest uses it): the sysroot is the emulator's -L
# prefix, its library folders (including Debian's alternatives folders such as usr/lib/<triplet>/blas, which
# dpkg-deb -x leaves without their symlinks) go to LD_LIBRARY_PATH of the target and to -rpath-link of the linker.
set(CMAKE_C_COMPILER ${DIEKF_CROSS_TRIPLET}-gcc)
set(CMAKE_CXX_COMPILER ${DIEKF_CROSS_TRIPLET}-g++)
set(CMAKE_LIBRARY_ARCHITECTURE ${DIEKF_CROSS_TRIPLET})

if(NOT DIEKF_SYSROOT AND DEFINED ENV{DIEKF_SYSROOT})
  set(DIEKF_SYSROOT $ENV{DIEKF_SYSROOT})
endif()
# try_compile projects see the same sysroot.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES DIEKF_SYSROOT)

if(DIEKF_SYSROOT)
  set(CMAKE_SYSROOT ${DIEKF_SYSROOT})
  set(CMAKE_FIND_ROOT_PATH ${DIEKF_SYSROOT})
  set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
  set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
  set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
  set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
  set(_diekf_lib_dirs ${DIEKF_SYSROOT}/lib/${DIEKF_CROSS_TRIPLET} ${DIEKF_SYSROOT}/usr/lib/${DIEKF_CROSS_TRIPLET})
  file(GLOB _diekf_sub LIST_DIRECTORIES true ${DIEKF_SYSROOT}/usr/lib/${DIEKF_CROSS_TRIPLET}/*)
  foreach(d ${_diekf_sub})
    file(GLOB _diekf_so ${d}/lib*.so.*)
    if(IS_DIRECTORY ${d} AND _diekf_so)
      list(APPEND _diekf_lib_dirs ${d})
    endif()
  endforeach()
  string(REPLACE ";" ":" _diekf_lib_path "${_diekf_lib_dirs}")
  set(CMAKE_EXE_LINKER_FLAGS_INIT "-Wl,-rpath-link,${_diekf_lib_path}")
  set(CMAKE_SHARED_LINKER_FLAGS_INIT "-Wl,-rpath-link,${_diekf_lib_path}")
  set(CMAKE_CROSSCOMPILING_EMULATOR ${DIEKF_CROSS_QEMU} -L ${DIEKF_SYSROOT} -E LD_LIBRARY_PATH=${_diekf_lib_path})
else()
  set(CMAKE_CROSSCOMPILING_EMULATOR ${DIEKF_CROSS_QEMU} -L /)
endif()
