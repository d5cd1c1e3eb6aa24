"""What every benchmark script shares: the results layout, the machine description, interleaved timing.

Every ``bench_*.py`` writes ``benchmarks/results/<name>.json`` with at least::

    {"benchmark": "<name>", "machine": {...}, "load_average": {"before": [1, 5, 15 min], "after": [...]},
     "elapsed_s": ..., "options": {...}, "figures": [<figure>, ...], ...its own tables...}

and a *figure* is ``{"id", "figure", "value", "unit", "target", "pass", "issue7", "issue12"}``: ``id`` is stable
(the aggregator ``run.py`` looks figures up by it), ``issue12`` (``issue7``) marks the figures issue 12 (7) sets a
target for (the others are supporting figures: budget splits, references).  ``run.py`` puts every figure marked
``issue12`` into its main table, whichever benchmark wrote it.  ``pass`` is ``True`` / ``False``, or
``None`` when the figure could not be measured in this run (then ``note`` says why).
"""

from __future__ import annotations

import gc
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def machine() -> dict:
    """The facts a reader needs to compare two result files."""
    info = {"python": platform.python_version(), "numpy": np.__version__, "cpus": os.cpu_count(),
            "platform": platform.platform(), "processor": _cpu_model()}
    try:
        import scipy

        info["scipy"] = scipy.__version__
    except ImportError:  # pragma: no cover - scipy is a runtime dependency
        pass
    return info


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> list[float]:
    """1, 5, 15-minute load averages (the machine is shared: other processes slow every figure down)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover - not on Linux
        return []


class Results:
    """Collects one benchmark's output and writes it in the common layout.

    >>> out = Results("tick", options=vars(args))
    >>> out.figure("tick_15k_fish_p99_first", "p99 tick ...", 14.2, "ms", "<= 16.7", 14.2 <= 16.7, issue12=True)
    >>> out.data["rows"] = rows
    >>> out.write()
    """

    def __init__(self, name: str, options: dict | None = None):
        self.name = name
        self.started = time.perf_counter()
        self.data: dict = {"benchmark": name, "machine": machine(),
                           "load_average": {"before": load_average()},
                           "speed_probe": {"before": speed_probe()}, "options": options or {}, "figures": []}

    def figure(self, id: str, figure: str, value, unit: str, target: str, passed, *, issue7: bool = False,  # noqa: A002
               issue12: bool = False, **extra) -> dict:
        entry = {"id": id, "figure": figure, "value": _plain(value), "unit": unit, "target": target,
                 "pass": None if passed is None else bool(passed), "issue7": issue7, "issue12": issue12, **extra}
        self.data["figures"].append(entry)
        return entry

    def write(self, path: Path | None = None) -> Path:
        self.data["load_average"]["after"] = load_average()
        self.data["speed_probe"]["after"] = speed_probe()
        self.data["elapsed_s"] = round(time.perf_counter() - self.started, 1)
        path = path or RESULTS / f"{self.name}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(_plain(self.data), indent=2) + "\n")
        return path


def _plain(value):
    """JSON-safe copy: numpy scalars and arrays to Python numbers and lists, NaN to None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return None if value != value else value
    return value


def reset_stage_times(solver) -> None:
    """Start the per-stage profiles of a contact solver and its detector over (``cgp_core.jit.StageProfile``)."""
    solver.profile.reset()
    solver.detector.profile.reset()


def stage_times(solver, steps: int) -> dict[str, float]:
    """Wall time per stage since :func:`reset_stage_times`, in ms per step (``steps``: the ticks or sub-steps the
    caller ran): ``{"detect.bounds": ..., "detect.broad_phase": ..., "solve.prepare": ..., ...,
    "solve.recover_penetration": ...}``, read from ``solver.detector.profile`` and ``solver.profile``."""
    times = {}
    for owner, profile in (("detect", solver.detector.profile), ("solve", solver.profile)):
        for stage, seconds in zip(profile.stages, profile.seconds):
            times[f"{owner}.{stage}"] = float(seconds) / max(steps, 1) * 1e3
    return times


def format_stage_times(times: dict[str, float]) -> str:
    """The stage times as two indented lines (detection, then the solver), ms per step, with their sums."""
    lines = []
    for owner in ("detect", "solve"):
        parts = {k.split(".", 1)[1]: v for k, v in times.items() if k.startswith(owner + ".")}
        lines.append(f"    {owner:6s} {sum(parts.values()):7.3f} ms = "
                     + " + ".join(f"{name} {ms:.3f}" for name, ms in parts.items()))
    return "\n".join(lines)


def format_speed_probe(probe: dict) -> str:
    """A result's ``speed_probe`` (before / after, :func:`speed_probe`) on one line, to print beside its figures."""
    return (f"speed probe (numpy / python ms): before {probe['before']['numpy_ms']} / {probe['before']['python_ms']}, "
            f"after {probe['after']['numpy_ms']} / {probe['after']['python_ms']}")


def format_figures(figures: list[dict], width: int = 62) -> str:
    """The figures as a plain-text table (value, target, pass / SHORT)."""
    lines = [f"{'figure':{width}} {'value':>10} {'unit':7} {'target':>28}  result"]
    for f in figures:
        lines.append(f"{f['figure'][:width]:{width}} {format_value(f['value']):>10} {f['unit']:7} "
                     f"{f['target'][:28]:>28}  {verdict(f)}")
    return "\n".join(lines)


def format_value(value) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        return str(value)
    if abs(value) >= 100:
        return f"{value:.0f}"
    if abs(value) >= 10:
        return f"{value:.1f}"
    return f"{value:.2f}"


def verdict(figure: dict) -> str:
    return {True: "pass", False: "SHORT", None: "n/a"}[figure["pass"]]


def speed_probe(repeats: int = 5) -> dict:
    """A fixed CPU workload (numpy ufuncs on 200k floats + a pure-Python loop), median ms of ``repeats``.

    The load average does not see other virtual machines on the same host; this does: on a quiet machine
    it takes the same time from run to run, so a larger value next to a figure says the machine was slower
    than usual while it was measured."""
    x = np.linspace(0.0, 1.0, 200_000)
    numpy_ms, python_ms = [], []
    for _ in range(repeats + 1):  # the first round warms up (allocator, caches) and is not counted
        t0 = time.perf_counter()
        y = x
        for _ in range(10):
            y = np.sin(y) * 0.5 + np.sqrt(np.abs(y) + 1.0)
        t1 = time.perf_counter()
        total = 0
        for i in range(200_000):
            total += i * i % 7
        t2 = time.perf_counter()
        numpy_ms.append((t1 - t0) * 1e3)
        python_ms.append((t2 - t1) * 1e3)
    return {"numpy_ms": round(float(np.median(numpy_ms[1:])), 2),
            "python_ms": round(float(np.median(python_ms[1:])), 2)}


class GcWatch:
    """Python's garbage collections while it is installed: how many per generation, and the longest."""

    def __init__(self):
        self.count = [0, 0, 0]
        self.longest_ms = 0.0
        self.total_ms = 0.0
        self._start = 0.0

    def __call__(self, phase, info):
        if phase == "start":
            self._start = time.perf_counter()
        else:
            ms = (time.perf_counter() - self._start) * 1e3
            self.count[info["generation"]] += 1
            self.longest_ms = max(self.longest_ms, ms)
            self.total_ms += ms

    def __enter__(self):
        gc.callbacks.append(self)
        return self

    def __exit__(self, *exc):
        gc.callbacks.remove(self)

    def as_dict(self) -> dict:
        return {"count": list(self.count), "longest_ms": self.longest_ms, "total_ms": self.total_ms}


def stop_node(process, timeout: float = 60.0) -> int | None:
    """Stop a ``cgp-sim`` child as Ctrl-C does (SIGINT: the node finishes its bag), killed if it takes longer than
    ``timeout`` s; its exit status (None: killed)."""
    import signal
    import subprocess

    process.send_signal(signal.SIGINT)
    try:
        return process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        return None
