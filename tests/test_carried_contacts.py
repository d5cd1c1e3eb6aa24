"""``world.contact_detection: once_per_tick`` (cgp_core/collision/carry.py): contacts found at a tick's first
sub-step and carried through the others — each side's surface point with its body, the separation their gap along
the normal — for the bodies that did not move by more than half the speculative distance; those that did are
detected again.  The kinematics of the carry against its definition, then the physics of a world that detects once
per tick against the closed forms the every-sub-step tests use (a stack stands; a dropped box rebounds to e² of its
height; the hull on a ramp that sticks or slides by μ, the bullets stopped by a thin wall and the arm pushing a crate
are tests/test_convex_bodies.py's, test_convex_scenes.py's and test_robot_world.py's, in both modes), piling hulls
sink no deeper than with every sub-step's detection, and what the mode is for: a resting stack detected once a
tick."""

from __future__ import annotations

import numpy as np
import pytest
from test_convex_bodies import prism_points, world

from cgp_core.collision.carry import carried_contacts, carry
from cgp_core.collision.contacts import GROUND, ContactSet
from cgp_core.rotation import quat_from_rotvec, quat_multiply, quat_to_matrices
from cgp_core.scene import SceneError


def random_contacts(rng, n_bodies=6, m=40):
    """``m`` contacts among ``n_bodies`` bodies at random poses, a quarter of them with the ground; body 0 fixed."""
    position = rng.normal(size=(n_bodies, 3))
    rotation = quat_to_matrices(quat_from_rotvec(rng.normal(size=(n_bodies, 3))))
    b = rng.integers(1, n_bodies, size=m)
    a = rng.integers(0, n_bodies, size=m)
    a[a == b] = 0
    a[: m // 4] = GROUND
    normal = rng.normal(size=(m, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    contacts = ContactSet(a.astype(np.intp), b.astype(np.intp), normal, rng.uniform(-0.01, 0.02, m),
                          rng.normal(size=(m, 3)), np.arange(m, dtype=np.int64), np.full(m, 0.5), np.zeros(m))
    fixed = np.zeros(n_bodies, bool)
    fixed[0] = True
    return contacts, position, rotation, fixed


def test_carried_to_the_poses_they_were_found_at_the_contacts_are_the_found_ones():
    contacts, position, rotation, fixed = random_contacts(np.random.default_rng(1))
    now = carried_contacts(carry(contacts, position, rotation, fixed), position, rotation)
    np.testing.assert_allclose(now.separation, contacts.separation, rtol=0, atol=1e-14)
    np.testing.assert_allclose(now.point, contacts.point, rtol=0, atol=1e-14)
    for field in ("body_a", "body_b", "normal", "key", "friction", "restitution"):
        assert getattr(now, field) is getattr(contacts, field)


def test_a_rigid_motion_carries_each_surface_point_with_its_body():
    """Every movable body turned by the same rotation Q about a point c and shifted by t (the fixed body and the
    ground stay).  Each side's surface point, p ∓ (s/2) n, moves with its body; the separation is their gap along
    the normal as found, n · (p_B − p_A): for two movable bodies s (n · Q n) — unchanged by the shift, and by a turn
    about the normal — and the point the midway Q (p − c) + c + t; where A stays, the point is B's surface point
    moved back by half the new gap."""
    rng = np.random.default_rng(2)
    contacts, position, rotation, fixed = random_contacts(rng)
    carried = carry(contacts, position, rotation, fixed)
    Q = quat_to_matrices(quat_from_rotvec(np.array([[0.3, -0.2, 0.5]])))[0]
    c, t = rng.normal(size=3), rng.normal(size=3)
    moved_position, moved_rotation = position.copy(), rotation.copy()
    moved_position[~fixed] = (position[~fixed] - c) @ Q.T + c + t
    moved_rotation[~fixed] = Q @ rotation[~fixed]
    now = carried_contacts(carried, moved_position, moved_rotation)
    n, s0, p = contacts.normal, contacts.separation, contacts.point
    both = (contacts.body_a != GROUND) & ~fixed[np.maximum(contacts.body_a, 0)]
    assert both.any() and (~both).any()
    np.testing.assert_allclose(now.separation[both], s0[both] * np.einsum("mk,kj,mj->m", n[both], Q, n[both]),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(now.point[both], (p[both] - c) @ Q.T + c + t, rtol=0, atol=1e-12)
    still = ~both
    surface_b = (p[still] + 0.5 * s0[still, None] * n[still] - c) @ Q.T + c + t
    surface_a = p[still] - 0.5 * s0[still, None] * n[still]
    gap = np.einsum("mk,mk->m", n[still], surface_b - surface_a)
    np.testing.assert_allclose(now.separation[still], gap, rtol=0, atol=1e-12)
    np.testing.assert_allclose(now.point[still], surface_b - 0.5 * gap[:, None] * n[still], rtol=0, atol=1e-12)
    shifted = position.copy()
    shifted[~fixed] += t
    np.testing.assert_allclose(carried_contacts(carried, shifted, rotation).separation[both], s0[both], rtol=0,
                               atol=1e-12)


def test_b_moved_along_the_normal_by_d_moves_the_separation_by_d():
    rng = np.random.default_rng(3)
    contacts, position, rotation, fixed = random_contacts(rng)
    carried = carry(contacts, position, rotation, fixed)
    for c in range(contacts.count):
        b, d = contacts.body_b[c], rng.uniform(-0.05, 0.05)
        moved = position.copy()
        moved[b] += d * contacts.normal[c]
        now = carried_contacts(carried, moved, rotation)
        if contacts.body_a[c] != b:
            assert now.separation[c] == pytest.approx(contacts.separation[c] + d, abs=1e-12)


# ---- a world that detects once per tick --------------------------------------------------------------------

def test_a_stack_of_hulls_stands_and_detection_runs_once_per_tick():
    """Six hexagonal prisms stacked, each turned and shifted a little, sleeping off: after 5 s none has moved by
    more than 1 % of its size, and the detector ran once per tick (every sub-step without the setting)."""
    rng = np.random.default_rng(5)
    bodies = []
    for k in range(6):
        q = quat_from_rotvec(np.array([0, 0, rng.uniform(-0.03, 0.03)]))
        x, y = rng.uniform(-0.004, 0.004, size=2)
        bodies.append(f"  - {{name: p{k}, shape: convex, points: {prism_points(6, 0.2, 0.1)}, mass: 2.0, "
                      f"position: [{x}, {y}, {0.1 + 0.2 * k}], orientation: {q.tolist()}, friction: 0.6}}")
    calls = {}
    for mode in ("every_substep", "once_per_tick"):
        w = world(f"world: {{substeps: 4, sleep: false, contact_detection: {mode}}}\nbodies:\n" + "\n".join(bodies)
                  + "\n")
        start = w.body_state.position.copy()
        w.solver.detector.profile.reset()
        for _ in range(300):
            w.step()
        calls[mode] = w.solver.detector.profile.calls
        drift = np.linalg.norm(w.body_state.position - start, axis=1)
        assert drift.max() <= 0.01 * 0.4, (mode, drift)
    assert calls == {"every_substep": 1200, "once_per_tick": 300}


@pytest.mark.parametrize("e", [0.5, 0.8])
def test_a_box_dropped_with_contacts_found_once_per_tick_rebounds_to_e_squared_of_its_height(e):
    """A box dropped flat from H = 1 m onto the ground (a 60 Hz tick of 4 sub-steps, contacts found once per tick):
    its apex after the first bounce is e² H within 4 % (the every-sub-step tests ask 2 % at 960 Hz; here the
    integrator alone misses an apex by O(h v) ≈ 2 %)."""
    half, drop = 0.1, 1.0
    w = world(f"""
world: {{substeps: 4, sleep: false, contact_detection: once_per_tick, ground_restitution: 0.0}}
bodies:
  - {{name: crate, shape: box, size: [0.3, 0.2, {2 * half}], mass: 1.0, position: [0, 0, {half + drop}],
     restitution: {e}}}
""", dt=1 / 60)
    heights, velocities = [], []
    for _ in range(150):
        w.step()
        heights.append(w.body_state.position[0, 2] - half)
        velocities.append(w.body_state.linear_momentum[0, 2])
    heights, velocities = np.array(heights), np.array(velocities)
    up = np.flatnonzero((velocities[:-1] > 0) & (velocities[1:] <= 0))
    assert len(up), "no apex after the bounce"
    assert heights[up[0]:up[0] + 2].max() == pytest.approx(e * e * drop, rel=0.04)
    assert heights.min() > -0.01  # it never sank into the ground by more than a centimetre


def test_an_unknown_contact_detection_is_a_scene_error_naming_the_key():
    with pytest.raises(SceneError, match=r"world\.contact_detection.*every_substep, once_per_tick.*sometimes"):
        world("world: {contact_detection: sometimes}\nbodies: []\n")


def hull_pile_scene(mode: str, count: int) -> str:
    """The first ``count`` hulls of benchmarks/bench_convex_pile.py's pile (two layers of 25 for 50)."""
    rng = np.random.default_rng(25)
    lines = [f"world: {{substeps: 4, sleep: false, contact_detection: {mode}}}", "bodies:"]
    for k in range(count):
        layer, cell = divmod(k, 25)
        i, j = divmod(cell, 5)
        n = int(rng.integers(16, 25))
        direction = rng.normal(size=(n, 3))
        direction /= np.linalg.norm(direction, axis=1)[:, None]
        points = direction * (rng.uniform(0.3, 0.5) / 2) * rng.uniform(0.8, 1.0, size=3)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        pts = ", ".join(f"[{a:.6f}, {b:.6f}, {c:.6f}]" for a, b, c in points)
        lines.append(f"  - {{name: h{k}, shape: convex, mass: 1.0, friction: 0.6, restitution: 0.0, position: "
                     f"[{(i - 2) * 0.7}, {(j - 2) * 0.7}, {0.4 + 0.7 * layer}], orientation: {q.tolist()}, "
                     f"points: [{pts}]}}")
    return "\n".join(lines) + "\n"


def test_a_body_whose_state_went_non_finite_has_the_sub_step_detect_again():
    """A blown-up body (its position NaN within the tick; World resets it after the tick) is not carried: the
    sub-step detects, which leaves it out of every pair — no NaN gap is handed to the bodies it touched."""
    w = world(f"""
world: {{substeps: 4, sleep: false, contact_detection: once_per_tick}}
bodies:
  - {{name: puck, shape: convex, points: {prism_points(8, 0.1, 0.05)}, mass: 1.0, position: [0, 0, 0.05]}}
  - {{name: lid, shape: convex, points: {prism_points(8, 0.1, 0.05)}, mass: 1.0, position: [0, 0, 0.15]}}
""", dt=1 / 60)
    for _ in range(30):
        w.step()
    detector = w.solver.detector
    state = w.body_state.copy()
    state.position[1] = np.nan
    detector.carry_next = True
    calls = detector.profile.calls
    contacts = detector.detect(w.body_model, state, w.dt / 4, ground=w.ground)
    detector.carry_next = False
    assert detector.profile.calls == calls + 1
    assert contacts.count and np.isfinite(contacts.separation).all()
    assert not (contacts.body_b == 1).any() and not (contacts.body_a == 1).any()


@pytest.mark.parametrize("motion", ["shift", "turn"])
def test_a_body_that_moved_within_the_tick_has_its_contacts_detected_again(motion):
    """A hull resting on the ground, its contacts carried: moved afterwards — shifted sideways, or turned about the
    vertical — so that its surface moved by just under the carry tolerance (half the speculative distance: |Δx| +
    θ · reach), the next sub-step carries its contacts (no detection); just over it, it detects them again."""
    w = world(f"""
world: {{substeps: 4, sleep: false, contact_detection: once_per_tick}}
bodies:
  - {{name: puck, shape: convex, points: {prism_points(8, 0.1, 0.05)}, mass: 1.0, position: [0, 0, 0.05]}}
""", dt=1 / 60)
    for _ in range(30):
        w.step()
    detector = w.solver.detector
    reach = detector.shape_model(w.body_model).body_reach[0]
    tolerance = 0.5 * detector.speculative_distance
    start = w.body_state.copy()
    counted = []
    for share in (0.8, 1.2):
        state = start.copy()
        if motion == "shift":
            state.position[0, 0] += share * tolerance
        else:
            turn = quat_from_rotvec(np.array([0.0, 0.0, share * tolerance / reach]))
            state.orientation[0] = quat_multiply(turn, start.orientation[0])
        w.body_state = state
        detector.carry_next = True
        calls = detector.profile.calls
        contacts = detector.detect(w.body_model, state, w.dt / 4, ground=w.ground)
        counted.append(detector.profile.calls - calls)
        assert contacts.count >= 3
    detector.carry_next = False
    assert counted == [0, 1]


def test_hulls_piling_with_contacts_found_once_per_tick_sink_no_deeper_than_found_every_sub_step():
    """Fifty hulls of the benchmark's pile dropped in two layers (2.5 s): with contacts once per tick, the deepest
    penetration of any tick is within 2 mm of every-sub-step detection's.  Carrying every body's contacts through
    the tick however it moves (``carry_tolerance`` = ∞) lets hulls fall into others several mm deeper — what the
    re-detection of the bodies that moved is for."""
    deepest = {}
    for mode, tolerance in (("every_substep", None), ("once_per_tick", None), ("once_per_tick", np.inf)):
        w = world(hull_pile_scene(mode, 50), dt=1 / 60)
        if tolerance is not None:
            w.solver.detector.carry_tolerance = tolerance
        worst = 0.0
        for _ in range(150):
            w.step()
            worst = max(worst, w.solver.stats.get("max_penetration", 0.0))
        deepest[(mode, tolerance)] = worst
    every, once, unchecked = deepest.values()
    assert once <= every + 0.002, deepest
    assert unchecked > once + 0.004, deepest
