# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
"""Cost of one prange launch from compiled code (numba's pool), vs the same loop serial."""
import sys
import time
from pathlib import Path

import numba
import numpy as np
from numba import njit, prange

sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))
from common import speed_probe


@njit(parallel={"prange": True, "comprehension": False, "reduction": False, "inplace_binop": False, "setitem": False,
                "numpy": False, "stencil": False, "fusion": False})
def par(x, L, n, work):
    for _l in range(L):
        for i in prange(n):
            s = x[i]
            for _k in range(work):
                s = s * 0.999999 + 1e-9
            x[i] = s


@njit
def ser(x, L, n, work):
    for _l in range(L):
        for i in range(n):
            s = x[i]
            for _k in range(work):
                s = s * 0.999999 + 1e-9
            x[i] = s


x = np.ones(4096)
par(x, 1, 8, 1); ser(x, 1, 8, 1)
print("threading layer:", numba.threading_layer(), "NUMBA_NUM_THREADS", numba.config.NUMBA_NUM_THREADS)
print("probe", speed_probe())
L = 20000
res = {}
for n, work in ((64, 0), (100, 0), (100, 60), (100, 150)):
    for label, f, th in (("serial", ser, 1), ("prange 1 thr", par, 1), ("prange 2 thr", par, 2)):
        numba.set_num_threads(th)
        ts = []
        for _r in range(7):
            t0 = time.perf_counter(); f(x, L, n, work); ts.append((time.perf_counter() - t0) / L * 1e6)
        res[(n, work, label)] = np.median(ts)
        print(f"n={n:4d} work/iter={work:4d}  {label:14s} {np.median(ts):7.2f} us per loop (min {min(ts):.2f})")
