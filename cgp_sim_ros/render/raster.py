"""A small CPU rasterizer with a z-buffer: flat-shaded triangles and exact shaded spheres, supersampled.

Why our own (``benchmarks/bench_render.py`` measures the alternatives; the numbers are in benchmarks/README.md):
matplotlib's mplot3d sorts whole polygons by depth (painter's algorithm), so fish and bodies pierce one another
wrongly, and draws ~10 frames/s of this scene at best; Pillow's polygon fill is fast but also painter's
and draws spheres as flat discs; OpenGL-based libraries (VTK, pyrender, moderngl) need a system OpenGL /
OSMesa / EGL library that PyPI does not ship.  Two loops over pixels, compiled with numba (the project's
compiler for loops numpy cannot batch, :mod:`cgp_core.jit`), draw the scene correctly occluded in a few
milliseconds a frame.

Pipeline of :meth:`Rasterizer.render` (one frame):

1. **view**: world points to camera coordinates (x right, y up, z = depth along the view direction) and to
   pixels by the pinhole projection ``px = cx + f x / z``, ``py = cy - f y / z`` (f from the vertical field
   of view);
2. **shade** (numpy, per triangle): Lambert with one directional light and an ambient term, two-sided (the
   normal is turned towards the camera), ``color (ambient + diffuse max(0, n·l))``;
3. **rasterize triangles**: for each triangle the pixels of its bounding box whose centre has non-negative
   barycentric (edge-function) weights; depth interpolated as 1/z (perspective-correct); nearest wins;
4. **rasterize spheres**: each sphere is a disc of the projected radius whose per-pixel depth and normal are
   those of the sphere's visible hemisphere (``z = z_c - r sqrt(1 - d²)``), shaded per pixel with Lambert and a
   Blinn-Phong highlight — round at any size, with no tessellation;
5. **resolve**: the image is drawn at ``supersample`` times the output size and averaged down (anti-aliasing).

Back faces of closed surfaces (boxes, cylinders) are culled; open ones (triangle lists) are drawn from both
sides.  Triangles with a vertex closer than ``near`` (behind or at the camera) are dropped, not clipped: the
large faces that could cross the near plane (the ground) are cut into tiles by :mod:`.primitives`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cgp_core.jit import njit

from .primitives import Primitives

#: direction *towards* the light, world frame (from above, behind the default camera's right shoulder)
LIGHT_DIRECTION = np.array([0.35, -0.45, 0.82])
AMBIENT = 0.38
DIFFUSE = 0.62
SPECULAR = 0.25
SHININESS = 32.0
#: background: a vertical gradient from the horizon colour (bottom) to the zenith colour (top)
SKY_TOP = np.array([0.62, 0.74, 0.88])
SKY_BOTTOM = np.array([0.93, 0.95, 0.97])


@dataclass
class Camera:
    """A pinhole camera looking from ``eye`` at ``target``, z up (REP-103), ``fov_deg`` vertical field of view."""

    eye: np.ndarray
    target: np.ndarray
    fov_deg: float = 40.0
    up: tuple = (0.0, 0.0, 1.0)

    def axes(self) -> np.ndarray:
        """(3, 3) rows: right, up, forward (world frame)."""
        forward = np.asarray(self.target, float) - np.asarray(self.eye, float)
        norm = np.linalg.norm(forward)
        if norm < 1e-9:
            raise ValueError("camera eye and target are the same point")
        forward /= norm
        right = np.cross(forward, self.up)
        if np.linalg.norm(right) < 1e-6:  # looking straight up or down: any horizontal right will do
            right = np.cross(forward, (0.0, 1.0, 0.0))
        right /= np.linalg.norm(right)
        return np.stack([right, np.cross(right, forward), forward])

    @classmethod
    def framing(cls, points: np.ndarray, aspect: float, *, azimuth_deg: float = -60.0,
                elevation_deg: float = 25.0, fov_deg: float = 40.0, margin: float = 1.05) -> Camera:
        """A camera that sees all ``points`` (n, 3): aimed at the centre of their bounding box from the given
        azimuth (from +x, counter-clockwise seen from above) and elevation, at the least distance where every
        point is inside the field of view (``aspect`` = width / height), times ``margin``."""
        points = np.asarray(points, float).reshape(-1, 3)
        if not len(points):
            points = np.zeros((1, 3))
        target = 0.5 * (points.min(axis=0) + points.max(axis=0))
        az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
        direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        axes = cls(eye=target + direction, target=target, fov_deg=fov_deg).axes()
        tan_v = math.tan(math.radians(fov_deg) / 2)
        tan_h = tan_v * aspect
        local = (points - target) @ axes.T  # right, up, forward offsets from the target
        # a point at (x, y, z) is inside when |x| <= tan_h (d + z) and |y| <= tan_v (d + z)
        needed = np.maximum(np.abs(local[:, 0]) / tan_h, np.abs(local[:, 1]) / tan_v) - local[:, 2]
        # ... and in front of the camera, with room to spare
        distance = margin * max(float(needed.max()), float(np.max(-local[:, 2])) + 0.5, 1.0)
        return cls(eye=target + distance * direction, target=target, fov_deg=fov_deg)


@njit
def _raster_triangles(px, py, depth, colors, zbuf, image):  # pragma: no cover - compiled
    """px, py, depth: (T, 3) screen x, y and view depth of each vertex; colors (T, 3) shaded RGB;
    zbuf (H, W) float64 and image (H, W, 3) float32, written in place."""
    height, width = zbuf.shape
    for t in range(px.shape[0]):
        x0, x1, x2 = px[t, 0], px[t, 1], px[t, 2]
        y0, y1, y2 = py[t, 0], py[t, 1], py[t, 2]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        xmin = max(int(math.floor(min(x0, x1, x2))), 0)
        xmax = min(int(math.ceil(max(x0, x1, x2))), width - 1)
        ymin = max(int(math.floor(min(y0, y1, y2))), 0)
        ymax = min(int(math.ceil(max(y0, y1, y2))), height - 1)
        if xmin > xmax or ymin > ymax:
            continue
        inv_area = 1.0 / area
        iz0, iz1, iz2 = 1.0 / depth[t, 0], 1.0 / depth[t, 1], 1.0 / depth[t, 2]
        r, g, b = colors[t, 0], colors[t, 1], colors[t, 2]
        for y in range(ymin, ymax + 1):
            sy = y + 0.5
            for x in range(xmin, xmax + 1):
                sx = x + 0.5
                w0 = ((x1 - sx) * (y2 - sy) - (x2 - sx) * (y1 - sy)) * inv_area
                w1 = ((x2 - sx) * (y0 - sy) - (x0 - sx) * (y2 - sy)) * inv_area
                w2 = 1.0 - w0 - w1
                if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                    continue
                z = 1.0 / (w0 * iz0 + w1 * iz1 + w2 * iz2)
                if z < zbuf[y, x]:
                    zbuf[y, x] = z
                    image[y, x, 0] = r
                    image[y, x, 1] = g
                    image[y, x, 2] = b


@njit
def _raster_spheres(sx, sy, srad, center_depth, radius, colors, light, lighting, zbuf, image):  # pragma: no cover
    """sx, sy: (S,) projected centres [px]; srad: (S,) projected radii [px]; center_depth, radius: (S,) view
    depth of the centre and world radius; colors (S, 3); light (3,) unit, camera axes (x right, y up,
    z forward); lighting: (ambient, diffuse, specular, shininess)."""
    ambient, diffuse, specular, shininess = lighting[0], lighting[1], lighting[2], lighting[3]
    height, width = zbuf.shape
    # Blinn-Phong half vector for a viewer looking along +z: h = normalize(l - view) with view = (0, 0, 1)
    hx, hy, hz = light[0], light[1], light[2] - 1.0
    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx / hn, hy / hn, hz / hn
    for s in range(sx.shape[0]):
        rad = srad[s]
        if rad <= 0.0:
            continue
        xmin = max(int(math.floor(sx[s] - rad)), 0)
        xmax = min(int(math.ceil(sx[s] + rad)), width - 1)
        ymin = max(int(math.floor(sy[s] - rad)), 0)
        ymax = min(int(math.ceil(sy[s] + rad)), height - 1)
        inv = 1.0 / rad
        for y in range(ymin, ymax + 1):
            dy = (sy[s] - (y + 0.5)) * inv  # up is +y in camera axes, down the image
            for x in range(xmin, xmax + 1):
                dx = (x + 0.5 - sx[s]) * inv
                d2 = dx * dx + dy * dy
                if d2 > 1.0:
                    continue
                nz = -math.sqrt(1.0 - d2)  # the visible hemisphere faces the camera (-z)
                z = center_depth[s] + radius[s] * nz
                if z >= zbuf[y, x]:
                    continue
                lambert = dx * light[0] + dy * light[1] + nz * light[2]
                if lambert < 0.0:
                    lambert = 0.0
                spec = dx * hx + dy * hy + nz * hz
                spec = specular * spec ** shininess if spec > 0.0 else 0.0
                shade = ambient + diffuse * lambert
                zbuf[y, x] = z
                for c in range(3):
                    v = colors[s, c] * shade + spec
                    image[y, x, c] = v if v < 1.0 else 1.0


@njit
def _resolve(image, ss, out):  # pragma: no cover - compiled
    """out (h, w, 3) uint8 = the mean of each ss x ss block of image (h ss, w ss, 3) float in [0, 1]."""
    height, width = out.shape[0], out.shape[1]
    scale = 255.0 / (ss * ss)
    for y in range(height):
        for x in range(width):
            for c in range(3):
                total = 0.0
                for i in range(ss):
                    for j in range(ss):
                        total += image[y * ss + i, x * ss + j, c]
                out[y, x, c] = np.uint8(min(total * scale + 0.5, 255.0))


class Rasterizer:
    """Renders :class:`Primitives` seen by a :class:`Camera` into ``(height, width, 3)`` uint8 RGB images."""

    def __init__(self, width: int, height: int, *, supersample: int = 2, near: float = 0.05) -> None:
        if width < 1 or height < 1:
            raise ValueError(f"image size must be positive, got {width}x{height}")
        self.width, self.height = int(width), int(height)
        self.supersample = max(1, int(supersample))
        self.near = near
        H, W = self.height * self.supersample, self.width * self.supersample
        rows = np.linspace(0.0, 1.0, H)[:, None, None]
        self._background = ((1 - rows) * SKY_TOP + rows * SKY_BOTTOM).astype(np.float32) * np.ones((1, W, 1),
                                                                                                    np.float32)

    def render(self, prims: Primitives, camera: Camera) -> np.ndarray:
        ss = self.supersample
        H, W = self.height * ss, self.width * ss
        image = self._background.copy()
        zbuf = np.full((H, W), np.inf)
        axes = camera.axes()
        eye = np.asarray(camera.eye, dtype=float)
        focal = 0.5 * H / math.tan(math.radians(camera.fov_deg) / 2)
        light_world = LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION)

        if len(prims.triangles):
            tri_world = prims.triangles
            view = (tri_world - eye) @ axes.T  # (T, 3, 3) camera coordinates
            normal = np.cross(tri_world[:, 1] - tri_world[:, 0], tri_world[:, 2] - tri_world[:, 0])
            facing = np.sum(normal * (eye - tri_world[:, 0]), axis=1)  # > 0: the front side faces the camera
            keep = np.all(view[:, :, 2] > self.near, axis=1) & ~(prims.closed & (facing <= 0.0))
            view, colors, normal, facing = view[keep], prims.triangle_colors[keep], normal[keep], facing[keep]
            norm = np.linalg.norm(normal, axis=1, keepdims=True)
            normal = np.divide(normal, norm, out=np.zeros_like(normal), where=norm > 0)
            normal *= np.where(facing < 0, -1.0, 1.0)[:, None]  # two-sided: the side the camera sees
            lambert = np.clip(normal @ light_world, 0.0, None)
            shaded = np.clip(colors * (AMBIENT + DIFFUSE * lambert)[:, None], 0.0, 1.0)
            depth = view[:, :, 2]
            px = 0.5 * W + focal * view[:, :, 0] / depth
            py = 0.5 * H - focal * view[:, :, 1] / depth
            _raster_triangles(px, py, depth, shaded.astype(np.float32), zbuf, image)

        if len(prims.sphere_centers):
            view = (prims.sphere_centers - eye) @ axes.T
            radius = np.asarray(prims.sphere_radii, dtype=float)
            keep = view[:, 2] - radius > self.near
            view, radius, colors = view[keep], radius[keep], prims.sphere_colors[keep]
            depth = view[:, 2]
            sx = 0.5 * W + focal * view[:, 0] / depth
            sy = 0.5 * H - focal * view[:, 1] / depth
            # the silhouette of a sphere at distance d subtends asin(r / d); its projected radius f tan(asin)
            dist = np.linalg.norm(view, axis=1)
            srad = focal * radius / np.sqrt(np.maximum(dist * dist - radius * radius, 1e-12))
            _raster_spheres(sx, sy, srad, depth, radius, colors.astype(np.float32), axes @ light_world,
                            np.array([AMBIENT, DIFFUSE, SPECULAR, SHININESS]), zbuf, image)

        out = np.empty((self.height, self.width, 3), dtype=np.uint8)
        _resolve(image, ss, out)  # box filter: the mean of each ss x ss block (numpy's mean over axes is slow)
        return out
