# Fix-ups for cross builds against a sysroot (toolchains/aarch64-linux-gnu.cmake).
# Included by the top-level CMakeLists.txt only when CMAKE_CROSSCOMPILING, after
# the find_package() calls.

# stillpoint_sysroot_link_paths(<imported target>...)
# Some packages' CMake targets list libraries by absolute host paths
# (Debian's Ceres: /usr/lib/<triplet>/libblas.so, liblapack.so, ...). The
# linker does not prefix such paths with --sysroot: move them into the sysroot.
function(stillpoint_sysroot_link_paths)
  if(NOT CMAKE_SYSROOT)
    return()
  endif()
  foreach(target IN LISTS ARGN)
    if(NOT TARGET ${target})
      continue()
    endif()
    get_target_property(libs ${target} INTERFACE_LINK_LIBRARIES)
    if(NOT libs)
      continue()
    endif()
    set(fixed "")
    foreach(lib IN LISTS libs)
      if(lib MATCHES "^/(usr/)?lib/" AND NOT lib MATCHES "^${CMAKE_SYSROOT}/")
        set(lib "${CMAKE_SYSROOT}${lib}")
        if(NOT EXISTS "${lib}")
          message(WARNING "${target} links ${lib}, which the sysroot lacks "
                          "(add its -dev package to toolchains/make-sysroot.sh)")
        endif()
      endif()
      list(APPEND fixed "${lib}")
    endforeach()
    set_target_properties(${target} PROPERTIES INTERFACE_LINK_LIBRARIES "${fixed}")
  endforeach()
endfunction()

stillpoint_sysroot_link_paths(Ceres::ceres ceres)
