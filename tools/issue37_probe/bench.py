# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
"""Per captured sub-step input: the sweeps under each variant (same input, fresh copies), median us."""
import pickle
import sys
import time

import numba
import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent)); sys.path.insert(0, str(__import__("pathlib").Path(__file__).parents[2] / "benchmarks"))
import sweepk
from common import speed_probe
from util import deep

from cgp_core.solver import sequential_impulse as si

cap = pickle.load(open(str(__import__("pathlib").Path(__file__).with_name("captured.pkl")), "rb"))
prof = np.zeros(len(si.STAGES))
REP = int(sys.argv[1]) if len(sys.argv) > 1 else 60


def variants(settings):
    return {
        "V0 plain order, inlined (main)": lambda s: sweepk.sweeps_inlined(s, settings, 0, 64),
        "V1 coloured, inlined, serial": lambda s: sweepk.sweeps_inlined(s, settings, 1, 64),
        "V1c coloured, all via call, serial": lambda s: sweepk.sweeps_called(s, settings, 1, 64),
        "V2 si.solve_contacts serial compile": lambda s: sweepk.sweeps_colour_serial(s, settings),
        "V3 solve_sweeps_wide 1 thread": lambda s: (numba.set_num_threads(1), si.solve_sweeps_wide(s, settings, prof))[1],
        "V4 solve_sweeps_wide 2 threads": lambda s: (numba.set_num_threads(2), si.solve_sweeps_wide(s, settings, prof))[1],
        "colour_manifolds alone": lambda s: sweepk.colour_only(s),
    }


print("probe", speed_probe())
for t in sorted(cap):
    contacts, bodies, memory, settings = cap[t]
    solving = si.solve_head(contacts, deep(bodies), memory, settings, prof)
    vs = variants(settings)
    times = {k: [] for k in vs}
    outs = {}
    for _r in range(REP):
        for k, f in vs.items():
            s = deep(solving)
            t0 = time.perf_counter(); o = f(s); dt = time.perf_counter() - t0
            times[k].append(dt * 1e6)
            outs[k] = o
    numba.set_num_threads(2)
    G = len(solving.manifolds.group_start) - 1
    rs = si._split_regions(solving.manifolds, solving.bodies, 1)[1]
    print(f"tick {t}: m={len(solving.manifolds.a)} G={G} regions {rs.tolist()}")
    for k in vs:
        o = outs[k]
        print(f"   {k:38s} {np.median(times[k]):8.1f} us  (p25 {np.percentile(times[k], 25):.1f})  -> {o if not isinstance(o, tuple) or len(o) != 2 else ''}")
    # whole step: solve_step (serial kernel, coloured order) vs the three calls
    ws = {"solve_step (1 call, serial)": si.solve_step, "_solve_wide (3 calls)": si._solve_wide}
    wt = {k: [] for k in ws}
    for _r in range(REP):
        for k, f in ws.items():
            b = deep(bodies)
            t0 = time.perf_counter(); f(contacts, b, memory, settings, si._NO_TALLY, False, prof); wt[k].append((time.perf_counter() - t0) * 1e6)
    for k in ws:
        print(f"   whole {k:32s} {np.median(wt[k]):8.1f} us")

# bits: solve_step vs the three calls (1 and 2 threads), each captured input
for t in sorted(cap):
    contacts, bodies, memory, settings = cap[t]
    res = []
    for f, th in ((si.solve_step, 2), (si._solve_wide, 1), (si._solve_wide, 2)):
        numba.set_num_threads(th)
        b = deep(bodies)
        h, mem, _ = f(contacts, b, memory, settings, si._NO_TALLY, False, prof)
        res.append((b[4], b[5], mem.normal, mem.friction))
    same = all(np.array_equal(x, y) for r in res[1:] for x, y in zip(res[0], r))
    print(f"bits tick {t}: solve_step == 3 calls (1 thr, 2 thr): {same}")
