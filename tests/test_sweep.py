"""cgp-sim-sweep (issue 26): sweep files, run identities, the runs' tables, chains, resume, faults, and the Dask
engine on a real local cluster (``distributed.LocalCluster``) and on a real ``dask scheduler`` with ``dask
worker`` processes on 127.0.0.1 — no mock of Dask.  Waiting on processes uses deadlines on what they show
(files, the scheduler's worker list, exit codes), never sleeps as synchronisation."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from cgp_sim_ros.sweep.spec import SweepError, code_version, load_sweep, parse_sweep, run_id
from cgp_sim_ros.sweep.store import FRAGMENTS

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
WO = "flocks[school].couzin.orientation_width"

#: a small Couzin school: ~1 ms per tick
SMALL = """
scene: couzin_torus
dt: 0.1
duration: {duration}
seeds: {seeds}
overrides:
  flocks[school].count: {count}
grid:
  flocks[school].couzin.orientation_width: {widths}
record: {{every: {every}}}
summary: {{window: {window}}}
"""


def small(tmp_path: Path, name="small.yaml", *, duration=2, seeds=2, count=30, widths="[0.5, 2.0]", every=5,
          window=1, extra="") -> Path:
    path = tmp_path / name
    path.write_text(SMALL.format(duration=duration, seeds=seeds, count=count, widths=widths, every=every,
                                 window=window) + textwrap.dedent(extra))
    return path


def deadline_wait(condition, timeout: float, what: str, interval: float = 0.05):
    """Poll ``condition`` until it returns something true or the deadline passes (then fail naming ``what``)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(interval)
    pytest.fail(f"timed out after {timeout:g} s waiting for {what}")


def sweep_command() -> list[str]:
    path = VENV_BIN / "cgp-sim-sweep"
    if not path.exists():
        pytest.fail("cgp-sim-sweep is not installed: run `make setup` first")
    return [str(path)]


@pytest.fixture(scope="module")
def client():
    """The command's own LocalCluster (engine.local_cluster: real worker processes) of two, shared by the
    in-process tests."""
    from distributed import Client

    from cgp_sim_ros.sweep.engine import local_cluster

    cluster = local_cluster(2)
    client = Client(cluster)
    yield client
    client.close()
    cluster.close()


# ---- the sweep file ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, key, reason", [
    ("scene: default\nduration: 1\ngrdi: {}\n", "grdi", "unknown key (valid:"),
    ("duration: 1\n", "scene", "missing"),
    ("scene: no_such_scene\nduration: 1\n", "scene", "no built-in scene of that name"),
    ("scene: default\n", "duration", "missing"),
    ("scene: default\nduration: 1\ngrid:\n  bodies[nosuch].mass: [1, 2]\n", "grid.bodies[nosuch].mass",
     "no entry named 'nosuch' in bodies (names: ball, crate"),
    ("scene: default\nduration: 1\ngrid:\n  bodies[9].mass: [1, 2]\n", "grid.bodies[9].mass", "index out of range"),
    ("scene: default\nduration: 1\noverrides: {world.substeps.x: 1}\n", "overrides.world.substeps.x",
     "is a int, not a mapping"),
    ("scene: couzin_torus\nduration: 1\ngrid:\n  flocks[school].couzin.orientation_widht: [1, 2]\n",
     "grid.flocks[school].couzin.orientation_widht", "the scene format has no such key"),
    ("scene: default\nduration: 1\ngrid: {gravity: [1]}\n", "grid.gravity", "a key path starts at a scene section"),
    ("scene: default\nduration: 1\ngrid: {bodies[ball].mass: [1]}\n", "line 3, column 14",
     "a key path with [...] inside {...} needs quotes"),
    ("scene: default\nduration: 1\ngrid: {world.substeps: 4}\n", "grid.world.substeps", "non-empty list"),
    ("scene: default\nduration: 1\ngrid: {world.substeps: [1, 1]}\n", "grid.world.substeps", "listed twice"),
    ("scene: default\ndt: 0.1\nduration: 1.05\n", "duration", "not a whole number of ticks"),
    ("scene: default\nduration: 1\nsummary: {window: 2}\n", "summary.window", "between one tick"),
    ("scene: default\nduration: 1\nrecord: {every: 0}\n", "record.every", "whole number of ticks >= 1"),
    ("scene: default\nduration: 1\nrecord: {poses: true}\n", "record.poses", "unknown key"),
    ("scene: default\nduration: 1\ngrid: {world.substeps: [1, 2]}\nchain: {key: world.sleep}\n", "chain.key",
     "must be one of the grid's keys (world.substeps)"),
    ("scene: default\nduration: 1\nexperiments: {a: {scene: pyramid}}\n", "experiments.a.scene", "unknown key"),
    ("scene: default\nduration: 1\nseeds: -3\n", "seeds", "must be >= 1"),
])
def test_sweep_file_errors_name_the_file_key_and_reason(text, key, reason):
    with pytest.raises(SweepError) as error:
        parse_sweep(text, "my_sweep.yaml")
    message = str(error.value)
    assert message.startswith("my_sweep.yaml: "), message
    line = next((li for li in message.splitlines() if f": {key}: " in li), None)
    assert line is not None, f"no problem names {key!r}: {message}"
    assert reason in line, message


def test_a_sweep_file_is_read_only_if_it_is_a_regular_file_and_with_a_bound(tmp_path):
    """Issue 27's rule for every file a user names: a FIFO would block the read forever, a link to /dev/zero
    would never end; both are refused by kind before anything is opened, and a big file by its size."""
    import os

    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    zero = tmp_path / "zero.yaml"
    zero.symlink_to("/dev/zero")
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (5 << 20) + "\n")  # over MAX_SWEEP_BYTES (4 MiB)
    for path, reason in ((fifo, "FIFO"), (zero, "device"), (big, "bytes")):
        with pytest.raises(SweepError) as error:
            load_sweep(path)
        assert str(error.value).startswith(f"{path}: ") and reason in str(error.value), str(error.value)


def test_the_cli_reports_a_bad_sweep_file_with_exit_2(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("scene: default\nduration: 1\ngrid:\n  bodies[ball].mas: [1, 2]\n")
    done = subprocess.run(sweep_command() + ["run", str(path), "-o", str(tmp_path / "out")], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert f"{path}: grid.bodies[ball].mas: the scene format has no such key" in done.stderr
    assert not (tmp_path / "out").exists()  # nothing ran


def test_key_paths_resolve_into_the_scene_the_runs_load():
    sweep = parse_sweep(textwrap.dedent("""
        scene: default
        duration: 0.5
        overrides:
          flocks[0].count: 40
          flocks[fish].spawn.center[2]: 7.5
        grid:
          bodies[ball].mass: [1.5, 3.0]
          world.substeps: [1, 4]
    """), "paths.yaml")
    from cgp_core.scene import scene_from_dict

    assert len(sweep.runs) == 4
    seen = set()
    for run in sweep.runs:
        scene = scene_from_dict(run.scene)
        ball = next(b for b in scene.bodies if b.name == "ball")
        assert ball.mass == run.params["bodies[ball].mass"]
        assert scene.world.substeps == run.params["world.substeps"]
        assert scene.flocks[0].count == 40 and scene.flocks[0].spawn_center[2] == 7.5
        seen.add((ball.mass, scene.world.substeps))
        assert run.refused is None
    assert seen == {(1.5, 1), (1.5, 4), (3.0, 1), (3.0, 4)}
    # the base scene itself is untouched by the overrides
    assert "substeps" not in (sweep.base_scene.get("world") or {}) or sweep.base_scene["world"]["substeps"] != 1


def test_a_value_the_scene_loader_refuses_is_a_refused_run_naming_the_key():
    sweep = parse_sweep("scene: default\nduration: 0.5\ngrid:\n  bodies[ball].mass: [2.0, 0]\n", "values.yaml")
    refused = sweep.refused
    assert [r.params["bodies[ball].mass"] for r in refused] == [0]
    assert "values.yaml (run bodies[ball].mass = 0): bodies[0] (ball).mass: must be > 0, got 0" in refused[0].refused


def test_the_issues_spelling_finds_the_builtin_sweep():
    assert load_sweep("examples/couzin_hysteresis.yaml").source == load_sweep("couzin_hysteresis").source
    hysteresis = load_sweep("couzin_hysteresis")
    assert {e.name: len([t for t in hysteresis.tasks if t.experiment is e]) for e in hysteresis.experiments} == \
        {"random": 144, "increasing": 12, "decreasing": 12}
    assert len(hysteresis.runs) == 12 * 12 * 3


# ---- identities ---------------------------------------------------------------------------------------------

def test_run_identities_are_stable_and_tell_runs_apart(tmp_path):
    path = small(tmp_path, extra="""
        experiments:
          random: {}
          up:
            chain:
              key: flocks[school].couzin.orientation_width
    """)
    sweep = load_sweep(path)
    ids = [r.id for r in sweep.runs]
    # the same file in another interpreter (another hash seed): the same identities
    code = (f"import sys; sys.path.insert(0, {str(REPO)!r}); from cgp_sim_ros.sweep.spec import load_sweep; "
            f"print(' '.join(r.id for r in load_sweep({str(path)!r}).runs))")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                           env={**os.environ, "PYTHONHASHSEED": "12345"})
    assert other.stdout.split() == ids, other.stderr
    # the random start at 0.5 and the chain's first link are the same run; every other run is distinct
    random = {(r.params[WO], r.seed): r for r in sweep.runs if r.experiment == "random"}
    chained = [r for r in sweep.runs if r.experiment == "up"]
    assert all(r.id == random[(r.params[WO], r.seed)].id for r in chained if r.link == 0)
    assert all(r.id != random[(r.params[WO], r.seed)].id for r in chained if r.link == 1)  # its start differs
    assert len(set(ids)) == len(ids) - 2
    # and what changes a run's result changes its identity
    run, e = sweep.runs[0], sweep.experiments[0]
    base = run_id(run.scene, run.seed, e, None, code_version())
    assert base == run.id
    variants = {"seed": run_id(run.scene, 7, e, None, code_version()),
                "code": run_id(run.scene, run.seed, e, None, code_version() + "x"),
                "previous link": run_id(run.scene, run.seed, e, "0" * 24, code_version())}
    for change, (key, value) in {"dt": ("dt", 0.05), "ticks": ("ticks", 99), "window": ("window_ticks", 3),
                                 "record": ("record", {**e.record, "every": 1})}.items():
        original = getattr(e, key)
        setattr(e, key, value)
        variants[change] = run_id(run.scene, run.seed, e, None, code_version())
        setattr(e, key, original)
    scene = json.loads(json.dumps(run.scene))
    scene["flocks"][0]["couzin"]["noise"] = 0.06
    variants["scene"] = run_id(scene, run.seed, e, None, code_version())
    assert len(set(variants.values()) | {base}) == len(variants) + 1, variants


# ---- runs on a LocalCluster -----------------------------------------------------------------------------------

def _block_cgp_sim(code: str) -> str:
    """Python code that runs ``code`` where cgp_sim (and ROS) cannot be imported."""
    return textwrap.dedent("""
        import importlib.abc, sys
        class Blocked(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("cgp_core", "cgp_sim_ros", "msgs_config", "rclpy"):
                    raise ImportError(f"blocked: {name}")
        sys.meta_path.insert(0, Blocked())
    """) + textwrap.dedent(code)


def test_a_local_sweep_writes_tidy_tables_that_pyarrow_alone_reads(client, tmp_path):
    from cgp_sim_ros.sweep.engine import run_sweep

    sweep = load_sweep(small(tmp_path, widths="[0.5, 2.0, 13.0]", duration=2, every=5))
    outcome = run_sweep(sweep, tmp_path / "out", client=client, quiet=True)
    assert (outcome.ran, outcome.failed, outcome.exit_code) == (6, 0, 0)
    # every worker ran with the quiet settings and with its objects frozen out of the collector's way
    from cgp_sim_ros.sweep.engine import QUIET_WORKERS

    def worker_settings():
        import gc

        import dask

        return {key: dask.config.get(key) for key in QUIET_WORKERS}, gc.get_freeze_count()

    settings = client.run(worker_settings)
    assert len(settings) == 2
    for config, frozen in settings.values():
        assert config == QUIET_WORKERS and frozen > 10_000, (config, frozen)
    code = _block_cgp_sim(f"""
        import json, pyarrow.parquet as pq
        out = {str(tmp_path / 'out')!r}
        runs, flocks = pq.read_table(out + "/runs.parquet"), pq.read_table(out + "/flocks.parquet")
        print(json.dumps({{"runs": runs.column_names, "flocks": flocks.column_names, "n_runs": runs.num_rows,
                          "n_flocks": flocks.num_rows,
                          "per_run": sorted(set(flocks.column("run").to_pylist())),
                          "ticks": sorted(set(flocks.column("tick").to_pylist())),
                          "status": runs.column("status").to_pylist(),
                          "widths": runs.column({WO!r}).to_pylist(), "seeds": runs.column("seed").to_pylist()}}))
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    assert seen["n_runs"] == 6 and seen["status"] == ["done"] * 6
    assert sorted(zip(seen["widths"], seen["seeds"])) == sorted((w, s) for w in (0.5, 2.0, 13.0) for s in (0, 1))
    assert seen["ticks"] == [0, 5, 10, 15, 20] and seen["n_flocks"] == 6 * 5 and len(seen["per_run"]) == 6
    for column in ("experiment", "run", "task", "link", "seed", WO, "dt", "duration", "status", "error", "flock",
                   "polarization", "milling", "groups", "order_class", "scene"):
        assert column in seen["runs"]
    for column in ("experiment", "run", "seed", WO, "tick", "time", "flock", "polarization", "milling",
                   "centroid_x", "radius_of_gyration", "mean_nearest_neighbor_distance"):
        assert column in seen["flocks"]
    # the summary's end values are the last sample's
    runs = pq.read_table(tmp_path / "out" / "runs.parquet").to_pylist()
    flocks = pq.read_table(tmp_path / "out" / "flocks.parquet").to_pylist()
    for row in runs:
        last = max((f for f in flocks if f["run"] == row["run"]), key=lambda f: f["tick"])
        assert last["polarization"] == row["polarization_end"] and last["milling"] == row["milling_end"]
        assert row["groups"] >= 1 and row["count"] == 30
    # the figure and its table from these tables
    from cgp_sim_ros.sweep.cli import main

    assert main(["plot", str(tmp_path / "out"), "-o", str(tmp_path / "fig.png")]) == 0
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_chain_carries_the_state_from_link_to_link(client, tmp_path):
    """Each link of a chain starts exactly where the previous one ended — the bodies' poses and velocities, the
    boids — not from the scene's start; and the Couzin noise stream goes on (the chain equals one flock whose
    parameter is changed in place, as the earlier figure script ran it)."""
    from cgp_sim_ros.sweep.engine import run_sweep

    path = tmp_path / "chain.yaml"
    path.write_text(textwrap.dedent("""
        scene: predator
        dt: 0.05
        duration: 1
        seeds: [3]
        overrides:
          flocks[school].count: 40
          bodies[shark].linear_velocity: [2.0, 0.5, 0.0]   # the shark moves: its pose is state to carry
        grid:
          flocks[school].couzin.orientation_width: [1.0, 3.0, 6.0]
        record: {every: 1, bodies: true}
        experiments:
          fresh: {}
          chained:
            chain:
              key: flocks[school].couzin.orientation_width
    """))
    sweep = load_sweep(path)
    assert run_sweep(sweep, tmp_path / "out", client=client, quiet=True).exit_code == 0
    flocks = pq.read_table(tmp_path / "out" / "flocks.parquet").to_pylist()
    bodies = pq.read_table(tmp_path / "out" / "bodies.parquet").to_pylist()
    columns = ("polarization", "milling", "centroid_x", "centroid_y", "centroid_z", "radius_of_gyration")
    chain = {r["link"]: [f for f in flocks if f["run"] == r["run"] and f["experiment"] == "chained"]
             for r in pq.read_table(tmp_path / "out" / "runs.parquet").to_pylist() if r["experiment"] == "chained"}
    assert sorted(chain) == [0, 1, 2]
    for link in (1, 2):
        end = max(chain[link - 1], key=lambda f: f["tick"])
        start = min(chain[link], key=lambda f: f["tick"])
        assert start["tick"] == 0 and start["time"] == pytest.approx(end["time"], abs=1e-12)
        assert [start[c] for c in columns] == [end[c] for c in columns]  # exactly the state it ended in
        fresh = next(f for f in flocks if f["experiment"] == "fresh" and f["tick"] == 0 and f[WO] == start[WO])
        assert fresh["centroid_x"] != start["centroid_x"]  # not the scene's start
        for body in ("shark",):
            b_end = max((b for b in bodies if b["run"] == end["run"] and b["body"] == body), key=lambda b: b["tick"])
            b_start = next(b for b in bodies if b["run"] == start["run"] and b["body"] == body and b["tick"] == 0)
            for c in ("x", "y", "z", "qx", "qw"):
                assert b_start[c] == b_end[c]
            for c in ("vx", "vy", "vz"):
                assert b_start[c] == pytest.approx(b_end[c], rel=1e-12, abs=1e-12)
    # the chain is one flock whose parameter changed in place, noise stream included
    from dataclasses import replace

    from cgp_core.world import World

    run0 = next(r for r in sweep.runs if r.experiment == "chained" and r.link == 0)
    from cgp_core.scene import scene_from_dict

    world = World(scene_from_dict(run0.scene), dt=0.05, seed=3)
    for width in (1.0, 3.0, 6.0):
        flock = world.flocks[0]
        flock.params = replace(flock.params, couzin=replace(flock.params.couzin, orientation_width=width))
        for _ in range(20):
            world.step()
    last = max(chain[2], key=lambda f: f["tick"])
    assert world.flocks[0].order().polarization == last["polarization"]
    assert world.flocks[0].centroid()[0] == last["centroid_x"]


def test_resume_runs_only_what_is_missing_and_a_failing_run_is_a_row(client, tmp_path):
    from cgp_sim_ros.sweep.engine import run_sweep

    path = tmp_path / "faults.yaml"
    path.write_text(textwrap.dedent("""
        scene: default
        duration: 0.5
        overrides:
          flocks[fish].count: 20
        grid:
          world.gravity: [[0, 0, -9.81], [0, 0, -1.0e300], [0, 0, -3.7]]
          bodies[ball].mass: [2.0, 0]
        record: {every: 10}
    """))
    sweep = load_sweep(path)
    # gravity 1e300 m/s² is refused by the scene loader since issue 27 (cgp_core.limits), as mass 0 is
    assert [r.params["bodies[ball].mass"] for r in sweep.refused] == [0, 2.0, 0, 0]
    out = tmp_path / "out"
    first = run_sweep(sweep, out, client=client, quiet=True)
    assert (first.ran, first.failed, first.exit_code) == (6, 4, 1)
    runs = pq.read_table(out / "runs.parquet").to_pylist()
    by = {(json.loads(r["world.gravity"])[2], r["bodies[ball].mass"]): r for r in runs}
    assert len(runs) == 6 and len(by) == 6
    assert by[(-1e300, 2.0)]["status"] == "failed" and "world.gravity[2]: must be in [-1000, 1000] m/s²" in \
        by[(-1e300, 2.0)]["error"]
    assert "bodies[0] (ball).mass: must be > 0, got 0" in by[(-9.81, 0)]["error"]
    assert by[(-9.81, 2.0)]["status"] == by[(-3.7, 2.0)]["status"] == "done"
    assert by[(-3.7, 2.0)]["polarization"] is not None and by[(-1e300, 2.0)]["polarization"] is None
    # a crash lost two finished runs' fragments: only those run again
    fragments = out / FRAGMENTS
    lost = [by[(-9.81, 2.0)]["run"], by[(-3.7, 2.0)]["run"]]
    for run in lost:
        for f in fragments.glob(f"{run}.*"):
            f.unlink()
    kept = {f.name: f.stat().st_mtime_ns for f in fragments.iterdir()}
    again = run_sweep(sweep, out, client=client, quiet=True)
    assert (again.already_finished, again.ran, again.failed) == (4, 2, 0)
    assert all(fragments.joinpath(name).stat().st_mtime_ns == mtime for name, mtime in kept.items())
    assert pq.read_table(out / "runs.parquet").num_rows == 6
    assert run_sweep(sweep, out, client=client, quiet=True).ran == 0
    assert run_sweep(sweep, out, client=client, quiet=True, retry_failed=True).ran == 4


# ---- issue 38: every bad input a named error (exit 2), caps before planning, tables that survive ----------------

_TEN = "[" + ", ".join(str(k) for k in range(10)) + "]"
_HUGE_GRID = "grid:\n" + "".join(f"  flocks[school].couzin.{key}: {_TEN}\n" for key in (
    "orientation_width", "attraction_width", "noise")) + "".join(
    f"  flocks[school].{key}: {values}\n" for key, values in (
        ("count", "[" + ", ".join(str(10 + k) for k in range(10)) + "]"),
        ("boid_size", "[" + ", ".join(str(0.1 * (k + 1)) for k in range(10)) + "]"),
        ("radius", "[" + ", ".join(str(k + 1) for k in range(10)) + "]"),
        ("seed", _TEN), ("fov_deg", "[" + ", ".join(str(100 + 10 * k) for k in range(10)) + "]"))) \
    + f"  world.substeps: {'[' + ', '.join(str(k + 1) for k in range(10)) + ']'}\n"
_CHAIN = "grid:\n  flocks[school].couzin.orientation_width: [" + ", ".join(str(k) for k in range(5000)) + \
    "]\nchain:\n  key: flocks[school].couzin.orientation_width\n"
_LONG_PATH = "overrides:\n  ? world" + ".a" * 20_000 + "\n  : 1\n"


@pytest.mark.parametrize("extra, key, reason", [
    (_HUGE_GRID, "grid", "= 1,000,000,000 runs; a sweep has at most 100,000"),
    ("seeds: 1000000000000\n", "seeds", "1000000000000 seeds; a sweep has at most 100,000 runs"),
    ("seeds: [9223372036854775808]\n", "seeds", "seed 9223372036854775808 is larger than 9223372036854775807"),
    ("dt: 1.0e-320\n", "dt", "is outside 0.0001 .. 1 s"),
    ("duration: 1.0e308\n", "duration", "is more than 100,000,000 ticks"),
    ("duration: " + "9" * 400 + "\n", "duration", "an integer of 1,329 bits is too large"),
    (_CHAIN, "chain.key", "5,000 values make a chain of as many links; a chain has at most 1,000"),
    (_LONG_PATH, "overrides.world.a.a", "a key path has at most 256 characters, this one 40,005"),
])
def test_caps_are_checked_before_anything_is_planned(extra, key, reason):
    """Issue 38, D10-D12 and the 540k-link chain: a grid of 10⁹ runs planned for minutes, ``seeds: 10¹²`` ran
    out of memory, ``dt: 1e-320`` / ``duration: 1e308`` overflowed the tick count, a seed of 2⁶³ broke every
    later assembly of the tables, a 20,000-segment key path took 84 s and was echoed whole.  Each is now one
    named problem, found before a run is planned."""
    text = "scene: couzin_torus\n" + ("" if extra.startswith(("dt", "duration")) else "duration: 1\n") + extra
    if extra.startswith("dt"):
        text += "duration: 1\n"
    with pytest.raises(SweepError) as error:
        parse_sweep(text, "caps.yaml")
    message = str(error.value)
    line = next((li for li in message.splitlines() if li.startswith(f"caps.yaml: {key}")), None)
    assert line is not None and reason in line, message
    assert len(message) < 2000  # nothing echoed whole


def test_bad_options_and_output_directories_are_refused_before_anything_runs(tmp_path):
    """Issue 38, D13 and D15: ``-o`` a regular file or a path that cannot be made (``/proc/self/x``) used to fail
    with a traceback — after the whole sweep had run, for an unwritable directory; ``--scheduler garbage``
    (``tcp://``, ``tcp://[::1``, ``foo://bar:1``) was a ValueError traceback.  Now: exit 2, the reason, nothing
    run."""
    from cgp_sim_ros.sweep.engine import EngineError, scheduler_address

    assert scheduler_address("tcp://127.0.0.1:8786") == "tcp://127.0.0.1:8786"
    assert scheduler_address("[::1]:8786") == "tcp://[::1]:8786"
    path = small(tmp_path, duration=0.5, seeds=1, widths="[1.0]", every=1, window=0.5)
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    cases = [(["-o", str(a_file)], f"-o {a_file}: exists and is not a directory"),
             (["-o", "/proc/self/x"], "-o /proc/self/x: cannot write there"),
             (["-o", str(tmp_path / "out"), "--scheduler", "garbage"], "expected [SCHEME://]HOST:PORT"),
             (["-o", str(tmp_path / "out"), "--scheduler", "tcp://"], "expected [SCHEME://]HOST:PORT"),
             (["-o", str(tmp_path / "out"), "--scheduler", "tcp://[::1"], "Invalid IPv6 URL"),
             (["-o", str(tmp_path / "out"), "--scheduler", "foo://bar:1"], "unknown transport 'foo'")]
    for args, says in cases:
        done = subprocess.run(sweep_command() + ["run", str(path), *args], capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 2 and says in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert not (tmp_path / "out").exists()
    with pytest.raises(EngineError):
        scheduler_address("tcp://host:99999")


def test_a_damaged_fragment_is_found_and_its_run_done_again(client, tmp_path):
    """Issue 38, D14: one truncated ``fragments/*.flocks.parquet`` made every later invocation (``--retry-failed``
    too) an ArrowInvalid traceback.  A fragment whose footer is gone is found before the sweep starts and its run
    done again at once; one damaged inside (its footer intact) is found when the tables are assembled: reported
    as not finished (exit 1), and done by the next invocation."""
    from cgp_sim_ros.sweep.engine import run_sweep

    sweep = load_sweep(small(tmp_path, duration=1, seeds=2, widths="[0.5, 2.0]", every=5, window=0.5))
    out = tmp_path / "out"
    assert run_sweep(sweep, out, client=client, quiet=True).exit_code == 0
    whole = pq.read_table(out / "flocks.parquet").num_rows
    first, second = sorted((out / FRAGMENTS).glob("*.flocks.parquet"))[:2]
    with first.open("r+b") as f:  # cut: no footer
        f.truncate(100)
    again = run_sweep(sweep, out, client=client, quiet=True)
    assert (again.ran, again.exit_code) == (1, 0)
    assert pq.read_table(out / "flocks.parquet").num_rows == whole
    data = bytearray(second.read_bytes())
    data[4:300] = b"\x55" * 296  # the first page's header garbled, the footer intact
    second.write_bytes(bytes(data))
    damaged = run_sweep(sweep, out, client=client, quiet=True)
    assert damaged.exit_code == 1 and len(damaged.not_finished) == 1
    assert "a fragment does not read" in damaged.not_finished[0]
    assert pq.read_table(out / "flocks.parquet").num_rows < whole
    repaired = run_sweep(sweep, out, client=client, quiet=True)
    assert (repaired.ran, repaired.exit_code) == (1, 0)
    assert pq.read_table(out / "flocks.parquet").num_rows == whole


def test_a_swept_integer_beyond_int64_is_a_text_column(client, tmp_path):
    """Issue 38, D12's table half: a swept value the int64 column cannot hold (a run the scene loader may refuse:
    a failed row) makes the key's column JSON text, so the tables are still written and read."""
    from cgp_sim_ros.sweep.engine import run_sweep

    path = small(tmp_path, duration=0.5, seeds=1, widths="[1.0]", every=5, window=0.5, extra="""
        experiments:
          big:
            grid:
              flocks[school].seed: [1, 9223372036854775808]
    """)
    outcome = run_sweep(load_sweep(path), tmp_path / "out", client=client, quiet=True)
    assert outcome.ran == 2
    runs = pq.read_table(tmp_path / "out" / "runs.parquet")
    assert runs.schema.field("flocks[school].seed").type == "string"
    assert sorted(runs.column("flocks[school].seed").to_pylist()) == ["1", "9223372036854775808"]


def test_the_sweep_code_runs_where_ros_cannot_be_imported(tmp_path):
    """What a worker imports and runs (and the command's modules) without rclpy or any ROS message package."""
    path = small(tmp_path, duration=0.5, seeds=1, widths="[1.0]", every=1, window=0.5)
    code = textwrap.dedent(f"""
        import importlib.abc, sys
        class NoRos(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                top = name.split(".")[0]
                if top in ("rclpy", "rosidl_runtime_py", "rpyutils", "ament_index_python") or top.endswith("_msgs"):
                    raise ImportError(f"no ROS here: {{name}}")
        sys.meta_path.insert(0, NoRos())
        try:
            import rclpy
        except ImportError:
            pass
        else:
            sys.exit("rclpy imported")
        import cgp_sim_ros.sweep.cli, cgp_sim_ros.sweep.engine, cgp_sim_ros.sweep.plot, cgp_sim_ros.sweep.store
        from cgp_sim_ros.sweep.runner import run_task
        from cgp_sim_ros.sweep.spec import code_version, load_sweep
        sweep = load_sweep({str(path)!r})
        result = run_task(sweep.tasks[0].payload(sweep.source, code_version()))
        assert result["results"][0]["status"] == "done", result
        assert result["results"][0]["flocks"].num_rows == 6
        print("ok", sorted(m for m in sys.modules if "rclpy" in m or m.endswith("_msgs")))
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok []"


# ---- the command: Ctrl-C, resume ------------------------------------------------------------------------------

def _fragments(out: Path) -> int:
    return len(list((out / FRAGMENTS).glob("*.run.parquet"))) if (out / FRAGMENTS).is_dir() else 0


def test_ctrl_c_stops_cleanly_and_the_same_command_resumes(tmp_path):
    psutil = pytest.importorskip("psutil")
    path = small(tmp_path, duration=60, seeds=4, count=60, widths="[0.5, 2.0]", every=100, window=1)
    out = tmp_path / "out"
    command = sweep_command() + ["run", str(path), "-o", str(out), "--workers", "2"]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline_wait(lambda: _fragments(out) >= 1, 120, "the first finished run")
        family = [proc.pid] + [c.pid for c in psutil.Process(proc.pid).children(recursive=True)]
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, stderr
    assert "the same command to resume" in stderr
    deadline_wait(lambda: not any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE
                                  for p in family), 30, "the command's worker processes to end")
    finished = _fragments(out)
    assert 1 <= finished < 8
    done = subprocess.run(command + ["-q"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"ran {8 - finished} runs (0 failed), {finished} were finished before" in done.stdout
    runs = pq.read_table(out / "runs.parquet").column("run").to_pylist()
    assert len(runs) == len(set(runs)) == 8


# ---- a real cluster: dask scheduler + dask worker processes on 127.0.0.1 -------------------------------------

class Cluster:
    """``dask scheduler`` and ``dask worker`` processes (each its own session, logs in files)."""

    def __init__(self, directory: Path):
        self.directory = directory
        self.processes: dict[str, subprocess.Popen] = {}
        self.logs = []
        scheduler_file = directory / "scheduler.json"
        self._start("scheduler", [str(VENV_BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--no-dashboard", "--scheduler-file", str(scheduler_file)])
        deadline_wait(lambda: scheduler_file.exists() and scheduler_file.stat().st_size > 0, 60,
                      "the scheduler's address file")
        self.address = json.loads(scheduler_file.read_text())["address"]
        from distributed import Client

        self.client = Client(self.address, timeout="30s")

    def _start(self, name: str, command: list[str], env: dict | None = None) -> None:
        log = open(self.directory / f"{name}.log", "wb")
        self.logs.append(log)
        self.processes[name] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, cwd=self.directory,
                                                env=env or os.environ.copy(), start_new_session=True)

    def add_worker(self, name: str, env: dict | None = None) -> None:
        self._start(name, [str(VENV_BIN / "dask"), "worker", self.address, "--name", name, "--nthreads", "1",
                           "--no-nanny", "--no-dashboard", "--host", "127.0.0.1"], env)
        deadline_wait(lambda: name in self.names(), 60, f"worker {name} to join")

    def names(self) -> dict[str, str]:
        """worker name -> address, as the scheduler sees them."""
        return {w["name"]: address for address, w in self.client.scheduler_info(n_workers=-1)["workers"].items()}

    def kill(self, name: str, sig=signal.SIGKILL) -> None:
        process = self.processes.pop(name)
        os.killpg(process.pid, sig)
        process.wait(timeout=30)

    def close(self) -> None:
        self.client.close()
        for name in list(self.processes):
            self.kill(name, signal.SIGTERM if name == "scheduler" else signal.SIGKILL)
        for log in self.logs:
            log.close()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    cluster = Cluster(tmp_path_factory.mktemp("dask"))
    try:
        cluster.add_worker("alpha")
        cluster.add_worker("beta")
        yield cluster
    finally:
        cluster.close()


def test_a_cluster_whose_worker_runs_other_code_is_refused(cluster, tmp_path):
    """A worker importing another cgp_core (a copy with one edited line, first on its PYTHONPATH) reports
    another code version: the sweep refuses to start, naming the worker and both versions."""
    import cgp_core

    installed = Path(cgp_core.__file__).resolve().parent  # (the checkout: make setup installs it editable)
    other = tmp_path / "other"
    shutil.copytree(installed, other / "cgp_core", ignore=shutil.ignore_patterns("__pycache__"))
    with open(other / "cgp_core" / "__init__.py", "a") as f:
        f.write("# an edit the client does not have\n")
    cluster.add_worker("stale", env={**os.environ, "PYTHONPATH": str(other)})
    try:
        path = small(tmp_path, duration=0.5, seeds=1, widths="[1.0]", window=0.5)
        done = subprocess.run(sweep_command() + ["run", str(path), "-o", str(tmp_path / "out"), "--scheduler",
                                                 cluster.address, "-q"], capture_output=True, text=True, timeout=120)
        stale = cluster.names()["stale"]
    finally:
        cluster.kill("stale")
    assert done.returncode == 2, done.stdout + done.stderr
    mine = code_version()
    line = next(li for li in done.stderr.splitlines() if stale in li)
    assert f"runs cgp_sim {mine.split('+')[0]}+" in line and f"this client {mine}" in line
    assert line.split("runs cgp_sim ")[1].split(",")[0] != mine
    assert _fragments(tmp_path / "out") == 0  # nothing ran


def test_a_worker_killed_mid_sweep_loses_nothing_and_duplicates_nothing(cluster, tmp_path):
    deadline_wait(lambda: "stale" not in cluster.names(), 60, "the stale worker to leave")
    path = small(tmp_path, duration=40, seeds=4, count=60, widths="[0.5, 2.0, 5.0]", every=50, window=5)
    out = tmp_path / "out"
    proc = subprocess.Popen(sweep_command() + ["run", str(path), "-o", str(out), "--scheduler", cluster.address,
                                               "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # kill beta while it runs a task, after the first results are in
        deadline_wait(lambda: _fragments(out) >= 1, 120, "the first finished run")
        beta = cluster.names()["beta"]
        deadline_wait(lambda: cluster.client.processing().get(beta), 60, "beta to be running a task")
        cluster.kill("beta")
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stdout + stderr
    runs = pq.read_table(out / "runs.parquet").to_pylist()
    assert len(runs) == 12 and len({r["run"] for r in runs}) == 12
    assert {r["status"] for r in runs} == {"done"}
    assert sorted((r[WO], r["seed"]) for r in runs) == sorted((w, s) for w in (0.5, 2.0, 5.0) for s in range(4))
    flocks = pq.read_table(out / "flocks.parquet")
    keys = list(zip(flocks.column("run").to_pylist(), flocks.column("tick").to_pylist()))
    assert len(keys) == len(set(keys)) == 12 * 9  # ticks 0, 50, ..., 400
    assert len(list((out / FRAGMENTS).glob("*.run.parquet"))) == 12
    assert "ran 12 runs (0 failed), 0 were finished before" in stdout
    assert np.all(np.isfinite([r["polarization"] for r in runs]))


def test_record_bag_writes_a_bag_per_run_with_the_samples(tmp_path):
    """``record.bag``: each run's samples as a rosbag2 MCAP that mcap's own reader reads (clock, the flock's
    poses and stats, the bodies' poses: one message each per sample)."""
    from mcap.reader import make_reader

    from cgp_sim_ros.sweep.runner import run_task

    path = tmp_path / "bag.yaml"
    path.write_text("scene: predator\ndt: 0.1\nduration: 1\noverrides:\n  flocks[school].count: 20\n"
                    "record: {every: 2, bag: true}\n")
    sweep = load_sweep(path)
    payload = sweep.tasks[0].payload(sweep.source, code_version())
    payload["bag_dir"] = str(tmp_path / "bags")
    result = run_task(payload)
    assert result["results"][0]["status"] == "done", result
    files = list((tmp_path / "bags" / sweep.runs[0].id).glob("*.mcap"))
    assert len(files) == 1
    counts: dict[str, int] = {}
    with open(files[0], "rb") as f:
        for _, channel, _message in make_reader(f).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    samples = result["results"][0]["flocks"].num_rows  # ticks 0, 2, 4, 6, 8, 10
    assert samples == 6
    assert counts == {"/clock": 6, "/cgp_sim/bodies/poses": 6, "/cgp_sim/flocks/school/poses": 6,
                      "/cgp_sim/flocks/school/stats": 6}
