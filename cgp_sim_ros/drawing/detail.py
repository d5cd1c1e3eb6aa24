"""Level of detail for big flocks: how the node draws fish, how often it redraws them, and how often it records
the flocks' poses — one explicit choice, made at start-up (and again when ``rate_hz``, ``fish_detail`` or
``markers_every`` change), logged, put on ``~/events`` and into the bag's metadata.  Never a silent drop.

Why: the marker is a view, the PoseArray is the data.  A fish is drawn with 30 vertices (24 bytes each); at
15,000 fish that is 10.8 MB per marker array, 650 MB per second at 60 Hz — more than a viewer can draw or a
disk should take, and serializing and publishing it alone would cost the tick its budget.  The PoseArray of
the same flock is 0.84 MB (50 MB/s at 60 Hz).  So for big flocks the node draws fewer triangles per fish,
publishes the markers less often, and records the big PoseArrays at a lower rate in the bag (subscribers
still get every tick).  Small flocks — the default scene's 300 fish — keep the full fish on every tick.

Budgets (bytes per simulated second, at the tick rate; what the choices below keep to):

- :data:`MARKER_BYTES_PER_S` (32 MB/s of marker payload, ~18 MB/s in the bag: lz4 on the rounded vertices);
- :data:`BAG_POSES_BYTES_PER_S` (32 MB/s of flock PoseArrays in the bag).

With the bodies, clock and odometry that keeps a recording under ~45 MB per simulated second (issue 12's
limit: 60) for any flock size.

Rules, for the parameters' automatic values (``fish_detail: auto``, ``markers_every: 0``,
``bag_flock_poses_every: 0``):

1. a fish flock is drawn ``full`` (10 triangles per fish) if all flocks' markers at full detail fit the
   marker budget on every tick; otherwise ``low`` (3 triangles: the full fish's outline seen from above and
   its tail fin, ``shapes.py``);
2. each flock's marker is redrawn every N-th tick, the smallest N that fits the marker budget — in N parts,
   one part per tick (``ros/messages.py``), so that every tick carries the same bytes: the whole flock every
   N-th tick was a burst that the bag writer's compression then spent the next tick's second core on (the
   15k-fish flock step took 14 ms on that tick instead of 8.5);
3. in the bag, ``~/flocks/<flock>/poses`` is recorded every M-th tick, the smallest M that fits the poses
   budget (all flocks together; every message is still published).

The bodies have a budget of their own, :data:`BODY_MARKER_BYTES_PER_S` (issue 38: 300 convex bodies with
1,000-vertex hulls made ``~/markers`` 43 MB per tick, and the node ran at 13.6 Hz):

4. hulls (convex bodies, compound parts) are drawn ``full`` (their triangles) if every body's markers at full
   detail fit the body budget on every tick; otherwise ``low``: the hull of their extreme vertices in 26
   directions, at most 48 triangles (:mod:`cgp_sim_ros.drawing.bodies`);
5. the bodies' markers are redrawn every B-th tick, the smallest B that fits the body budget — in B parts of
   about equal bytes (consecutive bodies), one part per tick, as the flocks' are.

Static meshes are not on ``~/markers`` at all: they go on ``~/static_markers``, latched (transient local, as
``/tf_static``), once when they change, each with at most
:data:`~cgp_sim_ros.drawing.bodies.STATIC_MESH_TRIANGLES` triangles.  ``~/contacts`` (and the contact markers)
carry at most :data:`~cgp_sim_ros.interface.MAX_CONTACTS_PER_MESSAGE` contacts, the strongest.

A parameter set to a value overrides its rule; the others still follow theirs.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

from ..interface import FISH_DETAIL_CHOICES
from .shapes import FISH_DETAILS

#: marker payload per simulated second the automatic choices keep to [bytes]
MARKER_BYTES_PER_S = 32e6
#: flock PoseArray payload per simulated second the bag keeps to [bytes]
BAG_POSES_BYTES_PER_S = 32e6
#: body marker payload per simulated second the automatic choices keep to [bytes] (rules 4 and 5)
BODY_MARKER_BYTES_PER_S = 16e6

_POINT_BYTES = 24  # geometry_msgs/Point: 3 float64
_POSE_BYTES = 56  # geometry_msgs/Pose: 7 float64


@dataclass(frozen=True)
class DetailPlan:
    """What the node draws and records.

    fish_detail:        flock name → ``"full"`` | ``"low"`` (fish flocks only).
    markers_every:      each flock's marker redrawn every N ticks, in N parts, one per tick (``~/markers`` is
                        published and recorded on every tick).
    flock_poses_every:  ``~/flocks/<flock>/poses`` recorded in the bag on every M-th tick (published every tick).
    marker_bytes:       payload of one marker array's flock markers [bytes] (at the chosen detail).
    pose_bytes:         payload of one tick's flock PoseArrays [bytes].
    rate_hz:            the tick rate the plan was made for.
    lines:              the choices in words, with their reasons (what the node logs).
    hull_detail:        ``"full"`` | ``"low"``: how hulls are drawn (rule 4).
    body_markers_every: the bodies' markers redrawn every B ticks, in B parts (rule 5).
    body_marker_bytes:  payload of every body's markers drawn once, at the chosen detail [bytes].
    """

    fish_detail: dict
    markers_every: int
    flock_poses_every: int
    marker_bytes: int
    pose_bytes: int
    rate_hz: float
    lines: list = field(default_factory=list)
    hull_detail: str = "full"
    body_markers_every: int = 1
    body_marker_bytes: int = 0

    def custom_data(self, flock_topics: dict[str, str], marker_topic: str) -> dict[str, str]:
        """The plan for the bag's ``custom_data`` (str → str): per recorded topic that is not in the bag on
        every tick, every how many ticks it is; every how many ticks each flock's marker is redrawn (in that
        many parts, ids 0 … N−1, one per tick); the fish drawing per flock."""
        decimated = {}
        if self.flock_poses_every > 1:
            decimated.update({topic: self.flock_poses_every for topic in flock_topics.values()})
        return {
            "cgp_sim.rate_hz": f"{self.rate_hz:g}",
            "cgp_sim.recorded_every_n_ticks": json.dumps(decimated, sort_keys=True),
            "cgp_sim.flock_markers_redrawn_every_n_ticks": json.dumps(
                {marker_topic: self.markers_every}, sort_keys=True),
            "cgp_sim.fish_detail": json.dumps(self.fish_detail, sort_keys=True),
            "cgp_sim.hull_detail": self.hull_detail,
            "cgp_sim.body_markers_redrawn_every_n_ticks": str(self.body_markers_every),
            "cgp_sim.level_of_detail": " ".join(self.lines),
        }

    def event(self) -> dict:
        """The plan as an ``~/events`` line."""
        return {"event": "level_of_detail", "fish_detail": self.fish_detail, "markers_every": self.markers_every,
                "bag_flock_poses_every": self.flock_poses_every, "hull_detail": self.hull_detail,
                "body_markers_every": self.body_markers_every, "rate_hz": self.rate_hz}

    def same_choices(self, other: DetailPlan) -> bool:
        """Whether ``other`` chooses the same (the payloads and words aside)."""
        return (self.fish_detail, self.markers_every, self.flock_poses_every, self.rate_hz, self.hull_detail,
                self.body_markers_every) == (other.fish_detail, other.markers_every, other.flock_poses_every,
                                             other.rate_hz, other.hull_detail, other.body_markers_every)


def _every(payload_bytes: float, rate_hz: float, budget: float) -> int:
    """The smallest N >= 1 with payload · rate / N <= budget."""
    return max(1, math.ceil(payload_bytes * rate_hz / budget - 1e-9))


def _megabytes(value: float) -> str:
    return f"{value / 1e6:.1f} MB" if value >= 1e6 else f"{value / 1e3:.0f} kB"


def _per_tick(every: int, rate_hz: float) -> str:
    return "every tick" if every == 1 else f"every {every} ticks ({rate_hz / every:.3g} Hz)"


def plan(flocks, rate_hz: float, fish_detail: str = "auto", markers_every: int = 0,
         flock_poses_every: int = 0, body_bytes: tuple[int, int] = (0, 0)) -> DetailPlan:
    """The level of detail for ``flocks`` (their :class:`~cgp_core.boids.FlockParams`) and bodies whose markers,
    all drawn once, are ``body_bytes`` = (at full hull detail, at low) bytes, at ``rate_hz``; the parameters as
    the node has them (``"auto"`` / 0 = follow the rules of the module docstring)."""
    if fish_detail not in FISH_DETAIL_CHOICES:
        raise ValueError(f"fish_detail must be one of {', '.join(FISH_DETAIL_CHOICES)}, got {fish_detail!r}")
    fish = [p for p in flocks if p.model == "fish"]
    spheres = sum(p.count for p in flocks if p.model != "fish") * _POINT_BYTES

    def marker_bytes(detail: str) -> int:
        return spheres + sum(p.count * len(FISH_DETAILS[detail]) for p in fish) * _POINT_BYTES

    lines = []
    if fish_detail == "auto":
        full = marker_bytes("full")
        detail = "full" if full * rate_hz <= MARKER_BYTES_PER_S else "low"
        if fish:
            names = ", ".join(f"{p.name} ({p.count:,} fish)" for p in fish)
            if detail == "full":
                lines.append(f"fish drawn in full ({len(FISH_DETAILS['full']) // 3} triangles each) for {names}: "
                             f"{_megabytes(full)} per marker array fits {_megabytes(MARKER_BYTES_PER_S)}/s at "
                             f"{rate_hz:g} Hz.")
            else:
                lines.append(f"fish drawn with low detail ({len(FISH_DETAILS['low']) // 3} triangles each: the "
                             f"outline seen from above and the tail fin) for {names}: in full they would be "
                             f"{_megabytes(full)} per marker array, {_megabytes(full * rate_hz)}/s at "
                             f"{rate_hz:g} Hz, over the {_megabytes(MARKER_BYTES_PER_S)}/s marker budget.")
    else:
        detail = fish_detail
        if fish:
            lines.append(f"fish drawn '{detail}' (fish_detail parameter).")
    payload = marker_bytes(detail)

    def redrawn(every: int) -> str:
        return ("every tick" if every == 1 else
                f"every {every} ticks ({rate_hz / every:.3g} Hz), in {every} parts, one per tick")

    if markers_every == 0 and not flocks:
        markers_every = 1
        lines.append("no flocks: ~/markers every tick.")
    elif markers_every == 0:
        markers_every = _every(payload, rate_hz, MARKER_BYTES_PER_S)
        lines.append(f"flock markers redrawn {redrawn(markers_every)}: {_megabytes(payload)} for the whole flock(s), "
                     f"{_megabytes(payload * rate_hz / markers_every)}/s"
                     + ("." if markers_every == 1 else f" (marker budget {_megabytes(MARKER_BYTES_PER_S)}/s)."))
    else:
        lines.append(f"flock markers redrawn {redrawn(markers_every)} (markers_every parameter).")

    poses = sum(p.count for p in flocks) * _POSE_BYTES
    if flock_poses_every == 0:
        flock_poses_every = _every(poses, rate_hz, BAG_POSES_BYTES_PER_S)
        if flocks:
            lines.append(f"bag: ~/flocks/*/poses recorded {_per_tick(flock_poses_every, rate_hz)}"
                         + (f" ({_megabytes(poses)} per tick, {_megabytes(poses * rate_hz)}/s at full rate, over "
                            f"the {_megabytes(BAG_POSES_BYTES_PER_S)}/s budget; published every tick)."
                            if flock_poses_every > 1 else "."))
    else:
        lines.append(f"bag: ~/flocks/*/poses recorded {_per_tick(flock_poses_every, rate_hz)} "
                     "(bag_flock_poses_every parameter; published every tick).")
    hull_detail, body_every, body_payload = _body_plan(body_bytes, rate_hz, lines)
    return DetailPlan(fish_detail={p.name: detail for p in fish}, markers_every=markers_every,
                      flock_poses_every=flock_poses_every, marker_bytes=payload, pose_bytes=poses, rate_hz=rate_hz,
                      lines=lines, hull_detail=hull_detail, body_markers_every=body_every,
                      body_marker_bytes=body_payload)


def _body_plan(body_bytes: tuple[int, int], rate_hz: float, lines: list) -> tuple[str, int, int]:
    """Rules 4 and 5: (hull detail, every how many ticks the bodies are redrawn, their payload at that detail)."""
    full, low = body_bytes
    budget = BODY_MARKER_BYTES_PER_S
    if full * rate_hz <= budget:
        return "full", 1, full
    detail = "low" if low < full else "full"
    payload = low if detail == "low" else full
    every = _every(payload, rate_hz, budget)
    if detail == "low":
        lines.append(f"hulls drawn with low detail (at most 48 triangles each): in full the bodies' markers would be "
                     f"{_megabytes(full)} per tick, {_megabytes(full * rate_hz)}/s at {rate_hz:g} Hz, over the "
                     f"{_megabytes(budget)}/s body marker budget.")
    lines.append(f"body markers redrawn {_per_tick(every, rate_hz)}"
                 + ("" if every == 1 else f", in {every} parts, one per tick")
                 + f": {_megabytes(payload)} for every body.")
    return detail, every, payload
