"""How to draw a bag's markers without a display: the candidates compared on speed and look, and the headline
figure of issue 15 (20 s of the default scene at 30 fps to MP4 with ``cgp-sim-render``).

Candidates, each drawing the same frame (the default scene at t = 10 s: 300 fish = 3,000 triangles, the
bodies, the 60 m ground as 2 m checker tiles, 960 x 540, the same camera and light), all headless on the CPU,
all from PyPI:

- ``zbuffer``: ours (cgp_sim_ros/render/raster.py): numba-compiled z-buffer, exact shaded spheres, 2 x 2
  supersampling (and ``zbuffer-ss1`` without);
- ``pillow``: a painter's algorithm with Pillow's ImageDraw (every triangle and sphere projected, sorted back to
  front by depth, filled flat; spheres as discs), drawn at 2x and downsampled (Lanczos) for anti-aliasing;
- ``matplotlib``: mplot3d (Poly3DCollection for the triangles with the same flat shading, scatter for the
  spheres), Agg canvas.

Not candidates: VTK / PyVista, pyrender, moderngl, Open3D — their PyPI wheels need a system OpenGL (EGL /
OSMesa / X) library to render off screen, which ``pip`` cannot install (and this project's users run from
wheels).

Each candidate's median time per frame over ``--repeats`` renders (after one warm-up), and its picture in
``results/render_<name>.png`` to compare the look.  Then the whole command: a 20 s bag of the default scene
recorded by the node (``realtime:=false``), rendered by ``cgp-sim-render -o out.mp4`` at its defaults
(960 x 540, 30 fps), wall time of the command.

    .venv/bin/python benchmarks/bench_render.py [--repeats 5] [--skip-mp4]
"""

from __future__ import annotations

import argparse
import math
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
os.environ.setdefault("CGP_SIM_BENCH_DOMAIN", str(random.Random(os.getpid() + 1).randint(1, 101)))
os.environ["ROS_DOMAIN_ID"] = os.environ["CGP_SIM_BENCH_DOMAIN"]

from common import RESULTS, Results  # noqa: E402

from cgp_sim_ros.render.primitives import MarkerSet, extent_points, primitives  # noqa: E402
from cgp_sim_ros.render.raster import AMBIENT, DIFFUSE, LIGHT_DIRECTION, SKY_BOTTOM, SKY_TOP, Camera, Rasterizer  # noqa: E402
from cgp_sim_ros.wire import cdr  # noqa: E402

WIDTH, HEIGHT = 960, 540
VENV_BIN = Path(sys.executable).parent


def default_scene_frame(seconds: float = 10.0):
    """The default scene's markers after ``seconds``, as the node serializes them, decoded as the renderer
    decodes them."""
    from cgp_core import World
    from cgp_sim_ros.ros.messages import TickMessages

    world = World.from_scene("default")
    for _ in range(round(seconds / world.dt)):
        world.step()
    markers = MarkerSet()
    markers.apply(cdr.read_marker_array(TickMessages(world).markers(world.time_ns)))
    return markers


def _flat_shade(prims, eye):
    """Per-triangle Lambert colours (two-sided), as raster.py shades them."""
    tri = prims.triangles
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    normal *= np.where(np.sum(normal * (eye - tri[:, 0]), axis=1) < 0, -1.0, 1.0)[:, None]
    light = LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION)
    return np.clip(prims.triangle_colors * (AMBIENT + DIFFUSE * np.clip(normal @ light, 0, None))[:, None], 0, 1)


def render_pillow(prims, camera, scale: int = 2) -> np.ndarray:
    from PIL import Image, ImageDraw

    W, H = WIDTH * scale, HEIGHT * scale
    axes = camera.axes()
    eye = np.asarray(camera.eye, float)
    focal = 0.5 * H / math.tan(math.radians(camera.fov_deg) / 2)
    rows = np.linspace(0, 1, H)[:, None, None]
    sky = ((1 - rows) * SKY_TOP + rows * SKY_BOTTOM) * np.ones((1, W, 1))
    image = Image.fromarray((sky * 255).astype(np.uint8))
    draw = ImageDraw.Draw(image)
    view = (prims.triangles - eye) @ axes.T
    keep = np.all(view[:, :, 2] > 0.05, axis=1)
    colors = (_flat_shade(prims, eye)[keep] * 255).astype(int)
    view = view[keep]
    px = 0.5 * W + focal * view[:, :, 0] / view[:, :, 2]
    py = 0.5 * H - focal * view[:, :, 1] / view[:, :, 2]
    items = [(float(view[i, :, 2].mean()), 0, i) for i in range(len(view))]
    sview = (prims.sphere_centers - eye) @ axes.T
    light = axes @ (LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION))
    items += [(float(sview[i, 2]), 1, i) for i in range(len(sview)) if sview[i, 2] > prims.sphere_radii[i]]
    items.sort(reverse=True)  # far to near
    for _depth, kind, i in items:
        if kind == 0:
            draw.polygon(list(zip(px[i], py[i])), fill=tuple(colors[i]))
        else:
            x, y, z = sview[i]
            r = focal * prims.sphere_radii[i] / z
            sx, sy = 0.5 * W + focal * x / z, 0.5 * H - focal * y / z
            shade = AMBIENT + DIFFUSE * max(0.0, -light[2])  # the normal facing the camera
            fill = tuple(int(c) for c in np.clip(prims.sphere_colors[i] * shade * 255, 0, 255))
            draw.ellipse([sx - r, sy - r, sx + r, sy + r], fill=fill)
    return np.asarray(image.resize((WIDTH, HEIGHT), Image.LANCZOS))


def render_matplotlib(prims, camera) -> np.ndarray:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    dpi = 100
    fig = plt.figure(figsize=(WIDTH / dpi, HEIGHT / dpi), dpi=dpi)
    ax = fig.add_axes([0, 0, 1, 1], projection="3d")
    ax.set_proj_type("persp", focal_length=1 / math.tan(math.radians(camera.fov_deg) / 2))
    eye = np.asarray(camera.eye, float)
    target = np.asarray(camera.target, float)
    d = eye - target
    ax.view_init(elev=math.degrees(math.atan2(d[2], math.hypot(d[0], d[1]))),
                 azim=math.degrees(math.atan2(d[1], d[0])))
    ax.add_collection3d(Poly3DCollection(prims.triangles, facecolors=_flat_shade(prims, eye), linewidths=0))
    ax.scatter(*prims.sphere_centers.T, s=(prims.sphere_radii * 60) ** 2, c=prims.sphere_colors, depthshade=True)
    half = 0.5 * np.linalg.norm(d) * math.tan(math.radians(camera.fov_deg) / 2)
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), target):
        setter(c - 2 * half, c + 2 * half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_axis_off()
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return image


def time_candidates(prims, camera, repeats: int) -> list[dict]:
    from PIL import Image

    zbuffer = Rasterizer(WIDTH, HEIGHT, supersample=2)
    zbuffer1 = Rasterizer(WIDTH, HEIGHT, supersample=1)
    candidates = {
        "zbuffer": lambda: zbuffer.render(prims, camera),
        "zbuffer-ss1": lambda: zbuffer1.render(prims, camera),
        "pillow": lambda: render_pillow(prims, camera),
        "matplotlib": lambda: render_matplotlib(prims, camera),
    }
    rows = []
    for name, draw in candidates.items():
        image = draw()  # warm-up (numba: load the cached kernels)
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            image = draw()
            times.append(time.perf_counter() - start)
        Image.fromarray(image).save(RESULTS / f"render_{name}.png")
        rows.append({"candidate": name, "median_ms": 1e3 * statistics.median(times), "min_ms": 1e3 * min(times),
                     "frames_per_s": 1.0 / statistics.median(times), "picture": f"results/render_{name}.png"})
        print(f"{name:12s} {rows[-1]['median_ms']:8.1f} ms per frame (median of {repeats})", flush=True)
    return rows


def time_mp4(seconds: float = 20.0) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        start = time.perf_counter()
        subprocess.run([str(VENV_BIN / "cgp-sim"), "--realtime", "false", "--duration", str(seconds), "--bag",
                        str(bag)], check=True, capture_output=True)
        record_s = time.perf_counter() - start
        start = time.perf_counter()
        subprocess.run([str(VENV_BIN / "cgp-sim-render"), str(bag), "-o", str(Path(tmp) / "out.mp4"), "-q"],
                       check=True)
        render_s = time.perf_counter() - start
        size = (Path(tmp) / "out.mp4").stat().st_size
    print(f"cgp-sim-render: {seconds:g} s of the default scene at 30 fps, 960x540 -> MP4 in {render_s:.1f} s "
          f"(recording the bag took {record_s:.1f} s)", flush=True)
    return {"sim_seconds": seconds, "render_s": render_s, "record_s": record_s, "mp4_bytes": size}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-mp4", action="store_true", help="only the per-frame comparison")
    args = parser.parse_args()
    out = Results("render", options=vars(args))
    markers = default_scene_frame()
    prims = primitives(markers)
    camera = Camera.framing(extent_points(markers), WIDTH / HEIGHT)
    out.data["frame"] = {"triangles": len(prims.triangles), "spheres": len(prims.sphere_centers),
                         "size": [WIDTH, HEIGHT]}
    rows = time_candidates(prims, camera, args.repeats)
    out.data["candidates"] = rows
    by = {r["candidate"]: r for r in rows}
    out.figure("render_frame_zbuffer", "one 960x540 frame of the default scene, cgp-sim-render's rasterizer "
               "(median)", round(by["zbuffer"]["median_ms"], 1), "ms", "(reference)", None)
    for other in ("pillow", "matplotlib"):
        out.figure(f"render_frame_{other}", f"the same frame with {other} / with ours",
                   round(by[other]["median_ms"] / by["zbuffer"]["median_ms"], 1), "x", "(reference)", None)
    if not args.skip_mp4:
        mp4 = time_mp4()
        out.data["mp4"] = mp4
        out.figure("render_20s_mp4", "cgp-sim-render: 20 s of the default scene at 30 fps (600 frames, 960x540) "
                   "to MP4, wall time", round(mp4["render_s"], 1), "s", "< 60", mp4["render_s"] < 60.0)
    out.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
