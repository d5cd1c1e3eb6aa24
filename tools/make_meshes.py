#!/usr/bin/env python3
"""Write the small mesh files the scenes use into ``msgs_config/meshes/`` (deterministic: seeded; rerun after a
change here and commit the files).

- ``rock.stl`` (binary STL): the convex hull of 48 seeded random points on a lumpy ellipsoid, 0.4 m across
  (~90 triangles) — a rock for ``convex_pile``.
- ``terrain.obj`` (OBJ): a 10 m × 10 m heightfield, a 24 × 24 grid of cells (1,152 triangles), gentle seeded
  hills of ±0.4 m — the static mesh the pile lands on.  Open (a surface, not a solid).
- ``mug.obj`` (OBJ): a cup as a closed surface of revolution (outer wall, rim, inner wall, floor: concave),
  8 cm radius, 10 cm high, 24 segments — a closed concave mesh (static; or its hull for a movable body).
- ``triangle.obj`` (OBJ): one triangle, 2 m wide and 2 m high, in the plane x = 0 facing −x — the ``bullet``
  scene's mesh wall (a single triangle: nothing behind it to catch what gets through).

Usage: ``.venv/bin/python tools/make_meshes.py`` (needs only numpy and scipy).
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from cgp_core.collision.convex import convex_hull  # noqa: E402
from cgp_core.inertia import polyhedron_mass_properties  # noqa: E402

OUT = REPO / "msgs_config" / "meshes"


def write_binary_stl(path: Path, vertices: np.ndarray, triangles: np.ndarray, header: str) -> None:
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    with open(path, "wb") as out:
        out.write(header.encode("ascii")[:80].ljust(80, b" "))
        out.write(struct.pack("<I", len(triangles)))
        for n, p, q, r in zip(normal, a, b, c, strict=True):
            out.write(struct.pack("<12fH", *n, *p, *q, *r, 0))


def write_obj(path: Path, vertices: np.ndarray, triangles: np.ndarray, comment: str) -> None:
    lines = [f"# {line}" for line in comment.splitlines()]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in triangles]
    path.write_text("\n".join(lines) + "\n")


def rock() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(25)
    direction = rng.normal(size=(48, 3))
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    lumps = 1.0 + 0.15 * rng.uniform(-1.0, 1.0, size=48)
    points = direction * lumps[:, None] * np.array([0.2, 0.16, 0.13])
    hull = convex_hull(points, what="rock")
    # float32 (STL) round trip first, so that the file's hull is the hull of what is written
    return hull.vertices.astype(np.float32).astype(float), hull.triangles


def terrain() -> tuple[np.ndarray, np.ndarray]:
    cells, size = 24, 10.0
    rng = np.random.default_rng(2025)
    xs = np.linspace(-size / 2, size / 2, cells + 1)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    z = np.zeros_like(x)
    for _ in range(6):  # gentle hills: a few Gaussian bumps
        cx, cy = rng.uniform(-size / 2, size / 2, 2)
        height, width = rng.uniform(-0.4, 0.4), rng.uniform(1.0, 2.5)
        z += height * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * width**2))
    vertices = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    index = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    triangles = []
    for i in range(cells):
        for j in range(cells):
            a, b, c, d = index[i, j], index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]
            triangles += [(a, b, c), (a, c, d)]  # counter-clockwise seen from above
    return vertices, np.array(triangles)


def mug() -> tuple[np.ndarray, np.ndarray]:
    radius, height, wall, floor, segments = 0.08, 0.10, 0.008, 0.01, 24
    # the profile (r, z) from the outer bottom's centre around to the inner floor's centre
    profile = [(0.0, 0.0), (radius, 0.0), (radius, height), (radius - wall, height), (radius - wall, floor),
               (0.0, floor)]
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    vertices, rings = [], []
    for r, z in profile:
        if r == 0.0:
            rings.append([len(vertices)] * segments)
            vertices.append((0.0, 0.0, z))
        else:
            rings.append(list(range(len(vertices), len(vertices) + segments)))
            vertices += [(r * np.cos(a), r * np.sin(a), z) for a in angles]
    triangles = []
    for p in range(len(profile) - 1):
        lower, upper = rings[p], rings[p + 1]
        for s in range(segments):
            t = (s + 1) % segments
            quad = (lower[s], lower[t], upper[t], upper[s])
            for tri in ((quad[0], quad[1], quad[2]), (quad[0], quad[2], quad[3])):
                if len(set(tri)) == 3:
                    triangles.append(tri)
    triangles = np.array(triangles)
    vertices = np.array(vertices)
    # the profile runs outward along the bottom, so the winding above faces out; check (volume > 0)
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    if np.einsum("ij,ij->", a, np.cross(b, c)) < 0.0:
        triangles = triangles[:, [0, 2, 1]]
    return vertices, triangles


def triangle() -> tuple[np.ndarray, np.ndarray]:
    vertices = np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]])
    return vertices, np.array([[0, 2, 1]])  # counter-clockwise seen from −x: its front faces −x


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    v, t = rock()
    write_binary_stl(OUT / "rock.stl", v, t, "cgp_sim rock: tools/make_meshes.py (seed 25)")
    volume = polyhedron_mass_properties(v, t, density=1.0, what="rock")[3]
    print(f"rock.stl: {len(v)} vertices, {len(t)} triangles, {volume * 1e3:.3f} l")
    v, t = terrain()
    write_obj(OUT / "terrain.obj", v, t, "cgp_sim terrain: tools/make_meshes.py (seed 2025)\n10 m x 10 m heightfield")
    print(f"terrain.obj: {len(v)} vertices, {len(t)} triangles")
    v, t = mug()
    write_obj(OUT / "mug.obj", v, t, "cgp_sim mug: tools/make_meshes.py\na closed concave surface of revolution")
    volume = polyhedron_mass_properties(v, t, density=1.0, what="mug")[3]
    print(f"mug.obj: {len(v)} vertices, {len(t)} triangles, {volume * 1e6:.1f} cm³ of material")
    v, t = triangle()
    write_obj(OUT / "triangle.obj", v, t, "cgp_sim one-triangle wall: tools/make_meshes.py\nfront faces -x")
    print(f"triangle.obj: {len(v)} vertices, {len(t)} triangle")
    return 0


if __name__ == "__main__":
    sys.exit(main())
