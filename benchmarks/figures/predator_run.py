#!/usr/bin/env python3
"""The fountain effect: a predator pushed through a school by a wrench command (the built-in ``predator``
scene), measured and drawn.

:func:`attack` is the experiment (``tests/test_predators.py`` runs the very same function and asserts on its
record): the scene's school swims for ``warm_up`` seconds; the predator is then placed ``start_distance``
behind the school's centroid on its line of travel and pushed forward by one wrench command (force m·V for
1 s: it reaches V = ``speed``, twice the fish's speed, and coasts through the school); the run goes on for
``duration`` seconds.  Every tick it records the school's order parameters (``cgp_core.boids.order``), the
smallest clearance between a fish and the predator's surface, and how the fish beside the predator surround
its path (:func:`surround`: 1 when they are spread evenly around it, as when the school splits and flows past
on every side; 0 when they are all on one side, as when the school merely dodges).

Writes ``benchmarks/figures/predator_fountain.png``: the school seen from above (its plane of travel) before,
during and after the attack, and the time series of polarization, radius of gyration, clearance and
surround.  Run: ``make figures`` (or ``.venv/bin/python benchmarks/figures/predator_run.py``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from cgp_core import World  # noqa: E402
from cgp_core.boids.order import flock_order  # noqa: E402

FIGURE = ROOT / "benchmarks" / "figures" / "predator_fountain.png"
MARGIN = 1.0  # m: no fish may come closer than this to the predator's surface


@dataclass
class AttackRecord:
    """Time series of one attack (one entry per tick after the push; shapes (T,) unless said)."""

    time: list = field(default_factory=list)             # s since the push
    polarization: list = field(default_factory=list)
    radius_of_gyration: list = field(default_factory=list)
    nearest_neighbor: list = field(default_factory=list)
    clearance: list = field(default_factory=list)        # min over fish of |x − x_p| − R [m]
    surround: list = field(default_factory=list)         # see surround(); NaN when fewer than 5 fish beside it
    beside: list = field(default_factory=list)           # fish in the slab |along| < SLAB around the predator
    along: list = field(default_factory=list)            # (centroid − predator) · û [m]: > 0 ahead of it
    snapshots: dict = field(default_factory=dict)        # name -> (positions (N, 3), predator (3,))
    before: object = None                                # FlockOrder at the push
    direction: np.ndarray | None = None                  # û, the predator's line of motion
    radius: float = 0.0                                  # the predator's bounding radius R


SLAB = 3.0  # m: "beside the predator" = within this distance of it along its path


def surround(positions: np.ndarray, predator: np.ndarray, direction: np.ndarray) -> tuple[float, int]:
    """``(1 − |mean of the fish's unit sideways offsets from the path|, fish counted)`` over the fish within
    SLAB of the predator along its path: ≈ 1 when they surround the path, 0 when all are on one side."""
    offset = positions - predator
    along = offset @ direction
    lateral = offset - np.outer(along, direction)
    length = np.linalg.norm(lateral, axis=1)
    beside = (np.abs(along) < SLAB) & (length > 1e-9)
    count = int(np.count_nonzero(beside))
    if count < 5:
        return float("nan"), count
    unit = lateral[beside] / length[beside, None]
    return float(1.0 - np.linalg.norm(unit.mean(axis=0))), count


def attack(scene: str = "predator", *, dt: float = 1.0 / 60.0, warm_up: float = 15.0, start_distance: float = 20.0,
           speed: float = 6.0, duration: float = 14.0, seed: int | None = None) -> AttackRecord:
    world = World.from_scene(scene, dt=dt, seed=seed)
    school = world.flocks[0]
    shark = int(np.flatnonzero(world.body_model.predator)[0])
    for _ in range(round(warm_up / dt)):
        world.step()
    record = AttackRecord()
    record.before = flock_order(school.positions, school.velocities)
    u = school.velocities.mean(axis=0)
    u /= np.linalg.norm(u)
    record.direction = u
    record.radius = float(world.body_model.bounding_radius()[shark])
    # place the predator on the school's line of travel, behind it, at rest; one wrench command pushes it
    world.body_state.position[shark] = record.before.centroid - start_distance * u
    world.body_state.linear_momentum[shark] = 0.0
    mass = float(world.body_model.mass[shark])
    world.apply_wrench(world.body_model.names[shark], force=mass * speed * u, duration=1.0)
    record.snapshots["before"] = (school.positions.copy(), world.body_state.position[shark].copy())
    passed = False
    for tick in range(round(duration / dt)):
        world.step()
        x_p = world.body_state.position[shark]
        order = flock_order(school.positions, school.velocities)
        distance = np.linalg.norm(school.positions - x_p, axis=1)
        record.time.append((tick + 1) * dt)
        record.polarization.append(order.polarization)
        record.radius_of_gyration.append(order.radius_of_gyration)
        record.nearest_neighbor.append(order.mean_nearest_neighbor_distance)
        record.clearance.append(float(distance.min() - record.radius))
        around, beside = surround(school.positions, x_p, u)
        record.surround.append(around)
        record.beside.append(beside)
        record.along.append(float((order.centroid - x_p) @ u))
        if not passed and record.along[-1] <= 0.0:
            passed = True
            record.snapshots["during"] = (school.positions.copy(), x_p.copy())
    record.snapshots["after"] = (school.positions.copy(), world.body_state.position[shark].copy())
    return record


def plot(record: AttackRecord, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    u = record.direction
    side = np.cross(u, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    fig = plt.figure(figsize=(12, 7.5), constrained_layout=True)
    grid = fig.add_gridspec(2, 4)
    t = np.array(record.time)
    passing = t[int(np.argmax(np.array(record.along) <= 0.0))]
    for column, (name, title) in enumerate((("before", "at the push"), ("during", f"passing (t = {passing:.1f} s)"),
                                            ("after", f"after (t = {t[-1]:.0f} s)"))):
        axis = fig.add_subplot(grid[0, column])
        positions, predator = record.snapshots[name]
        centre = positions.mean(axis=0)
        rel = positions - centre
        axis.scatter(rel @ u, rel @ side, s=6, color="#1f4e79")
        p = predator - centre
        axis.add_patch(plt.Circle((p @ u, p @ side), record.radius, color="#c0392b"))
        axis.add_patch(plt.Circle((p @ u, p @ side), record.radius + MARGIN, fill=False, ls="--", color="#c0392b"))
        axis.annotate("", xy=(p @ u + 3.0, p @ side), xytext=(p @ u + record.radius, p @ side),
                      arrowprops=dict(arrowstyle="->", color="#c0392b"))
        axis.set_aspect("equal")
        axis.set_xlim(-14, 14)
        axis.set_ylim(-12, 12)
        axis.set_title(title, fontsize=9)
        axis.set_xlabel("along the predator's path [m]")
        if column == 0:
            axis.set_ylabel("sideways [m] (school centroid at 0)")
    text = fig.add_subplot(grid[0, 3])
    text.axis("off")
    text.text(0.0, 0.95, "Fountain effect, built-in scene `predator`\n\n"
              f"150 fish (Couzin zonal model, s = 3 m/s),\nfright radius 7 m; predator R = {record.radius:g} m\n"
              f"pushed by one wrench to 6 m/s\n\n"
              f"closest fish: {min(record.clearance):.2f} m from its surface\n(margin {MARGIN:g} m)\n"
              f"p: {record.before.polarization:.2f} before, {min(record.polarization):.2f} at worst,\n"
              f"   {record.polarization[-1]:.2f} at the end\n"
              f"R_g: {record.before.radius_of_gyration:.1f} m before, {max(record.radius_of_gyration):.1f} m at "
              f"most,\n   {record.radius_of_gyration[-1]:.1f} m at the end", va="top", fontsize=9, family="monospace")
    series = ((record.polarization, "polarization p", (0, 1.05)),
              (record.radius_of_gyration, "radius of gyration [m]", None),
              (record.clearance, "closest fish to its surface [m]", None),
              (record.surround, f"surround (fish within {SLAB:g} m along)", (0, 1.05)))
    for column, (values, label, limits) in enumerate(series):
        axis = fig.add_subplot(grid[1, column])
        axis.plot(t, values, color="#1f4e79")
        axis.axvline(passing, color="#c0392b", lw=0.8, ls=":")
        if column == 2:
            axis.axhline(MARGIN, color="#c0392b", lw=0.8, ls="--")
            axis.set_yscale("log")
        if limits:
            axis.set_ylim(*limits)
        axis.set_xlabel("time since the push [s]")
        axis.set_title(label, fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> int:
    record = attack()
    print(f"closest fish {min(record.clearance):.2f} m from the predator's surface; polarization "
          f"{record.before.polarization:.2f} -> min {min(record.polarization):.2f} -> {record.polarization[-1]:.2f}; "
          f"radius of gyration {record.before.radius_of_gyration:.1f} -> max {max(record.radius_of_gyration):.1f} -> "
          f"{record.radius_of_gyration[-1]:.1f} m; surround at the pass {np.nanmax(record.surround):.2f}")
    plot(record, FIGURE)
    print(f"wrote {FIGURE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
