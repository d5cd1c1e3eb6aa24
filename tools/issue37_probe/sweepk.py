# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
"""Probe kernels: solve_contacts copies with a mode, returning counts (sweeps, impact sweeps, launches, colours)."""
import numpy as np
from numba import njit

from cgp_core.solver import sequential_impulse as si
from cgp_core.solver.arrays import Scratch, StepSettings
from cgp_core.solver.colouring import colour_manifolds
from cgp_core.solver.manifold import MAX_BLOCK

_solve_manifold = si._solve_manifold
_solve_manifold_call = si._solve_manifold_call
impact_manifolds = si.impact_manifolds


@njit(inline="always")
def _sweeps(manifolds, rows, targets, lam, bodies, settings, mode, threshold, update):
    """mode 0: plain order; 1: coloured order, every update ``update``.  Returns sweeps, impact sweeps,
    colour runs visited that are >= threshold ('wide'), colours C, overflow size."""
    group_start = manifolds.group_start
    m = len(manifolds.a)
    G = len(group_start) - 1
    lam_n = np.empty(m)
    scratch = Scratch(np.empty((2, MAX_BLOCK)), np.zeros(MAX_BLOCK, np.bool_), np.empty((m, 2)))
    impact, any_impact = impact_manifolds(manifolds, targets)
    if mode == 1:
        order, colour_start = colour_manifolds(manifolds.a, manifolds.b, manifolds.group_start, bodies.dynamic)
    else:
        order = np.arange(G)
        colour_start = np.array([0, G, G])
    C = len(colour_start) - 2
    V = bodies.velocity
    sweeps = 0
    impact_done = 0
    wide = 0
    regular = True
    while True:
        change = 0.0
        for k in range(C + 1):
            lo, hi = colour_start[k], colour_start[k + 1]
            if k < C and hi - lo >= threshold:
                wide += 1
            for q in range(lo, hi):
                g = order[q]
                if regular or impact[g]:
                    c = update(g, manifolds, rows, targets, lam, lam_n, V, scratch)
                    if c > change:
                        change = c
        if regular:
            sweeps += 1
            if change <= settings.velocity_tolerance or sweeps >= settings.velocity_iterations:
                regular = False
                if not any_impact or settings.impact_sweeps == 0:
                    break
        else:
            impact_done += 1
            if change <= settings.velocity_tolerance or impact_done >= settings.impact_sweeps:
                break
    return sweeps, impact_done, wide, C, colour_start[C + 1] - colour_start[C]


@njit(cache=True)
def sweeps_inlined(solving, settings, mode, threshold):
    settings = StepSettings(*settings)
    return _sweeps(solving.manifolds, solving.rows, solving.targets, solving.lam, solving.bodies, settings, mode,
                   threshold, _solve_manifold)


@njit(cache=True)
def sweeps_called(solving, settings, mode, threshold):
    settings = StepSettings(*settings)
    return _sweeps(solving.manifolds, solving.rows, solving.targets, solving.lam, solving.bodies, settings, mode,
                   threshold, _solve_manifold_call)


@njit(cache=True)
def sweeps_colour_serial(solving, settings):
    """si.solve_contacts compiled serially (what solve_step runs): coloured, wide colours through the call."""
    settings = StepSettings(*settings)
    return si.solve_contacts(solving.manifolds, solving.rows, solving.targets, solving.lam, solving.bodies,
                             settings, _solve_manifold, False)


@njit(cache=True)
def colour_only(solving):
    m = solving.manifolds
    return colour_manifolds(m.a, m.b, m.group_start, solving.bodies.dynamic)
