/* stillpointd: blocks SIGTERM, SIGINT and SIGUSR1, then runs the service
 * (stillpointd-service, beside this program). The signal mask survives exec,
 * so a stop signal that arrives while the service's ~170 shared libraries
 * load waits for it and ends its start-up cleanly, instead of killing the
 * process by the signal's default action. This program links only libc: the
 * window before its own mask is a millisecond at most. */
#include <errno.h>
#include <limits.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

int main(int argc, char** argv) {
  /* Answered here: it needs no library, and works where the service cannot
   * be exec'ed (an arm64 package checked under qemu-user). */
  if (argc == 2 && strcmp(argv[1], "--version") == 0) {
    puts("stillpointd " STILLPOINT_VERSION " (" STILLPOINT_ARCH ")");
    return 0;
  }
  sigset_t stop;
  sigemptyset(&stop);
  sigaddset(&stop, SIGTERM);
  sigaddset(&stop, SIGINT);
  sigaddset(&stop, SIGUSR1); /* save the map: not fatal while the service starts */
  sigprocmask(SIG_BLOCK, &stop, NULL);

  char path[PATH_MAX];
  const ssize_t n = readlink("/proc/self/exe", path, sizeof(path) - 1);
  if (n <= 0 || (size_t)n >= sizeof(path) - 32) {
    fprintf(stderr, "stillpointd: cannot find its own path: %s\n", strerror(errno));
    return 1;
  }
  path[n] = '\0';
  char* slash = strrchr(path, '/');
  strcpy(slash ? slash + 1 : path, "stillpointd-service");
  argv[0] = path;
  execv(path, argv);
  fprintf(stderr, "stillpointd: cannot run %s: %s\n", path, strerror(errno));
  return 1;
}
