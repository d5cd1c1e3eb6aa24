"""cgp_core.jit's typing of constant arguments in compiled calls (issue 34): a kernel that compiled code calls
with constants (``scaled(x, 2, True)``) is compiled once for the plain types, not once per constant value as numba
alone does; a kernel that cannot be typed without the constant (an index into a tuple of two types) still gets it.
Run in a fresh process each, so that nothing this suite compiled before is reused."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

KERNELS = '''
import numpy as np
from cgp_core import jit

DECORATE = jit.njit if PATCHED else __import__("numba").njit  # (under NUMBA_DISABLE_JIT both give the function)

@DECORATE(cache=False)
def scaled(x, k, flag):
    return x * k if flag else -x * k

@DECORATE(cache=False)
def pick(pair, k):  # an index into a tuple of two types: numba needs k as a constant
    return pair[k]

@DECORATE(cache=False)
def swept(x, sweep):  # a tuple holding a constant, as the broad phase's sweep passes its axis
    order, axis = sweep
    return x[order[0]] + axis

@DECORATE(cache=False)
def caller(x):
    t = (1.5, np.int64(2))
    axis = 0
    for d in range(1, 3):
        if x[d] > x[axis]:
            axis = d
    return (scaled(x[0], 2, True) + scaled(x[0], 3, False) + scaled(x[0], np.int64(4), True) + pick(t, 0)
            + pick(t, 1) + swept(x, (np.arange(2), axis)) + swept(x, (np.arange(2), 1)))
'''

RUN = r'''
import json, sys
import numpy as np
PATCHED = sys.argv[2] == "patched"
exec(compile(open(sys.argv[1]).read(), sys.argv[1], "exec"))
x = np.array([1.0, 5.0, 2.0])
compiled = () if jit.JIT_DISABLED else (scaled, pick, swept)
print(json.dumps({"value": float(caller(x)),
                  "signatures": {f.__name__: [", ".join(map(str, s)) for s in f.signatures] for f in compiled}}))
'''


def _run(tmp_path: Path, mode: str) -> dict:
    (tmp_path / "kernels.py").write_text(KERNELS)
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_DISABLE_JIT="1" if mode == "plain" else "0")
    out = subprocess.run([sys.executable, "-c", RUN, str(tmp_path / "kernels.py"), mode], env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_constant_arguments_of_compiled_calls_compile_the_callee_once_for_the_plain_types(tmp_path):
    patched, numba_alone, plain = _run(tmp_path, "patched"), _run(tmp_path, "numba"), _run(tmp_path, "plain")
    # the same results, compiled and as plain Python: 2 - 3 + 4 + 1.5 + 2, then x[order[0]] + axis twice
    assert patched["value"] == numba_alone["value"] == plain["value"] == 6.5 + (1.0 + 1) + (1.0 + 1)
    mine, theirs = patched["signatures"], numba_alone["signatures"]
    assert mine["scaled"] == ["float64, int64, bool"]
    assert len(theirs["scaled"]) == 3  # numba alone: Literal[int](2) and True, Literal[int](3) and False, int64
    assert mine["swept"] == ["array(float64, 1d, C), Tuple(array(int64, 1d, C), int64)"]
    assert len(theirs["swept"]) >= 2
    # a kernel that needs the constant still gets it, one compile per value, as with numba alone
    assert mine["pick"] == theirs["pick"] == ["Tuple(float64, int64), Literal[int](0)",
                                              "Tuple(float64, int64), Literal[int](1)"]
