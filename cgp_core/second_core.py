"""The machine's second core for compiled stages called from Python (issue 37): :func:`beside` runs a kernel on
one extra thread while the calling thread runs another, e.g. the narrow phase's two halves of its pair list.

Why a Python thread and not numba's ``prange``: every kernel is compiled with ``nogil=True`` (:mod:`cgp_core.jit`),
so two calls of one *serial* kernel run at the same time on two Python threads, with nothing compiled again — no
parallel twin of a stage (a ``prange`` kernel costs a second compile of everything it inlines, issue 34, and numba
refuses to cache a compiled caller of one) and none of numba's parfor pitfalls in the stages' code.  What it costs
is Python's: handing a call to the thread and back, ~20 µs here, and each call's arguments unboxed under the GIL,
one after the other (~10 µs for a stage's bundles) — so a stage is split only where each half's work is well above
that (each caller's threshold, measured).

One thread, started on first use and kept (idle, it ends at the interpreter's exit: :mod:`concurrent.futures`
joins it then); a child process forked after it started makes a thread of its own on first use
(:func:`os.register_at_fork`).  Off — every call on
the calling thread — when numba's JIT is disabled (plain Python holds the GIL: two threads would take turns) or
numba has a pool of one thread (``NUMBA_NUM_THREADS=1``, e.g. a one-core machine or container: one core would run
both halves in turn).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numba

from .jit import JIT_DISABLED

_pool: ThreadPoolExecutor | None = None
_lock = threading.Lock()


def available() -> bool:
    """Whether :func:`beside` runs its call on a second thread (else on the calling one, when asked for the
    result): numba's JIT on and its pool of more than one thread."""
    return not JIT_DISABLED and numba.config.NUMBA_NUM_THREADS > 1


def beside(function: Callable, *args) -> Future:
    """``function(*args)`` started on the second thread; its :class:`~concurrent.futures.Future` (``.result()``
    waits for it, and raises what it raised).  Where :func:`available` is False, the call runs here and now."""
    if not available():
        done: Future = Future()
        try:
            done.set_result(function(*args))
        except BaseException as error:  # noqa: BLE001 (handed to the caller by .result(), as the thread would)
            done.set_exception(error)
        return done
    global _pool
    pool = _pool
    if pool is None:
        with _lock:
            if _pool is None:
                _pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cgp_core-second-core")
            pool = _pool
    return pool.submit(function, *args)


def _forget_pool() -> None:
    """In a forked child: the parent's thread is not there (its executor would wait for it forever)."""
    global _pool
    _pool = None


os.register_at_fork(after_in_child=_forget_pool)
