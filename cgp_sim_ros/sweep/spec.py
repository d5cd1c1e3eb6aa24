"""Sweep files: validation, key paths, the plan of runs and their identities.

The format (every key but ``scene`` optional; SI units):

.. code-block:: yaml

    description: what the sweep shows
    title: the figures' title (cgp-sim-sweep plot)
    scene: couzin_torus              # a built-in scene name, or a path (relative to this file)
    dt: 0.1                          # s per tick (the node's 1 / rate_hz); default 1/60
    duration: 200                    # s of simulated time per run (per link of a chain)
    seeds: 12                        # seeds 0..11, or a list [0, 4, 7]; absent: the scene's own seeds
    overrides:                       # key path -> value, in every run
      flocks[school].model: sphere
    grid:                            # key path -> list of values: one run per combination (x seeds)
      flocks[school].couzin.orientation_width: [0, 0.5, 1, 2]
      world.substeps: [1, 4]
    record:
      every: 10                      # ticks between two samples (and one at the start of each run)
      flocks: true                   # the order parameters of every flock (cgp_core.boids.order)
      bodies: false                  # the pose and twist of every body
      bag: false                     # a rosbag2 MCAP per run (bags/<run>/), the same samples as messages
    summary:
      window: 40                     # s at the end of each run whose every tick the summary averages
                                     # (default: the whole run)
    chain:                           # optional: the runs along one grid key form a chain; each link starts
      key: flocks[school].couzin.orientation_width   # from the previous link's final state
      reverse: false                 # true: the key's values from the last to the first
    experiments:                     # optional: named variants, each merged over the keys above
      random: {}
      increasing:
        chain: {key: "flocks[school].couzin.orientation_width"}   # in YAML's {...} a [ needs quotes
      decreasing:
        chain:
          key: flocks[school].couzin.orientation_width
          reverse: true

Key paths
    Dot-separated keys of the scene's YAML, with ``[i]`` (a list index) or ``[name]`` (the entry of a list of
    named entries: ``flocks[school]``, ``bodies[ball]``) after a key: ``world.substeps``,
    ``flocks[0].couzin.orientation_width``, ``bodies[ball].mass``, ``flocks[school].spawn.center[2]``.
    Before any run starts every path is checked against the base scene (an entry that does not exist, an
    index out of range, a key the scene format does not know: an error naming the sweep file, the key and the
    reason).  Values are checked by the scene loader itself when the run's scene is built: a value it refuses
    is a failed run (its row says the loader's ``file: key: reason``) and the sweep goes on; the plan lists such
    runs before it starts (:attr:`Plan.refused`).

Runs, tasks, identities
    A *run* is one simulation of ``duration`` (a row of ``runs.parquet``).  A *task* is what one worker runs in
    one go: a single run, or a whole chain (its links one after the other in one process: the state is carried
    in memory, and a chain is in the tables complete or not at all).  A run's identity (:func:`run_id`) is the
    SHA-256 of its resolved scene, seed, tick (ns), tick count, what is recorded, the summary window, the
    previous link's identity (chains) and the code version (:func:`code_version`); the output directory keeps
    one fragment per identity, so a finished run is never run twice and a changed sweep file re-runs only the
    runs it changed.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import importlib.metadata
import itertools
import json
import math
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from cgp_core.scene import SceneError, parse_yaml, resolve_scene, scene_from_dict
from cgp_core.user_input import UserInputError, read_user_text

#: the node's default tick (rate_hz: 60)
DEFAULT_DT = 1.0 / 60.0
MAX_SWEEP_BYTES = 4 * 1024 * 1024
#: Caps on what a sweep file asks for, checked before anything is planned (issue 38: a grid of 10⁹ runs planned
#: for minutes, ``seeds: 10¹²`` ran out of memory, ``dt: 1e-320`` overflowed the tick count).  A sweep's runs,
#: all experiments together (the plan builds and checks every run's scene, once for the seeds that share it:
#: 100,000 runs of as many scenes planned in 27 s and 370 MB, speed probe numpy 36 / python 10.8 ms):
MAX_RUNS = 100_000
#: links of one chain (one task: its links run one after the other in one worker)
MAX_CHAIN_LINKS = 1_000
#: the tick [s]: the node's rate_hz range (1 to 10,000 Hz)
MIN_DT, MAX_DT = 1e-4, 1.0
#: ticks of one run (per link): 10⁸ ticks are ~19 days of simulated time at 60 Hz
MAX_TICKS = 100_000_000
#: a seed is an int64 (the tables' ``seed`` column; numpy takes it as is)
MAX_SEED = 2**63 - 1
#: a key path's characters and segments (a scene is 5 levels deep; ``flocks[school].spawn.center[2]`` has 5)
MAX_KEY_PATH_CHARS = 256
MAX_KEY_PATH_SEGMENTS = 32
#: key paths of one experiment's overrides and grid together (each is checked against the base scene)
MAX_KEYS = 1_000
#: an error lists at most this many problems
MAX_REPORTED_PROBLEMS = 30
TOP_KEYS = {"description", "title", "scene", "dt", "duration", "seeds", "overrides", "grid", "record", "summary",
            "chain", "experiments"}
#: what an experiment may set (merged over the top level; overrides / grid / record / summary key by key)
EXPERIMENT_KEYS = {"dt", "duration", "seeds", "overrides", "grid", "record", "summary", "chain"}
RECORD_KEYS = {"every": 10, "flocks": True, "bodies": False, "bag": False}
SCENE_SECTIONS = ("world", "bodies", "flocks")
EXPERIMENT_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
#: the experiment of a sweep file without ``experiments``
DEFAULT_EXPERIMENT = "main"


class SweepError(ValueError):
    """A sweep file that cannot be run; the message lists every problem as ``file: key: reason``."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = problems
        shown = [f"{source}: {p}" for p in problems[:MAX_REPORTED_PROBLEMS]]
        if len(problems) > MAX_REPORTED_PROBLEMS:
            shown.append(f"{source}: ... and {len(problems) - MAX_REPORTED_PROBLEMS} more problems")
        super().__init__("\n".join(shown))


# ---- the code version -------------------------------------------------------------------------------------

#: the sources whose change changes what a run computes: the physics and the runner (which steps and measures)
_SOURCE_PACKAGES = ("cgp_core",)
_SOURCE_FILES = (("cgp_sim_ros.sweep", "runner.py"),)


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """``<cgp_sim_ros version>+<12 hex digits>``: the installed package's version and the SHA-256 of the
    sources a run executes (every ``.py`` of ``cgp_core`` and the runner, by relative path and content).

    Why a hash of the sources and not ``git describe``: workers run an installed copy (``pip install`` on each,
    or a venv on a shared filesystem) that has no git metadata, and a checkout with uncommitted edits would
    describe itself as the commit it started from.  The hash is of the files that run, wherever they are."""
    try:
        version = importlib.metadata.version("cgp_sim_ros")
    except importlib.metadata.PackageNotFoundError:  # a source checkout on sys.path, not installed
        version = "0+unknown"
    digest = hashlib.sha256()
    files: list[tuple[str, Path]] = []
    for package in _SOURCE_PACKAGES:
        root = Path(str(resources.files(package)))
        files += [(f"{package}/{p.relative_to(root).as_posix()}", p) for p in root.rglob("*.py")
                  if "__pycache__" not in p.parts]
    for package, name in _SOURCE_FILES:
        files.append((f"{package}/{name}", Path(str(resources.files(package) / name))))
    for relative, path in sorted(files):
        digest.update(relative.encode() + b"\0" + path.read_bytes() + b"\0")
    return f"{version}+{digest.hexdigest()[:12]}"


# ---- key paths ----------------------------------------------------------------------------------------------

_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[[^\[\]]+\])*)")
_INDEX = re.compile(r"\[([^\[\]]+)\]")


def parse_key_path(path: str) -> list[str | int]:
    """``flocks[school].spawn.center[2]`` → ``["flocks", ("school",), "spawn", "center", 2]``: mapping keys as
    ``str``, list indices as ``int``, entry names as 1-tuples.  ``ValueError`` with the reason."""
    if not isinstance(path, str) or not path.strip():
        raise ValueError("a key path must be a non-empty text like flocks[0].count")
    if len(path) > MAX_KEY_PATH_CHARS:
        raise ValueError(f"a key path has at most {MAX_KEY_PATH_CHARS} characters, this one {len(path):,}")
    if path.count(".") + path.count("[") >= MAX_KEY_PATH_SEGMENTS:
        raise ValueError(f"more than {MAX_KEY_PATH_SEGMENTS} keys and indices; a key path has at most "
                         f"{MAX_KEY_PATH_SEGMENTS}")
    out: list = []
    for part in path.split("."):
        match = _SEGMENT.fullmatch(part)
        if match is None:
            raise ValueError(f"{part!r} is not a key (letters, digits, _) followed by optional [index] or [name]")
        out.append(match.group(1))
        for index in _INDEX.findall(match.group(2)):
            index = index.strip()
            if re.fullmatch(r"-?[0-9]+", index):
                out.append(int(index))
            elif re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", index):
                out.append((index,))
            else:
                raise ValueError(f"[{index}] is neither a list index nor an entry name")
    if out[0] not in SCENE_SECTIONS:
        raise ValueError(f"a key path starts at a scene section ({', '.join(SCENE_SECTIONS)}), not {out[0]!r}")
    return out


def _show_path(parts: list) -> str:
    text = ""
    for p in parts:
        if isinstance(p, tuple):
            text += f"[{p[0]}]"
        elif isinstance(p, int):
            text += f"[{p}]"
        else:
            text += f".{p}" if text else p
    return text


def set_key_path(data: dict, path: str, value: Any) -> None:
    """Set ``path`` (see :func:`parse_key_path`) in the scene dict ``data`` to a copy of ``value``; missing
    mappings on the way are created (``world`` of a scene that has none).  ``ValueError`` (the reason, the path
    up to where it failed) when the path does not exist: an entry name no entry has, an index out of range,
    a key under something that is not a mapping."""
    parts = parse_key_path(path)
    node: Any = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        here = _show_path(parts[:depth + 1])
        if isinstance(part, str):
            if not isinstance(node, dict):
                raise ValueError(f"{_show_path(parts[:depth])} is {_kind(node)}, not a mapping with key {part!r}")
            if last:
                node[part] = copy.deepcopy(value)
                return
            if node.get(part) is None:
                node[part] = [] if part in ("bodies", "flocks") else {}
            node = node[part]
        else:
            if not isinstance(node, list):
                raise ValueError(f"{_show_path(parts[:depth])} is {_kind(node)}, not a list")
            if isinstance(part, tuple):
                names = [e.get("name") for e in node if isinstance(e, dict)]
                if part[0] not in names:
                    raise ValueError(f"{here}: no entry named {part[0]!r} in {_show_path(parts[:depth])} (names: "
                                     f"{', '.join(map(str, names)) or 'none'})")
                index = names.index(part[0])
            else:
                index = part
                if not -len(node) <= index < len(node):
                    raise ValueError(f"{here}: index out of range ({_show_path(parts[:depth])} has {len(node)} "
                                     "entries)")
            if last:
                node[index] = copy.deepcopy(value)
                return
            node = node[index]


def _kind(value: Any) -> str:
    return {dict: "a mapping", list: "a list", str: "a text", bool: "a boolean", type(None): "nothing"}.get(
        type(value), f"a {type(value).__name__}")


# ---- the sweep ------------------------------------------------------------------------------------------------

@dataclass
class Experiment:
    """One experiment of a sweep, merged and validated."""

    name: str
    dt: float
    ticks: int               # per run (per link)
    window_ticks: int        # the summary's averaging window, the run's last ticks
    seeds: list[int] | None  # None: the scene's own seeds
    overrides: dict[str, Any]
    grid: dict[str, list]    # key path -> values, in the file's order
    record: dict[str, Any]   # every, flocks, bodies, bag
    chain_key: str | None
    chain_reverse: bool

    @property
    def duration(self) -> float:
        return self.ticks * self.dt

    @property
    def runs(self) -> int:
        """How many runs the experiment plans: the grid's product x seeds."""
        return math.prod(len(values) for values in self.grid.values()) * len(self.seeds or [None])


@dataclass
class Run:
    """One simulation: a resolved scene, a seed, a place in a chain."""

    id: str
    experiment: str
    params: dict[str, Any]   # the experiment's grid keys -> this run's values
    seed: int | None
    link: int                # position in its chain (0 for a single run)
    scene: dict              # the resolved scene (YAML data)
    refused: str | None = None  # the scene loader's error for this scene (the run will fail with it)


@dataclass
class Task:
    """What one worker runs in one go: a single run or a whole chain."""

    id: str                  # the last run's id (which depends on every link before it)
    experiment: Experiment
    runs: list[Run]

    @property
    def ticks(self) -> int:
        return self.experiment.ticks * len(self.runs)

    def payload(self, source: str, code: str) -> dict:
        """The plain data a worker needs (:func:`cgp_sim_ros.sweep.runner.run_task`)."""
        e = self.experiment
        return {"task": self.id, "source": source, "code_version": code, "dt": e.dt, "ticks": e.ticks,
                "window_ticks": e.window_ticks, "record": dict(e.record), "seed": self.runs[0].seed,
                "runs": [{"id": r.id, "scene": r.scene, "source": run_source(source, r.params)} for r in self.runs]}


@dataclass
class Sweep:
    """A validated sweep file."""

    source: str                 # the file (or built-in name) it was read from
    name: str                   # its stem: the default output directory's name
    description: str
    scene_name: str             # as written
    base_scene: dict
    experiments: list[Experiment]
    title: str = ""             # the figures' title
    tasks: list[Task] = field(default_factory=list)

    @property
    def runs(self) -> list[Run]:
        return [r for t in self.tasks for r in t.runs]

    @property
    def refused(self) -> list[Run]:
        """Runs whose scene the scene loader refuses (they fail, the others run)."""
        return [r for r in self.runs if r.refused]

    def grid_keys(self) -> list[str]:
        """Every swept key path, in first-seen order (the tables' parameter columns)."""
        keys: list[str] = []
        for e in self.experiments:
            keys += [k for k in e.grid if k not in keys]
        return keys


def builtin_sweep_dir() -> Path:
    return Path(str(resources.files("msgs_config") / "sweeps"))


def builtin_sweep_names() -> list[str]:
    return sorted(p.stem for p in builtin_sweep_dir().glob("*.yaml"))


def resolve_sweep(name_or_path: str) -> Path:
    """A sweep file path, or the name of a built-in sweep (``msgs_config/sweeps/<name>.yaml``): ``couzin_hysteresis``
    and ``examples/couzin_hysteresis.yaml`` (the issue's spelling: a path that does not exist whose file name is a
    built-in sweep's) both find the built-in one."""
    text = str(name_or_path).strip()
    builtins = ", ".join(builtin_sweep_names())
    if not text:
        raise SweepError("<sweep>", [f"empty sweep name; built-in sweeps: {builtins}"])
    path = Path(text).expanduser()
    if path.is_dir():
        raise SweepError(text, ["is a directory, not a sweep file"])
    if path.exists():  # a file, or a FIFO / device that load_sweep refuses by name (never opened: issue 27)
        return path
    candidate = builtin_sweep_dir() / (path.name if path.suffix in (".yaml", ".yml") else f"{path.name}.yaml")
    if candidate.is_file() and (path.suffix in (".yaml", ".yml") or "/" not in text):
        return candidate
    if path.suffix in (".yaml", ".yml") or "/" in text:
        raise SweepError(text, [f"no such sweep file (and no built-in sweep of that name; built-in sweeps: "
                                f"{builtins})"])
    raise SweepError(text, [f"no built-in sweep of that name; built-in sweeps: {builtins}"])


def load_sweep(name_or_path: str | Path, seeds: int | None = None) -> Sweep:
    """Read and validate a sweep file or built-in sweep; plan every run.  ``seeds``: seeds 0..seeds-1 in every
    experiment instead of the file's.  :class:`SweepError` names the file, the key and the reason (every
    problem at once)."""
    path = resolve_sweep(str(name_or_path))
    source = str(path)
    try:  # a regular file (links resolved), read with a bound: never a FIFO or a device (issue 27)
        text = read_user_text(path, max_bytes=MAX_SWEEP_BYTES)
    except UserInputError as exc:
        raise SweepError(source, [str(exc)]) from None
    return parse_sweep(text, source, base_dir=path.parent, seeds=seeds)


def parse_sweep(text: str, source: str = "<sweep>", base_dir: Path | None = None, seeds: int | None = None) -> Sweep:
    try:
        data = parse_yaml(text, source)
    except SceneError as exc:
        problems = [f"{p} (a key path with [...] inside {{...}} needs quotes, or write the mapping as a block)"
                    if "but got '['" in p or "did not find expected ',' or '}'" in p else p for p in exc.problems]
        raise SweepError(source, problems) from None
    if seeds is not None and isinstance(data, dict):
        data["seeds"] = seeds
        for experiment in (data.get("experiments") or {}).values():
            if isinstance(experiment, dict):
                experiment.pop("seeds", None)
    return sweep_from_dict(data, source, base_dir)


def sweep_from_dict(data: Any, source: str = "<sweep>", base_dir: Path | None = None) -> Sweep:
    problems: list[str] = []
    fail = problems.append
    if not isinstance(data, dict):
        raise SweepError(source, [f"top level must be a mapping with keys {', '.join(sorted(TOP_KEYS))}, got "
                                  f"{_kind(data)}"])
    for key in data:
        if key not in TOP_KEYS:
            fail(f"{key}: unknown key (valid: {', '.join(sorted(TOP_KEYS))})")
    description, title = data.get("description", ""), data.get("title", "")
    if not isinstance(description, str):
        fail("description: must be a text")
        description = ""
    if not isinstance(title, str):
        fail("title: must be a text (the figures' title)")
        title = ""
    if "scene" not in data:
        fail("scene: missing (a built-in scene name or a scene file)")
        raise SweepError(source, problems)
    scene_name, base = _base_scene(data["scene"], base_dir, fail)
    if base is None:
        raise SweepError(source, problems)

    raw_experiments = data.get("experiments")
    if raw_experiments is None:
        named = {DEFAULT_EXPERIMENT: {}}
    elif not isinstance(raw_experiments, dict) or not raw_experiments:
        fail("experiments: must be a mapping of experiment names to settings (each may be {})")
        named = {}
    else:
        named = raw_experiments
    experiments = []
    for name, raw in named.items():
        where = f"experiments.{name}" if raw_experiments is not None else ""
        if not isinstance(name, str) or not EXPERIMENT_NAME.match(name):
            fail(f"experiments.{name}: the name must be letters, digits and _, starting with a letter")
            continue
        if raw is None:
            raw = {}
        if not isinstance(raw, dict):
            fail(f"{where}: must be a mapping of settings ({', '.join(sorted(EXPERIMENT_KEYS))}), got {_kind(raw)}")
            continue
        for key in raw:
            if key not in EXPERIMENT_KEYS:
                fail(f"{where}.{key}: unknown key (valid: {', '.join(sorted(EXPERIMENT_KEYS))})")
        experiment = _experiment(name, data, raw, where, base, fail)
        if experiment is not None:
            experiments.append(experiment)
    total = sum(e.runs for e in experiments)
    if total > MAX_RUNS:
        fail(f"experiments: {' + '.join(f'{e.runs:,}' for e in experiments)} = {total:,} runs; a sweep has at most "
             f"{MAX_RUNS:,}")
    if problems:
        raise SweepError(source, problems)
    stem = Path(source).stem if source.endswith((".yaml", ".yml")) else source
    sweep = Sweep(source=source, name=stem, description=" ".join(description.split()), scene_name=scene_name,
                  base_scene=base, experiments=experiments, title=title.strip())
    sweep.tasks = plan(sweep)
    return sweep


def _base_scene(raw: Any, base_dir: Path | None, fail) -> tuple[str, dict | None]:
    if not isinstance(raw, str) or not raw.strip():
        fail(f"scene: must be a built-in scene name or a scene file path, got {_kind(raw)}")
        return "", None
    name = raw.strip()
    candidates = [name]
    if base_dir is not None and not Path(name).is_absolute() and (name.endswith((".yaml", ".yml")) or "/" in name):
        candidates.insert(0, str(base_dir / name))  # relative to the sweep file first
    error = None
    for candidate in candidates:
        try:
            path = resolve_scene(candidate)
            break
        except SceneError as exc:
            error = error or exc
    else:
        fail(f"scene: {error}")
        return name, None
    try:
        text = read_user_text(path)  # bounded, regular files only, as a scene file given to cgp-sim
        data = parse_yaml(text, str(path))
        scene_from_dict(copy.deepcopy(data), str(path))  # the base scene itself must load
    except UserInputError as exc:
        fail(f"scene: cannot read {path}: {exc}")
        return name, None
    except SceneError as exc:
        fail(f"scene: the base scene does not load: {exc}")
        return name, None
    if data is None:
        data = {}
    data.pop("description", None)  # text, not physics: not part of a run's identity
    return name, data


def _merged(top: Any, own: Any) -> Any:
    """An experiment's mapping settings over the top level's, key by key."""
    if isinstance(top, dict) and isinstance(own, dict):
        return {**top, **own}
    return own if own is not None else top


def _experiment(name: str, top: dict, own: dict, where: str, base: dict, fail) -> Experiment | None:
    before = _Count(fail)
    prefix = f"{where}." if where else ""

    def setting(key):
        return (f"{prefix}{key}", own[key]) if key in own else (key, top.get(key))

    key, raw = setting("dt")
    dt = DEFAULT_DT if raw is None else _positive(raw, key, before, MIN_DT, MAX_DT)
    key, raw = setting("duration")
    if raw is None:
        before(f"{key}: missing (simulated seconds per run)")
        duration = dt
    else:
        duration = _positive(raw, key, before)
    if duration / dt > MAX_TICKS:  # checked before the count is made (dt: 1e-320 overflowed it)
        before(f"{key}: {duration:g} s at dt = {dt:g} s is more than {MAX_TICKS:,} ticks, the most a run has")
        duration = dt
    ticks = max(1, round(duration / dt))
    if abs(ticks * dt - duration) > 1e-6 * max(duration, dt):
        before(f"{key}: {duration:g} s is not a whole number of ticks of dt = {dt:g} s")

    key, raw = setting("seeds")
    seeds = None
    if raw is not None:
        if isinstance(raw, int) and not isinstance(raw, bool):
            if raw < 1:
                before(f"{key}: a number of seeds must be >= 1, got {_show(raw)}")
            elif raw > MAX_RUNS:  # refused before the list is made (seeds: 10¹² ran out of memory)
                before(f"{key}: {_show(raw)} seeds; a sweep has at most {MAX_RUNS:,} runs")
            else:
                seeds = list(range(raw))
        elif isinstance(raw, list) and raw and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0
                                                   for s in raw):
            if len(set(raw)) != len(raw):
                before(f"{key}: a seed is listed twice")
            too_big = next((s for s in raw if s > MAX_SEED), None)
            if too_big is not None:  # the tables' seed column is int64 (2⁶³ broke every later assembly)
                before(f"{key}: seed {_show(too_big)} is larger than {MAX_SEED} (seeds are int64)")
            seeds = list(raw)
        else:
            before(f"{key}: must be a number of seeds (0..n-1) or a non-empty list of integers 0..{MAX_SEED}, got "
                   f"{_kind(raw)}")

    overrides = _mapping(_merged(top.get("overrides"), own.get("overrides")), f"{prefix}overrides", before)
    grid = _mapping(_merged(top.get("grid"), own.get("grid")), f"{prefix}grid", before)
    if len(overrides) + len(grid) > MAX_KEYS:  # each key is checked against the scene (a scene load each)
        before(f"{prefix}overrides, {prefix}grid: {len(overrides) + len(grid):,} key paths; a sweep sets at most "
               f"{MAX_KEYS:,}")
        return None
    for path, values in list(grid.items()):
        if not isinstance(values, list) or not values:
            before(f"{prefix}grid.{_show_key(path)}: must be a non-empty list of values, got {_kind(values)}")
            grid.pop(path)
    runs = math.prod(len(values) for values in grid.values()) * len(seeds or [None])
    if runs > MAX_RUNS:  # before the values are compared or anything is planned (10⁹ runs planned for minutes)
        before(f"{prefix}grid: {' x '.join(f'{len(v):,}' for v in grid.values())} values"
               + (f" x {len(seeds):,} seeds" if seeds else "") + f" = {runs:,} runs; a sweep has at most "
               f"{MAX_RUNS:,}")
        return None
    for path, values in grid.items():
        canonical = [json.dumps(v, sort_keys=True) for v in values]
        if len(set(canonical)) != len(canonical):
            before(f"{prefix}grid.{_show_key(path)}: a value is listed twice (it would be the same runs twice)")
        if path in overrides:
            before(f"{prefix}grid.{_show_key(path)}: also in overrides (a key is either fixed or swept)")
    for kind, entries in (("overrides", overrides), ("grid", grid)):
        for path, value in entries.items():
            _check_path(base, path, value[0] if kind == "grid" else value, f"{prefix}{kind}.{_show_key(path)}",
                        before)

    record = dict(RECORD_KEYS)
    raw_record = _mapping(_merged(top.get("record"), own.get("record")), f"{prefix}record", before)
    for k, v in raw_record.items():
        if k not in RECORD_KEYS:
            before(f"{prefix}record.{k}: unknown key (valid: {', '.join(RECORD_KEYS)})")
        elif k == "every":
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                before(f"{prefix}record.every: must be a whole number of ticks >= 1, got {v!r}")
            else:
                record[k] = v
        elif not isinstance(v, bool):
            before(f"{prefix}record.{k}: must be true or false, got {_kind(v)}")
        else:
            record[k] = v

    window_ticks = ticks
    raw_summary = _mapping(_merged(top.get("summary"), own.get("summary")), f"{prefix}summary", before)
    for k, v in raw_summary.items():
        if k != "window":
            before(f"{prefix}summary.{k}: unknown key (valid: window)")
        elif v is not None:
            window = _positive(v, f"{prefix}summary.window", before)
            window_ticks = round(window / dt)
            if not 1 <= window_ticks <= ticks:
                before(f"{prefix}summary.window: {window:g} s is not between one tick ({dt:g} s) and the run's "
                       f"duration ({duration:g} s)")

    chain_key, chain_reverse = None, False
    key, raw = setting("chain")
    if raw is not None:
        chain = raw if isinstance(raw, dict) else {}
        if not isinstance(raw, dict):
            before(f"{key}: must be a mapping {{key: <a grid key>, reverse: false}}, got {_kind(raw)}")
        for k in chain:
            if k not in ("key", "reverse"):
                before(f"{key}.{k}: unknown key (valid: key, reverse)")
        chain_key = chain.get("key")
        if isinstance(raw, dict) and (not isinstance(chain_key, str) or chain_key not in grid):
            known = ", ".join(_show_key(k) for k in list(grid)[:10]) + (", ..." if len(grid) > 10 else "")
            before(f"{key}.key: must be one of the grid's keys ({known or 'the grid is empty'}), got "
                   f"{_show_key(chain_key) if isinstance(chain_key, str) else _kind(chain_key)}")
        elif isinstance(raw, dict) and len(grid[chain_key]) > MAX_CHAIN_LINKS:
            before(f"{key}.key: {len(grid[chain_key]):,} values make a chain of as many links; a chain has at "
                   f"most {MAX_CHAIN_LINKS:,} (one worker runs its links one after the other)")
        chain_reverse = chain.get("reverse", False)
        if not isinstance(chain_reverse, bool):
            before(f"{key}.reverse: must be true or false")
    if before.count:
        return None
    return Experiment(name=name, dt=dt, ticks=ticks, window_ticks=window_ticks, seeds=seeds, overrides=overrides,
                      grid=grid, record=record, chain_key=chain_key, chain_reverse=bool(chain_reverse))


class _Count:
    """A problem collector that counts (to tell whether an experiment had problems)."""

    def __init__(self, fail):
        self.fail, self.count = fail, 0

    def __call__(self, problem: str) -> None:
        self.count += 1
        self.fail(problem)


def _positive(raw: Any, key: str, fail, minimum: float = 0.0, maximum: float = math.inf) -> float:
    """A number of seconds > 0 (and within [minimum, maximum] when given)."""
    try:
        value = float(raw) if isinstance(raw, (int, float)) and not isinstance(raw, bool) else math.nan
    except OverflowError:  # an int beyond float64
        fail(f"{key}: {_show(raw)} is too large (at most {maximum:g} s)")
        return maximum if math.isfinite(maximum) else 1.0
    if not math.isfinite(value) or value <= 0:
        fail(f"{key}: must be a number > 0 (seconds), got {_show(raw)}")
        return 1.0 if minimum <= 1.0 <= maximum else minimum
    if not minimum <= value <= maximum:
        fail(f"{key}: {value:g} s is outside {minimum:g} .. {maximum:g} s")
        return min(max(value, minimum), maximum)
    return value


def _show(value: Any, limit: int = 60) -> str:
    """``repr`` of a value from the file, cut to ``limit`` characters (an int of 10⁵ digits has no repr)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 200:
        return f"an integer of {value.bit_length():,} bits"
    text = repr(value) if not isinstance(value, (dict, list)) else _kind(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _show_key(path: Any) -> str:
    """A key path as errors show it: cut to MAX_KEY_PATH_CHARS (a 20,000-segment path was echoed whole)."""
    text = path if isinstance(path, str) else repr(path)
    return text if len(text) <= MAX_KEY_PATH_CHARS else f"{text[:60]}... ({len(text):,} characters)"


def _mapping(raw: Any, key: str, fail) -> dict:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        fail(f"{key}: must be a mapping of key paths to values, got {_kind(raw)}")
        return {}
    return dict(raw)


def _check_path(base: dict, path: Any, value: Any, where: str, fail) -> None:
    """The path exists in the base scene, and the scene format knows its key (probed with the scene loader:
    the base scene with this one override; only an *unknown key* reported there makes the path wrong — any
    other refusal is about the value, which the run reports)."""
    if not isinstance(path, str):
        fail(f"{where}: a key path must be a text, got {_kind(path)}")
        return
    probe = copy.deepcopy(base)
    try:
        set_key_path(probe, path, value)
    except ValueError as exc:
        fail(f"{where}: {exc}")
        return
    try:
        scene_from_dict(probe, "<probe>")
    except SceneError as exc:
        unknown = [p for p in exc.problems if ": unknown key (valid:" in p]
        if unknown:
            fail(f"{where}: the scene format has no such key ({unknown[0]})")


# ---- the plan ---------------------------------------------------------------------------------------------

def run_id(scene: dict, seed: int | None, experiment: Experiment, previous: str | None, code: str) -> str:
    """A run's identity: SHA-256 (hex, 24 digits) of everything that decides what it computes."""
    identity = {"scene": scene, "seed": seed, "dt_ns": max(1, round(experiment.dt * 1e9)),
                "ticks": experiment.ticks, "window_ticks": experiment.window_ticks, "record": experiment.record,
                "previous": previous, "code": code}
    text = json.dumps(identity, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def plan(sweep: Sweep, code: str | None = None) -> list[Task]:
    """Every task of the sweep: the grid's product x seeds per experiment; along a chain key, one task per
    combination of the other keys and seed, its links in the key's order (reversed with ``reverse``)."""
    code = code or code_version()
    tasks: list[Task] = []
    for e in sweep.experiments:
        keys = list(e.grid)
        outer = [k for k in keys if k != e.chain_key]
        chain_values = (e.grid[e.chain_key][::-1] if e.chain_reverse else e.grid[e.chain_key]) \
            if e.chain_key else [None]
        for combination in itertools.product(*(e.grid[k] for k in outer)):
            # the links' scenes, built and checked once: the seeds share them (the runs only read them)
            links = []
            for chain_value in chain_values:
                params = dict(zip(outer, combination))
                if e.chain_key:
                    params[e.chain_key] = chain_value
                params = {k: params[k] for k in keys}  # the file's order
                scene = copy.deepcopy(sweep.base_scene)
                for path, value in {**e.overrides, **params}.items():
                    set_key_path(scene, path, value)
                links.append((params, scene, _refusal(scene, sweep.source, params)))
            for seed in (e.seeds if e.seeds is not None else [None]):
                previous = None
                runs = []
                for link, (params, scene, refused) in enumerate(links):
                    identity = run_id(scene, seed, e, previous, code)
                    runs.append(Run(id=identity, experiment=e.name, params=params, seed=seed, link=link,
                                    scene=scene, refused=refused))
                    previous = identity
                tasks.append(Task(id=runs[-1].id, experiment=e, runs=runs))
    return tasks


def _refusal(scene: dict, source: str, params: dict) -> str | None:
    try:
        scene_from_dict(copy.deepcopy(scene), run_source(source, params))
    except SceneError as exc:
        return str(exc)
    return None


def run_source(source: str, params: dict) -> str:
    """What a run's scene errors name as their file: the sweep file and the run's values."""
    values = ", ".join(f"{k} = {json.dumps(v)}" for k, v in params.items())
    return f"{source} (run {values})" if values else source
