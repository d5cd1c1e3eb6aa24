"""cgp_core.jit's on-disk cache for numba's own overload implementations (issue 34): ``np.empty``'s implementation
for a dtype and shape type, compiled in one process, is loaded from the cache by the next process that needs it
(a compile worker that starts after another) instead of compiled again; the kernels that use it give the same
arrays.  Each process is fresh, with its own compile listener, and the cache a temporary directory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from _compile_events import LISTENER

ROOT = Path(__file__).resolve().parents[1]

RUN = r'''
import json, sys
import numpy as np
if sys.argv[1] == "patched":
    import cgp_core.jit  # noqa: F401 - its patches of numba
from numba import njit
''' + LISTENER + r'''

# a kernel of this process's own (not cached: each process compiles it), calling np.empty and np.zeros
if sys.argv[2] == "first":
    @njit
    def kernel(n):
        a = np.empty((n, 3), np.int64)
        a[:] = 7
        return a, np.zeros(n)
else:
    @njit
    def kernel(n):  # another kernel, the same numpy functions with the same argument types
        b = np.empty((n, 3), np.int64)
        b.fill(7)
        return b, np.zeros(n) * 2.0

a, z = kernel(4)
print(json.dumps({"compiled": compiled, "a": a.tolist(), "dtype": str(a.dtype), "z": z.tolist()}))
'''


def _run(cache: Path, mode: str, which: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT), NUMBA_DISABLE_JIT="0")
    out = subprocess.run([sys.executable, "-c", RUN, mode, which], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _numpy_implementations(compiled: list[str]) -> list[str]:
    return [name for name in compiled if name.startswith(("ol_np_empty", "ol_np_zeros"))]


def test_numbas_numpy_implementations_compiled_in_one_process_are_loaded_from_the_cache_by_the_next(tmp_path):
    first = _run(tmp_path / "patched", "patched", "first")
    second = _run(tmp_path / "patched", "patched", "second")
    assert _numpy_implementations(first["compiled"])  # the first process compiled them
    assert _numpy_implementations(second["compiled"]) == []  # the second loaded them
    assert "kernel" in second["compiled"]  # (while compiling its own kernel)
    assert second["a"] == first["a"] == [[7, 7, 7]] * 4 and second["dtype"] == first["dtype"] == "int64"
    assert first["z"] == second["z"] == [0.0] * 4
    # numba alone compiles them again in every process
    numba_first = _run(tmp_path / "numba", "numba", "first")
    numba_second = _run(tmp_path / "numba", "numba", "second")
    assert _numpy_implementations(numba_first["compiled"]) and _numpy_implementations(numba_second["compiled"])
