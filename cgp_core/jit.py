"""The one place cgp_core compiles Python with numba.

Hot loops that numpy cannot batch (contact generation and the sequential-impulse solver for a few bodies, the
boid neighbour sums) are written as plain Python loops that read like the lecture, and decorated with
:func:`njit`.  numba compiles them to machine code on first call and caches the result next to the source
(``__pycache__/*.nbi|*.nbc``), so only the first start after an install or an edit pays the compile time.

The same functions run as ordinary Python under ``NUMBA_DISABLE_JIT=1`` (numba then returns the function
unchanged), with the same results: that is how the tests check the compiled kernels against the readable ones,
and how a student steps through a kernel in a debugger.

Settings, and why:

- ``cache=True``: compiled kernels are written to disk; a warm start loads them in milliseconds.
- ``nogil=True``: a kernel releases the GIL, so the bag writer thread and DDS callbacks run on the other core
  while it computes.
- ``error_model="numpy"``: division by zero gives inf/nan as numpy does (the World's blow-up guard deals with
  it) instead of raising ``ZeroDivisionError`` from inside a kernel.
- no ``fastmath``: it lets LLVM reassociate floating-point sums, which would make compiled and plain-Python
  results differ beyond round-off and break the bit-for-bit determinism a seed promises.
- ``parallel=True`` kernels (per-boid loops written with :data:`prange`) run on numba's thread pool, one
  thread per core, for :data:`PARALLEL_MIN_ITEMS` items or more; for fewer, a serial twin of the same function
  runs (:class:`ParallelKernel`): compiling a loop for the pool costs half again as much as compiling it plain
  (measured: the default scene's flock kernels, 9 s serial and 14 s parallel), and a small flock never needs
  the pool.  Each iteration writes only its own outputs and no floating-point value is reduced across
  iterations, so the results do not depend on the number of threads.  By default numba cuts a parallel loop
  into one chunk per thread; a thread that the node's other threads (the bag writer, DDS) delay on a 2-core
  machine then holds up the whole kernel while the other core idles.  :func:`threads_for` therefore cuts it
  into chunks of :data:`PARALLEL_CHUNK` iterations (~15 at 15k boids), and the pool is Intel TBB's
  (``requirements/python.txt`` installs it; numba takes TBB first when it is there), which hands the chunks
  out as threads become free: the delayed thread's chunks are taken by the other (measured on the 15k-fish
  tick, three alternating runs each: p99 / tick CPU 1.5-1.9 with TBB against 1.7-2.3 with OpenMP, one chunk
  per thread both; then with TBB, chunks of 1024 against one per thread: 1.41-1.65 against 1.44-1.85, the
  worst run's p99 21 ms against 26 ms — gains of the size of this machine's run-to-run noise).  With the
  OpenMP pool, idle workers are told to sleep (``OMP_WAIT_POLICY=PASSIVE``) instead of spinning for a while
  after every kernel: on a 2-core machine the spinning worker took the core the bag writer and the DDS
  threads need (measured: twice the CPU time per flock step, and a slower tick).  Only the node's tick thread
  launches parallel kernels (numba's fallback ``workqueue`` pool is not safe to enter from two threads at
  once); :class:`ThreadPlacement` gives it a CPU of its own and the pool's workers (and every other thread)
  the others, which Linux's scheduler alone did not always do.

Bundles.  Kernels pass their arrays on as a few named bundles (``typing.NamedTuple`` classes of arrays, each
field documented with its shape where the class is defined: ``ContactSet``, ``CollisionModel``, the solver's
``Manifolds`` / ``Rows`` ...), which numba compiles as structs and which are ordinary tuples under
``NUMBA_DISABLE_JIT``.  A new per-contact or per-primitive array is a new field, not a change of every signature.
One rule at the border: a kernel that Python calls every sub-step takes its bundles as **plain tuples**
(``kernel(tuple(contacts), ...)``) and names them first thing (``contacts = ContactSet(*contacts)``).  numba's
dispatcher types a plain tuple of arrays in C but a namedtuple in Python, field by field: with the solver's 28
arrays and numbers that is ~6.5 µs against ~2.6 µs per call (measured with numba 0.68; loose arguments: ~2.8 µs),
which at 4 sub-steps a tick of the 5-body default scene would be a tenth of its tick.  Inside compiled code, and
from Python where the call is rare, bundles go as they are.

Stage timing.  :func:`clock` reads the monotonic clock ``time.perf_counter`` reads, from Python and from compiled
code (``clock_gettime``, ~25 ns), so a compiled pipeline times its own stages into a :class:`StageProfile`
without coming back to Python between them (each return to Python would cost the dispatch above again).

Compiling in parallel (:mod:`cgp_core.warmup`): numba compiles one kernel at a time, on one core, about 40 s
for the default scene's kernels when no cache exists.  :func:`cgp_core.warmup.compile_in_parallel` splits
that work over several processes, each compiling the kernels of some modules into the shared on-disk cache.
A worker is told which with ``CGP_SIM_JIT_ONLY`` (modules or packages, comma-separated, e.g.
``cgp_core.solver,cgp_core.rotation``; a package takes its modules along, a module only itself): there, the other
modules' kernels stay plain Python — the ``NUMBA_DISABLE_JIT`` path, per module — so the worker steps a scene (to give
every kernel the argument types the real run gives it) without compiling what another worker compiles.
"""

from __future__ import annotations

import copy
import functools
import os
import re
import sys
import threading
import time
import types
import warnings
from contextlib import contextmanager

# Before numba loads its OpenMP thread pool (at the first parallel kernel); a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba.core import caching, cgutils  # noqa: E402
from numba.core import ir as _ir  # noqa: E402
from numba.extending import intrinsic, overload  # noqa: E402

#: numba's own switch: with NUMBA_DISABLE_JIT=1 every kernel runs as plain Python
JIT_DISABLED = os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")

#: set in a compile worker only (see the module docstring): the module prefixes whose kernels this process
#: compiles; empty (everywhere else): every kernel is compiled
JIT_ONLY = tuple(prefix for prefix in os.environ.get("CGP_SIM_JIT_ONLY", "").split(",") if prefix)

_DEFAULTS = {"cache": True, "nogil": True, "error_model": "numpy"}


# ---- the on-disk cache: a kernel's compiled code is valid only with the code it calls ---------------------
#
# numba's cache checks a kernel against the hash of its own source file only.  A kernel that calls (and so
# inlines) a kernel of another module keeps its cached machine code when only that other module changes: after
# an edit of epa.py, manifold.py's cached contact kernels still ran the old EPA (seen while developing: the
# parity test failed by one ulp until the caches were deleted).  So the stamp of a cgp_core / cgp_sim_ros kernel
# is the hashes of its own file *and* of every module of these packages that file imports, directly or through
# others (read from the files' import lines): an edit anywhere a kernel can reach recompiles it, and nothing
# else.  numba's other locators (user-provided NUMBA_CACHE_DIR, in-tree __pycache__) are kept, only the stamp
# is wider.

_PACKAGES = ("cgp_core", "cgp_sim_ros")
_IMPORT_LINE = re.compile(r"^\s*(?:from\s+(\.*)([\w.]*)\s+import\s+(\([^)]*\)|[\w ,*]+)|import\s+([\w.]+))", re.M)


def _package_root(path: str) -> str | None:
    """The directory holding our package that ``path`` belongs to (the checkout or site-packages), or None."""
    parts = os.path.normpath(path).split(os.sep)
    for i in range(len(parts) - 1, -1, -1):
        if parts[i] in _PACKAGES:
            return os.sep.join(parts[:i]) or os.sep
    return None


def _module_file(root: str, dotted: str) -> str | None:
    base = os.path.join(root, *dotted.split("."))
    for candidate in (base + ".py", os.path.join(base, "__init__.py")):
        if os.path.isfile(candidate):
            return candidate
    return None


@functools.cache
def _direct_imports(path: str, stamp: tuple) -> tuple[str, ...]:
    """The files of our packages that the module at ``path`` imports (``stamp``: its mtime and size, so that an
    edit while the process runs is read again)."""
    root = _package_root(path)
    here = os.path.relpath(os.path.dirname(path), root).split(os.sep)
    with open(path, encoding="utf-8") as f:
        text = f.read()
    found = []
    for dots, module, names, plain in _IMPORT_LINE.findall(text):
        if plain:
            targets = [plain]
        else:
            package = here[:len(here) - (len(dots) - 1)] if dots else []
            base = ".".join(package + ([module] if module else []))
            targets = [base] + [f"{base}.{name}" for name in re.findall(r"\w+", names)]
        for dotted in targets:
            if dotted.split(".")[0] in _PACKAGES and (file := _module_file(root, dotted)) and file != path:
                found.append(file)
    return tuple(sorted(set(found)))


def dependency_stamp(path: str) -> tuple:
    """The hashes of ``path`` and of every module of our packages it imports, transitively (sorted by file)."""
    seen, todo = set(), [path]
    while todo:
        file = todo.pop()
        if file in seen:
            continue
        seen.add(file)
        st = os.stat(file)
        todo.extend(_direct_imports(file, (st.st_mtime_ns, st.st_size)))
    stamps = []
    for file in sorted(seen):
        st = os.stat(file)
        stamps.append(caching._hash_source_file(file, st.st_mtime, st.st_size))
    return tuple(stamps)


class _DependencyStamp:
    """Mixin for numba's source-file locators: the stamp covers the modules the kernel's module imports."""

    def get_source_stamp(self):
        return dependency_stamp(self._py_file)

    @classmethod
    def from_function(cls, py_func, py_file):
        if _package_root(py_file) is None:
            return None  # not ours: numba's own locators decide
        return super().from_function(py_func, py_file)


class _UserDirLocator(_DependencyStamp, caching.UserProvidedCacheLocator):
    pass


class _InTreeLocator(_DependencyStamp, caching.InTreeCacheLocator):
    pass


caching.CacheImpl._locator_classes[:0] = [_UserDirLocator, _InTreeLocator]


# ---- numba's cache: one process at a time adds an entry to a kernel's index ------------------------------------
#
# numba saves a new signature's machine code as "load the kernel's index, take the first free data-file number, write
# the index, write the data file" (``IndexDataCacheFile.save``), each file replaced atomically but the whole unlocked.
# Two processes adding different signatures of one kernel at once (the test suite's two workers, the compile workers,
# a node beside a test run) both take the same number: the index that is written last keeps one signature (the others
# are compiled again by every later process), and the data file written last may hold the *other* signature's code —
# which the next process loads for the one the index names (``Dispatcher.compile`` does not check the loaded code's
# signature against the one it asked for: code for other argument types runs, garbage or a crash, not an error).  Here
# a save holds an exclusive ``flock`` on ``<index>.lock`` beside the index, so the index it loads is the last one
# written and the number it takes is free.  Readers need no lock: every file is still replaced atomically.  Where the
# lock file cannot be made (a read-only cache), numba's own save runs, as before.

def _lock_cache_saves() -> None:
    import fcntl

    files = getattr(caching, "IndexDataCacheFile", None)
    if files is None or not hasattr(files, "save") or not hasattr(files, "_load_index"):
        return  # a numba whose cache files differ: left alone
    original = files.save

    @functools.wraps(original)
    def save(self, key, data):
        try:
            descriptor = os.open(f"{self._index_path}.lock", os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            return original(self, key, data)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX)
            return original(self, key, data)
        finally:
            os.close(descriptor)  # (closing releases the lock)

    files.save = save


_lock_cache_saves()


# ---- numba's typed lists: their functions cached too ------------------------------------------------------------
#
# A ``numba.typed.List`` (the robots' kernels take their per-robot bundles in one) is driven from Python by numba's
# own compiled functions (``numba.typed.typedlist``: make a list, append, get and set an item ...), which numba
# compiles without a cache, for each item type, in every process: ~2.6 s of CPU at every start of a world with
# robots, cache or not (measured: the warm-up's warm start compiled nothing else; issue 34).  They are cached
# here as cgp_core's kernels are (numba's own locators: beside numba's sources, or the user's cache directory),
# once numba loads that module: it is not imported before a typed list is made, and costs ~40 ms to import.

def _enable_cache(dispatcher) -> bool:
    """numba's on-disk cache for a dispatcher of numba's own that has none (numba's locators: beside numba's sources,
    or the user's cache directory); False where there is no writable location (it compiles as before)."""
    if type(getattr(dispatcher, "_cache", None)).__name__ != "NullCache":
        return True  # (cached already)
    try:
        dispatcher.enable_caching()
    except RuntimeError:
        return False
    return True


def _cache_typed_list_functions(module) -> None:
    from numba.core.registry import CPUDispatcher

    for value in vars(module).values():
        if isinstance(value, CPUDispatcher) and not _enable_cache(value):
            return  # (no writable location for numba's sources: none of the others has one either)


class _TypedListHook:
    """Import hook: calls :func:`_cache_typed_list_functions` on ``numba.typed.typedlist`` when it is loaded."""

    name = "numba.typed.typedlist"

    def find_spec(self, name, path, target=None):
        if name != self.name:
            return None
        sys.meta_path.remove(self)
        import importlib.util

        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            _cache_typed_list_functions(module)

        spec.loader.exec_module = exec_module
        return spec


if _TypedListHook.name in sys.modules:
    _cache_typed_list_functions(sys.modules[_TypedListHook.name])
else:
    sys.meta_path.insert(0, _TypedListHook())


# ---- inline="always": the callee's IR copied once per call site, not once per block ------------------------------
#
# numba inlines an ``inline="always"`` callee by copying its IR (``InlineWorker.inline_ir``: twice, a working copy
# and an untouched one) block by block, each block with ``copy.deepcopy`` of its own: every block's copy copies the
# function's whole scope (every variable of the function) again, so a copy costs blocks × variables.  The solver's
# big inlined bodies (``_solve_normal_rows``, ``_solve_manifold`` ... inlined into ``solve_step`` and the position
# stage) made that ~15 % of the solver's compile (cProfile of its compile worker: ``copy_ir`` 7.5 s of 45 s;
# issue 34).  Here the blocks of one copy share one deepcopy memo, so the scope and its variables are copied once
# per copy.  The copy is the same IR (numba dedupes the blocks' scopes to one anyway — ``_get_all_scopes`` — and
# renames the variables by name), so the same machine code: only numba's time changes.  The memo lives for one
# ``inline_ir`` call (started afresh at each call and for each IR copied: a block whose scope differs from the
# last one's, or a block already copied, starts a new memo).  Left as numba has it where numba's internals differ.

class _BlockCopier:
    """Stands for the ``copy`` module inside ``numba.core.inline_closurecall`` (which uses ``copy.deepcopy`` only
    to copy IR blocks): while ``InlineWorker.inline_ir`` runs, consecutive blocks of one IR share a memo."""

    def __init__(self):
        self.active = 0
        self._scope = None
        self._memo = None

    def reset(self) -> None:
        self._scope = self._memo = None

    def deepcopy(self, x, memo=None):
        if memo is not None or not self.active or not isinstance(x, _ir.Block):
            return copy.deepcopy(x, memo)
        if self._memo is None or x.scope is not self._scope or id(x) in self._memo:
            self._scope, self._memo = x.scope, {}  # (the scope held: its id cannot be reused meanwhile)
        return copy.deepcopy(x, self._memo)

    def __getattr__(self, name):
        return getattr(copy, name)


def _share_block_copies() -> None:
    from numba.core import inline_closurecall

    worker = getattr(inline_closurecall, "InlineWorker", None)
    if getattr(inline_closurecall, "copy", None) is not copy or worker is None or not hasattr(worker, "inline_ir"):
        return  # a numba whose inliner differs: left alone
    copier = _BlockCopier()
    original = worker.inline_ir

    @functools.wraps(original)
    def inline_ir(self, *args, **kwargs):
        copier.active += 1
        copier.reset()
        try:
            return original(self, *args, **kwargs)
        finally:
            copier.active -= 1
            copier.reset()

    inline_closurecall.copy = copier
    worker.inline_ir = inline_ir


_share_block_copies()


# ---- numba's compile flags: their values read without a property call per option ------------------------------
#
# numba keys its cache of typed overload implementations on the compile flags (``templates._get_impl``), so every
# call it types hashes and compares a ``Flags``: ``TargetConfig.values()``, a dict of its ~40 options each read
# through a property.  That was ~7 % of the solver's compile (cProfile of its worker: 135k calls, 3M property reads;
# issue 34).  The same dict, built from the class's defaults and the set values at C speed; left to numba for a
# config holding anything else than its options.

def _fast_config_values() -> None:
    from numba.core import targetconfig

    config = getattr(targetconfig, "TargetConfig", None)
    if config is None or not hasattr(config, "values") or not hasattr(config, "options"):
        return
    original = config.values
    defaults: dict = {}

    def values(self):
        mine = self._values
        known = defaults.get(type(self))
        if known is None:
            known = defaults[type(self)] = {name: option.default for name, option in type(self).options.items()}
        if mine.keys() <= known.keys():
            return {**known, **mine}
        return original(self)

    from numba.core.compiler import Flags

    probe = Flags()
    probe.nrt, probe.error_model = True, "numpy"
    if values(probe) != original(probe) or list(values(probe)) != list(original(probe)):
        return  # not the dict numba builds: left alone
    config.values = values


_fast_config_values()


# ---- arrays handed back to Python: their type read from the kernel's constants, not unpickled at every return ---
#
# When a kernel returns an array to Python, numba 0.68's boxing (``boxing.box_array`` →
# ``PythonAPI.nrt_adapt_ndarray_to_python``) gets the array's Python type (``np.ndarray``) by calling
# ``numba_unpickle`` on a pickle embedded in the code: at every return of every array, two bytes objects made and a
# Python-level call of ``serialize._numba_unpickle`` (a dict look-up), whose result is never released (``np.ndarray``'s
# reference count grows by one per array returned, ~5 million after a 100k-call loop).  Our kernels return their
# bundles to Python every sub-step — the 100-hull pile's ~250 arrays a sub-step, the 5-body default scene's ~170 a
# tick — so that was ~0.2 µs of the ~0.35 µs each array costs (measured: a kernel returning ten arrays, 3.7 → 1.8 µs a
# call; issue 37).  Here the type is a constant of the kernel's environment, as numba already keeps the array's dtype
# (``env_manager.add_const``: pickled with the cached code, read back with one ``PyList_GetItem``); the C function
# that builds the array is numba's own, called with the same type object, so the same array comes back (type, dtype,
# shape, strides, writeable flag, owner).  Left as numba has it without an environment or where numba differs.

def _box_arrays_from_constants() -> None:
    from llvmlite import ir as llvm_ir
    from numba.core import boxing, pythonapi, types
    from numba.np import numpy_support

    boxers = getattr(getattr(pythonapi, "_boxers", None), "functions", None)
    original = boxers.get(types.Array) if isinstance(boxers, dict) else None
    # (the strings numba's own boxing uses, read from its code's constants: no source file read at every import)
    adapt = getattr(getattr(pythonapi.PythonAPI, "nrt_adapt_ndarray_to_python", None), "__code__", None)
    if (original is not getattr(boxing, "box_array", None) or not hasattr(pythonapi.PythonAPI, "_get_function")
            or adapt is None or not {"NRT_adapt_ndarray_to_python_acqref", "captures(none)"} <= set(adapt.co_consts)):
        return  # a numba whose boxing differs (the C function, its signature, the attribute LLVM takes): left alone

    def box_array(typ, val, c):
        if not c.context.enable_nrt or c.env_manager is None:
            return original(typ, val, c)
        env = c.env_manager
        dtype = env.read_const(env.add_const(numpy_support.as_dtype(typ.dtype)))
        pytype = env.read_const(env.add_const(typ.box_type))  # (a borrowed reference: the function does not keep it)
        api, int32 = c.pyapi, llvm_ir.IntType(32)
        adapt = api._get_function(llvm_ir.FunctionType(api.pyobj, [api.voidptr, api.pyobj, int32, int32, api.pyobj]),
                                  name="NRT_adapt_ndarray_to_python_acqref")
        adapt.args[0].add_attribute("captures(none)")
        native = cgutils.alloca_once_value(c.builder, val)
        array = c.builder.call(adapt, [c.builder.bitcast(native, api.voidptr), pytype,
                                       c.context.get_constant(types.int32, typ.ndim),
                                       c.context.get_constant(types.int32, int(typ.mutable)), dtype])
        c.context.nrt.decref(c.builder, typ, val)  # (the array took its own reference to the data)
        return array

    boxers[types.Array] = box_array


_box_arrays_from_constants()


# ---- a slice assignment's shape mismatch: numba's fixed message, not one formatted by compiled string code --------
#
# Wherever a kernel assigns an array to a slice (``out[i, :] = v``), numba 0.68 compiles the error raised when the
# shapes differ, and its CPU version formats both shapes into the message with compiled string code (f-strings,
# ``str.join``, ``repr`` of integers: some twenty of numba's unicode functions), compiled in every worker that has
# such a kernel and linked into every kernel that calls one: ~10 s of own compile CPU over every kernel's warm-up
# (``bench_compile.py``, issue 34), for an error that is a bug of ours if it ever happens.  Here the CPU target uses
# numba's own generic-target version, which raises ``ValueError("cannot assign slice from input of different
# size")`` without the shapes (the same exception type; under ``NUMBA_DISABLE_JIT`` numpy's message, with them).
# Left as numba has it where its overloads differ.

def _plain_shape_mismatch_error() -> None:
    from numba.core.typing import templates
    from numba.np import arrayobj

    stub = getattr(arrayobj, "raise_with_shape_context", None)
    formatted = getattr(arrayobj, "ol_raise_with_shape_context_cpu", None)
    plain = getattr(arrayobj, "ol_raise_with_shape_context_generic", None)
    if stub is None or formatted is None or plain is None:
        return
    for function, function_type in templates.builtin_registry.globals:
        if function is stub:
            for template in getattr(function_type, "templates", ()):
                if getattr(template, "_overload_func", None) is formatted and not template.__dict__.get("_impl_cache"):
                    template._overload_func = plain


_plain_shape_mismatch_error()


# ---- a constant argument of a compiled call: one compile of the callee, not one per value --------------------
#
# When compiled code calls a kernel with a constant (``_w(a, b, i, 0)``, ``sweep_and_prune_kernel(lo, hi, g, -1)``)
# or with a tuple holding one, numba 0.68 types that argument as the literal value (``Literal[int](0)``) and compiles
# the callee for it: EPA's ``_w`` was compiled 18 times (each literal pair of its row and column), the sweep's
# ``_sweep_box`` 4 times (its axis a literal ``0`` in the first pass of the caller's type inference, an ``int64`` in
# the next), and every such copy was linked into, optimized and emitted with each caller again (issue 34).  Here
# an integer or boolean literal is typed as its plain type first — as numba does for a call from Python — and the
# literal is tried only when the kernel cannot be typed without it (a constant index into a tuple of several
# types).  Nothing of ours branches on a literal argument's type, and LLVM still folds a constant into a callee it
# inlines: every scene compared stepped to the same bits, at the same speed (``tools/compare_trees.py``).

def _plain_type(value_type):
    """``value_type`` with integer and boolean literals (also inside tuples) as their plain types."""
    from numba.core import types

    if isinstance(value_type, (types.IntegerLiteral, types.BooleanLiteral)):
        return value_type.literal_type
    if isinstance(value_type, types.BaseTuple) and not isinstance(value_type, types.BaseNamedTuple):
        items = [_plain_type(item) for item in value_type]
        if items != list(value_type):
            return types.BaseTuple.from_types(items)
    return value_type


def _compile_plain_literals(dispatcher) -> None:
    """Have compiled callers of ``dispatcher`` get its plain-typed compile for literal arguments (see above)."""
    from numba.core import errors

    original = dispatcher.get_call_template

    def get_call_template(args, kws):
        plain_args, plain_kws = tuple(_plain_type(a) for a in args), {k: _plain_type(v) for k, v in kws.items()}
        if plain_args != tuple(args) or plain_kws != kws:
            try:
                return original(plain_args, plain_kws)
            except errors.NumbaError:
                pass  # it needs the literal: typed with it, as numba would
        return original(args, kws)

    dispatcher.get_call_template = get_call_template


# ---- numba's own overloads (np.empty, argsort ...): their compiled implementations cached as our kernels are ---------
#
# numba compiles the implementation of each numpy function a kernel uses (``np.empty`` for each dtype and shape type,
# ``np.argsort``'s merge sort, ``np.zeros``, ``max`` ...) in every process, without a cache: the compile workers each
# compiled their own copies, ~23 s of the ~220 s of compile CPU over every kernel (76 compiles of ``np.empty``'s alone;
# ``bench_compile.py``, issue 34), and a worker that starts after another (convex after contacts, robots after solver)
# compiled again what the first had.  Here such an implementation gets numba's on-disk cache where numba can cache
# it: defined in a file of numba's, its closure's values picklable (numba keys the cache on them, so two
# implementations of one code with different closed-over types never share an entry).  Left uncached otherwise.

def _cachable_implementation(function) -> bool:
    from numba.core import serialize

    code = getattr(function, "__code__", None)
    if code is None or not os.path.isfile(code.co_filename):
        return False
    try:
        serialize.dumps(tuple(cell.cell_contents for cell in function.__closure__ or ()))
    except Exception:  # (anything pickle raises: numba's cache key would raise it at every compile)
        return False
    return True


def _cache_numba_overloads() -> None:
    from numba.core.typing import templates

    template = getattr(templates, "_OverloadFunctionTemplate", None)
    original = getattr(template, "_get_jit_decorator", None)
    if original is None:
        return  # a numba whose overload templates differ: left alone

    def _get_jit_decorator(self):
        jitter = original(self)
        if not (getattr(getattr(self, "_overload_func", None), "__module__", None) or "").startswith("numba."):
            return jitter  # (a library's own overloads: as that library has them)

        def cached_jitter(*args, **options):
            decorate = jitter(*args, **options)

            def decorator(function):
                dispatcher = decorate(function)
                if _cachable_implementation(function):
                    _enable_cache(dispatcher)
                return dispatcher

            return decorator

        return cached_jitter

    template._get_jit_decorator = _get_jit_decorator


_cache_numba_overloads()


# ---- a kernel compiled for its compiled callers only: the cheap pipeline, no machine code of its own ---------------
#
# numba finishes every kernel it compiles as if Python were to call it: the kernel's module (with every callee it
# links) goes through LLVM's module passes twice — the "cheap" pipeline that inlines, then the full one at O3 — and
# is emitted as machine code with a CPython wrapper.  A kernel compiled only because a compiled caller calls it
# (the solver's stages in ``contacts_head``, the joint solver's, the convex manifolds ...) needs none of that for
# itself: its caller links the callee's IR into its own module, runs both pipelines over the whole again and emits
# it there — so in a deep tree every level's code went through the full pipeline once per level above it.  LLVM's
# time per library over every kernel's warm-up (issue 34, one run): module passes ~38 s, machine code ~35 s of ~196 s
# of CPU, about half of each for libraries only linked into others.  Here a kernel compiled while a compiled caller
# is being typed is lowered as numba lowers it; its module passes stop after the cheap pipeline (and numba's
# reference-count pruning) unless the module is small (:data:`SMALL_CALLEE_INSTRUCTIONS`); and it stays out of
# LLVM's execution engine: its entry point is a placeholder (:class:`_ForCallersOnly`) that keys its implementation
# for its callers and is not in the dispatcher's table of Python entries.  Its callers are optimized as before, the
# full pipeline over everything they link (their machine code can differ a little — LLVM sees the callee less
# simplified — but not their arithmetic: no fast-math, so the same bits; ``tools/compare_trees.py bits``).  If
# Python calls it later with those types, :func:`_emitted` runs the full pipeline on it then and emits it: numba's
# own sequence (cheap, prune, full).  numba's disk cache keeps such a kernel as LLVM bitcode (kinds
# :data:`CALLERS_ONLY`, not machine code), which another process — the next compile worker — links without compiling
# it, and which one that calls it from Python finishes and emits.  Measured: every kernel cold 109 → 105 s wall,
# 192 → 179 s CPU, one run each; the skipped machine code alone saved nothing measurable, the skipped full pipeline
# of the big callees the rest (benchmarks/README.md, "Seventh round").

class _ForCallersOnly:
    """The entry point of a compile made for compiled callers only (never called: see above)."""

    __slots__ = ("__weakref__",)


class _TypingCaller(threading.local):
    active = False  # a compiled caller is being typed on this thread (its callees compile for callers only)


_typing_caller = _TypingCaller()

#: the cache's kinds of serialized library for a kernel compiled for callers only, after the cheap pipeline alone
#: or after both (a small one: :data:`SMALL_CALLEE_INSTRUCTIONS`); numba's own are "object" and "bitcode"
CALLERS_ONLY = {True: "cgp_sim: callers-only bitcode, cheap passes", False: "cgp_sim: callers-only bitcode"}


def _for_callers_only(library) -> bool:
    return getattr(library, "_cgp_for_callers_only", False)


#: a callee's module (with what it links) of at most this many LLVM instructions, before the passes, still gets the
#: full pipeline: small helpers called in hot loops (the flock's per-neighbour functions, 140–760 instructions) are
#: inlined into their callers, and LLVM decides that on their optimized size — given only the cheap pipeline, the
#: default scene's flock stepped ~3 % slower (``tools/compare_trees.py speed``, 2 × 12–20 pairs); the modules that
#: cost the full pipeline most are the big stages (``contacts_head`` 8,600 instructions, ``_solve_region`` 3,700)
SMALL_CALLEE_INSTRUCTIONS = 1000


def _small(module) -> bool:
    count = 0
    for function in module.functions:
        for block in function.blocks:
            for _ in block.instructions:
                count += 1
                if count > SMALL_CALLEE_INSTRUCTIONS:
                    return False
    return True


def _full_module_passes(library) -> None:
    """The full pipeline numba runs after the cheap one (``CPUCodeLibrary._optimize_final_module``)."""
    passes, builder = library._codegen._module_pass_manager()
    passes.run(library._final_module, builder)


def _callers_only_hooks() -> bool:
    """Patch numba's code library, CPU context and codegen for kernels compiled for callers only (see above);
    False (nothing patched) for a numba whose internals differ."""
    from numba.core import codegen, config, cpu

    library, jit_codegen = getattr(codegen, "CPUCodeLibrary", None), getattr(codegen, "JITCPUCodegen", None)
    needed = {library: ("_optimize_final_module", "_finalize_final_module", "_finalize_dynamic_globals",
                        "serialize_using_object_code", "_unserialize", "_ensure_finalized", "_get_module_for_linking"),
              jit_codegen: ("set_env", "_module_pass_manager", "_add_module"), cpu.CPUContext: ("get_executable",),
              codegen: ("remove_redundant_nrt_refct",),
              getattr(codegen, "JITCodeLibrary", None): ("_finalize_specific",)}
    if any(owner is None or not all(hasattr(owner, name) for name in names) for owner, names in needed.items()):
        return False
    optimize, finalize, serialize, unserialize = (library._optimize_final_module, library._finalize_final_module,
                                                  library.serialize_using_object_code, library._unserialize.__func__)
    get_executable, set_env = cpu.CPUContext.get_executable, jit_codegen.set_env

    def _optimize_final_module(self):
        if not _for_callers_only(self) or _small(self._final_module):
            return optimize(self)
        self._cgp_cheap = True  # (the full pipeline follows if Python calls it: _emitted)
        passes, builder = self._codegen._module_pass_manager(loop_vectorize=self._codegen._loopvect,
                                                             slp_vectorize=False, opt=self._codegen._opt_level,
                                                             cost="cheap")
        passes.run(self._final_module, builder)
        if not config.LLVM_REFPRUNE_PASS:
            self._final_module = codegen.remove_redundant_nrt_refct(self._final_module)

    def _finalize_final_module(self):
        if not _for_callers_only(self):
            return finalize(self)
        self._finalize_dynamic_globals()  # (what a caller's cache check asks; no engine, no machine code)
        self._finalized = True

    def serialize_using_object_code(self):
        if not _for_callers_only(self):
            return serialize(self)
        self._ensure_finalized()
        return self.name, CALLERS_ONLY[getattr(self, "_cgp_cheap", False)], self._final_module.as_bitcode()

    def _unserialize(cls, codegen_, state):
        name, kind, data = state
        if kind not in CALLERS_ONLY.values():
            return unserialize(cls, codegen_, state)
        self = codegen_.create_library(name)
        self.enable_object_caching()
        self._final_module = codegen.ll.parse_bitcode(data)
        self._cgp_for_callers_only, self._cgp_cheap = True, kind == CALLERS_ONLY[True]
        self._finalize_final_module()
        return self

    def get_executable_(self, library, fndesc, env):
        return _ForCallersOnly() if _for_callers_only(library) else get_executable(self, library, fndesc, env)

    def set_env_(self, env_name, env):
        if self._engine.is_symbol_defined(env_name):  # (a callers-only library's environments are nowhere yet)
            set_env(self, env_name, env)

    library._optimize_final_module, library._finalize_final_module = _optimize_final_module, _finalize_final_module
    library.serialize_using_object_code, library._unserialize = serialize_using_object_code, classmethod(_unserialize)
    cpu.CPUContext.get_executable, jit_codegen.set_env = get_executable_, set_env_
    return True


_CALLERS_ONLY_HOOKS = _callers_only_hooks()


def _emitted(dispatcher, add_overload, signature, compiled):
    """The Python entry of ``compiled`` (compiled or loaded for callers only): the full module passes, its library
    into the execution engine (machine code now), the CPython wrapper's address as the dispatcher's entry for these
    types; cached as machine code from now on."""
    library = compiled.library
    library._ensure_finalized()
    if getattr(library, "_cgp_cheap", False):
        _full_module_passes(library)
        library._cgp_cheap = False
    library._cgp_for_callers_only = False
    library._finalize_final_module()  # numba's own now: into the engine, machine code
    entry = dispatcher.targetctx.get_executable(library, compiled.fndesc, compiled.environment)
    compiled = compiled._replace(entry_point=entry)
    dispatcher.targetctx.insert_user_function(entry, compiled.fndesc, [library])
    add_overload(compiled)
    dispatcher._cache.save_overload(signature, compiled)
    return entry


def _compile_for_callers_only(dispatcher) -> None:
    """Have ``dispatcher``'s compiles for compiled callers stop short of machine code (see above)."""
    from numba.core import sigutils
    from numba.core.compiler_lock import global_compiler_lock

    compiler = getattr(dispatcher, "_compiler", None)
    if not _CALLERS_ONLY_HOOKS or not hasattr(compiler, "_customize_flags"):
        return
    customize, add_overload, compile_, get_call_template = (compiler._customize_flags, dispatcher.add_overload,
                                                            dispatcher.compile, dispatcher.get_call_template)

    def _customize_flags(flags):
        flags = customize(flags)
        if _typing_caller.active:
            flags.no_compile = True  # lowered, not handed to the engine (numba's own flag)
        return flags

    def add_overload_(compiled):
        if compiled.objectmode or not (compiled.entry_point is None
                                       or isinstance(compiled.entry_point, _ForCallersOnly)):
            return add_overload(compiled)
        if compiled.entry_point is None:  # compiled now (not loaded from the cache)
            compiled.library._cgp_for_callers_only = True
            compiled = compiled._replace(entry_point=_ForCallersOnly())
            dispatcher.targetctx.insert_user_function(compiled.entry_point, compiled.fndesc, [compiled.library])
        dispatcher.overloads[tuple(compiled.signature.args)] = compiled  # (not a Python entry: not _insert-ed)

    def compile(signature):
        entry = compile_(signature)
        if isinstance(entry, _ForCallersOnly) and not _typing_caller.active:  # Python calls it: machine code
            with global_compiler_lock:
                compiled = dispatcher.overloads[tuple(sigutils.normalize_signature(signature)[0])]
                if isinstance(compiled.entry_point, _ForCallersOnly):
                    return _emitted(dispatcher, add_overload, signature, compiled)
                return compiled.entry_point
        return entry

    def get_call_template_(args, kws):
        previous, _typing_caller.active = _typing_caller.active, True
        try:
            return get_call_template(args, kws)
        finally:
            _typing_caller.active = previous

    compiler._customize_flags = _customize_flags
    dispatcher.add_overload, dispatcher.compile, dispatcher.get_call_template = (add_overload_, compile,
                                                                                get_call_template_)


def njit(*args, **options):
    """``numba.njit`` with cgp_core's defaults (see the module docstring); use as ``@njit`` or ``@njit(...)``."""
    settings = {**_DEFAULTS, **options}
    if args and callable(args[0]) and len(args) == 1 and not options:
        return _compiled(args[0], settings)
    return lambda function: _compiled(function, settings)


def _compiled(function, settings):
    module = function.__module__
    # twin=False: a parallel kernel that compiled code calls (a ParallelKernel's choice of twin is Python's); its
    # caller decides when to go wide (e.g. the solver's sweeps by two regions, for big worlds only)
    twin = settings.pop("twin", True)
    if JIT_DISABLED or (JIT_ONLY and not any(module == m or module.startswith(m + ".") for m in JIT_ONLY)):
        return function  # plain Python: the JIT is off, or this is another compile worker's kernel
    if settings.get("parallel") and twin:
        return ParallelKernel(function, settings)
    dispatcher = numba.njit(**settings)(function)
    _compile_plain_literals(dispatcher)
    _compile_for_callers_only(dispatcher)
    return dispatcher


class ParallelKernel:
    """A ``parallel=True`` kernel, compiled twice: ``parallel`` for numba's thread pool and ``serial`` (the same
    function as a plain loop).  A call runs ``serial`` inside :func:`threads_for` with fewer than
    :data:`PARALLEL_MIN_ITEMS` items, ``parallel`` otherwise; each compiles on its first call.  Both run the
    same arithmetic per item (no floating-point value is reduced across items), so they give the same results
    bit for bit.  Call it from Python only (a compiled kernel cannot call it)."""

    def __init__(self, function, settings):
        self.parallel = numba.njit(**settings)(function)
        # The twin is a copy of the function under its own name: numba's cache names its files after the
        # function and does not tell a parallel from a serial compile of the same one apart.
        twin = types.FunctionType(function.__code__, function.__globals__, function.__name__,
                                  function.__defaults__, function.__closure__)
        twin.__qualname__ = f"{function.__qualname__}__serial"
        twin.__module__, twin.__doc__ = function.__module__, function.__doc__
        self.serial = numba.njit(**{**settings, "parallel": False})(twin)
        functools.update_wrapper(self, function)

    def __call__(self, *args):
        return (self.serial if _calling.serial else self.parallel)(*args)


class _Calling(threading.local):
    serial = False  # set by threads_for, per calling thread


_calling = _Calling()


#: ``numba.prange`` (a plain ``range`` when the JIT is disabled); only meaningful inside ``njit(parallel=True)``
prange = numba.prange


#: a parallel kernel over fewer items than this runs on one thread: waking the pool's other workers for each
#: kernel costs more than they save (measured: a 300-boid flock step takes 0.2 ms on one thread, 0.3-0.6 ms
#: and a long tail on two, on this project's 2-core machines)
PARALLEL_MIN_ITEMS = 2000


@contextmanager
def parallel_from(items: int):
    """Within: :func:`threads_for` picks the parallel kernels from ``items`` items on instead of from
    :data:`PARALLEL_MIN_ITEMS` (the warm-up sets 0 to compile the parallel twins with a small flock)."""
    global PARALLEL_MIN_ITEMS
    previous, PARALLEL_MIN_ITEMS = PARALLEL_MIN_ITEMS, items
    try:
        yield
    finally:
        PARALLEL_MIN_ITEMS = previous


def refuse_unparallelized_kernels() -> None:
    """From now on in this process, a ``parallel=True`` kernel that numba compiles without any parallel loop
    is an error instead of a warning (``NumbaPerformanceWarning``: "no transformation for parallel execution
    was possible").  numba gives up on a ``prange`` it cannot split (e.g. ``prange(a if c else b)``) and
    compiles a plain loop: the kernel is then silently one core's.  The warm-up (``make setup``, the compile
    workers) calls this, so such a kernel fails the set-up — and CI — instead of slowing every big flock."""
    warnings.filterwarnings("error", message=r"\s*The keyword argument 'parallel=True' was specified but no "
                            r"transformation for parallel execution was possible",
                            category=numba.NumbaPerformanceWarning)


def pool_size() -> int:
    """How many threads a parallel kernel called now runs on: 1 where :func:`threads_for` picked the serial
    twins, else numba's thread count (for kernels that split their work into one part per thread)."""
    return 1 if _calling.serial or JIT_DISABLED else numba.get_num_threads()


#: iterations per chunk of a parallel loop run inside :func:`threads_for` (see the module docstring): small
#: enough that a delayed thread's share is taken over, large enough that handing chunks out costs nothing
#: measurable (~15 chunks for 15k boids)
PARALLEL_CHUNK = 1024


def runs_on_pool(items: int) -> bool:
    """Does a parallel kernel over ``items`` items run on numba's thread pool (else: its serial twin)?"""
    return items >= PARALLEL_MIN_ITEMS and not JIT_DISABLED


@contextmanager
def threads_for(items: int):
    """Run the parallel kernels called inside on all of numba's threads, in chunks of :data:`PARALLEL_CHUNK`
    iterations, or as their serial twins for fewer than :data:`PARALLEL_MIN_ITEMS` items (per calling thread;
    the previous settings are restored)."""
    serial = not runs_on_pool(items)
    previous = _calling.serial, numba.get_num_threads()
    _calling.serial = serial
    if not serial:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        previous_chunk = numba.set_parallel_chunksize(PARALLEL_CHUNK)
    try:
        yield
    finally:
        _calling.serial = previous[0]
        if not serial:
            numba.set_num_threads(previous[1])
            numba.set_parallel_chunksize(previous_chunk)


class ThreadPlacement:
    """The thread that launches the parallel kernels (the node's tick: "the caller") on a CPU of its own, and
    every other thread of the process — numba's pool workers, the bag writer, DDS, the Foxglove server — on
    the other CPUs the process may use (Linux: ``os.sched_setaffinity`` per thread id).

    Why: on a 2-core machine the tick and numba's one pool worker need a core each, and Linux's scheduler does
    not always give them that.  When another thread (the bag writer, between two real-time ticks) has just run
    on the worker's core, the kernel that wakes the worker at the next tick's start often finds it queued behind
    the tick on the tick's core: one in five such ticks started with both on one core, and the worker then
    waited ~1 ms per tick for a core (``/proc/<pid>/task/<tid>/schedstat``) while the other idled.  Measured on
    the 15k-fish scene in real time, recording, alternating runs of 1,800 ticks: tick p99 13.2 / 13.0 ms
    unpinned, 9.8 / 10.0 ms pinned — the p99 without recording at all (9.7–10.3 ms); back to back 12.8 / 13.2
    against 11.2 / 11.3 ms.

    :meth:`place` pins from the calling thread, which becomes the caller (its CPU: the last one allowed).  Call
    it again now and then: a thread inherits its creator's CPUs, so one the caller starts later would share its
    CPU until then.  :meth:`release` gives every thread all the allowed CPUs back.  Where it cannot work — not
    Linux, fewer than 2 CPUs allowed, the JIT off, numba on 1 thread — :attr:`unavailable` says why and
    :meth:`place` does nothing.
    """

    def __init__(self) -> None:
        self.allowed: tuple[int, ...] = tuple(sorted(os.sched_getaffinity(0))) if hasattr(os, "sched_getaffinity") \
            else ()
        self.caller: int | None = None  # native thread id of the caller while placed
        self.cpu: int | None = None  # its CPU

    @property
    def unavailable(self) -> str | None:
        """Why threads cannot be placed here, or None."""
        if not sys.platform.startswith("linux"):
            return f"thread placement is Linux only (this is {sys.platform})"
        if len(self.allowed) < 2:
            return f"this process may use {len(self.allowed)} CPU"
        if JIT_DISABLED:
            return "the JIT is off (NUMBA_DISABLE_JIT): no thread pool"
        if numba.config.NUMBA_NUM_THREADS < 2:
            return "numba runs 1 thread (NUMBA_NUM_THREADS)"
        return None

    @property
    def others(self) -> tuple[int, ...]:
        """The CPUs of every thread but the caller (while placed)."""
        return tuple(c for c in self.allowed if c != self.cpu)

    def place(self) -> bool:
        """Pin the calling thread to its CPU and every other thread of the process to the others (only those
        not pinned so already are touched); False where :attr:`unavailable`."""
        if self.unavailable:
            return False
        numba.get_num_threads()  # launches numba's pool if it is not yet: its workers exist from here on
        caller = threading.get_native_id()
        if self.caller != caller:  # the first placement, or the kernels are launched from another thread now
            self.caller, self.cpu = caller, self.allowed[-1]
        own, others = {self.cpu}, set(self.others)
        for task in _tasks():
            _set_cpus(task, own if task == caller else others)
        return True

    def release(self) -> None:
        """Every thread of the process back on every allowed CPU."""
        if self.caller is None:
            return
        everywhere = set(self.allowed)
        for task in _tasks():
            _set_cpus(task, everywhere)
        self.caller = self.cpu = None


def _tasks() -> list[int]:
    """The native ids of this process's threads now."""
    return [int(task) for task in os.listdir("/proc/self/task")]


def _set_cpus(task: int, cpus: set[int]) -> None:
    try:
        if os.sched_getaffinity(task) != cpus:
            os.sched_setaffinity(task, cpus)
    except OSError:  # the thread ended meanwhile, or may not be moved (a restricted container): left alone
        pass


# ---- stage timing ----------------------------------------------------------------------------------------------

def clock() -> float:
    """Seconds on the monotonic clock ``time.perf_counter`` reads (an arbitrary origin: take differences).
    Callable from compiled kernels too (there: ``clock_gettime`` of the same clock; 0.0 where the platform has
    none, i.e. neither Linux nor macOS — stage times then read 0)."""
    return time.perf_counter()


#: the clock time.perf_counter reads: CLOCK_MONOTONIC (its number differs between Linux and macOS)
_MONOTONIC = {"linux": 1, "darwin": 6}.get(sys.platform)


@intrinsic
def _monotonic_ns(typingctx):
    """``clock_gettime(CLOCK_MONOTONIC)`` in nanoseconds, for compiled code (declared by name, so a cached kernel
    links it again in each process)."""
    from llvmlite import ir

    def codegen(context, builder, signature, args):
        i64, i32 = ir.IntType(64), ir.IntType(32)
        timespec = ir.LiteralStructType([i64, i64])
        function = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i32, [i32, timespec.as_pointer()]),
                                                  "clock_gettime")
        now = cgutils.alloca_once(builder, timespec)
        builder.call(function, [ir.Constant(i32, _MONOTONIC), now])
        seconds = builder.load(cgutils.gep_inbounds(builder, now, 0, 0))
        nanoseconds = builder.load(cgutils.gep_inbounds(builder, now, 0, 1))
        return builder.add(builder.mul(seconds, ir.Constant(i64, 1_000_000_000)), nanoseconds)

    return numba.types.int64(), codegen


@overload(clock)
def _clock_compiled():
    if _MONOTONIC is None:
        return lambda: 0.0
    return lambda: _monotonic_ns() * 1e-9


class StageProfile:
    """Wall time spent in each named stage of a pipeline, accumulated over its calls (a benchmark reads it,
    :meth:`reset` starts over).

    ``seconds`` (k,) float64, one entry per stage in ``stages`` order: what a compiled pipeline adds its stage
    times into (``profile[STAGE] += clock() - start``), or Python through :meth:`add`.  ``calls``: how many
    times the pipeline ran (the owner counts)."""

    def __init__(self, stages: tuple[str, ...]):
        self.stages = tuple(stages)
        self.seconds = np.zeros(len(self.stages))
        self.calls = 0

    def reset(self) -> None:
        self.seconds[:] = 0.0
        self.calls = 0

    def add(self, stage: int, seconds: float) -> None:
        self.seconds[stage] += seconds

    def as_dict(self) -> dict[str, float]:
        """``{stage: seconds}``, plus ``calls``."""
        return {**{name: float(t) for name, t in zip(self.stages, self.seconds)}, "calls": self.calls}


def lap(profile, stage, since):
    """Add the time since ``since`` (a :func:`clock` reading) to ``profile[stage]``; returns the clock now (the
    next stage's start).  From Python and compiled code (an overload, compiled into each caller: a compile
    worker that leaves cgp_core.jit's own module out still compiles it)."""
    now = clock()
    profile[stage] += now - since
    return now


@overload(lap)
def _lap_compiled(profile, stage, since):
    def impl(profile, stage, since):
        now = clock()
        profile[stage] += now - since
        return now

    return impl


__all__ = ["JIT_DISABLED", "JIT_ONLY", "PARALLEL_CHUNK", "PARALLEL_MIN_ITEMS", "ParallelKernel", "StageProfile",
           "ThreadPlacement", "clock", "lap", "njit", "parallel_from", "pool_size", "prange",
           "refuse_unparallelized_kernels", "runs_on_pool", "threads_for"]
