"""Narrow phase: contact points of primitive pairs, one vectorized function per shape-pair type
(Ericson ch. 4–5).  Box–box (SAT with face clipping) lives in :mod:`.box_box`.

Every function works on ``k`` pairs at once, with side A and side B fixed by the function name (the plane
z = 0 is always A; otherwise A is the shape that comes first in SPHERE < BOX < CAPSULE).  It returns, per
contact point, the unit ``normal`` from A to B, the signed ``separation`` (negative = penetration) and the
world ``point`` midway between the surfaces (see :mod:`.contacts`).

Functions that can give several points per pair return ``(pair, normal, separation, point, feature)`` where
``pair`` indexes the input pairs and ``feature`` (small int) names the geometric feature that made the point
(a box vertex, a capsule end ...), stable from one step to the next so the solver can warm start it.  They
keep a candidate only if its separation is below the pair's ``margin`` (the speculative distance).  Shapes:
centres ``(k, 3)``, rotations ``(k, 3, 3)`` (columns = body axes in world), radii ``(k,)``, box half extents
``(k, 3)``, capsule axes ``(k, 3)`` (unit) and half lengths ``(k,)``.
"""

from __future__ import annotations

import numpy as np

_TINY = 1e-12
_UP = np.array([0.0, 0.0, 1.0])

#: capsule pairs whose axes make an angle with sine below this are "parallel" and get two contact points
#: (the ends of their overlap), so a capsule lying on another does not rock on a single point
CAPSULE_PARALLEL_SINE = 0.05

#: the 8 box corners as signs of the half extents; vertex v has signs _CORNERS[v]
_CORNERS = np.array([(sx, sy, sz) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)])


def unit_vectors(v: np.ndarray, fallback: np.ndarray = _UP) -> tuple[np.ndarray, np.ndarray]:
    """``v / |v|`` along the last axis and ``|v|``; ``fallback`` where ``|v|`` is ~0 (coincident centres)."""
    length = np.linalg.norm(v, axis=-1)
    degenerate = length < _TINY
    unit = v / np.where(degenerate, 1.0, length)[..., None]
    if degenerate.any():
        unit[degenerate] = fallback
    return unit, length


def _flatten(valid: np.ndarray, normal, separation, point, feature=None):
    """Candidates ``(k, c, ...)`` with ``valid (k, c)`` → flat arrays of the valid ones, with pair index."""
    pair, slot = np.nonzero(valid)
    feat = slot if feature is None else feature[pair, slot]
    return (pair.astype(np.intp), normal[pair, slot], separation[pair, slot], point[pair, slot],
            feat.astype(np.int64))


# ---- sphere ------------------------------------------------------------------------------------------

def sphere_sphere(ca, ra, cb, rb):
    """Sphere A vs sphere B: one point per pair, along the line of centres (+z if the centres coincide)."""
    normal, dist = unit_vectors(cb - ca)
    separation = dist - ra - rb
    point = ca + normal * (ra + 0.5 * separation)[:, None]
    return normal, separation, point


def _up(k: int) -> np.ndarray:
    """``k`` copies ``(k, 3)`` of the ground's normal +z."""
    normal = np.zeros((k, 3))
    normal[:, 2] = 1.0
    return normal


def sphere_plane(c, r):
    """Ground plane z = 0 (A) vs sphere (B): normal +z; the point is under the centre, halfway between the
    plane and the sphere's lowest point."""
    separation = c[:, 2] - r
    point = c.copy()
    point[:, 2] = 0.5 * separation
    return _up(len(c)), separation, point


def point_box(p, cb, Rb, hb):
    """Signed distance from points ``p (k, 3)`` to boxes (negative inside), the box's outward normal
    ``(k, 3)`` at its closest surface point (towards the point) and that surface point ``(k, 3)``.
    Inside, the closest surface is the face of least penetration (Ericson 5.1.4 + the inside case)."""
    local = np.einsum("kji,kj->ki", Rb, p - cb)  # Rᵀ (p − c)
    clamped = np.clip(local, -hb, hb)
    diff = local - clamped
    dist_out = np.linalg.norm(diff, axis=1)
    inside = dist_out <= _TINY
    n_local = diff / np.where(inside, 1.0, dist_out)[:, None]
    surface = clamped
    distance = dist_out
    if inside.any():
        li, hi_ = local[inside], hb[inside]
        depth = hi_ - np.abs(li)  # distance to each pair of faces (>= 0)
        axis = np.argmin(depth, axis=1)
        rows = np.arange(len(axis))
        sign = np.where(li[rows, axis] >= 0.0, 1.0, -1.0)
        n_in = np.zeros_like(li)
        n_in[rows, axis] = sign
        surf_in = li.copy()
        surf_in[rows, axis] = sign * hi_[rows, axis]
        n_local[inside] = n_in
        surface = surface.copy()
        surface[inside] = surf_in
        distance = distance.copy()
        distance[inside] = -depth[rows, axis]
    normal = np.einsum("kij,kj->ki", Rb, n_local)
    surface_world = cb + np.einsum("kij,kj->ki", Rb, surface)
    return distance, normal, surface_world


def sphere_box(c, r, cb, Rb, hb):
    """Sphere A vs box B: one point per pair, at the box surface point closest to the centre."""
    dist, n_box, surface = point_box(c, cb, Rb, hb)
    separation = dist - r
    point = surface + n_box * (0.5 * separation)[:, None]
    return -n_box, separation, point


def closest_on_segments(p, a, b):
    """Closest points on segments ``a–b`` to points ``p`` (all ``(k, 3)``), and the parameter t in [0, 1]."""
    ab = b - a
    denom = np.einsum("ki,ki->k", ab, ab)
    t = np.einsum("ki,ki->k", p - a, ab) / np.where(denom > _TINY, denom, 1.0)
    t = np.clip(t, 0.0, 1.0)
    return a + ab * t[:, None], t


def capsule_ends(c, axis, half_length):
    """Segment end points ``(k, 3)`` x2 of capsules: ``c ∓ half_length · axis``."""
    d = axis * half_length[:, None]
    return c - d, c + d


def sphere_capsule(c, r, cc, axis, hl, rc):
    """Sphere A vs capsule B: sphere–sphere against the closest point of the capsule's segment."""
    a, b = capsule_ends(cc, axis, hl)
    q, _ = closest_on_segments(c, a, b)
    return sphere_sphere(c, r, q, rc)


# ---- plane -------------------------------------------------------------------------------------------

def box_plane(c, R, h, margin):
    """Ground (A) vs box (B): the (up to) 4 lowest corners with separation below ``margin``.  A box lying on a
    face gives its 4 bottom corners (a stable support polygon), on an edge 2, on a corner 1.  Feature =
    corner index 0..7."""
    corners = _box_corners(c, R, h)
    z = corners[:, :, 2]
    lowest = np.argsort(z, axis=1, kind="stable")[:, :4]  # (k, 4) corner indices, lowest first
    box = np.arange(len(c))[:, None]
    pair, slot = np.nonzero(z[box, lowest] < margin[:, None])
    vertex = lowest[pair, slot]
    separation = z[pair, vertex]
    point = corners[pair, vertex]
    point[:, 2] = 0.5 * separation
    return pair.astype(np.intp), _up(len(pair)), separation, point, vertex.astype(np.int64)


def _box_corners(c, R, h):
    """World corners ``(k, 8, 3)`` of boxes, corner v at signs ``_CORNERS[v]``."""
    local = _CORNERS[None, :, :] * h[:, None, :]  # (k, 8, 3)
    return c[:, None, :] + np.einsum("kij,kvj->kvi", R, local)


def capsule_plane(c, axis, hl, r, margin):
    """Ground (A) vs capsule (B): each segment end whose sphere is within ``margin``.  Feature = end 0/1."""
    e0, e1 = capsule_ends(c, axis, hl)
    ends = np.empty((len(c), 2, 3))  # (k, 2, 3)
    ends[:, 0] = e0
    ends[:, 1] = e1
    sep = ends[:, :, 2] - r[:, None]
    pair, end = np.nonzero(sep < margin[:, None])
    separation = sep[pair, end]
    point = ends[pair, end]
    point[:, 2] = 0.5 * separation
    return pair.astype(np.intp), _up(len(pair)), separation, point, end.astype(np.int64)


# ---- capsule -----------------------------------------------------------------------------------------

def closest_segment_segment(p1, q1, p2, q2):
    """Closest points between segments ``p1–q1`` and ``p2–q2`` (Ericson 5.1.9, vectorized with the
    degenerate (zero-length) and parallel cases folded in): returns ``s, t`` in [0, 1] and the two points."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = np.einsum("ki,ki->k", d1, d1)
    e = np.einsum("ki,ki->k", d2, d2)
    f = np.einsum("ki,ki->k", d2, r)
    c = np.einsum("ki,ki->k", d1, r)
    b = np.einsum("ki,ki->k", d1, d2)
    denom = a * e - b * b
    a_ok = a > _TINY
    e_ok = e > _TINY
    safe_a = np.where(a_ok, a, 1.0)
    safe_e = np.where(e_ok, e, 1.0)
    # general case: s from the infinite lines; parallel lines (denom ~ 0): any s works, take 0 and let the
    # clamping of t below pick the right end
    parallel = denom <= 1e-12 * a * e
    s = np.where(parallel, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0.0, 1.0))
    t = (b * s + f) / safe_e
    below, above = t < 0.0, t > 1.0
    t = np.clip(t, 0.0, 1.0)
    s = np.where(below, np.clip(-c / safe_a, 0.0, 1.0), np.where(above, np.clip((b - c) / safe_a, 0.0, 1.0), s))
    # degenerate segments: a point against a segment
    s = np.where(~a_ok, 0.0, s)
    t = np.where(~a_ok, np.clip(f / safe_e, 0.0, 1.0), t)
    t = np.where(~e_ok, 0.0, t)
    s = np.where(~e_ok & a_ok, np.clip(-c / safe_a, 0.0, 1.0), s)
    return s, t, p1 + d1 * s[:, None], p2 + d2 * t[:, None]


def capsule_capsule(ca, axa, hla, ra, cb, axb, hlb, rb, margin):
    """Capsule A vs capsule B: the closest points of the two segments (one contact), or, when the axes are
    parallel within ``CAPSULE_PARALLEL_SINE`` and overlap, the two ends of the overlap (two contacts)."""
    p1, q1 = capsule_ends(ca, axa, hla)
    p2, q2 = capsule_ends(cb, axb, hlb)
    _, _, x1, x2 = closest_segment_segment(p1, q1, p2, q2)
    k = len(ca)
    pa = np.empty((k, 2, 3))
    pb = np.empty((k, 2, 3))
    pa[:, 0], pb[:, 0] = x1, x2
    pa[:, 1], pb[:, 1] = x1, x2
    two = np.zeros(k, dtype=bool)

    sine = np.linalg.norm(np.cross(axa, axb), axis=1)
    parallel = (sine < CAPSULE_PARALLEL_SINE) & (hla > _TINY) & (hlb > _TINY)
    if parallel.any():
        d1 = (q1 - p1)[parallel]
        len2 = np.einsum("ki,ki->k", d1, d1)
        s_p2 = np.einsum("ki,ki->k", p2[parallel] - p1[parallel], d1) / len2
        s_q2 = np.einsum("ki,ki->k", q2[parallel] - p1[parallel], d1) / len2
        lo = np.maximum(0.0, np.minimum(s_p2, s_q2))
        hi = np.minimum(1.0, np.maximum(s_p2, s_q2))
        overlap = hi - lo > 1e-3
        ends_a = p1[parallel][:, None, :] + np.stack((lo, hi), axis=1)[:, :, None] * d1[:, None, :]  # (kp, 2, 3)
        seg_a, seg_b = p2[parallel], q2[parallel]
        ends_b = np.stack([closest_on_segments(ends_a[:, j], seg_a, seg_b)[0] for j in range(2)], axis=1)
        idx = np.flatnonzero(parallel)[overlap]
        pa[idx] = ends_a[overlap]
        pb[idx] = ends_b[overlap]
        two[idx] = True

    ra2 = np.repeat(ra, 2)
    rb2 = np.repeat(rb, 2)
    normal, sep, point = sphere_sphere(pa.reshape(-1, 3), ra2, pb.reshape(-1, 3), rb2)
    valid = (sep.reshape(k, 2) < margin[:, None]) & np.stack((np.ones(k, bool), two), axis=1)
    return _flatten(valid, normal.reshape(k, 2, 3), sep.reshape(k, 2), point.reshape(k, 2, 3))


def _segment_box_closest_parameter(p0, p1, cb, Rb, hb, iterations: int = 24):
    """Parameter t in [0, 1] of the segment point closest to (deepest in) the box, by golden-section search:
    the signed distance to a convex set is a convex function, and so is its restriction to a segment."""
    inv_phi = (np.sqrt(5.0) - 1.0) / 2.0
    lo = np.zeros(len(p0))
    hi = np.ones(len(p0))
    d = p1 - p0

    def f(t):
        return point_box(p0 + d * t[:, None], cb, Rb, hb)[0]

    x1 = hi - inv_phi * (hi - lo)
    x2 = lo + inv_phi * (hi - lo)
    f1, f2 = f(x1), f(x2)
    for _ in range(iterations):
        left = f1 < f2  # the minimum is in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        new_x = np.where(left, hi - inv_phi * (hi - lo), lo + inv_phi * (hi - lo))
        new_f = f(new_x)
        x2n = np.where(left, x1, new_x)
        f2n = np.where(left, f1, new_f)
        x1 = np.where(left, new_x, x2)
        f1 = np.where(left, new_f, f2)
        x2, f2 = x2n, f2n
    return 0.5 * (lo + hi)


def box_capsule(cb, Rb, hb, cc, axis, hl, rc, margin):
    """Box A vs capsule B — an approximation: the capsule is tested as spheres of its radius at three points
    of its segment, the two ends (features 0, 1) and the point of the segment deepest in / closest to the box
    (feature 2, found by golden-section search, kept only if it is deeper than both ends).  Exact for a capsule
    lying on a face (two end contacts), across an edge or poking in with an end; for a capsule crossing a box
    edge obliquely the middle point is still the true closest point, so only the contact count (≤ 3) is
    approximate."""
    e0, e1 = capsule_ends(cc, axis, hl)
    t = _segment_box_closest_parameter(e0, e1, cb, Rb, hb)
    mid = e0 + (e1 - e0) * t[:, None]
    k = len(cb)
    samples = np.stack((e0, e1, mid), axis=1).reshape(-1, 3)
    rep = np.repeat(np.arange(k), 3)
    dist, n_box, surface = point_box(samples, cb[rep], Rb[rep], hb[rep])
    sep = (dist - np.repeat(rc, 3)).reshape(k, 3)
    point = (surface + n_box * (0.5 * (dist - np.repeat(rc, 3)))[:, None]).reshape(k, 3, 3)
    normal = n_box.reshape(k, 3, 3)
    tol = 1e-6 + 1e-4 * rc
    interior = (sep[:, 2] < np.minimum(sep[:, 0], sep[:, 1]) - tol) & (t > 1e-3) & (t < 1.0 - 1e-3)
    valid = sep < margin[:, None]
    valid[:, 2] &= interior
    return _flatten(valid, normal, sep, point)
