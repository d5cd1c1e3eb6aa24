"""The output directory of a sweep: per-run fragments, and the tables assembled from them.

Layout of ``<out>/``::

    sweep.json                     the sweep as planned: file, description, code version, experiments, keys
    runs.parquet                   one row per run and flock: the run's labels, status, error, the summary
    flocks.parquet                 one row per run, sample and flock: the order parameters (record.flocks)
    bodies.parquet                 one row per run, sample and body: pose and twist (record.bodies)
    fragments/<run>.run.parquet    what one run measured (written last: its presence means "finished")
    fragments/<run>.flocks.parquet, fragments/<run>.bodies.parquet
    bags/<run>/                    a rosbag2 MCAP per run (record.bag)

Every fragment is written to a temporary name and renamed (atomic on one filesystem), so a crash, a Ctrl-C or a
killed worker leaves either a whole fragment or none; a run's ``.run`` fragment is renamed after its samples,
so a finished run has all its fragments.  A fragment damaged afterwards (a truncated copy, a disk error) makes
its run unfinished: :func:`finished` checks every fragment's footer, :func:`assemble` drops a run whose
fragment does not read (its ``.run`` fragment removed, the message kept), and the next invocation runs it again.
One fragment per run identity: a run done twice (a worker that was lost after all, a retry) replaces its
fragment with the same content — no duplicate rows by construction.

The tables (Parquet, written with pyarrow; pandas, polars, DuckDB or pyarrow read them, cgp_sim need not be
installed) are tidy (one observation per row, one table per kind of observation) and carry each run's labels
as columns: ``experiment``, ``run`` (its identity), ``task`` (the chain it belongs to; a single run's own
identity), ``link`` (its place in the chain), ``seed``, one column per swept key path (named by it:
``flocks[school].couzin.orientation_width``), ``dt`` and ``duration`` [s].  ``runs.parquet`` also has the run's
resolved scene as JSON text (``scene``).  They are assembled from the fragments of the sweep's planned runs
at the end of every invocation (:func:`assemble`), in plan order.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from .spec import Sweep

FRAGMENTS = "fragments"
SAMPLE_KINDS = ("flocks", "bodies")
INT64 = (-2**63, 2**63 - 1)
RUN_COLUMNS = [("flock", pa.string()), ("count", pa.int64()), ("polarization", pa.float64()),
               ("milling", pa.float64()), ("radius_of_gyration", pa.float64()),
               ("mean_nearest_neighbor_distance", pa.float64()), ("polarization_end", pa.float64()),
               ("milling_end", pa.float64()), ("groups", pa.int64()), ("order_class", pa.string())]
RUN_SCHEMA = pa.schema([("run", pa.string()), ("status", pa.string()), ("error", pa.string()),
                        ("wall_s", pa.float64()), ("worker", pa.string()), *RUN_COLUMNS])


class OutputError(OSError):
    """The output directory cannot be used (not a directory, cannot be made or written); says which and why."""


def fragment(out: Path, run_id: str, kind: str) -> Path:
    return out / FRAGMENTS / f"{run_id}.{kind}.parquet"


def _write_atomically(table: pa.Table, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def run_table(result: dict, worker: str) -> pa.Table:
    """A run's ``.run`` fragment: one row per flock of its summary (one row without a flock if it has none or
    failed)."""
    rows = result["summary"] or [{}]
    columns = {"run": [result["id"]] * len(rows), "status": [result["status"]] * len(rows),
               "error": [result["error"]] * len(rows), "wall_s": [float(result["wall_s"])] * len(rows),
               "worker": [worker] * len(rows)}
    for name, _ in RUN_COLUMNS:
        columns[name] = [row.get(name) for row in rows]
    return pa.Table.from_pydict(columns, schema=RUN_SCHEMA)


def prepare_output(out: Path) -> Path:
    """Make the output directory (and its ``fragments/``) and prove it writable before anything runs: a file
    written and removed.  :class:`OutputError` naming the path and the reason otherwise (``-o`` a regular file,
    a directory that cannot be written, a path under ``/proc``: issue 38 found these after the whole sweep had
    run)."""
    out = Path(out).expanduser()
    try:
        if out.exists() and not out.is_dir():
            raise OutputError(f"-o {out}: exists and is not a directory")
        (out / FRAGMENTS).mkdir(parents=True, exist_ok=True)
        probe = out / FRAGMENTS / f".write-test.{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OutputError:
        raise
    except OSError as exc:
        where = exc.filename or out
        raise OutputError(f"-o {out}: cannot write there ({where}: {exc.strerror or exc})") from None
    return out


def write_fragments(out: Path, results: list[dict], worker: str) -> None:
    """Every run's fragments, samples first, the ``.run`` fragment last (a sample fragment the run no longer has,
    from an earlier, damaged attempt, is removed first)."""
    (out / FRAGMENTS).mkdir(parents=True, exist_ok=True)
    for result in results:
        for kind in SAMPLE_KINDS:
            path = fragment(out, result["id"], kind)
            if result.get(kind) is not None:
                _write_atomically(result[kind], path)
            else:
                path.unlink(missing_ok=True)
        _write_atomically(run_table(result, worker), fragment(out, result["id"], "run"))


def finished(out: Path) -> dict[str, str]:
    """Run identity → status (``done`` / ``failed``) of every run whose ``.run`` fragment reads and whose sample
    fragments have an intact footer (a damaged one: the run is not finished, and is run again)."""
    status: dict[str, str] = {}
    directory = out / FRAGMENTS
    if not directory.is_dir():
        return status
    for path in directory.glob("*.run.parquet"):
        run = path.name.split(".", 1)[0]
        try:
            values = pq.read_table(path, columns=["status"]).column("status").to_pylist()
            for kind in SAMPLE_KINDS:
                sample = fragment(out, run, kind)
                if sample.exists():
                    pq.read_metadata(sample)
        except (OSError, pa.ArrowException):  # unreadable: treat as never run (it is rewritten)
            continue
        status[run] = values[0] if values else "failed"
    return status


def _column_type(values: list) -> pa.DataType:
    """The type of a swept key's column: bool, int64, float64, string, else JSON text (lists, mappings, and
    integers beyond int64)."""
    present = [v for v in values if v is not None]
    if present and all(isinstance(v, bool) for v in present):
        return pa.bool_()
    if present and all(isinstance(v, int) and not isinstance(v, bool) and INT64[0] <= v <= INT64[1]
                       for v in present):
        return pa.int64()
    if any(isinstance(v, int) and not isinstance(v, bool) and not INT64[0] <= v <= INT64[1] for v in present):
        return pa.string()
    if present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
        return pa.float64()
    if present and all(isinstance(v, str) for v in present):
        return pa.string()
    return pa.string()  # JSON text


def _column_value(value, kind: pa.DataType):
    if value is None:
        return None
    if kind == pa.float64():
        return float(value)
    if kind == pa.string() and not isinstance(value, str):
        return json.dumps(value, sort_keys=True)
    return value


def describe(sweep: Sweep, code: str) -> dict:
    """``sweep.json``: what the plot command and a reader need to know about the sweep."""
    return {"source": sweep.source, "name": sweep.name, "description": sweep.description, "title": sweep.title,
            "scene": sweep.scene_name,
            "code_version": code, "keys": sweep.grid_keys(),
            "experiments": [{"name": e.name, "dt": e.dt, "duration": e.duration, "ticks": e.ticks,
                             "window": e.window_ticks * e.dt, "seeds": e.seeds, "grid": e.grid,
                             "overrides": e.overrides, "chain": e.chain_key, "reverse": e.chain_reverse,
                             "record": e.record} for e in sweep.experiments],
            "runs": len(sweep.runs), "tasks": len(sweep.tasks)}


def assemble(out: Path, sweep: Sweep, code: str, damaged: list[str] | None = None) -> dict[str, int]:
    """Write ``runs.parquet``, ``flocks.parquet`` and ``bodies.parquet`` (each when it has rows) from the
    fragments of the sweep's planned runs; returns the row count of each.  A chain whose runs are not all
    finished is left out whole (it is re-run as one task); so is one with a fragment that does not read: its
    runs' ``.run`` fragments are removed (the next invocation runs them again) and a line saying so is appended
    to ``damaged``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep.json").write_text(json.dumps(describe(sweep, code), indent=1) + "\n")
    status = finished(out)
    keys = sweep.grid_keys()
    key_types = {k: _column_type([r.params.get(k) for r in sweep.runs]) for k in keys}
    tables: dict[str, list[pa.Table]] = {"runs": [], "flocks": [], "bodies": []}
    for task in sweep.tasks:
        if not all(r.id in status for r in task.runs):
            continue
        try:
            parts = _task_tables(out, task, keys, key_types)
        except (OSError, pa.ArrowException) as exc:
            for run in task.runs:
                fragment(out, run.id, "run").unlink(missing_ok=True)
            if damaged is not None:
                reason = " ".join(str(exc).split())[:200]
                damaged.append(f"task {task.id}: a fragment does not read ({type(exc).__name__}: {reason}); its runs "
                               "will run again")
            continue
        for name, table in parts:
            tables[name].append(table)
    counts = {}
    for name, parts in tables.items():
        path = out / f"{name}.parquet"
        if not parts:
            if path.exists():
                path.unlink()
            counts[name] = 0
            continue
        table = pa.concat_tables(parts)
        _write_atomically(table, path)
        counts[name] = table.num_rows
    return counts


def _task_tables(out: Path, task, keys: list[str], key_types: dict) -> list[tuple[str, pa.Table]]:
    """The labelled rows of one finished task's runs: (table name, rows) per fragment."""
    tables: list[tuple[str, pa.Table]] = []
    e = task.experiment
    for run in task.runs:
        labels = [("experiment", pa.string(), e.name), ("run", pa.string(), run.id),
                  ("task", pa.string(), task.id), ("link", pa.int32(), run.link),
                  ("seed", pa.int64(), run.seed)]
        labels += [(k, key_types[k], _column_value(run.params.get(k), key_types[k])) for k in keys]
        labels += [("dt", pa.float64(), e.dt), ("duration", pa.float64(), e.duration)]
        for kind in ("run", "flocks", "bodies"):
            path = fragment(out, run.id, kind)
            if kind != "run" and not path.exists():
                continue
            table = pq.read_table(path)
            if kind == "run":
                if not table.schema.equals(RUN_SCHEMA):
                    raise pa.ArrowInvalid(f"{path.name} is not a run fragment (other columns)")
                table = table.drop_columns(["run"])
                extra = [("scene", pa.string(), json.dumps(run.scene, sort_keys=True))]
            else:
                extra = []
            n = table.num_rows
            arrays = [pa.array([value] * n, kind_type) for _, kind_type, value in labels + extra]
            names = [name for name, _, _ in labels + extra]
            for name in names:
                if name in table.column_names:
                    table = table.drop_columns([name])
            labelled = pa.Table.from_arrays(arrays + table.columns, names=names + table.column_names)
            tables.append(("runs" if kind == "run" else kind, labelled))
    return tables
