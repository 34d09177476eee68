# CPACK_PRE_BUILD_SCRIPTS of the robot package: removes development files that
# an install() rule outside the "dev" component put into the staging tree
# (static libraries, headers, CMake package files), says which, and drops the
# folders that leaves empty.
set(_stage "${CPACK_TEMPORARY_INSTALL_DIRECTORY}")
if(NOT IS_DIRECTORY "${_stage}")
  message(FATAL_ERROR "CPack staging directory not found: '${_stage}'")
endif()
file(GLOB_RECURSE _files LIST_DIRECTORIES false RELATIVE "${_stage}" "${_stage}/*")
foreach(_file IN LISTS _files)
  if(_file MATCHES "\\.a$|(^|/)include/|(^|/)lib/([^/]+/)?cmake/")
    message(STATUS "package: leaving out development file ${_file} (install it with COMPONENT dev)")
    file(REMOVE "${_stage}/${_file}")
  endif()
endforeach()
file(GLOB_RECURSE _dirs LIST_DIRECTORIES true "${_stage}/*")
list(SORT _dirs ORDER DESCENDING)  # children before parents
foreach(_dir IN LISTS _dirs)
  if(IS_DIRECTORY "${_dir}")
    file(GLOB _entries "${_dir}/*")
    if(NOT _entries)
      file(REMOVE_RECURSE "${_dir}")
    endif()
  endif()
endforeach()
