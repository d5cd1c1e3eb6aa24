"""Issue 25's kernels — GJK, EPA, the hull and mesh manifolds, the BVH build and queries, time of impact —
compiled and as plain Python (NUMBA_DISABLE_JIT=1) give the same results bit for bit, on fixed cases, in two
processes (as tests/test_jit_parity.py does for the step)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

SCRIPT = r"""
import sys
import numpy as np
from scipy.spatial.transform import Rotation
from cgp_core.jit import JIT_DISABLED
from cgp_core.collision.bvh import StaticMesh, bvh_closest_point, bvh_overlap, bvh_raycast
from cgp_core.collision.convex import PosedHull, box_hull, convex_hull
from cgp_core.collision.epa import penetration
from cgp_core.collision.gjk import Core, gjk_distance
from cgp_core.collision.manifold import (hull_capsule_contacts, hull_hull_contacts, plane_hull_contacts,
                                         triangle_hull_contacts)
from cgp_core.collision.mesh_contacts import mesh_capsule_contacts, mesh_hull_contacts
from cgp_core.collision.narrowphase import ContactBuffer
from cgp_core.collision.toi import MovingCore, time_of_impact

assert JIT_DISABLED == (sys.argv[2] == "plain"), "NUMBA_DISABLE_JIT did not reach the child"
rng = np.random.default_rng(25)
hulls = [convex_hull(rng.normal(size=(20, 3)) * 0.15) for _ in range(6)] + [box_hull([0.3, 0.2, 0.1])]
p = rng.normal(size=(200, 3))
hulls.append(convex_hull(p / np.linalg.norm(p, axis=1)[:, None] * 0.3))  # hill climbing
rotations = Rotation.random(len(hulls), random_state=1).as_matrix()
out = []
def core(h, position, rotation):
    return Core(h.vertices, h.adjacency_start, h.adjacency, position, rotation)
def posed(h, position, rotation):
    return PosedHull(h.vertices, h.adjacency_start, h.adjacency, h.face_plane, h.face_vertex_start, h.face_vertices,
                     position, rotation)
n, s, q, f = np.zeros((64, 3)), np.zeros(64), np.zeros((64, 3)), np.zeros(64, np.int64)
out_buffer = ContactBuffer(n, s, q, f)
for i in range(len(hulls)):
    for j in range(len(hulls)):
        if i == j:
            continue
        pb = rng.normal(size=3) * 0.3
        d, hit, pa_, pb_, nn = gjk_distance(core(hulls[i], np.zeros(3), rotations[i]), 0.01,
                                            core(hulls[j], pb, rotations[j]), 0.02)
        out.append([d, float(hit), *pa_, *pb_, *nn])
        sep, nn, pa_, pb_ = penetration(core(hulls[i], np.zeros(3), rotations[i]), 0.0,
                                        core(hulls[j], pb, rotations[j]), 0.0)
        out.append([sep, *nn, *pa_, *pb_])
        m = hull_hull_contacts(posed(hulls[i], np.zeros(3), rotations[i]), posed(hulls[j], pb, rotations[j]), 0.05,
                               out_buffer, 0)
        out += [[*n[k], s[k], *q[k], float(f[k])] for k in range(m)]
    m = plane_hull_contacts(posed(hulls[i], np.array([0, 0, 0.1]), rotations[i]), 0.05, 0, out_buffer, 0)
    out += [[*n[k], s[k], *q[k], float(f[k])] for k in range(m)]
    m = hull_capsule_contacts(posed(hulls[i], np.zeros(3), rotations[i]), np.array([[0.0, 0, 0.2], [0.3, 0, 0.25]]),
                              0.05, 0.05, out_buffer, 0)
    out += [[*n[k], s[k], *q[k], float(f[k])] for k in range(m)]
    triangle = np.array([[-1.0, -1, 0], [1, -1, 0], [0, 1, 0.05]])
    m = triangle_hull_contacts(triangle, np.uint8(5), False, posed(hulls[i], np.array([0, 0, 0.12]), rotations[i]),
                               0.05, out_buffer, 0)
    out += [[*n[k], s[k], *q[k], float(f[k])] for k in range(m)]
    h, o = hulls[i], hulls[-2]
    t, sep, nn, hit, it = time_of_impact(
        MovingCore(h.vertices, h.adjacency_start, h.adjacency, np.zeros(3), np.eye(3), np.array([0.0, 0, 0]),
                   np.array([0.0, 0, 200.0]), 0.0),
        MovingCore(o.vertices, o.adjacency_start, o.adjacency, np.array([0.0, 0.9, 0]), np.eye(3), np.zeros(3),
                   np.zeros(3), 0.0), 1 / 60, 1e-3, 1e-5)
    out.append([t, sep, *nn, float(hit), float(it)])
x, y = np.meshgrid(np.linspace(-2, 2, 20), np.linspace(-2, 2, 20), indexing="ij")
vertices = np.column_stack([x.ravel(), y.ravel(), 0.2 * np.sin(x.ravel() * 2) * np.cos(y.ravel())])
index = np.arange(400).reshape(20, 20)
triangles = np.array([t for i in range(19) for j in range(19) for t in (
    (index[i, j], index[i + 1, j], index[i + 1, j + 1]), (index[i, j], index[i + 1, j + 1], index[i, j + 1]))])
mesh = StaticMesh.build(vertices, triangles)
out.append(np.concatenate([mesh.node_lo.ravel(), mesh.node_hi.ravel(), mesh.node_child_or_first,
                           mesh.node_count, mesh.triangle_order]).tolist())
found = np.empty(len(triangles), np.int64)
for k in range(50):
    c = rng.uniform(-2, 2, 3)
    cnt = bvh_overlap(mesh.arrays, c - 0.3, c + 0.3, found)
    out.append(found[:cnt].astype(float).tolist())
    out.append(list(bvh_closest_point(mesh.arrays, c, np.inf)))
    out.append(list(bvh_raycast(mesh.arrays, c + [0, 0, 1], rng.normal(size=3), 5.0)))
Rm = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix()
pm = np.array([0.3, -0.2, 0.1])
for i, h in enumerate(hulls):
    pos = pm + Rm @ np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 0.12])
    m, ok = mesh_hull_contacts(mesh.arrays, pm, Rm, False, posed(h, pos, rotations[i]), 0.05, found, out_buffer, 0)
    out += [[*n[k], s[k], *q[k], float(f[k]), float(ok)] for k in range(m)]
    m, ok = mesh_capsule_contacts(mesh.arrays, pm, Rm, False, np.array([pos, pos + [0.3, 0.1, 0.05]]), 0.1, 0.05,
                                  found, out_buffer, 0)
    out += [[*n[k], s[k], *q[k], float(f[k]), float(ok)] for k in range(m)]
flat = np.concatenate([np.asarray(row, dtype=float).ravel() for row in out])
np.save(sys.argv[1], flat)
"""


def run(tmp_path, mode: str) -> np.ndarray:
    env = os.environ.copy()
    env.pop("NUMBA_DISABLE_JIT", None)
    if mode == "plain":
        env["NUMBA_DISABLE_JIT"] = "1"
    path = tmp_path / f"{mode}.npy"
    done = subprocess.run([sys.executable, "-c", SCRIPT, str(path), mode], env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return np.load(path)


def test_geometry_kernels_compiled_and_plain_give_the_same_bits(tmp_path):
    compiled = run(tmp_path, "compiled")
    plain = run(tmp_path, "plain")
    assert compiled.size > 3000  # every kernel wrote something
    np.testing.assert_array_equal(compiled, plain)
