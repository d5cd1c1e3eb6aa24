"""Narrow phase: contact points of primitive pairs, one compiled function per shape-pair type, written for one
pair as a plain loop (Ericson ch. 4–5).  Box–box (SAT with face clipping) lives in :mod:`.box_box`.

Side A and side B are fixed by the function name (the plane z = 0 is always A; otherwise A is the shape that
comes first in SPHERE < BOX < CAPSULE).  Every function gives, per contact point, the unit ``normal`` from A to
B, the signed ``separation`` (negative = penetration) and the world ``point`` midway between the surfaces (see
:mod:`.contacts`).

Two kinds of kernels (all :func:`cgp_core.jit.njit`, so they also run as plain Python):

- one-point pairs (sphere–sphere, sphere–plane, sphere–box, sphere–capsule) return the point as a
  :class:`ContactPoint` ``(nx, ny, nz, separation, px, py, pz)`` (a tuple of numbers: no allocation);
- pairs that can give several points (box–plane, capsule–plane, capsule–capsule, box–capsule, box–box) write
  each kept point into a :class:`ContactBuffer` at row ``m`` on and return the next free row.  ``feature``
  (small int) names the geometric feature that made the point (a box vertex, a capsule end ...), stable from one
  step to the next so the solver can warm start it.  They keep a candidate only if its separation is below the
  pair's ``margin`` (the speculative distance).

Shapes, as the kernels take them: a :class:`Box` (centre ``(3,)``, rotation ``(3, 3)`` — columns = body axes in
world — half extents ``(3,)``), a :class:`Capsule` (centre, unit axis ``(3,)``, half length, radius), a sphere as
its centre ``(3,)`` and radius.  A new primitive kind (a convex hull ...) brings its own shape bundle and kernels
here.  The batch functions at the end (``sphere_sphere``, ``box_plane`` ...) run a kernel over ``k`` pairs given
as stacked arrays, for tests and interactive use; the detector calls the kernels directly from its own compiled
loop.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit

_TINY = 1e-12

#: capsule pairs whose axes make an angle with sine below this are "parallel" and get two contact points
#: (the ends of their overlap), so a capsule lying on another does not rock on a single point
CAPSULE_PARALLEL_SINE = 0.05

#: golden-section iterations of the box–capsule search (the bracket shrinks by 0.618 each: 24 → 1e-5 of the
#: segment)
GOLDEN_SECTION_ITERATIONS = 24
_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0

#: the 8 box corners as signs of the half extents; vertex v has signs _CORNERS[v]
_CORNERS = np.array([(sx, sy, sz) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)])


# ---- the bundles the kernels take and give ----------------------------------------------------------------

class Box(NamedTuple):
    """A box in the world."""

    centre: np.ndarray    # (3,) [m]
    rotation: np.ndarray  # (3, 3) its axes (columns) in world coordinates
    half: np.ndarray      # (3,) half extents along its axes [m]


class Capsule(NamedTuple):
    """A capsule in the world: the points within ``radius`` of the segment centre ± half_length · axis."""

    centre: np.ndarray  # (3,) [m]
    axis: np.ndarray    # (3,) unit, world
    half_length: float  # [m]
    radius: float       # [m]


class ContactPoint(NamedTuple):
    """One contact point (see the module docstring): unit normal from A to B, separation, world point."""

    nx: float
    ny: float
    nz: float
    separation: float
    px: float
    py: float
    pz: float


class SurfacePoint(NamedTuple):
    """A point's signed distance to a surface, the outward unit normal there and the closest surface point."""

    distance: float
    nx: float
    ny: float
    nz: float
    sx: float
    sy: float
    sz: float


class SegmentPoints(NamedTuple):
    """The closest points of two segments: their parameters in [0, 1] and coordinates."""

    s: float
    t: float
    x1: float
    y1: float
    z1: float
    x2: float
    y2: float
    z2: float


class ContactBuffer(NamedTuple):
    """Where the multi-point kernels write their points, row by row (``cap`` rows)."""

    normal: np.ndarray      # (cap, 3) unit normal from A to B
    separation: np.ndarray  # (cap,) signed gap [m]
    point: np.ndarray       # (cap, 3) world point midway between the surfaces
    feature: np.ndarray     # (cap,) int64 the feature that made the point (per kernel; see each)

    @staticmethod
    def empty(cap: int) -> ContactBuffer:
        return ContactBuffer(np.empty((cap, 3)), np.empty(cap), np.empty((cap, 3)), np.empty(cap, np.int64))


# ---- small vector helpers ------------------------------------------------------------------------------

@njit
def write_point(out, m, nx, ny, nz, sep, px, py, pz, feat):
    """Store one contact point in row ``m`` of the :class:`ContactBuffer` ``out``; returns ``m + 1``."""
    out.normal[m, 0] = nx
    out.normal[m, 1] = ny
    out.normal[m, 2] = nz
    out.separation[m] = sep
    out.point[m, 0] = px
    out.point[m, 1] = py
    out.point[m, 2] = pz
    out.feature[m] = feat
    return m + 1


@njit
def _clamp01(x):
    return min(max(x, 0.0), 1.0)


# ---- sphere ------------------------------------------------------------------------------------------

@njit
def sphere_sphere_point(ax, ay, az, ra, bx, by, bz, rb):
    """Sphere A vs sphere B (centres and radii): one point, along the line of centres (+z if the centres
    coincide)."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
    if dist < _TINY:
        nx, ny, nz = 0.0, 0.0, 1.0
    else:
        nx, ny, nz = dx / dist, dy / dist, dz / dist
    sep = dist - ra - rb
    reach = ra + 0.5 * sep
    return ContactPoint(nx, ny, nz, sep, ax + nx * reach, ay + ny * reach, az + nz * reach)


@njit
def sphere_plane_point(c, r):
    """Ground plane z = 0 (A) vs sphere (B): normal +z; the point is under the centre, halfway between the
    plane and the sphere's lowest point."""
    sep = c[2] - r
    return ContactPoint(0.0, 0.0, 1.0, sep, c[0], c[1], 0.5 * sep)


@njit
def point_box(px, py, pz, box):
    """Signed distance from a point to a :class:`Box` (negative inside), the box's outward unit normal at its
    closest surface point (towards the point) and that surface point, as a :class:`SurfacePoint`.  Inside, the
    closest surface is the face of least penetration (Ericson 5.1.4 + the inside case)."""
    cb, Rb, hb = box.centre, box.rotation, box.half
    dx, dy, dz = px - cb[0], py - cb[1], pz - cb[2]
    # the point in box axes, Rᵀ (p − c), and clamped to the box
    l0 = Rb[0, 0] * dx + Rb[1, 0] * dy + Rb[2, 0] * dz
    l1 = Rb[0, 1] * dx + Rb[1, 1] * dy + Rb[2, 1] * dz
    l2 = Rb[0, 2] * dx + Rb[1, 2] * dy + Rb[2, 2] * dz
    c0 = min(max(l0, -hb[0]), hb[0])
    c1 = min(max(l1, -hb[1]), hb[1])
    c2 = min(max(l2, -hb[2]), hb[2])
    e0, e1, e2 = l0 - c0, l1 - c1, l2 - c2
    dist = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    if dist > _TINY:
        n0, n1, n2 = e0 / dist, e1 / dist, e2 / dist
        s0, s1, s2 = c0, c1, c2
    else:
        # inside: push out through the nearest face (the first of equally near ones)
        d0, d1, d2 = hb[0] - abs(l0), hb[1] - abs(l1), hb[2] - abs(l2)
        n0 = n1 = n2 = 0.0
        s0, s1, s2 = l0, l1, l2
        if d0 <= d1 and d0 <= d2:
            n0 = 1.0 if l0 >= 0.0 else -1.0
            s0 = n0 * hb[0]
            dist = -d0
        elif d1 <= d2:
            n1 = 1.0 if l1 >= 0.0 else -1.0
            s1 = n1 * hb[1]
            dist = -d1
        else:
            n2 = 1.0 if l2 >= 0.0 else -1.0
            s2 = n2 * hb[2]
            dist = -d2
    nx = Rb[0, 0] * n0 + Rb[0, 1] * n1 + Rb[0, 2] * n2
    ny = Rb[1, 0] * n0 + Rb[1, 1] * n1 + Rb[1, 2] * n2
    nz = Rb[2, 0] * n0 + Rb[2, 1] * n1 + Rb[2, 2] * n2
    sx = cb[0] + Rb[0, 0] * s0 + Rb[0, 1] * s1 + Rb[0, 2] * s2
    sy = cb[1] + Rb[1, 0] * s0 + Rb[1, 1] * s1 + Rb[1, 2] * s2
    sz = cb[2] + Rb[2, 0] * s0 + Rb[2, 1] * s1 + Rb[2, 2] * s2
    return SurfacePoint(dist, nx, ny, nz, sx, sy, sz)


@njit
def sphere_box_point(c, r, box):
    """Sphere A (centre ``c``, radius ``r``) vs :class:`Box` B: one point, at the box surface point closest to the
    centre."""
    dist, nx, ny, nz, sx, sy, sz = point_box(c[0], c[1], c[2], box)
    sep = dist - r
    half = 0.5 * sep
    return ContactPoint(-nx, -ny, -nz, sep, sx + nx * half, sy + ny * half, sz + nz * half)


@njit
def closest_on_segment(px, py, pz, ax, ay, az, bx, by, bz):
    """Closest point on the segment a–b to the point p, and its parameter t in [0, 1]."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    denom = ux * ux + uy * uy + uz * uz
    t = ((px - ax) * ux + (py - ay) * uy + (pz - az) * uz) / (denom if denom > _TINY else 1.0)
    t = _clamp01(t)
    return ax + ux * t, ay + uy * t, az + uz * t, t


@njit
def sphere_capsule_point(c, r, capsule):
    """Sphere A (centre ``c``, radius ``r``) vs :class:`Capsule` B: sphere–sphere against the closest point of
    the capsule's segment."""
    cc, axis, hl, rc = capsule
    qx, qy, qz, _ = closest_on_segment(c[0], c[1], c[2], cc[0] - axis[0] * hl, cc[1] - axis[1] * hl,
                                       cc[2] - axis[2] * hl, cc[0] + axis[0] * hl, cc[1] + axis[1] * hl,
                                       cc[2] + axis[2] * hl)
    return sphere_sphere_point(c[0], c[1], c[2], r, qx, qy, qz, rc)


# ---- plane -------------------------------------------------------------------------------------------

@njit
def box_plane_contacts(box, margin, out, m):
    """Ground (A) vs :class:`Box` (B): the (up to) 4 lowest corners with separation below ``margin``.  A box
    lying on a face gives its 4 bottom corners (a stable support polygon), on an edge 2, on a corner 1.  Feature
    = corner index 0..7, lowest first (ties in corner order)."""
    c, R, h = box
    z = np.empty(8)
    order = np.empty(8, np.int64)
    for v in range(8):
        z[v] = c[2] + R[2, 0] * _CORNERS[v, 0] * h[0] + R[2, 1] * _CORNERS[v, 1] * h[1] \
            + R[2, 2] * _CORNERS[v, 2] * h[2]
        # insertion sort by height (stable)
        k = v
        while k > 0 and z[order[k - 1]] > z[v]:
            order[k] = order[k - 1]
            k -= 1
        order[k] = v
    for slot in range(4):
        v = order[slot]
        if z[v] < margin:
            lx = _CORNERS[v, 0] * h[0]
            ly = _CORNERS[v, 1] * h[1]
            lz = _CORNERS[v, 2] * h[2]
            m = write_point(out, m, 0.0, 0.0, 1.0, z[v],
                            c[0] + R[0, 0] * lx + R[0, 1] * ly + R[0, 2] * lz,
                            c[1] + R[1, 0] * lx + R[1, 1] * ly + R[1, 2] * lz, 0.5 * z[v], v)
    return m


@njit
def capsule_plane_contacts(capsule, margin, out, m):
    """Ground (A) vs :class:`Capsule` (B): each segment end whose sphere is within ``margin``.  Feature = end 0
    (c − hl axis) or 1 (c + hl axis)."""
    c, axis, hl, r = capsule
    for end in range(2):
        s = -1.0 if end == 0 else 1.0
        ex, ey, ez = c[0] + s * axis[0] * hl, c[1] + s * axis[1] * hl, c[2] + s * axis[2] * hl
        sep = ez - r
        if sep < margin:
            m = write_point(out, m, 0.0, 0.0, 1.0, sep, ex, ey, 0.5 * sep, end)
    return m


# ---- capsule -----------------------------------------------------------------------------------------

@njit
def closest_segment_segment(p1, q1, p2, q2):
    """Closest points between segments ``p1–q1`` and ``p2–q2`` (Ericson 5.1.9, with the degenerate
    (zero-length) and parallel cases), as :class:`SegmentPoints`: ``s, t`` in [0, 1] and the two points'
    coordinates."""
    d1x, d1y, d1z = q1[0] - p1[0], q1[1] - p1[1], q1[2] - p1[2]
    d2x, d2y, d2z = q2[0] - p2[0], q2[1] - p2[1], q2[2] - p2[2]
    rx, ry, rz = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    if a <= _TINY and e <= _TINY:  # both points
        s = t = 0.0
    elif a <= _TINY:  # a point against a segment
        s = 0.0
        t = _clamp01(f / e)
    else:
        c = d1x * rx + d1y * ry + d1z * rz
        if e <= _TINY:
            t = 0.0
            s = _clamp01(-c / a)
        else:
            b = d1x * d2x + d1y * d2y + d1z * d2z
            denom = a * e - b * b
            # parallel lines (denom ~ 0): any s works, take 0 and let the clamping of t pick the right end
            s = _clamp01((b * f - c * e) / denom) if denom > 1e-12 * a * e else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = _clamp01(-c / a)
            elif t > 1.0:
                t = 1.0
                s = _clamp01((b - c) / a)
    return SegmentPoints(s, t, p1[0] + d1x * s, p1[1] + d1y * s, p1[2] + d1z * s,
                         p2[0] + d2x * t, p2[1] + d2y * t, p2[2] + d2z * t)


@njit
def capsule_capsule_contacts(capsule_a, capsule_b, margin, out, m):
    """:class:`Capsule` A vs capsule B: the closest points of the two segments (one contact, feature 0), or, when
    the axes are parallel within ``CAPSULE_PARALLEL_SINE`` and overlap, the two ends of the overlap (features 0
    and 1)."""
    ca, axa, hla, ra = capsule_a
    cb, axb, hlb, rb = capsule_b
    p1, q1, p2, q2 = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for i in range(3):
        p1[i], q1[i] = ca[i] - axa[i] * hla, ca[i] + axa[i] * hla
        p2[i], q2[i] = cb[i] - axb[i] * hlb, cb[i] + axb[i] * hlb
    sx = axa[1] * axb[2] - axa[2] * axb[1]
    sy = axa[2] * axb[0] - axa[0] * axb[2]
    sz = axa[0] * axb[1] - axa[1] * axb[0]
    if math.sqrt(sx * sx + sy * sy + sz * sz) < CAPSULE_PARALLEL_SINE and hla > _TINY and hlb > _TINY:
        # the overlap of B's segment projected on A's, as parameters of A's segment
        d1x, d1y, d1z = q1[0] - p1[0], q1[1] - p1[1], q1[2] - p1[2]
        len2 = d1x * d1x + d1y * d1y + d1z * d1z
        s_p2 = ((p2[0] - p1[0]) * d1x + (p2[1] - p1[1]) * d1y + (p2[2] - p1[2]) * d1z) / len2
        s_q2 = ((q2[0] - p1[0]) * d1x + (q2[1] - p1[1]) * d1y + (q2[2] - p1[2]) * d1z) / len2
        lo = max(0.0, min(s_p2, s_q2))
        hi = min(1.0, max(s_p2, s_q2))
        if hi - lo > 1e-3:
            for end in range(2):
                s = lo if end == 0 else hi
                ax, ay, az = p1[0] + s * d1x, p1[1] + s * d1y, p1[2] + s * d1z
                bx, by, bz, _ = closest_on_segment(ax, ay, az, p2[0], p2[1], p2[2], q2[0], q2[1], q2[2])
                nx, ny, nz, sep, px, py, pz = sphere_sphere_point(ax, ay, az, ra, bx, by, bz, rb)
                if sep < margin:
                    m = write_point(out, m, nx, ny, nz, sep, px, py, pz, end)
            return m
    _, _, x1, y1, z1, x2, y2, z2 = closest_segment_segment(p1, q1, p2, q2)
    nx, ny, nz, sep, px, py, pz = sphere_sphere_point(x1, y1, z1, ra, x2, y2, z2, rb)
    if sep < margin:
        m = write_point(out, m, nx, ny, nz, sep, px, py, pz, 0)
    return m


@njit
def segment_box_closest_parameter(p0, p1, box):
    """Parameter t in [0, 1] of the segment point closest to (deepest in) the box, by golden-section search:
    the signed distance to a convex set is a convex function, and so is its restriction to a segment."""
    dx, dy, dz = p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]
    lo, hi = 0.0, 1.0
    x1 = hi - _INV_PHI * (hi - lo)
    x2 = lo + _INV_PHI * (hi - lo)
    f1 = point_box(p0[0] + dx * x1, p0[1] + dy * x1, p0[2] + dz * x1, box)[0]
    f2 = point_box(p0[0] + dx * x2, p0[1] + dy * x2, p0[2] + dz * x2, box)[0]
    for _ in range(GOLDEN_SECTION_ITERATIONS):
        if f1 < f2:  # the minimum is in [lo, x2]
            hi = x2
            x2, f2 = x1, f1
            x1 = hi - _INV_PHI * (hi - lo)
            f1 = point_box(p0[0] + dx * x1, p0[1] + dy * x1, p0[2] + dz * x1, box)[0]
        else:  # in [x1, hi]
            lo = x1
            x1, f1 = x2, f2
            x2 = lo + _INV_PHI * (hi - lo)
            f2 = point_box(p0[0] + dx * x2, p0[1] + dy * x2, p0[2] + dz * x2, box)[0]
    return 0.5 * (lo + hi)


@njit
def box_capsule_contacts(box, capsule, margin, out, m):
    """:class:`Box` A vs :class:`Capsule` B — an approximation: the capsule is tested as spheres of its radius at
    three points of its segment, the two ends (features 0, 1) and the point of the segment deepest in / closest
    to the box (feature 2, found by golden-section search, kept only if it is deeper than both ends).  Exact for a
    capsule lying on a face (two end contacts), across an edge or poking in with an end; for a capsule crossing a
    box edge obliquely the middle point is still the true closest point, so only the contact count (≤ 3) is
    approximate."""
    cc, axis, hl, rc = capsule
    e0, e1 = np.empty(3), np.empty(3)
    for i in range(3):
        e0[i] = cc[i] - axis[i] * hl
        e1[i] = cc[i] + axis[i] * hl
    t = segment_box_closest_parameter(e0, e1, box)
    sep = np.empty(3)
    sample = np.empty((3, 6))  # per sample: normal, point
    for k in range(3):
        s = 0.0 if k == 0 else (1.0 if k == 1 else t)
        dist, nx, ny, nz, sx, sy, sz = point_box(e0[0] + (e1[0] - e0[0]) * s, e0[1] + (e1[1] - e0[1]) * s,
                                                 e0[2] + (e1[2] - e0[2]) * s, box)
        sep[k] = dist - rc
        half = 0.5 * sep[k]
        sample[k, 0], sample[k, 1], sample[k, 2] = nx, ny, nz
        sample[k, 3], sample[k, 4], sample[k, 5] = sx + nx * half, sy + ny * half, sz + nz * half
    tol = 1e-6 + 1e-4 * rc
    interior = sep[2] < min(sep[0], sep[1]) - tol and 1e-3 < t < 1.0 - 1e-3
    for k in range(3):
        if sep[k] < margin and (k < 2 or interior):
            m = write_point(out, m, sample[k, 0], sample[k, 1], sample[k, 2], sep[k], sample[k, 3], sample[k, 4],
                            sample[k, 5], k)
    return m


# ---- batch forms (k pairs as stacked arrays) -------------------------------------------------------------

def _rows(*arrays):
    return [np.ascontiguousarray(a, dtype=float) for a in arrays]


def _single_point_batch(kernel, k, args):
    normal, separation, point = np.empty((k, 3)), np.empty(k), np.empty((k, 3))
    for i in range(k):
        nx, ny, nz, s, px, py, pz = kernel(*(a[i] for a in args))
        normal[i] = nx, ny, nz
        separation[i] = s
        point[i] = px, py, pz
    return normal, separation, point


def sphere_sphere(ca, ra, cb, rb):
    """``k`` sphere pairs: ``(normal (k, 3), separation (k,), point (k, 3))``."""
    ca, ra, cb, rb = _rows(ca, ra, cb, rb)
    return _single_point_batch(lambda a, r, b, s: sphere_sphere_point(a[0], a[1], a[2], r, b[0], b[1], b[2], s),
                               len(ca), (ca, ra, cb, rb))


def sphere_plane(c, r):
    c, r = _rows(c, r)
    return _single_point_batch(sphere_plane_point, len(c), (c, r))


def sphere_box(c, r, cb, Rb, hb):
    c, r, cb, Rb, hb = _rows(c, r, cb, Rb, hb)
    return _single_point_batch(lambda *pair: sphere_box_point(pair[0], pair[1], Box(*pair[2:])), len(c),
                               (c, r, cb, Rb, hb))


def sphere_capsule(c, r, cc, axis, hl, rc):
    c, r, cc, axis, hl, rc = _rows(c, r, cc, axis, hl, rc)
    return _single_point_batch(lambda *pair: sphere_capsule_point(pair[0], pair[1], Capsule(*pair[2:])), len(c),
                               (c, r, cc, axis, hl, rc))


class PointBatch(NamedTuple):
    """The points a multi-point kernel kept over ``k`` pairs (``q`` points)."""

    pair: np.ndarray        # (q,) intp: the input pair of each point
    normal: np.ndarray      # (q, 3)
    separation: np.ndarray  # (q,)
    point: np.ndarray       # (q, 3)
    feature: np.ndarray     # (q,) int64


def multi_point_batch(kernel, per_pair: int, k: int, arguments) -> PointBatch:
    """Run a multi-point kernel over ``k`` pairs, ``arguments(i)`` giving pair i's arguments before the buffer
    (its shapes and margin): the :class:`PointBatch` of the kept points."""
    out = ContactBuffer.empty(per_pair * k)
    pair = np.empty(per_pair * k, np.intp)
    m = 0
    for i in range(k):
        m_next = kernel(*arguments(i), out, m)
        pair[m:m_next] = i
        m = m_next
    return PointBatch(pair[:m], out.normal[:m], out.separation[:m], out.point[:m], out.feature[:m])


def box_plane(c, R, h, margin):
    c, R, h, margin = _rows(c, R, h, margin)
    return multi_point_batch(box_plane_contacts, 4, len(c), lambda i: (Box(c[i], R[i], h[i]), margin[i]))


def capsule_plane(c, axis, hl, r, margin):
    c, axis, hl, r, margin = _rows(c, axis, hl, r, margin)
    return multi_point_batch(capsule_plane_contacts, 2, len(c),
                             lambda i: (Capsule(c[i], axis[i], hl[i], r[i]), margin[i]))


def capsule_capsule(ca, axa, hla, ra, cb, axb, hlb, rb, margin):
    ca, axa, hla, ra, cb, axb, hlb, rb, margin = _rows(ca, axa, hla, ra, cb, axb, hlb, rb, margin)
    return multi_point_batch(capsule_capsule_contacts, 2, len(ca),
                             lambda i: (Capsule(ca[i], axa[i], hla[i], ra[i]), Capsule(cb[i], axb[i], hlb[i], rb[i]),
                                        margin[i]))


def box_capsule(cb, Rb, hb, cc, axis, hl, rc, margin):
    cb, Rb, hb, cc, axis, hl, rc, margin = _rows(cb, Rb, hb, cc, axis, hl, rc, margin)
    return multi_point_batch(box_capsule_contacts, 3, len(cb),
                             lambda i: (Box(cb[i], Rb[i], hb[i]), Capsule(cc[i], axis[i], hl[i], rc[i]), margin[i]))


def closest_segments(p1, q1, p2, q2):
    """:func:`closest_segment_segment` over ``k`` segment pairs: ``s, t (k,)`` and the points ``(k, 3)`` x2."""
    p1, q1, p2, q2 = _rows(p1, q1, p2, q2)
    out = np.array([closest_segment_segment(p1[i], q1[i], p2[i], q2[i]) for i in range(len(p1))]).reshape(-1, 8)
    return out[:, 0], out[:, 1], out[:, 2:5], out[:, 5:8]
