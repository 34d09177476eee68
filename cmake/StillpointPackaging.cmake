# Debian package for a robot: `cpack` in a build folder configured with
# CMAKE_INSTALL_PREFIX=/usr makes stillpoint_<version>_<arch>.deb (amd64 or,
# cross-built, arm64). Included at the end of the top-level CMakeLists.txt.
#
# Contents: every install() rule outside the "dev" component (the programs
# stillpoint-*, and stillpointd when it exists; models/), the systemd unit
# when systemd/stillpointd.service exists, and the default SLAM configuration
# as /etc/stillpoint/slam.yaml (a conffile: upgrades keep local changes).
# Libraries, headers and the CMake package are the "dev" component, left out.
# Depends: computed from the binaries' shared libraries (cmake/deb-depends.sh).

if(NOT CMAKE_INSTALL_PREFIX STREQUAL "/usr")
  message(STATUS "Packaging: CMAKE_INSTALL_PREFIX is ${CMAKE_INSTALL_PREFIX}; "
                 "configure with -DCMAKE_INSTALL_PREFIX=/usr for a .deb")
endif()

# /etc/stillpoint when the prefix is /usr (GNUInstallDirs' special case).
set(STILLPOINT_CONFIG_INSTALL_DIR "${CMAKE_INSTALL_FULL_SYSCONFDIR}/stillpoint")
set(stillpoint_config_files slam.yaml camera_example.yaml)
foreach(f stillpointd.yaml ipc.yaml)
  if(EXISTS ${PROJECT_SOURCE_DIR}/config/${f})
    list(APPEND stillpoint_config_files ${f})
  endif()
endforeach()
list(TRANSFORM stillpoint_config_files PREPEND ${PROJECT_SOURCE_DIR}/config/ OUTPUT_VARIABLE stillpoint_config_paths)
install(FILES ${stillpoint_config_paths} DESTINATION ${STILLPOINT_CONFIG_INSTALL_DIR})
if(IS_ABSOLUTE "${STILLPOINT_CONFIG_INSTALL_DIR}")
  list(TRANSFORM stillpoint_config_files PREPEND ${STILLPOINT_CONFIG_INSTALL_DIR}/ OUTPUT_VARIABLE stillpoint_conffiles)
  list(JOIN stillpoint_conffiles "\n" stillpoint_conffiles)
  file(WRITE ${CMAKE_BINARY_DIR}/package-control/conffiles "${stillpoint_conffiles}\n")
  set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA ${CMAKE_BINARY_DIR}/package-control/conffiles)
endif()
if(EXISTS ${PROJECT_SOURCE_DIR}/systemd/stillpointd.service)
  install(FILES ${PROJECT_SOURCE_DIR}/systemd/stillpointd.service
          DESTINATION ${CMAKE_INSTALL_PREFIX}/lib/systemd/system)
endif()
# The default segmentation model; lib/semantic installs models/ itself when built.
if(EXISTS ${PROJECT_SOURCE_DIR}/models/person_selfie_256.onnx AND NOT TARGET stillpoint_semantic)
  install(FILES ${PROJECT_SOURCE_DIR}/models/person_selfie_256.onnx
          DESTINATION ${CMAKE_INSTALL_DATADIR}/stillpoint/models)
endif()

if(CMAKE_SYSTEM_PROCESSOR MATCHES "^(aarch64|arm64)$")
  set(CPACK_DEBIAN_PACKAGE_ARCHITECTURE arm64)
elseif(CMAKE_SYSTEM_PROCESSOR MATCHES "^(x86_64|AMD64)$")
  set(CPACK_DEBIAN_PACKAGE_ARCHITECTURE amd64)
endif()

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME stillpoint)
set(CPACK_PACKAGE_VENDOR "stillpoint")
set(CPACK_PACKAGE_CONTACT "stillpoint maintainers <stillpoint@localhost>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "Real-time RGB-D SLAM daemon for dynamic scenes")
set(CPACK_PACKAGE_DESCRIPTION
    "stillpoint tracks an RGB-D camera and removes moving objects (geometry and semantic modules). This package holds the programs, the systemd unit, the default configuration in /etc/stillpoint and the default segmentation model.")
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_HOMEPAGE "https://localhost/stillpoint")
set(CPACK_PACKAGING_INSTALL_PREFIX "${CMAKE_INSTALL_PREFIX}")
set(CPACK_STRIP_FILES ON)
set(CPACK_RESOURCE_FILE_LICENSE ${PROJECT_SOURCE_DIR}/LICENSE)
set(CPACK_PACKAGE_DIRECTORY ${CMAKE_BINARY_DIR}/package)

# Every component but dev (get_cmake_property sees the rules of the whole tree
# because this file is included last).
get_cmake_property(_stillpoint_components COMPONENTS)
list(REMOVE_ITEM _stillpoint_components dev)
set(CPACK_COMPONENTS_ALL ${_stillpoint_components})
# One package of those components (a monolithic package would take them all).
set(CPACK_DEB_COMPONENT_INSTALL ON)
set(CPACK_COMPONENTS_GROUPING ALL_COMPONENTS_IN_ONE)

# Read by cpack: computes Depends from the staged binaries.
set(STILLPOINT_PACKAGE_BUILD_DIR ${CMAKE_BINARY_DIR})
set(STILLPOINT_PACKAGE_DEPENDS_SCRIPT ${PROJECT_SOURCE_DIR}/cmake/deb-depends.sh)
configure_file(${PROJECT_SOURCE_DIR}/cmake/StillpointCPackOptions.cmake.in
               ${CMAKE_BINARY_DIR}/StillpointCPackOptions.cmake @ONLY)
set(CPACK_PROJECT_CONFIG_FILE ${CMAKE_BINARY_DIR}/StillpointCPackOptions.cmake)
set(CPACK_PRE_BUILD_SCRIPTS ${PROJECT_SOURCE_DIR}/cmake/StillpointCPackPrune.cmake)

include(CPack)
