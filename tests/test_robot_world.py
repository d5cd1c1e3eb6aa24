"""Robots in a World (issue 35): the `arm_teleop` scene's URDF robot (the 4-joint arm.urdf, holding its pose:
the `arm` scene's 7-DoF arm follows a trajectory, tests/test_scene_trajectory.py) in reduced coordinates, its
drives, its mimic gripper, its links' contacts with the ground and free bodies, wrenches on links, and the
scene's refusals.
Closed forms: a body resting on a link loads the joints by its weight's moment, a wrench on a link by Jᵀ F."""

from __future__ import annotations

import numpy as np
import pytest

from cgp_core import World
from cgp_core.editing import EditError
from cgp_core.scene import SceneError, scene_from_dict

ARM_JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist", "finger_left_joint"]


def arm_scene(*, joints=None, hold=True, bodies=(), gravity=(0, 0, -9.81), ground=True, **robot):
    entry = {"name": "arm", "urdf": "arm.urdf", "hold": hold,
             "joints": joints if joints is not None else {"shoulder_lift": 0.6, "elbow": 1.2, "wrist": 0.6}}
    entry.update(robot)
    return scene_from_dict({"world": {"gravity": list(gravity), "ground": ground, "substeps": 4},
                            "robots": [entry], "bodies": list(bodies)}, "<test>")


def run(world: World, seconds: float, each=None) -> None:
    for _ in range(round(seconds / world.dt)):
        world.step()
        if each is not None:
            each(world)


def positions(world: World) -> dict[str, float]:
    names, q, _, _ = world.robots.joint_state("arm")
    return dict(zip(names, q))


def tool_position(world: World) -> np.ndarray:
    names, _, p = world.robots.frame_poses("arm")
    return p[list(names).index("tool")]


def test_the_arm_holds_its_pose_under_position_control():
    world = World.from_scene("arm_teleop")
    start = positions(world)
    worst = 0.0

    def check(w):
        nonlocal worst
        now = positions(w)
        worst = max(worst, max(abs(now[j] - start[j]) for j in start))

    run(world, 3.0, check)
    assert worst <= 1e-3, worst
    # every link's body is where the joints put it: the tool frame above the ground, the joints exact
    assert tool_position(world)[2] > 0.3


def test_the_mimic_finger_follows_its_leader_exactly():
    world = World.from_scene("arm_teleop")
    assert world.robots.command("arm", ["finger_left_joint"], position=[0.028]) == []
    trace = []
    run(world, 1.5, lambda w: trace.append((positions(w)["finger_left_joint"], positions(w)["finger_right_joint"])))
    left, right = np.array(trace).T
    assert abs(left[-1] - 0.028) < 1e-3
    assert np.abs(right - left).max() < 1e-6  # q_f = 1·q_l + 0 at every tick, not a spring's lag


def test_a_crate_resting_on_the_upper_arm_loads_the_shoulder_by_its_weights_moment():
    # the upper arm horizontal along +x (shoulder_lift = π/2), the forearm folded up out of the way
    joints = {"shoulder_lift": np.pi / 2, "elbow": -np.pi / 2, "wrist": 0.0}
    crate_x, m = 0.25, 0.4
    top = 0.2 + 0.025  # the shoulder_lift axis (0.1 + 0.1 above the ground) + half the upper arm's width
    crate = {"name": "crate", "shape": "box", "size": [0.06, 0.06, 0.04], "mass": m, "friction": 1.0,
             "position": [crate_x, 0.0, top + 0.02 + 0.002]}
    loaded, bare = World(arm_scene(joints=joints, bodies=[crate])), World(arm_scene(joints=joints))
    for world in (loaded, bare):
        run(world, 1.5)
    efforts = {}
    for label, world in (("loaded", loaded), ("bare", bare)):
        names, _, _, effort = world.robots.joint_state("arm")
        efforts[label] = dict(zip(names, effort))
    x = loaded.body_state.position[loaded.body_model.index("crate")][0]
    assert abs(x - crate_x) < 0.01  # it stayed on the arm
    # the weight m g at lever x about the shoulder's y axis: τ_y = m g x; the drive holds it with −m g x
    delta = efforts["loaded"]["shoulder_lift"] - efforts["bare"]["shoulder_lift"]
    assert delta == pytest.approx(-m * 9.81 * x, rel=0.03)
    assert abs(efforts["loaded"]["elbow"] - efforts["bare"]["elbow"]) < 0.02 * m * 9.81 * x  # not on the forearm


def test_a_wrench_on_a_link_is_taken_by_the_joints_as_j_transpose_f():
    """A force F at the tool, held by the position drives: their efforts change by −Jᵀ F, J the tool point's
    Jacobian (here by finite differences of the forward kinematics)."""
    joints = {"shoulder_lift": 0.6, "elbow": 1.2, "wrist": 0.6}
    force = np.array([3.0, 0.0, -2.0])
    pushed, bare = World(arm_scene(joints=joints, gravity=(0, 0, 0))), World(arm_scene(joints=joints,
                                                                                         gravity=(0, 0, 0)))
    point = tool_position(pushed)
    for _ in range(60):
        pushed.apply_wrench("arm/hand", force=force, point=point)
        pushed.step()
        bare.step()
    names, q, _, effort = pushed.robots.joint_state("arm")
    _, _, _, effort_bare = bare.robots.joint_state("arm")
    # J by central differences of the tool's position in the joint positions
    r = pushed.robots.robot("arm")
    from cgp_core.robots import algorithms

    qfull = pushed.robots.q[r.q_slice].copy()
    tool = list(r.model.frame_names).index("tool")

    def tool_at(qv):
        rot, pos = algorithms.forward_kinematics(r.arrays, qv)
        b = r.model.frame_body[tool]
        return pos[b] + rot[b] @ r.model.frame_position[tool]

    for k, joint in enumerate(names[:4]):
        dq = np.zeros_like(qfull)
        dq[k] = 1e-6
        column = (tool_at(qfull + dq) - tool_at(qfull - dq)) / 2e-6
        assert effort[k] - effort_bare[k] == pytest.approx(-column @ force, abs=1e-3), joint


def _push_a_crate(detection="every_substep", **robot):
    """The arm turning at 1 rad/s into a tall crate: the crate's displacement and the deepest contact per pair of
    kinds, (link, crate) and the others, over 1.5 s (the link contacts are in the report since the robot stage
    adds its contacts to it).  ``detection``: the scene's ``world.contact_detection``; ``robot``: more keys of the
    robot's entry."""
    # the forearm slants down to ~0.2 m above the ground at 0.48 m out; a tall crate stands 0.35 rad ahead of it
    crate = {"name": "crate", "shape": "box", "size": [0.1, 0.1, 0.3], "mass": 0.3, "friction": 0.4,
             "position": [0.48 * np.cos(0.35), 0.48 * np.sin(0.35), 0.15]}
    scene = arm_scene(joints={"shoulder_lift": 1.2, "elbow": 1.3, "wrist": -0.3}, bodies=[crate], **robot)
    scene.world.contact_detection = detection
    world = World(scene)
    start = world.body_state.position[world.body_model.index("crate")].copy()
    world.robots.command("arm", ["shoulder_pan"], velocity=[1.0])
    world.report_contacts = True
    deepest = {"link": 0.0, "other": 0.0}
    links = set(np.flatnonzero(world.robots.body_robot >= 0).tolist())

    def check(w):
        c = w.contacts
        for a, b, s in zip(c.body_a, c.body_b, c.separation):
            kind = "link" if int(a) in links or int(b) in links else "other"
            deepest[kind] = min(deepest[kind], float(s))

    run(world, 1.5, check)
    return world.body_state.position[world.body_model.index("crate")] - start, deepest


@pytest.mark.parametrize("detection", ["every_substep", "once_per_tick"])
def test_the_turning_arm_pushes_a_crate_and_never_sinks_into_it(detection):
    """With the contacts found every sub-step, and once per tick (cgp_core/collision/carry.py: the links the joints
    move are bodies like the others — the crate and the links at rest carried, the turning forearm detected again
    in every sub-step)."""
    moved, deepest = _push_a_crate(detection)
    assert np.linalg.norm(moved[:2]) > 0.05, moved
    assert deepest["other"] > -0.01, deepest
    assert deepest["link"] > -0.002, deepest


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "gauss_legendre_4"])
def test_the_pushing_link_never_sinks_into_the_crate(integrator):
    # the ground's friction holds the crate back: solved after the link's rows (two blocks, before issue 35's one
    # loop) it took back some of the link's push every sub-step, and the link sank 2.8 cm into the crate.  With a
    # Gauss–Legendre joint integrator the robot's q̇⁺ comes from the body solver's loop too (after Robots.solve):
    # its position update must take that q̇⁺ (Robots.integrate), or the link runs on into the crate
    moved, deepest = _push_a_crate(joint_integrator=integrator)
    assert deepest["link"] > -0.002, deepest
    assert np.linalg.norm(moved[:2]) > 0.05, moved


def test_the_link_and_the_crate_it_pushes_end_each_sub_step_without_approaching():
    """Issue 35's one loop: the link's rows and the crate's ground rows are solved in the same sweeps on one
    crate velocity, so where the link pushes, the two leave the sub-step not running into each other.  Solved as
    two blocks (the link's rows first, seeing the crate free; then the ground's friction taking part of the push
    back) the link ran on into the crate at a median 5 cm/s."""
    crate = {"name": "crate", "shape": "box", "size": [0.1, 0.1, 0.3], "mass": 0.3, "friction": 0.4,
             "position": [0.48 * np.cos(0.35), 0.48 * np.sin(0.35), 0.15]}
    world = World(arm_scene(joints={"shoulder_lift": 1.2, "elbow": 1.3, "wrist": -0.3}, bodies=[crate]))
    world.robots.command("arm", ["shoulder_pan"], velocity=[1.0])
    world.report_contacts = True
    links, box = world.robots.body_robot >= 0, world.body_model.index("crate")
    approach = []

    def check(w):  # the normal velocity of B relative to A at each pushing contact, after the tick
        c, s = w.contacts, w.body_state
        v, omega = s.linear_momentum / w.body_model.mass[:, None], s.angular_velocity(w.body_model)
        for a, b, p, n, impulse in zip(c.body_a, c.body_b, c.point, c.normal, c.normal_impulse):
            if a >= 0 and impulse > 0.0 and ((links[a] and b == box) or (links[b] and a == box)):
                at_b = v[b] + np.cross(omega[b], p - s.position[b])
                at_a = v[a] + np.cross(omega[a], p - s.position[a])
                approach.append(float(n @ (at_b - at_a)))

    run(world, 1.5, check)
    assert len(approach) > 20
    assert np.median(approach) > -0.01, np.percentile(approach, [5, 50, 95])


def test_a_crate_started_inside_a_link_is_pushed_out_without_gaining_energy():
    """The links' contacts with free bodies take part in the joint solver's position stage (split impulses: the
    crate is displaced, the robot moved by a pseudo-velocity; no momentum changes): a crate started 1 cm deep in
    the held upper arm, without gravity, ends outside it (within the slop) and at rest."""
    joints = {"shoulder_lift": np.pi / 2, "elbow": -np.pi / 2, "wrist": 0.0}  # the upper arm along +x
    top = 0.2 + 0.025  # its top face
    crate = {"name": "crate", "shape": "box", "size": [0.06, 0.06, 0.06], "mass": 0.4,
             "position": [0.25, 0.0, top + 0.03 - 0.01]}
    world = World(arm_scene(joints=joints, bodies=[crate], gravity=(0, 0, 0), ground=False))
    world.report_contacts = True
    box = world.body_model.index("crate")
    run(world, 0.5)
    assert world.contacts.separation.min() > -1e-3, world.contacts.separation
    speed = np.linalg.norm(world.body_state.linear_momentum[box]) / 0.4
    spin = np.linalg.norm(world.body_state.angular_velocity(world.body_model)[box])
    assert speed < 1e-6 and spin < 1e-5, (speed, spin)
    assert world.body_state.position[box][2] > top + 0.03 - 1e-3  # it went up, out of the arm


@pytest.mark.parametrize("crates", [1, 2])
def test_crates_squeezed_between_a_link_and_a_shelf_are_pushed_out_of_both(crates):
    """Issue 35's one position loop (cgp_core.robots.coupled.relax_together): a 6 cm crate started 1 cm deep in
    the held upper arm, under a fixed shelf it touches (``crates`` = 2: a second crate on it, the shelf on that),
    without gravity.  The shelf holds the crates, so only the arm can make room.  With two position stages (the
    joint solver's for the link's contacts, the body solver's recovery for the others) the link's stage pushed the
    crate into the shelf (or the other crate) and the recovery pushed it back into the link, the heavy arm taking
    almost none of it: after 1–2 s the link contact stayed 5.4 mm deep and the shelf's 4.4 mm (one crate; two:
    the link's 4.8 mm, the crates' 4.6 mm).  In one loop every contact ends within the slop (0.5 mm; measured
    0.50 mm with one crate, at most 0.50 mm with two) — asserted with 0.1 mm to spare — and the crates at rest."""
    joints = {"shoulder_lift": np.pi / 2, "elbow": -np.pi / 2, "wrist": 0.0}  # the upper arm along +x
    z = 0.2 + 0.025 - 0.01  # the upper arm's top face, 1 cm into it
    bodies = []
    for i in range(crates):
        bodies.append({"name": f"crate{i}", "shape": "box", "size": [0.06, 0.06, 0.06], "mass": 0.4,
                       "position": [0.25, 0.0, z + 0.03]})
        z += 0.06
    bodies.append({"name": "shelf", "shape": "box", "size": [0.2, 0.2, 0.02], "fixed": True, "mass": 1.0,
                   "position": [0.25, 0.0, z + 0.01]})
    world = World(arm_scene(joints=joints, bodies=bodies, gravity=(0, 0, 0), ground=False))
    world.report_contacts = True
    links = world.robots.body_robot >= 0
    deepest = {}

    def check(w):
        if w.time < 1.0:
            return
        c = w.contacts
        for a, b, s in zip(c.body_a, c.body_b, c.separation):
            kind = "-".join(sorted("link" if links[i] else w.body_model.names[i] for i in (a, b)))
            deepest[kind] = min(deepest.get(kind, 0.0), float(s))

    run(world, 2.0, check)
    kinds = {"crate0-link", "crate0-shelf"} if crates == 1 else {"crate0-link", "crate0-crate1", "crate1-shelf"}
    assert set(deepest) == kinds, deepest
    assert min(deepest.values()) > -0.6e-3, deepest
    for i in range(crates):
        k = world.body_model.index(f"crate{i}")
        assert np.linalg.norm(world.body_state.linear_momentum[k]) / 0.4 < 1e-3


def test_two_arms_each_holding_a_crate_of_its_own_step_exactly_as_one_alone():
    """The robots whose links touch free bodies are solved as one system in the body solver's loop (block-diagonal
    M, their warm-start memories merged and split again): two arms 2 m apart, each with a crate resting on its
    upper arm, give the one arm's joint efforts and crate pose to the bit."""
    joints = {"shoulder_lift": np.pi / 2, "elbow": -np.pi / 2, "wrist": 0.0}

    def scene(count):
        robots = [{"name": f"arm{i}", "urdf": "arm.urdf", "position": [0, 2.0 * i, 0], "joints": joints}
                  for i in range(count)]
        crates = [{"name": f"crate{i}", "shape": "box", "size": [0.06, 0.06, 0.04], "mass": 0.4, "friction": 1.0,
                   "position": [0.25, 2.0 * i, 0.247]} for i in range(count)]
        return World(scene_from_dict({"world": {"substeps": 4}, "robots": robots, "bodies": crates}, "<test>"))

    two, one = scene(2), scene(1)
    for _ in range(60):
        two.step()
        one.step()
    assert np.array_equal(two.robots.joint_state("arm0")[3], one.robots.joint_state("arm0")[3])
    assert np.array_equal(two.body_state.position[two.body_model.index("crate0")],
                          one.body_state.position[one.body_model.index("crate0")])
    assert one.robots.joint_state("arm0")[3][1] < -1.0  # the crate's weight is on the shoulder


def test_robot_islands_are_the_connected_components_of_the_link_link_contacts():
    """The robot stage's islands (a union–find of its own, for speed) are scipy's connected components of the
    robots joined by link–link contacts: each robot's root its island's smallest robot, the islands ascending and
    ordered by their smallest robot; contacts with a non-link side (−1) or within one robot join nothing."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from cgp_core.robots.world import _islands

    rng = np.random.default_rng(7)
    for trial in range(300):
        count = int(rng.integers(1, 12))
        m = int(rng.integers(0, 3 * count))
        robot_a = rng.integers(-1, count, size=m)
        robot_b = rng.integers(-1, count, size=m)
        root, groups = _islands(count, robot_a, robot_b)
        between = (robot_a >= 0) & (robot_b >= 0) & (robot_a != robot_b)
        graph = coo_matrix((np.ones(between.sum()), (robot_a[between], robot_b[between])), shape=(count, count))
        _, label = connected_components(graph, directed=False)
        expected = [np.flatnonzero(label == c).tolist() for c in np.unique(label)]
        expected.sort(key=lambda g: g[0])
        assert groups == expected, trial
        assert root.tolist() == [min(g) for k in range(count) for g in expected if k in g], trial


def test_the_link_contact_rows_are_each_points_directions_times_its_links_point_jacobian():
    """The robot stage's contact rows (one compiled call for an island's points: joint_solver.link_contact_rows)
    against the definition written per point here: directions d = (n, t₁, t₂) from A to B; a link side adds
    ± d · J_point(q) in its robot's columns of the island, a free body side is the body's row ± [d, r × d] — for two
    arms in one island (the second's columns after the first's), points with a link on side A or B, against a
    crate, the ground and the other arm, to the bit."""
    from cgp_core.collision.contacts import ContactSet
    from cgp_core.robots import algorithms
    from cgp_core.solver.sequential_impulse import tangent_basis_scalar

    joints = {"shoulder_lift": np.pi / 2, "elbow": -np.pi / 2}
    world = World(scene_from_dict({
        "robots": [{"name": f"arm{i}", "urdf": "arm.urdf", "position": [0, 1.0 * i, 0], "joints": joints}
                   for i in range(2)],
        "bodies": [{"name": "crate", "shape": "box", "size": [0.06, 0.06, 0.04], "mass": 0.4,
                    "position": [0.25, 0.0, 0.247]}]}, "<test>"))
    world.step()
    robots, model, state = world.robots, world.body_model, world.body_state
    crate = model.index("crate")
    links = [int(b) for b in np.flatnonzero(robots.body_robot >= 0)]
    arm0 = [b for b in links if robots.body_robot[b] == 0]
    arm1 = [b for b in links if robots.body_robot[b] == 1]
    rng = np.random.default_rng(3)
    sides = [(arm0[2], crate), (crate, arm0[3]), (-1, arm1[2]), (arm1[3], -1), (arm0[-1], arm1[-1])]
    normal = rng.normal(size=(len(sides), 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    normal[2] = (0.0, 0.0, -1.0)  # the branch of the tangent basis for z < 0 too
    m = len(sides)
    contacts = ContactSet(np.array([a for a, _ in sides], np.intp), np.array([b for _, b in sides], np.intp),
                          normal, np.zeros(m), rng.normal(size=(m, 3)) * 0.3, np.arange(m, dtype=np.int64),
                          np.full(m, 0.5), np.zeros(m))
    n0 = robots.robots[0].model.n_dofs
    n = n0 + robots.robots[1].model.n_dofs
    rows = robots._contact_rows(contacts, model, state, {0: 0, 1: n0}, n)

    J = np.zeros((m, 3, n))
    body = np.full(m, -1)
    body_jacobian = np.zeros((m, 3, 6))
    for c, pair in enumerate(sides):
        t = tangent_basis_scalar(*normal[c])
        D = np.array([normal[c], t[:3], t[3:]])
        for side, sign in zip(pair, (-1.0, 1.0)):
            if side < 0:
                continue
            k = int(robots.body_robot[side])
            if k >= 0:
                r = robots.robots[k]
                rotation, position = robots._poses[k]
                Jp = algorithms.point_jacobian(r.kernel_arrays, rotation, position, int(robots.body_link[side]),
                                               contacts.point[c])
                start = (0, n0)[k]
                J[c, :, start:start + r.model.n_dofs] += sign * (D @ Jp)
            else:
                body[c] = side
                body_jacobian[c, :, :3] = sign * D
                body_jacobian[c, :, 3:] = np.cross(contacts.point[c] - state.position[side], sign * D)
    assert np.array_equal(rows.joint_jacobian, J)
    assert np.array_equal(rows.body, body) and body.tolist() == [crate, crate, -1, -1, -1]
    assert np.array_equal(rows.body_jacobian, body_jacobian)
    assert np.count_nonzero(J[4, :, :n0]) and np.count_nonzero(J[4, :, n0:])  # both arms' columns


def test_a_limp_arm_falls_onto_the_ground_and_rests_there():
    world = World(arm_scene(hold=False))
    run(world, 3.0)
    lowest = min(world.body_state.position[i][2] - world.body_model.half_extents[i].min()
                 for i, name in enumerate(world.body_model.names) if name.startswith("arm/"))
    assert lowest > -0.01
    _, _, qd, _ = world.robots.joint_state("arm")
    assert np.abs(qd).max() < 0.05, qd


def test_robot_entries_are_refused_by_name():
    with pytest.raises(SceneError, match=r"robots\[0\]\.joints\.knee: arm has no movable joint 'knee'"):
        arm_scene(joints={"knee": 0.1})
    with pytest.raises(SceneError, match=r"robots\[0\]\.joints\.elbow: 9 is outside the joint's limits"):
        arm_scene(joints={"elbow": 9.0})
    with pytest.raises(SceneError, match=r"robots\[0\]\.urdf: no robot file 'nope\.urdf'"):
        arm_scene(urdf="nope.urdf")
    with pytest.raises(SceneError, match=r"robots\[0\]\.colour: unknown key"):
        arm_scene(colour=[1, 0, 0, 1])


def test_links_move_by_their_joints_only_and_reset_restores_the_pose():
    world = World.from_scene("arm_teleop")
    with pytest.raises(EditError, match="arm/forearm is a link of robot arm"):
        world.delete("arm/forearm")
    with pytest.raises(EditError, match="arm/forearm is a link of robot arm"):
        world.set_body_state("arm/forearm", [0, 0, 1], [0, 0, 0, 1])
    start = positions(world)
    world.robots.command("arm", ["shoulder_pan"], position=[1.0])
    run(world, 1.0)
    assert positions(world)["shoulder_pan"] > 0.5
    world.reset()
    assert positions(world) == pytest.approx(start, abs=1e-12)
    run(world, 0.2)
    assert positions(world)["shoulder_pan"] == pytest.approx(0.0, abs=1e-3)  # the command went with the reset


def test_bad_joint_commands_are_named_and_the_rest_applies():
    world = World.from_scene("arm_teleop")
    problems = world.robots.command("arm", ["knee", "elbow", "finger_right_joint", "wrist"],
                                    position=[0.0, float("nan"), 0.01, 5.0])
    assert any("no movable joint 'knee'" in p for p in problems)
    assert any("elbow: position nan is not finite" in p for p in problems)
    assert any("finger_right_joint mimics finger_left_joint" in p for p in problems)
    assert any("wrist: position 5 clamped to its limits [-2, 2]" in p for p in problems)
    run(world, 1.0)
    assert positions(world)["wrist"] == pytest.approx(2.0, abs=2e-3)


def test_tf_reaches_every_link_at_the_forward_kinematics_poses():
    world = World.from_scene("arm_teleop")
    world.robots.command("arm", ["shoulder_pan", "elbow"], position=[0.7, 0.4])
    run(world, 0.5)
    edges = world.robots.transforms("arm")
    frames, R_fk, p_fk = world.robots.frame_poses("arm")
    assert sorted(child for _, child, *_ in edges) == sorted(frames)  # every URDF link, once
    from cgp_core.rotation import quat_to_matrix

    pose = {"world": (np.eye(3), np.zeros(3))}
    pending = list(edges)
    while pending:  # compose the tree from the world down
        for edge in list(pending):
            parent, child, q, t, _ = edge
            if parent in pose:
                Rp, tp = pose[parent]
                pose[child] = (Rp @ quat_to_matrix(q[None])[0], tp + Rp @ t)
                pending.remove(edge)
    for f, frame in enumerate(frames):
        assert np.allclose(pose[frame][0], R_fk[f], atol=1e-12) and np.allclose(pose[frame][1], p_fk[f], atol=1e-12)
    static = {child for _, child, _, _, s in edges if s}
    assert static == {"base_link", "tool"}  # the fixed root and the fixed tool frame


def test_a_robot_that_blows_up_is_put_back_and_the_world_goes_on():
    crate = {"name": "crate", "shape": "box", "size": [0.1, 0.1, 0.1], "mass": 0.3, "position": [-0.6, 0, 1.0]}
    world = World(arm_scene(bodies=[crate]))
    start = positions(world)
    world.robots.qd[1] = np.nan  # what a numerical blow-up leaves
    world.step()
    events = [e.text for e in world.take_events() if e.level == "error"]
    assert any("numerical blow-up of robot arm" in text for text in events), events
    assert positions(world) == pytest.approx(start, abs=1e-9)
    run(world, 0.5)
    assert np.isfinite(world.body_state.position).all()
    assert world.body_state.position[world.body_model.index("crate")][2] < 0.9  # it kept falling meanwhile
    assert max(abs(positions(world)[j] - start[j]) for j in start) < 1e-3  # held again


def test_a_copy_of_a_world_with_robots_steps_alike_and_is_commanded_alone():
    """The node's warm-up steps a deep copy of the world (cgp_sim_ros/ros/process.py): the robots' compiled-kernel
    lists do not copy as they are, so the copy builds them again; its drives are its own."""
    import copy

    world = World.from_scene("arm_teleop")
    for _ in range(3):
        world.step()
    twin = copy.deepcopy(world)
    for _ in range(5):
        world.step()
        twin.step()
    np.testing.assert_array_equal(twin.robots.q, world.robots.q)
    twin.robots.drives.target_position[0] += 0.5
    for _ in range(30):
        twin.step()
    assert twin.robots.q[0] == pytest.approx(0.5, abs=1e-3)
    assert world.robots.q[0] == pytest.approx(0.0, abs=1e-9)


ROBOT_LOADS = """
from cgp_core import World
from cgp_core.robots import coupled
from cgp_core.scene import scene_from_dict
from cgp_core.warmup import load_kernels_for
world = World(scene_from_dict({"robots": [{"name": "arm", "urdf": "arm.urdf"}], "bodies": BODIES}, "<test>"))
before = len(coupled.step_coupled.signatures)
load_kernels_for(world)
print(before, len(coupled.step_coupled.signatures))
"""


@pytest.mark.parametrize("bodies, loaded", [
    ([{"name": "crate", "shape": "box", "size": [0.1, 0.1, 0.1], "mass": 1.0, "position": [1.0, 0.0, 0.05]}], True),
    ([{"name": "wall", "shape": "box", "size": [0.1, 1.0, 1.0], "fixed": True, "position": [1.0, 0.0, 0.5]}], False)])
def test_the_robot_and_body_loop_is_loaded_before_the_first_tick_of_a_world_that_may_take_it(bodies, loaded):
    """load_kernels_for (the node's start-up): a world with a robot and a free body has the loop that solves them
    together loaded (the ``arm`` scene's first sub-step with a link on a body took 110-240 ms loading it, mid-run,
    through the node and in process); with only fixed bodies beside the robot that loop never runs and is not
    loaded.  In a fresh process: nothing loaded before."""
    import subprocess
    import sys
    from pathlib import Path

    from cgp_core.jit import JIT_DISABLED

    if JIT_DISABLED:
        pytest.skip("numba's kernels are loaded only when compiled")
    result = subprocess.run([sys.executable, "-c", f"BODIES = {bodies!r}\n" + ROBOT_LOADS],
                            cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    before, after = map(int, result.stdout.split())
    assert before == 0 and (after > 0) == loaded


SPAWN_LOADS = """
from cgp_core import World
from cgp_core.robots import coupled
from cgp_core.scene import scene_from_dict
from cgp_sim_ros.ros.process import ConvexKernels
robots = [{"name": "arm", "urdf": "arm.urdf"}] if ROBOT else []
wall = {"name": "wall", "shape": "box", "size": [0.1, 1.0, 1.0], "fixed": True, "position": [1.0, 0.0, 0.5]}
world = World(scene_from_dict({"robots": robots, "bodies": [wall]}, "<test>"))
kernels = ConvexKernels(world)
box = world.prepare_spawn({"body": {"shape": "box", "size": [0.1, 0.1, 0.1], "mass": 1.0, "fixed": FIXED}},
                          name="box", taken=set(world.entity_names()), position=(1.0, 0.5, 0.05))
waiting = kernels.before_adding(box, world)
if waiting is not None:
    waiting.result(timeout=300)
print(waiting is not None, len(coupled.step_coupled.signatures))
"""


@pytest.mark.parametrize("robot, fixed, waits", [(True, False, True), (True, True, False), (False, False, False)])
def test_a_free_body_spawned_into_a_robot_world_waits_for_the_robot_and_body_loop(robot, fixed, waits):
    """The node's spawn path (process.ConvexKernels.before_adding): the first free body spawned into a world with
    a robot and no free body yet has the loop that solves them together loaded first, off the tick's thread (its
    first contact with a link would load it mid-run: 110-240 ms); a fixed body, or a world without robots, does
    not wait for it.  In a fresh process."""
    import subprocess
    import sys
    from pathlib import Path

    from cgp_core.jit import JIT_DISABLED

    if JIT_DISABLED:
        pytest.skip("numba's kernels are loaded only when compiled")
    result = subprocess.run([sys.executable, "-c", f"ROBOT, FIXED = {robot}, {fixed}\n" + SPAWN_LOADS],
                            cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    waited, loaded = result.stdout.split()
    assert (waited == "True") == waits and (int(loaded) > 0) == waits
