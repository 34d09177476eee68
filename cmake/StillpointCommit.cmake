# Writes OUT (a header defining STILLPOINT_COMMIT) from `git describe` of SRC,
# at every build, rewriting it only when the commit changed.
# usage: cmake -DSRC=<source dir> -DOUT=<header> -P StillpointCommit.cmake
set(commit "unknown")
find_package(Git QUIET)
if(GIT_FOUND AND EXISTS "${SRC}/.git")
  execute_process(COMMAND "${GIT_EXECUTABLE}" describe --always --dirty --abbrev=12
    WORKING_DIRECTORY "${SRC}" OUTPUT_VARIABLE described OUTPUT_STRIP_TRAILING_WHITESPACE
    RESULT_VARIABLE rc ERROR_QUIET)
  if(rc EQUAL 0 AND described)
    set(commit "${described}")
  endif()
endif()
set(text "#pragma once\n#define STILLPOINT_COMMIT \"${commit}\"\n")
if(EXISTS "${OUT}")
  file(READ "${OUT}" old)
endif()
if(NOT old STREQUAL text)
  file(WRITE "${OUT}" "${text}")
endif()
