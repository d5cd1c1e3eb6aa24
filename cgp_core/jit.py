"""The one place cgp_core compiles Python with numba.

Hot loops that numpy cannot batch (contact generation and the sequential-impulse solver for a few bodies, the
boid neighbour sums) are written as plain Python loops that read like the lecture, and decorated with
:func:`njit`.  numba compiles them to machine code on first call and caches the result next to the source
(``__pycache__/*.nbi|*.nbc``), so only the first start after an install or an edit pays the compile time.

The same functions run as ordinary Python under ``NUMBA_DISABLE_JIT=1`` (numba then returns the function
unchanged), with the same results: that is how the tests check the compiled kernels against the readable ones,
and how a student steps through a kernel in a debugger.

Settings, and why:

- ``cache=True``: compiled kernels are written to disk; a warm start loads them in milliseconds.
- ``nogil=True``: a kernel releases the GIL, so the bag writer thread and DDS callbacks run on the other core
  while it computes.
- ``error_model="numpy"``: division by zero gives inf/nan as numpy does (the World's blow-up guard deals with
  it) instead of raising ``ZeroDivisionError`` from inside a kernel.
- no ``fastmath``: it lets LLVM reassociate floating-point sums, which would make compiled and plain-Python
  results differ beyond round-off and break the bit-for-bit determinism a seed promises.
- ``parallel=True`` kernels (per-boid loops written with :data:`prange`) run on numba's thread pool, one
  thread per core.  Each iteration writes only its own outputs and no floating-point value is reduced across
  iterations, so the results do not depend on the number of threads.  With the OpenMP pool, idle workers are
  told to sleep (``OMP_WAIT_POLICY=PASSIVE``) instead of spinning for a while after every kernel: on a
  2-core machine the spinning worker took the core the bag writer and the DDS threads need (measured: twice
  the CPU time per flock step, and a slower tick).  Only the node's tick thread launches parallel kernels
  (numba's fallback ``workqueue`` pool is not safe to enter from two threads at once).
"""

from __future__ import annotations

import os
from contextlib import contextmanager

# Before numba loads its OpenMP thread pool (at the first parallel kernel); a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402

#: numba's own switch: with NUMBA_DISABLE_JIT=1 every kernel runs as plain Python
JIT_DISABLED = os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")

_DEFAULTS = {"cache": True, "nogil": True, "error_model": "numpy"}


def njit(*args, **options):
    """``numba.njit`` with cgp_core's defaults (see the module docstring); use as ``@njit`` or ``@njit(...)``."""
    settings = {**_DEFAULTS, **options}
    if args and callable(args[0]) and len(args) == 1 and not options:
        return numba.njit(**settings)(args[0])
    return numba.njit(*args, **settings)


#: ``numba.prange`` (a plain ``range`` when the JIT is disabled); only meaningful inside ``njit(parallel=True)``
prange = numba.prange

#: a parallel kernel over fewer items than this runs on one thread: waking the pool's other workers for each
#: kernel costs more than they save (measured: a 300-boid flock step takes 0.2 ms on one thread, 0.3-0.6 ms
#: and a long tail on two, on this project's 2-core machines)
PARALLEL_MIN_ITEMS = 2000


@contextmanager
def threads_for(items: int):
    """Run the parallel kernels called inside on all of numba's threads, or on one for fewer than
    :data:`PARALLEL_MIN_ITEMS` items (per calling thread; the previous setting is restored)."""
    previous = numba.get_num_threads()
    numba.set_num_threads(1 if items < PARALLEL_MIN_ITEMS else numba.config.NUMBA_NUM_THREADS)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


__all__ = ["JIT_DISABLED", "PARALLEL_MIN_ITEMS", "njit", "prange", "threads_for"]
