# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
"""Cost of one prange launch from compiled code (numba's pool), vs the same loop serial; then one big loop on 1 and
2 threads (whether a second core is free at all: a shared machine's other processes can take it)."""
import sys
import time
from pathlib import Path

import numba
import numpy as np
from numba import njit, prange

sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))
from common import speed_probe

from cgp_core.solver.sequential_impulse import PRANGE_ONLY


def loops(x, L, n, work):
    for _l in range(L):
        for i in prange(n):  # (a plain range where compiled without parallel)
            s = x[i]
            for _k in range(work):
                s = s * 0.999999 + 1e-9
            x[i] = s


par = njit(parallel=PRANGE_ONLY)(loops)
ser = njit(loops)

x = np.ones(100000)
par(x, 1, 8, 1); ser(x, 1, 8, 1)
print("threading layer:", numba.threading_layer(), "NUMBA_NUM_THREADS", numba.config.NUMBA_NUM_THREADS)
print("probe", speed_probe())
L = 20000
for n, work in ((64, 0), (100, 0), (100, 60), (100, 150)):
    for label, f, th in (("serial", ser, 1), ("prange 1 thr", par, 1), ("prange 2 thr", par, 2)):
        numba.set_num_threads(th)
        ts = []
        for _r in range(7):
            t0 = time.perf_counter(); f(x, L, n, work); ts.append((time.perf_counter() - t0) / L * 1e6)
        print(f"n={n:4d} work/iter={work:4d}  {label:14s} {np.median(ts):7.2f} us per loop (min {min(ts):.2f})")
for th in (1, 2, 1, 2):  # one big loop: 2 threads take half the time only if the second core is free
    numba.set_num_threads(th)
    t0 = time.perf_counter(); par(x, 20, 100000, 150); print(th, "threads", round((time.perf_counter() - t0) * 1e3, 1), "ms (n=100000, work/iter=150, 20 loops)")
