"""Compiling the kernels in parallel (cgp_core.warmup, cgp_core.jit): a compile worker compiles only its own
modules' kernels; a parallel kernel's serial twin is a kernel of its own, with its own cache; and a node that
starts with parts of its compile cache missing has them compiled by the workers, so that it compiles none itself.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cgp_core.jit import JIT_DISABLED

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(JIT_DISABLED, reason="the JIT is disabled: nothing is compiled")

WORKER_VIEW = r"""
from numba.core.registry import CPUDispatcher
from cgp_core.collision.detector import narrow_phase
from cgp_core.solver.sequential_impulse import solve_step
from cgp_core.rotation import quat_to_matrices
from cgp_core.boids.rules import _neighbor_sums
from cgp_core.jit import ParallelKernel
print(" ".join(f"{name}={'compiled' if isinstance(k, (CPUDispatcher, ParallelKernel)) else 'plain'}"
               for name, k in [("narrow_phase", narrow_phase), ("solve_step", solve_step),
                               ("quat_to_matrices", quat_to_matrices), ("neighbor_sums", _neighbor_sums)]))
"""


def _kernel_kinds(jit_only: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "CGP_SIM_JIT_ONLY"}
    if jit_only is not None:
        env["CGP_SIM_JIT_ONLY"] = jit_only
    return subprocess.run([sys.executable, "-c", WORKER_VIEW], env=env, capture_output=True, text=True,
                          check=True, timeout=60).stdout.strip()


def test_a_compile_worker_compiles_only_the_modules_it_is_given():
    assert _kernel_kinds("cgp_core.solver,cgp_core.rotation") == \
        "narrow_phase=plain solve_step=compiled quat_to_matrices=compiled neighbor_sums=plain"
    assert _kernel_kinds("cgp_core.boids") == \
        "narrow_phase=plain solve_step=plain quat_to_matrices=plain neighbor_sums=compiled"
    assert _kernel_kinds(None) == \
        "narrow_phase=compiled solve_step=compiled quat_to_matrices=compiled neighbor_sums=compiled"


TWINS = r"""
import sys
from pathlib import Path
import numpy as np
from cgp_core.jit import njit, prange, threads_for

@njit(parallel=True)
def affine(x, out):
    for i in prange(len(x)):
        out[i] = 2.5 * x[i] + 1.0 / (1.0 + x[i] * x[i])

x = np.random.default_rng(7).normal(size=int(sys.argv[1]))
serial, parallel, picked = np.empty_like(x), np.empty_like(x), np.empty_like(x)
affine.serial(x, serial)
affine.parallel(x, parallel)
with threads_for(len(x)):
    affine(x, picked)
np.save(sys.argv[2], np.stack([serial, parallel, picked]))
print(len(affine.serial.signatures), len(affine.parallel.signatures))
"""


@pytest.mark.parametrize("items", [50, 5000])
def test_a_parallel_kernel_and_its_serial_twin_agree_and_have_caches_of_their_own(tmp_path, items):
    """Both twins give the same numbers bit for bit; each writes its own cache files (numba's cache key does
    not tell a parallel compile from a serial one, so one shared file would hand one twin the other's code)."""
    from cgp_core.jit import PARALLEL_MIN_ITEMS

    script = tmp_path / "twins.py"
    script.write_text(TWINS)
    cache = tmp_path / "cache"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    out = subprocess.run([sys.executable, str(script), str(items), str(tmp_path / "r.npy")], env=env,
                         capture_output=True, text=True, check=True, timeout=120).stdout.split()
    serial, parallel, picked = np.load(tmp_path / "r.npy")
    assert serial.tobytes() == parallel.tobytes() == picked.tobytes()
    assert out == ["1", "1"]
    index_files = sorted(p.name.split("-")[0] for p in cache.rglob("*.nbi"))
    assert index_files == ["twins.affine", "twins.affine__serial"]
    # which twin threads_for picks: run again with a warm cache and count what each twin loaded
    probe = TWINS.replace("affine.serial(x, serial)\naffine.parallel(x, parallel)\n", "")
    script.write_text(probe)
    loaded = subprocess.run([sys.executable, str(script), str(items), str(tmp_path / "r2.npy")], env=env,
                            capture_output=True, text=True, check=True, timeout=120).stdout.split()
    assert loaded == (["1", "0"] if items < PARALLEL_MIN_ITEMS else ["0", "1"])
    assert np.load(tmp_path / "r2.npy")[2].tobytes() == picked.tobytes()


def test_big_parallel_loops_are_handed_out_in_chunks_and_the_settings_come_back():
    """Inside threads_for for a big flock, parallel loops are cut into PARALLEL_CHUNK-iteration chunks (so a
    delayed thread's share is taken over), on every thread; a small flock runs the serial twins and changes
    nothing; afterwards the caller's own settings are back."""
    import numba

    from cgp_core.jit import PARALLEL_CHUNK, PARALLEL_MIN_ITEMS, threads_for

    numba.set_num_threads(1)
    before = numba.set_parallel_chunksize(7)
    try:
        with threads_for(PARALLEL_MIN_ITEMS):
            assert numba.get_parallel_chunksize() == PARALLEL_CHUNK
            assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
        assert numba.get_parallel_chunksize() == 7 and numba.get_num_threads() == 1
        with threads_for(PARALLEL_MIN_ITEMS - 1):
            assert numba.get_parallel_chunksize() == 7 and numba.get_num_threads() == 1
    finally:
        numba.set_parallel_chunksize(before)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


UNSPLITTABLE = r"""
import sys
from pathlib import Path
import numpy as np
from cgp_core.jit import njit, prange, refuse_unparallelized_kernels, threads_for

if sys.argv[1] == "strict":
    refuse_unparallelized_kernels()

@njit(parallel=True)
def splittable(x, out):
    for i in prange(x.shape[0]):
        out[i] = 2.0 * x[i]

@njit(parallel=True)
def unsplittable(x, out, half):
    for i in prange(x.shape[0] // 2 if half else x.shape[0]):  # numba cannot split this range
        out[i] = 2.0 * x[i]

x = np.arange(5000.0)
out = np.zeros_like(x)
with threads_for(len(x)):
    splittable(x, out)
    print("splittable compiled", flush=True)
    unsplittable(x, out, False)
print("unsplittable compiled")
"""


def test_the_warm_up_refuses_a_parallel_kernel_numba_could_not_parallelize(tmp_path):
    """A ``prange`` numba cannot split compiles to a plain loop with only a warning: the kernel would quietly
    run on one core.  Where the warm-up runs (make setup, the compile workers) that is an error."""
    script = tmp_path / "unsplittable.py"
    script.write_text(UNSPLITTABLE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    lenient = subprocess.run([sys.executable, str(script), "lenient"], env=env, capture_output=True, text=True,
                             timeout=120)
    assert lenient.returncode == 0 and "unsplittable compiled" in lenient.stdout, lenient.stderr[-2000:]
    assert "no transformation for parallel execution was possible" in lenient.stderr
    strict = subprocess.run([sys.executable, str(script), "strict"], env=dict(env, NUMBA_CACHE_DIR=str(
        tmp_path / "cache2")), capture_output=True, text=True, timeout=120)
    assert strict.returncode != 0 and "splittable compiled" in strict.stdout, strict.stderr[-2000:]
    assert "unsplittable compiled" not in strict.stdout
    assert "no transformation for parallel execution was possible" in strict.stderr


def _seed_cache(cache: Path, modules: tuple[str, ...]) -> None:
    """Copy the checkout's compiled kernels of ``modules`` (packages or modules; ``make setup`` compiled them) into
    ``cache``, laid out as numba's locator for a ``NUMBA_CACHE_DIR`` looks for them."""
    import shutil

    from numba.core.caching import _CacheLocator

    for dotted in modules:
        base = REPO.joinpath(*dotted.split("."))
        for source in sorted(base.rglob("*.py")) if base.is_dir() else [base.with_suffix(".py")]:
            target = cache / _CacheLocator.get_suitable_cache_subpath(str(source))
            for compiled in (source.parent / "__pycache__").glob(f"{source.stem}.*.nb[ic]"):
                target.mkdir(parents=True, exist_ok=True)
                shutil.copy2(compiled, target)


def test_a_node_missing_compiled_kernels_has_them_compiled_in_parallel(start_node, tmp_path):
    """`cgp-sim` on the default scene with a numba cache that lacks two of its parts (contacts, flock): it has
    compile workers compile those side by side, and then finds every kernel it runs in the cache — numba's cache log
    (NUMBA_DEBUG_CACHE) of the node's own process shows loads and not a single save.  (The solver part's kernels
    are copied in from the checkout's cache first: compiling them too, ~23 s of CPU, tested nothing more and was
    the suite's longest test; with a checkout whose solver cache is stale the node compiles all three.)"""
    import re

    from cgp_core.warmup import PARTS

    cache = tmp_path / "cache"
    _seed_cache(cache, next(p for p in PARTS if p.name == "solver").modules)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), NUMBA_DEBUG_CACHE="1")
    node = start_node("--scene", "default", "--realtime", "false", "--duration", "0.5", "--bag",
                      str(tmp_path / "bag"), env=env)
    assert node.wait(timeout=300) == 0, node.log()[-4000:]
    log = node.log()
    assert re.search(r"compiling the simulation kernels \((solver, )?contacts, flock: .* in [23] processes", log), \
        log[-4000:]
    assert "kernels compiled in" in log and "compile worker failed" not in log, log[-4000:]
    saved = [line for line in log.splitlines() if line.startswith("[cache] data saved")]
    loaded = [line for line in log.splitlines() if line.startswith("[cache] data loaded")]
    assert not saved, "the node compiled kernels itself:\n" + "\n".join(saved)
    assert len(loaded) >= 20, log[-4000:]  # the workers' kernels: the contacts', the flock's, and the solver's
    assert (tmp_path / "bag" / "metadata.yaml").exists()
    # `make run` leaves the compile to the node; a `make setup` after it must not take the parts it compiled for
    # complete (its own process would then compile the rest of them — issue 14's flock rules, the grid — one
    # kernel after another): the node's start finds nothing missing, the complete warm-up finds them missing
    ask = ("from cgp_core.warmup import PARTS, missing_parts; "
           "print('missing:', ' '.join(p.name for p in missing_parts(tuple(p for p in PARTS if p.default_scene), "
           "complete=False)), '|', ' '.join(p.name for p in missing_parts(complete=True)))")
    found = subprocess.run([sys.executable, "-c", ask], env=env, capture_output=True, text=True, timeout=60)
    assert found.returncode == 0, found.stderr[-2000:]
    answer = next(line for line in found.stdout.splitlines() if line.startswith("missing:"))
    assert answer in ("missing:  | contacts flock convex robots", "missing:  | solver contacts flock convex robots"), \
        answer


def _workers_using(cache: str) -> list[int]:
    """Live compile workers (``-m cgp_sim_ros.warmup --part``) whose environment names this numba cache."""
    from pathlib import Path

    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmdline = (proc / "cmdline").read_bytes().split(b"\0")
            environ = (proc / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"cgp_sim_ros.warmup" in cmdline and f"NUMBA_CACHE_DIR={cache}".encode() in environ:
            found.append(int(proc.name))
    return found


def test_ctrl_c_while_the_kernels_compile_stops_the_node_and_its_workers(start_node, tmp_path):
    """SIGINT while the workers compile: cgp-sim says so and exits (130), and no worker is left running."""
    import signal
    import time

    cache = str(tmp_path / "cache")
    node = start_node("--scene", "default", "--bag", str(tmp_path / "bag"),
                      env=dict(os.environ, NUMBA_CACHE_DIR=cache))
    deadline = time.monotonic() + 60.0
    while not _workers_using(cache):
        assert node.alive() and time.monotonic() < deadline, "no compile worker started:\n" + node.log()[-3000:]
        time.sleep(0.05)
    node.send(signal.SIGINT)
    assert node.wait(timeout=30) == 130, node.log()[-3000:]
    assert "interrupted while compiling the kernels" in node.log()
    assert _workers_using(cache) == []
    assert not (tmp_path / "bag").exists()  # it stopped before building the node


def test_ctrl_c_while_a_worker_is_being_started_leaves_no_worker_running(tmp_path, monkeypatch):
    """A Ctrl-C that lands between a worker's start and its entry in the worker list (a loaded machine makes
    that window wide): compile_in_parallel is still interrupted, and every worker it started is stopped — none
    compiles on after the caller (seen once in a clean clone's `make test`)."""
    import signal

    from cgp_core import warmup

    (tmp_path / "sleeping_worker.py").write_text("import time\ntime.sleep(60)\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    started = []
    real_popen = subprocess.Popen

    def popen_then_ctrl_c(*args, **kwargs):
        process = real_popen(*args, **kwargs)
        started.append(process)
        if len(started) == 1:
            signal.raise_signal(signal.SIGINT)  # Ctrl-C right after the first worker started
        return process

    monkeypatch.setattr(warmup.subprocess, "Popen", popen_then_ctrl_c)
    parts = [warmup.CompilePart(name=f"part{i}", modules=("cgp_core",), sentinels=()) for i in range(3)]
    try:
        with pytest.raises(KeyboardInterrupt):
            warmup.compile_in_parallel(parts, "sleeping_worker")
        assert len(started) == 3  # the interrupt waited until every worker was started and entered ...
        assert [process.poll() is not None for process in started] == [True] * 3  # ... and stopped them all
    finally:
        for process in started:
            if process.poll() is None:
                process.kill()
                process.wait()


def test_a_part_after_another_starts_once_that_ones_worker_has_finished(tmp_path, monkeypatch):
    """CompilePart.after: the convex part's worker starts when the contacts part's has finished (the kernels
    both call are then loaded from the cache, not compiled twice); the other parts run side by side."""
    from cgp_core import warmup

    (tmp_path / "stamping_worker.py").write_text(
        "import pathlib, sys, time\n"
        f"out = pathlib.Path({str(tmp_path)!r})\n"
        "name = sys.argv[sys.argv.index('--part') + 1]\n"
        "(out / f'{name}.start').touch()\n"
        "deadline = time.monotonic() + 60\n"
        "while name == 'first' and not (out / 'free.start').exists() and time.monotonic() < deadline:\n"
        "    time.sleep(0.01)\n"
        "time.sleep(0.2)\n"
        "(out / f'{name}.end').touch()\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setattr(warmup, "worker_slots", lambda: 2)  # (a part waits: worker_slots() at a time, here 2)
    parts = [warmup.CompilePart("first", ("cgp_core",), ()),
             warmup.CompilePart("second", ("cgp_core",), (), after=("first",)),
             warmup.CompilePart("free", ("cgp_core",), ()),
             warmup.CompilePart("alone", ("cgp_core",), (), after=("not_compiling_now",))]
    assert warmup.compile_in_parallel(parts, "stamping_worker") == {}
    stamp = {f.name: f.stat().st_mtime_ns for f in tmp_path.iterdir() if f.suffix in (".start", ".end")}
    assert len(stamp) == 8  # every worker ran, "alone" too (the part it comes after is not among those given)
    assert stamp["second.start"] >= stamp["first.end"]
    assert stamp["free.start"] <= stamp["first.end"]


def test_with_a_part_that_waits_at_most_worker_slots_run_the_longest_chain_first(tmp_path, monkeypatch):
    """When a part waits for another, at most worker_slots() workers run at once, and the head of the longest
    chain (by CompilePart.cpu_s: contacts, then convex after it) starts first, the shorter parts after it."""
    from cgp_core import warmup

    (tmp_path / "stamping_worker.py").write_text(
        "import pathlib, sys, time\n"
        f"out = pathlib.Path({str(tmp_path)!r})\n"
        "name = sys.argv[sys.argv.index('--part') + 1]\n"
        "(out / f'{name}.start').write_text(str(time.monotonic_ns()))\n"
        "time.sleep(0.3)\n"
        "(out / f'{name}.end').write_text(str(time.monotonic_ns()))\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setattr(warmup, "worker_slots", lambda: 2)
    parts = [warmup.CompilePart("short", ("cgp_core",), (), cpu_s=10.0),
             warmup.CompilePart("long", ("cgp_core",), (), cpu_s=40.0),
             warmup.CompilePart("tail", ("cgp_core",), (), after=("head",), cpu_s=50.0),
             warmup.CompilePart("head", ("cgp_core",), (), cpu_s=20.0)]
    assert warmup.compile_in_parallel(parts, "stamping_worker") == {}
    at = {f.name: int(f.read_text()) for f in tmp_path.iterdir() if f.suffix in (".start", ".end")}
    spans = {name: (at[f"{name}.start"], at[f"{name}.end"]) for name in ("short", "long", "tail", "head")}
    first = sorted(spans, key=lambda name: spans[name][0])
    assert set(first[:2]) == {"head", "long"}  # the chain head (20 + 50 s) and the longest free part
    assert spans["tail"][0] >= spans["head"][1]
    for moment, _ in spans.values():  # never more than 2 at once
        assert sum(start <= moment < end for start, end in spans.values()) <= 2


LOADED_DURING_TICKS = r"""
import sys
from pathlib import Path
import rclpy
from numba.core.registry import CPUDispatcher
from rclpy.parameter import Parameter
from cgp_core.jit import ParallelKernel
from cgp_sim_ros.ros.node import SimNode

def loaded():
    out = {}
    for module in list(sys.modules.values()):
        if not getattr(module, "__name__", "").startswith(("cgp_core", "cgp_sim_ros")):
            continue
        for name, value in vars(module).items():
            kernels = [value] if isinstance(value, CPUDispatcher) else \
                [value.parallel, value.serial] if isinstance(value, ParallelKernel) else []
            for kernel in kernels:
                out[f"{module.__name__}.{kernel.__name__}"] = len(kernel.overloads)
    return out

rclpy.init()
node = SimNode(node_name="kernels_loaded", parameter_overrides=[Parameter("scene", value="default"),
                                                                Parameter("realtime", value=False)])
before = loaded()
for _ in range(int(sys.argv[1])):
    node.tick()
after = loaded()
print("kernels", len(before), "loaded during the ticks:",
      sorted(name for name, count in after.items() if count != before.get(name, 0)))
node.close()
node.destroy_node()
rclpy.try_shutdown()
"""


def test_the_default_scenes_ticks_load_no_kernel():
    """Every kernel the default scene's ticks run is loaded before the first tick (loading one from the cache
    takes ~10 ms, most of a 60 Hz tick's budget).  Its bodies touch for the first time 0.7 s in (the ball
    lands): 1.5 s of ticks, in a process of their own (this one has loaded kernels already)."""
    out = subprocess.run([sys.executable, "-c", LOADED_DURING_TICKS, "90"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    line = next(li for li in out.stdout.splitlines() if li.startswith("kernels"))
    assert int(line.split()[1]) > 20, line  # the scan sees the kernels at all
    assert line.endswith("loaded during the ticks: []"), line


CALLER = """
import sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
from cgp_core.caller import twice_plus_one
print(twice_plus_one(20))
"""


def test_a_cached_kernel_is_recompiled_when_a_module_it_calls_changes(tmp_path):
    """numba's cache checks a kernel against its own file only; cgp_core.jit's stamp also covers the modules that
    file imports.  A kernel in caller.py calls one in callee.py; after an edit of callee.py alone, the next process
    must run the new callee (numba's own stamp would load caller's stale machine code and print 41 again)."""
    package = tmp_path / "pkg" / "cgp_core"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "jit.py").write_text((REPO / "cgp_core" / "jit.py").read_text())
    (package / "caller.py").write_text("from .callee import twice\nfrom .jit import njit\n\n\n@njit\n"
                                       "def twice_plus_one(x):\n    return twice(x) + 1\n")

    def run_with_callee(body: str) -> str:
        (package / "callee.py").write_text(f"from .jit import njit\n\n\n@njit\ndef twice(x):\n    return {body}\n")
        out = subprocess.run([sys.executable, "-c", CALLER, str(tmp_path / "pkg")], capture_output=True, text=True,
                             env={k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}, timeout=120)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    assert run_with_callee("2 * x") == "41"
    assert list((package / "__pycache__").glob("caller.twice_plus_one-*.nbi")), "caller's kernel was not cached"
    assert run_with_callee("3 * x") == "61"


def _covers(modules, module: str) -> bool:
    """Whether a worker with ``CGP_SIM_JIT_ONLY=modules`` compiles ``module``'s kernels (cgp_core.jit's rule)."""
    return any(module == m or module.startswith(m + ".") for m in modules)


def test_every_kernel_a_part_compiles_calls_only_kernels_that_part_compiles():
    """A compile worker compiles its part's modules; every other module's kernels are plain Python there, and a
    compiled kernel that calls one fails to type (the robots part without cgp_core.rotation failed so on every
    cold cache, and the robots' kernels then compiled at first use).  So a kernel that a part's kernel calls
    from another cgp_core module must be that part's too."""
    import ast
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    from cgp_core.jit import ParallelKernel
    from cgp_core.warmup import PARTS

    def kernel(obj) -> bool:
        return isinstance(obj, (CPUDispatcher, ParallelKernel))

    missing = []
    for part in PARTS:
        names = []
        for name in part.modules:
            module = importlib.import_module(name)
            names.append(name)
            if hasattr(module, "__path__"):
                names += [info.name for info in pkgutil.walk_packages(module.__path__, name + ".")]
        for name in names:
            module = importlib.import_module(name)
            tree = ast.parse(Path(module.__file__).read_text())
            imported = {}  # name in this module -> the module of the kernel it names
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.level:
                    source = importlib.util.resolve_name("." * node.level + (node.module or ""), module.__package__)
                    for alias in node.names:
                        if kernel(getattr(importlib.import_module(source), alias.name, None)):
                            imported[alias.asname or alias.name] = source
            for function in tree.body:
                if not isinstance(function, ast.FunctionDef) or not kernel(getattr(module, function.name, None)):
                    continue
                for node in ast.walk(function):
                    source = imported.get(node.id) if isinstance(node, ast.Name) else None
                    if source is not None and not _covers(part.modules, source):
                        missing.append(f"part {part.name}: {name}.{function.name} calls {source}.{node.id}")
    assert not missing, "\n".join(sorted(set(missing)))


INLINED = r"""
import numpy as np
from numba import njit


@njit(inline="always")
def _body(x, k):
    total = 0.0
    for i in range(len(x)):
        if x[i] > k:
            total += x[i] * k
        elif x[i] < -k:
            total -= x[i]
        else:
            total += 1.0
    return total


@njit
def twice(x):
    return _body(x, 0.5) + _body(x, 1.5)
"""


def test_numbas_inliner_and_flags_patches_keep_numbas_results(tmp_path):
    """cgp_core.jit's two compile-time patches of numba (issue 34): the inliner's block copies share a memo (the
    same IR, so the same results), and a Flags' values() is the dict numba builds."""
    import copy as copy_module

    from numba.core import inline_closurecall
    from numba.core.compiler import Flags

    assert inline_closurecall.copy is not copy_module  # the copier is in place (numba 0.68's inliner)
    flags = Flags()
    flags.nrt, flags.error_model, flags.boundscheck = True, "numpy", False
    by_properties = {name: getattr(flags, name) for name in type(flags).options}
    assert flags.values() == by_properties and list(flags.values()) == list(by_properties)
    (tmp_path / "inlined_twice.py").write_text(INLINED)
    sys.path.insert(0, str(tmp_path))
    try:
        from inlined_twice import twice  # compiled with the patched inliner (cgp_core.jit is imported)
    finally:
        sys.path.remove(str(tmp_path))
    x = np.array([-2.0, -1.0, 0.0, 0.7, 1.0, 2.0])
    assert twice(x) == twice.py_func(x)


def test_a_slice_assignments_shape_error_is_numbas_plain_one_and_compiles_no_string_code():
    """cgp_core.jit's third compile-time patch (issue 34): a slice assignment whose shapes differ raises numba's
    generic-target ValueError, so no kernel compiles (and links) numba's string formatting for that message."""
    from numba import njit

    @njit
    def put(out, row):
        out[0, :] = row
        return out

    assert put(np.zeros((2, 3)), np.arange(3.0)).tolist() == [[0.0, 1.0, 2.0], [0.0, 0.0, 0.0]]
    with pytest.raises(ValueError, match="cannot assign slice from input of different size"):
        put(np.zeros((2, 3)), np.arange(4.0))
    with pytest.raises(ValueError):  # numpy's own, plain Python
        put.py_func(np.zeros((2, 3)), np.arange(4.0))
    code = "".join(put.inspect_llvm().values())
    assert "unicode" not in code and "raise_with_shape_context" in code


SAVER = r"""
import os, sys, time
sys.path[:0] = [sys.argv[1], sys.argv[2]]
import numpy as np
import cgp_core.jit  # noqa: F401 - its cache patches
from numba.core import caching

if sys.argv[4] == "save":
    real = caching.IndexDataCacheFile._save_index

    def slow(self, overloads):  # widen the window between loading the index and writing it
        time.sleep(1.0)
        real(self, overloads)

    caching.IndexDataCacheFile._save_index = slow
    go = os.path.join(sys.argv[2], "go")
    while not os.path.exists(go):
        time.sleep(0.005)
from racing.kernel import scaled

value = {"i8": np.arange(3, dtype=np.int64), "f8": np.arange(3.0), "c16": np.arange(3) + 1j,
         "f4": np.arange(3, dtype=np.float32)}
if sys.argv[4] == "save":
    print(scaled(value[sys.argv[3]]).tolist())
else:
    import json
    print(json.dumps({"results": {kind: repr(scaled(x).tolist()) for kind, x in value.items()},
                      "loaded": sum(scaled.stats.cache_hits.values()),
                      "compiled": sum(scaled.stats.cache_misses.values())}))
"""


def test_concurrent_saves_of_one_kernels_signatures_keep_each_with_its_own_code(tmp_path):
    """numba adds a signature to a kernel's cache as load index / take a free data-file number / write both,
    unlocked: two processes adding signatures at once take the same number, and the next process can load one
    signature's machine code for the other (cgp_core.jit locks the save).  Four processes compile four signatures
    of one kernel and save them at the same moment (each save held open 1 s); then a fifth loads all four from
    the cache — no compile — and each computes its own type's result."""
    import json

    package = tmp_path / "src" / "racing"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "kernel.py").write_text("from cgp_core.jit import njit\n\n\n@njit\ndef scaled(x):\n"
                                       "    return x * 2 + 1\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("NUMBA_DISABLE_JIT", None)
    args = [sys.executable, "-c", SAVER, str(REPO), str(tmp_path / "src")]
    savers = [subprocess.Popen([*args, kind, "save"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True) for kind in ("i8", "f8", "c16", "f4")]
    (tmp_path / "src" / "go").write_text("")
    for saver in savers:
        out, err = saver.communicate(timeout=120)
        assert saver.returncode == 0, err[-3000:]
    done = subprocess.run([*args, "-", "load"], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    x = {"i8": np.arange(3, dtype=np.int64), "f8": np.arange(3.0), "c16": np.arange(3) + 1j,
         "f4": np.arange(3, dtype=np.float32)}
    assert report["results"] == {kind: repr((v * 2 + 1).tolist()) for kind, v in x.items()}, report
    assert (report["loaded"], report["compiled"]) == (4, 0), report


@pytest.mark.parametrize("scene, parts", [
    ("default", ["solver", "contacts", "flock"]),
    ("pyramid", ["solver", "contacts", "flock"]),
    ("convex_pile", ["solver", "contacts", "flock", "convex", "robots"]),
    ("arm", ["solver", "contacts", "flock", "convex", "robots"]),
    (None, ["solver", "contacts", "flock"]),
])
def test_the_node_compiles_the_parts_its_scene_runs(monkeypatch, scene, parts):
    """`cgp-sim` compiles, before its first tick, the parts of the kernels its scene runs (`make run` leaves the
    compile to it): the default scene's three for a scene of spheres, boxes and capsules; every part, as `make
    setup` does, for one of hulls (convex_pile) or robots (arm), whose kernels would otherwise compile one by one
    in the first tick.  (Compiling them in parallel workers: the test above.)"""
    from cgp_core import warmup as core
    from cgp_core.scene import load_scene
    from cgp_sim_ros import warmup

    asked = []
    monkeypatch.setattr(core, "compile_in_parallel",
                        lambda missing, module, *args: asked.append(([p.name for p in missing], list(args))) or {})
    monkeypatch.setattr(core, "missing_parts", lambda given, complete: list(given))  # as on a cold cache
    warmup.compile_missing_kernels(lambda text: None, None if scene is None else load_scene(scene))
    # the workers: every kernel of every part, or (--default-scene) the default scene's of its parts
    assert asked == [(parts, [] if "convex" in parts else ["--default-scene"])]
