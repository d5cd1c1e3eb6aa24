"""The Dask engine: the sweep's unfinished tasks on a LocalCluster (default) or an existing cluster.

- **Local** (nothing to set up): a ``distributed.LocalCluster`` inside the command, one single-threaded worker
  process per core (``--workers``), started and closed by the command.
- **A cluster** (``--scheduler tcp://host:8786``): the same tasks go to an existing scheduler's workers.  Each
  worker needs cgp_sim installed (the same venv on a shared filesystem, or ``pip install`` of the same commit
  on each; README).  Before anything is submitted every worker is asked for its code version
  (:func:`cgp_sim_ros.sweep.runner.worker_version` through ``client.run``); a worker that differs from this
  client (or cannot import cgp_sim) stops the sweep with :class:`EngineError` naming the worker and both
  versions — its results would be filed under identities that do not describe them.  A worker that joins
  later is checked by the task itself (:class:`~cgp_sim_ros.sweep.runner.VersionMismatch`).
- **Where results go**: by default each task's tables come back to this client, which writes the fragments
  (:mod:`.store`), so nothing is left on a worker's disk; with ``workers_write`` (an output directory every
  worker sees under the same path) the workers write them there and return only the statuses.

Faults
    - A worker lost mid-task (killed, out of memory, its machine gone): the scheduler gives its tasks to
      other workers; a task that has brought down ``distributed.scheduler.allowed-failures`` (3) workers is
      reported (``KilledWorker``) as *not finished*, not as a failed run, and the next invocation tries it
      again.  An exception escaping a task (not a run's own error: those are failed rows) is retried
      ``retries`` times on other workers.  Results are filed once per run identity, so a retried task never
      adds rows twice.
    - A run that raises is a ``failed`` row with its error (:mod:`.runner`); the sweep goes on.
    - Ctrl-C: pending tasks are cancelled, the cluster is closed, the tables are assembled from what finished
      (every fragment is kept) and the command exits 130; the same command resumes.

Resume: a task is submitted only if one of its runs has no fragment (failed runs count as finished unless
``retry_failed``).
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

from .spec import Sweep, Task, code_version
from .store import assemble, finished, prepare_output, write_fragments

#: how long to wait for the first worker of an existing cluster [s]
WORKER_TIMEOUT_S = 60.0

#: Dask settings of the LocalCluster's workers (the Nanny hands them to each worker process).  A run steps a
#: small world thousands of times a second in pure Python, and the worker's event loop takes the GIL from it at
#: every periodic callback: Dask's defaults wake it ~70 times a second (the blocked-loop check every 20 ms, the
#: statistical profiler every 10 ms, the memory and system monitors).  Measured side by side with a plain
#: process running the same runs (bench_sweep's method, 12 runs of 30 s, 27 trials each): the sweep's
#: overhead per run was ~9 % (median) with the defaults, ~2.3 % with these plus :func:`runner.prepare_worker`.
#: The memory monitor's 5 s also means a worker near its memory limit is paused or restarted up to 5 s later.
#: A cluster you bring (``--scheduler``) keeps its own configuration: set these in its Dask configuration
#: (docs/sweeps.md).
QUIET_WORKERS = {
    "distributed.admin.tick.interval": "2s",
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "5s",
}


#: the transports a ``--scheduler`` address may name (Dask's; an address without one is tcp://)
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")


class EngineError(RuntimeError):
    """The sweep cannot run on this cluster (no workers, a version mismatch, an option it cannot honour)."""


def scheduler_address(text: str) -> str:
    """``--scheduler``'s address checked: ``[SCHEME://]HOST:PORT`` with a scheme of :data:`SCHEDULER_SCHEMES`
    and a port 1..65535 (IPv6 hosts in brackets); :class:`EngineError` saying what is wrong otherwise (issue 38:
    ``garbage``, ``tcp://[::1`` and ``foo://bar:1`` were ValueError tracebacks)."""
    shown = text if len(text) <= 200 else text[:200] + "..."
    usage = "expected [SCHEME://]HOST:PORT such as tcp://10.0.0.5:8786"
    scheme, separator, rest = text.strip().partition("://")
    if not separator:
        scheme, rest = "tcp", text.strip()
    if scheme not in SCHEDULER_SCHEMES:
        raise EngineError(f"--scheduler {shown!r}: unknown transport {scheme!r} (Dask's: "
                          f"{', '.join(SCHEDULER_SCHEMES)}); {usage}")
    try:
        parts = urlsplit(f"{scheme}://{rest}")
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        raise EngineError(f"--scheduler {shown!r}: {exc}; {usage}") from None
    if not host or not port or parts.path not in ("", "/") or parts.query or parts.fragment or parts.username:
        raise EngineError(f"--scheduler {shown!r}: {usage}")
    return f"{scheme}://{rest}"


@dataclass
class Outcome:
    """What one invocation did."""

    planned_runs: int
    already_finished: int            # runs with a fragment before this invocation
    ran: int = 0                     # runs executed (and filed) by this invocation
    failed: int = 0                  # of those, failed
    not_finished: list[str] = field(default_factory=list)  # tasks lost to the machinery: why
    interrupted: bool = False
    rows: dict[str, int] = field(default_factory=dict)
    wall_s: float = 0.0
    workers: int = 0

    @property
    def exit_code(self) -> int:
        if self.interrupted:
            return 130
        return 1 if self.failed or self.not_finished else 0


def pending_tasks(sweep: Sweep, out: Path, retry_failed: bool = False) -> tuple[list[Task], int]:
    """The tasks with a run to do, and how many runs are finished already."""
    status = finished(out)
    done = {k for k, v in status.items() if v == "done" or not retry_failed}
    todo = [t for t in sweep.tasks if not all(r.id in done for r in t.runs)]
    already = sum(1 for r in sweep.runs if r.id in done)
    return todo, already


def run_sweep(sweep: Sweep, out: Path, *, scheduler: str | None = None, workers: int | None = None,
              client=None, retry_failed: bool = False, workers_write: bool = False, retries: int = 2,
              stream=None, quiet: bool = False) -> Outcome:
    """Run what is missing of ``sweep`` into ``out`` and assemble the tables.  ``client``: an existing
    ``distributed.Client`` (tests, notebooks); else ``scheduler`` (an address) or a LocalCluster of ``workers``
    processes (default: one per core).  Raises :class:`EngineError`."""
    from cgp_sim_ros.progress import ProgressLine, bar, format_duration

    stream = stream or sys.stderr
    say = (lambda text: None) if quiet else (lambda text: print(text, file=stream, flush=True))
    if scheduler and client is None:
        scheduler = scheduler_address(scheduler)
    out = prepare_output(out)  # before anything runs (OutputError: not a directory, cannot be written)
    code = code_version()
    started = time.monotonic()
    todo, already = pending_tasks(sweep, out, retry_failed)
    outcome = Outcome(planned_runs=len(sweep.runs), already_finished=already)
    refused = [r for t in todo for r in t.runs if r.refused]
    say(f"sweep {sweep.name}: {len(sweep.runs)} runs in {len(sweep.tasks)} tasks, {already} finished before, "
        f"{sum(len(t.runs) for t in todo)} to run (code {code})")
    if refused:
        say(f"  {len(refused)} runs have scenes the scene loader refuses; they are recorded as failed. First:\n"
            + "\n".join("    " + line for line in refused[0].refused.splitlines()[:3]))
    needs_bags = any(t.experiment.record["bag"] for t in todo)
    if not todo:
        outcome.rows = assemble(out, sweep, code, outcome.not_finished)
        return outcome
    if needs_bags and scheduler and not workers_write:
        raise EngineError("record.bag writes each run's bag where the run executes: on a cluster give "
                          "--workers-write with an output directory every worker sees")

    owned = []  # what this function started and must close
    try:
        if client is None:
            client, owned = _connect(scheduler, workers)
        outcome.workers = check_workers(client)
        from .runner import prepare_worker

        client.run(prepare_worker)  # every worker's objects out of the collector's way (QUIET_WORKERS says why)
        shared = str(out.resolve()) if (workers_write or needs_bags) else None
        total_ticks = sum(t.ticks for t in todo)
        runs_to_do = sum(len(t.runs) for t in todo)
        progress = ProgressLine(stream) if not quiet else None
        done_ticks = 0
        futures = {}
        # longest first: the last tasks to start are short, so the workers finish together
        for task in sorted(todo, key=lambda t: -t.ticks):
            payload = task.payload(sweep.source, code)
            if shared:
                payload["bag_dir"] = str(Path(shared) / "bags")
                if workers_write:
                    payload["write_to"] = shared
            future = client.submit(_run_task, payload, key=f"cgp-sim-sweep-{task.id}-{uuid.uuid4().hex[:8]}",
                                   pure=False, retries=retries)
            futures[future] = task

        def status_line(final: bool = False) -> str:
            elapsed = time.monotonic() - started
            fraction = done_ticks / total_ticks if total_ticks else 1.0
            left = elapsed * (1.0 - fraction) / fraction if fraction > 0 else math.inf
            text = (f"{bar(fraction)} {outcome.ran}/{runs_to_do} runs, {outcome.failed} failed"
                    + (f", {len(outcome.not_finished)} not finished" if outcome.not_finished else "")
                    + f", {format_duration(elapsed)} elapsed")
            return text + ("" if final else f", ETA {format_duration(left)}")

        from distributed import wait
        from distributed.scheduler import KilledWorker

        from .runner import VersionMismatch

        pending = set(futures)
        try:
            while pending:
                try:
                    done, pending = wait(pending, timeout=0.5, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                for future in done:
                    task = futures.pop(future)
                    done_ticks += task.ticks
                    try:
                        result = future.result()
                    except VersionMismatch as exc:
                        raise EngineError(str(exc)) from None
                    except KilledWorker as exc:
                        outcome.not_finished.append(f"task {task.id}: its workers died running it ({exc})")
                        continue
                    except Exception as exc:  # noqa: BLE001 - the machinery failed, not the run: not filed
                        outcome.not_finished.append(f"task {task.id}: {type(exc).__name__}: {exc}")
                        continue
                    finally:
                        future.release()
                    if not workers_write:
                        write_fragments(out, result["results"], result["worker"])
                    outcome.ran += len(result["results"])
                    outcome.failed += sum(r["status"] == "failed" for r in result["results"])
                if progress is not None and progress.due():
                    progress.update(status_line())
        except KeyboardInterrupt:
            outcome.interrupted = True
            client.cancel(list(pending))
        if progress is not None:
            progress.finish(status_line(final=True))
    finally:
        for thing in reversed(owned):
            try:
                thing.close()
            except Exception:  # noqa: BLE001 - closing after an interrupt: nothing more to do
                pass
    outcome.rows = assemble(out, sweep, code, outcome.not_finished)
    outcome.wall_s = time.monotonic() - started
    return outcome


def _run_task(payload: dict) -> dict:
    """The function a worker calls (imported there by name: the worker needs cgp_sim installed)."""
    from .runner import run_task

    return run_task(payload)


def _connect(scheduler: str | None, workers: int | None):
    """A client of an existing scheduler, or of a LocalCluster started here; returns (client, [to close])."""
    from distributed import Client

    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise EngineError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            client.wait_for_workers(1, timeout=WORKER_TIMEOUT_S)
        except TimeoutError:
            client.close()
            raise EngineError(
                f"the Dask scheduler at {scheduler} has no worker (waited {WORKER_TIMEOUT_S:g} s)") from None
        return client, [client]
    cluster = local_cluster(workers or os.cpu_count() or 1)
    client = Client(cluster)
    return client, [cluster, client]


def local_cluster(workers: int):
    """The LocalCluster a sweep runs on: ``workers`` single-threaded worker processes with
    :data:`QUIET_WORKERS` (a flock of 2,000 boids or more also uses numba's pool in each: cgp_core.jit;
    NUMBA_NUM_THREADS=1 in the workers is refused by jit.threads_for, so it is left as is)."""
    import dask
    from distributed import LocalCluster

    with dask.config.set(QUIET_WORKERS):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                            silence_logs=logging.ERROR)


def check_workers(client) -> int:
    """Every worker's code version equals this client's, else :class:`EngineError` naming the workers and both
    versions.  Returns the number of workers."""
    from .runner import worker_version

    mine = code_version()
    answers = client.run(worker_version, on_error="return")
    wrong = []
    for address, answer in sorted(answers.items()):
        if isinstance(answer, BaseException):
            wrong.append(f"{address}: cannot run cgp_sim's sweep code ({type(answer).__name__}: {answer}); is "
                         "cgp_sim installed there?")
        elif answer["code_version"] != mine:
            wrong.append(f"{address} (host {answer['host']}, pid {answer['pid']}) runs cgp_sim "
                         f"{answer['code_version']}, this client {mine}")
    if wrong:
        raise EngineError("the cluster's workers do not run this client's cgp_sim (install the same version "
                          "on every worker, README: Sweeps on a cluster):\n  " + "\n  ".join(wrong))
    return len(answers)
