"""GJK distances and closest points, EPA penetration depths and normals (issue 25): closed forms (sphere–sphere,
box–box along an axis, point–box, segment–segment) and random hull pairs against an independent exact reference —
the origin's distance to the convex hull of the Minkowski difference's vertices (qhull + point–triangle distances
computed here with numpy), or, overlapping, the smallest distance of the origin to that hull's face planes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from cgp_core.collision.convex import convex_hull
from cgp_core.collision.epa import penetration
from cgp_core.collision.gjk import NO_ADJACENCY, Core, box_core, gjk_distance, no_adjacency, point_core, segment_core

EYE = np.eye(3)


def core(vertices, hull=None):
    """(vertices, adjacency_start, adjacency) of a core."""
    if hull is not None:
        return hull.vertices, hull.adjacency_start, hull.adjacency
    vertices = np.ascontiguousarray(vertices, dtype=float)
    return vertices, no_adjacency(vertices), NO_ADJACENCY


def posed(a, p, R):
    """The :class:`Core` of a core's arrays at position ``p``, rotation ``R``."""
    return Core(*a, np.asarray(p, float), np.asarray(R, float))


def distance(a, pa, Ra, ra, b, pb, Rb, rb):
    return gjk_distance(posed(a, pa, Ra), ra, posed(b, pb, Rb), rb)


def signed(a, pa, Ra, ra, b, pb, Rb, rb):
    return penetration(posed(a, pa, Ra), ra, posed(b, pb, Rb), rb)


def random_hull(rng, n=20, size=0.4):
    p = rng.normal(size=(n, 3))
    p = p / np.linalg.norm(p, axis=1)[:, None] * rng.uniform(0.3, 0.5) / 2 * size / 0.4
    return convex_hull(p * rng.uniform(0.7, 1.3, 3))


def point_triangle_distance(p, a, b, c):
    """Independent reference: the plane's foot if it is inside the triangle, else the nearest edge point."""
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    foot = p - (p - a) @ n * n
    inside = all(np.cross(q - s, foot - s) @ n >= 0 for s, q in ((a, b), (b, c), (c, a)))
    if inside:
        return abs((p - a) @ n)
    best = np.inf
    for s, q in ((a, b), (b, c), (c, a)):
        t = np.clip((p - s) @ (q - s) / ((q - s) @ (q - s)), 0, 1)
        best = min(best, np.linalg.norm(p - (s + t * (q - s))))
    return best


def minkowski_reference(A, B):
    """Signed distance between the convex hulls of point sets A and B (world): positive apart, minus the
    penetration depth overlapping."""
    M = (A[:, None, :] - B[None, :, :]).reshape(-1, 3)
    hull = ConvexHull(M)
    offsets = -hull.equations[:, 3]  # n · x = offset on each facet, n outward
    if (offsets >= 0).all():  # origin inside: depth = distance to the nearest facet plane
        return -offsets.min()
    return min(point_triangle_distance(np.zeros(3), *M[s]) for s in hull.simplices)


# ---- GJK against closed forms ---------------------------------------------------------------------------

def test_sphere_sphere_distance_and_points():
    ca, cb = np.array([0.1, 0.2, 0.3]), np.array([1.1, -0.4, 0.9])
    d, hit, pa, pb, n = distance(core(point_core()), ca, EYE, 0.2, core(point_core()), cb, EYE, 0.3)
    gap = np.linalg.norm(cb - ca)
    assert not hit and d == pytest.approx(gap - 0.5, abs=1e-12)
    np.testing.assert_allclose(n, (cb - ca) / gap, atol=1e-12)
    np.testing.assert_allclose(pa, ca + 0.2 * n, atol=1e-12)
    np.testing.assert_allclose(pb, cb - 0.3 * n, atol=1e-12)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_box_box_distance_along_an_axis_in_any_orientation(axis):
    ha, hb = np.array([0.3, 0.2, 0.1]), np.array([0.15, 0.25, 0.2])
    R = Rotation.from_euler("xyz", [0.3, -0.7, 1.1]).as_matrix()
    gap = 0.123456789
    offset = np.zeros(3)
    offset[axis] = ha[axis] + hb[axis] + gap
    shift = np.zeros(3)
    shift[(axis + 1) % 3] = 0.05  # still face to face
    pa = np.array([1.0, 2.0, 3.0])
    pb = pa + R @ (offset + shift)
    d, hit, qa, qb, n = distance(core(box_core(ha)), pa, R, 0.0, core(box_core(hb)), pb, R, 0.0)
    assert not hit and d == pytest.approx(gap, abs=1e-12)
    np.testing.assert_allclose(n, R[:, axis], atol=1e-12)
    assert np.linalg.norm(qb - qa) == pytest.approx(gap, abs=1e-12)


def test_point_box_distance_equals_the_clamped_point():
    rng = np.random.default_rng(0)
    h = np.array([0.4, 0.3, 0.2])
    R = Rotation.random(random_state=1).as_matrix()
    c = np.array([0.5, -0.2, 1.0])
    for _ in range(200):
        p = c + rng.uniform(-1.5, 1.5, 3)
        local = R.T @ (p - c)
        expected = np.linalg.norm(local - np.clip(local, -h, h))
        if expected < 1e-3:
            continue
        d, hit, qa, qb, n = distance(core(point_core()), p, EYE, 0.0, core(box_core(h)), c, R, 0.0)
        assert not hit and d == pytest.approx(expected, abs=1e-12)
        np.testing.assert_allclose(qb, c + R @ np.clip(local, -h, h), atol=1e-12)


def test_segment_segment_distance_of_skew_and_parallel_capsules():
    # perpendicular skew segments h apart: the common perpendicular
    Rx = Rotation.from_euler("y", 90, degrees=True).as_matrix()  # core z axis → world x
    d, hit, pa, pb, n = distance(core(segment_core(1.0)), [0, 0, 0], EYE, 0.1, core(segment_core(1.0)),
                                 [0.3, 0.2, 0.7], Rx, 0.05)
    assert not hit and d == pytest.approx(0.2 - 0.15, abs=1e-12)
    # parallel overlapping segments: the distance between the lines
    d, hit, *_ = distance(core(segment_core(1.0)), [0, 0, 0], EYE, 0.0, core(segment_core(0.5)), [0.3, 0.4, 0.6],
                          EYE, 0.0)
    assert d == pytest.approx(0.5, abs=1e-12)
    # end to end along the axis
    d, hit, *_ = distance(core(segment_core(1.0)), [0, 0, 0], EYE, 0.0, core(segment_core(0.5)), [0, 0, 1.75],
                          EYE, 0.0)
    assert d == pytest.approx(0.25, abs=1e-12)


def test_point_to_random_hull_distance_matches_the_reference():
    rng = np.random.default_rng(2)
    hull = random_hull(rng, 24)
    R = Rotation.random(random_state=3).as_matrix()
    c = np.array([0.0, 0.1, -0.2])
    world = hull.vertices @ R.T + c
    for _ in range(40):
        p = c + rng.normal(size=3) * 0.5
        expected = minkowski_reference(p[None, :], world)
        if expected <= 1e-6:
            continue
        d, hit, *_ = distance(core(point_core()), p, EYE, 0.0, core(None, hull), c, R, 0.0)
        assert not hit and d == pytest.approx(expected, abs=1e-9)


def test_random_hull_pairs_agree_with_the_minkowski_reference():
    """GJK apart, EPA overlapping: both against the exact reference, to 1e-9 m; the witness points lie on the
    shapes' supporting planes along the normal."""
    rng = np.random.default_rng(4)
    apart = overlapping = 0
    for trial in range(60):
        a, b = random_hull(rng, rng.integers(16, 25)), random_hull(rng, rng.integers(16, 25))
        Ra, Rb = Rotation.random(2, random_state=trial).as_matrix()
        pa = rng.uniform(-1, 1, 3)
        pb = pa + rng.normal(size=3) * 0.35
        A, B = a.vertices @ Ra.T + pa, b.vertices @ Rb.T + pb
        expected = minkowski_reference(A, B)
        sep, n, qa, qb = signed(core(None, a), pa, Ra, 0.0, core(None, b), pb, Rb, 0.0)
        assert sep == pytest.approx(expected, abs=1e-9), trial
        # qa is A's support point along n, qb B's along −n, and qb − qa = sep n
        assert qa @ n == pytest.approx((A @ n).max(), abs=1e-9)
        assert qb @ n == pytest.approx((B @ n).min(), abs=1e-9)
        np.testing.assert_allclose(qb - qa, sep * n, atol=1e-9)
        apart += sep > 0
        overlapping += sep < 0
    assert apart >= 10 and overlapping >= 10  # both branches ran


def test_hill_climbing_big_hulls_agree_with_the_reference():
    rng = np.random.default_rng(5)
    p = rng.normal(size=(300, 3))
    a = convex_hull(p / np.linalg.norm(p, axis=1)[:, None] * 0.3)
    b = random_hull(rng, 20)
    assert len(a.vertices) > 32  # hill climbing
    for trial in range(10):
        Ra, Rb = Rotation.random(2, random_state=100 + trial).as_matrix()
        pb = rng.normal(size=3) * 0.3
        sep, *_ = signed(core(None, a), np.zeros(3), Ra, 0.0, core(None, b), pb, Rb, 0.0)
        assert sep == pytest.approx(minkowski_reference(a.vertices @ Ra.T, b.vertices @ Rb.T + pb), abs=1e-9)


# ---- EPA against closed forms ---------------------------------------------------------------------------

def test_box_box_overlap_along_an_axis_gives_the_overlap_and_the_axis():
    ha, hb = np.array([0.5, 0.4, 0.3]), np.array([0.2, 0.2, 0.2])
    R = Rotation.from_euler("zyx", [0.4, 0.2, -0.3]).as_matrix()
    depth = 0.037
    pb = R @ np.array([0.0, 0.0, ha[2] + hb[2] - depth])  # B sunk into A's top face
    sep, n, qa, qb = signed(core(box_core(ha)), np.zeros(3), R, 0.0, core(box_core(hb)), pb, R, 0.0)
    assert sep == pytest.approx(-depth, abs=1e-12)
    np.testing.assert_allclose(n, R[:, 2], atol=1e-12)


def test_sphere_inside_a_hull_is_pushed_out_through_the_nearest_face():
    rng = np.random.default_rng(6)
    hull = random_hull(rng, 22)
    c = hull.vertices.mean(axis=0) * 0.5
    r = 0.05
    plane_gap = hull.face_plane[:, 3] - hull.face_plane[:, :3] @ c  # > 0: inside
    assert (plane_gap > 0).all()
    sep, n, qa, qb = signed(core(None, hull), np.zeros(3), EYE, 0.0, core(point_core()), c, EYE, r)
    assert sep == pytest.approx(-(plane_gap.min() + r), abs=1e-10)
    # from A to B: B leaves A through the nearest face, along its outward normal
    np.testing.assert_allclose(n, hull.face_plane[np.argmin(plane_gap), :3], atol=1e-9)


def test_touching_shapes_have_zero_depth():
    h = np.array([0.5, 0.5, 0.5])
    sep, n, *_ = signed(core(box_core(h)), np.zeros(3), EYE, 0.0, core(box_core(h)), [1.0, 0.3, 0.2], EYE, 0.0)
    assert abs(sep) <= 1e-12
    sep, n, *_ = signed(core(box_core(h)), np.zeros(3), EYE, 0.0, core(box_core(h)), [1.0, 1.0, 1.0], EYE, 0.0)
    assert abs(sep) <= 1e-12  # corner to corner
