"""The lecture's particle set (``shape: particles``): the ``particles`` rows [x, y, z, mass], checked as one
array and, for the messages, one by one."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..limits import MAX_LENGTH, MAX_MASS, MAX_PARTICLES_PER_BODY, MIN_MASS
from .validation import Validator, kind_of


def parse_particles(v: Validator, raw: Any, key: str) -> np.ndarray | None:
    """The (k, 4) rows [x, y, z, mass]: body-frame offsets within ±MAX_LENGTH m, masses in [MIN_MASS, MAX_MASS]
    kg, the total too.  The count is checked before anything is built; the rows are checked as one array (a
    100,000-particle body in ~0.1 s), and one by one, for the messages, only if that finds a problem."""
    if raw is None:
        v.fail(key, "missing (a list of [x, y, z, mass])")
        return None
    if not isinstance(raw, list) or not raw:
        v.fail(key, f"must be a non-empty list of [x, y, z, mass], got {kind_of(raw)}")
        return None
    if len(raw) > MAX_PARTICLES_PER_BODY:
        v.fail(key, f"{len(raw)} particles; at most {MAX_PARTICLES_PER_BODY}")
        return None
    numbers = (int, float)
    if all(type(p) is list and len(p) == 4 and all(type(x) in numbers for x in p) for p in raw):
        try:
            arr = np.array(raw, dtype=float)
        except OverflowError:  # an integer beyond float64
            arr = None
        if arr is not None and np.isfinite(arr).all() and (np.abs(arr[:, :3]) <= MAX_LENGTH).all() \
                and ((arr[:, 3] >= MIN_MASS) & (arr[:, 3] <= MAX_MASS)).all():
            return _particle_total(v, arr, key)
    before = len(v.problems)
    rows = []
    for i, p in enumerate(raw):
        row = v.vector(p, f"{key}[{i}]", 4)
        if len(v.problems) == before:
            if not (np.abs(row[:3]) <= MAX_LENGTH).all():
                v.fail(f"{key}[{i}]", f"offsets must be within ±{MAX_LENGTH:g} m of the origin (what cgp_sim "
                       f"simulates: cgp_core.limits), got {row[:3].tolist()}")
            elif not row[3] > 0.0:
                v.fail(f"{key}[{i}]", f"particle mass must be > 0, got {row[3]:g}")
            elif not MIN_MASS <= row[3] <= MAX_MASS:
                v.fail(f"{key}[{i}]", f"particle mass must be in [{MIN_MASS:g}, {MAX_MASS:g}] kg (what cgp_sim "
                       f"simulates: cgp_core.limits), got {row[3]:g}")
        rows.append(row)
    if len(v.problems) > before:
        return None
    return _particle_total(v, np.array(rows), key)


def _particle_total(v: Validator, arr: np.ndarray, key: str) -> np.ndarray | None:
    total = float(arr[:, 3].sum())
    if total > MAX_MASS:
        v.fail(key, f"total mass {total:g} kg; masses must be in [{MIN_MASS:g}, {MAX_MASS:g}] kg (what cgp_sim "
               "simulates: cgp_core.limits)")
        return None
    return arr
