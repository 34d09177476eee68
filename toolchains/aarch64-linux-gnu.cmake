# Cross build for 64-bit Arm (Jetson Xavier / Orin class) on a Debian bookworm
# x86-64 host: Debian's g++-aarch64-linux-gnu against an arm64 sysroot made by
# toolchains/make-sysroot.sh; tests run under qemu-aarch64-static.
#
#   bash toolchains/make-sysroot.sh
#   cmake --preset aarch64 && cmake --build --preset aarch64 -j2 && ctest --preset aarch64
#
# Settings (cache variables or environment):
#   STILLPOINT_SYSROOT   arm64 sysroot (default /opt/stillpoint-sysroot-arm64)
#   STILLPOINT_ARM_CPU   generic (default: armv8-a, runs on every 64-bit Arm),
#                        xavier (Carmel: armv8.2-a+crypto+fp16), orin (-mcpu=cortex-a78ae)
# Architecture flags live here and only here (see STYLE.md).

set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)

if(NOT STILLPOINT_SYSROOT)
  if(DEFINED ENV{STILLPOINT_SYSROOT})
    set(STILLPOINT_SYSROOT "$ENV{STILLPOINT_SYSROOT}")
  else()
    set(STILLPOINT_SYSROOT /opt/stillpoint-sysroot-arm64)
  endif()
endif()
set(STILLPOINT_SYSROOT "${STILLPOINT_SYSROOT}" CACHE PATH "arm64 sysroot (toolchains/make-sysroot.sh)")
if(NOT EXISTS "${STILLPOINT_SYSROOT}/usr/lib/aarch64-linux-gnu")
  message(FATAL_ERROR "No arm64 sysroot at ${STILLPOINT_SYSROOT}: run toolchains/make-sysroot.sh "
                      "(or set STILLPOINT_SYSROOT)")
endif()
# try_compile() projects re-read this file: pass the settings on.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES STILLPOINT_SYSROOT STILLPOINT_ARM_CPU)

set(CMAKE_SYSROOT "${STILLPOINT_SYSROOT}")
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)

# Libraries, headers and CMake packages come from the sysroot only; programs
# (code generators: lcm-gen, idlc, protoc) from the host.
set(CMAKE_FIND_ROOT_PATH "${STILLPOINT_SYSROOT}")
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)

set(ENV{PKG_CONFIG_SYSROOT_DIR} "${STILLPOINT_SYSROOT}")
set(ENV{PKG_CONFIG_LIBDIR}
    "${STILLPOINT_SYSROOT}/usr/lib/aarch64-linux-gnu/pkgconfig:${STILLPOINT_SYSROOT}/usr/share/pkgconfig")
unset(ENV{PKG_CONFIG_PATH})

# Indirect dependencies (libopencv_* -> libgdal, ...) are resolved in the sysroot.
set(_stillpoint_rpath_link
    "-Wl,-rpath-link,${STILLPOINT_SYSROOT}/usr/lib/aarch64-linux-gnu:${STILLPOINT_SYSROOT}/lib/aarch64-linux-gnu")
foreach(_kind EXE SHARED MODULE)
  set(CMAKE_${_kind}_LINKER_FLAGS_INIT "${_stillpoint_rpath_link}")
endforeach()

if(NOT STILLPOINT_ARM_CPU)
  set(STILLPOINT_ARM_CPU "$ENV{STILLPOINT_ARM_CPU}")
endif()
if(NOT STILLPOINT_ARM_CPU)
  set(STILLPOINT_ARM_CPU generic)
endif()
set(STILLPOINT_ARM_CPU "${STILLPOINT_ARM_CPU}" CACHE STRING "generic | xavier | orin")
if(STILLPOINT_ARM_CPU STREQUAL "generic")
  set(_stillpoint_cpu_flags "-march=armv8-a")
elseif(STILLPOINT_ARM_CPU STREQUAL "xavier")
  # NVIDIA Carmel: Armv8.2-A with crypto and FP16 (what LLVM's -mcpu=carmel
  # enables); GCC 12 has no carmel -mcpu.
  set(_stillpoint_cpu_flags "-march=armv8.2-a+crypto+fp16")
elseif(STILLPOINT_ARM_CPU STREQUAL "orin")
  set(_stillpoint_cpu_flags "-mcpu=cortex-a78ae")
else()
  message(FATAL_ERROR "STILLPOINT_ARM_CPU must be generic, xavier or orin, not '${STILLPOINT_ARM_CPU}'")
endif()
set(CMAKE_C_FLAGS_INIT "${_stillpoint_cpu_flags}")
set(CMAKE_CXX_FLAGS_INIT "${_stillpoint_cpu_flags}")

# ctest and add_custom_command run the arm64 binaries through qemu, with the
# sysroot's dynamic loader and libraries.
find_program(STILLPOINT_QEMU_AARCH64 qemu-aarch64-static)
if(STILLPOINT_QEMU_AARCH64)
  set(CMAKE_CROSSCOMPILING_EMULATOR "${STILLPOINT_QEMU_AARCH64};-L;${STILLPOINT_SYSROOT}")
endif()
