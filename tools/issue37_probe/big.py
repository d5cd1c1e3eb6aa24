# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
import time

import numba
import numpy as np
from numba import njit, prange


@njit(parallel=True)
def par(x, L, n, work):
    for _l in range(L):
        for i in prange(n):
            s = x[i]
            for _k in range(work):
                s = s * 0.999999 + 1e-9
            x[i] = s


x = np.ones(100000)
par(x, 1, 10, 1)
for th in (1, 2, 1, 2):
    numba.set_num_threads(th)
    t0 = time.perf_counter(); par(x, 20, 100000, 150); print(th, "threads", round((time.perf_counter() - t0) * 1e3, 1), "ms", numba.threading_layer())
