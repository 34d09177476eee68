#include "stillpoint/core/program.hpp"

#include <gtest/gtest.h>

#include <new>
#include <stdexcept>
#include <string>

namespace stillpoint {
namespace {

int exitsWith3(int, char**) { return 3; }
int throwsRuntimeError(int, char**) { throw std::runtime_error("disk on fire"); }
int throwsBadAlloc(int, char**) { throw std::bad_alloc(); }
int throwsAnInt(int, char**) { throw 7; }

// A program's main returns its body's status, and an exception escaping the
// body is a message and status 1, not an abort.
TEST(RunProgram, ReportsAnExceptionInsteadOfAborting) {
  char name[] = "tool";
  char* argv[] = {name, nullptr};
  EXPECT_EQ(runProgram("tool", exitsWith3, 1, argv), 3);
  struct Case {
    int (*body)(int, char**);
    const char* message;
  };
  for (const Case& c : {Case{throwsRuntimeError, "tool: disk on fire\n"}, Case{throwsBadAlloc, "tool: std::bad_alloc\n"},
                        Case{throwsAnInt, "tool: unknown error\n"}}) {
    ::testing::internal::CaptureStderr();
    const int status = runProgram("tool", c.body, 1, argv);
    const std::string err = ::testing::internal::GetCapturedStderr();
    EXPECT_EQ(status, 1) << c.message;
    EXPECT_EQ(err, c.message);
  }
}

}  // namespace
}  // namespace stillpoint
