"""The marker stream of a bag, read with the ``mcap`` library alone (no rclpy, no rosbag2).

A bag is a rosbag2 directory (``metadata.yaml`` + ``<name>_0.mcap``, ``<name>_1.mcap``, ... as the node writes
it) or one ``.mcap`` file.  The files of a directory are read in the order ``metadata.yaml`` lists them (or,
without it, by their split index), each in log-time order; a file without summary (a recording killed by
SIGKILL) is read sequentially by mcap's fallback reader.

A damaged file — cut in the middle of a write (a crash, a full disk, a copy interrupted), a corrupt chunk — is
read record by record with mcap's stream reader up to the damage, and what comes before it is rendered
(:attr:`MarkerStream.damaged` says which files and how many messages were recovered; the command prints it).
A file with nothing readable is an error naming it.  (Issue 27: the first half of a good bag used to be refused
as "not a readable MCAP file" although 2,642 of its messages were readable.)
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from cgp_core.user_input import UserInputError, load_yaml, open_user_file, read_user_text, regular_file

MARKER_ARRAY_SCHEMA = "visualization_msgs/msg/MarkerArray"
#: the topic the node publishes its markers on (``~/markers`` of a node named cgp_sim)
DEFAULT_MARKER_TOPIC = "/cgp_sim/markers"
#: the TF topics read beside the markers (as tf2 names them)
TF_TOPICS = ("/tf_static", "/tf")
_SPLIT_INDEX = re.compile(r"_(\d+)\.mcap$")
#: a rosbag2 metadata.yaml's bytes (the node's are a few kB; one per topic and file)
MAX_METADATA_BYTES = 4 * 1024 * 1024


class BagError(ValueError):
    """A bag that cannot be rendered (missing, not MCAP, no markers); the message says which and why."""


@dataclass
class MarkerStream:
    """The marker topic of a bag: where, and its time span (log time, integer ns)."""

    files: list[Path]
    topic: str
    message_count: int
    start_ns: int  # log time of the first marker message (what "0 s" means for --from / --to)
    end_ns: int  # log time of the bag's last message
    #: damaged files (read up to the damage): path -> what was recovered and why it stopped
    damaged: dict = None
    #: the latched companion of ``topic`` in this bag (``~/static_markers`` beside ``~/markers``: the static
    #: meshes, sent when they change), or None; drawn together with ``topic``
    static_topic: str | None = None
    #: the bag's TF topics (``/tf``, ``/tf_static``) with messages: they place the markers drawn in TF frames
    #: (the node's bodies, ``frame_locked`` in their own frames on the static topic)
    tf_topics: tuple = ()

    def messages(self, start_ns: int | None = None, end_ns: int | None = None,
                 topic: str | None = None) -> Iterator[tuple[int, bytes]]:
        """``(log_time_ns, CDR bytes)`` of the marker messages of ``topic`` (default: :attr:`topic`) logged in
        [start_ns, end_ns] (default: all), in log-time order (mcap seeks to the chunks that overlap the span)."""
        topic = topic or self.topic
        for path in self.files:
            if self.damaged and path in self.damaged:
                for log_time, _topic, _schema, data in _stream_messages(path):
                    if _topic == topic and (start_ns is None or log_time >= start_ns) \
                            and (end_ns is None or log_time <= end_ns):
                        yield log_time, data
                continue
            with open_user_file(path) as stream:
                reader = make_reader(stream)
                try:
                    for _schema, _channel, message in reader.iter_messages(
                            topics=[topic], start_time=start_ns, end_time=None if end_ns is None else end_ns + 1,
                            log_time_order=True):
                        yield message.log_time, message.data
                except Exception as exc:  # noqa: BLE001 - a damaged chunk in a file with a summary: stop there
                    if self.damaged is None:
                        self.damaged = {}
                    self.damaged.setdefault(path, f"{path.name} is damaged ({type(exc).__name__}: "
                                                  f"{str(exc)[:120]}): rendered up to the damage")


def bag_files(bag: str | Path) -> list[Path]:
    """The ``.mcap`` files of a bag directory (in recording order), or ``[bag]`` for a single file.  Only regular
    files are read: a FIFO, a device, a socket or a directory where a file should be — the bag itself, a file
    ``metadata.yaml`` lists, a ``*.mcap`` of the directory — is refused by its kind before anything is opened (a
    FIFO would block the reader for ever: issue 38), and ``metadata.yaml`` is read bounded (its size, its YAML)
    and checked to be what rosbag2 writes."""
    path = Path(bag).expanduser()
    if path.is_dir():
        return _directory_files(path, bag)
    try:
        return [regular_file(path)]
    except UserInputError as exc:
        if not path.exists() and not path.is_symlink():
            raise BagError(f"{bag}: no such bag (expected a rosbag2 directory or an .mcap file)") from None
        raise BagError(f"{bag}: {exc}; a bag is a rosbag2 directory or an .mcap file") from None


def _directory_files(path: Path, bag: str | Path) -> list[Path]:
    metadata = path / "metadata.yaml"
    if metadata.exists() or metadata.is_symlink():
        listed = [path / name for name in _listed_files(metadata, bag)]
        for candidate in listed:
            if candidate.exists() or candidate.is_symlink():
                _check_regular(candidate)
        files = [p for p in listed if p.is_file()]
        if files:
            return files
    files = sorted(path.glob("*.mcap"), key=lambda p: (int(m.group(1)) if (m := _SPLIT_INDEX.search(p.name))
                                                       else -1, p.name))
    if not files:
        raise BagError(f"{bag}: no .mcap file in this directory")
    for candidate in files:
        _check_regular(candidate)
    return files


def _check_regular(path: Path) -> None:
    try:
        regular_file(path)
    except UserInputError as exc:
        raise BagError(f"{path}: {exc}") from None


def _listed_files(metadata: Path, bag: str | Path) -> list[str]:
    """``relative_file_paths`` of a rosbag2 ``metadata.yaml`` (checked: a mapping ``rosbag2_bagfile_information``
    with a list of texts, MCAP storage); :class:`BagError` naming the file and what is wrong otherwise."""
    try:
        document = load_yaml(read_user_text(metadata, max_bytes=MAX_METADATA_BYTES))
    except UserInputError as exc:
        raise BagError(f"{metadata}: not a rosbag2 metadata file ({exc})") from None
    info = document.get("rosbag2_bagfile_information") if isinstance(document, dict) else None
    if not isinstance(info, dict):
        raise BagError(f"{metadata}: not a rosbag2 metadata file (no mapping rosbag2_bagfile_information)")
    storage = info.get("storage_identifier", "mcap")
    if storage != "mcap":
        shown = storage if isinstance(storage, str) and len(storage) <= 40 else type(storage).__name__
        raise BagError(f"{bag}: storage {shown!r}; only MCAP bags can be rendered")
    names = info.get("relative_file_paths", [])
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
        raise BagError(f"{metadata}: not a rosbag2 metadata file (relative_file_paths is not a list of file names)")
    return names


def open_marker_stream(bag: str | Path, topic: str | None = None) -> MarkerStream:
    """Find the MarkerArray topic of a bag (``topic``, or the only MarkerArray topic, preferring
    :data:`DEFAULT_MARKER_TOPIC`) and the bag's time span (from the files' summaries; a file without one is
    scanned)."""
    files = bag_files(bag)
    candidates: dict[str, int] = {}
    damaged: dict[Path, str] = {}
    start = end = None
    for path in files:
        try:
            with open_user_file(path) as stream:
                summary = make_reader(stream).get_summary()
                if summary is None or summary.statistics is None:  # a killed recording: scan it
                    counts, span = _scan(path)
                else:
                    stats = summary.statistics
                    counts = {}
                    for channel_id, channel in summary.channels.items():
                        schema = summary.schemas.get(channel.schema_id)
                        if schema is not None and schema.name == MARKER_ARRAY_SCHEMA:
                            counts[channel.topic] = stats.channel_message_counts.get(channel_id, 0)
                    span = (stats.message_start_time, stats.message_end_time) if stats.message_count else None
        except Exception as exc:  # noqa: BLE001 - mcap raises its own types (and struct / EOF errors) on bad files
            counts, span, note = _recover(path, exc)
            damaged[path] = note
        for name, count in counts.items():
            candidates[name] = candidates.get(name, 0) + count
        if span is not None:
            start = span[0] if start is None else min(start, span[0])
            end = span[1] if end is None else max(end, span[1])
    if topic is None:
        with_messages = {t: c for t, c in candidates.items() if c}
        if DEFAULT_MARKER_TOPIC in with_messages:
            topic = DEFAULT_MARKER_TOPIC
        elif len(with_messages) == 1:
            topic = next(iter(with_messages))
        elif not with_messages:
            raise BagError(f"{bag}: no {MARKER_ARRAY_SCHEMA} messages in this bag (nothing to draw)")
        else:
            raise BagError(f"{bag}: several MarkerArray topics ({', '.join(sorted(with_messages))}); choose one "
                           "with --topic")
    elif not candidates.get(topic):
        raise BagError(f"{bag}: no {MARKER_ARRAY_SCHEMA} messages on {topic} (MarkerArray topics: "
                       f"{', '.join(sorted(candidates)) or 'none'})")
    stream = MarkerStream(files, topic, candidates[topic], start, end, damaged)
    if topic.endswith("/markers") and candidates.get(topic[:-len("markers")] + "static_markers"):
        stream.static_topic = topic[:-len("markers")] + "static_markers"
    stream.tf_topics = tuple(t for t in TF_TOPICS if next(stream.messages(topic=t), None) is not None)
    # time 0 is the first picture there is: the first marker message (a bag may start with other topics, e.g. a
    # cgp-sim bag's start-up event on ~/events at t = 0, one tick before the first markers)
    stream.start_ns = next(stream.messages())[0]
    return stream


def _stream_messages(path: Path):
    """``(log_time, topic, schema name, data)`` of every message of ``path`` read record by record (mcap's stream
    reader, chunk CRCs checked), up to the first damaged or missing record."""
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    with open_user_file(path) as f:
        try:
            for record in StreamReader(f, validate_crcs=True, record_size_limit=1 << 30).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, record.schema_id)
                elif isinstance(record, Message) and record.channel_id in channels:
                    topic, schema_id = channels[record.channel_id]
                    yield record.log_time, topic, schemas.get(schema_id, ""), record.data
        except Exception:  # noqa: BLE001 - the damage (EOF, a bad CRC, a torn record): stop there
            return


def _recover(path: Path, error: Exception) -> tuple[dict[str, int], tuple[int, int] | None, str]:
    """Marker topic counts and time span of a damaged file, read up to the damage; BagError if nothing of it is
    readable."""
    counts: dict[str, int] = {}
    start = end = None
    total = 0
    for log_time, topic, schema, _data in _stream_messages(path):
        total += 1
        start = log_time if start is None else min(start, log_time)
        end = log_time if end is None else max(end, log_time)
        if schema == MARKER_ARRAY_SCHEMA:
            counts[topic] = counts.get(topic, 0) + 1
    if total == 0:
        raise BagError(f"{path}: not a readable MCAP file ({type(error).__name__}: {error}), and no message of it "
                       "could be recovered") from None
    note = (f"{path.name} is damaged ({type(error).__name__}: {str(error)[:120]}): {total} messages recovered from "
            "before the damage")
    return counts, (None if start is None else (start, end)), note


def _scan(path: Path) -> tuple[dict[str, int], tuple[int, int] | None]:
    """Marker topic counts and time span of a file without summary (sequential read)."""
    counts: dict[str, int] = {}
    start = end = None
    with open_user_file(path) as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            start = message.log_time if start is None else min(start, message.log_time)
            end = message.log_time if end is None else max(end, message.log_time)
            if schema is not None and schema.name == MARKER_ARRAY_SCHEMA:
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts, (None if start is None else (start, end))
