#!/usr/bin/env python3
"""The contact report (issue 25: ``~/contacts``, cgp_core/solver/report.py) — what it costs the tick and what its
message costs to build, on this machine.

1. **The tick, report on vs off**: the default scene (``make run``'s, flock included, sleep on as a user runs it)
   and bench_rigid's 200-body pile (sleep off: it keeps every contact awake), stepped from the first tick in two
   worlds side by side, one with ``World.report_contacts`` on (what the node does while a bag records or someone
   subscribes to ``~/contacts``), one off; the ticks interleaved in blocks of 10 so that the machine's drift
   cancels; median and p99 per tick of each, and the difference of the medians.
2. **The message**: ``cgp_sim_msgs/Contacts`` of the pile's report (a few hundred contacts) built by
   :class:`cgp_sim_ros.wire.cdr.ContactsSerializer` (the node's way) vs rclpy message objects filled field by
   field and ``serialize_message`` (what a node in rclpy would do); median of interleaved repetitions.  The two are
   proven to give the same bytes in tests/test_contacts_message.py.

Writes a table to stdout and ``benchmarks/results/contact_report.json``.  ``--quick``: fewer ticks.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the rclpy reference message

from bench_cdr import interleaved  # noqa: E402
from bench_rigid import pile_scene  # noqa: E402
from common import Results, speed_probe  # noqa: E402
from test_contacts_message import rclpy_message  # noqa: E402

from cgp_core import World  # noqa: E402
from cgp_core.scene import load_scene, parse_scene  # noqa: E402
from cgp_sim_ros.wire import cdr  # noqa: E402


def tick_costs(make_world, ticks: int, block: int = 10) -> dict:
    """Per-tick seconds of two identical worlds, report on and off, stepped in alternating blocks."""
    import time

    worlds = {"on": make_world(), "off": make_world()}
    worlds["on"].report_contacts = True
    times = {"on": [], "off": []}
    for start in range(0, ticks, block):
        for name in (("on", "off") if (start // block) % 2 == 0 else ("off", "on")):
            w = worlds[name]
            for _ in range(min(block, ticks - start)):
                t0 = time.perf_counter()
                w.step()
                times[name].append(time.perf_counter() - t0)
    out = {}
    for name, ts in times.items():
        ts = np.asarray(ts) * 1e3
        out[name] = {"median_ms": float(np.median(ts)), "p99_ms": float(np.percentile(ts, 99))}
    out["contacts"] = int(worlds["on"].contacts.count)
    out["world"] = worlds["on"]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    ticks = 200 if args.quick else 600
    out = Results("contact_report", options=vars(args))
    rows = out.data["rows"] = []

    cases = {"default scene (make run's, from the first tick)": lambda: World(load_scene("default")),
             "200-body pile (bench_rigid's)": lambda: World(parse_scene(pile_scene()))}
    pile_world = None
    for label, make in cases.items():
        probe = speed_probe()
        cost = tick_costs(make, ticks)
        pile_world = cost.pop("world")
        rows.append({"case": label, "ticks": ticks, "contacts_last_tick": cost["contacts"], "speed_probe": probe,
                     **{f"{k}_{m}": v[m] for k, v in cost.items() if k in ("on", "off") for m in v}})

    from cgp_sim_msgs.msg import Contacts
    from rclpy.serialization import deserialize_message, serialize_message

    report, names = pile_world.contacts, list(pile_world.body_model.names)
    serializer = cdr.ContactsSerializer("world", names)

    def ours():
        values = np.concatenate((report.point, report.normal, report.separation[:, None],
                                 report.normal_impulse[:, None], report.friction_impulse), axis=1)
        return serializer.serialize(5, report.duration, report.body_a, report.body_b, values, report.body,
                                    np.concatenate((report.force, report.torque), axis=1))

    # the same message (rclpy leaves its padding bytes uninitialised: compared as messages, as the tests do too)
    assert deserialize_message(bytes(ours()), Contacts) == rclpy_message(report, names, 5)
    times = interleaved({"rclpy objects": lambda: serialize_message(rclpy_message(report, names, 5)),
                         "numpy (ContactsSerializer)": ours}, 3 if args.quick else 7)
    out.data["message"] = {"contacts": report.count, "wrenches": len(report.body),
                           **{name: t * 1e3 for name, t in times.items()}}

    print(f"{'case':<50} {'contacts':>8} {'off med':>8} {'on med':>8} {'off p99':>8} {'on p99':>8}  ms")
    for r in rows:
        print(f"{r['case']:<50} {r['contacts_last_tick']:>8} {r['off_median_ms']:8.3f} {r['on_median_ms']:8.3f} "
              f"{r['off_p99_ms']:8.3f} {r['on_p99_ms']:8.3f}   (probe numpy/python "
              f"{r['speed_probe']['numpy_ms']:.0f}/{r['speed_probe']['python_ms']:.0f} ms)")
    m = out.data["message"]
    print(f"Contacts message, {m['contacts']} contacts + {m['wrenches']} wrenches: rclpy objects "
          f"{m['rclpy objects']:.2f} ms, ContactsSerializer {m['numpy (ContactsSerializer)']:.3f} ms")
    for r, key in zip(rows, ("default", "pile")):
        extra = r["on_median_ms"] - r["off_median_ms"]
        out.figure(f"contact_report_tick_{key}", f"contact report on - off, median tick, {r['case']}", extra, "ms",
                   "reference", None, off_ms=r["off_median_ms"], on_ms=r["on_median_ms"])
    ratio = m["rclpy objects"] / m["numpy (ContactsSerializer)"]
    out.figure("contact_message_speedup", f"Contacts message of {m['contacts']} contacts: rclpy objects / ours",
               ratio, "x", "reference", None, ours_ms=m["numpy (ContactsSerializer)"], rclpy_ms=m["rclpy objects"])
    print(f"written {out.write()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
