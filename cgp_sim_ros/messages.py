"""What the node publishes each tick, serialized once as CDR bytes (:mod:`cgp_sim_ros.cdr`, numpy-built and
proven equal to rclpy's serialization in tests/test_cdr.py) — the same bytes are published and recorded.

Markers (``~/markers``, frame ``world``), with stable namespaces and ids:

- ``ground`` / 0: a thin grey CUBE under z = 0 (only when the scene has a ground plane);
- ``bodies/<body>`` / 0: the body's shape — SPHERE, CUBE (box), CYLINDER (capsule shaft; ids 1 and 2 are the
  capsule's end SPHEREs), SPHERE_LIST (particle set, drawn in the body frame);
- ``flocks/<flock>`` / 0: SPHERE_LIST of all boids (``model: sphere``) or a TRIANGLE_LIST of fish
  (``model: fish``, :mod:`cgp_sim_ros.shapes`; full or low detail as :mod:`cgp_sim_ros.detail` chose), one
  marker per flock, its points rounded to 1/1024 m (a view: the poses are exact).
After a reset the first marker of the array is a DELETEALL, then the full set.

The flock markers are the big ones: each is laid out once in its own buffer
(:class:`cgp_sim_ros.cdr.MarkerPointsSerializer`) and the compiled fish kernel writes the vertices straight
into it; the marker array copies it once.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseArray
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from visualization_msgs.msg import MarkerArray

from cgp_core.bodies import Shape
from cgp_core.rotation import quat_rotate

from . import cdr
from .detail import DetailPlan
from .shapes import FISH_DETAILS, fish_triangles, quantized_points

GROUND_SIZE = 60.0  # m, edge of the drawn ground tile
GROUND_COLOR = (0.55, 0.57, 0.6, 1.0)
FLOCK_COLORS = ((0.95, 0.6, 0.15, 1.0), (0.2, 0.6, 0.95, 1.0), (0.55, 0.85, 0.3, 1.0), (0.85, 0.35, 0.75, 1.0))


class TickMessages:
    """Serializers for one world; each method returns what to publish for the given stamp (ns)."""

    PoseArray = PoseArray
    Odometry = Odometry
    Clock = Clock
    MarkerArray = MarkerArray

    def __init__(self, world, frame_id: str = "world", plan: DetailPlan | None = None):
        self.world = world
        self.frame_id = frame_id
        model = world.body_model
        self._body_poses = cdr.PoseArraySerializer(frame_id)
        self._odometry = cdr.OdometryBatchSerializer(frame_id, model.names)
        self._flock_poses = [cdr.PoseArraySerializer(frame_id) for _ in world.flocks]
        #: the fish drawing per flock name ('full' | 'low'); see :meth:`set_plan`
        self.fish_detail: dict[str, str] = {}
        self._flock_markers: dict[int, tuple] = {}  # flock index -> (key, MarkerPointsSerializer)
        if plan is not None:
            self.set_plan(plan)

    def set_plan(self, plan: DetailPlan) -> None:
        """Draw the fish as ``plan`` says (the rest of the plan — rates — is the node's business)."""
        self.fish_detail = dict(plan.fish_detail)

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

    def markers(self, stamp_ns: int, delete_all_first: bool = False) -> bytes:
        out = []
        if delete_all_first:
            out.append(cdr.marker_deleteall(stamp_ns, self.frame_id))
        common = {"stamp_ns": stamp_ns, "frame_id": self.frame_id}
        if self.world.ground is not None:
            out.append(cdr.marker(marker_type=cdr.CUBE, ns="ground", id=0, position=(0.0, 0.0, -0.025),
                                  scale=(GROUND_SIZE, GROUND_SIZE, 0.05), color=GROUND_COLOR, **common))
        out.extend(self._body_markers(common))
        for index, flock in enumerate(self.world.flocks):
            out.append(self._flock_marker(index, flock, common))
        return cdr.marker_array(out)

    def _body_markers(self, common: dict) -> list[bytes]:
        model, state = self.world.body_model, self.world.body_state
        out = []
        for i, name in enumerate(model.names):
            ns = f"bodies/{name}"
            pose = {"position": state.position[i], "orientation": state.orientation[i],
                    "color": model.color[i]}
            shape = Shape(int(model.shape[i]))
            r = model.radius[i]
            if shape == Shape.SPHERE:
                out.append(cdr.marker(marker_type=cdr.SPHERE, ns=ns, id=0, scale=(2 * r, 2 * r, 2 * r),
                                      **pose, **common))
            elif shape == Shape.BOX:
                out.append(cdr.marker(marker_type=cdr.CUBE, ns=ns, id=0, scale=2 * model.half_extents[i],
                                      **pose, **common))
            elif shape == Shape.CAPSULE:
                half_length = model.half_extents[i, 2]
                out.append(cdr.marker(marker_type=cdr.CYLINDER, ns=ns, id=0, scale=(2 * r, 2 * r, 2 * half_length),
                                      **pose, **common))
                axis = quat_rotate(state.orientation[i], np.array([0.0, 0.0, half_length]))
                for cap_id, sign in ((1, 1.0), (2, -1.0)):
                    out.append(cdr.marker(marker_type=cdr.SPHERE, ns=ns, id=cap_id, scale=(2 * r, 2 * r, 2 * r),
                                          **{**pose, "position": state.position[i] + sign * axis}, **common))
            else:  # particles, in the body frame
                out.append(cdr.marker(marker_type=cdr.SPHERE_LIST, ns=ns, id=0, scale=(2 * r, 2 * r, 2 * r),
                                      points=model.particles[i][:, :3], **pose, **common))
        return out

    def _flock_marker(self, index: int, flock, common: dict) -> memoryview:
        params = flock.params
        fish = params.model == "fish"
        detail = self.fish_detail.get(params.name, "full")
        points = flock.count * (len(FISH_DETAILS[detail]) if fish else 1)
        key = (points, detail, common["frame_id"])
        cached = self._flock_markers.get(index)
        if cached is None or cached[0] != key:
            size = params.boid_size
            serializer = cdr.MarkerPointsSerializer(
                points, marker_type=cdr.TRIANGLE_LIST if fish else cdr.SPHERE_LIST, frame_id=common["frame_id"],
                ns=f"flocks/{params.name}", id=0, color=FLOCK_COLORS[index % len(FLOCK_COLORS)],
                scale=(1.0, 1.0, 1.0) if fish else (size, size, size))
            cached = self._flock_markers[index] = (key, serializer)
        serializer = cached[1]
        if fish:
            fish_triangles(flock.positions, flock.orientations, params.boid_size, detail, out=serializer.points)
        else:
            quantized_points(flock.positions, out=serializer.points)
        return serializer.serialize(common["stamp_ns"])
