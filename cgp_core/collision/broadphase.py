"""Broad phase: which axis-aligned bounding boxes (AABBs) overlap (Ericson ch. 7).

Every function takes ``lo, hi (p, 3)`` (box corners) and, optionally, ``group (p,)`` (the collision detector's
groups are the bodies: a body's primitives never collide with each other, so a pair within one group is never
reported), and returns the overlapping pairs as two index arrays ``(i, j)`` with ``i < j``, each pair once,
sorted by ``(i, j)``; boxes that merely touch count as overlapping.  Three implementations behind that one
signature:

- :func:`brute_force_pairs` — every pair tested, O(p²): the reference the others are tested against.
- :func:`grid_pairs` — a uniform grid, stored as a sorted array of cell keys instead of a hash
  table (Ericson 7.1.2 / 7.1.5: the "sort the objects by cell" variant, which numpy does in one argsort).
  The cell edge is the largest extent among the ordinary-sized boxes, so each box is filed under the one
  cell holding its lower corner and any box it overlaps lies in that cell or one of its 26 neighbours;
  visiting the cell itself and 13 of the neighbours (one of each opposite pair) meets every pair exactly
  once.  The few boxes much larger than the typical one (walls, floors) are tested against everything by
  brute force.  O(p log p) for the sort, O(p) work per box for the typical scene.
- :func:`sweep_and_prune_pairs` — sort by the lower bound along the axis of largest spread and pair each box
  with those that start before it ends (Ericson 7.5.2, single axis), a compiled loop
  (:func:`sweep_and_prune_kernel`); **default**, the collision detector's above a few dozen primitives (one call,
  no per-call numpy overhead).  Its candidate count grows as p² · (box size / world size), so very large
  dense scenes favour the grid.

The grid and brute force are vectorized numpy: the variable-length candidate lists are generated with the
``repeat + arange`` idiom, never with a Python loop over boxes.
"""

from __future__ import annotations

import numpy as np

from ..jit import njit

_EMPTY = (np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp))

#: a box whose largest extent exceeds this multiple of the median extent is "large" for the grid and is
#: tested by brute force instead of being filed in cells (keeps the cells small when a scene has walls)
LARGE_FACTOR = 4.0

# the cell itself plus 13 of its 26 neighbours: one of each pair of opposite offsets
_HALF_NEIGHBOURHOOD = np.array(
    [(0, 0, 0)]
    + [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
       if (dx, dy, dz) > (0, 0, 0)],
    dtype=np.int64,
)


def _check(lo: np.ndarray, hi: np.ndarray, group=None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape:
        raise ValueError(f"AABB corners must both be (p, 3) arrays, got {lo.shape} and {hi.shape}")
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise ValueError("AABB corners must be finite (a body position or orientation is NaN/inf)")
    if group is not None:
        group = np.asarray(group)
        if group.shape != (len(lo),) or group.dtype.kind not in "iu":
            raise ValueError(f"group must be a ({len(lo)},) integer array (one group per box), got "
                             f"{group.shape} {group.dtype}")
    return lo, hi, group


def _other_groups(i: np.ndarray, j: np.ndarray, group: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The pairs ``(i, j)`` whose boxes are of different groups (all of them without groups)."""
    if group is None:
        return i, j
    keep = group[i] != group[j]
    return i[keep], j[keep]


def _overlap(lo, hi, i, j) -> np.ndarray:
    return np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)


def _sorted_pairs(i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical order: i < j, sorted lexicographically (so results compare equal across methods)."""
    a = np.minimum(i, j).astype(np.int64)
    b = np.maximum(i, j).astype(np.int64)
    order = np.argsort(a * (int(b.max(initial=0)) + 1) + b)
    return a[order].astype(np.intp), b[order].astype(np.intp)


def _expand_ranges(owner: np.ndarray, start: np.ndarray, count: np.ndarray):
    """For each k, the pairs (owner[k], start[k] + r) for r in range(count[k]) — without a Python loop."""
    total = int(count.sum())
    if total == 0:
        return _EMPTY
    rep_owner = np.repeat(owner, count)
    # position within each run: arange(total) minus the run's first output index
    run_first = np.repeat(np.cumsum(count) - count, count)
    rep_index = np.repeat(start, count) + (np.arange(total) - run_first)
    return rep_owner, rep_index


def brute_force_pairs(lo: np.ndarray, hi: np.ndarray, group: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """All overlapping pairs (of different ``group``) by testing every pair (O(p²) memory and time: the
    reference)."""
    lo, hi, group = _check(lo, hi, group)
    p = len(lo)
    if p < 2:
        return _EMPTY
    # boxes i and j overlap along an axis when lo_i <= hi_j and lo_j <= hi_i: the (p, p, 3) test and its
    # transpose; the three axes combined by slices (cheaper than .all(axis=2) and np.triu at these sizes)
    overlap = lo[:, None, :] <= hi[None, :, :]
    overlap &= overlap.transpose(1, 0, 2)
    i, j = np.nonzero(overlap[:, :, 0] & overlap[:, :, 1] & overlap[:, :, 2])
    upper = i < j
    return _other_groups(i[upper].astype(np.intp), j[upper].astype(np.intp), group)


def sweep_and_prune_pairs(lo: np.ndarray, hi: np.ndarray, group: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Single-axis sweep and prune along the axis of largest spread of the box centres (compiled:
    :func:`sweep_and_prune_kernel`), in the canonical pair order."""
    lo, hi, group = _check(lo, hi, group)
    if len(lo) < 2:
        return _EMPTY
    group = np.arange(len(lo)) if group is None else np.ascontiguousarray(group, np.int64)
    i, j = sweep_and_prune_kernel(np.ascontiguousarray(lo), np.ascontiguousarray(hi), group)
    return _sorted_pairs(i, j)


@njit
def sweep_and_prune_kernel(lo, hi, group):
    """Every overlapping pair of AABBs ``lo, hi (p, 3)`` of different ``group`` (p,) once (the collision
    detector's groups are the bodies: a body's primitives never collide with each other), as ``(i, j)`` with
    ``i < j``, in sweep order (Ericson 7.5.2, single axis): sort the boxes by their lower bound along the axis of
    largest spread of the centres, and pair each box with those that start before it ends.  A box with a
    non-finite bound overlaps nothing.  Good for sparse scenes and piles alike at a few thousand boxes; its
    candidate count grows as p² · (box size / world size).

    Boxes of the box's own group are skipped a run at a time (``next_other``: the next position in sweep order
    of another group), so a particle body's particles, which overlap each other, cost nothing among
    themselves: issue 27 measured a particle body's tick growing as N^2.2 (5,000 particles 0.46 s, 20,000 6.5 s,
    100,000 never) when every same-body pair was found here and rejected only in the narrow phase."""
    p = len(lo)
    mean = np.zeros(3)
    spread = np.zeros(3)
    for k in range(p):
        for d in range(3):
            mean[d] += lo[k, d] + hi[k, d]
    for d in range(3):
        mean[d] /= max(p, 1)
    for k in range(p):
        for d in range(3):
            x = lo[k, d] + hi[k, d] - mean[d]
            spread[d] += x * x
    axis = 0
    for d in range(1, 3):
        if spread[d] > spread[axis]:
            axis = d
    order = np.argsort(lo[:, axis], kind="mergesort")
    next_other = np.empty(p, np.int64)  # position -> the first later position holding another group
    for a in range(p - 1, -1, -1):
        if a + 1 < p and group[order[a + 1]] == group[order[a]]:
            next_other[a] = next_other[a + 1]
        else:
            next_other[a] = a + 1
    cap = 8 * p + 16
    pi = np.empty(cap, np.int64)
    pj = np.empty(cap, np.int64)
    count = 0
    for a in range(p):
        i = order[a]
        end = hi[i, axis]
        b = a + 1
        while b < p:
            j = order[b]
            if not lo[j, axis] <= end:
                break  # sorted by lower bound: no later box starts before this one ends (or a bound is NaN)
            if group[j] == group[i]:
                b = next_other[b]  # the rest of this run of i's own group
                continue
            if lo[i, 0] <= hi[j, 0] and lo[j, 0] <= hi[i, 0] and lo[i, 1] <= hi[j, 1] and lo[j, 1] <= hi[i, 1] \
                    and lo[i, 2] <= hi[j, 2] and lo[j, 2] <= hi[i, 2]:
                if count == cap:
                    cap *= 2
                    pi = _grow(pi, cap)
                    pj = _grow(pj, cap)
                pi[count] = min(i, j)
                pj[count] = max(i, j)
                count += 1
            b += 1
    return pi[:count], pj[:count]


@njit
def _grow(values, cap):
    out = np.empty(cap, values.dtype)
    out[:len(values)] = values
    return out


def grid_cell_size(lo: np.ndarray, hi: np.ndarray) -> float:
    """The grid's cell edge: the largest extent among boxes no larger than ``LARGE_FACTOR`` × the median."""
    extent = np.max(hi - lo, axis=1)
    ordinary = extent[extent <= LARGE_FACTOR * np.median(extent)]
    cell = float(ordinary.max()) if ordinary.size else float(extent.max())
    return cell if cell > 0.0 else 1.0


def grid_pairs(lo: np.ndarray, hi: np.ndarray, cell_size: float | None = None, group: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Uniform-grid broad phase (see the module docstring).  ``cell_size`` defaults to
    :func:`grid_cell_size`; boxes larger than a cell are handled by brute force against all boxes.  Candidates
    of one ``group`` are dropped before their overlap test (a particle body's particles share cells)."""
    lo, hi, group = _check(lo, hi, group)
    p = len(lo)
    if p < 2:
        return _EMPTY
    cell = grid_cell_size(lo, hi) if cell_size is None else float(cell_size)
    if not (np.isfinite(cell) and cell > 0.0):
        raise ValueError(f"grid cell size must be a positive number, got {cell_size!r}")
    # a hair larger, so two boxes whose lower corners are exactly one cell apart cannot land two cells apart
    # through the rounding of lo / cell
    cell *= 1.0 + 1e-9
    extent = np.max(hi - lo, axis=1)
    large = extent > cell
    small = np.flatnonzero(~large)
    pairs_i, pairs_j = [], []

    if small.size >= 2:
        cells_per_axis = np.floor((lo[small].max(axis=0) - lo[small].min(axis=0)) / cell) + 3
        if float(np.prod(cells_per_axis)) > 2.0 ** 62:
            # a scene spread over more cells than an int64 key can number (a body flung kilometres away):
            # sweep and prune needs no keys
            i, j = sweep_and_prune_pairs(lo[small], hi[small], None if group is None else group[small])
            pairs_i.append(small[i])
            pairs_j.append(small[j])
    if small.size >= 2 and not pairs_i:
        coords = np.floor(lo[small] / cell).astype(np.int64)
        coords -= coords.min(axis=0) - 1  # >= 1, so neighbour offsets of -1 stay >= 0
        span = coords.max(axis=0) + 2
        stride = np.array([span[1] * span[2], span[2], 1], dtype=np.int64)
        key = coords @ stride
        order = np.argsort(key, kind="stable")
        targets = (key[None, :] + (_HALF_NEIGHBOURHOOD @ stride)[:, None]).ravel()  # (14 * s,)
        cells = int(span.prod())
        if cells <= 8 * small.size + 4096:
            # few enough cells for a dense table: start of each cell's run in `order`, by direct indexing
            start = np.zeros(cells + 1, dtype=np.int64)
            np.cumsum(np.bincount(key, minlength=cells), out=start[1:])
            first, last = start[targets], start[targets + 1]
        else:
            # sparse: binary search in the sorted keys (the "hash table" of Ericson 7.1.3 as a sorted array)
            sorted_key = key[order]
            first = np.searchsorted(sorted_key, targets, side="left")
            last = np.searchsorted(sorted_key, targets, side="right")
        owner = np.tile(np.arange(small.size), len(_HALF_NEIGHBOURHOOD))
        a, k = _expand_ranges(owner, first, last - first)
        b = order[k]
        # within the own cell (offset 0, the first block) each pair appears twice and each box with itself
        own_cell = np.repeat(np.arange(len(targets)) < small.size, last - first)
        keep = ~own_cell | (a < b)
        a, b = _other_groups(small[a[keep]], small[b[keep]], group)
        hit = _overlap(lo, hi, a, b)
        pairs_i.append(a[hit])
        pairs_j.append(b[hit])

    big = np.flatnonzero(large)
    if big.size:
        # large vs everything (large-large pairs once: only against higher-index large boxes)
        others = np.arange(p)
        ov = np.all((lo[big][:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[big][:, None, :]), axis=2)
        ov &= ~(large[None, :] & (others[None, :] <= big[:, None]))
        bi, oj = np.nonzero(ov)
        a, b = _other_groups(big[bi], others[oj], group)
        pairs_i.append(a)
        pairs_j.append(b)

    if not pairs_i:
        return _EMPTY
    return _sorted_pairs(np.concatenate(pairs_i), np.concatenate(pairs_j))


BROAD_PHASES = {
    "grid": grid_pairs,
    "sweep_and_prune": sweep_and_prune_pairs,
    "brute_force": brute_force_pairs,
}
DEFAULT_BROAD_PHASE = "sweep_and_prune"


def get_broad_phase(name: str):
    """The broad-phase function called ``name``; ``ValueError`` listing the valid names otherwise."""
    try:
        return BROAD_PHASES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown broad phase {name!r}; valid: {', '.join(sorted(BROAD_PHASES))}") from None
