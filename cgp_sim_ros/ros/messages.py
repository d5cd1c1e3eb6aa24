"""What the node publishes each tick, serialized once as CDR bytes (:mod:`cgp_sim_ros.wire.cdr`, numpy-built and
proven equal to rclpy's serialization in tests/test_cdr.py) — the same bytes are published and recorded.

Markers, with stable namespaces and ids.  Every body with a TF frame of its own (a movable body on ``/tf``, a fixed
one on ``/tf_static``) is drawn **once**, in that frame, on the latched ``~/static_markers`` (below): its marker is
``frame_locked`` with its pose fixed in the body frame, and a viewer moves it with ``/tf`` (RViz and Foxglove
re-transform frame-locked markers with the latest transform on every frame).  A body's shape does not change while
it exists, so re-sending its geometry every tick sent the same bytes again and again — a 100-hull pile's markers
were 140 kB per tick (8.4 MB/s), and serializing and publishing them was most of the node's own cost per body
(issue 37; ``benchmarks/bench_node_cost.py``).  Only a robot's link bodies, whose TF frames are the URDF link
frames rather than their body frames, are drawn on ``~/markers`` at their poses (frame ``world``) every tick:

- ``ground`` / 0: a thin grey CUBE under z = 0 (only when the scene has a ground plane);
- ``bodies/<body>`` / 0: the body's shape — SPHERE, CUBE (box), CYLINDER (capsule shaft; ids 1 and 2 are the
  capsule's end SPHEREs), SPHERE_LIST (particle set, drawn in the body frame), TRIANGLE_LIST (a convex hull:
  its triangles in the body frame, the marker's pose the body's; in full or low detail,
  :mod:`cgp_sim_ros.drawing.bodies`);
- ``bodies/<body>`` / 3k, 3k + 1, 3k + 2: part k of a compound body, at the part's own pose (the body's pose
  times the part's): SPHERE, CUBE, CYLINDER (+ its two end SPHEREs at 3k + 1 and 3k + 2) or TRIANGLE_LIST.
  The bodies redrawn every B ticks (the level of detail's rule 5: :mod:`cgp_sim_ros.drawing.detail`) are split
  into B parts of consecutive bodies of about equal bytes, part k drawn on the ticks k mod B.
  TRIANGLE_LIST markers carry no per-vertex colours (the marker's colour; RViz and Foxglove both draw a
  TRIANGLE_LIST in the marker's pose, scaled by ``scale`` = 1, with the triangles' winding — counter-clockwise
  seen from outside — as their front);
- ``flocks/<flock>`` / 0 … K−1: SPHERE_LIST of boids (``model: sphere``) or TRIANGLE_LIST of fish (``model:
  fish``, :mod:`cgp_sim_ros.drawing.shapes`; full or low detail as :mod:`cgp_sim_ros.drawing.detail` chose),
  points rounded to 1/1024 m (a view: the poses are exact).  A flock redrawn every K ticks (``markers_every``)
  is split into K parts, part k = boids [k·N/K, (k+1)·N/K) with id k, and each array carries the part of its
  tick (tick mod K): every boid is redrawn every K ticks, with the same bytes on every tick (the whole flock
  every K-th tick was a burst the bag writer's compression then spent the next tick's second core on).
  K = 1: one marker, id 0, every tick.
- ``robots/<robot>`` / 0 … v−1: a robot's URDF ``<visual>`` elements (:mod:`cgp_sim_ros.drawing.robots`), one
  marker each in the order of :meth:`cgp_core.robots.world.Robots.visuals`, in ``world`` at the link's pose
  composed with the visual's origin: CUBE, SPHERE, CYLINDER, TRIANGLE_LIST (an STL / OBJ mesh, the URDF's scale
  in its points) or MESH_RESOURCE (another mesh format, a ``file://`` URI), in the URDF's colours.  A robot with
  visuals is drawn only by them: its link bodies (``bodies/<robot>/<link>``, their collision shapes) are not
  drawn; a robot without visuals keeps its link bodies' markers.  Robots count as bodies for the level of detail
  (each robot one more entry after the bodies, redrawn in the part its bytes fall in);
- ``contacts/points`` / 0 and ``contacts/forces`` / 0 … k−1 (parameter ``contact_markers``): a SPHERE_LIST of the
  tick's contact points and one ARROW per contact from its point along the contact force on entity_b (normal +
  friction, ``contact_force_scale`` m/N); the arrows of contacts gone since the last tick are DELETEd in the same
  array (ids k … before the arrays' new ones).
After a reset the first marker of the array is a DELETEALL, then the full set (every part).

``~/static_markers`` (latched: transient local, keep last 1), after a DELETEALL, the whole set: the static meshes,
``bodies/<body>`` / 0, a TRIANGLE_LIST in frame ``world`` at the body's pose (at most
:data:`~cgp_sim_ros.drawing.bodies.STATIC_MESH_TRIANGLES` triangles; issue 38: a 500,000-triangle mesh, 36 MB, was
re-sent every second on ``~/markers``), then every other body but a robot's links, with the namespaces and ids
above, in its own frame, ``frame_locked`` (:meth:`TickMessages.framed_markers`).  Sent on the first tick and
whenever that set changes — a body spawned or deleted, a static mesh moved, the hulls' level of detail changed —
so that a subscriber that joins late (and the bag, and a viewer seeking in it) gets every body's geometry, and
``/tf`` / ``/tf_static`` place it.  A sleeping pile's ``~/markers`` then carries the ground alone.

``~/contacts`` (``cgp_sim_msgs/Contacts``): the world's :class:`~cgp_core.solver.report.ContactReport` of the tick,
by :class:`cgp_sim_ros.wire.cdr.ContactsSerializer` (rclpy's message building took 7-10 ms for a 100-box pile's
360 contacts, ours ~0.2 ms; proven equal in tests/test_contacts_message.py).

The flock markers are the big ones: each part is laid out once in its own buffer
(:class:`cgp_sim_ros.wire.cdr.MarkerPointsSerializer`) and the compiled fish kernel writes the vertices straight
into it; the marker array copies it once.
"""

from __future__ import annotations

import numpy as np
from cgp_sim_msgs.msg import Contacts, FlockStats
from geometry_msgs.msg import PoseArray
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from cgp_core.bodies import Shape
from cgp_core.robots.links import link_name
from cgp_core.rotation import matrix_to_quat, quat_multiply, quat_rotate

from ..drawing.bodies import Drawings
from ..drawing.detail import DetailPlan
from ..drawing.robots import visual_drawing
from ..drawing.shapes import FISH_DETAILS, fish_triangles, quantized_points
from ..interface import MAX_CONTACTS_PER_MESSAGE, UNPREFIXED, Frames
from ..wire import cdr

GROUND_SIZE = 60.0  # m, edge of the drawn ground tile
GROUND_COLOR = (0.55, 0.57, 0.6, 1.0)
CONTACT_POINT_COLOR = (0.95, 0.15, 0.15, 1.0)
CONTACT_FORCE_COLOR = (0.95, 0.85, 0.1, 1.0)
CONTACT_POINT_SIZE = 0.04  # m, diameter of the contact point spheres
CONTACT_ARROW = (0.015, 0.035, 0.04)  # m: shaft diameter, head diameter, head length of the force arrows
FLOCK_COLORS = ((0.95, 0.6, 0.15, 1.0), (0.2, 0.6, 0.95, 1.0), (0.55, 0.85, 0.3, 1.0), (0.85, 0.35, 0.75, 1.0))
#: the bytes of a marker besides its points (header, namespace, pose, scale, colour, empty arrays ...): what the
#: level of detail counts per marker, next to 24 bytes per point
MARKER_OVERHEAD_BYTES = 200
_POINT_BYTES = 24


def robot_names(world) -> list[str]:
    """The world's robots (``World.robots``, :class:`cgp_core.robots.world.Robots`), none when it has none."""
    return [] if getattr(world, "robots", None) is None else list(world.robots.names())


def robot_link_rows(world) -> np.ndarray:
    """(n_bodies,) bool: the world bodies that are a robot's links (named ``<robot>/<link>``)."""
    names = world.body_model.names
    prefixes = tuple(f"{robot}/" for robot in robot_names(world))
    if not prefixes:
        return np.zeros(len(names), dtype=bool)
    return np.array([name.startswith(prefixes) for name in names], dtype=bool)


def part_marker_ids(parts) -> set[int]:
    """The marker ids of a compound body's parts: 3k for part k, 3k + 1 and 3k + 2 for a capsule part's caps."""
    ids = set()
    for k in range(parts.count):
        ids.add(3 * k)
        if int(parts.shape[k]) == int(Shape.CAPSULE):
            ids.update((3 * k + 1, 3 * k + 2))
    return ids


class TickMessages:
    """Serializers for one world; each method returns what to publish for the given stamp (ns)."""

    PoseArray = PoseArray
    Odometry = Odometry
    Clock = Clock
    MarkerArray = MarkerArray
    FlockStats = FlockStats
    Contacts = Contacts
    JointState = JointState
    String = String

    def __init__(self, world, frames: Frames = UNPREFIXED, plan: DetailPlan | None = None,
                 contact_force_scale: float | None = None, drawings: Drawings | None = None):
        self.world = world
        #: the hulls' and static meshes' drawings (shared with the node's next TickMessages: made once)
        self.drawings = drawings if drawings is not None else Drawings()
        #: how hulls are drawn ('full' | 'low') and the parts B the bodies' markers are split into (set_plan)
        self.hull_detail = "full"
        self.body_parts = 1
        robots = world.robots
        #: the robots drawn by their URDF visuals (robot_names order; the others are drawn by their link bodies)
        self.visual_robots = [name for name in robot_names(world) if robots.visuals(name)]
        #: (n,) bool: a body not drawn as a body (a link of a robot drawn by its visuals)
        self._hidden = self._hidden_links(world)
        #: (n + r,) the part each body's markers, then each visual robot's, are drawn in (set_plan)
        self._body_part = np.zeros(world.body_model.count + len(self.visual_robots), dtype=np.int64)
        #: contacts in the last ~/contacts message and in the tick's report (the cap: MAX_CONTACTS_PER_MESSAGE)
        self.contacts_sent = self.contacts_of = 0
        self.frame_id = frame_id = frames.world
        self.frames = frames
        model = world.body_model
        # Which body is drawn where (see the module docstring): in its own TF frame on ~/static_markers, sent
        # when the set changes (every body with a frame on /tf or /tf_static), or at its pose on ~/markers every
        # tick (a robot's link bodies: their TF frames are the URDF link frames, not the body frames)
        links = robot_link_rows(world)
        drawn = np.asarray(model.shape, dtype=np.int64) != int(Shape.MESH)
        #: (k,) the bodies drawn on ~/markers on every tick (at their poses, frame world)
        self.per_tick_bodies = np.flatnonzero(drawn & links & ~self._hidden)
        #: (m,) the bodies drawn once in their own frame (frame_locked) on ~/static_markers
        self.framed_bodies = np.flatnonzero(drawn & ~links)
        self._contacts = cdr.ContactsSerializer(frame_id, model.names)
        #: metres per newton of the contact force arrows; None: no contact markers
        self.contact_force_scale = contact_force_scale
        self._arrows_drawn = 0  # contact force arrows in the last array (ids 0 .. that − 1)
        self._body_poses = cdr.PoseArraySerializer(frame_id)
        self._odometry = cdr.OdometryBatchSerializer(frame_id, [frames.body(name) for name in model.names])
        self._flock_poses = [cdr.PoseArraySerializer(frame_id) for _ in world.flocks]
        self._flock_stats = [cdr.FlockStatsSerializer(frame_id) for _ in world.flocks]
        #: every robot's ~/robots/<robot>/joint_states, in the order of robot_names(world) (its joints do not
        #: change while the robot exists: laid out once)
        self._joint_states = [(name, cdr.JointStateSerializer(robots.joint_state(name)[0]))
                              for name in robot_names(world)]
        #: the fish drawing per flock name ('full' | 'low') and the parts K each flock's marker is split into
        #: (see :meth:`set_plan`)
        self.fish_detail: dict[str, str] = {}
        self.parts = 1
        self._flock_markers: dict[tuple, tuple] = {}  # (flock index, part) -> (key, MarkerPointsSerializer)
        self._body_templates: dict[tuple, cdr.MarkerPoseSerializer] = {}  # (body, part, frame) -> template
        self._part_orientations: dict[int, np.ndarray] = {}  # compound body -> its parts' quaternions (k, 4)
        if plan is not None:
            self.set_plan(plan)

    def set_plan(self, plan: DetailPlan) -> None:
        """Draw the fish as ``plan`` says, in ``plan.markers_every`` parts per flock; the hulls in
        ``plan.hull_detail``, the bodies in ``plan.body_markers_every`` parts."""
        self.fish_detail = dict(plan.fish_detail)
        self.parts = max(1, int(plan.markers_every))
        if plan.hull_detail != self.hull_detail:
            self._body_templates.clear()
        self.hull_detail = plan.hull_detail
        self.body_parts = max(1, int(plan.body_markers_every))
        self._body_part = body_parts(self.body_marker_bytes(self.hull_detail), self.body_parts)

    @staticmethod
    def _hidden_links(world) -> np.ndarray:
        """(n,) bool: the link bodies of the robots that have URDF visuals (drawn by those instead)."""
        model = world.body_model
        hidden = np.zeros(model.count, dtype=bool)
        row = {name: i for i, name in enumerate(model.names)}
        robots = world.robots
        for name in robot_names(world):
            if robots.visuals(name):
                for body in robots.robot(name).model.body_names:
                    i = row.get(link_name(name, body))
                    if i is not None:
                        hidden[i] = True
        return hidden

    def _marker_bytes(self, detail: str) -> np.ndarray:
        """(n + r,) the payload of each body's markers, then of each visual robot's (:attr:`visual_robots`),
        drawn once with hulls and visual meshes in ``detail`` [bytes] (about: the points and
        :data:`MARKER_OVERHEAD_BYTES` per marker; 0 for a static mesh, drawn at most STATIC_MESH_TRIANGLES, and
        for a link body drawn by its robot's visuals)."""
        model = self.world.body_model
        out = np.zeros(model.count + len(self.visual_robots), dtype=np.int64)
        for j, name in enumerate(self.visual_robots):
            drawings = [self.drawings.of(g, visual_drawing) for g in self.world.robots.visuals(name)]
            out[model.count + j] = sum(MARKER_OVERHEAD_BYTES + len(d.uri) + _POINT_BYTES * len(d.points(detail))
                                       for d in drawings if d.kind != "none")
        for i in range(model.count):
            shape = int(model.shape[i])
            if shape == Shape.MESH or self._hidden[i]:
                continue
            if shape == Shape.COMPOUND:
                parts = model.parts[i]
                markers = sum(3 if int(k) == int(Shape.CAPSULE) else 1 for k in parts.shape)
                points = sum(len(self.drawings.hull(h).points(detail)) for h in parts.hulls if h is not None)
            elif shape == Shape.CONVEX:
                markers, points = 1, len(self.drawings.hull(model.hulls[i]).points(detail))
            elif shape == Shape.PARTICLES:
                markers, points = 1, len(model.particles[i])
            else:
                markers, points = (3 if shape == Shape.CAPSULE else 1), 0
            out[i] = markers * MARKER_OVERHEAD_BYTES + points * _POINT_BYTES
        return out

    def body_marker_bytes(self, detail: str) -> np.ndarray:
        """(n + r,) the payload of each body's markers on ``~/markers``, then of each visual robot's, drawn once
        with hulls in ``detail`` [bytes] (0 for the bodies drawn on ``~/static_markers`` instead)."""
        every = self._marker_bytes(detail)
        n = self.world.body_model.count
        out = np.zeros(len(every), dtype=np.int64)
        out[self.per_tick_bodies] = every[self.per_tick_bodies]
        out[n:] = every[n:]
        return out

    def body_bytes(self) -> tuple[int, int]:
        """(full, low): the payload of the per-tick bodies' markers (``~/markers``) drawn once with hulls in full
        and in low detail [bytes], for the level-of-detail plan."""
        return int(self.body_marker_bytes("full").sum()), int(self.body_marker_bytes("low").sum())

    def body_set_bytes(self) -> tuple[int, int]:
        """(full, low): the payload of the bodies' markers on ``~/static_markers`` (every body but a robot's links
        and the static meshes), with hulls in full and in low detail [bytes], for the level-of-detail plan."""
        rows = self.framed_bodies
        return int(self._marker_bytes("full")[rows].sum()), int(self._marker_bytes("low")[rows].sum())

    def flock_parts(self, flock) -> int:
        """How many parts (marker ids 0 .. parts − 1) ``flock``'s marker is split into: at least one boid each."""
        return min(self.parts, flock.count)

    def part_range(self, flock, part: int) -> tuple[int, int]:
        """Boids [first, last) of ``part`` of ``flock``'s marker."""
        parts = self.flock_parts(flock)
        return part * flock.count // parts, (part + 1) * flock.count // parts

    def marker_ids(self) -> dict[str, set[int]]:
        """Marker namespace -> the ids :meth:`markers` draws (over its ticks): a body's shape (0) and a capsule's
        end caps (1, 2); every part of a flock's marker."""
        model = self.world.body_model  # (the other bodies: on ~/static_markers, replaced as a whole)
        shapes = [int(model.shape[i]) for i in self.per_tick_bodies.tolist()]
        ids = {f"bodies/{model.names[i]}": ({0, 1, 2} if shape == int(Shape.CAPSULE) else
                                            part_marker_ids(model.parts[i]) if shape == int(Shape.COMPOUND) else {0})
               for i, shape in zip(self.per_tick_bodies.tolist(), shapes)}
        for name in self.visual_robots:
            ids[f"robots/{name}"] = {k for k, g in enumerate(self.world.robots.visuals(name))
                                     if self.drawings.of(g, visual_drawing).kind != "none"}
        ids.update({f"flocks/{f.params.name}": set(range(self.flock_parts(f))) for f in self.world.flocks})
        return ids

    def clock(self, stamp_ns: int) -> bytes:
        return cdr.clock(stamp_ns)

    def body_poses(self, stamp_ns: int) -> bytes:
        state = self.world.body_state
        return self._body_poses.serialize(stamp_ns, state.position, state.orientation)

    def body_odometry(self, stamp_ns: int) -> list[bytes]:
        if self.world.body_model.count == 0:
            return []
        state = self.world.body_state
        v_body, w_body = self.world.body_twist_in_body_frame()
        return self._odometry.serialize(stamp_ns, state.position, state.orientation, v_body, w_body)

    def flock_poses(self, stamp_ns: int) -> list[bytes]:
        return [ser.serialize(stamp_ns, flock.positions, flock.orientations)
                for ser, flock in zip(self._flock_poses, self.world.flocks)]

    def flock_stats(self, stamp_ns: int) -> list[bytes]:
        """Every flock's order parameters now (``Flock.order``: computed in cgp_core, cheap: the nearest
        neighbours come from the step's own neighbour lists) as ``cgp_sim_msgs/FlockStats``."""
        out = []
        for ser, flock in zip(self._flock_stats, self.world.flocks):
            o = flock.order()
            out.append(ser.serialize(stamp_ns, o.count, (o.polarization, o.milling, *o.centroid, o.radius_of_gyration,
                                                         o.mean_nearest_neighbor_distance, o.mean_speed, o.min_speed,
                                                         o.max_speed)))
        return out

    def joint_states(self, stamp_ns: int) -> list[bytes]:
        """Every robot's ``sensor_msgs/JointState`` (``Robots.joint_state``: positions, velocities and the tick's
        mean efforts of its movable joints, URDF order), in the order of :func:`robot_names`."""
        robots = self.world.robots
        out = []
        for name, ser in self._joint_states:
            _, position, velocity, effort = robots.joint_state(name)
            out.append(ser.serialize(stamp_ns, position, velocity, effort))
        return out

    def sent_contacts(self) -> np.ndarray:
        """Indices of the report's contacts a message carries: every one, or — over
        :data:`~cgp_sim_ros.interface.MAX_CONTACTS_PER_MESSAGE` — those with the largest impulse (normal +
        friction magnitude), in the report's (the solver's) order."""
        r = self.world.contacts
        if r.count <= MAX_CONTACTS_PER_MESSAGE:
            return np.arange(r.count)
        strength = np.abs(r.normal_impulse) + np.linalg.norm(r.friction_impulse, axis=1)
        return np.sort(np.argsort(-strength, kind="stable")[:MAX_CONTACTS_PER_MESSAGE])

    def contacts(self, stamp_ns: int) -> bytes:
        """The world's last :class:`~cgp_core.solver.report.ContactReport` as ``cgp_sim_msgs/Contacts``: at most
        MAX_CONTACTS_PER_MESSAGE contacts (:meth:`sent_contacts`), every touching body's wrench."""
        r = self.world.contacts
        sent = self.sent_contacts()
        values = np.concatenate((r.point[sent], r.normal[sent], r.separation[sent, None],
                                 r.normal_impulse[sent, None], r.friction_impulse[sent]), axis=1)
        self.contacts_sent, self.contacts_of = len(sent), r.count
        return self._contacts.serialize(stamp_ns, r.duration, r.body_a[sent], r.body_b[sent], values, r.body,
                                        np.concatenate((r.force, r.torque), axis=1))

    def _contact_markers(self, common: dict) -> list[bytes]:
        """``contacts/points`` (a SPHERE_LIST) and ``contacts/forces`` (an ARROW per contact: the force on B,
        ``contact_force_scale`` m/N) of the contacts :meth:`sent_contacts` picks, the arrows no longer drawn
        DELETEd first."""
        r = self.world.contacts
        sent = self.sent_contacts()
        points = r.point[sent]
        out = [cdr.marker(cdr.MarkerFields(marker_type=cdr.ARROW, action=cdr.DELETE, ns="contacts/forces", id=i,
                                           **common)) for i in range(len(sent), self._arrows_drawn)]
        size = CONTACT_POINT_SIZE
        out.append(cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, ns="contacts/points", id=0,
                                               scale=(size, size, size), color=CONTACT_POINT_COLOR, points=points,
                                               **common)))
        tips = points + r.contact_force()[sent] * self.contact_force_scale if len(sent) else points
        for i, (start, tip) in enumerate(zip(points, tips)):
            out.append(cdr.marker(cdr.MarkerFields(marker_type=cdr.ARROW, ns="contacts/forces", id=i,
                                                   scale=CONTACT_ARROW, color=CONTACT_FORCE_COLOR,
                                                   points=np.array((start, tip)), **common)))
        self._arrows_drawn = len(sent)
        return out

    def markers(self, stamp_ns: int, delete_all_first: bool = False, tick: int = 0) -> bytes:
        """The marker array of ``tick`` (world ticks): ground, part ``tick mod B`` of the bodies and part
        ``tick mod K`` of every flock — every part after a reset (``delete_all_first``)."""
        out = []
        if delete_all_first:
            out.append(cdr.marker_deleteall(stamp_ns, self.frame_id))
        common = {"stamp_ns": stamp_ns, "frame_id": self.frame_id}
        if self.world.ground is not None:
            out.append(cdr.marker(cdr.MarkerFields(
                marker_type=cdr.CUBE, ns="ground", id=0, position=(0.0, 0.0, -0.025),
                scale=(GROUND_SIZE, GROUND_SIZE, 0.05), color=GROUND_COLOR, **common)))
        part = None if delete_all_first else tick % self.body_parts
        out.extend(self._body_markers(common, part))
        out.extend(self._robot_markers(common, part))
        for index, flock in enumerate(self.world.flocks):
            parts = self.flock_parts(flock)
            for part in (range(parts) if delete_all_first else (tick % parts,)):
                out.append(self._flock_marker(index, flock, part, common))
        if self.contact_force_scale is not None:
            out.extend(self._contact_markers(common))
        return cdr.marker_array(out)

    def static_signature(self) -> tuple:
        """What ``~/static_markers`` shows: (name, mesh object, position, orientation) of every static mesh, then
        the hull detail and (name, shape, shape objects, colour) of every body drawn in its own frame (it is sent
        again when this changes: a spawn, a delete, a moved static mesh, another hull detail)."""
        model, state = self.world.body_model, self.world.body_state
        meshes = tuple((model.names[i], id(model.meshes[i]), tuple(state.position[i].tolist()),
                        tuple(state.orientation[i].tolist()))
                       for i in range(model.count) if int(model.shape[i]) == Shape.MESH)
        if not len(self.framed_bodies):
            return meshes
        bodies = tuple((model.names[i], int(model.shape[i]), id(model.hulls[i]), id(model.parts[i]),
                        id(model.particles[i]), float(model.radius[i]),
                        tuple(np.asarray(model.half_extents[i]).tolist()), tuple(np.asarray(model.color[i]).tolist()))
                       for i in self.framed_bodies.tolist())
        return (*meshes, (self.hull_detail, self.frames.prefix, bodies))

    def static_markers(self, stamp_ns: int) -> bytes:
        """``~/static_markers``: a DELETEALL, then every static mesh at its pose (its drawing: at most
        STATIC_MESH_TRIANGLES triangles), then every other body's shape in the body's own TF frame, frame_locked
        (:meth:`framed_markers`)."""
        model, state = self.world.body_model, self.world.body_state
        out = [cdr.marker_deleteall(stamp_ns, self.frame_id)]
        for i in range(model.count):
            if int(model.shape[i]) != Shape.MESH:
                continue
            out.append(cdr.marker(cdr.MarkerFields(
                marker_type=cdr.TRIANGLE_LIST, stamp_ns=stamp_ns, frame_id=self.frame_id, ns=f"bodies/{model.names[i]}",
                id=0, position=state.position[i].tolist(), orientation=state.orientation[i].tolist(),
                color=model.color[i], points=self.drawings.mesh(model.meshes[i]).points)))
        for i in self.framed_bodies.tolist():
            out.extend(self.framed_markers(i, stamp_ns))
        return cdr.marker_array(out)

    def framed_markers(self, i: int, stamp_ns: int) -> list[bytes]:
        """Body i's markers in its own TF frame (``frame_prefix`` + its name: the frame ``/tf`` or ``/tf_static``
        carries), ``frame_locked``: their poses are fixed in the body frame — identity for the shape, the caps of a
        capsule at ±half its length along z, a compound's parts at their relative poses — and a viewer moves them
        with the frame's transform (RViz re-transforms frame-locked markers every frame, Foxglove likewise).  The
        namespaces and ids are those of ``~/markers`` (module docstring)."""
        model = self.world.body_model
        name = model.names[i]
        common = {"stamp_ns": stamp_ns, "frame_id": self.frames.body(name), "ns": f"bodies/{name}",
                  "color": model.color[i], "frame_locked": True}
        shape = Shape(int(model.shape[i]))
        if shape == Shape.PARTICLES:  # in the body frame already
            r = model.radius[i]
            return [cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, id=0, scale=(2 * r, 2 * r, 2 * r),
                                                points=model.particles[i][:, :3], **common))]
        if shape == Shape.COMPOUND:
            parts = model.parts[i]
            pieces = [(Shape(int(parts.shape[k])), parts.radius[k], parts.half_extents[k], parts.hulls[k],
                       parts.position[k], matrix_to_quat(parts.rotation[k]), 3 * k) for k in range(parts.count)]
        else:
            pieces = [(shape, model.radius[i], model.half_extents[i], model.hulls[i], np.zeros(3),
                       np.array([0.0, 0.0, 0.0, 1.0]), 0)]
        out = []
        for kind, radius, half_extents, hull, position, orientation, first_id in pieces:
            points = None if hull is None else self.drawings.hull(hull).points(self.hull_detail)
            for piece in ((0, 1, 2) if kind == Shape.CAPSULE else (0,)):
                where = np.asarray(position, dtype=float)
                if piece:
                    half_axis = quat_rotate(orientation, np.array([0.0, 0.0, half_extents[2]]))
                    where = where + (half_axis if piece == 1 else -half_axis)
                out.append(cdr.marker(cdr.MarkerFields(
                    id=first_id + piece, position=where.tolist(), orientation=np.asarray(orientation).tolist(),
                    **_shape_fields(kind, radius, half_extents, points, piece), **common)))
        return out

    def _body_markers(self, common: dict, part: int | None = None) -> list[bytes]:
        """The markers of the per-tick bodies (a robot's links: :attr:`per_tick_bodies`) of ``part`` (None: every
        one) at their current poses (from templates laid out on first use: only the stamp and the pose change from
        tick to tick); the other bodies are on ``~/static_markers`` (:meth:`static_markers`)."""
        model, state = self.world.body_model, self.world.body_state
        rows = self.per_tick_bodies
        if not len(rows):
            return []
        capsules = rows[model.shape[rows] == Shape.CAPSULE]
        # capsules' end caps: the body position ± the half-length along the body z axis (all capsules at once)
        half_axes = quat_rotate(state.orientation[capsules], model.half_extents[capsules, 2:3] * [[0.0, 0.0, 1.0]])
        caps = {int(i): (state.position[i] + a, state.position[i] - a) for i, a in zip(capsules, half_axes)}
        positions, orientations = state.position.tolist(), state.orientation.tolist()
        stamp, frame_id = common["stamp_ns"], common["frame_id"]
        drawn = rows.tolist() if part is None or self.body_parts == 1 else \
            rows[self._body_part[rows] == part].tolist()
        out = []
        for i in drawn:
            if self._hidden[i]:
                continue
            shape = int(model.shape[i])
            if shape == Shape.COMPOUND:
                out.extend(self._part_markers(i, stamp, frame_id))
                continue
            if shape == Shape.MESH:
                continue
            out.append(self._body_marker(i, 0, frame_id).serialize(stamp, positions[i], orientations[i]))
            if i in caps:
                for part, position in ((1, caps[i][0]), (2, caps[i][1])):
                    out.append(self._body_marker(i, part, frame_id).serialize(stamp, position.tolist(),
                                                                              orientations[i]))
        return out

    def _robot_markers(self, common: dict, part: int | None = None) -> list[bytes]:
        """The visual markers of the robots of ``part`` (None: every robot) at the visuals' poses now (forward
        kinematics composed with the visual origins: ``Robots.visual_poses``), from templates laid out once."""
        robots, first = self.world.robots, self.world.body_model.count
        stamp, frame_id = common["stamp_ns"], common["frame_id"]
        out = []
        for j, name in enumerate(self.visual_robots):
            if part is not None and self.body_parts > 1 and self._body_part[first + j] != part:
                continue
            rotation, position = robots.visual_poses(name)
            orientation = matrix_to_quat(rotation).tolist()  # (v, 4) x y z w, one batched call
            position = position.tolist()
            for k, geometry in enumerate(robots.visuals(name)):
                serializer = self._visual_marker(name, k, geometry, frame_id)
                if serializer is not None:
                    out.append(serializer.serialize(stamp, position[k], orientation[k]))
        return out

    def _visual_marker(self, robot: str, k: int, geometry, frame_id: str) -> cdr.MarkerPoseSerializer | None:
        """Robot visual k's marker template (None: not drawn), laid out once per detail."""
        key = ("robot", robot, k, frame_id)
        if key in self._body_templates:
            return self._body_templates[key]
        d = self.drawings.of(geometry, visual_drawing)
        fields = {"ns": f"robots/{robot}", "id": k, "color": d.color, "frame_id": frame_id, "scale": d.scale}
        if d.kind == "none":
            serializer = None
        else:
            if d.kind == "triangles":
                fields.update(marker_type=cdr.TRIANGLE_LIST, points=d.points(self.hull_detail))
            elif d.kind == "mesh_resource":
                fields.update(marker_type=cdr.MESH_RESOURCE, mesh_resource=d.uri)
            else:
                fields.update(marker_type={"box": cdr.CUBE, "sphere": cdr.SPHERE, "cylinder": cdr.CYLINDER}[d.kind])
            serializer = cdr.MarkerPoseSerializer(**fields)
        self._body_templates[key] = serializer
        return serializer

    def _part_markers(self, i: int, stamp: int, frame_id: str) -> list[bytes]:
        """Compound body i's parts at their poses now: position x + R oₖ, orientation q ⊗ qₖ (capsule caps at the
        part's centre ± its half length along its axis)."""
        model, state = self.world.body_model, self.world.body_state
        parts = model.parts[i]
        part_q = self._part_orientations.get(i)
        if part_q is None:
            part_q = self._part_orientations[i] = matrix_to_quat(parts.rotation)
        q = np.asarray(state.orientation[i])
        centres = state.position[i] + quat_rotate(np.broadcast_to(q, (parts.count, 4)), parts.position)
        turned = quat_multiply(np.broadcast_to(q, (parts.count, 4)), part_q)
        out = []
        for k in range(parts.count):
            orientation = turned[k].tolist()
            out.append(self._body_marker(i, 3 * k, frame_id).serialize(stamp, centres[k].tolist(), orientation))
            if int(parts.shape[k]) == int(Shape.CAPSULE):
                half_axis = quat_rotate(turned[k], np.array([0.0, 0.0, parts.half_extents[k, 2]]))
                for cap, sign in ((1, 1.0), (2, -1.0)):
                    out.append(self._body_marker(i, 3 * k + cap, frame_id).serialize(
                        stamp, (centres[k] + sign * half_axis).tolist(), orientation))
        return out

    def _body_marker(self, i: int, part: int, frame_id: str) -> cdr.MarkerPoseSerializer:
        """Body i's marker ``part`` (0: the shape; 1, 2: a capsule's end caps; a compound's: see the module
        docstring), laid out once."""
        key = (i, part, frame_id)
        serializer = self._body_templates.get(key)
        if serializer is None:
            model = self.world.body_model
            ns = f"bodies/{model.names[i]}"
            shape = Shape(int(model.shape[i]))
            fields = {"ns": ns, "id": part, "color": model.color[i], "frame_id": frame_id}
            if shape == Shape.COMPOUND:
                parts = model.parts[i]
                k, piece = divmod(part, 3)
                hull = parts.hulls[k]
                fields.update(_shape_fields(Shape(int(parts.shape[k])), parts.radius[k], parts.half_extents[k],
                                            None if hull is None else self.drawings.hull(hull).points(
                                                self.hull_detail), piece))
            elif shape == Shape.PARTICLES:  # in the body frame
                r = model.radius[i]
                fields.update(marker_type=cdr.SPHERE_LIST, scale=(2 * r, 2 * r, 2 * r),
                              points=model.particles[i][:, :3])
            else:
                hull = model.hulls[i]
                fields.update(_shape_fields(shape, model.radius[i], model.half_extents[i],
                                            None if hull is None else self.drawings.hull(hull).points(
                                                self.hull_detail), part))
            serializer = self._body_templates[key] = cdr.MarkerPoseSerializer(**fields)
        return serializer

    def _flock_marker(self, index: int, flock, part: int, common: dict) -> memoryview:
        params = flock.params
        fish = params.model == "fish"
        detail = self.fish_detail.get(params.name, "full")
        first, last = self.part_range(flock, part)
        points = (last - first) * (len(FISH_DETAILS[detail]) if fish else 1)
        key = (points, detail, common["frame_id"])
        cached = self._flock_markers.get((index, part))
        if cached is None or cached[0] != key:
            size = params.boid_size
            serializer = cdr.MarkerPointsSerializer(
                points, marker_type=cdr.TRIANGLE_LIST if fish else cdr.SPHERE_LIST, frame_id=common["frame_id"],
                ns=f"flocks/{params.name}", id=part, color=FLOCK_COLORS[index % len(FLOCK_COLORS)],
                scale=(1.0, 1.0, 1.0) if fish else (size, size, size))
            cached = self._flock_markers[(index, part)] = (key, serializer)
        serializer = cached[1]
        if fish:
            fish_triangles(flock.positions[first:last], flock.orientations[first:last], params.boid_size, detail,
                           out=serializer.points)
        else:
            quantized_points(flock.positions[first:last], out=serializer.points)
        return serializer.serialize(common["stamp_ns"])


def _shape_fields(shape: Shape, r: float, half_extents, hull_points, piece: int) -> dict:
    """Marker type, scale and points of a sphere, box, capsule (piece 1, 2: its end caps) or hull (``hull_points``
    (3t, 3): its TRIANGLE_LIST at the chosen detail)."""
    if shape == Shape.SPHERE or piece > 0:
        return {"marker_type": cdr.SPHERE, "scale": (2 * r, 2 * r, 2 * r)}
    if shape == Shape.BOX:
        return {"marker_type": cdr.CUBE, "scale": 2 * np.asarray(half_extents)}
    if shape == Shape.CAPSULE:
        return {"marker_type": cdr.CYLINDER, "scale": (2 * r, 2 * r, 2 * half_extents[2])}
    return {"marker_type": cdr.TRIANGLE_LIST, "points": hull_points}


def body_parts(body_bytes: np.ndarray, parts: int) -> np.ndarray:
    """(n,) the part (0 .. parts − 1) each body's markers are drawn in: consecutive bodies, parts of about equal
    bytes (a body's part is where the middle of its bytes falls)."""
    body_bytes = np.asarray(body_bytes, dtype=float)
    total = float(body_bytes.sum())
    if parts <= 1 or total <= 0.0:
        return np.zeros(len(body_bytes), dtype=np.int64)
    middle = np.cumsum(body_bytes) - 0.5 * body_bytes
    return np.minimum((middle * parts / total).astype(np.int64), parts - 1)
