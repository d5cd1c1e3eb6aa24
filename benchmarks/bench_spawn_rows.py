"""Issue 38's heavy spawn requests: does the node hold its 60 Hz while each arrives, and does Ctrl-C end it in 2 s?

The node runs as ``cgp-sim`` would (the installed script, its own process, real time at 60 Hz, the default scene:
5 bodies and 300 fish, recording a bag as ``make run`` does).  This process is the client: it counts the node's
``/clock`` messages (one per tick, their receive times) and sends one ``~/spawn_entity`` request per row, waiting
for its reply:

- ``grid_500k``: D2, a static mesh of 500,000 triangles (a 501 x 501 grid, binary STL, 25 MB);
- ``grid_80k``: the same at 80,000 triangles;
- ``solids_ascii``: D5, an ASCII STL of one-triangle ``solid``s (as many as fit the 32 MB mesh-file cap) as ``uri``;
- ``compound_obj``: D6, a compound of 256 convex parts all naming one ~30 MB OBJ;
- ``hull_100k``: a convex body of 100,000 points (the cap), as ``resource_string``;
- ``particles_400k``: a 4.4 MB YAML of 400,000 particles (refused: over the particle cap);

Per row: the tick rate from the request to the reply (ticks counted / wall time), the slowest 1-second window
in that span, the reply's latency, its result code and message (cut).  Then ``sigint``: D3, the 500k grid spawned
again and SIGINT 1 s later: wall time until the process has exited (and no process of its group is left).
Then ``hulls_300``: 300 convex bodies with 1,000-vertex hulls (a scene file), ``~/markers`` bytes per tick and the
tick rate with a subscriber: after the first 60 ticks, and per second from the first ``/clock`` (the first 4 s: the
bodies fall, land and fall asleep).  The speed probe (``common.speed_probe``) is taken before and after.

Usage: ``.venv/bin/python benchmarks/bench_spawn_rows.py [--quick] [--only ROW ...]`` (writes
``benchmarks/results/spawn_rows.json``; the data files go to a temporary directory).
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import Results, format_figures, format_speed_probe, speed_probe  # noqa: E402

RATE_HZ = 60.0
TARGET_HZ = 55.0
ROWS = ("grid_80k", "grid_500k", "solids_ascii", "compound_obj", "hull_100k", "particles_400k")


# ---- the rows' data ---------------------------------------------------------------------------------------------

def grid_stl(path: Path, n: int) -> Path:
    """A binary STL of an n x n vertex grid, 1 cm apart, gently waved: 2 (n − 1)² triangles."""
    x, y = np.meshgrid(np.arange(n) * 0.01, np.arange(n) * 0.01)
    z = 0.02 * np.sin(x * 3.0) * np.cos(y * 2.0)
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    record = np.zeros(len(tri), dtype=[("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["normal"] = (0.0, 0.0, 1.0)
    record["v"] = v[tri]
    with path.open("wb") as f:
        f.write(b"\0" * 80 + struct.pack("<I", len(tri)))
        f.write(record.tobytes())
    return path


def solids_stl(path: Path, max_bytes: int = 32 * 1024 * 1024 - 1024) -> Path:
    """An ASCII STL of one-triangle solids, as many as fit ``max_bytes``."""
    rng = np.random.default_rng(5)
    parts, size = [], 0
    k = 0
    while True:
        p = rng.uniform(-1, 1, (3, 3))
        text = (f"solid s{k}\nfacet normal 0 0 1\nouter loop\nvertex {p[0, 0]:.4f} {p[0, 1]:.4f} {p[0, 2]:.4f}\n"
                f"vertex {p[1, 0]:.4f} {p[1, 1]:.4f} {p[1, 2]:.4f}\nvertex {p[2, 0]:.4f} {p[2, 1]:.4f} "
                f"{p[2, 2]:.4f}\nendloop\nendfacet\nendsolid s{k}\n")
        if size + len(text) > max_bytes:
            break
        parts.append(text)
        size += len(text)
        k += 1
    path.write_text("".join(parts))
    return path


def big_obj(path: Path, max_bytes: int = 30 * 1024 * 1024) -> Path:
    """An OBJ of random points on a sphere and triangles between them, about ``max_bytes``."""
    rng = np.random.default_rng(6)
    n = max_bytes // 60
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    f = rng.integers(1, n + 1, size=(n, 3))
    lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v] + [f"f {a} {b} {c}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")
    return path


def hull_sphere_stl(path: Path, vertices: int = 1000) -> Path:
    """A binary STL of the convex hull of ``vertices`` points on a 0.2 m sphere (about 2 vertices - 4 triangles)."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(7)
    p = rng.normal(size=(vertices, 3))
    p *= 0.2 / np.linalg.norm(p, axis=1)[:, None]
    hull = ConvexHull(p)
    tri = hull.simplices.copy()
    outward = np.einsum("ij,ij->i", np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]), p[tri[:, 0]])
    tri[outward < 0] = tri[outward < 0][:, ::-1]
    record = np.zeros(len(tri), dtype=[("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    record["v"] = p[tri]
    with path.open("wb") as f:
        f.write(b"\0" * 80 + struct.pack("<I", len(tri)))
        f.write(record.tobytes())
    return path


def row_request(row: str, data: Path) -> dict:
    """The SpawnEntity request fields of a row."""
    if row == "grid_500k":
        return {"resource_string": f"body: {{shape: mesh, mesh: {grid_stl(data / 'grid500k.stl', 501)}, fixed: true}}"}
    if row == "grid_80k":
        return {"resource_string": f"body: {{shape: mesh, mesh: {grid_stl(data / 'grid80k.stl', 201)}, fixed: true}}"}
    if row == "solids_ascii":
        return {"uri": str(solids_stl(data / "solids.stl"))}
    if row == "compound_obj":
        obj = big_obj(data / "big.obj")
        parts = ", ".join(f"{{shape: convex, mesh: {obj}, position: [{k % 16}, {k // 16}, 0]}}" for k in range(256))
        return {"resource_string": f"body: {{shape: compound, mass: 10, parts: [{parts}]}}"}
    if row == "hull_100k":
        rng = np.random.default_rng(8)
        p = rng.normal(size=(100_000, 3))
        p /= np.linalg.norm(p, axis=1)[:, None]
        points = ", ".join(f"[{a:.5f}, {b:.5f}, {c:.5f}]" for a, b, c in p)
        return {"resource_string": f"body: {{shape: convex, mass: 1, points: [{points}]}}"}
    if row == "particles_400k":
        rng = np.random.default_rng(9)
        p = rng.uniform(-1, 1, size=(400_000, 3))
        points = ", ".join(f"[{a:.3f}, {b:.3f}, {c:.3f}]" for a, b, c in p)
        return {"resource_string": f"body: {{shape: particles, particle_mass: 0.001, radius: 0.01, "
                                   f"particles: [{points}]}}"}
    raise ValueError(row)


# ---- the node and the client --------------------------------------------------------------------------------------

class Client:
    def __init__(self):
        import rclpy
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from simulation_interfaces.srv import SpawnEntity

        rclpy.init()
        self.rclpy = rclpy
        self.node = rclpy.create_node("bench_spawn_rows_client")
        self.ticks: list[float] = []  # receive times of /clock
        self.node.create_subscription(Clock, "/clock", lambda m: self.ticks.append(time.monotonic()),
                                      QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.SpawnEntity = SpawnEntity
        self.spawn = self.node.create_client(SpawnEntity, "/cgp_sim/spawn_entity")
        self.executor = rclpy.executors.SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def spin_until(self, condition, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                raise TimeoutError(f"timed out waiting for {what}")
            self.executor.spin_once(timeout_sec=0.01)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def send(self, fields: dict, name: str):
        request = self.SpawnEntity.Request(name=name, **fields)
        request.initial_pose.pose.position.z = 2.0
        return self.spawn.call_async(request)

    def call(self, fields: dict, name: str, timeout: float = 300.0) -> tuple[float, object]:
        sent = time.monotonic()
        future = self.send(fields, name)
        self.spin_until(future.done, timeout, f"the reply to {name}")
        return time.monotonic() - sent, future.result()

    def rate(self, t0: float, t1: float) -> float:
        return sum(1 for w in self.ticks if t0 <= w <= t1) / (t1 - t0) if t1 > t0 else 0.0

    def slowest_window(self, t0: float, t1: float, width: float = 1.0) -> float:
        width = min(width, t1 - t0)
        if width <= 0:
            return 0.0
        starts = np.arange(t0, max(t0, t1 - width) + 1e-9, 0.1)
        return min(sum(1 for w in self.ticks if s <= w < s + width) / width for s in starts)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def start_node(bag_root: Path, log_path: Path, *args: str) -> subprocess.Popen:
    executable = Path(sys.executable).parent / "cgp-sim"
    with log_path.open("wb") as log:
        return subprocess.Popen([str(executable), "--rate-hz", str(RATE_HZ), "--bag", str(bag_root / "bag"), *args],
                                stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def stop_node(process: subprocess.Popen) -> float:
    """SIGINT; the seconds until the process and its whole group are gone."""
    sent = time.monotonic()
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    exited = time.monotonic() - sent
    end = time.monotonic() + 10
    while _group_alive(process.pid) and time.monotonic() < end:
        time.sleep(0.02)
    return exited


def _group_alive(pgid: int) -> bool:
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if os.getpgid(int(entry.name)) == pgid and (entry / "stat").read_text().split()[2] != "Z":
                    return True
            except (OSError, IndexError):
                continue
    return False


def run_rows(rows: list[str], data: Path, baseline_s: float) -> list[dict]:
    bag_root = Path(tempfile.mkdtemp(prefix="bench_spawn_rows_", dir=os.environ.get("BENCH_BAG_DIR")))
    log_path = Path(tempfile.gettempdir()) / "bench_spawn_rows_node.log"
    requests = {row: row_request(row, data) for row in rows}  # made before the node starts
    node = start_node(bag_root, log_path, "--scene", "default")
    client = Client()
    out = []
    try:
        client.spin_until(lambda: client.spawn.service_is_ready() and len(client.ticks) > 60, 120, "the node")
        client.call({}, "warm_up")  # refused (no resource): the client's reply path is matched
        t0 = time.monotonic()
        client.spin_for(baseline_s)
        out.append({"row": "baseline", "rate_hz": client.rate(t0, time.monotonic()),
                    "slowest_second_hz": client.slowest_window(t0, time.monotonic())})
        for row in rows:
            t0 = time.monotonic()
            latency, response = client.call(requests[row], row)
            t1 = time.monotonic()
            client.spin_for(2.0)  # the ticks right after the entity is added count too
            t2 = time.monotonic()
            out.append({"row": row, "latency_s": latency, "code": response.result.result,
                        "message": response.result.error_message[:200], "rate_hz": client.rate(t0, t2),
                        "slowest_second_hz": client.slowest_window(t0, t2), "span_s": t2 - t0,
                        "reply_rate_hz": client.rate(t0, t1)})
            print(f"  {row}: {out[-1]}", flush=True)
    finally:
        client.close()
        stop_node(node)
        shutil.rmtree(bag_root, ignore_errors=True)
    return out


def run_sigint(data: Path) -> dict:
    """D3: SIGINT 1 s into the 500k-triangle spawn: seconds until the node (and its worker) are gone."""
    bag_root = Path(tempfile.mkdtemp(prefix="bench_spawn_rows_", dir=os.environ.get("BENCH_BAG_DIR")))
    fields = row_request("grid_500k", data)
    node = start_node(bag_root, Path(tempfile.gettempdir()) / "bench_spawn_rows_sigint.log", "--scene", "default")
    client = Client()
    try:
        client.spin_until(lambda: client.spawn.service_is_ready() and len(client.ticks) > 60, 120, "the node")
        client.call({}, "warm_up")
        client.send(fields, "grid")
        client.spin_for(1.0)
        exited = stop_node(node)
        left = _group_alive(node.pid)
    finally:
        client.close()
        if node.poll() is None:
            node.kill()
        shutil.rmtree(bag_root, ignore_errors=True)
    return {"row": "sigint_during_grid_500k", "exit_s": exited, "processes_left": left,
            "code": node.returncode}


def run_hulls(data: Path, seconds: float) -> dict:
    """300 convex bodies with 1,000-vertex hulls: ~/markers bytes per tick and the tick rate with a subscriber."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from visualization_msgs.msg import MarkerArray

    stl = hull_sphere_stl(data / "ball1000.stl")
    scene = data / "hulls300.yaml"
    bodies = "\n".join(f"  - {{name: b{k}, shape: convex, mesh: {stl.name}, mass: 1, "
                       f"position: [{(k % 20) * 0.6 - 6}, {(k // 20) * 0.6 - 4}, 0.25]}}" for k in range(300))
    scene.write_text(f"description: 300 hulls of 1,000 vertices\nbodies:\n{bodies}\n")
    bag_root = Path(tempfile.mkdtemp(prefix="bench_spawn_rows_", dir=os.environ.get("BENCH_BAG_DIR")))
    node = start_node(bag_root, Path(tempfile.gettempdir()) / "bench_spawn_rows_hulls.log", "--scene", str(scene))
    client = Client()
    sizes: list[int] = []
    client.node.create_subscription(MarkerArray, "/cgp_sim/markers", lambda m: sizes.append(len(m)),
                                    QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE), raw=True)
    try:
        client.spin_until(lambda: len(client.ticks) > 0, 400, "the node's first tick (300 hulls)")
        first_tick = client.ticks[0]  # the rate is counted from the first /clock: the bodies fall, land, sleep
        client.spin_until(lambda: len(client.ticks) > 60 and len(sizes) > 10, 400, "60 ticks and 10 marker arrays")
        first = len(sizes)
        t0 = time.monotonic()
        client.spin_for(seconds)
        end = time.monotonic()
        rate = client.rate(t0, end)
        seen = sizes[first:]
        ticks = np.array(client.ticks) - first_tick
        per_second = [int(np.count_nonzero((ticks >= k) & (ticks < k + 1))) for k in range(int(end - first_tick))]
    finally:
        client.close()
        stop_node(node)
        shutil.rmtree(bag_root, ignore_errors=True)
    return {"row": "hulls_300", "rate_hz": rate, "markers_bytes_max": max(seen) if seen else None,
            "markers_bytes_median": float(np.median(seen)) if seen else None,
            "first_4s_hz": sum(per_second[:4]) / 4.0, "per_second_from_first_tick": per_second}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter windows")
    parser.add_argument("--only", nargs="*", default=None, help=f"rows of {', '.join(ROWS)}, sigint, hulls_300")
    args = parser.parse_args(argv)
    out = Results("spawn_rows", options=vars(args))
    probe_before = speed_probe()
    wanted = args.only or [*ROWS, "sigint", "hulls_300"]
    data = Path(tempfile.mkdtemp(prefix="bench_spawn_rows_data_"))
    results = []
    try:
        rows = [r for r in ROWS if r in wanted]
        if rows:
            results += run_rows(rows, data, 3.0 if args.quick else 5.0)
        if "sigint" in wanted:
            results.append(run_sigint(data))
        if "hulls_300" in wanted:
            results.append(run_hulls(data, 5.0 if args.quick else 10.0))
    finally:
        shutil.rmtree(data, ignore_errors=True)
    probe_after = speed_probe()
    for r in results:
        if r["row"] == "baseline":
            out.figure("spawn_rows_baseline", "reference: the node before the rows (60 Hz, default scene, recording)",
                       r["rate_hz"], "Hz", "60", None)
        elif r["row"].startswith("sigint"):
            out.figure("spawn_rows_sigint", "D3: SIGINT 1 s into the 500k-triangle spawn -> process gone",
                       r["exit_s"], "s", "<= 2", r["exit_s"] <= 2.0 and not r["processes_left"])
        elif r["row"] == "hulls_300":
            out.figure("spawn_rows_hulls_bytes", "300 hulls of 1,000 vertices: ~/markers per tick, largest",
                       r["markers_bytes_max"], "bytes", "(was 43 MB)", None)
            out.figure("spawn_rows_hulls_rate", "  ... tick rate with a ~/markers subscriber", r["rate_hz"], "Hz",
                       f">= {TARGET_HZ:g}", r["rate_hz"] >= TARGET_HZ)
            out.figure("spawn_rows_hulls_first_4s", "  ... the first 4 s from the first /clock (falling, landing: "
                       f"ticks per second {r['per_second_from_first_tick']})", r["first_4s_hz"], "Hz",
                       f">= {TARGET_HZ:g}", r["first_4s_hz"] >= TARGET_HZ)
        else:
            out.figure(f"spawn_rows_{r['row']}", f"{r['row']}: tick rate from request to reply + 2 s "
                       f"(reply after {r['latency_s']:.1f} s, code {r['code']})", r["rate_hz"], "Hz",
                       f">= {TARGET_HZ:g}", r["rate_hz"] >= TARGET_HZ)
            out.figure(f"spawn_rows_{r['row']}_worst", "  slowest 1-s window", r["slowest_second_hz"], "Hz",
                       "(reference)", None)
    out.data["rows"] = results
    out.data["speed_probe"] = {"before": probe_before, "after": probe_after}
    path = out.write()
    print(format_figures(out.data["figures"]))
    print(format_speed_probe(out.data["speed_probe"]))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
