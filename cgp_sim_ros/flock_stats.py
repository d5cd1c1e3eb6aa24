"""``~/flocks/<flock>/stats``: each flock's order parameters every tick (issue 14), as ``cgp_sim_msgs/FlockStats``.

The numbers are computed in ``cgp_core`` (:func:`cgp_core.boids.order.flock_order`: polarization, milling,
centroid, radius of gyration, mean nearest-neighbour distance, speeds); this module only serializes them, once
per flock per tick, as CDR bytes (:func:`serialize`, proven equal to rclpy's ``serialize_message``, outside the
padding bytes rclpy leaves uninitialised, in
``tests/test_flock_stats.py``), and the node publishes and records those same bytes.  In Foxglove, a Plot
panel with ``/cgp_sim/flocks/<flock>/stats.polarization`` (and ``.milling``, ...) shows them live or from a bag.
"""

from __future__ import annotations

import struct

from cgp_core.boids.order import FlockOrder, flock_order

from . import interface as itf
from .cdr import ENCAPSULATION, split_stamp

# body after the header's frame_id string: uint32 count (4-aligned), then 10 float64 (8-aligned)
_COUNT = struct.Struct("<I")
_VALUES = struct.Struct("<10d")
_ZEROS = bytes(8)


def serialize(stamp_ns: int, frame_id: str, order: FlockOrder) -> bytes:
    """``cgp_sim_msgs/FlockStats`` as CDR (XCDR1, little endian), encapsulation header included."""
    sec, nanosec = split_stamp(stamp_ns)
    frame = frame_id.encode("utf-8")
    if b"\x00" in frame:
        raise ValueError(f"frame_id={frame_id!r} contains a NUL character")
    body = bytearray(struct.pack("<iII", sec, nanosec, len(frame) + 1) + frame + b"\x00")
    body += _ZEROS[:-len(body) % 4]
    body += _COUNT.pack(order.count)
    body += _ZEROS[:-len(body) % 8]
    body += _VALUES.pack(order.polarization, order.milling, *map(float, order.centroid), order.radius_of_gyration,
                         order.mean_nearest_neighbor_distance, order.mean_speed, order.min_speed, order.max_speed)
    return ENCAPSULATION + bytes(body)


class FlockStatsPublishers:
    """One ``~/flocks/<flock>/stats`` publisher per flock of the node's world (a small piece of the node)."""

    def __init__(self, node, world, frame_id: str = itf.WORLD_FRAME):
        from cgp_sim_msgs.msg import FlockStats

        self.world = world
        self.frame_id = frame_id
        self.publishers = [node.create_publisher(FlockStats, itf.TOPIC_FLOCK_STATS.format(flock=f.params.name),
                                                 itf.STATE_QOS) for f in world.flocks]

    def publish(self, stamp_ns: int, out) -> None:
        """Serialize every flock's order parameters once and hand the bytes to ``out(publisher, data, stamp)``
        (the node's publish-and-record)."""
        for publisher, flock in zip(self.publishers, self.world.flocks):
            out(publisher, serialize(stamp_ns, self.frame_id, flock_order(flock.positions, flock.velocities)),
                stamp_ns)
