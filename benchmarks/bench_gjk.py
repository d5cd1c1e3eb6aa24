"""Benchmark: GJK distance queries per second on random hull pairs, ours against FCL's (python-fcl), and the BVH
build of a static mesh (issue 25).

Hulls as in the issue's pile: 16–24 points on an ellipsoid, 0.3–0.5 m across (``--hulls`` of them, seeded).
Pairs: ``--pairs`` random pairs at random orientations, centres 0.45–0.9 m apart (mostly apart: distance
queries) and, for the penetration figure, 0.1–0.3 m apart (overlapping: GJK + EPA).  Measured, interleaved
round by round (``--rounds``, the median kept):

- ours from Python, one call per pair (``gjk_distance``: what a test or a tool pays, call overhead included);
- ours in a compiled loop over the pairs (what the narrow phase pays: the kernels called from a kernel);
- FCL (``fcl.distance`` on ``fcl.Convex`` objects, the poses set per pair, one call per pair from Python);
- penetration (GJK + EPA) on overlapping pairs: ours in a compiled loop, FCL's ``fcl.collide`` with contacts.

The distances are compared (ours against FCL's: its GJK tolerance is ~1e-6) and reported.  The depths are not
the same quantity: FCL's default solver (libccd) measures them by MPR (along the line of the centres, an upper
bound), ours by EPA (the minimum): the figure is that ours is never the deeper.  The BVH: build time
and memory for the shipped terrain (1,152 triangles) and a 100k-triangle heightfield.

Plain script: prints a table and writes ``benchmarks/results/gjk.json`` (``benchmarks/common.py``'s layout), with
the speed probe before and after.

    .venv/bin/python benchmarks/bench_gjk.py [--pairs 2000] [--rounds 5] [--hulls 100]
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import Results, format_figures, format_speed_probe  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from cgp_core.collision.bvh import StaticMesh  # noqa: E402
from cgp_core.collision.convex import HullSet, convex_hull  # noqa: E402
from cgp_core.collision.epa import penetration  # noqa: E402
from cgp_core.collision.gjk import Core, gjk_distance  # noqa: E402
from cgp_core.collision.meshfile import load_mesh  # noqa: E402
from cgp_core.jit import njit  # noqa: E402


def pile_hulls(count: int, seed: int = 25) -> list:
    rng = np.random.default_rng(seed)
    hulls = []
    for _ in range(count):
        n = int(rng.integers(16, 25))
        p = rng.normal(size=(n, 3))
        p /= np.linalg.norm(p, axis=1)[:, None]
        size = rng.uniform(0.3, 0.5)
        axes = rng.uniform(0.7, 1.0, 3)
        hulls.append(convex_hull(p * axes / axes.max() * size / 2))
    return hulls


def random_pairs(count: int, hulls: int, near: float, far: float, seed: int):
    rng = np.random.default_rng(seed)
    a = rng.integers(0, hulls, count)
    b = (a + rng.integers(1, hulls, count)) % hulls
    ra = Rotation.random(count, random_state=seed).as_matrix()
    rb = Rotation.random(count, random_state=seed + 1).as_matrix()
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    pb = direction * rng.uniform(near, far, (count, 1))
    return a, b, ra, rb, np.zeros((count, 3)), pb


@njit
def distance_loop(vertex_start, vertices, adjacency_start, adjacency, a, b, ra, rb, pa, pb, out):
    """The narrow phase's way: every pair's GJK distance from inside a compiled loop."""
    for k in range(len(a)):
        i, j = a[k], b[k]
        a_core = Core(vertices[vertex_start[i]:vertex_start[i + 1]],
                      adjacency_start[vertex_start[i]:vertex_start[i + 1] + 1], adjacency, pa[k], ra[k])
        b_core = Core(vertices[vertex_start[j]:vertex_start[j + 1]],
                      adjacency_start[vertex_start[j]:vertex_start[j + 1] + 1], adjacency, pb[k], rb[k])
        d, _, _, _, _ = gjk_distance(a_core, 0.0, b_core, 0.0)
        out[k] = d


@njit
def penetration_loop(vertex_start, vertices, adjacency_start, adjacency, a, b, ra, rb, pa, pb, out):
    for k in range(len(a)):
        i, j = a[k], b[k]
        a_core = Core(vertices[vertex_start[i]:vertex_start[i + 1]],
                      adjacency_start[vertex_start[i]:vertex_start[i + 1] + 1], adjacency, pa[k], ra[k])
        b_core = Core(vertices[vertex_start[j]:vertex_start[j + 1]],
                      adjacency_start[vertex_start[j]:vertex_start[j + 1] + 1], adjacency, pb[k], rb[k])
        s, _, _, _ = penetration(a_core, 0.0, b_core, 0.0)
        out[k] = s


def ours_from_python(hulls, pairs):
    a, b, ra, rb, pa, pb = pairs
    out = np.empty(len(a))
    for k in range(len(a)):
        ha, hb = hulls[a[k]], hulls[b[k]]
        # (plain tuples at the Python → compiled border: see "Bundles" in cgp_core.jit)
        out[k] = gjk_distance((ha.vertices, ha.adjacency_start, ha.adjacency, pa[k], ra[k]), 0.0,
                              (hb.vertices, hb.adjacency_start, hb.adjacency, pb[k], rb[k]), 0.0)[0]
    return out


def fcl_objects(fcl, hulls):
    objects = []
    for h in hulls:
        faces = np.column_stack([np.full(len(h.triangles), 3), h.triangles]).ravel()
        objects.append(fcl.CollisionObject(fcl.Convex(h.vertices, len(h.triangles), faces), fcl.Transform()))
    return objects


def fcl_distances(fcl, objects, pairs):
    a, b, ra, rb, pa, pb = pairs
    out = np.empty(len(a))
    request = fcl.DistanceRequest()
    for k in range(len(a)):
        oa, ob = objects[a[k]], objects[b[k]]
        oa.setTransform(fcl.Transform(ra[k], pa[k]))
        ob.setTransform(fcl.Transform(rb[k], pb[k]))
        result = fcl.DistanceResult()
        out[k] = fcl.distance(oa, ob, request, result)
    return out


def fcl_penetrations(fcl, objects, pairs):
    a, b, ra, rb, pa, pb = pairs
    out = np.empty(len(a))
    request = fcl.CollisionRequest(enable_contact=True, num_max_contacts=1)
    for k in range(len(a)):
        oa, ob = objects[a[k]], objects[b[k]]
        oa.setTransform(fcl.Transform(ra[k], pa[k]))
        ob.setTransform(fcl.Transform(rb[k], pb[k]))
        result = fcl.CollisionResult()
        fcl.collide(oa, ob, request, result)
        out[k] = -result.contacts[0].penetration_depth if result.contacts else 0.0
    return out


def heightfield(cells: int, size: float = 100.0):
    xs = np.linspace(-size / 2, size / 2, cells + 1)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    z = 0.5 * np.sin(x * 0.3) * np.cos(y * 0.2)
    vertices = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    index = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return vertices, triangles


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--hulls", type=int, default=100)
    parser.add_argument("--quick", action="store_true", help="fewer rounds (benchmarks/run.py --quick)")
    args = parser.parse_args(argv)
    if args.quick:
        args.rounds = min(args.rounds, 2)
    out = Results("gjk", options=vars(args))
    hulls = pile_hulls(args.hulls)
    hs = HullSet.from_hulls(hulls)
    apart = random_pairs(args.pairs, len(hulls), 0.45, 0.9, seed=1)
    overlapping = random_pairs(args.pairs, len(hulls), 0.1, 0.3, seed=2)
    csr = (hs.vertex_start, hs.vertices, hs.adjacency_start, hs.adjacency)
    d_loop, s_loop = np.empty(args.pairs), np.empty(args.pairs)
    distance_loop(*csr, *apart, d_loop)  # compile / load
    penetration_loop(*csr, *overlapping, s_loop)
    d_python = ours_from_python(hulls, apart)
    try:
        import fcl
    except ImportError:
        fcl = None
        print("python-fcl is not installed (pip install -r requirements/bench.txt): FCL figures skipped")
    times = {"ours_python": [], "ours_loop": [], "fcl": [], "ours_penetration": [], "fcl_penetration": []}
    if fcl is not None:
        objects = fcl_objects(fcl, hulls)
        d_fcl = fcl_distances(fcl, objects, apart)
        s_fcl = fcl_penetrations(fcl, objects, overlapping)
    for _ in range(args.rounds):  # interleaved
        t0 = time.perf_counter()
        ours_from_python(hulls, apart)
        t1 = time.perf_counter()
        distance_loop(*csr, *apart, d_loop)
        t2 = time.perf_counter()
        penetration_loop(*csr, *overlapping, s_loop)
        t3 = time.perf_counter()
        times["ours_python"].append(t1 - t0)
        times["ours_loop"].append(t2 - t1)
        times["ours_penetration"].append(t3 - t2)
        if fcl is not None:
            t4 = time.perf_counter()
            fcl_distances(fcl, objects, apart)
            t5 = time.perf_counter()
            fcl_penetrations(fcl, objects, overlapping)
            t6 = time.perf_counter()
            times["fcl"].append(t5 - t4)
            times["fcl_penetration"].append(t6 - t5)
    rate = {k: args.pairs / float(np.median(v)) if v else None for k, v in times.items()}
    assert np.array_equal(d_python, d_loop), "the compiled loop and the Python calls disagree"
    agreement = float(np.max(np.abs(d_loop - d_fcl))) if fcl is not None else None
    overlapping_fraction = float(np.mean(s_loop < 0))
    # FCL's default solver (libccd) measures the depth by MPR, along the centres' line, which is not the minimum:
    # EPA's depth is never larger (tests/test_gjk_epa.py checks ours against the exact minimum)
    not_deeper = float(np.mean(-s_loop <= -s_fcl + 1e-9)) if fcl is not None else None
    median_gap = float(np.median(np.abs(s_loop - s_fcl))) if fcl is not None else None
    out.figure("gjk_ours_loop_qps", "GJK distance, ours in a compiled loop [queries/s]", rate["ours_loop"], "1/s",
               ">= FCL's", None if fcl is None else rate["ours_loop"] >= rate["fcl"])
    out.figure("gjk_ours_python_qps", "GJK distance, ours called from Python [queries/s]", rate["ours_python"], "1/s",
               "reference", None)
    out.figure("gjk_fcl_qps", "GJK distance, python-fcl (fcl.distance, Convex) [queries/s]", rate["fcl"], "1/s",
               "reference", None)
    out.figure("gjk_agreement", "max |ours - FCL| distance over the pairs", agreement, "m", "<= 1e-5",
               None if agreement is None else agreement <= 1e-5)
    out.figure("epa_ours_loop_qps", "GJK+EPA penetration, ours in a compiled loop [queries/s]",
               rate["ours_penetration"], "1/s", ">= FCL's",
               None if fcl is None else rate["ours_penetration"] >= rate["fcl_penetration"])
    out.figure("epa_fcl_qps", "GJK+EPA penetration, python-fcl (fcl.collide, contacts)", rate["fcl_penetration"],
               "1/s", "reference", None)
    out.figure("epa_not_deeper", f"pairs where our depth <= FCL's MPR depth ({overlapping_fraction:.0%} overlap)",
               not_deeper, "", "1 (EPA: minimum)", None if not_deeper is None else not_deeper == 1.0)
    out.figure("epa_median_gap", "median |our depth - FCL's MPR depth|", median_gap, "m", "reference", None)
    # the BVH
    StaticMesh.build(*heightfield(4))  # compile / load
    bvh_rows = []
    for name, (vertices, triangles) in (("terrain.obj", load_mesh(ROOT / "msgs_config" / "meshes" / "terrain.obj")),
                                        ("heightfield 100k", heightfield(224))):
        builds = [StaticMesh.build(vertices, triangles) for _ in range(3)]
        seconds = float(np.median([m.build_seconds for m in builds]))
        mesh = builds[0]
        bvh_rows.append({"mesh": name, "triangles": len(triangles), "nodes": len(mesh.node_count),
                         "build_ms": seconds * 1e3, "bvh_bytes": mesh.bvh_nbytes, "mesh_bytes": mesh.nbytes})
        out.figure(f"bvh_build_{len(triangles)}", f"BVH build, {name} ({len(triangles)} triangles)", seconds * 1e3,
                   "ms", "reference", None)
        out.figure(f"bvh_bytes_{len(triangles)}", f"BVH memory, {name} (nodes, order, triangle boxes)",
                   mesh.bvh_nbytes / 1e6, "MB", "reference", None)
    out.data["bvh"] = bvh_rows
    out.data["rates"] = rate
    path = out.write()
    print(format_figures(out.data["figures"]))
    print(format_speed_probe(out.data["speed_probe"]) + f"; load {os.getloadavg()[0]:.2f}")
    print(f"wrote {path.relative_to(ROOT)}")
    return 0 if math.isfinite(rate["ours_loop"]) else 1


if __name__ == "__main__":
    sys.exit(main())
