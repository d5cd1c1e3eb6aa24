"""Thread placement (``cgp_core.jit.ThreadPlacement``, the node's ``pin_threads``): while a flock runs on numba's
thread pool, the tick's thread has a CPU of its own and every other thread of the process the others.

What each test reads is what the kernel enforces: every thread's ``Cpus_allowed_list`` in ``/proc``.  The core
tests run in a child process (placing threads would pin this test process's own); the node tests read a
running ``cgp-sim``'s threads from outside."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

ALLOWED = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
needs_two_cpus = pytest.mark.skipif(not sys.platform.startswith("linux") or len(ALLOWED) < 2,
                                    reason="thread placement needs Linux and 2 CPUs or more")


def cpus_of_threads(pid: int | str = "self") -> dict[int, set[int]]:
    """{thread id: the CPUs it may run on} for every thread of process ``pid``, as /proc says."""
    out = {}
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/status") as status:
                line = next(line for line in status if line.startswith("Cpus_allowed_list:"))
        except (OSError, StopIteration):
            continue  # ended meanwhile
        cpus = set()
        for part in line.split(":", 1)[1].strip().split(","):
            low, _, high = part.partition("-")
            cpus.update(range(int(low), int(high or low) + 1))
        out[int(task)] = cpus
    return out


CHILD = textwrap.dedent("""
    import json, sys, threading
    sys.path.insert(0, sys.argv[1])
    from test_thread_placement import cpus_of_threads
    from cgp_core.jit import ThreadPlacement

    report = {}
    placement = ThreadPlacement()
    report["unavailable"] = placement.unavailable
    before = cpus_of_threads()
    report["placed"] = placement.place()
    report["caller"] = threading.get_native_id()
    report["cpu"] = placement.cpu
    report["after_place"] = {t: sorted(c) for t, c in cpus_of_threads().items()}
    report["new_threads"] = sorted(set(report["after_place"]) - set(before))  # numba's pool, launched by place()
    # a thread the caller starts now inherits the caller's CPU, until the next place() moves it
    started, stop = threading.Event(), threading.Event()
    late = {}
    def work():
        late["id"] = threading.get_native_id()
        started.set()
        stop.wait()
    thread = threading.Thread(target=work)
    thread.start()
    started.wait()
    report["late"] = late["id"]
    report["late_before"] = sorted(cpus_of_threads()[late["id"]])
    placement.place()
    report["late_after"] = sorted(cpus_of_threads()[late["id"]])
    placement.release()
    report["after_release"] = {t: sorted(c) for t, c in cpus_of_threads().items()}
    stop.set()
    thread.join()
    print(json.dumps(report))
""")


def run_child(env_extra: dict | None = None) -> dict:
    import json

    env = {**os.environ, **(env_extra or {})}
    done = subprocess.run([sys.executable, "-c", CHILD, os.path.dirname(__file__)], capture_output=True, text=True,
                          timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@needs_two_cpus
def test_the_caller_gets_a_cpu_of_its_own_and_every_other_thread_the_others():
    report = run_child()
    assert report["unavailable"] is None and report["placed"]
    cpu, caller = report["cpu"], str(report["caller"])
    others = [c for c in ALLOWED if c != cpu]
    assert cpu in ALLOWED
    placed = report["after_place"]
    assert placed[caller] == [cpu]
    assert report["new_threads"], "place() launched numba's pool: its worker threads exist"
    for thread, cpus in placed.items():
        if thread != caller:
            assert cpus == others, f"thread {thread} may run on {cpus}, beside the caller"
    # a thread started by the caller after a placement shares its CPU until the next placement moves it
    assert report["late_before"] == [cpu]
    assert report["late_after"] == others
    # release: every thread on every CPU the process may use
    assert all(cpus == ALLOWED for cpus in report["after_release"].values()), report["after_release"]


def test_without_the_jit_nothing_is_placed_and_the_reason_is_given():
    report = run_child({"NUMBA_DISABLE_JIT": "1"})
    assert report["placed"] is False
    assert "NUMBA_DISABLE_JIT" in report["unavailable"] or not sys.platform.startswith("linux") \
        or len(ALLOWED) < 2
    assert all(cpus == ALLOWED for cpus in report["after_place"].values()), report["after_place"]


# ---- the node --------------------------------------------------------------------------------------------------

BIG_FLOCK_SCENE = """
description: one flock big enough for numba's thread pool (2,000 boids), nothing else
world: {gravity: [0, 0, -9.81], ground: true}
flocks:
  - {name: school, count: 2000, model: sphere, spawn: {center: [0, 0, 10], extent: [30, 30, 10]}, seed: 1}
"""


def _set_pin_threads(probe, value: bool) -> None:
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    param = ParameterMsg(name="pin_threads", value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value))
    results = probe.call(SetParameters, "/cgp_sim/set_parameters", SetParameters.Request(parameters=[param])).results
    assert all(r.successful for r in results), results


@needs_two_cpus
def test_a_node_running_a_big_flock_pins_its_tick_thread_and_lets_go_when_told(start_node, probe, tmp_path):
    """cgp-sim with a 2,000-boid flock: its main thread (the executor's, which runs the ticks) on one CPU, every
    other thread of the process on the others, logged; ``pin_threads`` set false at run time: every thread on
    every CPU; true again: placed again."""
    from ros_probe import pause

    scene = tmp_path / "big_flock.yaml"
    scene.write_text(BIG_FLOCK_SCENE)
    node = start_node("--scene", str(scene), "--start-paused", "true")
    pause(probe, True)  # answered: the node is built and spinning
    pid = node.proc.pid
    threads = cpus_of_threads(pid)
    (tick_cpu,) = threads[pid]
    others = set(ALLOWED) - {tick_cpu}
    assert {t: c for t, c in threads.items() if t != pid and c != others} == {}, threads
    assert f"threads: the tick on CPU {tick_cpu} alone" in node.log()

    _set_pin_threads(probe, False)
    assert all(cpus == set(ALLOWED) for cpus in cpus_of_threads(pid).values())
    assert "threads: not pinned (pin_threads false)" in node.log()

    _set_pin_threads(probe, True)
    threads = cpus_of_threads(pid)
    assert threads[pid] == {tick_cpu}
    assert all(c == others for t, c in threads.items() if t != pid)
    assert node.stop() == 0


def test_a_node_with_a_small_flock_leaves_its_threads_to_the_os(start_node, probe):
    """The default scene's 300 fish run on one thread (the serial twins): nothing is pinned, nothing said."""
    from ros_probe import pause

    node = start_node("--scene", "default", "--start-paused", "true")
    pause(probe, True)
    assert all(cpus == set(ALLOWED) for cpus in cpus_of_threads(node.proc.pid).values())
    assert node.stop() == 0
    assert "threads:" not in node.log_path.read_text(errors="replace")
