"""``joints`` entries of a scene: joints between free bodies, or a body and the world (issue 35), parsed into
:class:`JointSpec` and built into articulations (:mod:`cgp_core.robots.articulations`)::

    joints:
      - name: hinge                  # ROS-safe, unique among bodies, flocks, robots and joints
        type: revolute               # revolute | prismatic | ball | fixed
        parent: frame_body           # a body, or world (a fixed body is the world for its joints)
        child: door                  # a free (not fixed) body
        anchor: [0.5, 0, 1]          # the joint's point in the world at the scene's initial poses [m]
        axis: [0, 0, 1]              # revolute: turned about it (right hand); prismatic: moved along it
                                     # (ball, fixed: no axis)
        limits: [-1.5, 1.5]          # [rad or m], relative to the initial poses (where the coordinate is 0);
                                     # none for a ball (no cone limit)
        damping: 0.0                 # viscous [N m s/rad or N s/m]; a ball: on each of its 3 angular velocities
        friction: 0.0                # Coulomb [N m or N]; none for a ball
        drive: {mode: position, target: 0.5, stiffness: 100, damping: 10, effort_limit: 50}
                                     # position | velocity | effort; implicit, bounded by effort_limit

Joints that form a tree become an articulation in reduced coordinates (exact: no joint stretches); a joint whose
child already hangs from another joint closes a loop, a row of the joint solver (see the articulations module).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .validation import COORDINATES, Validator, kind_of, short_repr

JOINT_KEYS = {"name", "type", "parent", "child", "anchor", "axis", "limits", "damping", "friction", "drive"}
DRIVE_KEYS = {"mode", "target", "stiffness", "damping", "effort_limit"}
JOINT_TYPES = ("revolute", "prismatic", "ball", "fixed")
DRIVE_MODES = ("position", "velocity", "effort")
#: the most joints a scene holds (their trees are dense joint-space systems: cgp_core.limits.MAX_ROBOT_DOFS per tree)
MAX_JOINTS = 200


@dataclass
class JointSpec:
    name: str
    type: str
    parent: str
    child: str
    anchor: np.ndarray
    axis: np.ndarray          # unit (zeros for fixed)
    limits: tuple[float, float] | None = None
    damping: float = 0.0
    friction: float = 0.0
    drive: dict | None = None  # {mode, target, stiffness, damping, effort_limit}


def parse_joints(v: Validator, raw: Any, bodies: list, seen: set[str]) -> tuple[list[JointSpec], list]:
    """The scene's joints and the articulations they make (:class:`cgp_core.robots.articulations.Articulation`);
    every problem recorded on ``v`` with its key path."""
    if raw is None:
        return [], []
    if not isinstance(raw, list):
        v.fail("joints", f"must be a list of joint entries, got {kind_of(raw)}")
        return [], []
    if len(raw) > MAX_JOINTS:
        v.fail("joints", f"{len(raw)} joints; a scene holds at most {MAX_JOINTS}")
        return [], []
    by_name = {b.name: b for b in bodies}
    before = len(v.problems)
    if "world" in by_name:
        v.fail("joints", "a body is named world: a joint's parent world could not be told from it (rename it)")
        return [], []
    specs = [parse_joint(v, entry, f"joints[{i}]", by_name, seen) for i, entry in enumerate(raw)]
    if len(v.problems) > before or not specs:
        return [], []
    from ..robots.articulations import ArticulationError, build_articulations

    try:
        articulations = build_articulations(bodies, specs)
    except ArticulationError as exc:
        v.fail(exc.key, exc.reason)
        return [], []
    from ..limits import MAX_ROBOT_DOFS

    for a in articulations:  # each tree is one dense joint-space system (World would refuse it: say so here)
        if a.model.n_dofs > MAX_ROBOT_DOFS:
            tops = [b for b in a.model.body_names if not b.endswith("/world")]
            v.fail("joints", f"the tree of bodies jointed from {tops[0]} has {a.model.n_dofs} joint velocities; "
                             f"a tree has at most {MAX_ROBOT_DOFS} (cgp_core.limits.MAX_ROBOT_DOFS): split it, or "
                             f"make some of its joints fixed")
    if len(v.problems) > before:
        return [], []
    for a in articulations:
        loops = {loop.name for loop in a.loops}
        for k, j in enumerate(specs):
            if j.name not in loops:
                continue
            if j.type not in ("revolute", "ball"):
                v.fail(f"joints[{k}].type", f"{j.name} closes a loop ({j.child} already hangs from another joint): "
                                            f"a loop-closing joint must be revolute or ball (a point coincidence); "
                                            f"{j.type} loop closures are not there yet")
            if j.limits is not None or j.drive is not None:
                v.fail(f"joints[{k}]", f"{j.name} closes a loop ({j.child} already hangs from another joint): it "
                                       f"takes no limits or drive (only the tree's joints do)")
    return (specs, articulations) if len(v.problems) == before else ([], [])


def parse_joint(v: Validator, raw: Any, key: str, bodies: dict, seen: set[str]) -> JointSpec | None:
    before = len(v.problems)
    d = v.mapping(raw, key)
    if not d and not isinstance(raw, dict):
        return None
    v.no_unknown_keys(d, JOINT_KEYS, key)
    for required in ("name", "type", "parent", "child", "anchor"):
        if required not in d:
            v.fail(f"{key}.{required}", "missing")
    if len(v.problems) > before:
        return None
    name = v.name(d["name"], f"{key}.name", seen)
    kind = v.choice(d["type"], f"{key}.type", list(JOINT_TYPES), "revolute")
    parent = v.string(d["parent"], f"{key}.parent")
    child = v.string(d["child"], f"{key}.child")
    known = ", ".join(sorted(bodies)) or "none"
    if parent != "world" and parent not in bodies:
        v.fail(f"{key}.parent", f"no body {short_repr(parent)} (world, or one of the bodies: {known})")
    if child == "world":
        v.fail(f"{key}.child", "the world cannot be a child: make it the parent")
    elif child not in bodies:
        v.fail(f"{key}.child", f"no body {short_repr(child)} (bodies: {known})")
    elif bodies[child].fixed:
        v.fail(f"{key}.child", f"{child} is a fixed body: a joint's child must move (make it the parent, or not "
                               f"fixed)")
    if child == parent:
        v.fail(f"{key}.child", f"{child} cannot be jointed to itself")
    anchor = v.vector(d["anchor"], f"{key}.anchor", 3, within=COORDINATES, unit="m")
    axis = np.zeros(3)
    if kind == "ball":
        # a cone (swing) or twist limit is not implemented: refused rather than silently ignored
        for refused, why in (("axis", "it turns about every axis through its anchor"),
                             ("limits", "a cone or twist limit for a ball joint is not implemented"),
                             ("friction", "a Coulomb friction per axis would not be isotropic; use damping"),
                             ("drive", "a drive for a ball joint's 3 dofs is not implemented")):
            if refused in d:
                v.fail(f"{key}.{refused}", f"a ball joint takes no {refused}: {why}")
    elif kind != "fixed":
        if "axis" not in d:
            v.fail(f"{key}.axis", f"missing (a {kind} joint needs its axis)")
        else:
            axis = v.vector(d["axis"], f"{key}.axis", 3)
            norm = float(np.linalg.norm(axis))
            if norm < 1e-9:
                v.fail(f"{key}.axis", "zero axis: give a direction, e.g. [0, 0, 1]")
            else:
                axis = axis / norm
    elif "axis" in d or "limits" in d or "drive" in d:
        v.fail(key, "a fixed joint takes no axis, limits or drive")
    limits = None
    if "limits" in d and kind != "ball":
        lim = v.vector(d["limits"], f"{key}.limits", 2, within=(-1e4, 1e4), unit="rad or m")
        if lim[0] > lim[1]:
            v.fail(f"{key}.limits", f"lower {lim[0]:g} is above upper {lim[1]:g}")
        elif not lim[0] <= 0.0 <= lim[1]:
            v.fail(f"{key}.limits", f"[{lim[0]:g}, {lim[1]:g}] excludes 0, the joint's coordinate at the scene's "
                                    f"initial poses")
        limits = (float(lim[0]), float(lim[1]))
    damping = v.number(d.get("damping", 0.0), f"{key}.damping", minimum=0.0, maximum=1e9)
    friction = v.number(d.get("friction", 0.0), f"{key}.friction", minimum=0.0, maximum=1e9)
    drive = None
    if "drive" in d and kind != "ball":
        dd = v.mapping(d["drive"], f"{key}.drive")
        v.no_unknown_keys(dd, DRIVE_KEYS, f"{key}.drive")
        mode = v.choice(dd.get("mode", "position"), f"{key}.drive.mode", list(DRIVE_MODES), "position")
        drive = {"mode": mode,
                 "target": v.number(dd.get("target", 0.0), f"{key}.drive.target", within=(-1e4, 1e4)),
                 "stiffness": v.number(dd.get("stiffness", 0.0), f"{key}.drive.stiffness", minimum=0.0, maximum=1e9),
                 "damping": v.number(dd.get("damping", 0.0), f"{key}.drive.damping", minimum=0.0, maximum=1e9),
                 "effort_limit": v.number(dd.get("effort_limit", np.inf) if "effort_limit" in dd else 1e9,
                                          f"{key}.drive.effort_limit", minimum=0.0, maximum=1e9)}
        if "effort_limit" not in dd:
            drive["effort_limit"] = np.inf
        if mode == "position" and drive["stiffness"] <= 0.0:
            v.fail(f"{key}.drive.stiffness", "a position drive needs a stiffness > 0")
        if mode == "velocity" and drive["damping"] <= 0.0:
            v.fail(f"{key}.drive.damping", "a velocity drive needs a damping gain > 0")
    if len(v.problems) > before:
        return None
    return JointSpec(name=name, type=kind, parent=parent, child=child, anchor=anchor, axis=axis, limits=limits,
                     damping=damping, friction=friction, drive=drive)
