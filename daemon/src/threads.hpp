#pragma once
// Thread naming, pinning and real-time priority. Each call degrades instead of
// failing: a core the machine lacks is skipped with a warning, and SCHED_FIFO
// without permission (no CAP_SYS_NICE / RLIMIT_RTPRIO) keeps normal scheduling
// with a warning. The warnings are returned so callers (and tests) see them.
#include <string>
#include <vector>

#include "config.hpp"

namespace stillpoint::daemon {

// Cores this process may run on (sched_getaffinity at start-up), ascending.
std::vector<int> availableCores();

// Applies `placement` to the calling thread and names it (Linux: at most 15
// characters). `what` is the config field, e.g. "threads.tracking".
std::vector<std::string> placeCurrentThread(const std::string& name, const ThreadPlacement& placement,
                                            const std::vector<int>& available, const std::string& what);

// For a thread started from a placed thread that is to be placed on its own:
// undoes what it inherited (runs on every available core again, normal
// scheduling) so that an empty placement means "not pinned" for it too.
void clearInheritedPlacement(const std::vector<int>& available);

// Locks the process's pages in RAM, present and future (mlockall), so a page
// fault never stalls tracking. Only with CAP_IPC_LOCK or an unlimited
// RLIMIT_MEMLOCK (the unit grants both): under a finite limit future
// allocations past it would fail, so nothing is locked and a warning says why.
// Returns the warnings; `locked` tells whether the lock took.
std::vector<std::string> lockMemory(bool* locked);

// Whether the process holds CAP_IPC_LOCK (effective set).
bool hasIpcLockCapability();

}  // namespace stillpoint::daemon
