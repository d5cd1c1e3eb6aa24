"""Issue 38, the box on a fine mesh at the cost the contact needs: the fast face contact of a triangle under a hull's
face (:func:`cgp_core.collision.manifold._corners_under_face`) gives what the clipping gives
(:func:`~cgp_core.collision.manifold.clip_incident`) and agrees with GJK / EPA, and a box rests on an 80,000-triangle
grid for 2 s.  (Timing is benchmarks/bench_mesh.py's, never a test's.)"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cgp_core.collision.convex import HullSet, PosedHull, box_hull, convex_hull, posed
from cgp_core.collision.manifold import (
    NOT_FLIPPED,
    _corners_under_face,
    clip_incident,
    core_of,
    face_scratch,
    incident_face,
    signed_distance,
    triangle_hull_contacts,
)
from cgp_core.collision.narrowphase import ContactBuffer


def _buffer(rows: int = 32) -> ContactBuffer:
    return ContactBuffer(np.zeros((rows, 3)), np.zeros(rows), np.zeros((rows, 3)), np.zeros(rows, np.int64))


def _flat(triangle: np.ndarray) -> PosedHull:
    normal = np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])
    normal /= np.linalg.norm(normal)
    planes = np.array([[*normal, normal @ triangle[0]], [*-normal, -normal @ triangle[0]]])
    return PosedHull(triangle, np.zeros(4, np.int64), np.zeros(0, np.int64), planes, np.array([0, 3, 6]),
                     np.array([0, 1, 2, 0, 2, 1]), np.zeros(3), np.eye(3))


def _rows(out: ContactBuffer, m: int) -> list:
    order = np.argsort(out.feature[:m], kind="stable")
    return [(int(out.feature[k]), out.normal[k].copy(), float(out.separation[k]), out.point[k].copy()) for k in order]


def _configurations(seed: int, count: int):
    """Hulls (boxes, a random hull) resting on, sunk into or hovering over small triangles under them (front up),
    tilted a little or more."""
    rng = np.random.default_rng(seed)
    hulls = [HullSet.from_hulls([h]).hull(0) for h in
             (box_hull([0.5, 0.5, 0.5]), box_hull([0.3, 0.2, 0.1]), convex_hull(rng.normal(size=(30, 3))))]
    for trial in range(count):
        hull = hulls[trial % len(hulls)]
        size = rng.uniform(0.005, 0.2)
        triangle = rng.normal(size=(3, 3)) * size * [1, 1, 0.05]
        normal = np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])
        if np.linalg.norm(normal) < 1e-3 * size ** 2:
            continue
        if normal[2] < 0.0:  # (its front up, towards the hull: the resting case)
            triangle = triangle[[0, 2, 1]]
        R = Rotation.from_rotvec(rng.normal(size=3) * rng.choice([0.0, 1e-3, 0.05, 0.3])).as_matrix()
        low = (hull.vertices @ R.T)[:, 2].min()
        position = np.array([*(rng.normal(size=2) * 0.05), -low + rng.uniform(-0.01, 0.01)])
        yield triangle, posed(hull, position, R)


def test_the_corner_fast_path_gives_what_the_clipping_gives():
    """Wherever :func:`_corners_under_face` answers (the triangle's corners well inside the incident face), its rows
    are the clipping's: the same features (labels), normals, separations and points to round-off."""
    answered = 0
    for triangle, hull in _configurations(38, 3000):
        flat = _flat(triangle)
        for front in (0, 1):
            face_i, capacity = incident_face(flat, front, hull)
            best = float(np.random.default_rng(answered).choice([-2e-3, 0.0, 1e-3]))
            fast, slow = _buffer(), _buffer()
            m_fast = _corners_under_face(flat, front, hull, face_i, best, 0.02, fast, 0)
            m_slow = clip_incident(flat, front, hull, face_i, NOT_FLIPPED, best, 0.02, slow, 0, face_scratch(capacity))
            if m_fast < 0:
                continue
            answered += 1
            assert m_fast == m_slow
            for (f_a, n_a, s_a, p_a), (f_b, n_b, s_b, p_b) in zip(_rows(fast, m_fast), _rows(slow, m_slow)):
                assert f_a == f_b
                np.testing.assert_allclose(n_a, n_b, atol=1e-12)
                assert abs(s_a - s_b) <= 1e-12
                np.testing.assert_allclose(p_a, p_b, atol=1e-12)
    assert answered > 500  # (it is exercised: a hull resting over a small triangle is its case)


def test_a_resting_hull_on_a_triangle_agrees_with_gjk_and_epa():
    """The manifold of a hull over a small triangle (now mostly the fast path): its deepest point's separation is
    the true separation (GJK's distance, or minus EPA's depth) and its normal the triangle's, within tolerance."""
    checked = 0
    for triangle, hull in _configurations(5, 3000):
        flat = _flat(triangle)
        out = _buffer()
        m = triangle_hull_contacts(triangle, np.uint8(0), False, hull, 0.05, out, 0)
        if m == 0:
            continue
        separation, nx, ny, nz = signed_distance(core_of(flat), core_of(hull))[:4]
        if abs(nx * flat.face_plane[0, 0] + ny * flat.face_plane[0, 1] + nz * flat.face_plane[0, 2]) < 1 - 1e-6:
            continue  # (an edge or a hull face is the true axis: not this path's case)
        checked += 1
        assert abs(out.separation[:m].min() - separation) <= 1e-6 + 1e-6 * abs(separation)
        for k in range(m):
            assert out.normal[k] @ flat.face_plane[0, :3] > 1 - 1e-6 or out.normal[k] @ flat.face_plane[0, :3] < -0.5
    assert checked > 50


@pytest.mark.timeout(180)
def test_a_box_rests_on_an_80k_triangle_grid_for_two_seconds(tmp_path):
    """2 s on the 80,000-triangle grid: it sinks less than 1 mm, does not drift or jitter (speeds ~0), and gains no
    energy."""
    from test_fine_meshes import _box_on_grid

    world = _box_on_grid(200, tmp_path)
    box = world.body_model.names.index("box")
    heights, speeds = [], []
    for _ in range(120):
        world.step()
        heights.append(world.body_state.position[box, 2])
        speeds.append(np.linalg.norm(world.body_state.linear_momentum[box]) / 1.0)
    assert 0.5 - min(heights) < 1e-3
    assert max(heights) - min(heights[30:]) < 1e-4  # no jitter once settled
    assert max(speeds[30:]) < 1e-3  # (m/s: kinetic energy ~0, no gain)
    np.testing.assert_allclose(world.body_state.position[box, :2], [0.003, 0.002], atol=1e-5)
