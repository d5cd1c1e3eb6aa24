"""A fresh clone's ``make run`` to its first tick, step by step (issue 34): what a new user waits for; then
``make setup`` in that clone (every other kernel: what ``make test`` adds before its suite).

    .venv/bin/python benchmarks/bench_fresh_clone.py [--keep] [--ref HEAD]

Clones this checkout's commit (``--ref``, default ``HEAD``: commit first) into a temporary directory and runs
``make run ARGS="--realtime false --duration 0.0167 --foxglove false"`` there with a new ``.venv`` (one tick of the
default scene, then the node stops) — pip's download cache is the user's, so on a machine that ran it before the
pip step measures installing, not downloading — timing each step from the line that starts it to the next: pip
(ROS 2 wheels and Python dependencies), the interface packages (``tools/build_msgs.py``: cgp_sim_msgs, tf2_msgs,
simulation_interfaces, side by side), the editable install and its bytecode, the default scene's kernels (``python
-m cgp_sim_ros.warmup --default-scene``: its three parts in their workers) and the node's start to its end after
that one tick.  Then ``make setup`` (the rest of every kernel).  ~5-10 min on 2 cores; an extra of ``run.py``
(``--extras`` or ``--only fresh_clone``).  Asserts nothing; the speed probe before and after is in the JSON, beside
the figures.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import Results, format_speed_probe  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
#: the issue's goals: `make run`'s first /clock on a fresh clone within 6 min, of which everything but pip within
#: 3 min; the interface packages within 60 s; the default scene's kernels compiled within 20 s
TARGETS = {"total": 360.0, "after_pip": 180.0, "msgs": 60.0, "default_kernels": 20.0}
#: the line that starts each step: make's `setup: ...` lines, the node's own
STEP_NAMES = {"setup: installing ROS 2 wheels": "pip", "setup: building the interface packages": "msgs",
              "setup: installing cgp_sim": "project", "setup: compiling the default scene's kernels": "default_kernels",
              "cgp-sim: compiling the simulation kernels": "node_kernels", "cgp-sim: kernels compiled in": "node_start",
              "setup: compiling the simulation kernels": "kernels"}
RUN_ARGS = "--realtime false --duration 0.0167 --foxglove false"


def timed(clone: Path, *command: str) -> tuple[dict[str, float], float, list[str]]:
    """Run ``command`` (make ...) in ``clone``; returns ({step: seconds}, total seconds, the output lines)."""
    started = time.monotonic()
    marks, lines = [], []
    process = subprocess.Popen(list(command), cwd=clone, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    for line in process.stdout:
        now = time.monotonic() - started
        lines.append(f"{now:7.1f} {line.rstrip()}")
        print(lines[-1], flush=True)
        for prefix, step in STEP_NAMES.items():
            if line.startswith(prefix):
                marks.append((step, now))
    if process.wait() != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n" + "\n".join(lines[-40:]))
    total = time.monotonic() - started
    steps = {step: (marks[i + 1][1] if i + 1 < len(marks) else total) - at for i, (step, at) in enumerate(marks)}
    if marks:
        steps["venv"] = marks[0][1]
    return steps, total, lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ref", default="HEAD", help="the commit to clone (default: HEAD)")
    parser.add_argument("--keep", action="store_true", help="keep the clone (its path is printed)")
    parser.add_argument("--quick", action="store_true", help="(accepted for run.py; the same run)")
    args = parser.parse_args(argv)
    out = Results("fresh_clone", options=vars(args))
    workdir = Path(tempfile.mkdtemp(prefix="cgp_sim_fresh_clone_"))
    clone = workdir / "cgp_sim"
    try:
        subprocess.run(["git", "clone", "--quiet", str(REPO), str(clone)], check=True)
        subprocess.run(["git", "checkout", "--quiet", args.ref], cwd=clone, check=True)
        steps, total, lines = timed(clone, "make", "run", f"ARGS={RUN_ARGS}")
        _, rest_total, _ = timed(clone, "make", "setup")
    finally:
        if args.keep:
            print(f"the clone: {clone}")
        else:
            shutil.rmtree(workdir, ignore_errors=True)
    built = [line for line in lines if re.search(r"build_msgs.py: .* installed into|package\(s\) built in", line)]
    out.data.update({"steps_s": steps, "run_s": total, "setup_after_s": rest_total, "build_msgs": built})
    but_pip = total - steps.get("pip", 0.0) - steps.get("venv", 0.0)
    out.figure("fresh_clone_first_tick_s", "fresh clone: make run to the end of its first tick", total, "s",
               f"<= {TARGETS['total']:g}", total <= TARGETS["total"])
    out.figure("fresh_clone_after_pip_s",
               "fresh clone: make run but pip (interfaces, install, the default scene's kernels)", but_pip, "s",
               f"<= {TARGETS['after_pip']:g}", but_pip <= TARGETS["after_pip"])
    for step in ("pip", "msgs", "default_kernels"):
        if step in steps:
            target = TARGETS.get(step)
            out.figure(f"fresh_clone_{step}_s", f"fresh clone: make run's step {step}", steps[step], "s",
                       f"<= {target:g}" if target else "(reference)", steps[step] <= target if target else None)
    out.figure("fresh_clone_setup_after_run_s", "fresh clone: then make setup (the rest of every kernel)",
               rest_total, "s", "(reference)", None)
    path = out.write()
    print("\n".join(f"{name:12s} {seconds:7.1f} s" for name, seconds in steps.items()))
    print(f"make run {total:.1f} s to the end of its first tick; then make setup {rest_total:.1f} s; "
          f"{format_speed_probe(out.data['speed_probe'])}")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
