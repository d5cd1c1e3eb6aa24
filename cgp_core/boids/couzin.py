"""Couzin's zonal model: the second rule set of a flock (``rules: couzin``).

Couzin, Krause, James, Ruxton & Franks 2002, "Collective memory and spatial sorting in animal groups",
J. theor. Biol. 218:1-11.  Each animal i has a position c_i, a unit heading v̂_i and the constant speed s.
Per step it looks at its neighbours j (offset r_ij = c_j − c_i, r̂_ij its direction, d = |r_ij|) in three
non-overlapping zones, ignoring those in its *blind volume* (the cone of 360° − α behind it: j is perceived
when the angle between v̂_i and r̂_ij is at most α/2):

- repulsion, d < r_r:                          d_r = −Σ r̂_ij                       (absolute priority)
- orientation, r_r <= d < r_r + Δr_o:         d_o = Σ v̂_j
- attraction, r_r + Δr_o <= d <= r_r + Δr_o + Δr_a:   d_a = Σ r̂_ij

The desired direction d_i is d_r if any neighbour is in the zone of repulsion; otherwise d_o alone, d_a alone,
or ½ (d_o + d_a) when both zones hold neighbours; with no neighbour at all (or a zero sum) the animal keeps
its heading (:func:`decide`).  d_i is then rotated by a Gaussian random angle of standard deviation σ (about a
uniformly random axis perpendicular to it, :func:`with_noise`), and the heading turns towards it by at most
θ·dt (it snaps to it when closer, :func:`turn_towards`); the animal moves ``c += s v̂ dt``.  All animals update
synchronously from the state at the start of the step.

Where the paper leaves a choice, this is the one made (and why):

- ½ (d_o + d_a) averages the two *unit* directions d̂_o, d̂_a: the paper treats desired directions as
  directions (only the direction of d_i matters for the turn), and averaging the raw sums would let the zone
  holding more neighbours win by headcount alone.
- The focal animal is not in its own zone of orientation (its distance 0 is not >= r_r); its own heading
  enters only through the turning-rate limit.
- The blind volume applies to every zone, repulsion included (the paper: neighbours there "cannot be
  detected"); it is the Reynolds rules' field-of-view test (``rules.sees``).
- Coincident animals (d = 0) have no direction r̂_ij: they are ignored by each other (measure zero).
- Noise is a rotational diffusion: σ is the standard deviation per paper step τ = 0.1 s
  (:data:`NOISE_TIME_STEP`), so a tick of dt draws an angle of s.d. σ·sqrt(dt / τ).  The paper steps at τ;
  with this scaling the heading's random walk per second is the same at any tick rate (``rate_hz``), and at
  dt = τ it is exactly the paper's.  θ and s are per second already.

How it runs: :func:`desired_directions` is one compiled loop over every boid's neighbour row (a
:class:`~cgp_core.boids.neighbors.NeighborList`, in its slot order, as ``rules._neighbor_sums`` reads it):
the metric search within r_r + Δr_o + Δr_a, or the k nearest in topological mode (``topological.py``; the
zone of attraction then has no outer edge).  The turn is part of the flock's per-boid move kernel
(``flock._turn``), which first lets avoidance (walls, bodies, predators: the flock's "needed" acceleration)
take over the desired direction in proportion to its strength (:func:`blend_avoidance`).  Each kernel writes
only its own boid's outputs, so results do not depend on the number of threads, and under
``NUMBA_DISABLE_JIT=1`` they run as plain Python with the same results.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import njit, prange
from .neighbors import NeighborList, pair_offset, squared_length
from .rules import sees

#: the paper's time step τ [s] (the response latency of a fish): σ is the noise per τ
NOISE_TIME_STEP = 0.1
#: seed stream of a Couzin flock's noise (its initial state uses the seed itself)
NOISE_STREAM = 2002


@njit
def _unit(x: float, y: float, z: float):
    """(x, y, z) / |(x, y, z)| and whether it had a direction (length > 1e-12)."""
    length = math.sqrt(x * x + y * y + z * z)
    if length > 1e-12:
        return x / length, y / length, z / length, True
    return x, y, z, False


@njit
def decide(n_r: int, d_r, n_o: int, d_o, n_a: int, d_a, heading):
    """The paper's decision rule for one animal: d_r if anyone is in the zone of repulsion (n_r > 0); else
    d̂_o, d̂_a, or ½ (d̂_o + d̂_a) when both zones hold someone; the current ``heading`` when nothing is perceived
    or the sums cancel.  Sums as 3-tuples; returns a unit direction (3 floats)."""
    if n_r > 0:
        dx, dy, dz = d_r
    else:
        dx = dy = dz = 0.0
        zones = 0
        if n_o > 0:
            ux, uy, uz, ok = _unit(d_o[0], d_o[1], d_o[2])
            if ok:
                dx, dy, dz = dx + ux, dy + uy, dz + uz
            zones += 1
        if n_a > 0:
            ux, uy, uz, ok = _unit(d_a[0], d_a[1], d_a[2])
            if ok:
                dx, dy, dz = dx + ux, dy + uy, dz + uz
            zones += 1
        if zones == 2:
            dx, dy, dz = 0.5 * dx, 0.5 * dy, 0.5 * dz
    ux, uy, uz, ok = _unit(dx, dy, dz)
    if ok:
        return ux, uy, uz
    return heading[0], heading[1], heading[2]  # nothing perceived, or the responses cancel: carry on


class Zones(NamedTuple):
    """An animal's zones, as the compiled loop takes them (distances to the neighbour [m])."""

    repulsion: float     # r_r: closer than this, move away
    orientation: float   # r_r + Δr_o: closer than this (and not repelled), align
    attraction: float    # r_r + Δr_o + Δr_a (inf for topological neighbours): closer than this, approach
    cos_half_fov: float  # cos(blind angle's complement / 2); <= −1: no blind volume


@njit(parallel=True)
def _desired_directions(neighbors, positions, headings, period, zones, out_desired, out_perceived):
    """The :class:`Zones` of every animal, one slot of the :class:`NeighborList` per iteration: inputs in the
    list's slot order, each result written to its boid's row ``order[s]`` (unit desired direction, number of
    neighbours perceived)."""
    start, count, index, order = neighbors.start, neighbors.count, neighbors.index, neighbors.order
    repulsion_radius, orientation_radius, attraction_radius, cos_half_fov = zones
    for s in prange(positions.shape[0]):
        n_r = n_o = n_a = 0
        rx = ry = rz = 0.0  # d_r = −Σ r̂_ij
        ox = oy = oz = 0.0  # d_o = Σ v̂_j
        ax = ay = az = 0.0  # d_a = Σ r̂_ij
        for e in range(start[s], start[s] + count[s]):
            j = index[e]
            dx, dy, dz = pair_offset(positions, s, j, period)  # r_ij = c_j − c_i
            d2 = squared_length(dx, dy, dz)
            if d2 <= 0.0 or not sees(headings, s, dx, dy, dz, d2, cos_half_fov):
                continue  # coincident, or in the blind volume
            d = math.sqrt(d2)
            if d < repulsion_radius:
                n_r += 1
                rx -= dx / d
                ry -= dy / d
                rz -= dz / d
            elif d < orientation_radius:
                n_o += 1
                ox += headings[j, 0]
                oy += headings[j, 1]
                oz += headings[j, 2]
            elif d <= attraction_radius:
                n_a += 1
                ax += dx / d
                ay += dy / d
                az += dz / d
        b = order[s]
        out_desired[b, 0], out_desired[b, 1], out_desired[b, 2] = decide(
            n_r, (rx, ry, rz), n_o, (ox, oy, oz), n_a, (ax, ay, az), headings[s])
        out_perceived[b] = n_r + n_o + n_a


def desired_directions(neighbors: NeighborList, positions: np.ndarray, headings: np.ndarray, params,
                       period: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every animal's desired direction from its neighbours' zones.

    Args:
        neighbors: each boid's neighbours (metric within r_r + Δr_o + Δr_a, or the k nearest).
        positions: (N, 3) float64.
        headings:  (N, 3) float64 unit headings v̂.
        params:    the flock's :class:`~cgp_core.boids.params.FlockParams` (its ``couzin`` block and
                   ``neighbor_mode``).
        period:    (3,) box sizes of a periodic box (0 = open axis); None = open space.

    Returns:
        ``(desired (N, 3) unit, perceived (N,) int64)``.
    """
    c = params.couzin
    n = len(positions)
    desired = np.empty((n, 3))
    perceived = np.empty(n, np.int64)
    attraction = math.inf if params.neighbor_mode == "topological" else c.perception_radius
    zones = Zones(float(c.repulsion_radius), float(c.repulsion_radius + c.orientation_width), float(attraction),
                  float(c.cos_half_fov))
    _desired_directions(neighbors, neighbors.sorted(positions), neighbors.sorted(headings),
                        np.zeros(3) if period is None else period, zones, desired, perceived)
    return desired, perceived


@njit
def blend_avoidance(dx: float, dy: float, dz: float, nx: float, ny: float, nz: float, full_strength: float):
    """Avoidance takes over the desired direction d in proportion to its strength, as Reynolds' prioritized
    allocation does for the other rule set: ``d' = unit((1 − w) d + w n̂)``, n̂ the direction of the needed
    acceleration (walls, bodies, predators) and ``w = min(1, |n| / full_strength)``: 0 where nothing is near,
    1 (pure avoidance: absolute priority) at ``full_strength``.  Exactly opposed halves keep d."""
    strength = math.sqrt(nx * nx + ny * ny + nz * nz)
    if strength <= 0.0:
        return dx, dy, dz
    w = min(strength / full_strength, 1.0)
    mx = (1.0 - w) * dx + w * (nx / strength)
    my = (1.0 - w) * dy + w * (ny / strength)
    mz = (1.0 - w) * dz + w * (nz / strength)
    ux, uy, uz, ok = _unit(mx, my, mz)
    if ok:
        return ux, uy, uz
    return dx, dy, dz


@njit
def _perpendicular(x: float, y: float, z: float):
    """A unit vector perpendicular to the unit vector (x, y, z) (deterministic: crossed with the world axis it
    is least aligned with)."""
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax <= ay and ax <= az:  # e_x × v
        px, py, pz = 0.0, -z, y
    elif ay <= az:  # e_y × v
        px, py, pz = z, 0.0, -x
    else:  # e_z × v
        px, py, pz = -y, x, 0.0
    length = math.sqrt(px * px + py * py + pz * pz)
    return px / length, py / length, pz / length


@njit
def with_noise(dx: float, dy: float, dz: float, psi: float, phi: float):
    """The unit direction d rotated by the angle ψ towards its perpendicular at azimuth φ:
    ``d' = cos ψ d + sin ψ (cos φ e1 + sin φ e2)``, (e1, e2) an orthonormal basis of the plane ⊥ d."""
    if psi == 0.0:
        return dx, dy, dz
    e1x, e1y, e1z = _perpendicular(dx, dy, dz)
    e2x = dy * e1z - dz * e1y  # e2 = d × e1
    e2y = dz * e1x - dx * e1z
    e2z = dx * e1y - dy * e1x
    c, s = math.cos(phi), math.sin(phi)
    cp, sp = math.cos(psi), math.sin(psi)
    nx = cp * dx + sp * (c * e1x + s * e2x)
    ny = cp * dy + sp * (c * e1y + s * e2y)
    nz = cp * dz + sp * (c * e1z + s * e2z)
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx / length, ny / length, nz / length


@njit
def turn_towards(hx: float, hy: float, hz: float, dx: float, dy: float, dz: float, cos_max: float,
                 sin_max: float):
    """The unit heading v̂ turned towards the unit direction d by at most θ·dt (``cos_max = cos θdt``,
    ``sin_max = sin θdt``): d itself when it is within θ·dt, else ``cos θdt v̂ + sin θdt ŵ`` with
    ``ŵ = unit(d − (v̂·d) v̂)`` (the turn in the plane of v̂ and d)."""
    cosine = hx * dx + hy * dy + hz * dz
    if cosine >= cos_max:  # within θ·dt: take the desired direction
        return dx, dy, dz
    wx, wy, wz, ok = _unit(dx - cosine * hx, dy - cosine * hy, dz - cosine * hz)
    if not ok:  # d exactly behind: any perpendicular plane will do
        wx, wy, wz = _perpendicular(hx, hy, hz)
    nx = cos_max * hx + sin_max * wx
    ny = cos_max * hy + sin_max * wy
    nz = cos_max * hz + sin_max * wz
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx / length, ny / length, nz / length


def noise_angles(rng: np.random.Generator, count: int, sigma: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The per-tick noise: Gaussian angles ψ of s.d. ``σ·sqrt(dt / τ)`` and uniform azimuths φ in [0, 2π), (N,)
    each (both are drawn even when σ = 0, so a flock's random stream does not depend on σ)."""
    angle = rng.standard_normal(count) * (sigma * math.sqrt(dt / NOISE_TIME_STEP))
    azimuth = rng.random(count) * (2.0 * math.pi)
    return angle, azimuth


__all__ = ["NOISE_STREAM", "NOISE_TIME_STEP", "blend_avoidance", "decide", "desired_directions", "noise_angles",
           "turn_towards", "with_noise"]
