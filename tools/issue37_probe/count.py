# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
"""Run the pile on the colour tree; per sub-step: contacts, G, the real sweeps; on a copy: the counts."""
import json
import pickle
import sys

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parents[2] / "tools")); sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
import sweepk
from compare_trees import pile_scene

from cgp_core import World
from cgp_core.scene import parse_scene
from cgp_core.solver import sequential_impulse as si


def deep(x):
    if isinstance(x, np.ndarray):
        return x.copy()
    if isinstance(x, tuple) and hasattr(x, "_fields"):
        return type(x)(*[deep(v) for v in x])
    if isinstance(x, tuple):
        return tuple(deep(v) for v in x)
    return x


rows = []
captured = {}
tick = [0]
CAPTURE = {20, 40, 60, 120, 200, 280}
orig_wide = si._solve_wide


def wide(contacts, bodies, memory, settings, tally, report, profile):
    if tick[0] in CAPTURE and tick[0] not in captured:
        captured[tick[0]] = deep((contacts, bodies, memory, settings))
    solving = si.solve_head(contacts, bodies, memory, settings, profile)
    c = deep(solving)
    cnt = sweepk.sweeps_inlined(c, settings, 1, 64)
    sweeps = si.solve_sweeps_wide(solving, settings, profile)
    out = si.solve_tail(solving, bodies, settings, sweeps, tally, report, profile)
    deep(solving)  # (after; only G needed)
    G = len(solving.manifolds.group_start) - 1
    order, cs = sweepk.colour_only(solving)
    sizes = np.diff(cs)
    rows.append(dict(tick=tick[0], contacts=int(contacts[0].shape[0]) if False else None, m=len(solving.manifolds.a), G=G,
                     wide_path=1, coloured=int(G >= 256), sweeps=int(sweeps), probe_sweeps=int(cnt[0]), impact_sweeps=int(cnt[1]),
                     C=int(cnt[3]), overflow=int(cnt[4]), wide_colours=int((sizes[:-1] >= 64).sum()) if G >= 256 else 0,
                     sizes=sizes.tolist()))
    return out


si._solve_wide = wide
orig_step = si.solve_step


def step(contacts, bodies, memory, settings, tally, report, profile):
    out = orig_step(contacts, bodies, memory, settings, tally, report, profile)
    h = out[0]
    rows.append(dict(tick=tick[0], m=len(h.a), G=len(h.group_start) - 1, wide_path=0, coloured=0, sweeps=int(h.sweeps)))
    return out


si.solve_step = step

w = World(parse_scene(pile_scene()))
for t in range(300):
    tick[0] = t
    w.step()
pickle.dump(captured, open(str(__import__("pathlib").Path(__file__).with_name("captured.pkl")), "wb"))
json.dump(rows, open(str(__import__("pathlib").Path(__file__).with_name("rows.json")), "w"))
print(len(rows), "substeps recorded")
