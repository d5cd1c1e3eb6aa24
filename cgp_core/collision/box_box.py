"""Box–box contact: the separating-axis test (SAT) picks the contact normal, face clipping builds the
contact manifold (Ericson 4.4.1 for the 15 axes; the manifold as in Box2D / Bullet / Gregorius' GDC 2013
talk "The Separating Axis Test between convex polyhedra"), vectorized over box pairs.

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

import numpy as np

from .narrowphase import closest_segment_segment

#: an edge axis must beat the best face axis by this much (relative to the separation, plus the absolute
#: part) to be chosen; B's face must beat A's by the same (keeps reference face and features stable)
AXIS_RELATIVE_TOLERANCE = 0.05
AXIS_ABSOLUTE_TOLERANCE = 5e-5  # [m]

_EDGE_FEATURE_BASE = 288
_CYCLE = np.array([(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)])  # quad corners, counter-clockwise


def _cross2(ax, ay, bx, by):
    return ax * by - ay * bx


def sat_separations(ca, Ra, ha, cb, Rb, hb):
    """Separations along the 15 SAT axes: face axes of A ``(k, 3)``, of B ``(k, 3)``, edge axes ``(k, 3, 3)``
    (−inf where the edges are parallel), and the unit edge axes ``(k, 3, 3, 3)`` in world coordinates."""
    d = cb - ca
    C = np.einsum("kmi,kmj->kij", Ra, Rb)  # C[i, j] = a_i · b_j
    absC = np.abs(C)
    dA = np.einsum("kmi,km->ki", Ra, d)  # d in A's axes
    dB = np.einsum("kmj,km->kj", Rb, d)
    sep_a = np.abs(dA) - ha - np.einsum("kij,kj->ki", absC, hb)
    sep_b = np.abs(dB) - hb - np.einsum("kij,ki->kj", absC, ha)

    eye = np.eye(3)
    # L_ij = a_i × b_j expressed in A's axes (a_i = e_i, b_j = column j of C) and in B's axes
    # (a_i = row i of C, b_j = e_j)
    L_in_a = np.cross(eye[None, :, None, :], np.swapaxes(C, 1, 2)[:, None, :, :])  # (k, i, j, 3)
    L_in_b = np.cross(C[:, :, None, :], eye[None, None, :, :])  # (k, i, j, 3)
    length = np.linalg.norm(L_in_a, axis=-1)
    radius_a = np.einsum("kijm,km->kij", np.abs(L_in_a), ha)
    radius_b = np.einsum("kijm,km->kij", np.abs(L_in_b), hb)
    centre_gap = np.abs(np.einsum("kijm,km->kij", L_in_a, dA))
    usable = length > 1e-6
    sep_e = np.where(usable, (centre_gap - radius_a - radius_b) / np.where(usable, length, 1.0), -np.inf)
    L_world = np.einsum("knm,kijm->kijn", Ra, L_in_a) / np.where(usable, length, 1.0)[..., None]
    return sep_a, sep_b, sep_e, L_world


def box_box(ca, Ra, ha, cb, Rb, hb, margin):
    """Box A vs box B, ``k`` pairs.  Returns ``(pair, normal, separation, point, feature)`` (see
    :mod:`.narrowphase`), up to 4 points per pair, normal from A to B."""
    k = len(ca)
    sep_a, sep_b, sep_e, L_world = sat_separations(ca, Ra, ha, cb, Rb, hb)
    ia = np.argmax(sep_a, axis=1)
    ib = np.argmax(sep_b, axis=1)
    rows = np.arange(k)
    best_a = sep_a[rows, ia]
    best_b = sep_b[rows, ib]
    flat_e = sep_e.reshape(k, 9)
    ie = np.argmax(flat_e, axis=1)
    best_e = flat_e[rows, ie]

    use_b = best_b > best_a + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * np.abs(best_a)
    best_face = np.where(use_b, best_b, best_a)
    use_edge = best_e > best_face + AXIS_ABSOLUTE_TOLERANCE + AXIS_RELATIVE_TOLERANCE * np.abs(best_face)
    best = np.where(use_edge, best_e, best_face)
    touching = best < margin

    out = []
    face = np.flatnonzero(touching & ~use_edge)
    if face.size:
        out.append(_face_contacts(face, ca, Ra, ha, cb, Rb, hb, ia, ib, use_b, margin, best))
    edge = np.flatnonzero(touching & use_edge)
    if edge.size:
        out.append(_edge_contacts(edge, ca, Ra, ha, cb, Rb, hb, ie, L_world, margin, best))
    if not out:
        return (np.zeros(0, np.intp), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64))
    return tuple(np.concatenate([o[f] for o in out]) for f in range(5))


def _edge_contacts(sel, ca, Ra, ha, cb, Rb, hb, ie, L_world, margin, best):
    i, j = np.divmod(ie[sel], 3)
    ca, Ra, ha, cb, Rb, hb = ca[sel], Ra[sel], ha[sel], cb[sel], Rb[sel], hb[sel]
    rows = np.arange(len(sel))
    L = L_world[sel, i, j]
    L = np.where((np.einsum("ki,ki->k", L, cb - ca) < 0.0)[:, None], -L, L)  # from A towards B
    # supporting edge of A along +L, of B along −L: the corner furthest that way, with the edge's own
    # coordinate set to the middle
    sa = np.where(np.einsum("kmi,km->ki", Ra, L) >= 0.0, 1.0, -1.0)
    sb = np.where(np.einsum("kmi,km->ki", Rb, L) >= 0.0, -1.0, 1.0)
    sa[rows, i] = 0.0
    sb[rows, j] = 0.0
    mid_a = ca + np.einsum("kij,kj->ki", Ra, sa * ha)
    mid_b = cb + np.einsum("kij,kj->ki", Rb, sb * hb)
    dir_a = Ra[rows, :, i] * ha[rows, i][:, None]
    dir_b = Rb[rows, :, j] * hb[rows, j][:, None]
    _, _, xa, xb = closest_segment_segment(mid_a - dir_a, mid_a + dir_a, mid_b - dir_b, mid_b + dir_b)
    separation = np.einsum("ki,ki->k", xb - xa, L)
    # apart: never report more gap than the SAT bound (the clamped closest points of two edges that do not
    # face each other can be farther apart than the boxes are)
    separation = np.where(best[sel] > 0.0, np.minimum(separation, best[sel]), separation)
    keep = separation < margin[sel]
    feature = _EDGE_FEATURE_BASE + 3 * i + j
    point = 0.5 * (xa + xb)
    return sel[keep].astype(np.intp), L[keep], separation[keep], point[keep], feature[keep].astype(np.int64)


def _face_contacts(sel, ca, Ra, ha, cb, Rb, hb, ia, ib, use_b, margin, best):
    n = len(sel)
    rows = np.arange(n)
    flip = use_b[sel]
    f3 = flip[:, None]
    f33 = flip[:, None, None]
    # reference box R owns the face; incident box I
    cR = np.where(f3, cb[sel], ca[sel])
    cI = np.where(f3, ca[sel], cb[sel])
    RR = np.where(f33, Rb[sel], Ra[sel])
    RI = np.where(f33, Ra[sel], Rb[sel])
    hR = np.where(f3, hb[sel], ha[sel])
    hI = np.where(f3, ha[sel], hb[sel])
    axis = np.where(flip, ib[sel], ia[sel])

    n_axis = RR[rows, :, axis]
    side = np.where(np.einsum("ki,ki->k", n_axis, cI - cR) >= 0.0, 1.0, -1.0)
    n_ref = n_axis * side[:, None]
    face_centre = cR + n_ref * hR[rows, axis][:, None]
    iu, iv = (axis + 1) % 3, (axis + 2) % 3
    u, v = RR[rows, :, iu], RR[rows, :, iv]
    hu, hv = hR[rows, iu], hR[rows, iv]

    # incident face: the face of I most anti-parallel to n_ref
    dots = np.einsum("kmi,km->ki", RI, n_ref)
    kI = np.argmax(np.abs(dots), axis=1)
    s_inc = np.where(dots[rows, kI] > 0.0, -1.0, 1.0)
    n_inc = RI[rows, :, kI] * s_inc[:, None]
    inc_centre = cI + n_inc * hI[rows, kI][:, None]
    k1, k2 = (kI + 1) % 3, (kI + 2) % 3
    e1 = RI[rows, :, k1] * hI[rows, k1][:, None]
    e2 = RI[rows, :, k2] * hI[rows, k2][:, None]
    inc_world = inc_centre[:, None, :] + _CYCLE[None, :, 0:1] * e1[:, None, :] + _CYCLE[None, :, 1:2] * e2[:, None, :]

    # everything in the reference face frame (x along u, y along v, z along n_ref from the face)
    rel = inc_world - face_centre[:, None, :]
    qx = np.einsum("kvi,ki->kv", rel, u)
    qy = np.einsum("kvi,ki->kv", rel, v)
    qz = np.einsum("kvi,ki->kv", rel, n_ref)
    px = _CYCLE[None, :, 0] * hu[:, None]  # reference corners (k, 4)
    py = _CYCLE[None, :, 1] * hv[:, None]
    size = (hu + hv)[:, None]
    eps = 1e-9 * size

    # (a) incident corners inside the reference rectangle
    a_ok = (np.abs(qx) <= hu[:, None] + eps) & (np.abs(qy) <= hv[:, None] + eps)

    # (b) reference corners inside the projected incident quad; their height on the incident plane
    ex = np.roll(qx, -1, axis=1) - qx
    ey = np.roll(qy, -1, axis=1) - qy
    orient = np.sign(np.sum(_cross2(qx, qy, np.roll(qx, -1, axis=1), np.roll(qy, -1, axis=1)), axis=1))
    side_b = _cross2(ex[:, None, :], ey[:, None, :], px[:, :, None] - qx[:, None, :],
                     py[:, :, None] - qy[:, None, :])  # [ref corner, incident edge]
    edge_len = np.hypot(ex, ey)[:, None, :]
    b_ok = (np.all(orient[:, None, None] * side_b >= -1e-9 * edge_len * size[:, :, None], axis=2)
            & (orient[:, None] != 0))
    rel_c = inc_centre - face_centre
    nu = np.einsum("ki,ki->k", n_inc, u)
    nv = np.einsum("ki,ki->k", n_inc, v)
    nn = np.einsum("ki,ki->k", n_inc, n_ref)  # <= -1/sqrt(3): the incident face is never edge-on
    x0 = np.einsum("ki,ki->k", rel_c, u)
    y0 = np.einsum("ki,ki->k", rel_c, v)
    z0 = np.einsum("ki,ki->k", rel_c, n_ref)
    pz = z0[:, None] - (nu[:, None] * (px - x0[:, None]) + nv[:, None] * (py - y0[:, None])) / nn[:, None]

    # (c) reference edge (P_a → P_a+1) × incident edge (Q_b → Q_b+1) crossings
    rx = (np.roll(px, -1, axis=1) - px)[:, :, None]
    ry = (np.roll(py, -1, axis=1) - py)[:, :, None]
    sx, sy = ex[:, None, :], ey[:, None, :]
    wx = qx[:, None, :] - px[:, :, None]
    wy = qy[:, None, :] - py[:, :, None]
    denom = _cross2(rx, ry, sx, sy)
    ok_denom = np.abs(denom) > 1e-9 * np.hypot(rx, ry) * np.hypot(sx, sy)
    safe = np.where(ok_denom, denom, 1.0)
    t = _cross2(wx, wy, sx, sy) / safe
    w = _cross2(wx, wy, rx, ry) / safe
    c_ok = ok_denom & (t >= 0.0) & (t <= 1.0) & (w >= 0.0) & (w <= 1.0)
    cx = px[:, :, None] + t * rx
    cy = py[:, :, None] + t * ry
    cz = qz[:, None, :] + w * (np.roll(qz, -1, axis=1) - qz)[:, None, :]

    X = np.concatenate((qx, px, cx.reshape(n, 16)), axis=1)  # (n, 24)
    Y = np.concatenate((qy, py, cy.reshape(n, 16)), axis=1)
    Z = np.concatenate((qz, pz, cz.reshape(n, 16)), axis=1)
    valid = np.concatenate((a_ok, b_ok, c_ok.reshape(n, 16)), axis=1)

    # merge duplicates: a candidate coinciding with an earlier valid one is dropped
    dist2 = (X[:, :, None] - X[:, None, :]) ** 2 + (Y[:, :, None] - Y[:, None, :]) ** 2
    close = dist2 <= ((1e-4 * size) ** 2)[:, :, None]
    earlier = np.tril(np.ones((24, 24), dtype=bool), k=-1)  # [j, i]: i < j
    valid &= ~np.any(close & earlier[None] & valid[:, None, :], axis=2)

    # apart (speculative contact): when the incident feature nearest the reference face lies outside the
    # clipping region (or is dropped by the reduction), every kept point is farther than the boxes really
    # are.  Lower the points together (keeping their relative heights, i.e. the tilt) until the nearest
    # reports the SAT separation, a lower bound of the true gap, so a fast approach is never let through
    Z_geom = Z
    apart = best[sel] > 0.0
    Z = _lower_to(Z, valid, best[sel], apart)
    valid &= Z < margin[sel][:, None]
    valid = _reduce_to_four(X / hu[:, None], Y / hv[:, None], valid)
    Z = _lower_to(Z, valid, best[sel], apart)

    pair, slot = np.nonzero(valid)
    fc = face_centre[pair]
    point = (fc + X[pair, slot][:, None] * u[pair] + Y[pair, slot][:, None] * v[pair]
             + (0.5 * Z_geom[pair, slot])[:, None] * n_ref[pair])
    normal = np.where(flip[pair][:, None], -n_ref[pair], n_ref[pair])
    face_id = flip.astype(np.int64) * 6 + axis * 2 + (side > 0)
    feature = face_id[pair] * 24 + slot
    return sel[pair].astype(np.intp), normal, Z[pair, slot], point, feature.astype(np.int64)



def _lower_to(Z, valid, best, apart):
    """Shift the rows of ``Z`` flagged ``apart`` down so their smallest valid entry is at most ``best``."""
    if not apart.any():
        return Z
    nearest = np.min(np.where(valid, Z, np.inf), axis=1)
    shift = np.where(apart & np.isfinite(nearest), np.maximum(nearest - best, 0.0), 0.0)
    return Z - shift[:, None]


def _reduce_to_four(X, Y, valid):
    """Keep at most 4 valid candidates per row: the extreme ones along the face's diagonal directions
    (``X``, ``Y`` in units of the face's half sizes).  Unlike "deepest point first" (Bullet), this choice
    does not flip between nearly equal candidates from one step to the next — a box turned on another has an
    octagonal contact region whose 8 corners are all equally deep — which kept a stack of turned boxes
    jittering."""
    count = valid.sum(axis=1)
    many = np.flatnonzero(count > 4)
    if many.size == 0:
        return valid
    x, y, ok = X[many], Y[many], valid[many]
    r = np.arange(len(many))
    keep = np.zeros_like(ok)
    for dx, dy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
        keep[r, np.argmax(np.where(ok, dx * x + dy * y, -np.inf), axis=1)] = True
    valid = valid.copy()
    valid[many] = keep
    return valid
