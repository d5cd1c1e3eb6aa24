"""Recording to rosbag2-style MCAP bags, off the caller's thread and crash-safe.

A bag is a directory ``<dir>/`` holding ``<name>_0.mcap``, ``<name>_1.mcap`` … (``<name>`` = the directory's
name, as rosbag2 names them) and ``metadata.yaml``.  What is written, and why:

Files
    MCAP written with the ``mcap`` library's :class:`mcap.writer.Writer`: profile ``ros2``; one schema per type,
    named ``pkg/msg/Type``, encoding ``ros2msg``, data = the concatenated definition of
    :func:`cgp_sim_ros.wire.schemas.message_definition`; one channel per topic, message encoding ``cdr``, metadata
    ``offered_qos_profiles`` (YAML, :func:`~cgp_sim_ros.wire.schemas.offered_qos_profiles_yaml`) and
    ``topic_type_hash`` (``RIHS01_…``); chunked and compressed (lz4 by default, see ``benchmarks/bench_bag.py``)
    with message indexes, chunk indexes, statistics and summary offsets; before the summary a ``rosbag2``
    metadata record ``{"serialized_metadata": <the bag's metadata as YAML>}`` as rosbag2's MCAP plugin writes it
    when it closes a file.  Message ``sequence`` = a per-topic counter from 1 (gaps would show lost messages).
    (mcap-python's chunked writer puts a topic's schema and channel records in the chunk of its first message,
    so a recording killed before a topic's first chunk has no definition for it; a closed file has all of
    them in its summary.)

metadata.yaml
    ``rosbag2_bagfile_information`` version 9 (what Jazzy writes; rosbags reads versions up to 9): storage
    ``mcap``, ``relative_file_paths``, ``files`` (path, starting time, duration, count), ``duration``,
    ``starting_time``, ``message_count``, ``topics_with_message_count`` (name, type, ``cdr``, QoS as a YAML
    list, type hash), ``compression_format``/``compression_mode`` empty (MCAP compresses chunks itself: these
    fields are for rosbag2's file/message compression), ``custom_data``, ``ros_distro``.  It exists from the
    start and is rewritten when a topic is added, when a file rolls, at most every ``sync_interval_s`` while
    recording, and at close; it always describes what is committed in the files (never more).

Times
    ``write(topic, data, log_time_ns, publish_time_ns)`` stores the times it is given; the node passes sim time
    for both, so a replay's messages line up with the recorded ``/clock``.  Readers that scan a file without
    index (rosbags on a file cut by a crash) require log times in non-decreasing write order.

Threading
    ``write`` appends to a queue and returns (about a microsecond; no lock on the common path); one writer
    thread owns the MCAP writer and the files, so messages are written exactly in ``write`` order.  The queue
    is bounded by ``max_queue_bytes`` (payload bytes waiting).  At the bound, ``on_queue_full="block"``
    (default) makes ``write`` wait for the writer: the simulation slows down instead of losing data (the bag
    stays complete and, being stamped in sim time, stays correct; the node's "falling behind" warning shows
    it).  If the writer makes no progress for ``block_timeout_s`` the disk is declared stalled: the error is
    reported and the writer switches to dropping.  ``on_queue_full="drop"`` drops the new message instead and
    counts it (``dropped_messages``); the first drop is reported through the error callback.

Faults
    - ``close()`` (the node calls it on SIGINT / SIGTERM) finishes the file: metadata record, summary, footer,
      ``metadata.yaml``.  Call it from normal program flow, or from a signal handler that runs in the main thread
      (it does not share a lock with ``write``).
    - SIGKILL: chunks are finished when they reach ``chunk_size`` bytes or ``chunk_interval_s`` seconds and are
      committed to the OS at once, each commit followed by a *provisional end of file* (a DataEnd record, a
      Footer without summary, the magic) that the next commit overwrites.  So between commits the file is
      always a complete, summary-less MCAP: mcap's readers and rosbags (which needs a valid footer) read
      every committed chunk of a killed recording; the loss is bounded by ``chunk_interval_s`` plus what was
      queued.
    - Power loss: the file and ``metadata.yaml`` are fsync'ed at most every ``sync_interval_s`` (and the
      directory when files are created), bounding the loss to about ``chunk_interval_s + sync_interval_s``.
      The periodic fsync runs on a thread of its own, so the writer thread goes on taking messages meanwhile.
      A commit cut by power loss leaves a torn tail that rosbags cannot open; :func:`recover_bag` rewrites such
      files from every intact chunk (like ``mcap recover`` / ``ros2 bag reindex``).
    - Disk full, unwritable directory, any I/O error: never raised into ``write`` (nor the constructor): the
      first error is stored in :attr:`BagWriter.error` and passed once to ``on_error``; the file is put back to
      its last committed state if possible; later messages are dropped and counted; ``write`` returns False.
    - An existing, non-empty directory is refused (:class:`BagExistsError` from the constructor), as
      ``ros2 bag record`` refuses to overwrite a bag.

Splitting
    As rosbag2 does: before writing a message, the file is closed and ``<name>_<i+1>.mcap`` opened if the file
    has reached ``max_bytes`` (bytes committed to it, so files overshoot by up to one chunk, like rosbag2's MCAP
    plugin) or if the message's log time is more than ``max_duration_s`` after the file's first message.
    Every file carries all topics' schemas and channels.
"""

from __future__ import annotations

import atexit
import os
import queue
import re
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mcap import __version__ as _MCAP_VERSION
from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer
from mcap.writer import MCAP0_MAGIC, CompressionType, IndexType, Writer

from . import schemas

__all__ = ["BagWriter", "BagOptions", "BagExistsError", "recover_bag", "METADATA_VERSION", "COMPRESSIONS"]

#: rosbag2 metadata version written (Jazzy's; rosbags reads <= 9).
METADATA_VERSION = 9
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
_QUEUE_POLICIES = ("block", "drop")
_NS_PER_S = 1_000_000_000
_POLL_S = 0.005  # writer thread's queue polling period (see BagWriter._run)
_HOLD_MAX_S = 0.25  # a hold (BagWriter.hold) older than this is ignored: a caller that never said wake()
_TOPIC_NAME = re.compile(r"^/?[A-Za-z~{][A-Za-z0-9_/{}~]*$")


class BagExistsError(FileExistsError):
    """The bag directory already exists and is not empty."""


def _provisional_tail() -> bytes:
    """DataEnd + Footer (no summary) + magic, built with the mcap library's own record writers."""
    builder = RecordBuilder()
    DataEnd(data_section_crc=0).write(builder)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
    return bytes(builder.end()) + MCAP0_MAGIC


_TAIL = _provisional_tail()
_LIBRARY = f"cgp_sim_ros.wire.bag; mcap-python/{_MCAP_VERSION}"


class _CommittingFile:
    """The stream handed to ``mcap.writer.Writer``: it buffers what the writer emits and, on :meth:`commit`,
    writes the buffer and a provisional end of file with one ``pwrite`` at the committed offset, so the
    previous provisional end is overwritten by the new data and the file on disk is always a complete MCAP.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self.committed = 0  # bytes of real data on disk; the provisional tail follows them
        self.pending = bytearray()

    # --- the file-like interface mcap.Writer uses
    def write(self, data) -> int:
        self.pending += data
        return len(data)

    def tell(self) -> int:
        return self.committed + len(self.pending)

    def flush(self) -> None:  # commits are explicit (the writer thread decides when)
        pass

    # --- commits
    def _pwrite_all(self, data: bytes, offset: int) -> None:
        view = memoryview(data)
        while view:
            written = os.pwrite(self.fd, view, offset)
            if written <= 0:  # pragma: no cover - pwrite raises rather than returning 0 on errors
                raise OSError(f"short write to {self.path}")
            view = view[written:]
            offset += written

    def commit(self, final: bool = False) -> None:
        """Write the pending bytes (and, unless ``final``, the provisional tail after them)."""
        if not self.pending and not final:
            return
        buffers = [self.pending] if final else [self.pending, _TAIL]
        total = len(self.pending) + (0 if final else len(_TAIL))
        written = os.pwritev(self.fd, buffers, self.committed)
        if written < total:  # short write (e.g. the disk just filled up): retry the rest, or raise
            self._pwrite_all(b"".join(buffers)[written:], self.committed + written)
        self.committed += len(self.pending)
        self.pending.clear()
        if final:
            os.ftruncate(self.fd, self.committed)

    def restore_last_commit(self) -> None:
        """After a failed commit: drop the pending bytes and put back the provisional tail after the last
        committed data (overwriting blocks the file already has, so it works on a full disk too)."""
        self.pending.clear()
        self._pwrite_all(_TAIL, self.committed)
        os.ftruncate(self.fd, self.committed + len(_TAIL))

    def sync(self) -> None:
        os.fsync(self.fd)

    def close(self) -> None:
        if self.fd >= 0:
            fd, self.fd = self.fd, -1
            os.close(fd)


@dataclass
class _Topic:
    name: str
    type: str
    qos_dicts: list
    qos_yaml: str
    type_hash: str
    schema_text: bytes
    sequence: int = 0
    added: int = 0  # messages handed to the MCAP writer (all files)
    committed: int = 0  # of which committed to disk


@dataclass
class _FileStats:
    path: str
    added: int = 0
    start: int | None = None
    end: int | None = None
    committed: tuple = (0, None, None)  # (count, start, end) as of the last commit

    def snapshot(self) -> None:
        self.committed = (self.added, self.start, self.end)


@dataclass
class _Control:
    kind: str  # "topic" | "flush" | "close"
    payload: object = None
    done: threading.Event = field(default_factory=threading.Event)


def bag_path_occupied(path: Path) -> bool:
    """True if ``path`` exists and is not an empty directory: a bag is never written there (it would mix two
    runs).  Raises ``OSError`` for a path that cannot be examined (a name longer than NAME_MAX, ...)."""
    return path.exists() and (not path.is_dir() or any(path.iterdir()))


@dataclass(frozen=True)
class BagOptions:
    """How a :class:`BagWriter` writes: compression and chunking, file splitting, the bound on what waits for
    the writer thread and what happens at it, fsync, the writer thread's priority.  The defaults are what the
    node records with.  Checked on construction (a ``ValueError`` naming the option).

    compression: ``"lz4"`` (default), ``"zstd"`` or ``"none"``: MCAP chunk compression.  lz4 is the
        default because it keeps the 15k-boid tick budget: zstd (level 3, mcap-python's fixed level)
        compresses this float data 1.4x instead of 1.1x but costs ~3x the CPU and barely keeps up with
        the ~87 MB/s of a 15k-boid scene on this 2-core machine (``benchmarks/bench_bag.py``).
    chunk_size: a chunk is finished once it holds this many (uncompressed) bytes.
    chunk_interval_s: ... or once its first message is this old (wall time): bounds what a kill loses.
    max_bytes: split to a new file once the current one has this many bytes (0 = no limit).
    max_duration_s: split once a message's log time is this far past the file's first (0 = no limit).
    max_queue_bytes: bound on payload bytes waiting for the writer thread.
    on_queue_full: ``"block"`` (wait; default) or ``"drop"`` (drop and count) at the bound.
    block_timeout_s: with ``"block"``: a writer without progress for this long is declared stalled.
    sync_interval_s: fsync file + metadata.yaml at most this often (None: never fsync).
    ros_distro: ``ros_distro`` of metadata.yaml.
    writer_nice: how much lower the writer thread's CPU priority is than the caller's (Linux ``nice``
        increment for that thread alone; 0: the same).  The writer has slack — a bounded queue, and the
        idle core during the caller's serial Python — while the simulation's compiled kernels want both
        cores for a few milliseconds at a time: a writer that takes a core then (lz4 on a 1 MB chunk,
        ~2 ms) makes the kernel wait for its delayed half.  A lower priority lets the kernels have the
        cores when they run and the writer catch up in between; nothing is lost (``on_queue_full``).
        Measured on the 15k-fish tick (three alternating runs each): p99 / tick CPU 1.46-1.70 at 10
        against 1.63-1.71 at 0 — within this machine's run-to-run noise — and the bag kept up (queue at
        most 3.6 MB, nothing dropped).
    hold_bytes: while the caller holds the writer (:meth:`BagWriter.hold`: a real-time tick is running), the
        writer takes nothing from the queue until :meth:`BagWriter.wake` — unless this many bytes are waiting (then it
        works beside the caller, as without a hold, so that a caller that never leaves it time cannot make
        the queue grow without bound).
    """

    compression: str = "lz4"
    chunk_size: int = 1024 * 1024
    chunk_interval_s: float = 0.5
    max_bytes: int = 0
    max_duration_s: float = 0.0
    max_queue_bytes: int = 256 * 1024 * 1024
    on_queue_full: str = "block"
    block_timeout_s: float = 10.0
    sync_interval_s: float | None = 1.0
    ros_distro: str = "jazzy"
    writer_nice: int = 10
    hold_bytes: int = 16 * 1024 * 1024

    def __post_init__(self) -> None:
        if self.compression not in COMPRESSIONS:
            raise ValueError(f"compression={self.compression!r}: expected one of {sorted(COMPRESSIONS)}")
        if self.on_queue_full not in _QUEUE_POLICIES:
            raise ValueError(f"on_queue_full={self.on_queue_full!r}: expected one of {_QUEUE_POLICIES}")
        for name in ("chunk_size", "max_queue_bytes", "hold_bytes"):
            if int(getattr(self, name)) <= 0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0")
        for name in ("chunk_interval_s", "block_timeout_s"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0 seconds")
        if int(self.max_bytes) < 0 or float(self.max_duration_s) < 0:
            raise ValueError(f"max_bytes={self.max_bytes} and max_duration_s={self.max_duration_s} must be >= 0 "
                             f"(0 = no splitting)")
        if self.sync_interval_s is not None and float(self.sync_interval_s) < 0:
            raise ValueError(f"sync_interval_s={self.sync_interval_s} must be >= 0 or None")


class BagWriter:
    """Writes a rosbag2-style MCAP bag directory from already-serialized CDR messages.

    ``add_topic`` / ``write`` / ``flush`` / ``close`` are meant to be called from one thread (the node's
    stepping thread); the writer thread is internal.

    Args:
        path: the bag directory (created; must not exist or be empty).
        options: how it is written (:class:`BagOptions`; the defaults if None).
        on_error: called once, with a message, on the first error (from the writer thread or the caller).
        custom_data: ``custom_data`` of metadata.yaml (str -> str).
    """

    def __init__(self, path, options: BagOptions | None = None, *, on_error: Callable[[str], None] | None = None,
                 custom_data: dict | None = None) -> None:
        options = BagOptions() if options is None else options
        if custom_data is not None and not all(isinstance(k, str) and isinstance(v, str)
                                               for k, v in custom_data.items()):
            raise ValueError("custom_data must map str to str")

        self.path = Path(path)
        try:
            occupied = bag_path_occupied(self.path)
            path_error = None
        except OSError as exc:  # e.g. a name longer than NAME_MAX: an I/O error like any other (below)
            occupied, path_error = False, exc
        if occupied:
            raise BagExistsError(f"bag directory {str(self.path)!r} already exists and is not empty (or is not "
                                 f"a directory); refusing to overwrite a bag (choose a new directory)")
        self._name = self.path.resolve().name or "bag"
        self._compression = COMPRESSIONS[options.compression]
        self._chunk_size = int(options.chunk_size)
        self._chunk_interval = float(options.chunk_interval_s)
        self._max_bytes = int(options.max_bytes)
        self._max_duration_ns = int(float(options.max_duration_s) * _NS_PER_S)
        self._max_queue_bytes = int(options.max_queue_bytes)
        self._drop_when_full = options.on_queue_full == "drop"
        self._block_timeout = float(options.block_timeout_s)
        self._sync_interval = None if options.sync_interval_s is None else float(options.sync_interval_s)
        self._on_error = on_error
        self._custom_data = dict(custom_data or {})
        self._ros_distro = options.ros_distro
        self._writer_nice = int(options.writer_nice)
        self._hold_bytes = min(int(options.hold_bytes), self._max_queue_bytes // 2)

        # Caller-side state (only the caller thread writes these).
        self._topics: dict[str, _Topic] = {}
        self._enqueued_bytes = 0
        self._dropped_caller = 0
        self._closing = False
        # Writer-side state (only the writer thread writes these).
        self._drained_bytes = 0
        self._dropped_writer = 0
        self._failed = False
        self._written = 0
        self._committed_messages = 0
        self._max_backlog = 0
        # Shared.
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._space = threading.Event()
        self._waiting = False
        self._error: str | None = None
        self._error_lock = threading.Lock()
        self._gate = threading.Event()  # test seam: cleared = a disk that does not keep up
        self._gate.set()
        self._wake = threading.Event()  # see wake()
        self._held_since: float | None = None  # see hold(): written by the caller, read by the writer thread
        self._urgent = 0  # callers waiting for the writer (flush): a hold does not apply

        # Files and the topics they carry (owned by the writer thread once it runs).
        self._recorded_topics: list[_Topic] = []
        self._files: list[_FileStats] = []
        self._file: _CommittingFile | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._chunk_opened_at: float | None = None
        self._last_sync = time.monotonic()
        self._metadata_stale = False  # a topic was added since metadata.yaml was last written
        self._housekeeping_due = False  # a commit since the last _housekeep
        # The periodic fsync runs on a thread of its own (_sync_in_background); metadata.yaml is written by
        # both threads, in the order its texts were made (_store_metadata_yaml).
        self._sync_thread: threading.Thread | None = None
        self._sync_jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._sync_idle = threading.Event()
        self._sync_idle.set()
        self._sync_error: OSError | None = None
        self._yaml_lock = threading.Lock()
        self._yaml_made = 0  # texts of metadata.yaml made (writer thread)
        self._yaml_stored = 0  # the number of the newest text on disk
        self._thread: threading.Thread | None = None

        try:
            if path_error is not None:
                raise path_error
            self.path.mkdir(parents=True, exist_ok=True)
            self._open_file()
            self._write_metadata_yaml(sync=True)
            self._sync_directory()
        except OSError as exc:
            self._fail(f"cannot record the bag in {str(self.path)!r}: {exc.strerror or exc} "
                       f"({type(exc).__name__}); recording is off, the simulation goes on")
            return
        self._thread = threading.Thread(target=self._run, name=f"bag-writer:{self._name}", daemon=True)
        self._thread.start()
        # A program that ends without close() (an exception in the node, sys.exit) still finishes the bag.
        atexit.register(self.close)

    # ------------------------------------------------------------------------------------ public API
    @property
    def error(self) -> str | None:
        """The first error (disk full, unwritable directory, stalled writer…), or None."""
        return self._error

    @property
    def dropped_messages(self) -> int:
        """Messages given to :meth:`write` that will not be in the bag: rejected (queue full with ``"drop"``,
        after an error) or lost with a failed commit.  ``write`` calls = messages in the bag + this."""
        return self._dropped_caller + self._dropped_writer

    @property
    def written_messages(self) -> int:
        """Messages handed to the MCAP writer (after an I/O error: those committed before it)."""
        return self._written

    @property
    def committed_messages(self) -> int:
        """Messages in chunks committed to the files (what a reader sees if the process dies now)."""
        return self._committed_messages

    @property
    def queued_bytes(self) -> int:
        """Payload bytes waiting for the writer thread."""
        return self._enqueued_bytes - self._drained_bytes

    @property
    def max_queued_bytes(self) -> int:
        """High-water mark of :attr:`queued_bytes` seen by the writer thread."""
        return self._max_backlog

    @property
    def files(self) -> list[Path]:
        return [self.path / f.path for f in self._files]

    def add_topic(self, name: str, type_name: str, qos=None, *, qos_as_discovered: bool = True) -> None:
        """Declare a topic before writing to it.

        Args:
            name: topic name as recorded (fully qualified, e.g. ``/cgp_sim/bodies/poses``).
            type_name: ``pkg/msg/Type`` (``pkg/Type`` is accepted and normalized).
            qos: the rclpy ``QoSProfile`` (or a list of them) the topic is published / subscribed with;
                None = no profile (``[]``).
            qos_as_discovered: write the profile as rosbag2 would see it through the ROS graph (see
                :func:`cgp_sim_ros.wire.schemas.qos_profile_dict`).
        Raises ValueError / FileNotFoundError for a bad name or an unknown type (a programming error).
        """
        if not isinstance(name, str) or not _TOPIC_NAME.match(name):
            raise ValueError(f"topic name {name!r} is not a valid ROS topic name")
        package, kind, short = schemas.normalize_type_name(type_name)
        full_type = f"{package}/{kind}/{short}"
        if name in self._topics:
            if self._topics[name].type != full_type:
                raise ValueError(f"topic {name!r} was added as {self._topics[name].type}, not {full_type}")
            return
        profiles = [] if qos is None else (list(qos) if isinstance(qos, (list, tuple)) else [qos])
        qos_dicts = [schemas.qos_profile_dict(p, qos_as_discovered) for p in profiles]
        topic = _Topic(name=name, type=full_type, qos_dicts=qos_dicts, qos_yaml=schemas.dump_yaml(qos_dicts),
                       type_hash=schemas.type_hash(full_type),
                       schema_text=schemas.message_definition(full_type).encode("utf-8"))
        self._topics[name] = topic
        if self._thread is not None:
            self._queue.put(_Control("topic", topic))

    def set_custom_data(self, custom_data: dict) -> None:
        """Replace ``custom_data`` (str -> str) for the metadata written from now on (``metadata.yaml`` at the
        next commit, each file's rosbag2 record when it is finished)."""
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in custom_data.items()):
            raise ValueError("custom_data must map str to str")
        self._custom_data = dict(custom_data)  # a new dict: the writer thread reads whichever is current

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> bool:
        """Queue one serialized message; returns at once.  True if queued, False if dropped (error, full
        queue with ``"drop"``, or closed).  Never raises for I/O problems."""
        state = self._topics.get(topic)
        if state is None:
            raise KeyError(f"topic {topic!r} was not added to the bag (call add_topic first)")
        if type(data) is not bytes:
            raise TypeError(f"data must be bytes (immutable: the writer thread keeps it), got "
                            f"{type(data).__name__}")
        if self._closing or self._thread is None or self._failed:
            if not self._closing:
                self._dropped_caller += 1
            return False
        size = len(data)
        backlog = self._enqueued_bytes - self._drained_bytes
        if backlog + size > self._max_queue_bytes and backlog > 0 and not self._make_room(size):
            return False
        self._enqueued_bytes += size
        self._queue.put((state, data, int(log_time_ns),
                         int(log_time_ns if publish_time_ns is None else publish_time_ns)))
        return True

    def hold(self) -> None:
        """The caller starts a burst of work that wants both cores (a real-time tick): until :meth:`wake`, the
        writer thread takes nothing from the queue, so that its work — Python framing under the GIL, lz4 on a
        core the tick's parallel kernels want — falls into the time the caller sleeps before its next tick.
        Bounded: with ``hold_bytes`` waiting, or a hold older than 0.25 s (a caller that never woke it), the
        writer works anyway; :meth:`flush` and :meth:`close` are never held.  Measured on the 15k-fish scene
        at 60 Hz in real time: without a hold, 1.06 ms of the writer's ~2 ms of work per tick fell inside the
        ticks (its 5 ms poll finds a tick's first messages while the tick runs), with it 0.29 ms (a chunk it
        started between ticks may run into the next).  What that does to the tick's p99 was within this
        machine's run-to-run noise (alternating runs: p99 15.0-19.1 ms held, 16.0-20.8 not)."""
        self._held_since = time.monotonic()

    def wake(self) -> None:
        """Have the writer thread take what is queued now, instead of at its next poll (<= 5 ms later), and
        end a :meth:`hold`.  A real-time caller calls it once per tick, after the tick's writes: the writer then
        does its work while the caller sleeps until its next tick."""
        self._held_since = None
        self._wake.set()

    def _holding(self) -> bool:
        """Writer thread: should it leave the queue alone for now (see :meth:`hold`)?"""
        since = self._held_since
        return (since is not None and not self._closing and not self._urgent
                and time.monotonic() - since < _HOLD_MAX_S
                and self._enqueued_bytes - self._drained_bytes < self._hold_bytes)

    def flush(self, timeout: float | None = None) -> bool:
        """Finish the current chunk and commit everything written so far; True when done in time."""
        if self._thread is None or not self._thread.is_alive():
            return False
        control = _Control("flush")
        self._urgent += 1
        try:
            self._queue.put(control)
            self._wake.set()
            return control.done.wait(timeout)
        finally:
            self._urgent -= 1

    def close(self, timeout: float | None = None) -> None:
        """Finish the bag: write what is queued, the metadata record, the summary, metadata.yaml.
        Idempotent; returns when the writer thread has finished (or after ``timeout`` seconds)."""
        if self._closing:
            if self._thread is not None:
                self._thread.join(timeout)
            return
        self._closing = True
        if self._thread is not None:
            atexit.unregister(self.close)
            self._queue.put(_Control("close"))
            self._space.set()
            self._thread.join(timeout)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------- queue bound
    def _make_room(self, size: int) -> bool:
        """At the bound: drop (policy "drop") or wait for the writer.  False = the message is dropped."""
        if self._drop_when_full:
            self._dropped_caller += 1
            if self._dropped_caller == 1:
                self._report(f"bag writer cannot keep up: queue full ({self._max_queue_bytes} bytes waiting); "
                             f"dropping messages (on_queue_full='drop')")
            return False
        deadline = time.monotonic() + self._block_timeout
        progress = self._drained_bytes
        self._waiting = True
        try:
            while self._enqueued_bytes - self._drained_bytes + size > self._max_queue_bytes \
                    and self._enqueued_bytes != self._drained_bytes:
                if self._failed or self._closing:
                    self._dropped_caller += 1
                    return False
                self._space.clear()
                if self._enqueued_bytes - self._drained_bytes + size <= self._max_queue_bytes:
                    break
                self._space.wait(0.05)
                if self._drained_bytes != progress:
                    progress = self._drained_bytes
                    deadline = time.monotonic() + self._block_timeout
                elif time.monotonic() > deadline:
                    self._drop_when_full = True
                    self._dropped_caller += 1
                    self._report(f"bag writer stalled: no progress for {self._block_timeout:g} s with "
                                 f"{self._enqueued_bytes - self._drained_bytes} bytes queued; dropping "
                                 f"messages from now on")
                    return False
        finally:
            self._waiting = False
        return True

    # ------------------------------------------------------------------------------ error handling
    def _report(self, message: str) -> None:
        with self._error_lock:
            first = self._error is None
            if first:
                self._error = message
        if first and self._on_error is not None:
            try:
                self._on_error(message)
            except Exception:  # noqa: BLE001 - a failing logger must not stop the recording
                pass

    def _fail(self, message: str) -> None:
        self._failed = True
        self._report(message)

    def _fail_io(self, exc: OSError, doing: str) -> None:
        # Messages handed to the MCAP writer but not committed are lost with the failed commit.
        self._dropped_writer += self._written - self._committed_messages
        self._written = self._committed_messages
        where = self._file.path if self._file is not None else self.path
        self._fail(f"bag recording stopped: {doing} {str(where)!r} failed: {exc.strerror or exc} "
                   f"({type(exc).__name__}); the recording keeps what was committed before, the simulation "
                   f"goes on")
        if self._file is not None:
            try:
                self._file.restore_last_commit()
                self._file.sync()
            except OSError:
                pass

    # --------------------------------------------------------------------------------- file handling
    def _open_file(self) -> None:
        index = len(self._files)
        rel = f"{self._name}_{index}.mcap"
        self._file = _CommittingFile(self.path / rel)
        self._files.append(_FileStats(rel))
        self._writer = Writer(self._file, chunk_size=self._chunk_size, compression=self._compression,
                              index_types=IndexType.ALL, repeat_channels=True, repeat_schemas=True,
                              use_chunking=True, use_statistics=True, use_summary_offsets=True)
        self._writer.start(profile="ros2", library=_LIBRARY)
        self._channels = {}
        self._schemas = {}
        for topic in self._recorded_topics:
            self._register(topic)
        self._file.commit()  # header on disk: an empty but valid MCAP
        self._chunk_opened_at = None

    def _register(self, topic: _Topic) -> None:
        schema_id = self._schemas.get(topic.type)
        if schema_id is None:
            schema_id = self._writer.register_schema(topic.type, "ros2msg", topic.schema_text)
            self._schemas[topic.type] = schema_id
        self._channels[topic.name] = self._writer.register_channel(
            topic.name, "cdr", schema_id,
            {"offered_qos_profiles": topic.qos_yaml, "topic_type_hash": topic.type_hash})

    def _finish_file(self) -> None:
        """Last chunk, metadata record, summary, footer; fsync; close."""
        self._writer.flush()  # the last chunk first: the rosbag2 record comes after all the data
        self._writer.add_metadata("rosbag2", {"serialized_metadata": schemas.dump_yaml(
            self._metadata(final_file=True))})
        self._writer.finish()
        self._file.commit(final=True)
        self._commit_bookkeeping()
        if self._sync_interval is not None:
            self._file.sync()
        self._file.close()

    def _commit(self) -> None:
        self._file.commit()
        self._commit_bookkeeping()
        self._housekeeping_due = True  # done by the writer loop, between the caller's ticks (_housekeep)

    def _housekeep(self) -> None:
        """After commits: the fsync every ``sync_interval_s`` (handed to the sync thread with its metadata.yaml:
        :meth:`_sync_in_background`), or metadata.yaml alone (every second without sync, or when a topic was
        added: ~2 ms of Python holding the GIL).  The writer loop calls it only while the caller does not hold
        the writer (:meth:`hold`).  Done inside the commit, as before, the fsync (~14 ms, ~2 ms of it CPU in the
        kernel) and metadata.yaml were what the 15k-fish scene's slowest real-time ticks were made of: the
        slowest 2 % of ticks had ~4.5 ms of the writer's work inside them against 0.3 ms on average."""
        self._housekeeping_due = False
        now = time.monotonic()
        if self._sync_interval is not None and now - self._last_sync >= self._sync_interval:
            if self._sync_idle.is_set():  # else the last one is still at it: the next commit tries again
                self._sync_in_background()
                self._last_sync = now
        elif (self._sync_interval is None and now - self._last_sync >= 1.0) or self._metadata_stale:
            self._write_metadata_yaml(sync=False)
            if self._sync_interval is None:
                self._last_sync = now

    def _commit_bookkeeping(self) -> None:
        self._files[-1].snapshot()
        for topic in self._recorded_topics:
            topic.committed = topic.added
        self._committed_messages = self._written
        self._chunk_opened_at = None

    def _roll(self) -> None:
        self._finish_file()
        self._open_file()
        self._write_metadata_yaml(sync=self._sync_interval is not None)
        self._sync_directory()

    def _sync_directory(self) -> None:
        if self._sync_interval is None:
            return
        fd = os.open(self.path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    # ------------------------------------------------------------------------------------- metadata
    def _metadata(self, final_file: bool = False) -> dict:
        """rosbag2's BagMetadata of what is committed (plus the file being finished, if ``final_file``)."""
        files = []
        total, start, end = 0, None, None
        for stats in self._files:
            count, f_start, f_end = ((stats.added, stats.start, stats.end)
                                     if final_file and stats is self._files[-1] else stats.committed)
            files.append({"path": stats.path,
                          "starting_time": {"nanoseconds_since_epoch": f_start or 0},
                          "duration": {"nanoseconds": (f_end - f_start) if count else 0},
                          "message_count": count})
            total += count
            if count:
                start = f_start if start is None else min(start, f_start)
                end = f_end if end is None else max(end, f_end)
        return {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": (end - start) if total else 0},
            "starting_time": {"nanoseconds_since_epoch": start if total else 0},
            "message_count": total,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.type, "serialization_format": "cdr",
                                    "offered_qos_profiles": t.qos_dicts, "type_description_hash": t.type_hash},
                 "message_count": t.added if final_file else t.committed}
                for t in self._recorded_topics],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [f.path for f in self._files],
            "files": files,
            "custom_data": dict(self._custom_data) or None,
            "ros_distro": self._ros_distro,
        }

    def _write_metadata_yaml(self, sync: bool) -> None:
        self._store_metadata_yaml(*self._metadata_yaml(), sync=sync)

    def _metadata_yaml(self) -> tuple[str, int]:
        """Writer thread: metadata.yaml's text for what is committed now, and its number."""
        self._metadata_stale = False
        self._yaml_made += 1
        return schemas.dump_yaml({"rosbag2_bagfile_information": self._metadata()}) + "\n", self._yaml_made

    def _store_metadata_yaml(self, text: str, number: int, sync: bool) -> None:
        """Replace metadata.yaml with ``text`` (atomically: a temporary file renamed over it) unless a newer
        text is on disk already (the writer and the sync thread both store texts).

        On a full disk the temporary file cannot be written (issue 27: a split bag's metadata.yaml then kept
        counting 222 messages where the files held 277, and an empty metadata.yaml.tmp stayed behind): the
        temporary file is removed and metadata.yaml is overwritten in place instead, in the blocks it already
        has — which is why every stored text is padded (a YAML comment) to METADATA_SLACK bytes more than it
        needs: the final text, with a file more and larger counts, still fits."""
        with self._yaml_lock:
            if number < self._yaml_stored:
                return
            data = _padded(text)
            final = self.path / "metadata.yaml"
            tmp = self.path / "metadata.yaml.tmp"
            try:
                with open(tmp, "wb") as f:
                    f.write(data)
                    if sync:
                        f.flush()
                        os.fsync(f.fileno())
                os.replace(tmp, final)
            except OSError:
                try:
                    tmp.unlink()
                except OSError:
                    pass
                if not _overwrite_in_place(final, text, sync):
                    raise
            self._yaml_stored = number

    def _sync_in_background(self) -> None:
        """Writer thread: have the sync thread fsync the file as committed now, then store (and fsync) the
        metadata.yaml of that state — so a metadata.yaml on disk never counts messages its file may lack.  An
        fsync takes ~14 ms here (the kernel writes a second of recording out), during which a writer that did it
        itself took no messages, and caught up inside the caller's next tick.  Measured on the 15k-fish scene at
        60 Hz in real time, alternating runs: tick p99 15.0-18.4 ms with the fsync on the writer thread,
        13.2-15.6 ms on the sync thread, 13.6-15.5 ms with no fsync at all."""
        if self._sync_thread is None:
            self._sync_thread = threading.Thread(target=self._run_syncs, name=f"bag-sync:{self._name}", daemon=True)
            self._sync_thread.start()
        self._sync_idle.clear()
        self._sync_jobs.put((os.dup(self._file.fd), *self._metadata_yaml()))  # the dup outlives a roll's close

    def _run_syncs(self) -> None:
        self._lower_priority()
        while True:
            job = self._sync_jobs.get()
            if job is None:
                return
            fd, text, number = job
            try:
                os.fsync(fd)
                self._store_metadata_yaml(text, number, sync=True)
            except OSError as exc:
                self._sync_error = exc  # reported by the writer thread (_run)
            finally:
                os.close(fd)
                self._sync_idle.set()

    def _stop_syncs(self) -> None:
        """Writer thread, at the end: wait for the sync in progress and end the sync thread."""
        if self._sync_thread is not None:
            self._sync_jobs.put(None)
            self._sync_thread.join(self._block_timeout)
            self._sync_thread = None

    # ---------------------------------------------------------------------------------- writer thread
    def _run(self) -> None:
        # The thread polls the queue instead of blocking on it: a blocked reader would be woken by the
        # caller's first put of each tick, which costs that write() ~35 µs (futex wake-up and GIL hand-over,
        # measured); polling every _POLL_S keeps every write() at ~1 µs and delays the bag by a few ms.  A caller
        # that knows when its burst of writes is over says so with wake() (once per tick).
        self._lower_priority()
        get = self._queue.get_nowait
        while True:
            if self._holding():
                self._wake.wait(_POLL_S)
                self._wake.clear()
                continue
            if self._sync_error is not None and not self._failed:
                error, self._sync_error = self._sync_error, None
                self._fail_io(error, "syncing")
            if self._housekeeping_due and not self._failed:
                self._guard(self._housekeep, "syncing")
            try:
                item = get()
            except queue.Empty:
                if self._chunk_opened_at is not None and not self._failed \
                        and time.monotonic() - self._chunk_opened_at >= self._chunk_interval:
                    self._guard(self._close_chunk, "writing a chunk to")
                self._wake.wait(_POLL_S)
                self._wake.clear()
                continue
            self._gate.wait()
            try:
                if type(item) is tuple:
                    self._message(item)
                elif item.kind == "topic":
                    if not self._failed:
                        self._guard(self._add_topic, "adding a topic to", item.payload)
                elif item.kind == "flush":
                    if not self._failed:
                        self._guard(self._checkpoint, "writing a chunk to")
                elif item.kind == "close":
                    self._finish()
                    return
            except Exception as exc:  # noqa: BLE001 - a bug must not leave the queue growing unread
                self._fail(f"bag recording stopped: the writer thread failed: {exc!r}")
            finally:
                if type(item) is not tuple:
                    item.done.set()

    def _lower_priority(self) -> None:
        """This (the writer) thread's nice value raised by ``writer_nice`` (see the constructor).  Linux only:
        there a thread is a task with its own nice value (``setpriority`` on its thread id); elsewhere the same
        call would lower the whole process."""
        if self._writer_nice <= 0 or not sys.platform.startswith("linux"):
            return
        thread = threading.get_native_id()
        try:
            os.setpriority(os.PRIO_PROCESS, thread, os.getpriority(os.PRIO_PROCESS, thread) + self._writer_nice)
        except OSError:  # not permitted (a sandbox): the writer keeps the caller's priority
            pass

    def _guard(self, action, doing: str, *args) -> None:
        try:
            action(*args)
        except OSError as exc:
            self._fail_io(exc, doing)

    def _message(self, item: tuple) -> None:
        topic, data, log_time, publish_time = item
        if self._failed:
            self._dropped_writer += 1
        else:
            written_before = self._written
            try:
                self._write_message(topic, data, log_time, publish_time)
            except Exception as exc:
                if self._written == written_before:  # failed before the MCAP writer took it (a roll)
                    self._dropped_writer += 1
                if isinstance(exc, OSError):
                    self._fail_io(exc, "writing to")
                else:
                    self._fail(f"bag recording stopped: the writer thread failed: {exc!r}")
        self._drained_bytes += len(data)
        backlog = self._enqueued_bytes - self._drained_bytes + len(data)
        if backlog > self._max_backlog:
            self._max_backlog = backlog
        if self._waiting:
            self._space.set()

    def _write_message(self, topic: _Topic, data: bytes, log_time: int, publish_time: int) -> None:
        stats = self._files[-1]
        if stats.added and ((self._max_bytes and self._file.committed >= self._max_bytes)
                            or (self._max_duration_ns and log_time - stats.start > self._max_duration_ns)):
            self._roll()
            stats = self._files[-1]
        topic.sequence = (topic.sequence + 1) & 0xFFFFFFFF
        self._writer.add_message(self._channels[topic.name], log_time, data, publish_time, topic.sequence)
        topic.added += 1
        self._written += 1
        stats.added += 1
        if stats.start is None or log_time < stats.start:
            stats.start = log_time
        if stats.end is None or log_time > stats.end:
            stats.end = log_time
        now = time.monotonic()
        if self._file.pending:  # the MCAP writer finished a chunk (size bound)
            self._commit()
        elif self._chunk_opened_at is None:
            self._chunk_opened_at = now
        elif now - self._chunk_opened_at >= self._chunk_interval:
            self._close_chunk()

    def _checkpoint(self) -> None:
        """flush(): the open chunk, metadata.yaml and (unless sync is off) fsync."""
        self._close_chunk()
        sync = self._sync_interval is not None
        if sync:
            self._file.sync()
            self._last_sync = time.monotonic()
        self._write_metadata_yaml(sync=sync)
        self._housekeeping_due = False

    def _close_chunk(self) -> None:
        if self._chunk_opened_at is None and not self._file.pending:
            return
        self._writer.flush()  # finishes the open chunk (mcap.Writer.flush); the file commits it
        self._commit()

    def _add_topic(self, topic: _Topic) -> None:
        self._recorded_topics.append(topic)
        self._register(topic)
        # metadata.yaml lists the topic from the next commit on (<= chunk_interval_s later), not from here: a
        # rewrite per new topic (a few ms of YAML holding the GIL with a few hundred topics) took ~1 s of the 2 s
        # in which 100 bodies were spawned one request at a time, and the ticks waited for the GIL (measured).
        self._metadata_stale = True

    def _finish(self) -> None:
        self._stop_syncs()
        if not self._failed:
            try:
                self._finish_file()
                self._write_metadata_yaml(sync=self._sync_interval is not None)
                return
            except OSError as exc:
                self._fail_io(exc, "finishing")
        # After an error: leave the last committed state and a metadata.yaml that matches it.
        try:
            if self._file is not None:
                self._file.close()
            self._write_metadata_yaml(sync=False)
        except OSError:
            pass


#: bytes of room kept at the end of metadata.yaml (a comment of spaces), for the in-place rewrite on a full disk
METADATA_SLACK = 4096
_PADDING_LINE = "# room kept to rewrite this file in place when the disk is full (cgp_sim_ros/wire/bag.py)"


def _padded(text: str) -> bytes:
    """``text`` and a comment line padding it by at least METADATA_SLACK bytes, to a whole number of KiB."""
    data = text.encode("utf-8") + _PADDING_LINE.encode() + b"\n"
    size = -(-(len(data) + METADATA_SLACK) // 1024) * 1024
    return data[:-1] + b" " * (size - len(data)) + b"\n"


def _overwrite_in_place(path: Path, text: str, sync: bool) -> bool:
    """Write ``text`` over ``path``'s existing bytes (no new blocks: it works on a full disk), padded with
    spaces to the file's size; False if the file is missing or the text does not fit."""
    data = text.encode("utf-8") + _PADDING_LINE.encode() + b"\n"
    try:
        with open(path, "r+b") as f:
            size = os.fstat(f.fileno()).st_size
            if len(data) > size:
                return False
            f.write(data[:-1] + b" " * (size - len(data)) + b"\n")
            f.flush()
            if sync:
                os.fsync(f.fileno())
    except OSError:
        return False
    return True


# ------------------------------------------------------------------------------------------- recovery
def recover_bag(path) -> dict[str, int]:
    """Make a bag whose recording was cut (power loss, torn last commit) readable by every reader.

    Each ``.mcap`` file listed in ``metadata.yaml`` is read record by record with mcap's stream reader,
    validating chunk CRCs and stopping at the first damaged or missing record: everything before it (every
    intact chunk) is kept and rewritten as a finished, indexed MCAP.  ``metadata.yaml`` is then rebuilt from
    what the files contain.  Returns the number of messages kept per file name.
    """
    import yaml
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    path = Path(path)
    meta_path = path / "metadata.yaml"
    info = yaml.safe_load(meta_path.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
    previous = {t["topic_metadata"]["name"]: t["topic_metadata"]
                for t in info.get("topics_with_message_count") or []}
    kept: dict[str, int] = {}
    files_info: list[dict] = []
    topics: dict[str, dict] = {}  # name -> topic_metadata + message_count, in first-seen order
    for rel in info["relative_file_paths"]:
        file_path = path / Path(rel).name
        found_schemas, found_channels, messages, metadata_records = {}, {}, [], []
        with open(file_path, "rb") as f:
            try:
                for record in StreamReader(f, validate_crcs=True).records:
                    if isinstance(record, Schema):
                        found_schemas[record.id] = record
                    elif isinstance(record, Channel):
                        found_channels[record.id] = record
                    elif isinstance(record, Message):
                        messages.append(record)
                    elif isinstance(record, Metadata):
                        metadata_records.append(record)
            except (McapError, ValueError, EOFError, IndexError, KeyError, UnicodeDecodeError):
                pass  # the damaged tail: keep everything read before it
        messages = [m for m in messages if m.channel_id in found_channels]
        tmp = file_path.with_name(file_path.name + ".recovering")
        with open(tmp, "wb") as out:
            writer = Writer(out, compression=CompressionType.ZSTD)
            writer.start(profile="ros2", library=_LIBRARY + "; recover_bag")
            schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                          for sid, s in found_schemas.items()}
            channel_ids = {cid: writer.register_channel(c.topic, c.message_encoding,
                                                        schema_ids.get(c.schema_id, 0), c.metadata)
                           for cid, c in found_channels.items()}
            for m in messages:
                writer.add_message(channel_ids[m.channel_id], m.log_time, m.data, m.publish_time, m.sequence)
            for record in metadata_records:
                writer.add_metadata(record.name, record.metadata)
            writer.finish()
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, file_path)
        times = [m.log_time for m in messages]
        kept[file_path.name] = len(messages)
        files_info.append({"path": file_path.name,
                           "starting_time": {"nanoseconds_since_epoch": min(times, default=0)},
                           "duration": {"nanoseconds": max(times, default=0) - min(times, default=0)},
                           "message_count": len(messages)})
        for channel in found_channels.values():
            schema = found_schemas.get(channel.schema_id)
            old = previous.get(channel.topic, {})
            qos = old.get("offered_qos_profiles")
            if qos is None:
                qos = yaml.safe_load(channel.metadata.get("offered_qos_profiles") or "[]") or []
            entry = topics.setdefault(channel.topic, {"topic_metadata": {
                "name": channel.topic, "type": schema.name if schema else old.get("type", ""),
                "serialization_format": channel.message_encoding, "offered_qos_profiles": qos,
                "type_description_hash": channel.metadata.get("topic_type_hash",
                                                              old.get("type_description_hash", ""))},
                "message_count": 0})
            entry["message_count"] += sum(1 for m in messages if m.channel_id == channel.id)
    spans = [(f["starting_time"]["nanoseconds_since_epoch"],
              f["starting_time"]["nanoseconds_since_epoch"] + f["duration"]["nanoseconds"])
             for f in files_info if f["message_count"]]
    start = min((a for a, _ in spans), default=0)
    info.update({
        "version": METADATA_VERSION,
        "duration": {"nanoseconds": max((b for _, b in spans), default=0) - start},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": sum(f["message_count"] for f in files_info),
        "topics_with_message_count": list(topics.values()),
        "files": files_info,
    })
    tmp = meta_path.with_name("metadata.yaml.tmp")
    tmp.write_text(schemas.dump_yaml({"rosbag2_bagfile_information": info}) + "\n", encoding="utf-8")
    os.replace(tmp, meta_path)
    return kept
