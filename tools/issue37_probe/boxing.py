# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
import pickle
import sys
import time

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
from numba import njit
from util import deep

from cgp_core.solver import sequential_impulse as si

cap = pickle.load(open(str(__import__("pathlib").Path(__file__).with_name("captured.pkl")), "rb"))
prof = np.zeros(len(si.STAGES))


@njit
def touch(solving):
    return len(solving.lam)


contacts, bodies, memory, settings = cap[200]
solving = si.solve_head(contacts, deep(bodies), memory, settings, prof)
touch(solving)


def t(f, n=300):
    ts = []
    for _ in range(n):
        t0 = time.perf_counter(); f(); ts.append(time.perf_counter() - t0)
    return np.median(ts) * 1e6


print("solve_head (stages 1-3 + boxing Solving) us", round(t(lambda: si.solve_head(contacts, bodies, memory, settings, prof)), 1))
print("unbox Solving into a kernel (trivial njit) us", round(t(lambda: touch(solving)), 1))
b = deep(bodies)
print("solve_tail us", round(t(lambda: si.solve_tail(solving, b, settings, 8, si._NO_TALLY, False, prof)), 1))
