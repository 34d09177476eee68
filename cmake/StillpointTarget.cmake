# Helpers that give every stillpoint target the same warnings and test wiring.

function(stillpoint_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Werror)
endfunction()

# stillpoint_library(NAME <name> SOURCES ... [PUBLIC_LINKS ...] [PRIVATE_LINKS ...])
# Creates stillpoint_<name> with alias stillpoint::<name>, public headers in include/.
function(stillpoint_library)
  cmake_parse_arguments(ARG "" "NAME" "SOURCES;PUBLIC_LINKS;PRIVATE_LINKS" ${ARGN})
  add_library(stillpoint_${ARG_NAME} ${ARG_SOURCES})
  add_library(stillpoint::${ARG_NAME} ALIAS stillpoint_${ARG_NAME})
  set_target_properties(stillpoint_${ARG_NAME} PROPERTIES EXPORT_NAME ${ARG_NAME}
                        POSITION_INDEPENDENT_CODE ON)
  target_include_directories(stillpoint_${ARG_NAME}
    PUBLIC $<BUILD_INTERFACE:${CMAKE_CURRENT_SOURCE_DIR}/include>
           $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>
    PRIVATE ${CMAKE_CURRENT_SOURCE_DIR}/src)
  target_link_libraries(stillpoint_${ARG_NAME} PUBLIC ${ARG_PUBLIC_LINKS} PRIVATE ${ARG_PRIVATE_LINKS})
  stillpoint_warnings(stillpoint_${ARG_NAME})
  # Component "dev": the robot package (cmake/StillpointPackaging.cmake) leaves it out.
  install(TARGETS stillpoint_${ARG_NAME} EXPORT stillpointTargets COMPONENT dev)
  install(DIRECTORY ${CMAKE_CURRENT_SOURCE_DIR}/include/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
          COMPONENT dev)
endfunction()

# stillpoint_test(NAME <name> SOURCES ... LINKS ... [LABELS ...])
function(stillpoint_test)
  if(NOT STILLPOINT_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "NAME" "SOURCES;LINKS;LABELS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SOURCES})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_LINKS} GTest::gtest GTest::gtest_main)
  stillpoint_warnings(${ARG_NAME})
  add_test(NAME ${ARG_NAME} COMMAND ${ARG_NAME})
  if(NOT ARG_LABELS)
    set(ARG_LABELS unit)
  endif()
  set_tests_properties(${ARG_NAME} PROPERTIES LABELS "${ARG_LABELS}")
endfunction()

# stillpoint_benchmark(NAME <name> SOURCES ... LINKS ...)
function(stillpoint_benchmark)
  if(NOT STILLPOINT_BUILD_BENCHMARKS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "NAME" "SOURCES;LINKS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SOURCES})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_LINKS} benchmark::benchmark benchmark::benchmark_main)
  stillpoint_warnings(${ARG_NAME})
endfunction()

# stillpoint_program_path(<var> <target>)
# Sets <var> to the path a test should run <target> by. Natively the program
# itself; in a cross build a wrapper script that starts it under
# CMAKE_CROSSCOMPILING_EMULATOR, because ctest runs the test binary there but
# a program the test starts (std::system) would go to the host's kernel.
function(stillpoint_program_path var target)
  if(NOT CMAKE_CROSSCOMPILING OR NOT CMAKE_CROSSCOMPILING_EMULATOR)
    set(${var} "$<TARGET_FILE:${target}>" PARENT_SCOPE)
    return()
  endif()
  set(command "")
  foreach(word IN LISTS CMAKE_CROSSCOMPILING_EMULATOR)
    string(APPEND command "'${word}' ")
  endforeach()
  set(wrapper ${CMAKE_BINARY_DIR}/emulated/${target})
  file(GENERATE OUTPUT ${wrapper}
       CONTENT "#!/bin/sh\nexec ${command}'$<TARGET_FILE:${target}>' \"$@\"\n"
       FILE_PERMISSIONS OWNER_READ OWNER_WRITE OWNER_EXECUTE GROUP_READ GROUP_EXECUTE
                        WORLD_READ WORLD_EXECUTE)
  set(${var} ${wrapper} PARENT_SCOPE)
endfunction()
