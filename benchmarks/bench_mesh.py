"""Benchmark (issue 38): fine static meshes — a box resting on a 1 cm grid, side by side with PyBullet — and the
cost of loading a big mesh file.

**Contacts.** A 1 × 1 × 1 m box (1 kg) resting on a flat grid of 1 cm squares (two triangles each), the grid
a static mesh (``shape: mesh``, one-sided, no ground plane), at 60 Hz with 4 sub-steps (the node's tick).  Grids
of 100 × 100 cells (20,000 triangles, all under the box) and 200 × 200 (80,000: the issue's case).  Measured
per tick after 1 s of settling: the median wall time of ``World.step``, and of PyBullet's 4 ``stepSimulation``
calls at 1/240 s on the same mesh (``createCollisionShape(GEOM_MESH)``, a static multibody: its BVH triangle
mesh) and box, interleaved tick by tick in the same process.  The issue's target: within 2x PyBullet's.  Also:
where our tick's time goes (the detector's and the solver's stages, :func:`common.stage_times`), how many
contact points the box has (one reduced manifold: at most 4) and how far it sank.

**Loading.** A 501 × 501 grid (500,000 triangles, a 25 MB binary STL): the file's parse
(:func:`cgp_core.collision.meshfile.load_mesh`), the BVH build, the active edges, and the same as ASCII STL of
many ``solid`` blocks and OBJ of many groups (the issue measured 55 s for the active edges alone and
quadratic parsers).

Plain script: prints a table and writes ``benchmarks/results/mesh.json`` (layout: ``benchmarks/common.py``).

    .venv/bin/python benchmarks/bench_mesh.py [--quick] [--no-pybullet]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from common import (  # noqa: E402
    Results,
    format_figures,
    format_speed_probe,
    format_stage_times,
    reset_stage_times,
    stage_times,
)

from cgp_core.collision.bvh import active_edges, build_bvh  # noqa: E402
from cgp_core.collision.meshfile import load_mesh  # noqa: E402
from cgp_core.scene import parse_scene  # noqa: E402
from cgp_core.world import World  # noqa: E402

CELL = 0.01  # m
RATE_HZ = 60.0
SUBSTEPS = 4


def grid(cells: int, cell: float = CELL) -> tuple[np.ndarray, np.ndarray]:
    """A flat square grid centred on the origin, z = 0, facing +z: ``(vertices ((cells + 1)², 3), triangles
    (2 cells², 3))``."""
    xs = (np.arange(cells + 1) - cells / 2) * cell
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    index = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return vertices, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def write_binary_stl(path: pathlib.Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    record = np.zeros(len(triangles), dtype=[("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    record["corners"] = vertices[triangles]
    path.write_bytes(b"\0" * 80 + np.uint32(len(triangles)).tobytes() + record.tobytes())


def write_ascii_stl_solids(path: pathlib.Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    """One ``solid`` per triangle."""
    with open(path, "w") as out:
        for i, corners in enumerate(vertices[triangles]):
            out.write(f"solid s{i}\nfacet normal 0 0 1\nouter loop\n")
            out.writelines(f"vertex {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in corners)
            out.write(f"endloop\nendfacet\nendsolid s{i}\n")


def write_obj_groups(path: pathlib.Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    """A group and a material per triangle."""
    with open(path, "w") as out:
        out.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in vertices)
        out.writelines(f"g g{i}\nusemtl m{i}\nf {a + 1} {b + 1} {c + 1}\n"
                       for i, (a, b, c) in enumerate(triangles))


def box_on_grid(path: pathlib.Path) -> World:
    text = f"""
world: {{ground: false, substeps: {SUBSTEPS}, sleep: false}}
bodies:
  - {{name: grid, shape: mesh, mesh: {path}, fixed: true}}
  - {{name: box, shape: box, size: [1, 1, 1], mass: 1.0, position: [0.003, 0.002, 0.5]}}
"""
    return World(parse_scene(text, str(path.with_suffix(".yaml"))), dt=1.0 / RATE_HZ)


def pybullet_box_on_grid(vertices: np.ndarray, triangles: np.ndarray):
    import pybullet

    client = pybullet.connect(pybullet.DIRECT)
    pybullet.setGravity(0, 0, -9.81, physicsClientId=client)
    pybullet.setTimeStep(1.0 / (RATE_HZ * SUBSTEPS), physicsClientId=client)
    shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices.tolist(),
                                          indices=triangles.ravel().tolist(), physicsClientId=client)
    pybullet.createMultiBody(0.0, shape, physicsClientId=client)
    box = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[0.5, 0.5, 0.5], physicsClientId=client)
    body = pybullet.createMultiBody(1.0, box, basePosition=[0.003, 0.002, 0.5], physicsClientId=client)

    def tick():
        for _ in range(SUBSTEPS):
            pybullet.stepSimulation(physicsClientId=client)

    def height():
        return pybullet.getBasePositionAndOrientation(body, physicsClientId=client)[0][2]

    return tick, height, lambda: pybullet.disconnect(client)


def contacts_rows(args, out: Results, work: pathlib.Path) -> None:
    for cells in args.grids:
        vertices, triangles = grid(cells)
        path = work / f"grid{cells}.stl"
        write_binary_stl(path, vertices, triangles)
        world = box_on_grid(path)
        peer = None
        if not args.no_pybullet:
            try:
                peer = pybullet_box_on_grid(vertices, triangles)
            except ImportError:
                print("PyBullet not installed (pip install pybullet): ours alone")
        for _ in range(int(RATE_HZ)):  # 1 s of settling (and the kernels' first calls)
            world.step()
            if peer:
                peer[0]()
        ours, theirs = [], []
        reset_stage_times(world.solver)
        for _ in range(args.ticks):
            start = time.perf_counter()
            world.step()
            ours.append(time.perf_counter() - start)
            if peer:
                start = time.perf_counter()
                peer[0]()
                theirs.append(time.perf_counter() - start)
        stages = stage_times(world.solver, args.ticks * SUBSTEPS)
        box = world.body_model.names.index("box")
        sank = 0.5 - float(world.body_state.position[box, 2])
        world.report_contacts = True  # (one tick more, reported: how many points the box has)
        world.step()
        points = int(np.sum(world.contacts.body_b == box))
        ours_ms = 1e3 * float(np.median(ours))
        row = {"triangles": len(triangles), "ours_ms": ours_ms, "sank_m": sank, "contact_points": points,
               "stages_ms_per_substep": stages}
        line = f"box on a {cells} x {cells} grid ({len(triangles):,} triangles): ours {ours_ms:.1f} ms/tick"
        if peer:
            theirs_ms = 1e3 * float(np.median(theirs))
            row.update(pybullet_ms=theirs_ms, ratio=ours_ms / theirs_ms, pybullet_sank_m=0.5 - peer[1]())
            line += f", PyBullet {theirs_ms:.1f} ms/tick: {ours_ms / theirs_ms:.2f}x"
            peer[2]()
        print(line + f"; box {sank * 1e3:.3f} mm below its resting height, {points} contact points")
        print(format_stage_times(stages))
        out.data.setdefault("contacts", []).append(row)
        target = "<= 2x PyBullet's" if peer else "<= 2x PyBullet's (PyBullet absent)"
        out.figure(f"mesh_box_{len(triangles) // 1000}k_tick_ms", f"1 m box resting on a 1 cm grid of "
                   f"{len(triangles):,} triangles: tick (4 sub-steps)", round(ours_ms, 1), "ms", target,
                   (ours_ms <= 2.0 * row["pybullet_ms"]) if peer else None, issue12=True,
                   pybullet_ms=round(row.get("pybullet_ms", float("nan")), 1))


def loading_rows(args, out: Results, work: pathlib.Path) -> None:
    vertices, triangles = grid(args.load_cells)
    files = {"binary STL": work / "big.stl", "ASCII STL, a solid per triangle": work / "solids.stl",
             "OBJ, a group per triangle": work / "groups.obj"}
    write_binary_stl(files["binary STL"], vertices, triangles)
    few = grid(args.text_cells)
    write_ascii_stl_solids(files["ASCII STL, a solid per triangle"], *few)
    write_obj_groups(files["OBJ, a group per triangle"], *few)
    for what, path in files.items():
        start = time.perf_counter()
        v, t = load_mesh(path)
        parse = time.perf_counter() - start
        print(f"{what}: {path.stat().st_size / 1e6:.1f} MB, {len(t):,} triangles parsed in {parse:.2f} s")
        out.data.setdefault("loading", []).append({"file": what, "MB": path.stat().st_size / 1e6,
                                                   "triangles": len(t), "parse_s": parse})
    v, t = load_mesh(files["binary STL"])
    build_bvh(v[:3], t[:1])  # (compiled before it is timed)
    start = time.perf_counter()
    build_bvh(v, t)
    bvh = time.perf_counter() - start
    start = time.perf_counter()
    active_edges(v, t)
    edges = time.perf_counter() - start
    print(f"{len(t):,} triangles: BVH built in {bvh:.2f} s, active edges in {edges:.2f} s")
    out.data["build"] = {"triangles": len(t), "bvh_s": bvh, "active_edges_s": edges}
    out.figure("mesh_500k_active_edges_s", f"active edges of {len(t):,} triangles", round(edges, 2), "s",
               "the issue measured 55 s", None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer ticks, smaller files")
    parser.add_argument("--no-pybullet", action="store_true")
    parser.add_argument("--grids", type=int, nargs="+", default=[100, 200], help="grid sizes in cells per side")
    args = parser.parse_args()
    args.ticks = 10 if args.quick else 30
    args.load_cells = 200 if args.quick else 500
    args.text_cells = 100 if args.quick else 200
    out = Results("mesh", options=vars(args))
    with tempfile.TemporaryDirectory() as tmp:
        contacts_rows(args, out, pathlib.Path(tmp))
        loading_rows(args, out, pathlib.Path(tmp))
    path = out.write()
    print(format_figures(out.data["figures"]))
    print(format_speed_probe(out.data["speed_probe"]))
    print(f"written: {path}")


if __name__ == "__main__":
    main()
