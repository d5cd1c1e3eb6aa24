"""cgp_core.jit's boxing of the arrays a kernel returns to Python (issue 37): the array's Python type read from the
kernel's constants instead of unpickled at every return.  The arrays that come back must be exactly those numba's own
boxing gives — compared in a process without the patch — from freshly compiled code and from numba's on-disk cache."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

KERNELS = '''
import numpy as np
from numba import njit

@njit(cache=True)
def returned(a, ro, n):
    """Arrays of every kind a kernel hands back: new ones, views of its arguments (strided, transposed, of a
    read-only argument), an argument itself, empty ones, other dtypes, inside a tuple."""
    return (a.copy(), ro, a[::2], a.reshape(2, 2).T, np.zeros(0), a > 1.0, a.astype(np.int32), a, ro[1:],
            np.empty((2, 0, 3)), np.arange(n) * 0.5, np.ones((n, 3), dtype=np.complex128))
'''

RUN = r'''
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
if sys.argv[2] == "patched":
    import cgp_core.jit  # noqa: F401 - its patches of numba
from kernels import returned

a, ro = np.arange(4.0), np.arange(3.0)
ro.flags.writeable = False
arrays = returned(a, ro, 3)
described = [[type(x).__name__, str(x.dtype), list(x.shape), list(x.strides), bool(x.flags.writeable),
              bool(x.flags.owndata), type(x.base).__name__, repr(x.tolist()), bool(np.shares_memory(x, a)),
              bool(np.shares_memory(x, ro))] for x in arrays]
arrays[0][0] = 99.0  # a new array is the caller's own: writing it changes nothing else
again = returned(a, ro, 3)
before = sys.getrefcount(np.ndarray)
for _ in range(1000):
    returned(a, ro, 3)
print(json.dumps({"arrays": described, "fresh": again[0].tolist(), "type_references": sys.getrefcount(np.ndarray)
                  - before, "loaded": sum(returned.stats.cache_hits.values())}))
'''


def _run(tmp_path: Path, mode: str, cache: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / cache), PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", RUN, str(tmp_path), mode], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_returned_arrays_are_numbas_own_compiled_and_from_the_cache_and_leak_no_reference(tmp_path):
    (tmp_path / "kernels.py").write_text(KERNELS)
    numbas = _run(tmp_path, "plain", "plain_cache")
    compiled = _run(tmp_path, "patched", "patched_cache")
    cached = _run(tmp_path, "patched", "patched_cache")  # the same kernel loaded from the cache just written
    assert compiled["loaded"] == 0 and cached["loaded"] >= 1
    assert compiled["arrays"] == numbas["arrays"] and cached["arrays"] == numbas["arrays"]
    assert numbas["fresh"] == compiled["fresh"] == cached["fresh"] == [0.0, 1.0, 2.0, 3.0]
    # the array type fetched by reference: numba's unpickling kept one reference per array returned (12 a call)
    assert numbas["type_references"] >= 12 * 1000
    assert compiled["type_references"] == cached["type_references"] == 0
