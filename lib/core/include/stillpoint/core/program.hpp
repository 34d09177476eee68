#pragma once
// A program's main with no exception escaping it.

namespace stillpoint {

// Runs body(argc, argv) and returns its exit status. An exception that
// escapes it (an allocation that fails, a library call that throws where no
// caller expected it) is reported on stderr as "<program>: <what>" and gives
// exit status 1 instead of std::terminate's abort.
int runProgram(const char* program, int (*body)(int, char**), int argc, char** argv) noexcept;

}  // namespace stillpoint
