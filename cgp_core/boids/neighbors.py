"""Neighbour search: for every boid, the boids closer than a radius — the lists the rules loop over.

A *search* answers "who are boid i's neighbours?" and a *rule* (``rules.py``) loops over the answer.  The two
are kept apart on purpose: other neighbourhoods (the k nearest, "topological" neighbours after Ballerini et
al. 2008) and other rule sets (Couzin et al. 2002's zones of repulsion, orientation and attraction) plug in
on either side — a search returns a :class:`NeighborList`, a rule kernel takes one.

Three interchangeable backends return the *same* neighbour sets (a test proves it on random and awkward
point sets, open and periodic):

- :class:`GridSearch` — the fast one, average O(N): points sorted by cell of a uniform grid, each boid tests
  the points of the cells around its own that can hold a neighbour.  Compiled with numba, one boid per
  iteration of a parallel loop (both cores, the GIL released).
- :class:`KDTreeSearch` — scipy's ``cKDTree.query_pairs`` (O(N log N)), a second independent implementation.
- :class:`BruteForceSearch` — every pair, O(N²): the reference.

Common contract (what makes them interchangeable)
-------------------------------------------------
``search.neighbors(positions, radius, period=None) -> NeighborList`` with ``positions (N, 3)`` float64.
Membership is decided by one shared formula on these coordinates, :func:`pair_offset` and
:func:`squared_length`: ``d = x_j − x_i`` (the minimum image in a periodic box), ``r² = (dx² + dy²) + dz²``,
neighbour iff ``r² < radius²``.  A backend may find candidates any way it likes (cells, a tree with a slightly
larger radius, all pairs) but decides with this formula, so all backends agree to the last bit on who is a
neighbour.  The order within a row is the backend's (the grid: cell order; the others: ascending index); it is
deterministic, and it is the order the rules sum in, so two backends give the same trajectories up to the
round-off of that order.

Periodic boxes (``bounds_mode: wrap``): ``period (3,)`` holds the box size per axis (0 = open along that
axis) and the positions lie in ``[low, low + period)``; offsets are minimum images, ``d −= L·round(d / L)``,
unique as long as every side is longer than 2 d (``FlockParams`` checks it).

Every kernel here runs as plain Python under ``NUMBA_DISABLE_JIT=1`` with the same results (``jit.py``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit, pool_size, prange

# Relative slack on the search radius when *enumerating candidates* (never for membership): covers the tree's
# own rounding of the distances it compares.
_CANDIDATE_SLACK = 1e-6
# above this many cells per point (a sparse, far-spread cloud) the grid looks cells up by binary search in the
# sorted keys instead of a dense table of cell starts
_MAX_TABLE_CELLS_PER_POINT = 8
# cells per axis must stay below 2^20 so that a cell key (x, y, z) fits an int64
_MAX_CELLS_PER_AXIS = 2**20


class NeighborList(NamedTuple):
    """Every boid's neighbours, one row per boid, in the list's own numbering of the boids ("slots").

    A search may number the boids its own way: the grid numbers them in cell order, so that boids near each
    other in space are near each other in memory — a rule loop then reads its neighbours' data from a few
    cache lines instead of from all over the flock's arrays (at 15k boids that halves the loop's time).
    Rows and their entries are slots; :meth:`sorted` puts an array of the flock's (boid order) into slot order
    for a rule kernel, :meth:`unsorted` puts a kernel's per-slot result back into boid order.

    A k-nearest search fits the same layout (``start = k·s``, ``count = k``), so rule kernels written against
    it work for metric and topological neighbourhoods alike; they take the list whole (a bundle, see
    :mod:`cgp_core.jit`).
    """

    order: np.ndarray  # (N,) int64 — slot s is boid ``order[s]`` (the grid: cell order; the other backends: identity)
    start: np.ndarray  # (N,) int64 — where slot s's row begins in ``index``
    count: np.ndarray  # (N,) int64 — how many neighbours slot s has
    index: np.ndarray  # (C,) int32 — the rows: slot s's neighbours are the slots ``index[start[s] : start[s] +
    #                    count[s]]`` (in the backend's order).  ``C`` may exceed ``count.sum()``: a backend may leave
    #                    room it did not use between rows (the grid gives every row the same room, so no counting
    #                    pass is needed)

    @property
    def boids(self) -> int:
        return len(self.order)

    @property
    def total(self) -> int:
        """Number of (boid, neighbour) entries: twice the number of neighbour pairs."""
        return int(self.count.sum())

    def sorted(self, array: np.ndarray) -> np.ndarray:
        """``array`` (N,) or (N, k) in boid order → a copy in slot order (what a rule kernel reads)."""
        out = np.empty_like(array)
        if array.ndim == 1:
            _gather(array.reshape(-1, 1), self.order, out.reshape(-1, 1))
        else:
            _gather(array, self.order, out)
        return out

    def of(self, boid: int) -> np.ndarray:
        """Boid ``boid``'s neighbours, as boid indices."""
        slot = int(np.flatnonzero(self.order == boid)[0])
        return self.order[self.index[self.start[slot]:self.start[slot] + self.count[slot]]]

    def pairs(self) -> np.ndarray:
        """(P, 2) int64 unordered pairs of boids ``(a, b)``, ``a < b``, sorted: a canonical set for comparisons."""
        n = self.boids
        slot = np.repeat(np.arange(n), self.count)
        rows = [self.index[self.start[s]:self.start[s] + self.count[s]] for s in range(n)]
        other = np.concatenate(rows).astype(np.int64) if n else np.zeros(0, np.int64)
        a, b = self.order[slot], self.order[other]
        keep = a < b
        pairs = np.stack((a[keep], b[keep]), axis=1).astype(np.int64)
        return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


class BoidArrays(NamedTuple):
    """A flock's per-boid rows as a kernel reads them (N rows; in boid order, or in a list's slot order)."""

    positions: np.ndarray   # (N, 3) b [m]
    velocities: np.ndarray  # (N, 3) b_v [m/s]
    headings: np.ndarray    # (N, 3) unit headings (the frames' x axes)


@njit
def _gather(array, order, out):
    """``out[s] = array[order[s]]`` for rows of an (N, k) array (numpy's fancy indexing takes several times
    longer on (N, 3))."""
    columns = array.shape[1]
    if columns == 3:
        for s in range(order.shape[0]):
            b = order[s]
            out[s, 0], out[s, 1], out[s, 2] = array[b, 0], array[b, 1], array[b, 2]
    else:
        for s in range(order.shape[0]):
            for c in range(columns):
                out[s, c] = array[order[s], c]


@njit
def bounding_box(positions):
    """Per-axis minimum and maximum ``(low (3,), high (3,))`` of (N >= 1, 3) positions, in one pass."""
    low = positions[0].copy()
    high = positions[0].copy()
    for i in range(1, positions.shape[0]):
        for a in range(3):
            low[a] = min(low[a], positions[i, a])
            high[a] = max(high[a], positions[i, a])
    return low, high


# ---- the shared membership formula -------------------------------------------------------------------------

@njit
def minimum_image(d: float, period: float) -> float:
    """``d`` wrapped into ``[−L/2, L/2]`` for a periodic axis of length ``L = period`` (``period <= 0``: open
    axis, ``d`` unchanged)."""
    if period > 0.0:
        d -= period * math.floor(d / period + 0.5)
    return d


@njit
def pair_offset(positions: np.ndarray, i: int, j: int, period: np.ndarray):
    """``x_j − x_i`` as three floats, the minimum image along periodic axes."""
    dx = minimum_image(positions[j, 0] - positions[i, 0], period[0])
    dy = minimum_image(positions[j, 1] - positions[i, 1], period[1])
    dz = minimum_image(positions[j, 2] - positions[i, 2], period[2])
    return dx, dy, dz


@njit
def squared_length(dx: float, dy: float, dz: float) -> float:
    """``(dx² + dy²) + dz²`` — this exact order of operations wherever a neighbour distance is computed."""
    return (dx * dx + dy * dy) + dz * dz


# ---- checks ------------------------------------------------------------------------------------------------

def _check(positions: np.ndarray, radius: float, period) -> np.ndarray:
    if not isinstance(positions, np.ndarray) or positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must be an (N, 3) array, got shape {getattr(positions, 'shape', None)}")
    if positions.dtype != np.float64:
        raise ValueError(f"positions must be float64, got {positions.dtype}")
    if not (radius > 0.0 and math.isfinite(radius)):
        raise ValueError(f"radius must be a finite number > 0, got {radius!r}")
    period = np.zeros(3) if period is None else np.asarray(period, dtype=np.float64).reshape(3)
    if np.any(period < 0.0) or not np.all(np.isfinite(period)):
        raise ValueError(f"period must be 3 finite sizes >= 0 (0 = open axis), got {period.tolist()}")
    if np.any((period > 0.0) & (period <= 2.0 * radius)):
        raise ValueError(f"every periodic side must be longer than 2 * radius = {2.0 * radius}; got "
                         f"{period.tolist()}")
    return period


def _empty(n: int) -> NeighborList:
    return NeighborList(np.arange(n, dtype=np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64),
                        np.zeros(0, np.int32))


# ---- brute force ---------------------------------------------------------------------------------------------

@njit(parallel=True)
def _count_all_pairs(positions, radius2, period, count):
    n = positions.shape[0]
    for i in prange(n):
        found = 0
        for j in range(n):
            if j != i:
                dx, dy, dz = pair_offset(positions, i, j, period)
                if squared_length(dx, dy, dz) < radius2:
                    found += 1
        count[i] = found


@njit(parallel=True)
def _fill_all_pairs(positions, radius2, period, start, index):
    n = positions.shape[0]
    for i in prange(n):
        k = start[i]
        for j in range(n):
            if j != i:
                dx, dy, dz = pair_offset(positions, i, j, period)
                if squared_length(dx, dy, dz) < radius2:
                    index[k] = j
                    k += 1


class BruteForceSearch:
    """Every boid against every other, O(N²): the reference the fast backends are tested against."""

    name = "brute"

    def reset(self) -> None:
        pass

    def neighbors(self, positions: np.ndarray, radius: float, period=None) -> NeighborList:
        period = _check(positions, radius, period)
        n = len(positions)
        count = np.zeros(n, np.int64)
        _count_all_pairs(positions, radius * radius, period, count)
        start = np.zeros(n, np.int64)
        np.cumsum(count[:-1], out=start[1:])
        index = np.empty(int(count.sum()), np.int32)
        _fill_all_pairs(positions, radius * radius, period, start, index)
        return NeighborList(np.arange(n, dtype=np.int64), start, count, index)


# ---- KD-tree ---------------------------------------------------------------------------------------------------

@njit
def _keep_within(positions, pairs, radius2, period, keep):
    for k in range(pairs.shape[0]):
        dx, dy, dz = pair_offset(positions, pairs[k, 0], pairs[k, 1], period)
        keep[k] = squared_length(dx, dy, dz) < radius2


def kd_tree(positions: np.ndarray, period: np.ndarray, who: str):
    """``(tree, points)``: scipy's ``cKDTree`` over ``positions`` (N, 3) and the points it holds.  In a box
    periodic along every axis (``period`` > 0) the tree gets ``boxsize=period``, which wants coordinates in
    [0, L): the points are shifted by the lower corner and the rounding at L is folded back to 0.  A box
    periodic along some axes only is refused (``who`` names the caller in the error)."""
    from scipy.spatial import cKDTree  # here, not at import: scipy.spatial takes ~0.3 s to load

    periodic = period > 0.0
    if np.any(periodic) and not np.all(periodic):
        raise ValueError(f"{who} handles a box periodic along every axis or none")
    if np.all(periodic):
        points = np.mod(positions - positions.min(axis=0), period)
        points[points >= period] = 0.0
        return cKDTree(points, boxsize=period), points
    return cKDTree(positions), positions


class KDTreeSearch:
    """scipy ``cKDTree.query_pairs`` (``boxsize`` for periodic boxes) with a slightly larger radius, then the
    shared membership test; the pairs become rows in ascending index."""

    name = "kdtree"

    def reset(self) -> None:
        pass

    def neighbors(self, positions: np.ndarray, radius: float, period=None) -> NeighborList:
        period = _check(positions, radius, period)
        n = len(positions)
        if n < 2:
            return _empty(n)
        tree, _ = kd_tree(positions, period, "KDTreeSearch")
        scale = float(np.max(np.abs(positions))) if n else 0.0
        found = tree.query_pairs(radius * (1.0 + _CANDIDATE_SLACK) + 1e-12 * scale, output_type="ndarray")
        keep = np.empty(len(found), dtype=np.bool_)
        _keep_within(positions, found.astype(np.int64), radius * radius, period, keep)
        found = found[keep]
        boid = np.concatenate((found[:, 0], found[:, 1]))
        other = np.concatenate((found[:, 1], found[:, 0])).astype(np.int32)
        order = np.lexsort((other, boid))
        count = np.bincount(boid, minlength=n).astype(np.int64)
        start = np.zeros(n, np.int64)
        np.cumsum(count[:-1], out=start[1:])
        return NeighborList(np.arange(n, dtype=np.int64), start, count, other[order])


# ---- the grid --------------------------------------------------------------------------------------------------

#: The half shell: a pair is found once, from the boid whose column comes first in the grid's (x, y) order —
#: its own column (later slots only) and these four, as (Δx, Δy) in columns.
_FORWARD_COLUMNS = ((0, 0), (0, 1), (1, -1), (1, 0), (1, 1))


class CellGrid(NamedTuple):
    """The grid search's points sorted by cell (N points in slot order) and how to find a cell's run of them."""

    relative: np.ndarray     # (N, 3) positions relative to the cloud's lower corner (periodic axes folded)
    positions: np.ndarray    # (N, 3) positions
    edge: np.ndarray         # (3,) cell sizes [m]
    dims: np.ndarray         # (3,) int64 cells per axis
    period: np.ndarray       # (3,) periodic box sizes (0: open axis)
    dense: bool              # cells looked up in ``table`` (else by binary search in ``sorted_keys``)
    table: np.ndarray        # (cells + 1,) int64 first slot of each cell (dense), else unused
    sorted_keys: np.ndarray  # (N,) int64 cell key of each slot (sparse), else empty
    radius: float            # the neighbour radius d [m]


class Probe(NamedTuple):
    """One point's candidate test: the point and the shared formula's parameters."""

    x: float
    y: float
    z: float
    radius2: float   # d²
    periodic: bool   # minimum images along the periodic axes of ``CellGrid.period``


@njit
def _first_slot(key, grid):
    """The first sorted slot of the cell ``key`` or of a later one: from the dense table of cell starts, or
    by binary search in the sorted keys (sparse clouds)."""
    if grid.dense:
        return grid.table[key]
    sorted_keys = grid.sorted_keys
    first, last = 0, sorted_keys.shape[0]  # the first index whose key is >= key (a lower bound)
    while first < last:
        middle = (first + last) // 2
        if sorted_keys[middle] < key:
            first = middle + 1
        else:
            last = middle
    return first


@njit
def _neighbor_column(c, offset, dims, periodic):
    """Column coordinate ``c + offset`` along x or y: wrapped in a periodic axis, −1 when off an open grid or
    when a periodic axis has a single column (every offset is then the own column)."""
    if offset == 0:
        return c
    if periodic:
        if dims == 1:
            return -1
        c += offset
        return c + dims if c < 0 else (c - dims if c >= dims else c)
    c += offset
    return -1 if c < 0 or c >= dims else c


@njit
def _column_gap(inside, edge, offset):
    """Distance along one axis from a point (``inside`` = its offset from its cell's lower face) to the
    neighbouring column at ``offset`` (0 for its own column)."""
    if offset == 0:
        return 0.0
    inside = min(max(inside, 0.0), edge)
    return inside if offset < 0 else edge - inside


@njit
def _test_run(first, last, probe, grid, index, row, room, found):
    """Test the candidates in slots [first, last) against the :class:`Probe` with the shared formula and
    append the slots that pass to the row ``index[row :]``; returns the new number found.

    The store is unconditional and ``found`` advances by the test's outcome (the entry after the last one
    found is scratch; ``room`` clamps it, past which the row has overflowed): a branch-free loop runs ~1.5
    times faster than an ``if`` the processor mispredicts for about one candidate in three."""
    sorted_positions, period = grid.positions, grid.period
    x0, y0, z0, radius2, periodic = probe
    for t in range(first, last):
        dx = sorted_positions[t, 0] - x0
        dy = sorted_positions[t, 1] - y0
        dz = sorted_positions[t, 2] - z0
        if periodic:
            dx = minimum_image(dx, period[0])
            dy = minimum_image(dy, period[1])
            dz = minimum_image(dz, period[2])
        index[row + min(found, room)] = t
        found += squared_length(dx, dy, dz) < radius2
    return found


@njit
def _count_run(first, last, probe, grid, found):
    """:func:`_test_run` without writing: how many of the slots [first, last) pass."""
    sorted_positions, period = grid.positions, grid.period
    x0, y0, z0, radius2, periodic = probe
    for t in range(first, last):
        dx = sorted_positions[t, 0] - x0
        dy = sorted_positions[t, 1] - y0
        dz = sorted_positions[t, 2] - z0
        if periodic:
            dx = minimum_image(dx, period[0])
            dy = minimum_image(dy, period[1])
            dz = minimum_image(dz, period[2])
        found += squared_length(dx, dy, dz) < radius2
    return found


@njit(parallel=True)
def _forward_neighbors(grid, row_start, row_room, forward, index):
    """Half shell, parallel over slots (the :class:`CellGrid`'s): each slot's neighbours among the *later* ones
    (own column: later slots;
    the four forward columns: all), written as slots to the slot's row ``index[row_start[s] :]`` (which has
    ``row_room[s] + 1`` entries: the last is scratch; ``row_room[s] < 0``: count only, write nothing); their
    number to ``forward[s]`` (more than ``row_room[s]``: the row overflowed).

    Per column, the candidates are the z cells ``[z − d, z + d]`` — one run of the sorted order (two when it
    wraps around a periodic z axis) — and columns farther than d from the point in the xy plane are skipped.
    """
    relative, sorted_positions, edge, dims, period, radius = (grid.relative, grid.positions, grid.edge, grid.dims,
                                                              grid.period, grid.radius)
    n = relative.shape[0]
    radius2 = radius * radius
    reach = radius * (1.0 + _CANDIDATE_SLACK)  # candidate enumeration only: a little generous
    x_periodic, y_periodic, z_periodic = period[0] > 0.0, period[1] > 0.0, period[2] > 0.0
    periodic = x_periodic or y_periodic or z_periodic
    for s in prange(n):
        row, room = row_start[s], row_room[s]
        rx, ry, rz = relative[s, 0], relative[s, 1], relative[s, 2]
        probe = Probe(sorted_positions[s, 0], sorted_positions[s, 1], sorted_positions[s, 2], radius2, periodic)
        cx = min(int(rx / edge[0]), dims[0] - 1)
        cy = min(int(ry / edge[1]), dims[1] - 1)
        z_first = int(math.floor((rz - reach) / edge[2]))
        z_last = int(math.floor((rz + reach) / edge[2]))
        # the z cells [z_first, z_last] as up to two runs of cells [a0, a1] and [b0, b1] (a periodic wrap)
        b0, b1 = 0, -1
        if z_periodic:
            if z_last - z_first + 1 >= dims[2]:
                a0, a1 = 0, dims[2] - 1
            elif z_first < 0:
                a0, a1, b0, b1 = z_first + dims[2], dims[2] - 1, 0, z_last
            elif z_last >= dims[2]:
                a0, a1, b0, b1 = z_first, dims[2] - 1, 0, z_last - dims[2]
            else:
                a0, a1 = z_first, z_last
        else:
            a0, a1 = max(z_first, 0), min(z_last, dims[2] - 1)
        found = 0
        for ox, oy in _FORWARD_COLUMNS:
            nx = _neighbor_column(cx, ox, dims[0], x_periodic)
            ny = _neighbor_column(cy, oy, dims[1], y_periodic)
            if nx < 0 or ny < 0:
                continue
            gx = _column_gap(rx - cx * edge[0], edge[0], ox)
            gy = _column_gap(ry - cy * edge[1], edge[1], oy)
            if gx * gx + gy * gy >= reach * reach:
                continue
            column = (nx * dims[1] + ny) * dims[2]
            own = ox == 0 and oy == 0
            for run in range(2):
                first_cell, last_cell = (a0, a1) if run == 0 else (b0, b1)
                if last_cell < first_cell:
                    continue
                first = _first_slot(column + first_cell, grid)
                last = _first_slot(column + last_cell + 1, grid)
                if own:
                    first = max(first, s + 1)
                if room < 0:
                    found = _count_run(first, last, probe, grid, found)
                else:
                    found = _test_run(first, last, probe, grid, index, row, room, found)
        forward[s] = found


@njit(parallel=True)
def _complete_rows(forward_start, forward, forward_index, start, room, count, index, parts):
    """Full rows from the half-shell ones: slot s's row ``index[start[s] :]`` gets s's forward entries (from
    ``forward_index[forward_start[s] :]``; nothing to copy when the two are the same place) and every s' < s
    that has s among its forward entries, in ascending s'.  ``count`` = the full rows' lengths.  Returns False
    if a row needed more than ``room[s]`` entries (then the rows are incomplete).

    The appending is split into ``parts`` (one per thread) by the *receiving* row: part k walks every forward
    entry in slot order and appends only to the rows of its range of slots.  Each row is appended to by one
    part, in the same order as a single sequential walk, so the rows do not depend on ``parts``; every part
    reads all the entries (a sequential read) but writes only its share (the scattered writes are the cost)."""
    n = forward.shape[0]
    in_place = forward_index is index
    for s in prange(n):
        count[s] = forward[s]
        if not in_place:
            for k in range(forward[s]):
                index[start[s] + k] = forward_index[forward_start[s] + k]
    fits = np.ones(parts, np.bool_)
    for part in prange(parts):
        low, high = n * part // parts, n * (part + 1) // parts
        for s in range(n):
            for k in range(forward_start[s], forward_start[s] + forward[s]):
                t = forward_index[k]
                if low <= t < high:
                    if count[t] >= room[t]:
                        fits[part] = False
                        break
                    index[start[t] + count[t]] = s
                    count[t] += 1
            if not fits[part]:
                break
    return fits.all()


@njit
def _relative(positions, low, period, relative):
    """Positions relative to the cloud's lower corner, folded into [0, L) along periodic axes."""
    for i in range(positions.shape[0]):
        for a in range(3):
            r = positions[i, a] - low[a]
            if period[a] > 0.0:
                r = r % period[a]
            relative[i, a] = r


@njit
def _cell_keys(relative, edge, dims, keys):
    """Cell key of every point, x-major then y then z (a point on the far face of the box joins the last
    cell)."""
    for i in range(relative.shape[0]):
        cx = min(int(relative[i, 0] / edge[0]), dims[0] - 1)
        cy = min(int(relative[i, 1] / edge[1]), dims[1] - 1)
        cz = min(int(relative[i, 2] / edge[2]), dims[2] - 1)
        keys[i] = (cx * dims[1] + cy) * dims[2] + cz


@njit
def _counting_sort(keys, cell_count, table, order):
    """Stable counting sort of the boids by cell key: ``table[c]`` = first sorted slot of cell c (size
    ``cell_count + 1``), ``order`` = boids in cell order (ties in boid order)."""
    for c in range(cell_count + 1):
        table[c] = 0
    for i in range(keys.shape[0]):
        table[keys[i] + 1] += 1
    for c in range(cell_count):
        table[c + 1] += table[c]
    cursor = table[:-1].copy()
    for i in range(keys.shape[0]):
        order[cursor[keys[i]]] = i
        cursor[keys[i]] += 1


class GridSearch:
    """Uniform grid on cell-sorted arrays: average O(N) at bounded density; compiled, parallel over boids.

    Cells are ``d × d × d/4`` (z split finer; in a periodic box the edges are stretched to divide its sides).
    Steps (``neighbors``):

    1. cell coordinates ``floor((x − low) / edge)`` per axis and one integer key per boid, x-major then y then
       z, so that a z *column* of cells (fixed x, y) — and any z range inside it — is one contiguous run of
       the sorted order;
    2. boids sorted by key (a counting sort, O(N + cells)); ``table[key]`` = first sorted slot of each cell (a
       dense table over the cloud's bounding box; for a sparse cloud spread over far more cells than boids, a
       binary search in the sorted keys instead);
    3. half shell, in parallel: each boid tests, in its own column (later slots only) and the four columns
       after it, the z cells within d of it (columns farther than d in the xy plane are skipped), with the
       shared formula — every pair is tested once;
    4. rows completed, sequentially: a pair found from one end is entered in the other end's row too.

    The thin z cells make the ranges tight: the candidates fill ~2.5 times the neighbourhood sphere's volume,
    each pair tested once.  Rows come out in cell order, the pairs found from the boid first, then those found
    from its neighbours (the rules sum in that order: it is deterministic; other backends give the same sets in
    another order, hence the same trajectories up to round-off).  The list's slots are the cell order.

    Every row has the same room (``capacity``), so the boids fill their rows in parallel without counting
    first; the room grows (and the search is repeated) when a row overflows, which happens only when a flock
    gets denser than it ever was.  The buffer is kept between calls, so a step allocates nothing large: a
    returned list is valid until the next call.  A clump of hundreds of boids within d of each other (a flock
    spawned in a point, pressed into a corner) would make every row that long; beyond
    :data:`MAX_UNIFORM_CAPACITY` the rows are sized exactly instead (a counting pass first).
    """

    name = "grid"
    #: z cells per neighbour radius (more: tighter z ranges but more cells; 4 measured best)
    Z_CELLS_PER_RADIUS = 4
    #: room per row to start with; grown by half on overflow, up to MAX_UNIFORM_CAPACITY; beyond, rows are sized
    #: exactly (two passes: see _exact)
    INITIAL_CAPACITY = 48
    MAX_UNIFORM_CAPACITY = 256

    def __init__(self):
        self._capacity = self.INITIAL_CAPACITY
        self._index = np.zeros(0, np.int32)
        self._uniform: tuple | None = None  # (n, capacity, row starts, rooms) of the uniform layout

    def reset(self) -> None:
        pass

    def neighbors(self, positions: np.ndarray, radius: float, period=None) -> NeighborList:
        period = _check(positions, radius, period)
        n = len(positions)
        if n < 2:
            return _empty(n)
        periodic = period > 0.0
        low, high = bounding_box(positions)
        relative = np.empty_like(positions)
        _relative(positions, low, period, relative)  # periodic axes folded into [0, L)
        wanted_edge = np.array([radius, radius, radius / self.Z_CELLS_PER_RADIUS])
        dims = np.where(periodic, np.maximum(np.floor(period / wanted_edge), 1.0),
                        np.floor((high - low) / wanted_edge) + 1.0)
        # a periodic x or y axis of 2 columns would make the columns before and after a boid the same one (a
        # pair found twice): one column then (the axis is shorter than 3 d, a tiny box)
        dims[:2] = np.where(periodic[:2] & (dims[:2] < 3.0), 1.0, dims[:2])
        if np.any(dims > _MAX_CELLS_PER_AXIS):
            raise ValueError(f"the flock spans {((high - low) / radius).round().tolist()} neighbour radii "
                             f"on an axis, more than {_MAX_CELLS_PER_AXIS // self.Z_CELLS_PER_RADIUS}; bound it "
                             "(bounds_mode 'soft' or 'wrap')")
        edge = np.where(periodic, period / dims, wanted_edge)
        dims = dims.astype(np.int64)
        keys = np.empty(n, np.int64)
        _cell_keys(relative, edge, dims, keys)
        cell_count = int(dims[0] * dims[1] * dims[2])
        order = np.empty(n, np.int64)
        dense = cell_count <= _MAX_TABLE_CELLS_PER_POINT * n + (1 << 16)
        if dense:
            table = np.empty(cell_count + 1, np.int64)
            _counting_sort(keys, cell_count, table, order)
            sorted_keys = keys[:0]
        else:
            order[:] = np.argsort(keys, kind="stable")
            sorted_keys = keys[order]
            table = np.zeros(1, np.int64)
        sorted_positions = np.empty_like(positions)
        sorted_relative = np.empty_like(relative)
        _gather(positions, order, sorted_positions)
        _gather(relative, order, sorted_relative)
        grid = CellGrid(sorted_relative, sorted_positions, edge, dims, period, dense, table, sorted_keys,
                        float(radius))
        forward = np.empty(n, np.int64)
        count = np.empty(n, np.int64)
        while self._capacity <= self.MAX_UNIFORM_CAPACITY:
            start, room = self._uniform_layout(n)
            _forward_neighbors(grid, start, room - 1, forward, self._index)
            if forward.max() < self._capacity - 1 and _complete_rows(start, forward, self._index, start, room, count,
                                                                     self._index, pool_size()):
                return NeighborList(order, start, count, self._index)
            self._capacity = int(1.5 * self._capacity) + 8  # a flock denser than ever: more room, once more
        result = self._exact(grid, order, forward, count)
        # the next call tries the uniform layout again once the clump has dispersed
        largest = int(count.max())
        self._capacity = int(1.5 * largest) + 8 if 1.5 * largest + 8 <= self.MAX_UNIFORM_CAPACITY else \
            self.MAX_UNIFORM_CAPACITY + 1
        return result

    def _uniform_layout(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Row starts ``capacity · s`` and rooms (all ``capacity``) for n slots, kept between calls."""
        if self._uniform is None or self._uniform[:2] != (n, self._capacity):
            if len(self._index) < self._capacity * n:
                self._index = np.empty(self._capacity * n, np.int32)
            self._uniform = (n, self._capacity, np.arange(n, dtype=np.int64) * self._capacity,
                             np.full(n, self._capacity, np.int64))
        return self._uniform[2], self._uniform[3]

    def _exact(self, grid, order, forward, count) -> NeighborList:
        """Rows sized exactly, for flocks with a dense clump: one row of thousands would make every row that
        long in the uniform layout (N × the largest row).  Counts first (a pass that writes nothing), then the
        forward rows at their exact size, then the full rows."""
        n = len(order)
        no_index = np.zeros(0, np.int32)
        _forward_neighbors(grid, np.zeros(n, np.int64), np.full(n, -1, np.int64), forward, no_index)
        forward_start = np.zeros(n, np.int64)
        np.cumsum(forward[:-1] + 1, out=forward_start[1:])  # + 1: each row's scratch entry
        forward_index = np.empty(int(forward.sum()) + n, np.int32)
        _forward_neighbors(grid, forward_start, forward, forward, forward_index)
        entries = np.repeat(forward_start - (np.cumsum(forward) - forward), forward) + np.arange(int(forward.sum()))
        full = forward + np.bincount(forward_index[entries], minlength=n)  # + the rows' backward entries
        start = np.zeros(n, np.int64)
        np.cumsum(full[:-1], out=start[1:])
        index = np.empty(int(full.sum()), np.int32)
        if not _complete_rows(forward_start, forward, forward_index, start, full, count, index, pool_size()):
            raise AssertionError("exact neighbour rows overflowed")  # pragma: no cover - sized exactly
        return NeighborList(order, start, count, index)


def make_search(name: str):
    """The backend called ``name`` ('grid', 'kdtree', 'brute')."""
    backends = {"grid": GridSearch, "kdtree": KDTreeSearch, "brute": BruteForceSearch}
    try:
        return backends[name]()
    except KeyError:
        raise ValueError(f"unknown neighbor_search {name!r}; choose one of {', '.join(backends)}") from None
