"""Issue 37: a big world's contact sweeps by two regions of the contact graph, the two on numba's thread pool, then
their border (sequential_impulse.solve_contacts, _split_regions, _sweep_regions): the two regions share no moving
body; the same bits on one thread and on two, compiled and as plain Python; below the split's threshold the same
bits through the three calls big worlds take as through solve_step (whose plain order the regions change above it;
also through impact sweeps); and the physics of the resting pile (its weight carried, no sinking)."""

from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest
from test_jit_parity import RECORD_BODIES, run

from cgp_core import World, parse_scene
from cgp_core.jit import JIT_DISABLED
from cgp_core.solver import sequential_impulse as si

G_ACCEL = 9.81
REPO = Path(__file__).resolve().parents[1]


def pile_scene(layers: int = 3, side: int = 10) -> str:
    """layers × side² spheres (r 0.1, 1 kg) stacked in a square box of fixed walls, touching: a contact graph of
    more than SPLIT_MIN_CONTACTS contacts from the first tick."""
    bodies = [f"  - {{name: wall_{k}, shape: box, size: {size}, position: {pos}, fixed: true}}" for k, (size, pos) in
              enumerate((([0.2, 2.4, 1], [-0.1, 1.0, 0.5]), ([0.2, 2.4, 1], [2.1, 1.0, 0.5]),
                         ([2.4, 0.2, 1], [1.0, -0.1, 0.5]), ([2.4, 0.2, 1], [1.0, 2.1, 0.5])))]
    for z in range(layers):
        shift = 0.1 if z % 2 else 0.0
        for i in range(side - (1 if shift else 0)):
            for j in range(side - (1 if shift else 0)):
                bodies.append(f"  - {{name: s{z}_{i}_{j}, shape: sphere, radius: 0.1, mass: 1, "
                              f"position: [{0.1 + 0.2 * i + shift}, {0.1 + 0.2 * j + shift}, {0.1 + 0.15 * z}]}}")
    return "world: {sleep: false, substeps: 4}\nbodies:\n" + "\n".join(bodies) + "\n"


def box_pile_scene(layers: int = 5, side: int = 8) -> str:
    """layers × side² boxes (0.2 m, 1 kg) stacked face on face, touching from the first tick: manifolds of four
    points (the LCP block path), more than SPLIT_MIN_CONTACTS points (a sphere pile has one-point manifolds
    only).  Each layer is shifted 2 cm so that no two faces coincide exactly."""
    bodies = []
    for z in range(layers):
        for i in range(side):
            for j in range(side):
                bodies.append(f"  - {{name: b{z}_{i}_{j}, shape: box, size: [0.2, 0.2, 0.2], mass: 1, "
                              f"position: [{0.25 * i + 0.02 * (z % 2)}, {0.25 * j}, {0.1 + 0.2 * z}]}}")
    return "world: {sleep: false, substeps: 4}\nbodies:\n" + "\n".join(bodies) + "\n"


def step_pile(threads: int, ticks: int, scene=pile_scene) -> np.ndarray:
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        world = World(parse_scene(scene()))
        out = []
        for _ in range(ticks):
            world.step()
            assert world.solver.stats["contacts"] >= si.SPLIT_MIN_CONTACTS
            s = world.body_state
            out.append(np.concatenate((s.position, s.orientation, s.linear_momentum, s.angular_momentum), axis=1))
        return np.array(out)
    finally:
        numba.set_num_threads(previous)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs numba's pool of 2 threads or more")
def test_the_same_bits_on_one_thread_and_on_two():
    one = step_pile(1, 30)
    two = step_pile(2, 30)
    assert np.abs(one[-1, :, 2] - one[0, :, 2]).max() > 1e-3  # the pile moved (the spheres settled into it)
    np.testing.assert_array_equal(one, two)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs numba's pool of 2 threads or more")
def test_a_box_pile_steps_to_the_same_bits_on_one_thread_and_on_two_and_stays_stacked():
    """Four-point manifolds through the two regions.  (Inlined into the function compiled with prange on, the
    manifold update had read garbage: this pile flew apart within 2 ticks, differently on each run.)"""
    one = step_pile(1, 20, box_pile_scene)
    two = step_pile(2, 20, box_pile_scene)
    np.testing.assert_array_equal(one, two)
    # resting boxes stay where they were stacked: none moved more than a millimetre in height
    assert np.abs(one[-1, :, 2] - one[0, :, 2]).max() < 1e-3


@pytest.mark.parametrize("scene, split", [(pile_scene, True), (lambda: box_pile_scene(layers=1, side=7), False)],
                         ids=["split", "plain"])
def test_the_three_calls_of_a_big_world_keep_solve_steps_bits_below_the_split(scene, split, monkeypatch):
    """``plain``: 196 contacts in 49 four-point manifolds — too few for the regions: the world steps them through
    solve_step (moving_contacts: not the three calls' boxing), and the three calls would give the same bits (one
    run in the plain order).  ``split``: the three calls, in the regions' order, not solve_step's (which keeps the
    plain order for every world): other bits."""
    world = World(parse_scene(scene()))
    for _ in range(10):
        world.step()
    seen = {"three calls": 0}
    solve_velocities, by_regions = world.solver.solve_velocities, si._solve_step_by_regions

    def capture(model, state, contacts, h, **kw):
        seen["args"] = (model, state, contacts, h, kw)
        return solve_velocities(model, state, contacts, h, **kw)

    def counted(*args):
        seen["three calls"] += 1
        return by_regions(*args)

    world.solver.solve_velocities = capture
    monkeypatch.setattr(si, "_solve_step_by_regions", counted)
    world.step()
    assert seen["three calls"] == (world.substeps if split else 0)
    monkeypatch.setattr(si, "_solve_step_by_regions", by_regions)
    model, state, contacts, h, kw = seen["args"]
    solver = world.solver
    settings = solver._settings_for(float(h))
    results = []
    for solve in (si.solve_step, si._solve_step_by_regions):
        P, L = state.linear_momentum.copy(), state.angular_momentum.copy()
        bodies = (model.inv_mass, model.inv_mass > 0.0, np.ascontiguousarray(state.inv_inertia_world(model)),
                  state.position, P, L, state.force, state.torque)
        handover, memory, _ = solve(tuple(contacts), bodies, tuple(solver._memory), settings, si._NO_TALLY, False,
                                    np.zeros(len(si.STAGES)))
        results.append((P, L, handover.rows.J, memory.normal, memory.friction))
    moving = si.moving_contacts(contacts, model.inv_mass > 0.0)
    assert moving == len(handover.a)  # the contacts prepare_contacts kept
    assert (moving >= si.SPLIT_MIN_CONTACTS) == split
    same = all(np.array_equal(x, y) for x, y in zip(*results))
    assert same != split, "the split changed nothing" if split else "the plain order through the three calls differs"


def test_the_two_regions_share_no_moving_body():
    rng = np.random.default_rng(38)
    for _ in range(20):
        n = int(rng.integers(4, 80))
        G = int(rng.integers(2, 300))
        dynamic = np.append(rng.random(n) < 0.8, False)  # row n: the ground
        position = np.vstack((rng.normal(size=(n, 3)), np.zeros((1, 3))))
        a = rng.integers(0, n + 1, size=G)
        b = (a + rng.integers(1, n + 1, size=G)) % (n + 1)
        keep = dynamic[a] | dynamic[b]  # (a manifold moves something)
        a, b = a[keep], b[keep]
        points = rng.integers(1, 5, size=len(a))
        group_start = np.concatenate(([0], np.cumsum(points))).astype(np.int64)
        manifolds = si.Manifolds(np.repeat(a, points).astype(np.int64), np.repeat(b, points).astype(np.int64),
                                 group_start, *([None] * 7))
        bodies = si.SolverBodies(None, None, position, dynamic, None, None)
        split = getattr(si._split_regions, "py_func", si._split_regions)  # (plain Python under NUMBA_DISABLE_JIT)
        order, start, _, _ = split(manifolds, bodies, True)
        assert sorted(order.tolist()) == list(range(len(a))) and start[-1] == len(a)
        sides = []
        for r in range(2):
            members = order[start[r]:start[r + 1]]
            assert (np.diff(members) > 0).all()
            sides.append({x for g in members for x in (a[g], b[g]) if dynamic[x]})
        assert not sides[0] & sides[1]


PILE_SCRIPT = r"""
import sys
import numpy as np
from cgp_core.jit import JIT_DISABLED
from cgp_core import World, parse_scene

assert JIT_DISABLED == (sys.argv[2] == "plain"), "NUMBA_DISABLE_JIT did not reach the child"
w = World(parse_scene(pile_scene(layers=1, side=17)))
"""


@pytest.mark.parametrize("scene, make", [(pile_scene, "pile_scene(layers=1, side=17)"),
                                         (box_pile_scene, "box_pile_scene(layers=4, side=8)")],
                         ids=["spheres", "boxes"])
def test_the_split_sweeps_give_the_same_bits_compiled_and_as_plain_python(tmp_path, scene, make):
    ticks = 2
    script = PILE_SCRIPT.replace("pile_scene(layers=1, side=17)", make).replace(
        "w = World(", inspect.getsource(scene) + "\nw = World(") + RECORD_BODIES
    compiled = run(tmp_path, "compiled", ticks, script)
    plain = run(tmp_path, "plain", ticks, script)
    np.testing.assert_array_equal(compiled, plain)


def test_a_split_pile_carries_its_weight_and_does_not_sink():
    """Resting spheres: the contact forces on them (the contact report) add up to their weight — the spheres'
    forces on each other cancel, what is left is the ground's and the walls' — and no contact ends deeper than the
    solver's penetration slop."""
    world = World(parse_scene(pile_scene()))
    for _ in range(150):
        world.step()
    world.report_contacts = True
    world.step()
    report = world.contacts
    spheres = np.array([name.startswith("s") for name in world.body_model.names])
    assert world.solver.stats["contacts"] >= si.SPLIT_MIN_CONTACTS
    assert np.linalg.norm(world.body_state.linear_momentum, axis=1).max() < 0.02  # at rest (1 kg spheres)
    on_spheres = spheres[report.body]
    assert report.force[on_spheres, 2].sum() == pytest.approx(spheres.sum() * G_ACCEL, rel=1e-3)
    assert world.solver.stats["max_penetration"] < world.solver.settings.penetration_slop + 1e-4


def impact_scene(side: int) -> str:
    """side² boxes (0.2 m, 1 kg, restitution 0.5) resting on the ground and as many falling onto them face on face
    at 2 m/s from 4 cm above: four-point manifolds with bouncing points (the impact sweeps) in the second tick."""
    bodies = []
    for z, (height, speed) in enumerate(((0.1, 0.0), (0.34, -2.0))):
        for i in range(side):
            for j in range(side):
                bodies.append(f"  - {{name: b{z}_{i}_{j}, shape: box, size: [0.2, 0.2, 0.2], mass: 1, "
                              f"restitution: 0.5, position: [{0.25 * i + 0.02 * z}, {0.25 * j}, {height}], "
                              f"linear_velocity: [0, 0, {speed}]}}")
    return "world: {sleep: false, substeps: 4}\nbodies:\n" + "\n".join(bodies) + "\n"


def step_impacts(side: int, ticks: int) -> tuple[np.ndarray, list]:
    world = World(parse_scene(impact_scene(side)))
    out, stats = [], []
    for _ in range(ticks):
        world.step()
        s = world.body_state
        out.append(np.concatenate((s.position, s.orientation, s.linear_momentum, s.angular_momentum), axis=1))
        stats.append(dict(world.solver.stats))
    return np.array(out), stats


@pytest.mark.parametrize("side, split", [(5, False), (17, True)], ids=["plain", "split"])
def test_impact_sweeps_through_the_three_calls(monkeypatch, side, split):
    """Bouncing four-point manifolds: their impact sweeps (the sweeps over the manifolds ``impact`` marks) through
    the three calls.  ``plain``: 50 boxes, fewer than SPLIT_MIN_CONTACTS contacts, made to take the three calls
    (Python's threshold set to 1): too few contacts for the regions (the plain order through _solve_region) — the
    same bits as solve_step.  ``split``: the 289 boxes on the ground alone make more than SPLIT_MIN_CONTACTS
    contacts, the regions: the same bits on one thread and on two.  (Without the impact sweeps the bits differ:
    they ran.)"""
    regions_from = si.SPLIT_MIN_CONTACTS  # (the compiled sweeps' threshold)
    calls = []
    by_regions = si._solve_step_by_regions
    monkeypatch.setattr(si, "_solve_step_by_regions", lambda *args: calls.append(1) or by_regions(*args))
    if not split:
        monkeypatch.setattr(si, "SPLIT_MIN_CONTACTS", 1)  # Python's choice only: the three calls for every sub-step
    three, stats = step_impacts(side, 4)
    assert calls  # (the three calls ran)
    assert (max(s["contacts"] for s in stats) >= regions_from) == split
    assert np.abs(three[-1, side * side:, 9] - three[0, side * side:, 9]).max() > 1.0  # the falling boxes bounced
    if split:
        if numba.config.NUMBA_NUM_THREADS < 2:
            pytest.skip("needs numba's pool of 2 threads or more")
        previous = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            one, _ = step_impacts(side, 4)
        finally:
            numba.set_num_threads(previous)
    else:
        monkeypatch.setattr(si, "SPLIT_MIN_CONTACTS", regions_from)  # solve_step
        one, _ = step_impacts(side, 4)
    np.testing.assert_array_equal(three, one)
    monkeypatch.setattr(si, "IMPACT_SWEEPS", 0)
    without, _ = step_impacts(side, 4)
    assert not np.array_equal(three, without)


LOADS = """
from cgp_core import World, parse_scene
from cgp_core.solver import sequential_impulse as si
from cgp_core.warmup import load_kernels_for
bodies = "".join(f"  - {{name: s{i}, shape: sphere, radius: 0.1, position: [{0.3 * i}, 0, 1]}}\\n" for i in range(N))
world = World(parse_scene("world: {sleep: false}\\nbodies:\\n" + bodies))
before = len(si.solve_sweeps_by_regions.signatures)
load_kernels_for(world)
print(before, len(si.solve_sweeps_by_regions.signatures))
"""


@pytest.mark.skipif(JIT_DISABLED, reason="numba's kernels are loaded only when compiled")
@pytest.mark.parametrize("bodies, loaded", [(70, True), (10, False)])
def test_the_big_worlds_path_is_loaded_before_the_first_tick_of_a_world_that_may_take_it(bodies, loaded):
    """load_kernels_for (the node's start-up): a world of 70 movable bodies (4 contacts each could make
    SPLIT_MIN_CONTACTS) has the three calls' parallel kernel loaded (a 115 ms sub-step when the 100-hull pile loaded
    it itself, mid-run); one of 10 does not pay for it.  In a fresh process: nothing loaded before."""
    result = subprocess.run([sys.executable, "-c", f"N = {bodies}\n" + LOADS], cwd=REPO, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    before, after = map(int, result.stdout.split())
    assert before == 0 and (after > 0) == loaded
