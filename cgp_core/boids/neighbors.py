"""Fixed-radius neighbour search: every unordered pair of points closer than ``radius``.

Three interchangeable backends return the *same* pair set (a test proves it on random flocks):

- :class:`GridSearch` — the fast one, average O(N): points sorted by cell, pairs enumerated from contiguous
  runs of the sorted arrays (details in the class docstring).
- :class:`KDTreeSearch` — scipy's ``cKDTree.query_pairs`` (O(N log N)); kept for comparison and as a second
  independent implementation.
- :class:`BruteForceSearch` — all N(N−1)/2 pairs, the O(N²) reference.

Common contract (what makes them interchangeable)
-------------------------------------------------
``search.pairs(points, radius, reuse=True) -> NeighborPairs`` with ``points (3, W)`` float32 *work coordinates* (component
-major: one contiguous row per axis, which is what numpy is fast at).  The membership test is one shared
float32 formula, :func:`pair_offsets`: ``r2 = (dx*dx + dy*dy) + dz*dz < radius²`` with ``dx = x_j − x_i``.
A backend may find candidates any way it likes (cells, a tree with a slightly larger radius, all pairs) but
decides membership only with this formula on these coordinates, so all backends agree to the last bit.

``reuse=False`` tells a backend that keeps state between calls (the grid's candidate list) that these are
not the same points as last call.

Periodic worlds are handled outside the backends by :func:`periodic_images`: points near a face get a
shifted copy ("ghost") beyond the opposite face, and a backend sees only open space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# Relative slack on the search radius when *enumerating candidates* (never for membership): covers float32
# rounding of cell coordinates and of the work coordinates the tree sees.
_CANDIDATE_SLACK = 1e-3


@dataclass
class NeighborPairs:
    """Unordered neighbour pairs of W points, in a backend-chosen order of the points.

    Attributes (shapes):
        order:  (W,) intp — a permutation of range(W): slot ``s`` holds point ``order[s]``.  The grid uses
                its cell-sorted order (memory locality); the other backends the identity.
        i, j:   (P,) int32 — slots of the two ends, ``i < j``, ``i`` non-decreasing.
        rows:   (P, 4) float32 — per pair ``[dx, dy, dz, r2]``: the offset ``x_j − x_i`` in work coordinates
                and its squared length as computed by :func:`pair_offsets` (< radius²).  One 16-byte row per
                pair because numpy gathers whole rows several times faster than separate components.

    ``offset`` (3, P) and ``dist2`` (P,) are (strided) views of ``rows``.
    """

    order: np.ndarray
    i: np.ndarray
    j: np.ndarray
    rows: np.ndarray

    @property
    def count(self) -> int:
        return len(self.i)

    @property
    def offset(self) -> np.ndarray:
        return self.rows[:, :3].T

    @property
    def dist2(self) -> np.ndarray:
        return self.rows[:, 3]

    def point_pairs(self) -> np.ndarray:
        """(P, 2) int64 pairs of *point* indices (smaller first), sorted: a canonical set for comparisons."""
        a = self.order[self.i]
        b = self.order[self.j]
        pairs = np.stack((np.minimum(a, b), np.maximum(a, b)), axis=1).astype(np.int64)
        return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def pair_offsets(points: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """The shared membership formula, as ``rows (P, 4)`` = ``[dx, dy, dz, r2]`` with ``d = points[:, j] −
    points[:, i]`` and ``r2 = (dx*dx + dy*dy) + dz*dz``, in float32 (``points`` is float32)."""
    rows = np.zeros((len(i), 4), dtype=np.float32)
    for axis in range(3):
        np.subtract(np.take(points[axis], j), np.take(points[axis], i), out=rows[:, axis])
    _squared_length(rows)
    return rows


def _squared_length(rows: np.ndarray, scratch: np.ndarray | None = None) -> np.ndarray:
    """Fill ``rows[:, 3]`` with ``(dx*dx + dy*dy) + dz*dz`` (this exact order of operations everywhere) and
    return it (a view).  The squares are taken on whole 16-byte rows at once, into ``scratch`` (same shape as
    ``rows``) if given: one contiguous pass instead of three strided ones.  That squares ``rows[:, 3]`` too
    (then overwritten), so it must hold a finite value on entry: every caller has 0 there."""
    square = np.multiply(rows, rows, out=scratch)
    r2 = rows[:, 3]
    np.add(square[:, 0], square[:, 1], out=r2)
    r2 += square[:, 2]
    return r2


def _empty_pairs(width: int, order: np.ndarray | None = None) -> NeighborPairs:
    return NeighborPairs(order=np.arange(width) if order is None else order, i=np.zeros(0, np.int32),
                         j=np.zeros(0, np.int32), rows=np.zeros((0, 4), np.float32))


class _KeptPairs:
    """Output of a block-by-block pair test: arrays sized for every candidate, filled front to back with the
    pairs each block keeps (no per-block pieces to concatenate at the end: one pass less over the pairs).

    ``mode="clip"`` on the gathers: the indices are valid by construction, and numpy's default
    bounds-checking mode would copy through a buffer when writing into ``out``."""

    def __init__(self, capacity: int):
        self.i = np.empty(capacity, dtype=np.int32)
        self.j = np.empty(capacity, dtype=np.int32)
        self.rows = np.empty((capacity, 4), dtype=np.float32)
        self.count = 0

    def append(self, keep: np.ndarray, i: np.ndarray, j: np.ndarray, rows: np.ndarray) -> None:
        """Append the candidates ``keep`` (indices) of a block with ends ``i``, ``j`` and ``rows``."""
        first, end = self.count, self.count + len(keep)
        np.take(i, keep, out=self.i[first:end], mode="clip")
        np.take(j, keep, out=self.j[first:end], mode="clip")
        np.take(rows, keep, axis=0, out=self.rows[first:end], mode="clip")
        self.count = end

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(i, j, rows)`` of the kept pairs (views)."""
        return self.i[:self.count], self.j[:self.count], self.rows[:self.count]


def _check_points(points: np.ndarray, radius: float) -> None:
    if points.ndim != 2 or points.shape[0] != 3:
        raise ValueError(f"points must have shape (3, W) (component-major), got {points.shape}")
    if points.dtype != np.float32:
        raise ValueError(f"points must be float32 work coordinates, got {points.dtype}")
    if not (radius > 0.0 and math.isfinite(radius)):
        raise ValueError(f"radius must be a finite number > 0, got {radius!r}")


class BruteForceSearch:
    """All pairs, O(N²) time, O(block · N) memory: the reference the fast backends are tested against."""

    name = "brute"

    def __init__(self, block: int = 1024):
        self.block = block

    def reset(self) -> None:
        pass

    def pairs(self, points: np.ndarray, radius: float, reuse: bool = True) -> NeighborPairs:
        _check_points(points, radius)
        width = points.shape[1]
        radius2 = np.float32(radius * radius)
        found_i, found_j = [], []
        x, y, z = points
        for first in range(0, width, self.block):
            last = min(first + self.block, width)
            # the shared formula, dense: rows are i, columns j
            dx = x[None, :] - x[first:last, None]
            dy = y[None, :] - y[first:last, None]
            dz = z[None, :] - z[first:last, None]
            dist2 = dx * dx
            dist2 += dy * dy
            dist2 += dz * dz
            rows, cols = np.nonzero((dist2 < radius2) & np.triu(np.ones(dist2.shape, bool), k=first + 1))
            found_i.append(rows.astype(np.int32) + np.int32(first))
            found_j.append(cols.astype(np.int32))
        if not found_i:
            return _empty_pairs(width)
        i = np.concatenate(found_i)
        j = np.concatenate(found_j)
        return NeighborPairs(order=np.arange(width), i=i, j=j, rows=pair_offsets(points, i, j))


class KDTreeSearch:
    """scipy ``cKDTree.query_pairs`` with a slightly larger radius, then the shared exact test."""

    name = "kdtree"

    def reset(self) -> None:
        pass

    def pairs(self, points: np.ndarray, radius: float, reuse: bool = True) -> NeighborPairs:
        _check_points(points, radius)
        width = points.shape[1]
        if width < 2:
            return _empty_pairs(width)
        coordinates = points.T.astype(np.float64)
        scale = float(np.max(np.abs(coordinates)))
        tree = cKDTree(coordinates)
        found = tree.query_pairs(radius * (1.0 + _CANDIDATE_SLACK) + 1e-6 * scale, output_type="ndarray")
        i = found[:, 0].astype(np.int32)  # query_pairs returns i < j
        j = found[:, 1].astype(np.int32)
        rows = pair_offsets(points, i, j)
        keep = rows[:, 3] < np.float32(radius * radius)
        i, j, rows = i[keep], j[keep], rows[keep]
        sort = np.lexsort((j, i))
        return NeighborPairs(order=np.arange(width), i=i[sort], j=j[sort], rows=rows[sort])


@dataclass
class _CandidateList:
    """Pairs within ``radius + skin`` of the points at one instant (the grid's reusable candidates).

    Attributes (shapes):
        radius:    the neighbour radius d the list serves.
        skin:      how much farther than d the list reaches [work units].
        order:     (W,) intp — slot order of the build.
        i, j:      (C,) int32 — candidate pairs (slots), ``i < j``, ``i`` non-decreasing.
        reference: (3, W) float32 — the points (point order) when the list was built.
    """

    radius: float
    skin: float
    order: np.ndarray
    i: np.ndarray
    j: np.ndarray
    reference: np.ndarray


class GridSearch:
    """Uniform grid on cell-sorted arrays: average O(N) for bounded density, exact, pure numpy.

    **Candidate list (Verlet list).**  The grid finds the pairs within ``d + skin`` (``skin = skin_fraction ·
    d``) and keeps them.  Later calls only re-test those candidates with the shared formula, until some two
    points may have closed the skin: a pair's distance changes by at most ``|Δ_a − Δ_b| <= 2 max |Δ − c|``
    (Δ the displacements since the build, c any common vector: the centre of their bounding box, so a flock
    gliding as a whole never forces a rebuild), so the list is rebuilt when ``2 max |Δ − c|`` reaches the
    skin.  Exact at every call; what the list saves is the cell search (a candidate test is ~3 times cheaper
    than finding it), paid back every few ticks by one rebuild with the larger radius.  Call
    ``pairs(..., reuse=False)`` (or :meth:`reset`) when the points are not the same points as last call.

    **Cell search** (each build).  Cells are ``d' × d' × d'/4`` (``d' = d + skin``; z is split finer):

    1. cell coordinates → one integer key per point, x-major then y then z; points sorted by key.  A whole
       z *column* of cells (fixed x, y) is then one contiguous run of the sorted arrays, and so is any z
       range inside it.  The sort starts from the previous build's order: points move little between
       builds, the keys are nearly sorted and numpy's stable sort (timsort) is then close to O(N).
    2. ``start[key]``: index of the first sorted point of each cell (a dense table over the point cloud's
       bounding box: bincount + cumsum; a binary search when that box would be too large for a table).
    3. Half shell: a pair is found once, from the point whose column comes first.  Each point looks at 5
       columns — its own (only later points: ``i < j``) and (x, y+1), (x+1, y−1), (x+1, y), (x+1, y+1) —
       and in each only at the z range that can hold neighbours: with ``ρ`` the distance from the point to
       the column in the xy plane, ``|Δz| < sqrt(d'² − ρ²)``; columns with ``ρ ≥ d'`` are skipped.  The thin
       z cells make that range tight: the candidates fill ~3.5 times the neighbourhood sphere's volume
       (a plain 3 × 3 × 3 cell search: 6.4 times, half of it twice).
    4. Candidates are enumerated with ``np.repeat``/``cumsum`` (no Python loop per point), tested with the
       shared formula and compressed, in blocks of ~24k candidates so the temporaries stay in cache, with the
       points as 16-byte rows (one row gather per candidate).

    **The slot order is part of the result.**  Pairs come out sorted by (slot i, slot j), and the neighbour
    sums (``rules.py``) add each boid's neighbours in that order, in float32: another slot order gives other
    roundings (~1e-8 m after the first rebuild of a 2,000-boid flock), hence other trajectories.  The order
    is the cell key order with ties (points sharing a cell) kept in the previous build's order, so the cell
    shape (``d' × d' × d'/4``) and the rebuild schedule fix the results bit for bit: finer x/y columns
    would cut the candidates (~3.3 tested per pair within d') but change the order, and so would another
    skin or rebuild criterion.
    """

    name = "grid"
    # z cells per radius: 4 measured best (fewer → more candidates; more → more z cells, no fewer columns)
    Z_CELLS_PER_RADIUS = 4
    _BLOCK_CANDIDATES = 24_000  # ~100 kB per temporary: measured best on this machine (L2-sized)
    # above this many cells per point the dense start table is replaced by a binary search (sparse flocks)
    _MAX_TABLE_CELLS_PER_POINT = 16

    def __init__(self, skin_fraction: float = 0.15):
        if not (skin_fraction >= 0.0 and math.isfinite(skin_fraction)):
            raise ValueError(f"skin_fraction must be a finite number >= 0, got {skin_fraction!r}")
        self.skin_fraction = skin_fraction
        self._previous_order: np.ndarray | None = None
        self._ramp_cache = np.zeros(0, dtype=np.int32)
        self._list: _CandidateList | None = None
        self.builds = 0  # how many times the cell search ran (for benchmarks)

    def _ramp(self, length: int) -> np.ndarray:
        """0, 1, …, length − 1 as int32 (cached: allocated once, not per block)."""
        if len(self._ramp_cache) < length:
            self._ramp_cache = np.arange(max(length, 2 * len(self._ramp_cache)), dtype=np.int32)
        return self._ramp_cache[:length]

    def reset(self) -> None:
        """Forget the candidate list and the previous order (results never depend on them, only speed)."""
        self._previous_order = None
        self._list = None

    def pairs(self, points: np.ndarray, radius: float, reuse: bool = True) -> NeighborPairs:
        _check_points(points, radius)
        width = points.shape[1]
        radius2 = np.float32(radius * radius)
        cached = self._list
        if (reuse and cached is not None and cached.radius == radius and cached.reference.shape[1] == width
                and self._within_skin(points, cached)):
            return self._filter(points, cached, radius2)
        skin = self.skin_fraction * radius
        order, i, j, rows = self._cell_search(points, radius + skin)
        self.builds += 1
        self._list = _CandidateList(radius, skin, order, i, j, points.copy()) if reuse and skin > 0.0 else None
        if skin > 0.0:
            keep = np.flatnonzero(rows[:, 3] < radius2)
            i, j, rows = np.take(i, keep), np.take(j, keep), np.take(rows, keep, axis=0)
        return NeighborPairs(order=order, i=i, j=j, rows=rows)

    @staticmethod
    def _within_skin(points: np.ndarray, cached: _CandidateList) -> bool:
        """True while no pair can have come from beyond d + skin to within d since the build."""
        displacement = points - cached.reference
        centre = 0.5 * (displacement.max(axis=1) + displacement.min(axis=1))
        displacement -= centre[:, None]
        displacement *= displacement
        largest2 = float(np.max(displacement[0] + displacement[1] + displacement[2]))
        # float32 work coordinates: keep a margin of a few ulps of the coordinates' magnitude
        margin = 1e-3 * cached.skin + 4e-7 * float(np.max(np.abs(points)))
        return 2.0 * math.sqrt(largest2) + margin < cached.skin

    def _filter(self, points: np.ndarray, cached: _CandidateList, radius2: np.float32) -> NeighborPairs:
        """Re-test the cached candidates at the current points (shared formula), block by block (the block
        temporaries are allocated once per call)."""
        width = points.shape[1]
        packed = np.zeros((width, 4), dtype=np.float32)
        for axis in range(3):
            packed[:, axis] = np.take(points[axis], cached.order)
        count = len(cached.i)
        kept = _KeptPairs(count)
        block = min(count, self._BLOCK_CANDIDATES)
        rows_buffer = np.empty((block, 4), dtype=np.float32)
        scratch = np.empty((block, 4), dtype=np.float32)
        for first in range(0, count, self._BLOCK_CANDIDATES):
            last = min(first + self._BLOCK_CANDIDATES, count)
            i = cached.i[first:last]
            j = cached.j[first:last]
            rows = np.take(packed, j, axis=0, out=rows_buffer[:last - first], mode="clip")
            rows -= np.take(packed, i, axis=0, out=scratch[:last - first], mode="clip")
            kept.append(np.flatnonzero(_squared_length(rows, scratch[:last - first]) < radius2), i, j, rows)
        i, j, rows = kept.arrays()
        return NeighborPairs(order=cached.order, i=i, j=j, rows=rows)

    def _cell_search(self, points: np.ndarray, radius: float):
        """All pairs closer than ``radius`` by the cell search: ``(order, i, j, rows)`` as in NeighborPairs."""
        width = points.shape[1]
        if width < 2:
            self._previous_order = None
            return np.arange(width), np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros((0, 4), np.float32)
        fz_cells = self.Z_CELLS_PER_RADIUS
        pad = np.array([2, 2, fz_cells + 2])  # empty cells around the cloud: neighbour lookups never leave the grid
        scale = np.array([1.0 / radius, 1.0 / radius, fz_cells / radius])

        # 1. cells and keys (float64 for the cell coordinates: exact floors even far from the origin)
        low = points.min(axis=1).astype(np.float64)
        cell_coordinates = (points.astype(np.float64) - low[:, None]) * scale[:, None] + pad[:, None]
        cells = cell_coordinates.astype(np.int64)  # floor: coordinates are >= pad > 0
        dims = cells.max(axis=1) + pad + 1
        if np.any(dims > 2**20):
            raise ValueError(f"the point cloud spans {np.ceil((dims - 2 * pad) / scale).tolist()} m, more than "
                             f"2^20 neighbour radii on an axis; bound the flock (bounds_mode 'soft' or 'wrap')")
        stride_y = int(dims[2])
        stride_x = int(dims[1]) * stride_y
        keys = cells[0] * stride_x + cells[1] * stride_y + cells[2]

        previous = self._previous_order
        if previous is not None and len(previous) == width:
            order = np.take(previous, np.argsort(np.take(keys, previous), kind="stable"))
        else:
            order = np.argsort(keys, kind="stable")
        self._previous_order = order
        sorted_keys = np.take(keys, order)
        # sorted points as 16-byte rows [x, y, z, 0]: one row gather per candidate instead of three
        packed = np.zeros((width, 4), dtype=np.float32)
        fraction = np.empty((3, width), dtype=np.float32)  # position inside the cell, in cell units
        for axis in range(3):
            packed[:, axis] = np.take(points[axis], order)
            fraction[axis] = np.take(cell_coordinates[axis], order) - np.take(cells[axis], order)

        # 2. first sorted index of every cell
        cell_count = int(dims[0]) * stride_x
        if cell_count <= self._MAX_TABLE_CELLS_PER_POINT * width + (1 << 16):
            table = np.zeros(cell_count + 1, dtype=np.int32)
            np.cumsum(np.bincount(sorted_keys, minlength=cell_count), out=table[1:])

            def cell_start(query):
                return np.take(table, query)
        else:
            def cell_start(query):
                return np.searchsorted(sorted_keys, query).astype(np.int32)

        # 3. per point and column: the sorted range [low, high) of candidate partners
        fx, fy, fz = fraction
        one = np.float32(1.0)
        gap_x_next = one - fx  # distance (in cells of size d) to the column at x+1
        gap_x_next *= gap_x_next
        gap_y_next = one - fy
        gap_y_next *= gap_y_next
        gap_y_prev = fy * fy
        reach2 = np.float32((1.0 + _CANDIDATE_SLACK) ** 2)
        half_height = np.empty((5, width), dtype=np.float32)  # in z cells
        half_height[0] = fz_cells * (1.0 + _CANDIDATE_SLACK)
        rest = half_height[1:]
        rest[0] = reach2 - gap_y_next          # (x,   y+1)
        rest[1] = reach2 - gap_x_next - gap_y_prev  # (x+1, y−1)
        rest[2] = reach2 - gap_x_next          # (x+1, y)
        rest[3] = reach2 - gap_x_next - gap_y_next  # (x+1, y+1)
        unreachable = rest < 0.0
        np.sqrt(rest, out=rest, where=~unreachable)
        rest *= np.float32(fz_cells)
        rest[unreachable] = -2.0  # makes the z range empty below
        # z cell range relative to the point's own cell, shifted by +bias so the float->int cast floors
        bias = fz_cells + 4
        z_first = (fz + np.float32(bias) - half_height).astype(np.int64)
        z_last = (fz + np.float32(bias) + half_height).astype(np.int64)
        column_offset = np.array([0, stride_y, stride_x - stride_y, stride_x, stride_x + stride_y], np.int64) - bias
        column_key = sorted_keys[None, :] + column_offset[:, None]
        low_index = cell_start(column_key + z_first)
        low_index[0] = np.arange(1, width + 1, dtype=np.int32)  # own column: only later points (i < j)
        high_index = cell_start(column_key + z_last + 1)
        counts = high_index - low_index
        np.maximum(counts, 0, out=counts)
        per_point = counts.sum(axis=0)
        counts = np.ascontiguousarray(counts.T).reshape(-1)  # point-major: pairs come out sorted by i
        low_index = np.ascontiguousarray(low_index.T).reshape(-1)
        cumulative = np.cumsum(per_point)
        total = int(cumulative[-1])

        # 4. enumerate, test and compress, block by block (blocks sized so the temporaries stay in cache)
        blocks = max(1, -(-total // self._BLOCK_CANDIDATES))
        edges = np.concatenate(([0], np.searchsorted(cumulative, np.linspace(0, total, blocks + 1)[1:-1]), [width]))
        radius2 = np.float32(radius * radius)
        slots = np.arange(width, dtype=np.int32)
        kept = _KeptPairs(total)
        for first, last in zip(edges[:-1].tolist(), edges[1:].tolist()):
            if last <= first:
                continue
            block_counts = counts[5 * first:5 * last]
            block_point_counts = per_point[first:last]
            ends = np.cumsum(block_counts)
            m = int(ends[-1])
            if m == 0:
                continue
            # j = low + (running index within the range): a ramp minus the repeated start of each range
            shift = low_index[5 * first:5 * last] - ends
            shift += block_counts
            j = np.repeat(shift.astype(np.int32), block_counts)
            j += self._ramp(m)
            rows = np.take(packed, j, axis=0)
            rows -= np.repeat(packed[first:last], block_point_counts, axis=0)
            near = np.flatnonzero(_squared_length(rows) < radius2)
            kept.append(near, np.repeat(slots[first:last], block_point_counts), j, rows)
        return (order,) + kept.arrays()


def make_search(name: str):
    """The backend called ``name`` ('grid', 'kdtree', 'brute')."""
    backends = {"grid": GridSearch, "kdtree": KDTreeSearch, "brute": BruteForceSearch}
    try:
        return backends[name]()
    except KeyError:
        raise ValueError(f"unknown neighbor_search {name!r}; choose one of {', '.join(backends)}") from None


def periodic_images(points: np.ndarray, box: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Ghost copies for a periodic box, so open-space neighbour search sees the wrapped neighbourhoods.

    Args:
        points: (3, N) float32 work coordinates inside ``[0, box)``.
        box:    (3,) box sizes; each must exceed ``2 * reach`` (then no pair is found twice).
        reach:  the search radius (ghosts are made for points closer than ``reach`` to a face).

    Returns:
        ``(augmented (3, W) float32, source (W,) intp)``: the N points first, then the ghosts; ``source[s]``
        is the real point slot ``s`` copies.  Faces are handled one axis after the other, copying earlier
        ghosts too, so edges and corners get their 3 / 7 images.
    """
    box32 = np.asarray(box, dtype=np.float32)
    augmented = points
    source = np.arange(points.shape[1])
    margin = np.float32(reach * (1.0 + _CANDIDATE_SLACK))
    for axis in range(3):
        coordinate = augmented[axis]
        low = np.flatnonzero(coordinate < margin)
        high = np.flatnonzero(coordinate >= box32[axis] - margin)
        if len(low) == 0 and len(high) == 0:
            continue
        ghosts = np.concatenate((augmented[:, low], augmented[:, high]), axis=1)
        ghosts[axis, :len(low)] += box32[axis]
        ghosts[axis, len(low):] -= box32[axis]
        augmented = np.concatenate((augmented, ghosts), axis=1)
        source = np.concatenate((source, source[low], source[high]))
    return augmented, source
