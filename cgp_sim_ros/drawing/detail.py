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

The bodies' shapes do not change while they exist, so every body with a TF frame of its own is drawn once, in
that frame (``frame_locked``: a viewer moves it with ``/tf``), on the latched ``~/static_markers``, sent again only
when the set changes (a spawn, a delete, another hull detail); ``~/markers`` carries no body a TF frame places
(issue 37: a 100-hull pile's 140 kB per tick, sent again every tick, were most of the node's own cost per body).
Only a robot's links, whose TF frames are the URDF link frames rather than their body frames, are drawn at their
poses on ``~/markers`` every tick.  Two bounds:

4. hulls (convex bodies, compound parts) are drawn ``full`` (their triangles) if the bodies' set on
   ``~/static_markers`` fits :data:`BODY_SET_BYTES` in full and the robots' links on ``~/markers`` fit the body
   budget :data:`BODY_MARKER_BYTES_PER_S` on every tick; otherwise ``low``: the hull of their extreme vertices in
   26 directions, at most 48 triangles (:mod:`cgp_sim_ros.drawing.bodies`) — issue 38's 300 bodies with 1,000-vertex
   hulls, 43 MB in full, are then ~1 MB, sent once.  Past the cap in low detail too (thousands of compound bodies
   of hull parts) the set is still sent whole, once per change: the limits on bodies and parts
   (:mod:`cgp_core.limits`) bound it, and a viewer needs every body;
5. the robots' link markers on ``~/markers`` are redrawn every B-th tick, the smallest B that fits the body budget
   — in B parts of about equal bytes (consecutive bodies), one part per tick, as the flocks' are.

Static meshes go on ``~/static_markers`` too, in frame ``world`` at their poses, each with at most
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
#: per-tick body marker payload (a robot's links on ~/markers) per simulated second the automatic choices keep to
#: [bytes] (rules 4 and 5)
BODY_MARKER_BYTES_PER_S = 16e6
#: the bodies' markers on the latched ~/static_markers, sent whole when the set changes: hulls in full up to this
#: [bytes] (rule 4)
BODY_SET_BYTES = 8e6

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
    body_markers_every: the per-tick bodies' markers (a robot's links) redrawn every B ticks, in B parts (rule 5).
    body_marker_bytes:  payload of the per-tick bodies' markers drawn once, at the chosen detail [bytes].
    body_set_bytes:     payload of the bodies' markers on ``~/static_markers``, at the chosen detail [bytes].
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
    body_set_bytes: int = 0

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
         flock_poses_every: int = 0, body_bytes: tuple[int, int] = (0, 0),
         body_set_bytes: tuple[int, int] = (0, 0)) -> DetailPlan:
    """The level of detail for ``flocks`` (their :class:`~cgp_core.boids.FlockParams`) and bodies whose per-tick
    markers (a robot's links), all drawn once, are ``body_bytes`` = (at full hull detail, at low) bytes and whose
    markers on ``~/static_markers`` are ``body_set_bytes`` (likewise), at ``rate_hz``; the parameters as the node
    has them (``"auto"`` / 0 = follow the rules of the module docstring)."""
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
    hull_detail, body_every, body_payload = _body_plan(body_bytes, body_set_bytes, rate_hz, lines)
    return DetailPlan(fish_detail={p.name: detail for p in fish}, markers_every=markers_every,
                      flock_poses_every=flock_poses_every, marker_bytes=payload, pose_bytes=poses, rate_hz=rate_hz,
                      lines=lines, hull_detail=hull_detail, body_markers_every=body_every,
                      body_marker_bytes=body_payload,
                      body_set_bytes=body_set_bytes[1] if hull_detail == "low" else body_set_bytes[0])


def _body_plan(body_bytes: tuple[int, int], set_bytes: tuple[int, int], rate_hz: float,
               lines: list) -> tuple[str, int, int]:
    """Rules 4 and 5: (hull detail, every how many ticks the per-tick bodies are redrawn, their payload at that
    detail)."""
    full, low = body_bytes
    set_full, set_low = set_bytes
    budget = BODY_MARKER_BYTES_PER_S
    over_rate, over_set = full * rate_hz > budget, set_full > BODY_SET_BYTES
    detail = "low" if (over_rate or over_set) and (low < full or set_low < set_full) else "full"
    payload = low if detail == "low" else full
    every = _every(payload, rate_hz, budget)
    if detail == "low":
        reasons = []
        if over_set:
            reasons.append(f"the bodies on ~/static_markers would be {_megabytes(set_full)}, over its "
                           f"{_megabytes(BODY_SET_BYTES)} cap")
        if over_rate:
            reasons.append(f"the robots' links on ~/markers would be {_megabytes(full)} per tick, "
                           f"{_megabytes(full * rate_hz)}/s at {rate_hz:g} Hz, over the {_megabytes(budget)}/s body "
                           "marker budget")
        lines.append("hulls drawn with low detail (at most 48 triangles each): in full " + "; ".join(reasons) + ".")
    if set_full:
        lines.append(f"bodies drawn once, in their own TF frames, on ~/static_markers "
                     f"({_megabytes(set_low if detail == 'low' else set_full)}; sent again when the set changes).")
    if every > 1 or (full and detail == "low"):
        lines.append(f"robot link markers redrawn {_per_tick(every, rate_hz)}"
                     + ("" if every == 1 else f", in {every} parts, one per tick")
                     + f": {_megabytes(payload)} for every link.")
    return detail, every, payload
