"""What the Foxglove live view (issue 15) costs the tick: no client, a live client, a client that reads nothing.

The node is built as ``cgp-sim --foxglove true`` builds it — ``SimNode`` with ``foxglove:=true`` on a free port,
no bag, in a process of its own ROS domain — and ticked back to back by this script (no executor: no command
or service traffic), paced at the scene's 60 Hz so a client sees the real message rate.  Clients are separate
processes speaking the Foxglove protocol (``tests/foxglove_client.py``), subscribed to every channel:

- *live*: reads everything as it comes (a Python websockets reader: like the app, it keeps up or falls behind
  on its own CPU; on this 2-core machine its CPU competes with the node's);
- *stalled*: subscribes, then never reads again: its socket fills and the SDK's per-client queue (the node's
  ``CLIENT_BACKLOG`` messages) drops the oldest; it stays connected (the SDK drops a client only when its
  control queue of statuses and service responses overflows), so the phase also reports the memory it holds.

In each client state the node alternates blocks of ticks with the live view *on* (the server object hooked into
``_out``, as with ``foxglove:=true``) and *off* (``node.foxglove = None``, exactly the node's code path with the
parameter false), so the two medians come from the same minutes of this shared machine.  Also measured
directly: the hook's own cost per tick (the tick's messages handed to ``FoxgloveServer.publish`` in a loop,
without and with a subscriber), the process's memory while a client stalls, and how long until the SDK drops a
stalled client.

A fourth client floods a command topic (20,000 rejected wrenches a second), alternately running and stopped
(SIGSTOP): what a flood costs the tick's thread.

Scenes: the default scene (what ``make run`` shows; ~10 messages, ~0.3 MB per tick) and issue 7's 15k-boid
tick scene (~30 messages, ~1.2 MB per tick).  Writes ``benchmarks/results/foxglove.json``.  Run alone:
``.venv/bin/python benchmarks/bench_foxglove.py`` (``--quick``: fewer ticks).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

from common import Results, format_figures  # noqa: E402

SCENES = {"default": "default", "15k": str(Path(__file__).resolve().parent / "scenes" / "tick_15k.yaml")}
CLIENT = ROOT / "tests" / "foxglove_client.py"
BLOCK = 30  # ticks per on / off block


def make_node(scene: str):
    from rclpy.parameter import Parameter

    from cgp_sim_ros.ros.node import SimNode

    return SimNode(node_name="cgp_sim_bench_foxglove", parameter_overrides=[
        Parameter("scene", value=scene), Parameter("realtime", value=False), Parameter("foxglove", value=True),
        Parameter("foxglove_port", value=0)])


class Peer:
    """A client process (``tests/foxglove_client.py URL read|stall``)."""

    def __init__(self, url: str, mode: str, log_path: Path):
        import psutil

        self._log = open(log_path, "w+")
        self.proc = subprocess.Popen([sys.executable, str(CLIENT), url, mode], stdout=self._log,
                                     stderr=subprocess.STDOUT)
        self.ps = psutil.Process(self.proc.pid)
        deadline = time.monotonic() + 30
        while "subscribed" not in self.output():
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError(f"the {mode} client did not subscribe: {self.output()}")
            time.sleep(0.05)

    def output(self) -> str:
        self._log.seek(0)
        return self._log.read()

    def cpu_s(self) -> float:
        try:
            t = self.ps.cpu_times()
            return t.user + t.system
        except Exception:  # noqa: BLE001 - exited
            return float("nan")

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        out = self.output()
        self._log.close()
        return out


def all_subscribed(server) -> bool:
    return all(channel.has_sinks() for channel in server._channels.values())


def any_subscribed(server) -> bool:
    return any(channel.has_sinks() for channel in server._channels.values())


def wait_for(condition, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.01)


def run_blocks(node, server, blocks: int, period: float, stop_when=None, switch=None) -> dict:
    """``blocks`` pairs of BLOCK ticks with the hook on, then off (or ``switch(True / False)``); paced at
    ``period``.  Tick times in ms."""
    on, off = [], []
    on_ticks_until_stop = None
    next_start = time.perf_counter()
    for _ in range(blocks):
        for hooked, sink in ((True, on), (False, off)):
            if switch is not None:
                switch(hooked)
            else:
                node.foxglove = server if hooked else None
            for _ in range(BLOCK):
                now = time.perf_counter()
                if now < next_start:
                    time.sleep(next_start - now)
                next_start = max(next_start + period, time.perf_counter() - period)
                start = time.perf_counter()
                node.tick()
                sink.append(1e3 * (time.perf_counter() - start))
                if stop_when is not None and on_ticks_until_stop is None and stop_when():
                    on_ticks_until_stop = len(on)
        if on_ticks_until_stop is not None:
            break
    node.foxglove = server
    return {"on": on, "off": off, "on_ticks_until_stop": on_ticks_until_stop}


def hook_cost_us(node, server, repeats: int) -> tuple[float, int, int]:
    """µs per tick that ``FoxgloveServer.publish`` takes for one tick's messages (median of ``repeats``), the
    number of messages and their bytes."""
    captured = []
    outputs = node.outputs
    original = outputs.publish
    outputs.publish = lambda publisher, data, stamp, **_: captured.append((publisher, data, stamp))
    try:
        node.tick()
    finally:
        del outputs.__dict__["publish"]
    assert outputs.publish == original
    publish = server.publish
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for publisher, data, stamp in captured:
            publish(publisher, data, stamp)
        times.append(time.perf_counter() - start)
    return 1e6 * float(np.median(times)), len(captured), sum(len(d) for _, d, _ in captured)


def rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 1e6


def stats(ms: list[float]) -> dict:
    a = np.asarray(ms)
    return {"ticks": len(a), "median_ms": float(np.median(a)) if len(a) else None,
            "p90_ms": float(np.percentile(a, 90)) if len(a) else None}


def bench_scene(label: str, scene: str, blocks: int, log_dir: Path) -> dict:
    node = make_node(scene)
    server = node.foxglove
    url = f"ws://127.0.0.1:{server.port}"
    period = node.world.dt
    for _ in range(60):  # warm-up: numba, caches, the bodies' first fall
        node.tick()
    row: dict = {"scene": label}

    row["hook_no_subscriber_us"], row["messages_per_tick"], payload = hook_cost_us(node, server, 2000)
    row["payload_MB_per_tick"] = payload / 1e6
    print(f"[{label}] {row['messages_per_tick']} messages, {row['payload_MB_per_tick']:.2f} MB per tick; hook "
          f"with no subscriber: {row['hook_no_subscriber_us']:.2f} µs per tick", flush=True)
    phase = run_blocks(node, server, blocks, period)
    row["no_client"] = {"on": stats(phase["on"]), "off": stats(phase["off"])}

    live = Peer(url, "read", log_dir / f"foxglove_{label}_live.log")
    try:
        wait_for(lambda: all_subscribed(server), 20, "the live client's subscriptions")
        cpu0, wall0 = live.cpu_s(), time.perf_counter()
        phase = run_blocks(node, server, blocks, period)
        ticks = len(phase["on"]) + len(phase["off"])
        row["live_client"] = {"on": stats(phase["on"]), "off": stats(phase["off"]),
                              "client_cpu_ms_per_tick": 1e3 * (live.cpu_s() - cpu0) / ticks,
                              "wall_s": time.perf_counter() - wall0}
        row["hook_live_subscriber_us"] = hook_cost_us(node, server, 200)[0]
    finally:
        output = live.stop()
    row["live_client"]["client_output"] = output.strip().splitlines()[-1:]
    wait_for(lambda: not any_subscribed(server), 20, "the live client to go")

    stalled = Peer(url, "stall", log_dir / f"foxglove_{label}_stalled.log")
    try:
        wait_for(lambda: all_subscribed(server), 20, "the stalled client's subscriptions")
        rss0 = rss_mb()
        phase = run_blocks(node, server, blocks, period, stop_when=lambda: not any_subscribed(server))
        until = phase["on_ticks_until_stop"]
        row["stalled_client"] = {"on": stats(phase["on"][:until]), "off": stats(phase["off"][:until]),
                                 "rss_growth_MB": rss_mb() - rss0, "disconnected_after_on_ticks": until}
    finally:
        stalled.stop()
    # A client flooding a command topic (20,000 rejected wrenches a second), on in one block and stopped
    # (SIGSTOP) in the next.  No executor runs here, so this is the cost on the tick's side: the SDK's threads
    # taking the GIL for each message and the bounded inbox (the validation itself runs between ticks, at most
    # COMMAND_BATCH_S per executor turn, in the real node).
    body = next(name for name, fixed in zip(node.world.body_model.names, node.world.body_model.fixed) if not fixed)
    flood = Peer(url, f"flood:{body}", log_dir / f"foxglove_{label}_flood.log")
    try:
        phase = run_blocks(node, server, blocks, period, switch=lambda on: os.kill(
            flood.proc.pid, signal.SIGCONT if on else signal.SIGSTOP))
        row["flooding_client"] = {"on": stats(phase["on"]), "off": stats(phase["off"])}
    finally:
        os.kill(flood.proc.pid, signal.SIGCONT)
        flood.stop()
    node.close()
    node.destroy_node()
    for name in ("no_client", "live_client", "stalled_client", "flooding_client"):
        r = row[name]
        print(f"[{label}] {name:15} tick median: live view on {r['on']['median_ms']:.3f} ms, off "
              f"{r['off']['median_ms']:.3f} ms (p90 {r['on']['p90_ms']:.2f} / {r['off']['p90_ms']:.2f}; "
              f"{r['on']['ticks']} + {r['off']['ticks']} ticks)", flush=True)
    print(f"[{label}] live client used {row['live_client']['client_cpu_ms_per_tick']:.2f} ms CPU per tick; hook "
          f"with a live subscriber {row['hook_live_subscriber_us']:.1f} µs per tick; stalled client: RSS "
          f"{row['stalled_client']['rss_growth_MB']:+.1f} MB, "
          + ("still connected" if row['stalled_client']['disconnected_after_on_ticks'] is None else
             f"disconnected by the SDK after {row['stalled_client']['disconnected_after_on_ticks']} ticks"),
          flush=True)
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer ticks")
    parser.add_argument("--blocks", type=int, default=None, help="on/off block pairs per client state")
    args = parser.parse_args(argv)
    blocks = args.blocks or (3 if args.quick else 10)
    import rclpy

    rclpy.init()
    out = Results("foxglove", options={"quick": args.quick, "blocks": blocks, "block_ticks": BLOCK})
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_foxglove_") as log_dir:  # the client processes' output
        try:
            for label, scene in SCENES.items():
                rows.append(bench_scene(label, scene, blocks if label == "default" else max(2, blocks // 2),
                                        Path(log_dir)))
        finally:
            rclpy.try_shutdown()
    out.data["rows"] = rows
    for r in rows:
        s = r["scene"]
        for state, what in (("no_client", "no client"), ("live_client", "a live client"),
                            ("stalled_client", "a stalled client"), ("flooding_client", "a flooding client")):
            on, off = r[state]["on"]["median_ms"], r[state]["off"]["median_ms"]
            out.figure(f"foxglove_{s}_{state}_delta", f"Foxglove live view, {s} scene, {what}: tick on - off",
                       on - off, "ms", f"(reference: off {off:.2f} ms)", None)
        out.figure(f"foxglove_{s}_hook_idle_us", f"Foxglove hook per tick, {s} scene, no subscriber",
                   r["hook_no_subscriber_us"], "µs", "(reference)", None)
    print(format_figures(out.data["figures"]))
    print(f"wrote {out.write()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
