// Heap settings for the processes that run for a whole shift.
#pragma once

namespace omni {

// glibc's malloc serves blocks of 128 KiB and more with their own mapping, returned to the
// system when freed, but it raises that threshold to the size of each such block freed (up to
// 32 MiB). A mapper that builds and drops large buffers over and over (likelihood fields, grid
// renders, encoded messages) then has them carved from the heap, between small blocks that stay,
// and the freed space is kept: the pose-graph process's resident memory grew twice as fast as its
// heap on the simulator's ten laps (docs/sim.md, "A long run"). Fixing the threshold at its
// initial 128 KiB keeps large blocks mapped (glibc then leaves its trim threshold at 128 KiB too;
// more page faults, measured there). Call once at the start of main(). A threshold given
// in the environment (MALLOC_MMAP_THRESHOLD_) is left as it is. Returns false when it was not set
// (the environment's, or an allocator that does not take it, e.g. under AddressSanitizer).
bool FixMallocThresholds();

}  // namespace omni
