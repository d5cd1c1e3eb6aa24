"""Bag recording cost per tick (cgp_sim_ros.wire.bag.BagWriter), on this machine.

Scenes (the messages of one tick, serialized once with cgp_sim_ros.wire.cdr, from positions that move a little
each tick like a simulation's, so the compressors see realistic float data):
- ``default``: ~300 boids in 2 flocks + 8 bodies: 3 PoseArrays (bodies, 2 flocks), a MarkerArray (8 body
  markers + 2 coloured SPHERE_LISTs), 8 Odometry, a Clock.
- ``boids_10k`` / ``boids_15k``: one 10k / 15k PoseArray + a 10k / 15k-point coloured SPHERE_LIST marker, plus
  the bodies' PoseArray, 8 Odometry and a Clock.

For each scene and chunk compression (zstd, lz4, none):
- ``write_us``: time on the caller's thread for all of a tick's ``write`` calls (median, p99), at 60 Hz;
- ``tick_slowdown``: how much longer a CPU-bound numpy "tick" of ~8 ms takes while the writer thread works
  (the GIL and the second core are shared), median ratio to the same tick with no bag (interleaved runs);
- ``bag_cpu_cores``: the CPU the recording adds (process CPU time per wall second, minus the baseline's);
- ``backlog_max_MB``: the largest queue the writer had at 60 Hz (it keeps up if this stays small);
- ``capacity_MB_s``: payload the writer sustains when fed as fast as possible, vs ``needed_MB_s`` at 60 Hz;
- ``file_MB_per_s`` (what one second of recording costs on disk) and the compression ratio.
Also raw zstd / lz4 levels on one 4 MiB chunk of the 15k scene (the mcap writer uses zstd level 3 / lz4
level 0 and has no option for others).

Writes a table to stdout and ``benchmarks/results/bag.json``.  Run: ``.venv/bin/python benchmarks/bench_bag.py``
(``--quick`` for a shorter run).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cgp_sim_ros.wire import cdr  # noqa: E402
from cgp_sim_ros.wire.bag import BagOptions, BagWriter  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
RATE_HZ = 60
DT_NS = 1_000_000_000 // RATE_HZ
TOPICS = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "/cgp_sim/bodies/poses": "geometry_msgs/msg/PoseArray",
    "/cgp_sim/markers": "visualization_msgs/msg/MarkerArray",
}


class Scene:
    """Generates the serialized messages of successive ticks."""

    def __init__(self, flocks: list[int], n_bodies: int = 8, seed: int = 0):
        self.rng = np.random.default_rng(seed)
        self.flocks = [(f"/cgp_sim/flocks/flock_{i}/poses", self.rng.uniform(-20, 20, size=(n, 3)),
                        self.rng.normal(size=(n, 3))) for i, n in enumerate(flocks)]
        self.bodies = self.rng.uniform(-5, 5, size=(n_bodies, 3))
        self.body_names = [f"body_{i}" for i in range(n_bodies)]
        self.odom = cdr.OdometryBatchSerializer("world", self.body_names)
        self.flock_serializers = [cdr.PoseArraySerializer("world") for _ in flocks]
        self.body_serializer = cdr.PoseArraySerializer("world")
        self.tick = 0

    def topics(self) -> dict[str, str]:
        topics = dict(TOPICS)
        for name, _, _ in self.flocks:
            topics[name] = "geometry_msgs/msg/PoseArray"
        for body in self.body_names:
            topics[f"/cgp_sim/bodies/{body}/odom"] = "nav_msgs/msg/Odometry"
        return topics

    def next(self) -> list[tuple[str, bytes]]:
        self.tick += 1
        stamp = self.tick * DT_NS
        out = [("/clock", cdr.clock(stamp))]
        n_b = len(self.bodies)
        self.bodies += self.rng.normal(scale=0.01, size=self.bodies.shape)
        quats = np.tile([0.0, 0.0, 0.0, 1.0], (n_b, 1)) + self.rng.normal(scale=1e-3, size=(n_b, 4))
        out.append(("/cgp_sim/bodies/poses", self.body_serializer.serialize(stamp, self.bodies, quats)))
        markers = [cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE, stamp_ns=stamp, frame_id="world", ns="bodies",
                                               id=i, position=self.bodies[i], orientation=quats[i],
                                               scale=(0.5, 0.5, 0.5), color=(0.8, 0.2, 0.2, 1.0)))
                   for i in range(n_b)]
        for k, (name, pos, vel) in enumerate(self.flocks):
            vel += self.rng.normal(scale=0.05, size=vel.shape)
            pos += vel / RATE_HZ
            heading = vel / np.linalg.norm(vel, axis=1, keepdims=True)
            quat = np.concatenate([np.zeros((len(pos), 1)), -heading[:, 2:3], heading[:, 1:2],
                                   1.0 + heading[:, :1]], axis=1)
            quat /= np.linalg.norm(quat, axis=1, keepdims=True) + 1e-12
            out.append((name, self.flock_serializers[k].serialize(stamp, pos, quat)))
            speed = np.linalg.norm(vel, axis=1)
            colors = np.stack([speed / (speed.max() + 1e-9), 0.5 + 0 * speed, 1 - speed / (speed.max() + 1e-9),
                               np.ones_like(speed)], axis=1).astype(np.float32)
            markers.append(cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, stamp_ns=stamp, frame_id="world",
                                                       ns=f"flock_{k}", points=pos, colors=colors,
                                                       scale=(0.1, 0.1, 0.1))))
        out.append(("/cgp_sim/markers", cdr.marker_array(markers)))
        lin = self.rng.normal(size=(n_b, 3))
        for body, data in zip(self.body_names,
                              self.odom.serialize(stamp, self.bodies, quats, lin, lin)):
            out.append((f"/cgp_sim/bodies/{body}/odom", data))
        return out


SCENES = {
    "default": dict(flocks=[150, 150]),
    "boids_10k": dict(flocks=[10_000]),
    "boids_15k": dict(flocks=[15_000]),
}


def make_ticks(scene_kwargs: dict, n_ticks: int) -> tuple[dict, list]:
    scene = Scene(**scene_kwargs)
    return scene.topics(), [scene.next() for _ in range(n_ticks)]


def busy_tick(work: np.ndarray) -> np.ndarray:
    """A CPU-bound stand-in for a simulation step: numpy ufuncs over a large array."""
    x = work
    for _ in range(6):
        x = np.sin(x) * 0.5 + np.sqrt(np.abs(x) + 1.0)
    return x


def calibrate_work(target_s: float = 0.008) -> np.ndarray:
    n = 20_000
    while True:
        work = np.linspace(0, 1, n)
        t0 = time.perf_counter()
        for _ in range(5):
            busy_tick(work)
        if (time.perf_counter() - t0) / 5 >= target_s:
            return work
        n = int(n * 1.5)


def paced_run(topics, ticks, compression, work, seconds: float, directory: Path) -> dict:
    """60 Hz: a busy tick, then the tick's writes; measures caller time and the tick's duration.
    ``compression=None``: the same loop without a bag (the baseline)."""
    if compression is None:
        bag = None
    else:
        bag = BagWriter(directory, BagOptions(compression=compression))
        for name, type_name in topics.items():
            bag.add_topic(name, type_name)
    n = int(seconds * RATE_HZ)
    write_s, tick_s = [], []
    period = 1.0 / RATE_HZ
    cpu0, wall0 = time.process_time(), time.perf_counter()
    next_t = time.perf_counter()
    for i in range(n):
        t0 = time.perf_counter()
        busy_tick(work)
        t1 = time.perf_counter()
        stamp = (i + 1) * DT_NS
        if bag is not None:
            for name, data in ticks[i % len(ticks)]:
                bag.write(name, data, stamp, stamp)
        t2 = time.perf_counter()
        tick_s.append(t1 - t0)
        write_s.append(t2 - t1)
        next_t += period
        delay = next_t - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    if bag is None:
        return {"tick_s": tick_s, "cpu_cores": (time.process_time() - cpu0) / (time.perf_counter() - wall0)}
    t_close = time.perf_counter()
    bag.close()
    close_s = time.perf_counter() - t_close
    cpu_cores = (time.process_time() - cpu0) / (time.perf_counter() - wall0)
    file_bytes = sum(f.stat().st_size for f in bag.files)
    assert bag.error is None, bag.error
    return {"write_s": write_s, "tick_s": tick_s, "cpu_cores": cpu_cores,
            "backlog_max_MB": bag.max_queued_bytes / 1e6,
            "close_s": close_s, "file_MB_per_s": file_bytes / 1e6 / seconds,
            "messages": bag.written_messages}


def capacity_run(topics, ticks, compression, n_ticks: int, directory: Path) -> dict:
    """Writer fed as fast as the caller can write (blocking at the queue bound): sustained payload MB/s."""
    bag = BagWriter(directory, BagOptions(compression=compression, max_queue_bytes=64 * 1024 * 1024))
    for name, type_name in topics.items():
        bag.add_topic(name, type_name)
    payload = 0
    t0 = time.perf_counter()
    for i in range(n_ticks):
        stamp = (i + 1) * DT_NS
        for name, data in ticks[i % len(ticks)]:
            bag.write(name, data, stamp, stamp)
            payload += len(data)
    bag.close()
    elapsed = time.perf_counter() - t0
    file_bytes = sum(f.stat().st_size for f in bag.files)
    return {"capacity_MB_s": payload / 1e6 / elapsed, "ratio": payload / max(file_bytes, 1)}


def compression_levels(ticks) -> list[dict]:
    import lz4.frame
    import zstandard

    chunk = b"".join(data for tick in ticks for _, data in tick)[: 4 * 1024 * 1024]
    rows = []
    for name, fn in [("zstd-1", lambda d: zstandard.compress(d, 1)),
                     ("zstd-3 (mcap)", lambda d: zstandard.compress(d, 3)),
                     ("zstd-6", lambda d: zstandard.compress(d, 6)),
                     ("zstd-19", lambda d: zstandard.compress(d, 19)),
                     ("lz4-0 (mcap)", lambda d: lz4.frame.compress(d)),
                     ("lz4-9", lambda d: lz4.frame.compress(d, compression_level=9))]:
        times = []
        for _ in range(3 if "19" not in name else 1):
            t0 = time.perf_counter()
            out = fn(chunk)
            times.append(time.perf_counter() - t0)
        rows.append({"codec": name, "MB_s": len(chunk) / 1e6 / min(times), "ratio": len(chunk) / len(out)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    args = parser.parse_args()
    seconds = 2.0 if args.quick else 4.0
    root = Path(tempfile.mkdtemp(prefix="bench_bag_", dir=os.environ.get("BENCH_BAG_DIR")))
    work = calibrate_work()
    results = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "dir": str(root)},
               "rate_hz": RATE_HZ, "scenes": {}}
    codecs = (None, "zstd", "lz4", "none")
    rows = []
    try:
        for scene_name, kwargs in SCENES.items():
            topics, ticks = make_ticks(kwargs, 30)
            tick_bytes = float(np.mean([sum(len(d) for _, d in t) for t in ticks]))
            scene = {"messages_per_tick": len(ticks[0]), "payload_kB_per_tick": tick_bytes / 1e3,
                     "needed_MB_s": tick_bytes * RATE_HZ / 1e6, "compression": {}}
            # Interleaved repetitions (no bag, zstd, lz4, none, no bag, ...) so that drifts of the machine
            # affect every variant alike; the tick slowdown is a ratio of medians within this run.
            runs: dict = {c: [] for c in codecs}
            for rep in range(2):
                for compression in codecs:
                    directory = root / f"{scene_name}_{compression}_{rep}"
                    runs[compression].append(paced_run(topics, ticks, compression, work, seconds / 2, directory))
                    shutil.rmtree(directory, ignore_errors=True)
            base_tick = float(np.median([t for r in runs[None] for t in r["tick_s"]]))
            base_cpu = float(np.mean([r["cpu_cores"] for r in runs[None]]))
            scene["busy_tick_ms_no_bag"] = base_tick * 1e3
            for compression in codecs[1:]:
                paced = runs[compression]
                write_s = [t for r in paced for t in r["write_s"]]
                entry = {
                    "write_us_median": float(np.median(write_s) * 1e6),
                    "write_us_p99": float(np.percentile(write_s, 99) * 1e6),
                    "tick_slowdown": float(np.median([t for r in paced for t in r["tick_s"]])) / base_tick,
                    # CPU the recording adds (writer thread + write calls), in cores, at 60 Hz.
                    "bag_cpu_cores": float(np.mean([r["cpu_cores"] for r in paced])) - base_cpu,
                    "backlog_max_MB": max(r["backlog_max_MB"] for r in paced),
                    "close_s": max(r["close_s"] for r in paced),
                    "file_MB_per_s": float(np.mean([r["file_MB_per_s"] for r in paced])),
                }
                directory = root / f"{scene_name}_{compression}_cap"
                entry.update(capacity_run(topics, ticks, compression, int(seconds * RATE_HZ), directory))
                shutil.rmtree(directory, ignore_errors=True)
                scene["compression"][compression] = entry
                rows.append((scene_name, compression, scene["payload_kB_per_tick"], entry))
            results["scenes"][scene_name] = scene
        results["raw_codecs_15k_chunk"] = compression_levels(make_ticks(SCENES["boids_15k"], 4)[1])
    finally:
        shutil.rmtree(root, ignore_errors=True)

    print("busy tick without bag (ms): " + ", ".join(
        f"{k} {v['busy_tick_ms_no_bag']:.2f}" for k, v in results["scenes"].items()))
    header = (f"{'scene':<10} {'codec':<5} {'kB/tick':>8} {'write us med':>12} {'p99':>8} {'tick x':>7} "
              f"{'bag cores':>9} {'backlog MB':>10} {'cap MB/s':>9} {'need MB/s':>9} {'disk MB/s':>9} "
              f"{'ratio':>6}")
    print(header)
    print("-" * len(header))
    for scene_name, compression, kb, e in rows:
        need = results["scenes"][scene_name]["needed_MB_s"]
        print(f"{scene_name:<10} {compression:<5} {kb:8.1f} {e['write_us_median']:12.1f} {e['write_us_p99']:8.1f} "
              f"{e['tick_slowdown']:7.2f} {e['bag_cpu_cores']:9.2f} {e['backlog_max_MB']:10.2f} "
              f"{e['capacity_MB_s']:9.1f} {need:9.1f} {e['file_MB_per_s']:9.2f} {e['ratio']:6.2f}")
    print("\nraw codecs on a 4 MiB chunk of the 15k scene:")
    for row in results["raw_codecs_15k_chunk"]:
        print(f"  {row['codec']:<14} {row['MB_s']:8.1f} MB/s  ratio {row['ratio']:.3f}")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bag.json").write_text(json.dumps(results, indent=2))
    print(f"\nwritten {RESULTS / 'bag.json'}")


if __name__ == "__main__":
    main()
