"""Write ``msgs_config/robots/arm7.urdf``: cgp_sim's 7-DoF arm (the ``arm`` gallery scene's robot), written for
this package (no file of another robot copied).

    python tools/arm7_urdf.py        # rewrites msgs_config/robots/arm7.urdf

The file is committed; this script is how it was made (edit it, not the URDF, and run it again;
tests/test_urdf.py checks that the two agree).

**Kinematics** (a KUKA LBR iiwa 7's layout, an upper arm and a forearm of 0.4 m, the reach of a Franka Panda): seven
revolute joints, their axes alternating z, y, z, y, z, y, z of the link frames, every joint origin a pure
translation along z (so the stretched arm points straight up), then a fixed flange-to-hand joint, a two-finger
gripper whose right finger ``<mimic>``s the left (prismatic, 0 to 4 cm each) and a massless ``tcp`` frame between
the fingertips.  Limits, effort and velocity limits are the iiwa 7's (±170°/±120° alternately, 176 / 110 / 40 N m,
1.7 to 3.1 rad/s); viscous damping 0.5 N m s/rad on the four big joints, 0.2 on the wrist's three.

**Mass properties** (how they were computed): every link is one or more primitives (a cylinder along z, or along y
for a joint housing, a box), used as both its visual and its collision geometry.  The link's mass (chosen: 17.5 kg
for the moving links, a Panda's 18 kg) is spread over its primitives by volume (uniform density within the link;
overlapping housings count twice, as a scene's compound body does); the COM is the mass-weighted mean of their
centres, and the inertia tensor about it is the sum of each primitive's closed form (solid cylinder:
m (3 r² + L²) / 12 across, m r² / 2 along its axis; solid box: m (b² + c²) / 12) rotated into the link axes and
moved by the parallel-axis theorem, J = Σ (Rᵢ Jᵢ Rᵢᵀ + mᵢ (|dᵢ|² 1 − dᵢ dᵢᵀ)) — the same rule as
:func:`cgp_core.inertia.parallel_axis`, written out here in numpy.  The values are printed to 6 significant digits.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "msgs_config" / "robots" / "arm7.urdf"
HALF_PI = math.pi / 2

MATERIALS = {"orange": (0.96, 0.45, 0.08), "light": (0.85, 0.86, 0.88), "dark": (0.18, 0.18, 0.2),
             "steel": (0.6, 0.62, 0.66)}

# a primitive: (kind, size, centre xyz in the link frame, axis) with kind "cyl" (size (radius, length), axis "z" or
# "y") or "box" (size (x, y, z))
# (link, mass [kg], primitives, material)
LINKS = [
    ("base_link", 5.0, [("cyl", (0.1, 0.1), (0, 0, 0.05), "z")], "dark"),
    ("shoulder_link", 4.0, [("cyl", (0.07, 0.24), (0, 0, 0.12), "z"), ("cyl", (0.075, 0.15), (0, 0, 0.24), "y")],
     "light"),
    ("upper_arm_link", 4.0, [("cyl", (0.065, 0.2), (0, 0, 0.1), "z")], "orange"),
    ("upper_arm_roll_link", 3.0, [("cyl", (0.06, 0.2), (0, 0, 0.1), "z"), ("cyl", (0.065, 0.13), (0, 0, 0.2), "y")],
     "light"),
    ("forearm_link", 2.7, [("cyl", (0.055, 0.2), (0, 0, 0.1), "z")], "orange"),
    ("forearm_roll_link", 1.7, [("cyl", (0.05, 0.2), (0, 0, 0.1), "z"), ("cyl", (0.055, 0.11), (0, 0, 0.2), "y")],
     "light"),
    ("wrist_link", 1.0, [("cyl", (0.045, 0.08), (0, 0, 0.04), "z")], "orange"),
    ("flange", 0.4, [("cyl", (0.04, 0.03), (0, 0, 0.015), "z")], "dark"),
    ("hand", 0.6, [("box", (0.07, 0.2, 0.06), (0, 0, 0.03), "z")], "light"),
    ("finger_left", 0.05, [("box", (0.02, 0.02, 0.07), (0, 0.01, 0.035), "z")], "steel"),
    ("finger_right", 0.05, [("box", (0.02, 0.02, 0.07), (0, 0.01, 0.035), "z")], "steel"),
]

# (joint, parent, child, origin z [m], axis, lower, upper, effort, velocity, damping)
JOINTS = [
    ("shoulder_pan", "base_link", "shoulder_link", 0.1, "0 0 1", -2.97, 2.97, 176, 1.71, 0.5),
    ("shoulder_lift", "shoulder_link", "upper_arm_link", 0.24, "0 1 0", -2.09, 2.09, 176, 1.71, 0.5),
    ("upper_arm_roll", "upper_arm_link", "upper_arm_roll_link", 0.2, "0 0 1", -2.97, 2.97, 110, 1.75, 0.5),
    ("elbow", "upper_arm_roll_link", "forearm_link", 0.2, "0 1 0", -2.09, 2.09, 110, 2.27, 0.5),
    ("forearm_roll", "forearm_link", "forearm_roll_link", 0.2, "0 0 1", -2.97, 2.97, 110, 2.44, 0.2),
    ("wrist", "forearm_roll_link", "wrist_link", 0.2, "0 1 0", -2.09, 2.09, 40, 3.14, 0.2),
    ("wrist_roll", "wrist_link", "flange", 0.08, "0 0 1", -3.05, 3.05, 40, 3.14, 0.2),
]


def _g(x: float) -> str:
    """A number to 6 significant digits, as short as it goes."""
    if abs(x) < 1e-12:
        return "0"
    return f"{x:.6g}"


def _volume(kind, size) -> float:
    return math.pi * size[0] ** 2 * size[1] if kind == "cyl" else size[0] * size[1] * size[2]


def _own_inertia(kind, size, axis, m) -> np.ndarray:
    """A primitive's inertia about its centre in the link axes."""
    if kind == "box":
        a, b, c = size
        return np.diag([m * (b * b + c * c), m * (a * a + c * c), m * (a * a + b * b)]) / 12.0
    r, length = size
    across, along = m * (3 * r * r + length * length) / 12.0, m * r * r / 2.0
    return np.diag([across, across, along]) if axis == "z" else np.diag([across, along, across])


def mass_properties(mass: float, primitives) -> tuple[np.ndarray, np.ndarray]:
    """(COM (3,), inertia about the COM (3, 3)) of ``mass`` spread over ``primitives`` by volume."""
    volumes = np.array([_volume(kind, size) for kind, size, _, _ in primitives])
    masses = mass * volumes / volumes.sum()
    centres = np.array([c for _, _, c, _ in primitives], float)
    com = masses @ centres / mass
    inertia = np.zeros((3, 3))
    for (kind, size, _, axis), m, c in zip(primitives, masses, centres):
        d = c - com
        inertia += _own_inertia(kind, size, axis, m) + m * (d @ d * np.eye(3) - np.outer(d, d))
    return com, inertia


def _geometry(kind, size, centre, axis) -> str:
    rpy = f' rpy="{HALF_PI!r} 0 0"' if kind == "cyl" and axis == "y" else ""
    origin = f'<origin xyz="{" ".join(_g(v) for v in centre)}"{rpy}/>'
    shape = (f'<cylinder radius="{_g(size[0])}" length="{_g(size[1])}"/>' if kind == "cyl"
             else f'<box size="{" ".join(_g(v) for v in size)}"/>')
    return origin + f"<geometry>{shape}</geometry>"


def link_xml(name, mass, primitives, material) -> str:
    com, inertia = mass_properties(mass, primitives)
    assert np.allclose(inertia, np.diag(np.diag(inertia)), atol=1e-15), name  # axis-aligned primitives
    ixx, iyy, izz = np.diag(inertia)
    lines = [f'  <link name="{name}">',
             f'    <inertial><origin xyz="{" ".join(_g(v) for v in com)}"/><mass value="{_g(mass)}"/>',
             f'      <inertia ixx="{_g(ixx)}" ixy="0" ixz="0" iyy="{_g(iyy)}" iyz="0" izz="{_g(izz)}"/></inertial>']
    for p in primitives:
        lines.append(f'    <visual>{_geometry(*p)}<material name="{material}"/></visual>')
    for p in primitives:
        lines.append(f"    <collision>{_geometry(*p)}</collision>")
    lines.append("  </link>")
    return "\n".join(lines)


def urdf() -> str:
    links = {name: (name, mass, primitives, material) for name, mass, primitives, material in LINKS}
    out = ['<?xml version="1.0"?>',
           "<!-- Generated by tools/arm7_urdf.py: edit that script, not this file.",
           "     cgp_sim's 7-DoF arm (the `arm` scene's robot): an iiwa-like chain of seven revolute joints (axes",
           "     z y z y z y z, iiwa 7 limits), primitives only, and a two-finger gripper whose right finger",
           "     mimics the left. Each link's inertia is that of its collision primitives at uniform density",
           "     (how: the script). -->",
           '<robot name="cgp_arm7">']
    for name, rgb in MATERIALS.items():
        out.append(f'  <material name="{name}"><color rgba="{" ".join(_g(c) for c in rgb)} 1"/></material>')
    out.append("")
    out.append(link_xml(*links["base_link"]))
    for name, parent, child, z, axis, lower, upper, effort, velocity, damping in JOINTS:
        out += ["",
                f'  <joint name="{name}" type="revolute">',
                f'    <parent link="{parent}"/><child link="{child}"/>',
                f'    <origin xyz="0 0 {_g(z)}" rpy="0 0 0"/><axis xyz="{axis}"/>',
                f'    <limit lower="{_g(lower)}" upper="{_g(upper)}" effort="{_g(effort)}" velocity="{_g(velocity)}"/>',
                f'    <dynamics damping="{_g(damping)}" friction="0"/>',
                "  </joint>",
                link_xml(*links[child])]
    out += ["",
            "  <!-- the hand: fixed to the flange (merged into it for the dynamics, its own frame for TF) -->",
            '  <joint name="hand_joint" type="fixed">',
            '    <parent link="flange"/><child link="hand"/><origin xyz="0 0 0.03" rpy="0 0 0"/>',
            "  </joint>",
            link_xml(*links["hand"])]
    # the right finger: the left one turned half a turn about z (its axis and its box mirrored), mimicking it
    follow = '\n    <mimic joint="finger_left_joint" multiplier="1" offset="0"/>'
    for side, yaw, mimic in (("left", "0", ""), ("right", repr(math.pi), follow)):
        out += ["",
                f'  <joint name="finger_{side}_joint" type="prismatic">',
                f'    <parent link="hand"/><child link="finger_{side}"/>',
                f'    <origin xyz="0 0 0.06" rpy="0 0 {yaw}"/><axis xyz="0 1 0"/>',
                '    <limit lower="0" upper="0.04" effort="20" velocity="0.2"/>',
                f'    <dynamics damping="2" friction="0"/>{mimic}',
                "  </joint>",
                link_xml(*links[f"finger_{side}"])]
    out += ["",
            "  <!-- the tool centre point between the fingertips: no mass, no geometry; a frame for TF -->",
            '  <joint name="tcp_joint" type="fixed">',
            '    <parent link="hand"/><child link="tcp"/><origin xyz="0 0 0.13" rpy="0 0 0"/>',
            "  </joint>",
            '  <link name="tcp"/>',
            "</robot>", ""]
    return "\n".join(out)


if __name__ == "__main__":
    OUT.write_text(urdf())
    print(f"wrote {OUT}")
