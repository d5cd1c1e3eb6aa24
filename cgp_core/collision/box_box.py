"""Box–box contact: the separating-axis test (SAT) picks the contact normal, face clipping builds the
contact manifold (Ericson 4.4.1 for the 15 axes; the manifold as in Box2D / Bullet / Gregorius' GDC 2013
talk "The Separating Axis Test between convex polyhedra"), one compiled kernel per box pair.

1. **SAT.**  The 15 candidate axes are the 3 face normals of A, the 3 of B and the 9 cross products of an
   edge direction of A with one of B.  On each axis the boxes' projections are intervals; the *separation*
   along it is the gap between them (negative = overlap).  The axis of largest separation is the contact
   normal (if even that separation exceeds the speculative margin, there is no contact).  Face axes are
   preferred over nearly-as-good edge axes and A's faces over B's (a relative + absolute tolerance), so a
   resting box keeps the same reference face and the same features step after step, which warm starting
   needs.  Cross products of (nearly) parallel edges are skipped: they are not separating directions.
2. **Face contact.**  The box owning the chosen face is the *reference*, its face the reference face; the
   *incident* face is the other box's face most anti-parallel to the normal.  In the reference face's 2-D
   frame the contact region is the intersection of two convex quads, whose vertices are (a) incident corners
   inside the reference rectangle, (b) reference corners inside the projected incident quad and (c)
   crossings of an incident edge with a reference edge — 4 + 4 + 16 fixed candidate slots, so no ragged
   Sutherland–Hodgman polygons are needed.  Each candidate's separation is the incident surface's height
   above the reference face there.  Duplicates (a corner that is also a crossing ...) are merged, and more
   than 4 points are reduced to the 4 extreme ones along the face's diagonals (stable from step to step,
   see ``_reduce_to_four``).  A box resting flat on another gets its 4 corners.
3. **Edge contact.**  One point: midway between the closest points of the two supporting edges.

Features (for warm starting): ``face id × 24 + candidate slot`` for face contacts, ``288 + 3 i + j`` for the
edge pair (i of A, j of B).
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit
from .narrowphase import Box, _rows, closest_segment_segment, multi_point_batch, write_point

#: an edge axis must beat the best face axis by this much (relative to the separation, plus the absolute
#: part) to be chosen; B's face must beat A's by the same (keeps reference face and features stable)
AXIS_RELATIVE_TOLERANCE = 0.05
AXIS_ABSOLUTE_TOLERANCE = 5e-5  # [m]

_EDGE_FEATURE_BASE = 288
_CYCLE = np.array([(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)])  # quad corners, counter-clockwise
_CANDIDATES = 24  # 4 incident corners, 4 reference corners, 16 edge crossings


@njit
def _cross2(ax, ay, bx, by):
    return ax * by - ay * bx


@njit
def box_box_contacts(box_a, box_b, margin, out, m):
    """:class:`~.narrowphase.Box` A vs box B: up to 4 points, normal from A to B, written into the
    :class:`~.narrowphase.ContactBuffer` ``out`` from row ``m``; returns the next free row."""
    ca, Ra, ha = box_a
    cb, Rb, hb = box_b
    d = cb - ca
    C = np.empty((3, 3))  # C[i, j] = a_i · b_j
    for i in range(3):
        for j in range(3):
            C[i, j] = Ra[0, i] * Rb[0, j] + Ra[1, i] * Rb[1, j] + Ra[2, i] * Rb[2, j]
    dA = np.empty(3)  # d in A's axes, in B's
    dB = np.empty(3)
    for i in range(3):
        dA[i] = Ra[0, i] * d[0] + Ra[1, i] * d[1] + Ra[2, i] * d[2]
        dB[i] = Rb[0, i] * d[0] + Rb[1, i] * d[1] + Rb[2, i] * d[2]

    # -- SAT: face axes of A, of B (the first of equal maxima wins)
    ia, best_a = np.int64(0), -np.inf
    ib, best_b = np.int64(0), -np.inf
    for i in range(3):
        sa = abs(dA[i]) - ha[i] - (abs(C[i, 0]) * hb[0] + abs(C[i, 1]) * hb[1] + abs(C[i, 2]) * hb[2])
        if sa > best_a:
            ia, best_a = i, sa
        sb = abs(dB[i]) - hb[i] - (abs(C[0, i]) * ha[0] + abs(C[1, i]) * ha[1] + abs(C[2, i]) * ha[2])
        if sb > best_b:
            ib, best_b = i, sb
    # edge axes L_ij = a_i × b_j, in A's axes (a_i = e_i, b_j = column j of C) and in B's (a_i = row i of C,
    # b_j = e_j); cross products of (nearly) parallel edges are not separating directions and are skipped
    ie, best_e = np.int64(0), -np.inf
    La = np.empty(3)
    Lb = np.empty(3)
    for i in range(3):
        for j in range(3):
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            La[:] = 0.0
            La[i1] = -C[i2, j]
            La[i2] = C[i1, j]
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            Lb[:] = 0.0
            Lb[j1] = C[i, j2]
            Lb[j2] = -C[i, j1]
            length = math.sqrt(La[0] * La[0] + La[1] * La[1] + La[2] * La[2])
            if length <= 1e-6:
                continue
            radius_a = abs(La[0]) * ha[0] + abs(La[1]) * ha[1] + abs(La[2]) * ha[2]
            radius_b = abs(Lb[0]) * hb[0] + abs(Lb[1]) * hb[1] + abs(Lb[2]) * hb[2]
            gap = abs(La[0] * dA[0] + La[1] * dA[1] + La[2] * dA[2])
            se = (gap - radius_a - radius_b) / length
            if se > best_e:
                ie, best_e = 3 * i + j, se

    use_b = best_b > best_a + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * abs(best_a)
    best_face = best_b if use_b else best_a
    use_edge = best_e > best_face + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * abs(best_face)
    best = best_e if use_edge else best_face
    if not best < margin:
        return m
    if use_edge:
        return _edge_contact(box_a, box_b, ie // 3, ie % 3, margin, best, out, m)
    if use_b:
        return _face_contact(box_b, box_a, ib, use_b, margin, best, out, m)
    return _face_contact(box_a, box_b, ia, use_b, margin, best, out, m)


@njit
def _edge_contact(box_a, box_b, i, j, margin, best, out, m):
    """One point midway between the closest points of the two supporting edges (edge i of A, j of B)."""
    ca, Ra, ha = box_a
    cb, Rb, hb = box_b
    # the axis a_i × b_j in world coordinates, unit, from A towards B
    ai, bj = Ra[:, i], Rb[:, j]
    L = np.empty(3)
    L[0] = ai[1] * bj[2] - ai[2] * bj[1]
    L[1] = ai[2] * bj[0] - ai[0] * bj[2]
    L[2] = ai[0] * bj[1] - ai[1] * bj[0]
    length = math.sqrt(L[0] * L[0] + L[1] * L[1] + L[2] * L[2])
    L /= length
    if L[0] * (cb[0] - ca[0]) + L[1] * (cb[1] - ca[1]) + L[2] * (cb[2] - ca[2]) < 0.0:
        L *= -1.0
    # supporting edge of A along +L, of B along −L: the corner furthest that way, with the edge's own
    # coordinate set to the middle
    p1, q1, p2, q2 = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for r in range(3):
        mid_a = ca[r]
        mid_b = cb[r]
        for k in range(3):
            if k != i:
                s = 1.0 if Ra[0, k] * L[0] + Ra[1, k] * L[1] + Ra[2, k] * L[2] >= 0.0 else -1.0
                mid_a += Ra[r, k] * s * ha[k]
            if k != j:
                s = -1.0 if Rb[0, k] * L[0] + Rb[1, k] * L[1] + Rb[2, k] * L[2] >= 0.0 else 1.0
                mid_b += Rb[r, k] * s * hb[k]
        p1[r], q1[r] = mid_a - Ra[r, i] * ha[i], mid_a + Ra[r, i] * ha[i]
        p2[r], q2[r] = mid_b - Rb[r, j] * hb[j], mid_b + Rb[r, j] * hb[j]
    _, _, x1, y1, z1, x2, y2, z2 = closest_segment_segment(p1, q1, p2, q2)
    sep = (x2 - x1) * L[0] + (y2 - y1) * L[1] + (z2 - z1) * L[2]
    # apart: never report more gap than the SAT bound (the clamped closest points of two edges that do not
    # face each other can be farther apart than the boxes are)
    if best > 0.0:
        sep = min(sep, best)
    if sep < margin:
        m = write_point(out, m, L[0], L[1], L[2], sep, 0.5 * (x1 + x2), 0.5 * (y1 + y2), 0.5 * (z1 + z2),
                        _EDGE_FEATURE_BASE + 3 * i + j)
    return m


@njit
def _face_contact(reference, incident, axis, flip, margin, best, out, m):
    """Face contact: box ``reference`` owns the reference face (normal along its axis ``axis``), box ``incident``
    is incident.  ``flip``: the reference is B (the normal written is then reversed, so it still points from A
    to B)."""
    cR, RR, hR = reference
    cI, RI, hI = incident
    n_ref = np.empty(3)
    side = 1.0 if (RR[0, axis] * (cI[0] - cR[0]) + RR[1, axis] * (cI[1] - cR[1])
                   + RR[2, axis] * (cI[2] - cR[2])) >= 0.0 else -1.0
    iu, iv = (axis + 1) % 3, (axis + 2) % 3
    hu, hv = hR[iu], hR[iv]
    u, v = RR[:, iu], RR[:, iv]
    face_centre = np.empty(3)
    for r in range(3):
        n_ref[r] = RR[r, axis] * side
        face_centre[r] = cR[r] + n_ref[r] * hR[axis]

    # incident face: the face of I most anti-parallel to n_ref
    kI, best_dot, dot_kI = np.int64(0), -1.0, 0.0
    for k in range(3):
        dot = RI[0, k] * n_ref[0] + RI[1, k] * n_ref[1] + RI[2, k] * n_ref[2]
        if abs(dot) > best_dot:
            kI, best_dot, dot_kI = k, abs(dot), dot
    s_inc = -1.0 if dot_kI > 0.0 else 1.0
    k1, k2 = (kI + 1) % 3, (kI + 2) % 3
    n_inc = np.empty(3)
    rel_c = np.empty(3)  # incident face centre − reference face centre
    for r in range(3):
        n_inc[r] = RI[r, kI] * s_inc
        rel_c[r] = cI[r] + n_inc[r] * hI[kI] - face_centre[r]

    # everything in the reference face frame (x along u, y along v, z along n_ref from the face)
    qx, qy, qz = np.empty(4), np.empty(4), np.empty(4)  # incident corners
    px, py = np.empty(4), np.empty(4)  # reference corners
    for c in range(4):
        rel0 = rel_c[0] + _CYCLE[c, 0] * RI[0, k1] * hI[k1] + _CYCLE[c, 1] * RI[0, k2] * hI[k2]
        rel1 = rel_c[1] + _CYCLE[c, 0] * RI[1, k1] * hI[k1] + _CYCLE[c, 1] * RI[1, k2] * hI[k2]
        rel2 = rel_c[2] + _CYCLE[c, 0] * RI[2, k1] * hI[k1] + _CYCLE[c, 1] * RI[2, k2] * hI[k2]
        qx[c] = rel0 * u[0] + rel1 * u[1] + rel2 * u[2]
        qy[c] = rel0 * v[0] + rel1 * v[1] + rel2 * v[2]
        qz[c] = rel0 * n_ref[0] + rel1 * n_ref[1] + rel2 * n_ref[2]
        px[c] = _CYCLE[c, 0] * hu
        py[c] = _CYCLE[c, 1] * hv
    size = hu + hv
    eps = 1e-9 * size
    X, Y, Z = np.empty(_CANDIDATES), np.empty(_CANDIDATES), np.empty(_CANDIDATES)
    valid = np.zeros(_CANDIDATES, np.bool_)

    # (a) incident corners inside the reference rectangle
    for c in range(4):
        X[c], Y[c], Z[c] = qx[c], qy[c], qz[c]
        valid[c] = abs(qx[c]) <= hu + eps and abs(qy[c]) <= hv + eps

    # (b) reference corners inside the projected incident quad; their height on the incident plane
    ex, ey, edge_len = np.empty(4), np.empty(4), np.empty(4)
    turn = 0.0
    for c in range(4):
        c1 = (c + 1) % 4
        ex[c], ey[c] = qx[c1] - qx[c], qy[c1] - qy[c]
        edge_len[c] = math.sqrt(ex[c] * ex[c] + ey[c] * ey[c])
        turn += _cross2(qx[c], qy[c], qx[c1], qy[c1])
    orient = 1.0 if turn > 0.0 else (-1.0 if turn < 0.0 else 0.0)
    nu = n_inc[0] * u[0] + n_inc[1] * u[1] + n_inc[2] * u[2]
    nv = n_inc[0] * v[0] + n_inc[1] * v[1] + n_inc[2] * v[2]
    nn = n_inc[0] * n_ref[0] + n_inc[1] * n_ref[1] + n_inc[2] * n_ref[2]  # <= −1/√3: never edge-on
    x0 = rel_c[0] * u[0] + rel_c[1] * u[1] + rel_c[2] * u[2]
    y0 = rel_c[0] * v[0] + rel_c[1] * v[1] + rel_c[2] * v[2]
    z0 = rel_c[0] * n_ref[0] + rel_c[1] * n_ref[1] + rel_c[2] * n_ref[2]
    for r in range(4):
        inside = orient != 0.0
        for c in range(4):
            if orient * _cross2(ex[c], ey[c], px[r] - qx[c], py[r] - qy[c]) < -1e-9 * edge_len[c] * size:
                inside = False
        X[4 + r], Y[4 + r] = px[r], py[r]
        Z[4 + r] = z0 - (nu * (px[r] - x0) + nv * (py[r] - y0)) / nn
        valid[4 + r] = inside

    # (c) reference edge (P_r → P_r+1) × incident edge (Q_c → Q_c+1) crossings
    for r in range(4):
        rx, ry = px[(r + 1) % 4] - px[r], py[(r + 1) % 4] - py[r]
        for c in range(4):
            slot = 8 + 4 * r + c
            sx, sy = ex[c], ey[c]
            wx, wy = qx[c] - px[r], qy[c] - py[r]
            denom = _cross2(rx, ry, sx, sy)
            ok = abs(denom) > 1e-9 * math.sqrt(rx * rx + ry * ry) * math.sqrt(sx * sx + sy * sy)
            safe = denom if ok else 1.0
            t = _cross2(wx, wy, sx, sy) / safe
            w = _cross2(wx, wy, rx, ry) / safe
            valid[slot] = ok and 0.0 <= t <= 1.0 and 0.0 <= w <= 1.0
            X[slot] = px[r] + t * rx
            Y[slot] = py[r] + t * ry
            Z[slot] = qz[c] + w * (qz[(c + 1) % 4] - qz[c])

    # merge duplicates: a candidate coinciding with an earlier valid one is dropped
    close = (1e-4 * size) * (1e-4 * size)
    keep = valid.copy()
    for j in range(_CANDIDATES):
        for i in range(j):
            if valid[i] and valid[j] and (X[j] - X[i]) * (X[j] - X[i]) + (Y[j] - Y[i]) * (Y[j] - Y[i]) <= close:
                keep[j] = False
                break
    valid = keep

    # apart (speculative contact): when the incident feature nearest the reference face lies outside the
    # clipping region (or is dropped by the reduction), every kept point is farther than the boxes really
    # are.  Lower the points together (keeping their relative heights, i.e. the tilt) until the nearest
    # reports the SAT separation, a lower bound of the true gap, so a fast approach is never let through
    Z_geom = Z.copy()
    apart = best > 0.0
    _lower_to(Z, valid, best, apart)
    for s in range(_CANDIDATES):
        valid[s] = valid[s] and Z[s] < margin
    _reduce_to_four(X, Y, hu, hv, valid)
    _lower_to(Z, valid, best, apart)

    face_id = (6 if flip else 0) + axis * 2 + (1 if side > 0.0 else 0)
    sign = -1.0 if flip else 1.0
    for s in range(_CANDIDATES):
        if valid[s]:
            half = 0.5 * Z_geom[s]
            m = write_point(out, m, sign * n_ref[0], sign * n_ref[1], sign * n_ref[2], Z[s],
                            face_centre[0] + X[s] * u[0] + Y[s] * v[0] + half * n_ref[0],
                            face_centre[1] + X[s] * u[1] + Y[s] * v[1] + half * n_ref[1],
                            face_centre[2] + X[s] * u[2] + Y[s] * v[2] + half * n_ref[2],
                            face_id * _CANDIDATES + s)
    return m


@njit
def _lower_to(Z, valid, best, apart):
    """If ``apart``, shift ``Z`` down (in place) so its smallest valid entry is at most ``best``."""
    if not apart:
        return
    nearest = np.inf
    for s in range(len(Z)):
        if valid[s] and Z[s] < nearest:
            nearest = Z[s]
    if nearest < np.inf:
        shift = max(nearest - best, 0.0)
        for s in range(len(Z)):
            Z[s] -= shift


@njit
def _reduce_to_four(X, Y, hu, hv, valid):
    """Keep at most 4 valid candidates (in place): the extreme ones along the face's diagonal directions
    (``X / hu``, ``Y / hv``: in units of the face's half sizes).  Unlike "deepest point first" (Bullet), this
    choice does not flip between nearly equal candidates from one step to the next — a box turned on another
    has an octagonal contact region whose 8 corners are all equally deep — which kept a stack of turned boxes
    jittering."""
    count = 0
    for s in range(len(valid)):
        if valid[s]:
            count += 1
    if count <= 4:
        return
    keep = np.zeros(len(valid), np.bool_)
    for dx, dy in ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)):
        best, best_s = -np.inf, -1
        for s in range(len(valid)):
            if valid[s]:
                score = dx * (X[s] / hu) + dy * (Y[s] / hv)
                if score > best:
                    best, best_s = score, s
        keep[best_s] = True
    for s in range(len(valid)):  # a loop, not valid[:] = keep: numba compiles a slice copy with a shape check
        valid[s] = keep[s]       # whose error message alone takes ~2 s to compile


def box_box(ca, Ra, ha, cb, Rb, hb, margin):
    """Box A vs box B, ``k`` pairs as stacked arrays.  Returns ``(pair, normal, separation, point, feature)``
    (see :mod:`.narrowphase`), up to 4 points per pair, normal from A to B."""
    ca, Ra, ha, cb, Rb, hb, margin = _rows(ca, Ra, ha, cb, Rb, hb, margin)
    return multi_point_batch(box_box_contacts, 4, len(ca),
                             lambda i: (Box(ca[i], Ra[i], ha[i]), Box(cb[i], Rb[i], hb[i]), margin[i]))
