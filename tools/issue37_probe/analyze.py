# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
import json

import numpy as np

rows = json.load(open(str(__import__("pathlib").Path(__file__).with_name("rows.json"))))


def summ(sel, label):
    r = [x for x in rows if sel(x["tick"])]
    ticks = len({x["tick"] for x in r})

    def f(k):
        return np.array([x.get(k, 0) for x in r])
    wide = f("wide_path"); col = f("coloured")
    sweeps = f("sweeps"); imp = f("impact_sweeps"); C = f("C"); wc = f("wide_colours")
    print(f"{label}: ticks {ticks}, substeps {len(r)} ({len(r)/ticks:.1f}/tick); 3-call path {wide.sum()}, coloured {col.sum()}")
    print(f"  m median {np.median(f('m')):.0f}, G median {np.median(f('G')):.0f} (min {f('G').min()} max {f('G').max()})")
    print(f"  regular sweeps/substep mean {sweeps.mean():.2f} median {np.median(sweeps):.0f} max {sweeps.max()}; probe==real: {all(x.get('probe_sweeps', x['sweeps']) == x['sweeps'] for x in r)}")
    cc = col == 1
    if cc.any():
        print(f"  coloured substeps: impact sweeps mean {imp[cc].mean():.2f} (substeps with any: {(imp[cc] > 0).sum()}), colours C mean {C[cc].mean():.1f} (min {C[cc].min()} max {C[cc].max()}), wide colours mean {wc[cc].mean():.2f}, overflow max {f('overflow').max()}")
        launches = wc * (sweeps + imp)
        print(f"  prange launches per substep mean {launches[cc].mean():.1f}; per tick {launches.sum()/ticks:.1f}")
        print(f"  serial colours per sweep mean {(C[cc]-wc[cc]).mean():.1f}")
        sz = [x["sizes"] for x in r if x["coloured"]]
        print("  example sizes (last):", sz[-1])
        print("  example sizes (first):", sz[0])
        frac = np.mean([sum(s for s in x["sizes"][:-1] if s >= 64) / sum(x["sizes"]) for x in r if x["coloured"]])
        print(f"  fraction of manifolds in wide colours: {frac:.3f}")


summ(lambda t: t < 60, "ticks 0-59")
summ(lambda t: 60 <= t < 300, "ticks 60-299")
summ(lambda t: t >= 3 and t < 243, "ticks 3-242 (speed case window)")
