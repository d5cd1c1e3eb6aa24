"""CDR serialization with numpy (cgp_sim_ros.wire.cdr) vs rclpy message objects, on this machine.

Per message, median of interleaved repetitions (each variant runs in turn, several rounds):
- PoseArray 1k / 10k / 100k poses:
  * ``rclpy objects``: build the Pose objects from the arrays, ``serialize_message`` (once: the bytes go to
    the bag; publishing the object would serialize it again inside rclpy, not counted here);
  * ``numpy``: :func:`cdr.pose_array`; ``numpy reuse``: :class:`cdr.PoseArraySerializer`;
  * ``publish``: the numpy bytes published with ``Publisher.publish(bytes)`` vs the Pose objects built and
    the message published with ``Publisher.publish(msg)`` (rclpy serializes it inside publish);
  * ``publish + record``: the figure of issue 7 — the numpy bytes published with ``Publisher.publish(bytes)``
    and the same bytes queued to a :class:`BagWriter`, vs the rclpy message built, published and serialized
    once more for the bag (a node that records what it publishes needs the bytes; rclpy's publish does not
    hand them back).  Target: >= 20x cheaper at 10k.
  The publisher is a real one (reliable, depth 10, in this process's own ROS domain, no subscriber).
- SPHERE_LIST Marker 1k / 10k / 100k points with colours, MarkerArray of 20 shapes, 8 / 20 Odometry, Clock.

Writes a table to stdout and ``benchmarks/results/cdr.json`` (layout: ``benchmarks/common.py``).
Run: ``.venv/bin/python benchmarks/bench_cdr.py`` (``--quick`` for fewer repetitions).
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

# A ROS domain of our own (before rclpy loads), as in bench_tick.py.
if "CGP_SIM_BENCH_DOMAIN" not in os.environ:
    os.environ["CGP_SIM_BENCH_DOMAIN"] = str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 101))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

from common import Results  # noqa: E402
from geometry_msgs.msg import Point, Pose, PoseArray  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from std_msgs.msg import ColorRGBA  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from cgp_sim_ros.wire import cdr  # noqa: E402
from cgp_sim_ros.wire.bag import BagOptions, BagWriter  # noqa: E402

TARGET_RATIO_10K = 20.0


def rclpy_pose_array(stamp, positions, quaternions) -> PoseArray:
    msg = PoseArray()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.header.frame_id = "world"
    poses = []
    for (x, y, z), (qx, qy, qz, qw) in zip(positions.tolist(), quaternions.tolist()):
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = x, y, z
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = qx, qy, qz, qw
        poses.append(pose)
    msg.poses = poses
    return msg


def rclpy_sphere_list(points, colors) -> Marker:
    msg = Marker()
    msg.header.frame_id = "world"
    msg.type = Marker.SPHERE_LIST
    msg.scale.x = msg.scale.y = msg.scale.z = 0.1
    msg.pose.orientation.w = 1.0
    msg.points = [Point(x=x, y=y, z=z) for x, y, z in points.tolist()]
    msg.colors = [ColorRGBA(r=r, g=g, b=b, a=a) for r, g, b, a in colors.tolist()]
    return msg


def rclpy_odometry(stamp, names, p, q, v, w) -> list[Odometry]:
    out = []
    for i, name in enumerate(names):
        msg = Odometry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        msg.header.frame_id = "world"
        msg.child_frame_id = name
        pose, twist = msg.pose.pose, msg.twist.twist
        pose.position.x, pose.position.y, pose.position.z = p[i].tolist()
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = q[i].tolist()
        twist.linear.x, twist.linear.y, twist.linear.z = v[i].tolist()
        twist.angular.x, twist.angular.y, twist.angular.z = w[i].tolist()
        out.append(msg)
    return out


def interleaved(variants: dict, rounds: int, min_time: float = 0.02) -> dict[str, float]:
    """Median seconds per call of each variant; variants alternate within each round."""
    numbers = {}
    for name, fn in variants.items():  # calls per sample so that one sample lasts >= min_time
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        numbers[name] = max(1, int(min_time / max(dt, 1e-7)))
    samples = {name: [] for name in variants}
    for _ in range(rounds):
        for name, fn in variants.items():
            n = numbers[name]
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            samples[name].append((time.perf_counter() - t0) / n)
    return {name: float(np.median(s)) for name, s in samples.items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    rounds = 3 if args.quick else 7
    rng = np.random.default_rng(0)
    out = Results("cdr", options=vars(args))
    results = out.data
    results["rows"] = []
    rows = results["rows"]

    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    results["ros_domain_id"] = int(os.environ["ROS_DOMAIN_ID"])
    node = rclpy.create_node("bench_cdr", context=context)
    publisher = node.create_publisher(PoseArray, "bench_poses", 10)
    bag_dir = Path(tempfile.mkdtemp(prefix="bench_cdr_")) / "bag"
    bag = BagWriter(bag_dir, BagOptions(max_queue_bytes=1 << 30))
    bag.add_topic("/bench_poses", "geometry_msgs/msg/PoseArray")
    try:
        for n in (1_000, 10_000, 100_000):
            positions, quaternions = rng.normal(size=(n, 3)), rng.normal(size=(n, 4))
            serializer = cdr.PoseArraySerializer("world")
            stamp = [0]

            def rclpy_serialize():
                return serialize_message(rclpy_pose_array(5, positions, quaternions))

            def rclpy_publish():
                publisher.publish(rclpy_pose_array(5, positions, quaternions))

            def numpy_publish():
                publisher.publish(serializer.serialize(5, positions, quaternions))

            def rclpy_publish_record():
                msg = rclpy_pose_array(5, positions, quaternions)
                publisher.publish(msg)
                stamp[0] += 1
                bag.write("/bench_poses", serialize_message(msg), stamp[0])

            def numpy_publish_record():
                data = serializer.serialize(5, positions, quaternions)
                publisher.publish(data)
                stamp[0] += 1
                bag.write("/bench_poses", data, stamp[0])

            variants = {"rclpy objects": rclpy_serialize,
                        "numpy": lambda: cdr.pose_array(5, "world", positions, quaternions),
                        "numpy reuse": lambda: serializer.serialize(5, positions, quaternions),
                        "rclpy publish": rclpy_publish,
                        "numpy publish": numpy_publish,
                        "rclpy publish+record": rclpy_publish_record,
                        "numpy publish+record": numpy_publish_record}
            times = interleaved(variants, rounds if n < 100_000 else max(3, rounds // 2))
            bag.flush()
            base = times["rclpy objects"]
            for name, t in times.items():
                ref = (times["rclpy publish+record"] if "record" in name else times["rclpy publish"]
                       if "publish" in name else base)
                rows.append({"message": f"PoseArray {n}", "variant": name, "ms": t * 1e3, "speedup": ref / t})
        results["publish_record_ratio_10k"] = next(
            r["speedup"] for r in rows if r["message"] == "PoseArray 10000" and r["variant"] == "numpy publish+record")
        results["target_ratio_10k"] = TARGET_RATIO_10K

        for n in (1_000, 10_000, 100_000):
            points = rng.normal(size=(n, 3))
            colors = rng.uniform(size=(n, 4)).astype(np.float32)
            times = interleaved({
                "rclpy objects": lambda: serialize_message(rclpy_sphere_list(points, colors)),
                "numpy": lambda: cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, frame_id="world",
                                                             points=points, colors=colors, scale=(0.1, 0.1, 0.1))),
            }, rounds if n < 100_000 else max(3, rounds // 2))
            for name, t in times.items():
                rows.append({"message": f"SPHERE_LIST {n}", "variant": name, "ms": t * 1e3,
                             "speedup": times["rclpy objects"] / t})

        shapes = [dict(marker_type=cdr.SPHERE, ns="bodies", id=i, frame_id="world", position=rng.normal(size=3),
                       scale=(0.5, 0.5, 0.5), color=(1, 0, 0, 1)) for i in range(20)]

        def rclpy_shapes():
            array = MarkerArray()
            for kw in shapes:
                m = Marker(type=Marker.SPHERE, ns="bodies", id=kw["id"])
                m.header.frame_id = "world"
                m.pose.position = Point(x=float(kw["position"][0]), y=float(kw["position"][1]),
                                        z=float(kw["position"][2]))
                m.pose.orientation.w = 1.0
                m.scale.x = m.scale.y = m.scale.z = 0.5
                m.color = ColorRGBA(r=1.0, a=1.0)
                array.markers.append(m)
            return serialize_message(array)

        times = interleaved({"rclpy objects": rclpy_shapes,
                             "numpy": lambda: cdr.marker_array([cdr.marker(cdr.MarkerFields(**kw)) for kw in shapes])},
                            rounds)
        for name, t in times.items():
            rows.append({"message": "MarkerArray 20 shapes", "variant": name, "ms": t * 1e3,
                         "speedup": times["rclpy objects"] / t})

        for n in (8, 20):
            names = [f"body_{i}" for i in range(n)]
            p, q, v, w = (rng.normal(size=(n, k)) for k in (3, 4, 3, 3))
            batch = cdr.OdometryBatchSerializer("world", names)
            times = interleaved({
                "rclpy objects": lambda: [serialize_message(m) for m in rclpy_odometry(5, names, p, q, v, w)],
                "numpy batch": lambda: batch.serialize(5, p, q, v, w),
                "numpy one by one": lambda: [cdr.odometry(5, "world", names[i], p[i], q[i], v[i], w[i])
                                             for i in range(n)],
            }, rounds)
            for name, t in times.items():
                rows.append({"message": f"Odometry x{n}", "variant": name, "ms": t * 1e3,
                             "speedup": times["rclpy objects"] / t})

        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock
        times = interleaved({"rclpy objects": lambda: serialize_message(Clock(clock=Time(sec=1, nanosec=5))),
                             "numpy": lambda: cdr.clock(1_000_000_005)}, rounds)
        for name, t in times.items():
            rows.append({"message": "Clock", "variant": name, "ms": t * 1e3, "speedup": times["rclpy objects"] / t})
    finally:
        bag.close()
        shutil.rmtree(bag_dir.parent, ignore_errors=True)
        node.destroy_node()
        rclpy.shutdown(context=context)

    print(f"{'message':<24} {'variant':<22} {'ms':>10} {'x faster':>9}")
    print("-" * 68)
    for r in rows:
        print(f"{r['message']:<24} {r['variant']:<22} {r['ms']:10.4f} {r['speedup']:9.1f}")

    def speedup(message, variant):
        return next(r["speedup"] for r in rows if r["message"] == message and r["variant"] == variant)

    ratio = results["publish_record_ratio_10k"]
    results["publish_record_ratio"] = {n: speedup(f"PoseArray {n}", "numpy publish+record")
                                       for n in (1_000, 10_000, 100_000)}
    out.figure("cdr_publish_record_10k", "publish + record 10k-pose PoseArray: rclpy objects / numpy CDR",
               ratio, "x", f">= {TARGET_RATIO_10K:g}", ratio >= TARGET_RATIO_10K, issue7=True,
               numpy_ms=next(r["ms"] for r in rows if r["message"] == "PoseArray 10000"
                             and r["variant"] == "numpy publish+record"),
               rclpy_ms=next(r["ms"] for r in rows if r["message"] == "PoseArray 10000"
                             and r["variant"] == "rclpy publish+record"))
    publish_only = speedup("PoseArray 10000", "numpy publish")
    out.figure("cdr_publish_10k", "publish only, 10k-pose PoseArray: rclpy objects / numpy CDR", publish_only, "x",
               f">= {TARGET_RATIO_10K:g} (reference)", publish_only >= TARGET_RATIO_10K)
    print(f"\npublish + record a 10k PoseArray: numpy {ratio:.1f}x cheaper than rclpy objects "
          f"(target >= {TARGET_RATIO_10K:.0f}x): {'pass' if ratio >= TARGET_RATIO_10K else 'SHORT'}")
    path = out.write()
    print(f"written {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
