"""Broad phase: which axis-aligned bounding boxes (AABBs) overlap (Ericson ch. 7).

Every function takes ``lo, hi (p, 3)`` (box corners) and, optionally, ``group (p,)`` (the collision detector's
groups are the bodies: a body's primitives never collide with each other, so a pair within one group is never
reported), and returns the overlapping pairs as two index arrays ``(i, j)`` with ``i < j``, each pair once,
sorted by ``(i, j)``; boxes that merely touch count as overlapping.  Three implementations behind that one
signature:

- :func:`brute_force_pairs` — every pair tested, O(p²): the reference the others are tested against.
- :func:`grid_pairs` — a uniform grid, stored as a sorted array of cell keys instead of a hash
  table (Ericson 7.1.2 / 7.1.5: the "sort the objects by cell" variant), a compiled loop (:func:`grid_kernel`).
  The cell edge is the largest extent among the ordinary-sized boxes, so each box is filed under the one
  cell holding its lower corner and any box it overlaps lies in that cell or one of its 26 neighbours;
  visiting the cell itself and 13 of the neighbours (one of each opposite pair) meets every pair exactly
  once.  The few boxes much larger than the typical one (walls, floors) are tested against the boxes in their
  slab along x and against each other by the sweep.
  O(p log p) for the sort, O(1) work per box for boxes of similar size, however they are arranged.
- :func:`sweep_and_prune_pairs` — sort by the lower bound along the axis of largest spread and pair each box
  with those that start before it ends (Ericson 7.5.2, single axis), a compiled loop
  (:func:`sweep_and_prune_kernel`); **default**, the collision detector's above a few dozen primitives (one call,
  no per-call numpy overhead).  Its candidate count grows as p² · (box size / world size): a dense 3-D pile of
  thousands of bodies (10,000 spheres in a 22³ lattice: ~1,000 candidates per box) is the grid's, and the
  detector hands such a scene to the grid once the sweep's candidates pass a bound
  (:data:`~cgp_core.collision.detector.SWEEP_TESTS_PER_BOX`).

Brute force is vectorized numpy (the reference, kept simple); the two structures are compiled loops, which skip
a box's own group (a body's own primitives) a run at a time.
"""

from __future__ import annotations

import numpy as np

from ..jit import njit

_EMPTY = (np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp))

#: a box whose largest extent exceeds this multiple of the median extent is "large" for the grid and is not
#: filed in cells (:func:`grid_kernel` tests it apart; keeps the cells small when a scene has walls)
LARGE_FACTOR = 4.0


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


def _sorted_pairs(i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical order: i < j, sorted lexicographically (so results compare equal across methods)."""
    a = np.minimum(i, j).astype(np.int64)
    b = np.maximum(i, j).astype(np.int64)
    order = np.argsort(a * (int(b.max(initial=0)) + 1) + b)
    return a[order].astype(np.intp), b[order].astype(np.intp)


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
    i, j, _ = sweep_and_prune_kernel(np.ascontiguousarray(lo), np.ascontiguousarray(hi), group, -1)
    return _sorted_pairs(i, j)


@njit
def sweep_and_prune_kernel(lo, hi, group, max_tests):
    """Every overlapping pair of AABBs ``lo, hi (p, 3)`` of different ``group`` (p,) once (the collision
    detector's groups are the bodies: a body's primitives never collide with each other), as ``(i, j)`` with
    ``i < j``, in sweep order (Ericson 7.5.2, single axis): sort the boxes by their lower bound along the axis of
    largest spread of the centres, and pair each box with those that start before it ends.  A box with a
    non-finite bound overlaps nothing.  Good for sparse scenes and piles alike at a few thousand boxes; its
    candidate count grows as p² · (box size / world size).

    Boxes of the box's own group are skipped a run at a time (``next_other``: the next position in sweep order
    of another group), so a particle body's particles, which overlap each other, cost nothing among
    themselves: issue 27 measured a particle body's tick growing as N^2.2 (5,000 particles 0.46 s, 20,000 6.5 s,
    100,000 never) when every same-body pair was found here and rejected only in the narrow phase.

    Returns ``(i, j, complete)``.  ``max_tests`` >= 0 bounds the candidates tested (boxes of other groups that
    start within a box's extent): past it the sweep gives up and returns no pairs and ``complete`` False — the
    scene is dense along every axis and the grid (:func:`grid_kernel`) finds its pairs in O(p) instead; -1: no
    bound."""
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
    # (a contiguous copy: the grid sorts contiguous float64 too, so numba compiles one merge sort for both)
    order = np.argsort(np.ascontiguousarray(lo[:, axis]), kind="mergesort")
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
    tests = 0
    sweep = (order, next_other, group, axis)
    for a in range(p):
        status = FULL
        while status == FULL:
            count, tests, status = _sweep_box(a, sweep, lo, hi, pi, pj, count, tests, max_tests)
            if status == FULL:  # no room for this box's pairs: the arrays doubled, the box swept again
                pi = _grow(pi, 2 * len(pi))
                pj = _grow(pj, 2 * len(pj))
        if status == GAVE_UP:
            return pi[:0], pj[:0], False
    return pi[:count], pj[:count], True


#: what :func:`_sweep_box` says of the box it swept
SWEPT, FULL, GAVE_UP = 0, 1, 2


@njit
def _sweep_box(a, sweep, lo, hi, pi, pj, count, tests, max_tests):
    """The pairs of the box at position ``a`` of the sweep order with the boxes after it that start before it ends,
    written into ``pi, pj`` from ``count``; ``sweep``: ``(order, next_other, group, axis)`` of
    :func:`sweep_and_prune_kernel`.  Returns the new count and tests, and :data:`SWEPT`; or the count and tests as
    they were and :data:`FULL` when ``pi`` has no room left; or :data:`GAVE_UP` past ``max_tests``.  (A function of
    its own so that ``pi, pj`` are never reassigned inside the sweep's inner loop: numba would count references of
    such a loop-carried array at every test, which cost ten times the tests themselves.)"""
    order, next_other, group, axis = sweep
    p = len(order)
    i = order[a]
    end = hi[i, axis]
    start_count, start_tests = count, tests
    b = a + 1
    while b < p:
        j = order[b]
        if not lo[j, axis] <= end:
            break  # sorted by lower bound: no later box starts before this one ends (or a bound is NaN)
        if group[j] == group[i]:
            b = next_other[b]  # the rest of this run of i's own group
            continue
        tests += 1
        if max_tests >= 0 and tests > max_tests:
            return count, tests, GAVE_UP
        if _overlap(lo, hi, i, j):
            if count == len(pi):
                return start_count, start_tests, FULL
            pi[count] = min(i, j)
            pj[count] = max(i, j)
            count += 1
        b += 1
    return count, tests, SWEPT


@njit
def _grow(values, cap):
    out = np.empty(cap, values.dtype)
    out[:len(values)] = values
    return out


@njit(inline="always")
def _overlap(lo, hi, i, j):
    """Whether boxes ``i`` and ``j`` of ``lo, hi`` overlap (touching counts; a NaN bound never does)."""
    return lo[i, 0] <= hi[j, 0] and lo[j, 0] <= hi[i, 0] and lo[i, 1] <= hi[j, 1] and lo[j, 1] <= hi[i, 1] \
        and lo[i, 2] <= hi[j, 2] and lo[j, 2] <= hi[i, 2]


@njit(inline="always")
def _add_pair(pi, pj, count, i, j):
    """Append the pair ``(min, max)`` of ``i, j`` at ``count`` (the arrays doubled when full); returns them and the
    new count."""
    if count == len(pi):
        pi = _grow(pi, 2 * len(pi))
        pj = _grow(pj, 2 * len(pj))
    pi[count] = min(i, j)
    pj[count] = max(i, j)
    return pi, pj, count + 1


def grid_cell_size(lo: np.ndarray, hi: np.ndarray) -> float:
    """The grid's cell edge: the largest extent among boxes no larger than ``LARGE_FACTOR`` × the median
    (:func:`cell_edge`)."""
    return float(cell_edge(np.max(np.asarray(hi, float) - np.asarray(lo, float), axis=1)))


@njit
def cell_edge(extent):
    """The grid's cell edge from the boxes' largest extents ``(n,)`` (finite): the largest among those no larger
    than ``LARGE_FACTOR`` × the median; 1 m when there are none or all are points."""
    n = len(extent)
    if n == 0:
        return 1.0
    # the median as numpy's (the middle one, or the mean of the middle two), from the float merge sort the grid and
    # the sweep use anyway: numba's np.median compiles a selection algorithm of its own, ~1 s of a cold compile
    # (issue 34)
    ranked = extent[np.argsort(extent, kind="mergesort")]
    median = ranked[n // 2] if n % 2 else (ranked[n // 2 - 1] + ranked[n // 2]) / 2.0
    top = LARGE_FACTOR * median
    cell = 0.0
    for e in extent:
        if cell < e <= top:
            cell = e
    return cell if cell > 0.0 else 1.0


def grid_pairs(lo: np.ndarray, hi: np.ndarray, cell_size: float | None = None, group: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Uniform-grid broad phase (see the module docstring; compiled: :func:`grid_kernel`).  ``cell_size``
    defaults to :func:`grid_cell_size`; boxes larger than a cell are tested apart (see :func:`grid_kernel`)."""
    lo, hi, group = _check(lo, hi, group)
    p = len(lo)
    if p < 2:
        return _EMPTY
    cell = grid_cell_size(lo, hi) if cell_size is None else cell_size
    if not (isinstance(cell, (int, float, np.floating)) and np.isfinite(cell) and cell > 0.0):
        raise ValueError(f"grid cell size must be a positive number, got {cell_size!r}")
    group = np.arange(p) if group is None else np.ascontiguousarray(group, np.int64)
    i, j = grid_kernel(np.ascontiguousarray(lo), np.ascontiguousarray(hi), group, float(cell))
    return _sorted_pairs(i, j)


@njit
def grid_kernel(lo, hi, group, cell):
    """Every overlapping pair of AABBs ``lo, hi (p, 3)`` of different ``group`` (p,) once, as ``(i, j)`` with
    ``i < j``, unordered: a uniform grid of edge ``cell`` [m] (``<= 0``: :func:`cell_edge` of the finite boxes).  A box
    with a non-finite bound overlaps nothing.

    The grid is a sorted array (Ericson 7.1.5): each box no larger than a cell is filed under the cell of its
    lower corner, and the boxes are sorted by (cell, group).  A box then visits its own cell after itself and 13
    of the 26 neighbours (one of each opposite pair): a box it overlaps has its lower corner there, and each
    pair is met once.  Within a cell, a run of the box's own group is skipped at once (``skip``: the end of the
    run), so a particle body's particles, which share cells, cost nothing among themselves — as in
    :func:`sweep_and_prune_kernel`.  Larger boxes (walls, floors) are tested against the small boxes in their slab
    along x (a small box starts at most a cell before) and against each other by the sweep.  O(p) work for
    boxes of similar size, whatever their arrangement: the sweep's candidates grow as p² · (box / world) along
    its axis, so a dense 3-D pile of thousands of bodies is the grid's (:mod:`.detector` switches)."""
    p = len(lo)
    finite = np.empty(p, np.bool_)
    extent = np.empty(p)
    for k in range(p):
        ok = True
        e = 0.0
        for d in range(3):
            if not (np.isfinite(lo[k, d]) and np.isfinite(hi[k, d])):
                ok = False
            e = max(e, hi[k, d] - lo[k, d])
        finite[k] = ok
        extent[k] = e if ok else 0.0
    if cell <= 0.0:
        cell = cell_edge(extent[finite])
    # a hair larger, so two boxes whose lower corners are exactly one cell apart cannot land two cells apart
    # through the rounding of lo / cell
    cell *= 1.0 + 1e-9
    small = np.empty(p, np.bool_)
    for k in range(p):
        small[k] = finite[k] and extent[k] <= cell
    base = np.full(3, np.inf)
    top = np.full(3, -np.inf)
    for k in range(p):
        if small[k]:
            for d in range(3):
                base[d] = min(base[d], lo[k, d])
                top[d] = max(top[d], lo[k, d])
    cap = 8 * p + 16
    pi = np.empty(cap, np.int64)
    pj = np.empty(cap, np.int64)
    count = 0
    members = np.flatnonzero(small)
    m = len(members)
    if m >= 2:
        span = np.empty(3, np.int64)
        cells = 1.0
        for d in range(3):
            cells *= np.floor((top[d] - base[d]) / cell) + 3.0
        if cells > 2.0 ** 62:
            # spread over more cells than an int64 key can number (a body flung kilometres away): the sweep
            # needs no keys
            sub_i, sub_j, _ = sweep_and_prune_kernel(lo[members], hi[members], group[members], -1)
            for k in range(len(sub_i)):
                pi, pj, count = _add_pair(pi, pj, count, members[sub_i[k]], members[sub_j[k]])
        else:
            coords = np.empty((m, 3), np.int64)
            for k in range(m):
                for d in range(3):
                    coords[k, d] = np.int64(np.floor((lo[members[k], d] - base[d]) / cell)) + 1  # >= 1
            for d in range(3):
                span[d] = coords[:, d].max() + 2  # neighbours at -1 / +1 stay inside [0, span)
            stride0, stride1 = span[1] * span[2], span[2]
            key = coords[:, 0] * stride0 + coords[:, 1] * stride1 + coords[:, 2]
            by_group = np.argsort(group[members], kind="mergesort")
            order = by_group[np.argsort(key[by_group], kind="mergesort")]  # by cell, then by group
            sorted_key = key[order]
            box = members[order]  # the box at each sorted position
            # the boxes' bounds and groups in sorted order: a cell's boxes lie next to each other in memory
            slo = np.empty((m, 3))
            shi = np.empty((m, 3))
            sgroup = np.empty(m, np.int64)
            for a in range(m):
                slo[a] = lo[box[a]]
                shi[a] = hi[box[a]]
                sgroup[a] = group[box[a]]
            skip = np.empty(m, np.int64)  # position -> the end of its run of one cell and one group
            for a in range(m - 1, -1, -1):
                if a + 1 < m and sorted_key[a + 1] == sorted_key[a] and sgroup[a + 1] == sgroup[a]:
                    skip[a] = skip[a + 1]
                else:
                    skip[a] = a + 1
            offsets = np.empty(13, np.int64)
            n_off = 0
            for dx in range(-1, 2):
                for dy in range(-1, 2):
                    for dz in range(-1, 2):
                        if dx > 0 or (dx == 0 and (dy > 0 or (dy == 0 and dz > 0))):
                            offsets[n_off] = dx * stride0 + dy * stride1 + dz
                            n_off += 1
            # where each cell's run starts in the sorted order: a dense table for a compact grid (direct
            # indexing), else a binary search in the sorted keys (the "hash table" of Ericson 7.1.3)
            n_cells = span[0] * span[1] * span[2]
            dense = n_cells <= 8 * m + 4096
            start = np.zeros(n_cells + 1 if dense else 1, np.int64)
            if dense:
                for a in range(m):
                    start[sorted_key[a] + 1] += 1
                for c in range(n_cells):
                    start[c + 1] += start[c]
            run = 0
            while run < m:  # cell by cell: its neighbours' runs are looked up once for all its boxes
                run_end = run + 1
                while run_end < m and sorted_key[run_end] == sorted_key[run]:
                    run_end += 1
                for o in range(14):
                    if o == 0:
                        first, last = run, run_end  # the own cell: each box with the boxes after it
                    else:
                        target = sorted_key[run] + offsets[o - 1]
                        if dense:
                            first, last = start[target], start[target + 1]
                        else:
                            first = np.searchsorted(sorted_key, target)
                            last = np.searchsorted(sorted_key, target, side="right")
                    for a in range(run, run_end):
                        ga = sgroup[a]
                        b = a + 1 if o == 0 else first
                        while b < last:
                            if sgroup[b] == ga:
                                b = skip[b]  # the rest of this cell's run of a's own group
                                continue
                            if _overlap(slo, shi, a, b):
                                pi, pj, count = _add_pair(pi, pj, count, box[a], box[b])
                            b += 1
                run = run_end
    # the boxes larger than a cell (walls, floors; a heavy tail of sizes): against the small boxes in the slab
    # along x where one can overlap them (a small box starts at most one cell before the large box does), and
    # against each other by the sweep
    large = np.flatnonzero(finite & ~small)
    if len(large):
        by_x = members[np.argsort(lo[members, 0], kind="mergesort")]  # (the grid's one sort: no quicksort compiled)
        start_x = lo[by_x, 0]
        for i in large:
            first = np.searchsorted(start_x, lo[i, 0] - cell)
            last = np.searchsorted(start_x, hi[i, 0], side="right")
            for k in range(first, last):
                j = by_x[k]
                if group[j] != group[i] and _overlap(lo, hi, i, j):
                    pi, pj, count = _add_pair(pi, pj, count, i, j)
        if len(large) >= 2:
            sub_i, sub_j, _ = sweep_and_prune_kernel(lo[large], hi[large], group[large], -1)
            for k in range(len(sub_i)):
                pi, pj, count = _add_pair(pi, pj, count, large[sub_i[k]], large[sub_j[k]])
    return pi[:count], pj[:count]


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
