"""A worker process for the expensive work a request triggers: off the tick's thread *and* off its GIL.

Issue 38 measured what a spawn request's work did to the tick while it ran on a thread of the node's process
(the spawn worker thread of issue 27): a 500,000-triangle mesh (reading, parsing, the BVH, the active edges)
held the GIL for most of 71 s and the tick fell to 7.8 Hz with a 19 s gap; parsing a 4.4 MB YAML held it to
31 Hz; a Ctrl-C waited 6 s for the Python that held it.  Only another process takes that work away: its own
interpreter, its own GIL, on the other core.

:class:`WorkerProcess` runs plain functions (``fn(*args)``, module-level: they travel by name) one at a time in
a child process and hands each result back as a ``concurrent.futures.Future``:

- **Start method** ``forkserver``: the node runs Fast DDS threads, and a ``fork`` of a process with threads
  copies their locks in whatever state they are (a child may deadlock in its first malloc).  The fork server is
  a fresh interpreter started with ``fork`` + ``exec`` (it imports nothing heavy: :data:`PRELOAD`), and every
  worker is a fork of *it*, with no thread in it; the worker imports what its jobs need and warms up (a second
  or two, at its low priority) before it says it is ready.
- **Deadline per job** (``timeout``, counted from when the job is handed to a ready worker: a new worker's start
  and warm-up are not the job's): a job that has not finished by then is ended by ending the process
  (SIGKILL: a job cannot be interrupted any other way in the middle of a C call), its future fails with
  :class:`JobFailed` (``reason`` ``"timeout"``), and the next job starts in a new process.  So a request that
  cannot finish is refused and never blocks the ones behind it.
- **A crash is contained**: a worker that dies (a segfault, the kernel's OOM killer) fails its job with
  ``reason`` ``"died"`` and the signal; the node goes on.
- **Results come back without a long hold of the node's GIL**: the child pickles a result with protocol 5 and
  sends its large buffers (numpy arrays: a mesh, a flock's state) out of band, each read by the node's
  supervisor thread straight into a buffer the unpickled array then uses (the pipe reads release the GIL).
- **Shutdown never waits for a job**: :meth:`WorkerProcess.close` kills the worker; the worker ignores SIGINT
  (a terminal's Ctrl-C goes to the whole process group: the node decides what stops, and when), and asks the
  kernel to kill it when its parent — the fork server, which ends with the node — goes (``PR_SET_PDEATHSIG``),
  so no worker outlives a node that was killed.
- The worker runs at a lower priority (nice +10), as the node's bag writer does: on a machine with fewer free
  cores than busy threads, the tick is served first.

The jobs the node gives it are in :mod:`cgp_sim_ros.spawning` (a spawn request: read, parse, validate, build,
draw); a robot's URDF and its meshes (issue 36) are one more such function.  ROS-free: the worker never imports
rclpy.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import queue
import signal
import threading
import time
import traceback
from concurrent.futures import Future
from dataclasses import dataclass
from os import _exit as exit_now  # a worker whose parent is gone ends at once

#: what the fork server imports before it forks workers: nothing heavy (it runs at the node's priority, at the
#: node's start-up: the workers import what they need themselves, at their lower priority, before they are ready)
PRELOAD = ("cgp_sim_ros.workers",)
#: the worker's scheduling priority relative to the node (as the bag writer's)
WORKER_NICE = 10
#: how long :meth:`WorkerProcess.close` waits for a worker to end after SIGKILL [s] (it cannot refuse)
REAP_TIMEOUT_S = 0.5
#: how long a new worker may take to start and warm up before its first job [s]; the job's own deadline starts
#: when the worker is ready (a worker started after a timeout does not eat into the next request's time)
START_TIMEOUT_S = 120.0
_READY = b"ready"
_PR_SET_PDEATHSIG = 1


class JobFailed(Exception):
    """A job that did not give a result: ``reason`` is ``"timeout"`` (it passed its deadline and its worker was
    ended), ``"died"`` (its worker ended without an answer: a crash, a kill), ``"error"`` (it raised: ``str``
    is the exception's type and message, :attr:`details` the worker's traceback) or ``"closed"`` (the worker
    was shut down)."""

    def __init__(self, reason: str, message: str, details: str = ""):
        super().__init__(message)
        self.reason = reason
        self.details = details


@dataclass
class _Job:
    future: Future
    payload: bytes  # pickle of (fn, args)
    timeout: float  # seconds of work allowed
    name: str  # fn's name, for messages


class WorkerProcess:
    """One worker process, jobs in order (see the module docstring).  ``name`` names the supervisor thread and
    the messages; ``warm_up`` (a module-level function, or None) runs in every new worker before its first job
    (loading compiled kernels from the cache: the first job does not pay them)."""

    def __init__(self, name: str, warm_up=None):
        self.name = name
        self._warm_up = warm_up
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._process = None
        self._connection = None
        self._closed = False
        self._lock = threading.Lock()  # guards _process / _connection between the supervisor and close()
        #: worker processes started so far (a new one after each timeout or death)
        self.started = 0
        self._thread = threading.Thread(target=self._supervise, name=name, daemon=True)
        self._thread.start()

    # ---- the node's side ----------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the worker now (and warm it up) instead of at the first job.  Cheap to call again."""
        self._jobs.put(None)

    def submit(self, fn, *args, timeout: float) -> Future:
        """Run ``fn(*args)`` in the worker, at most ``timeout`` seconds once it starts; the future's result is
        fn's, or it fails with :class:`JobFailed`.  ``fn`` and ``args`` must pickle (``fn`` by name)."""
        future: Future = Future()
        if self._closed:
            future.set_exception(JobFailed("closed", f"{self.name}: shut down"))
            return future
        payload = pickle.dumps((fn, args), protocol=pickle.HIGHEST_PROTOCOL)
        self._jobs.put(_Job(future, payload, float(timeout), getattr(fn, "__name__", str(fn))))
        return future

    @property
    def pid(self) -> int | None:
        """The worker's process id (None before it starts or after it ended)."""
        process = self._process
        return process.pid if process is not None and process.is_alive() else None

    def close(self) -> None:
        """End the worker at once (a running job fails with ``"closed"``; queued ones too).  Never waits for a
        job; safe to call twice."""
        self._closed = True
        self._jobs.put(_CLOSE)
        self._end_process()

    # ---- the supervisor thread ----------------------------------------------------------------------------

    def _supervise(self) -> None:
        while True:
            job = self._jobs.get()
            if job is _CLOSE:
                break
            if self._closed:
                if job is not None:
                    job.future.set_exception(JobFailed("closed", f"{self.name}: shut down"))
                continue
            if job is None:  # start()
                try:
                    self._ensure_process()
                except JobFailed:  # (the next job tries again, and reports it)
                    pass
                continue
            if not job.future.set_running_or_notify_cancel():
                continue
            try:
                job.future.set_result(self._run(job))
            except JobFailed as failure:
                job.future.set_exception(failure)
            except BaseException as exc:  # noqa: BLE001 - the supervisor must survive anything a job does
                job.future.set_exception(JobFailed("died", f"{self.name}: {type(exc).__name__}: {exc}"))
        while True:  # closed: fail what is still queued
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                return
            if isinstance(job, _Job):
                job.future.set_exception(JobFailed("closed", f"{self.name}: shut down"))

    def _run(self, job: _Job):
        connection = self._ensure_process()
        try:
            connection.send_bytes(job.payload)
        except (OSError, ValueError):
            self._end_process()
            connection = self._ensure_process()
            connection.send_bytes(job.payload)
        deadline = time.monotonic() + job.timeout
        while True:
            if self._closed:
                raise JobFailed("closed", f"{self.name}: shut down while {job.name} ran")
            left = deadline - time.monotonic()
            if left <= 0.0:
                self._end_process()
                raise JobFailed("timeout", f"did not finish within {job.timeout:g} s (its worker process was "
                                           "ended)")
            try:
                if connection.poll(min(left, 0.1)):
                    return self._receive(connection)
            except (EOFError, OSError):
                code = self._end_process()
                if self._closed:
                    raise JobFailed("closed", f"{self.name}: shut down while {job.name} ran") from None
                raise JobFailed("died", f"its worker process ended without an answer ({_exit_text(code)})") \
                    from None

    @staticmethod
    def _receive(connection):
        header = pickle.loads(connection.recv_bytes())
        status, sizes = header
        data = connection.recv_bytes()
        buffers = []
        for size in sizes:
            buffer = bytearray(size)
            if size:
                connection.recv_bytes_into(buffer)
            else:
                connection.recv_bytes()
            buffers.append(buffer)
        value = pickle.loads(data, buffers=buffers)
        if status == "ok":
            return value
        kind, message, details = value
        raise JobFailed("error", f"{kind}: {message}", details)

    def _ensure_process(self):
        with self._lock:
            if self._process is not None and self._process.is_alive() and self._connection is not None:
                return self._connection
        self._end_process()
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(list(PRELOAD))
        ours, theirs = context.Pipe(duplex=True)
        process = context.Process(target=_serve, args=(theirs, self._warm_up), name=f"{self.name}-worker",
                                  daemon=True)
        process.start()
        theirs.close()
        with self._lock:
            self._process, self._connection = process, ours
            self.started += 1
        if self._closed:  # close() ran meanwhile
            self._end_process()
            raise JobFailed("closed", f"{self.name}: shut down")
        try:  # the worker says when it is warmed up; only then do jobs' deadlines start
            ready = ours.poll(START_TIMEOUT_S) and ours.recv_bytes() == _READY
        except (EOFError, OSError):
            ready = False
        if not ready:
            code = self._end_process()
            if self._closed:
                raise JobFailed("closed", f"{self.name}: shut down")
            raise JobFailed("died", f"its worker process did not start ({_exit_text(code)})")
        return ours

    def _end_process(self) -> int | None:
        """Kill the worker (if any) and reap it; its exit code (None if there was none)."""
        with self._lock:
            process, connection = self._process, self._connection
            self._process = self._connection = None
        if connection is not None:
            try:
                connection.close()
            except OSError:
                pass
        if process is None:
            return None
        if process.is_alive():
            try:
                os.kill(process.pid, signal.SIGKILL)
            except OSError:
                pass
        process.join(REAP_TIMEOUT_S)
        return process.exitcode


_CLOSE = object()


def _exit_text(code: int | None) -> str:
    if code is None:
        return "exit status unknown"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


# ---- the worker's side -----------------------------------------------------------------------------------------

def _serve(connection, warm_up) -> None:
    """The worker process: jobs from ``connection`` until it closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the node decides when to stop (close() kills this process)
    _die_with_parent()
    # The worker starts no process of its own.  With "fork" as its start method the named semaphores made in it
    # (numba's thread-pool lock, when a flock's state is built) are unlinked at once instead of registered with
    # the node's resource tracker, so a worker ended by SIGKILL leaves none behind (the tracker warned of a
    # "leaked semaphore" at the node's exit).
    multiprocessing.set_start_method("fork", force=True)
    try:
        os.nice(WORKER_NICE)
    except OSError:
        pass
    if warm_up is not None:
        try:
            warm_up()
        except Exception:  # noqa: BLE001 - a job will meet (and report) whatever failed here
            pass
    try:
        connection.send_bytes(_READY)
    except (EOFError, OSError):
        return
    while True:
        try:
            request = connection.recv_bytes()
        except (EOFError, OSError):
            return
        try:
            fn, args = pickle.loads(request)
            result, status = fn(*args), "ok"
        except BaseException as exc:  # noqa: BLE001 - every error of a job is its answer
            result = (type(exc).__name__, str(exc)[:2000], traceback.format_exc()[-8000:])
            status = "error"
        try:
            _send(connection, status, result)
        except (EOFError, OSError):
            return
        except Exception as exc:  # noqa: BLE001 - a result that does not pickle is the job's error
            _send(connection, "error", (type(exc).__name__, f"its result cannot be sent: {exc}"[:2000],
                                        traceback.format_exc()[-8000:]))
        del result


def _send(connection, status: str, value) -> None:
    buffers: list[pickle.PickleBuffer] = []
    data = pickle.dumps(value, protocol=5, buffer_callback=buffers.append)
    raws = [b.raw() for b in buffers]
    connection.send_bytes(pickle.dumps((status, [r.nbytes for r in raws])))
    connection.send_bytes(data)
    for raw in raws:
        connection.send_bytes(raw)


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent (the fork server, which ends with the node) ends."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: close() and the pipe's end still end it
        pass
    if os.getppid() == 1:  # the parent already went before the request took effect
        exit_now(0)
