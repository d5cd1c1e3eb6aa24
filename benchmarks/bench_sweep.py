#!/usr/bin/env python3
"""cgp-sim-sweep on Dask (issue 26): a 48-run Couzin sweep with 1 and with 2 LocalCluster workers, and what the
sweep machinery costs per run next to stepping the same worlds in this process.

The sweep: the ``couzin_torus`` scene (N = 100, Couzin's zonal model, open water), Δr_o over 12 values x 4 seeds
= 48 runs of 60 s at the node's 60 Hz (3,600 ticks each), the order parameters recorded once a second and
averaged over the last 20 s (``--quick``: 12 runs of 20 s).  Measured in one process, interleaved so that the
machine's drifting speed cannot favour one side:

1. in-process, every 8th run: the sweep's own run function (``runner.run_task``: the same stepping and
   measurements a worker does), and ``World.from_scene`` + ``world.step()`` x ticks, nothing else;
2. the sweep on LocalClusters of **1** and of **2** workers (both started, and their workers warmed with a short
   run, before the clock starts: the figures are per run, the start-up is reported apart), in halves (every
   other Δr_o) in the order 1, 2, 2, 1 workers, so that a steady drift of the machine's speed (tens of
   percent within minutes here) cancels out of the ratio; each into a fresh output directory (nothing resumed);
3. in-process, every 8th run from the 5th (a quarter of the runs in all).

Figures: the wall time with 1 and 2 workers and the speed-up (goal >= 1.8x on this 2-core machine), and the
overhead per run of the 1-worker sweep (its wall time / runs) over the same runs stepped by ``run_task`` in a
plain process beside it, at the same time, on the other core (extra runs of half 0 after the A B B A order;
the median of 3 such trials; goal <= 5 %; also, as before, against in-process runs before and after the
sweeps, which the machine's drift between them skews by ±10 %):
the Parquet fragments and tables, Dask's scheduling and the transfer of the results to the client; and, as a
supporting figure, what the runs' measurements (order parameters at every tick of the summary's window) cost
next to bare stepping.  Writes ``benchmarks/results/sweep.json``.
"""

from __future__ import annotations

import argparse
import copy
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import Results, format_figures, speed_probe  # noqa: E402
from cgp_core.scene import scene_from_dict  # noqa: E402
from cgp_core.world import World  # noqa: E402
from cgp_sim_ros.sweep.engine import local_cluster, run_sweep  # noqa: E402
from cgp_sim_ros.sweep.runner import run_task  # noqa: E402
from cgp_sim_ros.sweep.spec import code_version, load_sweep  # noqa: E402

SIDE_TRIALS = 3  # side-by-side overhead trials (half 0 each)
WIDTHS = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 13.0]
SWEEP = """
scene: couzin_torus
dt: 0.016666666666666666
duration: {duration}
seeds: {seeds}
overrides:
  flocks[school].spawn.center: [0, 0, 0]
grid:
  flocks[school].couzin.orientation_width: {widths}
record: {{every: 60}}
summary: {{window: {window}}}
"""


def in_process(sweep, runs, *, with_bare: bool = True) -> tuple[list[float], list[float]]:
    """Seconds per run, here in this process: (the sweep's own run function, ``run_task``: the same stepping
    and measurements a worker does; ``World.step`` x ticks and nothing else — an empty list without
    ``with_bare``)."""
    e = sweep.experiments[0]
    measured, bare = [], []
    tasks = {t.runs[0].id: t for t in sweep.tasks}
    for run in runs:
        started = time.perf_counter()
        result = run_task(tasks[run.id].payload(sweep.source, code_version()))
        assert result["results"][0]["status"] == "done", result
        measured.append(time.perf_counter() - started)
        if not with_bare:
            continue
        started = time.perf_counter()
        world = World(scene_from_dict(copy.deepcopy(run.scene)), dt=e.dt, seed=run.seed)
        for _ in range(e.ticks):
            world.step()
        bare.append(time.perf_counter() - started)
    return measured, bare


def _bare_runs(path: str, indices: list[int]) -> float:
    """In a process of its own: bare stepping of the sweep's runs ``indices``; returns the seconds."""
    sweep = load_sweep(path)
    in_process(sweep, [sweep.runs[i] for i in indices[:1]])  # load the kernels first, not timed
    started = time.perf_counter()
    for i in indices:
        run = sweep.runs[i]
        world = World(scene_from_dict(copy.deepcopy(run.scene)), dt=sweep.experiments[0].dt, seed=run.seed)
        for _ in range(sweep.experiments[0].ticks):
            world.step()
    return time.perf_counter() - started


def _run_tasks(path: str) -> list[float]:
    """In a process of its own: ``run_task`` (what a worker runs) on every run of the sweep file ``path``, after
    one untimed run that loads the kernels; the seconds of each."""
    sweep = load_sweep(path)
    in_process(sweep, sweep.runs[:1], with_bare=False)
    return in_process(sweep, sweep.runs, with_bare=False)[0]


def machine_ceiling(path: Path, count: int) -> float:
    """The speed-up this machine gives the same work without Dask: ``count`` runs stepped by 1 process, then
    by 2 processes side by side (half each): wall(1) / wall(2)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=context) as pool:
        one = pool.submit(_bare_runs, str(path), list(range(count))).result()
    with ProcessPoolExecutor(2, mp_context=context) as pool:
        halves = [pool.submit(_bare_runs, str(path), list(range(k, count, 2))) for k in (0, 1)]
        two = max(h.result() for h in halves)
    return one / two


def start_cluster(workers: int, work: Path):
    """A LocalCluster of ``workers`` processes, its workers warmed (each has loaded the kernels); returns
    (cluster, client, seconds it took)."""
    from distributed import Client

    started = time.perf_counter()
    cluster = local_cluster(workers)  # the command's own LocalCluster (its workers' settings included)
    client = Client(cluster)
    run_sweep(load_sweep(work / "warm.yaml"), work / f"warm_{workers}", client=client, quiet=True)
    return cluster, client, time.perf_counter() - started


def sweep_on(client, path: Path, out: Path) -> float:
    """Wall seconds of running the sweep file ``path`` into the fresh directory ``out`` on ``client``."""
    sweep = load_sweep(path)
    outcome = run_sweep(sweep, out, client=client, quiet=True)
    assert outcome.exit_code == 0 and outcome.ran == len(sweep.runs), outcome
    return outcome.wall_s


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="12 runs of 20 s")
    args = parser.parse_args(argv)
    duration, seeds, widths, window = (20, 1, WIDTHS, 10) if args.quick else (60, 4, WIDTHS, 20)
    out = Results("sweep", options=vars(args))
    work = Path(tempfile.mkdtemp(prefix="bench_sweep_"))
    try:
        (work / "sweep.yaml").write_text(SWEEP.format(duration=duration, seeds=seeds, widths=widths, window=window))
        (work / "warm.yaml").write_text(SWEEP.format(duration=1, seeds=4, widths=[1.0], window=1))
        sweep = load_sweep(work / "sweep.yaml")
        runs = sweep.runs
        # the sweep's two halves (every other Δr_o) as sweep files of their own, for the A B B A order below
        halves = []
        for index in (0, 1):
            halves.append(work / f"half{index}.yaml")
            halves[-1].write_text(SWEEP.format(duration=duration, seeds=seeds, widths=widths[index::2],
                                               window=window))
        print(f"{len(runs)} runs of {duration} s at 60 Hz; in-process, an 8th of them", flush=True)
        measured, bare = in_process(sweep, runs[0::8])
        probes = [speed_probe()]
        clusters = {w: start_cluster(w, work) for w in (1, 2)}
        walls = {1: 0.0, 2: 0.0}
        steps = []  # each half's wall time, to see the drift the A B B A order is there to cancel
        # A B B A: the machine's speed drifts by tens of percent within minutes; this order cancels a steady drift
        for step, (workers, half) in enumerate(((1, 0), (2, 0), (2, 1), (1, 1))):
            print(f"half {half} of the sweep on {workers} worker(s)", flush=True)
            wall = sweep_on(clusters[workers][1], halves[half], work / f"out_{step}")
            walls[workers] += wall
            steps.append({"workers": workers, "half": half, "wall_s": wall})
            probes.append(speed_probe())
        # The overhead per run, over the same minutes: half 0 once more on the 1-worker cluster while a plain
        # process (no Dask) runs the same runs with run_task on the other core (the in-process runs before and
        # after, below, are minutes away from the sweeps: the machine's drift counts in that comparison)
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # One such trial moves by +-10 % with what the two cores happen to share in it: the median of
        # SIDE_TRIALS is the figure, every trial is in the JSON.
        print(f"half 0 on 1 worker, beside a plain process running the same runs, {SIDE_TRIALS} times", flush=True)
        side_trials = []
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as plain:
            plain.submit(_run_tasks, str(work / "warm.yaml")).result()  # started and its kernels loaded
            for trial in range(SIDE_TRIALS):
                alongside = plain.submit(_run_tasks, str(halves[0]))
                side_sweep = sweep_on(clusters[1][1], halves[0], work / f"out_beside_{trial}")
                side_trials.append({"sweep_s": side_sweep, "plain_s": sum(alongside.result())})
        probes.append(speed_probe())
        for cluster, client, _ in clusters.values():
            client.close()
            cluster.close()
        print("in-process, another 8th", flush=True)
        more = in_process(sweep, runs[4::8])
        measured, bare = measured + more[0], bare + more[1]
        probes.append(speed_probe())
        clusters = {w: {"workers": w, "start_and_warm_up_s": clusters[w][2], "wall_s": walls[w]} for w in (1, 2)}
        print("the same work in 1 and in 2 plain processes (the machine's own speed-up)", flush=True)
        ceiling = machine_ceiling(work / "sweep.yaml", 4 if args.quick else 8)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    per_run_local = sum(measured) / len(measured)
    per_run_bare = sum(bare) / len(bare)
    per_run_sweep = clusters[1]["wall_s"] / len(runs)
    speedup = clusters[1]["wall_s"] / clusters[2]["wall_s"]
    overhead = per_run_sweep / per_run_local - 1.0
    out.figure("sweep_wall_1_worker", f"{len(runs)}-run Couzin sweep (N = 100, {duration} s at 60 Hz), 1 worker",
               clusters[1]["wall_s"], "s", "", None, issue26=True)
    out.figure("sweep_wall_2_workers", "the same sweep, 2 workers", clusters[2]["wall_s"], "s", "", None,
               issue26=True)
    out.figure("sweep_speedup_2_workers", "speed-up of 2 workers over 1 (2-core machine)", speedup, "x", ">= 1.8",
               speedup >= 1.8, issue26=True)
    out.figure("sweep_machine_speedup_2_processes", "the same stepping in 2 plain processes over 1 (no Dask): "
               "this machine's ceiling", ceiling, "x", "", None)
    for trial in side_trials:
        trial["overhead_percent"] = 100 * (trial["sweep_s"] / trial["plain_s"] - 1.0)
    side_overhead = statistics.median(t["overhead_percent"] for t in side_trials)
    out.figure("sweep_overhead_per_run", f"sweep (1 worker) per run over the same runs in a plain process beside "
               f"it (median of {SIDE_TRIALS} trials)", side_overhead, "%", "<= 5", side_overhead <= 5.0,
               issue26=True, trials=side_trials)
    out.figure("sweep_overhead_vs_before_after", "the same, against in-process runs before and after the sweeps "
               "(the machine's drift between them counts)", 100 * overhead, "%", "", None)
    out.figure("sweep_in_process_per_run", "a run in-process (run_task: steps + measurements)", per_run_local, "s", "",
               None)
    out.figure("sweep_bare_per_run", "World.step x ticks in-process, nothing else, per run", per_run_bare, "s", "",
               None)
    out.figure("sweep_measurements_share", "the runs' measurements (order parameters every window tick) over bare "
               "stepping", 100 * (per_run_local / per_run_bare - 1.0), "%", "", None)
    out.figure("sweep_cluster_start", "LocalCluster start + warm-up run (2 workers)",
               clusters[2]["start_and_warm_up_s"], "s", "", None)
    out.data.update(in_process_s=measured, bare_s=bare, clusters=clusters, halves=steps,
                    speed_probes_between=probes)
    path = out.write()
    print(format_figures(out.data["figures"]))
    print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
