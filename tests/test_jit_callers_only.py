"""cgp_core.jit's kernels compiled for their compiled callers only (issue 34): a kernel that numba compiles because a
compiled caller calls it gets no machine code and no Python entry of its own (its callers link its IR), and goes
into the disk cache as LLVM bitcode; another caller in the next process links it from there without compiling it;
a call from Python then emits it (from the cache, no compile; after the full pipeline where only the cheap one ran)
and caches its machine code; every result is the plain-Python function's.  Each step is a fresh process with its
own compile listener; the kernels are a module of the test's own, the cache a temporary directory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _compile_events import LISTENER

ROOT = Path(__file__).resolve().parents[1]

KERNELS = '''
import numpy as np
from cgp_core.jit import njit


@njit
def inner(a, k):
    out = np.empty_like(a)
    for i in range(len(a)):
        out[i] = a[i] * k + np.sqrt(abs(a[i]))
    return out


@njit
def outer(a):
    return inner(a, 2.5).sum()


@njit
def outer_again(a):  # another caller, the same argument types for inner
    return inner(a, -1.25).max()
'''

RUN = r'''
import json, sys
import numpy as np
''' + LISTENER + r'''
import cgp_core.jit  # noqa: E402

cgp_core.jit.SMALL_CALLEE_INSTRUCTIONS = int(sys.argv[2])  # 0: every callee after the cheap pipeline alone
import kernels_for_callers  # noqa: E402

a = np.linspace(-2.0, 3.0, 7)
value = getattr(kernels_for_callers, sys.argv[1])(*((a, 0.75) if sys.argv[1] == "inner" else (a,)))
entries = [type(c.entry_point).__name__ for c in kernels_for_callers.inner.overloads.values()]
print(json.dumps({"compiled": compiled, "value": np.asarray(value).tolist(), "inner_entries": entries}))
'''


def _run(directory: Path, call: str, small: int = 1000) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(directory / "cache"), NUMBA_DISABLE_JIT="0",
               PYTHONPATH=os.pathsep.join([str(ROOT), str(directory)]))
    out = subprocess.run([sys.executable, "-c", RUN, call, str(small)], env=env, capture_output=True, text=True,
                         timeout=180)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _plain(call: str):
    a = np.linspace(-2.0, 3.0, 7)

    def inner(x, k):
        return np.array([x[i] * k + np.sqrt(abs(x[i])) for i in range(len(x))])

    return {"outer": inner(a, 2.5).sum(), "outer_again": inner(a, -1.25).max(), "inner": inner(a, 0.75)}[call]


@pytest.mark.parametrize("small", [1000, 0], ids=["full-pipeline", "cheap-pipeline"])
def test_a_callee_compiled_for_its_callers_is_linked_from_the_cache_and_emitted_when_python_calls_it(tmp_path, small):
    (tmp_path / "kernels_for_callers.py").write_text(KERNELS)
    first = _run(tmp_path, "outer", small)
    assert {"outer", "inner"} <= set(first["compiled"])
    assert first["inner_entries"] == ["_ForCallersOnly"]  # no Python entry, no machine code of its own
    assert np.allclose(first["value"], _plain("outer"), rtol=1e-15, atol=0.0)

    second = _run(tmp_path, "outer_again", small)  # another caller links inner from the cache (bitcode)
    assert "outer_again" in second["compiled"] and "inner" not in second["compiled"]
    assert second["inner_entries"] == ["_ForCallersOnly"]
    assert np.allclose(second["value"], _plain("outer_again"), rtol=1e-15, atol=0.0)

    third = _run(tmp_path, "inner", small)  # Python calls it: emitted from the cached bitcode, not compiled again
    assert "inner" not in third["compiled"]
    assert third["inner_entries"][0] != "_ForCallersOnly"
    assert np.allclose(third["value"], _plain("inner"), rtol=1e-15, atol=0.0)

    fourth = _run(tmp_path, "inner", small)  # its machine code is cached now
    assert fourth["compiled"] == [] and fourth["inner_entries"][0] != "_ForCallersOnly"
    assert fourth["value"] == third["value"]


def test_python_calling_a_callee_compiled_for_a_caller_in_the_same_process_gets_numbas_numbers(tmp_path):
    """A callee first compiled for a caller, then called from Python in the same process, is emitted then: the same
    numbers as a process where Python called it first (numba's own compile, its own cache)."""
    for name in ("after_caller", "alone"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "kernels_for_callers.py").write_text(KERNELS)
    first_the_caller = RUN.replace("value = getattr(", "kernels_for_callers.outer(a)\nvalue = getattr(")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "after_caller" / "cache"), NUMBA_DISABLE_JIT="0",
               PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp_path / "after_caller")]))
    out = subprocess.run([sys.executable, "-c", first_the_caller, "inner", "0"], env=env, capture_output=True,
                         text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-3000:]
    after_caller = json.loads(out.stdout.strip().splitlines()[-1])
    assert {"outer", "inner"} <= set(after_caller["compiled"])
    assert after_caller["inner_entries"][0] != "_ForCallersOnly"
    alone = _run(tmp_path / "alone", "inner", 0)
    assert "outer" not in alone["compiled"] and "inner" in alone["compiled"]
    assert after_caller["value"] == alone["value"]
    assert np.allclose(alone["value"], _plain("inner"), rtol=1e-15, atol=0.0)
