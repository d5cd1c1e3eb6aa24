"""Reading what users give, with the cost bounded before it is paid: files and YAML.

- :func:`read_user_file`: a file named by a user (a scene file, a spawn request's ``uri``, a mesh file) is read
  only if it is a *regular file* after its links are resolved — a FIFO would block the reader until someone
  writes to it, ``/dev/zero`` never ends, a directory is not a file — with its size checked before reading
  (:data:`~cgp_core.limits.MAX_FILE_BYTES` unless the caller says otherwise) and the read itself bounded
  (a file can grow after ``stat``, and ``/proc`` files report size 0).  The file is opened non-blocking, so
  even a FIFO swapped in between the check and the open cannot block.
- :func:`load_yaml`: YAML's safe subset (plain data: a ``!!python/...`` tag is an error, never executed), a
  key given twice in one mapping is an error, YAML 1.2 floats (``1e3``) are floats, and the document is
  bounded while its events are read — at most :data:`~cgp_core.limits.MAX_YAML_DEPTH` levels of nesting and
  :data:`~cgp_core.limits.MAX_YAML_NODES` nodes — before anything recursive or big is built.  libyaml's C
  parser does the reading where PyYAML has it (~10x faster than PyYAML's own).

Errors (:class:`UserInputError`) name the file and a position and say what is wrong, but **never quote the
content**: a file that is not ours may be anything a user can point at (``/etc/shadow``), and the message
goes into a service reply, onto ``~/events`` and into the bag.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

import yaml

from .limits import MAX_FILE_BYTES, MAX_YAML_BYTES, MAX_YAML_DEPTH, MAX_YAML_NODES

__all__ = ["UserInputError", "regular_file", "open_user_file", "read_user_file", "read_user_text", "load_yaml",
           "YAML12_FLOAT", "SceneLoader"]

_FILE_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
               (stat.S_ISSOCK, "a socket"))


class UserInputError(ValueError):
    """Input that is refused; ``str(exc)`` says why (with the position in the text, if any) without quoting
    content."""


def regular_file(path: str | Path) -> Path:
    """``path`` (``~`` expanded) resolved through its links, if it is a regular file; :class:`UserInputError`
    naming what it is otherwise (no such file, a link loop, a directory, a FIFO, a device, a socket).  Nothing is
    opened."""
    given = Path(path).expanduser()
    try:
        resolved = given.resolve(strict=True)
    except FileNotFoundError:
        raise UserInputError("cannot read: no such file") from None
    except (OSError, RuntimeError) as exc:  # a link loop is a RuntimeError before 3.13
        raise UserInputError(f"cannot resolve the path: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        mode = resolved.stat().st_mode
    except OSError as exc:
        raise UserInputError(f"cannot read: {exc.strerror or exc}") from None
    _refuse_unless_regular(mode, resolved, given)
    return resolved


def open_user_file(path: str | Path):
    """The regular file ``path`` (see :func:`regular_file`) opened for binary reading, non-blocking: a FIFO swapped
    in after the check cannot block the open, and is refused by the open file's own kind.  For readers that
    stream a file too big for :func:`read_user_file` (a bag)."""
    resolved = regular_file(path)
    try:
        fd = os.open(resolved, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise UserInputError(f"cannot read: {exc.strerror or exc}") from None
    try:
        _refuse_unless_regular(os.fstat(fd).st_mode, resolved, Path(path).expanduser())
    except BaseException:
        os.close(fd)
        raise
    return os.fdopen(fd, "rb")


def read_user_file(path: str | Path, *, max_bytes: int = MAX_FILE_BYTES) -> bytes:
    """The bytes of the regular file ``path`` (``~`` expanded, links resolved), at most ``max_bytes`` of them;
    :class:`UserInputError` otherwise (no such file, not a regular file, too large, unreadable)."""
    given = Path(path).expanduser()
    resolved = regular_file(given)
    try:
        before = resolved.stat()
    except OSError as exc:
        raise UserInputError(f"cannot read: {exc.strerror or exc}") from None
    _refuse_unless_regular(before.st_mode, resolved, given)
    if before.st_size > max_bytes:
        raise UserInputError(f"{before.st_size} bytes; files are limited to {max_bytes} bytes")
    try:
        fd = os.open(resolved, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise UserInputError(f"cannot read: {exc.strerror or exc}") from None
    try:
        _refuse_unless_regular(os.fstat(fd).st_mode, resolved, given)  # swapped after the check above?
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise UserInputError(f"more than {max_bytes} bytes; files are limited to {max_bytes} bytes")
        return b"".join(chunks)
    except OSError as exc:
        raise UserInputError(f"cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)


def read_user_text(path: str | Path, *, max_bytes: int = MAX_FILE_BYTES) -> str:
    """:func:`read_user_file` decoded as UTF-8 (:class:`UserInputError` naming the byte offset otherwise)."""
    data = read_user_file(path, max_bytes=max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UserInputError(f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def _refuse_unless_regular(mode: int, resolved: Path, given: Path) -> None:
    if stat.S_ISREG(mode):
        return
    kind = next((name for test, name in _FILE_KINDS if test(mode)), "not a regular file")
    via = f" (the link resolves to {str(resolved)!r})" if resolved != given.absolute() else ""
    raise UserInputError(f"is {kind}, not a regular file{via}")


# ---- YAML ---------------------------------------------------------------------------------------------------

#: A float of YAML 1.2's core schema (section 10.3.2): ``1e3``, ``1.0e3``, ``-2E-4``, ``+1.5``, ``.5``, ``-.5``.
#: PyYAML resolves plain scalars by YAML 1.1, whose floats need a decimal point and a signed exponent
#: (``1.0e+3``): ``mass: 1e3`` would otherwise be the text "1e3".
YAML12_FLOAT = re.compile(r"^[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?$")

_NODE_START = (yaml.ScalarEvent, yaml.AliasEvent)
_COLLECTION_START = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
_COLLECTION_END = (yaml.SequenceEndEvent, yaml.MappingEndEvent)
#: what PyYAML / libyaml quote in an error: an indicator of YAML's syntax (``','``, ``'<block end>'``) is kept,
#: anything else (a character of the text, an alias, a tag) is content and is dropped
_QUOTED = re.compile(r"\s*(?:'[^']*'|\"[^\"]*\"|#x[0-9a-fA-F]+)")
_SYNTAX = re.compile(r"""\s*(?:'[][{},:?|>#&*!%@-]'|'<[a-z ]+>')""")

if yaml.__with_libyaml__:  # PyYAML built with libyaml (its wheels are): the C parser
    from yaml import CSafeLoader as _BaseLoader
    from yaml._yaml import CParser as _Parser
else:  # pragma: no cover - a PyYAML without libyaml: the same loader in pure Python
    from yaml import SafeLoader as _BaseLoader

    def _Parser(text):  # noqa: N802 - a stand-in for the class
        return yaml.SafeLoader(text)


class SceneLoader(_BaseLoader):
    """PyYAML's safe loader (plain data only) with two changes:

    - a key given twice in one mapping is an error: PyYAML keeps the last value silently, so
      ``{mass: 1, mass: 2}`` would drop a value the author wrote.  Keys merged in with ``<<`` may still be
      overridden, as YAML's merge semantics say.
    - plain scalars that are YAML 1.2 floats (:data:`YAML12_FLOAT`) are floats, as users write them.  The
      resolver is added after the safe loader's own (first match wins), so everything YAML 1.1 already read as
      a number (``1_000``, ``.inf``, ``.nan``) is read as before; quoted scalars stay strings.

    Use it through :func:`load_yaml`, which bounds the document first (this class alone does not).
    """

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            first_seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    earlier = first_seen.setdefault(key, key_node.start_mark)
                except TypeError:  # an unhashable key: the base class reports it
                    continue
                if earlier is not key_node.start_mark:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key (first given at line {earlier.line + 1}, column "
                        f"{earlier.column + 1})", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


# add_implicit_resolver copies the inherited resolver table into SceneLoader first: the base is unchanged.
SceneLoader.add_implicit_resolver("tag:yaml.org,2002:float", YAML12_FLOAT, list("-+.0123456789"))


def load_yaml(text: str, *, max_depth: int = MAX_YAML_DEPTH, max_nodes: int = MAX_YAML_NODES,
              max_bytes: int = MAX_YAML_BYTES) -> Any:
    """YAML ``text`` as plain data (see :class:`SceneLoader`), bounded: at most ``max_bytes`` UTF-8 bytes (checked
    before parsing), ``max_depth`` levels of nesting and ``max_nodes`` nodes (checked while the parser's events
    are read, before the document is composed).  :class:`UserInputError` with the line and column otherwise;
    the reason never quotes the text."""
    if not isinstance(text, str):
        raise UserInputError(f"YAML must be text, got {type(text).__name__}")
    size = len(text) if len(text) * 4 <= max_bytes else len(text.encode("utf-8", "surrogatepass"))
    if size > max_bytes:
        raise UserInputError(f"{size} bytes of YAML; at most {max_bytes} are parsed")
    try:
        _check_bounds(text, max_depth, max_nodes)
        return yaml.load(text, Loader=SceneLoader)  # noqa: S506 - a safe loader (SceneLoader: plain data only)
    except yaml.YAMLError as exc:
        raise _yaml_error(exc) from None


def _check_bounds(text: str, max_depth: int, max_nodes: int) -> None:
    """Walk the parser's events (no composition, no recursion) and stop at the first bound passed."""
    parser = _Parser(text)
    depth = nodes = 0
    try:
        while True:
            event = parser.get_event()
            if event is None or isinstance(event, yaml.StreamEndEvent):
                return
            if isinstance(event, _COLLECTION_START):
                depth += 1
                nodes += 1
                if depth > max_depth:
                    raise UserInputError(f"{_position(event.start_mark)}: YAML nested deeper than {max_depth} "
                                         "levels")
            elif isinstance(event, _COLLECTION_END):
                depth -= 1
            elif isinstance(event, _NODE_START):
                nodes += 1
            if nodes > max_nodes:
                raise UserInputError(f"{_position(event.start_mark)}: more than {max_nodes} YAML nodes; documents "
                                     f"are limited to {max_nodes}")
    finally:
        dispose = getattr(parser, "dispose", None)
        if dispose is not None:
            dispose()


def _position(mark) -> str:
    return f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""


def _yaml_error(exc: yaml.YAMLError) -> UserInputError:
    """PyYAML's error as a position and a reason without the text it quotes (a character, an alias, a tag)."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    if isinstance(exc, yaml.reader.ReaderError):
        return UserInputError(f"malformed YAML: position {exc.position}: a character YAML does not allow (a "
                              "control character or invalid UTF-8)")
    if not problem:
        problem = type(exc).__name__.replace("Error", " error").lower()
    problem = _QUOTED.sub(lambda m: m.group(0) if _SYNTAX.fullmatch(m.group(0)) else "", problem).strip()
    where = _position(mark)
    return UserInputError(f"malformed YAML: {where}: {problem}" if where else f"malformed YAML: {problem}")
