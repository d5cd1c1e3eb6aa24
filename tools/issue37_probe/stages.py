# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
"""Pile: per-stage solver time and tick time, 3 warm + 240 ticks (compare_trees' pile case). Tree from PYTHONPATH."""
import json
import sys
import time

import numpy as np

sys.path.insert(0, sys.argv[1] + "/benchmarks"); sys.path.insert(0, sys.argv[1] + "/tools")
from common import speed_probe
from compare_trees import pile_scene

from cgp_core import World
from cgp_core.scene import parse_scene

w = World(parse_scene(pile_scene()))
for _ in range(3):
    w.step()
w.solver.profile.reset()
probe = speed_probe()
t = np.empty(240)
for k in range(240):
    t0 = time.perf_counter(); w.step(); t[k] = time.perf_counter() - t0
d = w.solver.profile.as_dict()
calls = d.pop("calls")
print(json.dumps({"tree": sys.argv[1], "median_ms": round(float(np.median(t) * 1e3), 3), "total_ms_per_tick": round(float(t.sum() / 240 * 1e3), 3),
                  "substeps": w.substeps, "solver_calls": calls,
                  "stage_ms_per_tick": {k: round(v / 240 * 1e3, 3) for k, v in d.items()}, "probe": probe}))
