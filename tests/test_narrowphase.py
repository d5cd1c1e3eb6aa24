"""Narrow phase: contact normal, separation and points on hand-made configurations with known answers, and
a geometric identity checked on random ones: ``point ∓ normal · separation / 2`` lie on the surfaces of A and
B (the contact point is midway between them)."""

import numpy as np
import pytest
from _bodies import box, make_bodies, particles, sphere

from cgp_core import geometry
from cgp_core.collision import GROUND, CollisionDetector, Ground
from cgp_core.collision import narrowphase as nph
from cgp_core.collision.box_box import box_box
from cgp_core.rotation import quat_from_rotvec, quat_to_matrix

I3 = np.eye(3)[None]
Z = np.array([0.0, 0.0, 1.0])
BIG = np.array([1.0])  # a generous margin: report everything near


def rot(rotvec):
    return quat_to_matrix(quat_from_rotvec(np.asarray(rotvec, dtype=float)))[None]


def detect(specs, ground=True, spec_distance=0.0):
    model, state = make_bodies(specs)
    det = CollisionDetector(speculative_distance=spec_distance)
    zero = np.zeros((model.count, 3))
    return det.detect(model, state, 1e-3, ground=Ground() if ground else None, velocity=zero,
                      angular_velocity=zero)


# ---- spheres and the plane ---------------------------------------------------------------------------

def test_sphere_sphere_overlap_touch_apart():
    ca = np.zeros((3, 3))
    cb = np.array([[0.25, 0, 0], [0.3, 0, 0], [0.0, 0.4, 0]])
    n, sep, p = nph.sphere_sphere(ca, np.full(3, 0.1), cb, np.full(3, 0.2))
    np.testing.assert_allclose(sep, [-0.05, 0.0, 0.1], atol=1e-15)
    np.testing.assert_allclose(n, [[1, 0, 0], [1, 0, 0], [0, 1, 0]], atol=1e-15)
    # midway between the surfaces: x = 0.1 + sep / 2 along the normal
    np.testing.assert_allclose(p, [[0.075, 0, 0], [0.1, 0, 0], [0, 0.15, 0]], atol=1e-15)


def test_sphere_sphere_coincident_centres_get_a_unit_normal():
    n, sep, _ = nph.sphere_sphere(np.zeros((1, 3)), np.array([0.1]), np.zeros((1, 3)), np.array([0.1]))
    assert np.isclose(np.linalg.norm(n), 1.0) and np.isclose(sep[0], -0.2)


def test_sphere_plane():
    n, sep, p = nph.sphere_plane(np.array([[1.0, 2.0, 0.08], [0, 0, 0.1], [0, 0, 0.5]]), np.full(3, 0.1))
    np.testing.assert_allclose(sep, [-0.02, 0.0, 0.4], atol=1e-15)
    np.testing.assert_allclose(n, np.tile(Z, (3, 1)))
    np.testing.assert_allclose(p[0], [1.0, 2.0, -0.01], atol=1e-15)


def test_box_resting_on_the_ground_gives_its_four_bottom_corners():
    c = np.array([[0.5, -0.5, 0.099]])
    h = np.array([[0.2, 0.3, 0.1]])
    pair, n, sep, p, feat = nph.box_plane(c, I3, h, BIG * 0.01)
    assert len(pair) == 4 and len(set(feat.tolist())) == 4
    np.testing.assert_allclose(sep, -0.001, atol=1e-15)
    corners = {(round(x, 9), round(y, 9)) for x, y in p[:, :2]}
    assert corners == {(0.3, -0.8), (0.3, -0.2), (0.7, -0.8), (0.7, -0.2)}
    np.testing.assert_allclose(p[:, 2], -0.0005, atol=1e-15)


def test_box_on_an_edge_and_on_a_corner():
    h = np.array([[0.1, 0.1, 0.1]])
    # 45° about x: lowest is the edge along x at depth 0.1·√2
    c = np.array([[0.0, 0.0, 0.1 * np.sqrt(2) - 0.002]])
    pair, n, sep, p, feat = nph.box_plane(c, rot([np.pi / 4, 0, 0]), h, np.array([0.001]))
    assert len(pair) == 2
    np.testing.assert_allclose(sep, -0.002, atol=1e-12)
    np.testing.assert_allclose(sorted(p[:, 0]), [-0.1, 0.1], atol=1e-12)
    # standing on a corner: the body diagonal vertical
    R = rot(np.cross([1.0, 1.0, 1.0], Z) / np.linalg.norm(np.cross([1.0, 1.0, 1.0], Z))
            * np.arccos(1 / np.sqrt(3)))
    c = np.array([[0.0, 0.0, 0.1 * np.sqrt(3) - 0.001]])
    pair, n, sep, p, feat = nph.box_plane(c, R, h, np.array([0.001]))
    assert len(pair) == 1
    np.testing.assert_allclose(sep, -0.001, atol=1e-12)
    np.testing.assert_allclose(p[0, :2], [0, 0], atol=1e-12)


def test_capsule_on_the_ground_lying_and_standing():
    lying = rot([0, np.pi / 2, 0])[0]  # axis along x
    pair, n, sep, p, feat = nph.capsule_plane(np.array([[0, 0, 0.049], [0, 0, 0.249]]),
                                              np.stack((lying[:, 2], Z)), np.array([0.2, 0.2]),
                                              np.array([0.05, 0.05]), np.array([0.001, 0.001]))
    assert pair.tolist() == [0, 0, 1]
    np.testing.assert_allclose(sep, [-0.001, -0.001, -0.001], atol=1e-12)
    np.testing.assert_allclose(sorted(p[:2, 0]), [-0.2, 0.2], atol=1e-12)


# ---- sphere vs box / capsule ---------------------------------------------------------------------------

def test_sphere_against_box_face_edge_corner_and_inside():
    h = np.array([0.5, 0.5, 0.5])
    centres = np.array([[0.0, 0.0, 0.6],  # over the top face
                        [0.6, 0.0, 0.6],  # over the edge x = y... the edge at x = 0.5, z = 0.5
                        [0.6, 0.6, 0.6],  # off the corner
                        [0.0, 0.0, 0.4]])  # centre inside, nearest face is the top
    k = len(centres)
    n, sep, p = nph.sphere_box(centres, np.full(k, 0.2), np.zeros((k, 3)), np.repeat(I3, k, 0), np.tile(h, (k, 1)))
    d_edge, d_corner = np.hypot(0.1, 0.1), np.sqrt(3) * 0.1
    np.testing.assert_allclose(sep, [-0.1, d_edge - 0.2, d_corner - 0.2, -0.3], atol=1e-12)
    # normal from A (sphere) to B (box): towards the box
    np.testing.assert_allclose(n[0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(n[1], [-1 / np.sqrt(2), 0, -1 / np.sqrt(2)], atol=1e-12)
    np.testing.assert_allclose(n[2], -np.ones(3) / np.sqrt(3), atol=1e-12)
    np.testing.assert_allclose(n[3], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(p[3], [0, 0, 0.5 - 0.15], atol=1e-12)  # top face − half the depth


def test_sphere_against_rotated_box_matches_the_geometry_module():
    """Reference: cgp_core.geometry.box_distance (point vs oriented box), minus the radius."""
    rng = np.random.default_rng(2)
    k = 200
    R = quat_to_matrix(quat_from_rotvec(rng.normal(size=(k, 3))))
    cb = rng.normal(size=(k, 3)) * 0.1
    hb = rng.uniform(0.1, 0.5, size=(k, 3))
    cs = rng.uniform(-1, 1, size=(k, 3))
    r = rng.uniform(0.05, 0.3, size=k)
    n, sep, p = nph.sphere_box(cs, r, cb, R, hb)
    for i in range(k):
        dist, normal = geometry.box_distance(cs[i:i + 1], cb[i:i + 1], R[i:i + 1], hb[i:i + 1])
        assert np.isclose(sep[i], dist[0, 0] - r[i], atol=1e-12)
        assert np.allclose(-n[i], normal[0, 0], atol=1e-9)


def test_sphere_capsule():
    axis = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    n, sep, p = nph.sphere_capsule(np.array([[0.25, 0, 0.1], [0, 0, 0.55]]), np.array([0.1, 0.1]),
                                   np.zeros((2, 3)), axis, np.array([0.3, 0.3]), np.array([0.1, 0.1]))
    np.testing.assert_allclose(sep, [0.05, 0.55 - 0.3 - 0.2], atol=1e-12)  # side of the cylinder; the cap
    np.testing.assert_allclose(n, [[-1, 0, 0], [0, 0, -1]], atol=1e-12)


# ---- capsules ----------------------------------------------------------------------------------------

def test_crossed_capsules_touch_at_the_crossing():
    ax_x, ax_y = np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])
    pair, n, sep, p, feat = nph.capsule_capsule(np.zeros((1, 3)), ax_x, np.array([0.5]), np.array([0.1]),
                                                np.array([[0.0, 0.0, 0.19]]), ax_y, np.array([0.5]),
                                                np.array([0.1]), BIG)
    assert len(pair) == 1
    np.testing.assert_allclose(sep, [-0.01], atol=1e-12)
    np.testing.assert_allclose(n[0], Z, atol=1e-12)
    np.testing.assert_allclose(p[0], [0, 0, 0.095], atol=1e-12)


def test_parallel_capsules_get_two_points_at_the_overlap_ends():
    ax = np.array([[1.0, 0, 0]])
    pair, n, sep, p, feat = nph.capsule_capsule(np.zeros((1, 3)), ax, np.array([0.5]), np.array([0.1]),
                                                np.array([[0.3, 0.0, 0.19]]), ax, np.array([0.5]),
                                                np.array([0.1]), BIG)
    assert len(pair) == 2
    np.testing.assert_allclose(sep, [-0.01, -0.01], atol=1e-12)
    np.testing.assert_allclose(sorted(p[:, 0]), [-0.2, 0.5], atol=1e-12)  # overlap of [-0.5, 0.5] and [-0.2, 0.8]


def test_capsule_lying_on_a_box_and_across_its_edge():
    h = np.array([[0.5, 0.5, 0.5]])
    ax_x = np.array([[1.0, 0, 0]])
    # lying flat on the top face: the two end spheres touch
    pair, n, sep, p, feat = nph.box_capsule(np.zeros((1, 3)), I3, h, np.array([[0.0, 0.0, 0.59]]), ax_x,
                                            np.array([0.3]), np.array([0.1]), BIG * 0.01)
    assert sorted(feat.tolist()) == [0, 1]
    np.testing.assert_allclose(sep, -0.01, atol=1e-12)
    np.testing.assert_allclose(n, np.tile(Z, (2, 1)), atol=1e-12)
    # draped over the top edge (x = 0.5, z = 0.5, along y), axis in the x–z plane at 45°: the middle of the
    # segment is the point nearest the box, 0.05·√2 from the edge; the ends are far
    axis = np.array([[1.0, 0.0, -1.0]]) / np.sqrt(2)
    centre = np.array([[0.55, 0.0, 0.55]])
    pair, n, sep, p, feat = nph.box_capsule(np.zeros((1, 3)), I3, h, centre, axis, np.array([0.3]),
                                            np.array([0.1]), BIG * 0.01)
    assert feat.tolist() == [2]
    np.testing.assert_allclose(sep, 0.05 * np.sqrt(2) - 0.1, atol=1e-6)
    np.testing.assert_allclose(n[0], [1 / np.sqrt(2), 0, 1 / np.sqrt(2)], atol=1e-5)


# ---- box vs box --------------------------------------------------------------------------------------

def test_resting_face_contact_gives_four_points_at_the_overlap_corners():
    """B sits on A, shifted by (0.3, 0.2): the overlap of the two 1 × 1 squares is [-0.2, 0.5] × [-0.3, 0.5]."""
    h = np.full((1, 3), 0.5)
    pair, n, sep, p, feat = box_box(np.zeros((1, 3)), I3, h, np.array([[0.3, 0.2, 0.998]]), I3, h, BIG * 0.01)
    assert len(pair) == 4
    np.testing.assert_allclose(n, np.tile(Z, (4, 1)), atol=1e-15)
    np.testing.assert_allclose(sep, -0.002, atol=1e-12)
    corners = {(round(x, 9), round(y, 9)) for x, y in p[:, :2]}
    assert corners == {(-0.2, -0.3), (-0.2, 0.5), (0.5, -0.3), (0.5, 0.5)}
    np.testing.assert_allclose(p[:, 2], 0.499, atol=1e-12)


def test_box_turned_on_top_of_a_box_keeps_four_points_spanning_the_octagon():
    h = np.full((1, 3), 0.5)
    pair, n, sep, p, feat = box_box(np.zeros((1, 3)), I3, h, np.array([[0, 0, 0.999]]), rot([0, 0, np.pi / 4]),
                                    h, BIG * 0.01)
    assert len(pair) == 4
    np.testing.assert_allclose(sep, -0.001, atol=1e-12)
    # all on the octagon (the intersection of the two squares): |x|, |y| <= 0.5 and |x| + |y| <= √2/2
    assert np.all(np.abs(p[:, :2]) <= 0.5 + 1e-12)
    assert np.all(np.abs(p[:, 0]) + np.abs(p[:, 1]) <= np.sqrt(2) / 2 + 1e-12)
    # spanning it: the quad's area is at least half the octagon's (2·(√2 − 1) ≈ 0.83)
    q = p[np.argsort(np.arctan2(p[:, 1], p[:, 0])), :2]
    area = 0.5 * abs(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))
    assert area > 0.5 * 2 * (np.sqrt(2) - 1)


def test_edge_edge_contact():
    """Two cubes turned 45° about perpendicular horizontal axes meet edge on edge (x edge of A, y edge of B)."""
    h = np.full((1, 3), 0.5)
    top = 0.5 * np.sqrt(2)
    pair, n, sep, p, feat = box_box(np.zeros((1, 3)), rot([np.pi / 4, 0, 0]), h,
                                    np.array([[0.0, 0.0, 2 * top - 0.01]]), rot([0, np.pi / 4, 0]), h, BIG * 0.01)
    assert len(pair) == 1
    assert feat[0] >= 288  # an edge-pair feature
    np.testing.assert_allclose(n[0], Z, atol=1e-12)
    np.testing.assert_allclose(sep, -0.01, atol=1e-12)
    np.testing.assert_allclose(p[0], [0, 0, top - 0.005], atol=1e-12)


def test_box_box_touching_and_separated_boundaries():
    h = np.full((1, 3), 0.5)
    for gap, margin, expect in ((0.0, 0.0, 0), (0.0, 1e-9, 4), (0.004, 0.005, 4), (0.006, 0.005, 0)):
        pair, n, sep, p, feat = box_box(np.zeros((1, 3)), I3, h, np.array([[0, 0, 1.0 + gap]]), I3, h,
                                        np.array([margin]))
        assert len(pair) == expect, (gap, margin)
        if expect:
            np.testing.assert_allclose(sep, gap, atol=1e-12)


def random_pairs(seed=11, count=60):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        Ra = quat_to_matrix(quat_from_rotvec(rng.normal(size=3)))[None]
        Rb = quat_to_matrix(quat_from_rotvec(rng.normal(size=3)))[None]
        ha = rng.uniform(0.1, 0.5, size=(1, 3))
        hb = rng.uniform(0.1, 0.5, size=(1, 3))
        cb = rng.normal(size=(1, 3))
        cb *= rng.uniform(0.5, 0.9) * (np.linalg.norm(ha) + np.linalg.norm(hb)) / np.linalg.norm(cb)
        yield np.zeros((1, 3)), Ra, ha, cb, Rb, hb


def test_box_box_points_are_midway_between_the_surfaces():
    """For every penetrating contact, point − n·sep/2 is on A's surface and point + n·sep/2 on B's."""
    checked = 0
    for ca, Ra, ha, cb, Rb, hb in random_pairs():
        pair, n, sep, p, feat = box_box(ca, Ra, ha, cb, Rb, hb, BIG)
        keep = sep <= 0.0
        on_a = geometry.box_distance(p[keep] - n[keep] * sep[keep, None] / 2, ca, Ra, ha)[0][:, 0]
        on_b = geometry.box_distance(p[keep] + n[keep] * sep[keep, None] / 2, cb, Rb, hb)[0][:, 0]
        assert np.abs(on_a).max(initial=0) < 1e-9 and np.abs(on_b).max(initial=0) < 1e-9
        checked += int(keep.sum())
    assert checked > 50


def box_box_distance(ca, Ra, ha, cb, Rb, hb):
    """Reference distance between two *disjoint* boxes: the smallest of corner-to-box distances both ways
    and of edge-to-edge distances (the closest features of two convex polyhedra are one of those)."""
    corners = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    va = ca + (corners * ha) @ Ra[0].T
    vb = cb + (corners * hb) @ Rb[0].T
    best = min(geometry.box_distance(va, cb, Rb, hb)[0].min(), geometry.box_distance(vb, ca, Ra, ha)[0].min())
    edges = [(i, j) for i in range(8) for j in range(8) if i < j and np.sum(corners[i] != corners[j]) == 1]
    for i, j in edges:
        for k, l in edges:
            s, t, x1, x2 = nph.closest_segments(va[i:i + 1], va[j:j + 1], vb[k:k + 1], vb[l:l + 1])
            best = min(best, np.linalg.norm(x1 - x2))
    return best


def test_separated_box_box_never_overestimates_the_gap():
    """Speculative contacts must not report more gap than there is (or a fast box would be let through)."""
    checked = 0
    for ca, Ra, ha, cb, Rb, hb in random_pairs(seed=5, count=40):
        cb = cb * 1.4  # mostly apart
        pair, n, sep, p, feat = box_box(ca, Ra, ha, cb, Rb, hb, BIG)
        if len(pair) and sep.min() > 0.0:
            assert sep.min() <= box_box_distance(ca, Ra, ha, cb, Rb, hb) + 1e-12
            checked += 1
    assert checked >= 10


def test_box_capsule_finds_the_deepest_point_of_the_segment():
    """The smallest reported separation equals the capsule–box signed distance (dense sampling of the
    segment as the reference), and every A-side point lies on the box surface."""
    checked = 0
    for ca, Ra, ha, cb, Rb, hb in random_pairs(seed=3):
        axis, half, radius = Rb[:, :, 2], hb[:, 2], np.array([0.1])
        pair, n, sep, p, feat = nph.box_capsule(ca, Ra, ha, cb, axis, half, radius, BIG)
        t = np.linspace(-1.0, 1.0, 20001)[:, None]
        samples = cb + t * axis * half
        reference = geometry.box_distance(samples, ca, Ra, ha)[0].min() - radius[0]
        if reference < 0.5:
            assert len(pair) and abs(sep.min() - reference) < 1e-6
            on_a = geometry.box_distance(p - n * sep[:, None] / 2, ca, Ra, ha)[0][:, 0]
            assert np.abs(on_a).max() < 1e-9
            checked += 1
    assert checked > 40


# ---- through the detector: particles, fixed bodies, the ground -----------------------------------------

def test_particle_body_collides_as_its_spheres():
    dumbbell = particles([[-0.2, 0, 0.05, 1.0], [0.2, 0, 0.05, 1.0], [0.0, 0, 0.4, 1.0]], radius=0.06)
    c = detect([dumbbell])
    # the two low particles touch the ground (penetrating 1 cm), the high one does not; no self contacts
    assert c.count == 2
    assert np.all(c.body_a == GROUND) and np.all(c.body_b == 0)
    np.testing.assert_allclose(c.separation, -0.01, atol=1e-12)
    np.testing.assert_allclose(sorted(c.point[:, 0]), [-0.2, 0.2], atol=1e-12)


def test_fixed_bodies_collide_with_moving_ones_but_not_with_each_other_or_the_ground():
    specs = [box((1, 1, 0.1), fixed=True, position=(0, 0, 0.05)),  # a fixed slab on (in) the ground
             box((0.1, 0.1, 0.1), fixed=True, position=(0, 0, 0.2)),  # fixed, overlapping the slab
             sphere(0.1, position=(0.5, 0, 0.24))]  # resting on the slab (top at 0.15), 1 cm in
    c = detect(specs)
    assert c.count == 1
    assert (c.body_a[0], c.body_b[0]) == (2, 0) or (c.body_a[0], c.body_b[0]) == (0, 2)
    np.testing.assert_allclose(c.separation, -0.01, atol=1e-12)
    # normal from A to B
    expected = Z if c.body_a[0] == 0 else -Z
    np.testing.assert_allclose(c.normal[0], expected, atol=1e-12)


def test_speculative_margin_reports_gaps_that_may_close_this_step():
    model, state = make_bodies([sphere(0.1, position=(0, 0, 0.5), velocity=(0, 0, -30.0))])
    det = CollisionDetector(speculative_distance=0.0)
    far = det.detect(model, state, 1e-3, ground=Ground())  # moves 3 cm: 40 cm gap stays open
    near = det.detect(model, state, 1.0 / 60.0, ground=Ground())  # moves 50 cm: could reach the ground
    assert far.count == 0
    assert near.count == 1 and np.isclose(near.separation[0], 0.4)


def test_keys_are_unique_and_stable():
    specs = [box((0.1, 0.1, 0.1), position=(0, 0, 0.099)), box((0.1, 0.1, 0.1), position=(0.05, 0, 0.298)),
             sphere(0.05, position=(0.5, 0, 0.049))]
    c1, c2 = detect(specs), detect(specs)
    assert len(np.unique(c1.key)) == c1.count == 9
    assert np.array_equal(c1.key, c2.key)


def test_bad_detector_settings_are_named():
    with pytest.raises(ValueError, match="speculative_distance"):
        CollisionDetector(speculative_distance=-1.0)
    with pytest.raises(ValueError, match="unknown broad phase"):
        CollisionDetector(broad_phase="kd")
