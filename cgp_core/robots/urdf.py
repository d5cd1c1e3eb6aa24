"""URDF (and xacro) files into a :class:`~cgp_core.robots.model.RobotModel`.

:func:`load_urdf` takes a path (``.urdf``; ``.xacro`` expanded by the ``xacro`` PyPI package with the ``xacro_args``
given) or URDF XML text, and builds the static model: bodies parent before child, fixed joints merged into their
parent body (masses, COMs and inertias combined by the parallel-axis theorem, :func:`cgp_core.inertia.parallel_axis`)
with every URDF link kept as a frame, limits, dynamics, mimic pairs, collision and visual geometry with resolved
mesh paths.

Parsing, and why not yourdfpy's.  The XML may be hostile (it arrives in ROS spawn requests), and yourdfpy's
``URDF.load`` parses with ``etree.XMLParser(remove_blank_text=True)``, which resolves entities (external ones
included: XXE) and has no public entry for an element parsed elsewhere.  So the text is parsed here with a hardened
lxml parser — ``resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False`` — after a document with
a ``<!DOCTYPE`` (the only place an entity can be declared) has been refused outright: no DTD, no external or
internal entity is ever read or expanded, so neither ``<!ENTITY x SYSTEM "file:///etc/passwd">`` nor an entity
bomb gets anywhere (defusedxml's ``forbid_dtd`` rule).  The elements are then read by the code below (the URDF
schema is small), which checks what the specification requires (``<limit>`` on revolute and prismatic joints, one
parent per link, one root, no cycle) and raises :class:`UrdfError` — a ``ValueError`` naming the link or joint
and the reason, never a library's traceback, never quoting the file's text (names of links, joints and mesh URIs
are named: they are what is wrong).  xacro runs only on files named by path (``.xacro``); it evaluates
expressions and includes files, so it is for a user's own files, not for XML text from a request.

Conventions chosen:

- **Limits**: revolute and prismatic joints must have ``<limit>``; its ``lower`` / ``upper`` default to 0 (the
  specification's defaults); a continuous joint has (−inf, +inf) whatever it says.  ``effort`` and ``velocity``
  missing, or given as 0, mean "no limit" (+inf): URDF files write 0 where nothing was meant (a joint that may
  exert no effort would be a fixed joint); a negative value is an error.
- **Inertias** (per URDF link, before merging): a negative or non-finite mass, a non-finite tensor or one with a
  negative principal moment (not positive semi-definite: a sign error in the file, nothing to repair) is refused;
  principal moments that break the triangle inequality (``I_max > I_a + I_b``) are **repaired with a warning**:
  the two smaller moments are raised by half the excess each (same principal axes), and ``warnings.warn`` names the
  link with the moments before and after.  CAD exports break the triangle inequality by rounding often enough that
  refusing would reject everyday robots (MuJoCo offers the same repair as ``balanceinertia``).
- **Massless links**: a body with dofs whose subtree holds no mass at all makes the mass matrix singular: refused,
  naming the link and the joint.  A link without ``<inertial>`` has mass 0 (merged like any other).
- **Base**: the root body is welded to the world (``JOINT_FIXED_ROOT``) with ``fixed_base=True``, floating
  (``JOINT_FLOATING``) otherwise; a root link named ``world`` always makes a fixed base (its children's joints then
  attach the robot to the world, the common ``world → base_link`` fixed joint included).  A ``floating`` joint
  anywhere in the file is refused (use ``fixed_base=False``).
- **Meshes**: ``package://pkg/path`` is looked up in ``package_paths`` (a dict ``{pkg: dir}``, or directories that
  hold packages — ``<dir>/<pkg>`` — or are the package), then ``$AMENT_PREFIX_PATH`` (``<prefix>/share/<pkg>``),
  then ``$ROS_PACKAGE_PATH`` (like the list); ``file://`` URIs and plain paths are taken relative to the URDF's
  directory (the working directory for XML text).  The file must exist (it is not read here).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np
from lxml import etree

from ..inertia import parallel_axis
from ..limits import MAX_FILE_BYTES
from ..user_input import UserInputError, read_user_text
from .model import (
    JOINT_DOFS,
    JOINT_FIXED_ROOT,
    JOINT_FLOATING,
    JOINT_PLANAR,
    JOINT_PRISMATIC,
    JOINT_REVOLUTE,
    Geometry,
    RobotModel,
)

__all__ = ["UrdfError", "load_urdf", "rpy_matrix", "MAX_URDF_LINKS", "MAX_URDF_SHAPES"]

#: at most this many links (and joints) in one URDF (the largest humanoids have a few hundred)
MAX_URDF_LINKS = 2000
#: every number of a URDF (lengths, masses, inertias, limits) within ± this: products of them stay finite
MAX_URDF_NUMBER = 1e9
#: at most this many collision and visual shapes in one URDF, all links together
MAX_URDF_SHAPES = 20000

_JOINT_KINDS = {"revolute": JOINT_REVOLUTE, "continuous": JOINT_REVOLUTE, "prismatic": JOINT_PRISMATIC,
                "planar": JOINT_PLANAR, "floating": JOINT_FLOATING, "fixed": -1}
_DOF_SUFFIXES = {JOINT_PLANAR: ("/x", "/y", "/theta"), JOINT_FLOATING: ("/x", "/y", "/z", "/wx", "/wy", "/wz")}


class UrdfError(ValueError):
    """A URDF that is refused; the message names the file (if any), the link or joint, and the reason."""


# ---- reading the text ------------------------------------------------------------------------------------------

def _looks_like_xml(source) -> bool:
    return isinstance(source, str) and source.lstrip().startswith("<")


def _text_of(source) -> str | None:
    """``source`` as XML text if it is text (a ``str`` starting with ``<``, or UTF-8 bytes), else None."""
    if isinstance(source, (bytes, bytearray)):
        if len(source) > MAX_FILE_BYTES:
            raise UrdfError(f"URDF text: {len(source)} bytes; URDFs are limited to {MAX_FILE_BYTES}")
        try:
            return bytes(source).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise UrdfError(f"URDF text: not UTF-8 ({exc.reason} at byte {exc.start})") from None
    return source if _looks_like_xml(source) else None


def _read_source(source, xacro_args) -> tuple[str, Path | None, str]:
    """(URDF text, directory relative mesh paths are relative to, label for messages)."""
    text = _text_of(source)
    if text is not None:
        if len(text) > MAX_FILE_BYTES:
            raise UrdfError(f"URDF text: {len(text)} characters; URDFs are limited to {MAX_FILE_BYTES}")
        return text, None, "URDF text"
    if not isinstance(source, (str, os.PathLike)):
        raise UrdfError(f"a URDF is a path or XML text, got {type(source).__name__}")
    path = Path(source).expanduser()
    label = str(path)
    try:
        text = read_user_text(path)
    except UserInputError as exc:
        raise UrdfError(f"{label}: {exc}") from None
    directory = path.resolve().parent
    if path.suffix == ".xacro":
        return _expand_xacro(text, path, xacro_args, label), directory, label
    if xacro_args:
        raise UrdfError(f"{label}: xacro_args given for a file that is not .xacro")
    return text, directory, label


def _refuse_dtd(text: str, label: str) -> None:
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise UrdfError(f"{label}: the XML declares a document type (<!DOCTYPE>): DTDs and entities are not "
                        f"accepted in a URDF")


def _expand_xacro(text: str, path: Path, xacro_args, label: str) -> str:
    _refuse_dtd(text, label)
    import xacro
    mappings = {str(k): str(v) for k, v in dict(xacro_args or {}).items()}
    try:
        xacro.init_stacks(str(path.resolve()))
        doc = xacro.parse(text, str(path.resolve()))
        xacro.process_doc(doc, mappings=mappings)
        return doc.toxml()
    except Exception as exc:  # xacro raises many kinds (XacroException, ExpatError, NameError ...)
        raise UrdfError(f"{label}: xacro could not expand the file ({type(exc).__name__}; its message is not "
                        f"shown, it may quote the file)") from None


def _parse_xml(text: str, label: str):
    """The root element of ``text``, parsed by the hardened parser (module docstring)."""
    _refuse_dtd(text, label)
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False,
                             dtd_validation=False, remove_comments=True, remove_pis=True)
    try:
        root = etree.fromstring(text.encode("utf-8"), parser)
    except etree.XMLSyntaxError as exc:
        where = f" at line {exc.lineno}, column {exc.offset}" if exc.lineno else ""
        raise UrdfError(f"{label}: malformed XML{where}") from None
    except ValueError:
        raise UrdfError(f"{label}: malformed XML") from None
    if root is None or root.tag != "robot":
        raise UrdfError(f"{label}: the root element must be <robot>")
    return root


# ---- numbers and poses ---------------------------------------------------------------------------------------

def _floats(text: str | None, count: int, what: str, default=None) -> np.ndarray:
    if text is None:
        if default is None:
            raise UrdfError(f"{what}: missing")
        return np.array(default, dtype=float)
    try:
        values = np.array([float(v) for v in text.split()], dtype=float)
    except ValueError:
        raise UrdfError(f"{what}: not a list of numbers") from None
    if len(values) != count:
        raise UrdfError(f"{what}: {count} numbers expected, got {len(values)}")
    if not np.isfinite(values).all():
        raise UrdfError(f"{what}: numbers must be finite")
    if (np.abs(values) > MAX_URDF_NUMBER).any():
        raise UrdfError(f"{what}: numbers must be within ±{MAX_URDF_NUMBER:g}")
    return values


def _attr(element, name: str, what: str, default=None) -> float:
    return float(_floats(element.get(name), 1, f"{what} {name}", None if default is None else [default])[0])


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (3, 3)."""
    cr, sr = math.cos(rpy[0]), math.sin(rpy[0])
    cp, sp = math.cos(rpy[1]), math.sin(rpy[1])
    cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _origin(element, what: str) -> tuple[np.ndarray, np.ndarray]:
    origin = element.find("origin") if element is not None else None
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = _floats(origin.get("xyz"), 3, f"{what} origin xyz", [0.0, 0.0, 0.0])
    rpy = _floats(origin.get("rpy"), 3, f"{what} origin rpy", [0.0, 0.0, 0.0])
    return rpy_matrix(rpy), xyz


# ---- links ---------------------------------------------------------------------------------------------------

def _checked_inertia(link: str, mass: float, tensor: np.ndarray) -> np.ndarray:
    """The inertia tensor, refused or repaired per the module docstring's rule."""
    if not math.isfinite(mass) or mass < 0.0:
        raise UrdfError(f"link '{link}': mass must be a finite number >= 0, got {mass:g}")
    moments, axes = np.linalg.eigh(tensor)
    scale = max(float(np.abs(moments).max()), 1e-300)
    tol = 1e-9 * scale
    if moments[0] < -tol:
        raise UrdfError(f"link '{link}': inertia is not positive semi-definite (principal moments "
                        f"{moments[0]:.6g}, {moments[1]:.6g}, {moments[2]:.6g})")
    moments = np.maximum(moments, 0.0)
    excess = moments[2] - moments[0] - moments[1]
    if excess > tol:
        repaired = moments + np.array([0.5 * excess, 0.5 * excess, 0.0])
        warnings.warn(f"URDF link '{link}': principal moments of inertia {moments[0]:.6g}, {moments[1]:.6g}, "
                      f"{moments[2]:.6g} break the triangle inequality; raised to {repaired[0]:.6g}, "
                      f"{repaired[1]:.6g}, {repaired[2]:.6g}", stacklevel=4)
        tensor = axes @ np.diag(repaired) @ axes.T
        return 0.5 * (tensor + tensor.T)
    return tensor


def _inertial(link_el, link: str) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass [kg], COM (3,) in the link frame, inertia about the COM in the link axes (3, 3) = R I Rᵀ)."""
    inertial = link_el.find("inertial")
    if inertial is None:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    what = f"link '{link}' inertial"
    R, xyz = _origin(inertial, what)
    mass_el = inertial.find("mass")
    mass = 0.0 if mass_el is None else _attr(mass_el, "value", f"{what} mass")
    el = inertial.find("inertia")
    values = {k: 0.0 if el is None else _attr(el, k, f"{what} inertia", 0.0)
              for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    tensor = np.array([[values["ixx"], values["ixy"], values["ixz"]],
                       [values["ixy"], values["iyy"], values["iyz"]],
                       [values["ixz"], values["iyz"], values["izz"]]])
    tensor = _checked_inertia(link, mass, R @ tensor @ R.T)
    return mass, xyz, tensor


def _geometries(link_el, link: str, tag: str, materials, resolve) -> list[Geometry]:
    out = []
    for k, el in enumerate(link_el.findall(tag)):
        what = f"link '{link}' {tag} {k}"
        R, xyz = _origin(el, what)
        geometry = el.find("geometry")
        shapes = [] if geometry is None else [g for g in geometry if isinstance(g.tag, str)]
        if len(shapes) != 1:
            raise UrdfError(f"{what}: <geometry> must hold exactly one shape")
        shape = shapes[0]
        mesh_path, scale, size = None, np.ones(3), np.zeros(0)
        if shape.tag == "box":
            size = _floats(shape.get("size"), 3, f"{what} box size")
        elif shape.tag == "sphere":
            size = np.array([_attr(shape, "radius", f"{what} sphere")])
        elif shape.tag == "cylinder":
            size = np.array([_attr(shape, "radius", f"{what} cylinder"), _attr(shape, "length", f"{what} cylinder")])
        elif shape.tag == "mesh":
            uri = shape.get("filename")
            if not uri:
                raise UrdfError(f"{what}: mesh without filename")
            mesh_path = resolve(uri, link)
            scale = _floats(shape.get("scale"), 3, f"{what} mesh scale", [1.0, 1.0, 1.0])
        else:
            raise UrdfError(f"{what}: unknown geometry <{shape.tag}> (box, sphere, cylinder, mesh)")
        if (size < 0).any() or (scale == 0).any():
            raise UrdfError(f"{what}: sizes must be >= 0 and mesh scales non-zero")
        rgba = _material_rgba(el.find("material"), materials, what) if tag == "visual" else None
        out.append(Geometry(shape.tag, size, R, xyz, mesh_path, scale, rgba, link))
    return out


def _material_rgba(material, materials: dict, what: str):
    if material is None:
        return None
    color = material.find("color")
    if color is not None:
        return np.clip(_floats(color.get("rgba"), 4, f"{what} material color rgba"), 0.0, 1.0)
    return materials.get(material.get("name"))


# ---- mesh paths ------------------------------------------------------------------------------------------------

def _package_dirs(package: str, package_paths) -> list[Path]:
    candidates = []
    if isinstance(package_paths, Mapping):
        if package in package_paths:
            candidates.append(Path(package_paths[package]))
    else:
        for d in package_paths or ():
            d = Path(d)
            candidates += [d / package] + ([d] if d.name == package else [])
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        candidates.append(Path(prefix) / "share" / package)
    for d in filter(None, os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep)):
        d = Path(d)
        candidates += [d / package] + ([d] if d.name == package else [])
    return candidates


def _mesh_resolver(base_dir: Path | None, package_paths):
    base = base_dir if base_dir is not None else Path.cwd()

    def resolve(uri: str, link: str) -> str:
        if uri.startswith("package://"):
            package, _, rest = uri[len("package://"):].partition("/")
            for d in _package_dirs(package, package_paths):
                candidate = d / rest
                if package and rest and candidate.is_file():
                    return str(candidate.resolve())
            raise UrdfError(f"link '{link}': mesh '{uri}' not found: no package '{package}' holding it in "
                            f"package_paths, AMENT_PREFIX_PATH or ROS_PACKAGE_PATH")
        path = uri[len("file://"):] if uri.startswith("file://") else uri
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*://", path):
            raise UrdfError(f"link '{link}': mesh '{uri}': only package://, file:// and plain paths are read")
        candidate = (base / Path(path).expanduser())
        if not candidate.is_file():
            raise UrdfError(f"link '{link}': mesh '{uri}' not found (no such file)")
        return str(candidate.resolve())

    return resolve


# ---- the tree --------------------------------------------------------------------------------------------------

class _Joint:
    __slots__ = ("name", "kind", "parent", "child", "rotation", "position", "axis", "lower", "upper", "effort",
                 "velocity", "damping", "friction", "mimic")


def _read_joint(el, links: set) -> _Joint:
    j = _Joint()
    j.name = el.get("name") or ""
    what = f"joint '{j.name}'"
    if not j.name:
        raise UrdfError("a joint without a name")
    kind = el.get("type")
    if kind not in _JOINT_KINDS:
        raise UrdfError(f"{what}: unknown type '{kind}' (revolute, continuous, prismatic, fixed, floating, planar)")
    j.kind = _JOINT_KINDS[kind]
    for end in ("parent", "child"):
        e = el.find(end)
        link = None if e is None else e.get("link")
        if not link:
            raise UrdfError(f"{what}: no <{end} link=...>")
        if link not in links:
            raise UrdfError(f"{what}: its {end} link '{link}' is not defined")
        setattr(j, end, link)
    if j.parent == j.child:
        raise UrdfError(f"{what}: parent and child are the same link '{j.child}' (a cycle)")
    j.rotation, j.position = _origin(el, what)
    axis = _floats(el.find("axis").get("xyz") if el.find("axis") is not None else None, 3, f"{what} axis xyz",
                   [1.0, 0.0, 0.0])
    norm = float(np.linalg.norm(axis))
    if j.kind in (JOINT_REVOLUTE, JOINT_PRISMATIC, JOINT_PLANAR) and norm < 1e-9:
        raise UrdfError(f"{what}: the axis is zero")
    j.axis = axis / norm if j.kind in (JOINT_REVOLUTE, JOINT_PRISMATIC, JOINT_PLANAR) else np.zeros(3)
    limit = el.find("limit")
    if limit is None and kind in ("revolute", "prismatic"):
        raise UrdfError(f"{what}: a {kind} joint must have a <limit> (URDF specification)")
    j.lower, j.upper, j.effort, j.velocity = -math.inf, math.inf, math.inf, math.inf
    if limit is not None:
        if kind in ("revolute", "prismatic"):
            j.lower = _attr(limit, "lower", f"{what} limit", 0.0)
            j.upper = _attr(limit, "upper", f"{what} limit", 0.0)
            if j.lower > j.upper:
                raise UrdfError(f"{what}: limit lower {j.lower:g} > upper {j.upper:g}")
        for key in ("effort", "velocity"):
            value = _attr(limit, key, f"{what} limit", 0.0)
            if value < 0:
                raise UrdfError(f"{what}: limit {key} must be >= 0, got {value:g}")
            setattr(j, key, math.inf if value == 0.0 else value)
    dynamics = el.find("dynamics")
    j.damping = 0.0 if dynamics is None else _attr(dynamics, "damping", f"{what} dynamics", 0.0)
    j.friction = 0.0 if dynamics is None else _attr(dynamics, "friction", f"{what} dynamics", 0.0)
    if j.damping < 0 or j.friction < 0:
        raise UrdfError(f"{what}: dynamics damping and friction must be >= 0")
    mimic = el.find("mimic")
    j.mimic = None
    if mimic is not None:
        leader = mimic.get("joint")
        if not leader:
            raise UrdfError(f"{what}: <mimic> without joint")
        j.mimic = (leader, _attr(mimic, "multiplier", f"{what} mimic", 1.0),
                   _attr(mimic, "offset", f"{what} mimic", 0.0))
    return j


class _Tree(NamedTuple):
    links: dict      # link name -> element, in file order
    joints: list     # _Joint, in file order
    root: str        # the root link
    children: dict   # link name -> the joints whose parent it is, in file order
    materials: dict  # material name -> rgba (4,)


def _tree(robot_el, label: str) -> _Tree:
    """The links, joints and materials of a ``<robot>``, checked to form one tree."""
    links: dict = {}
    materials: dict = {}
    for el in robot_el:
        if el.tag == "link":
            name = el.get("name")
            if not name:
                raise UrdfError(f"{label}: a link without a name")
            if name in links:
                raise UrdfError(f"{label}: link '{name}' is defined twice")
            links[name] = el
        elif el.tag == "material" and el.get("name") and el.find("color") is not None:
            materials[el.get("name")] = np.clip(_floats(el.find("color").get("rgba"), 4,
                                                        f"material '{el.get('name')}' rgba"), 0.0, 1.0)
        if len(links) > MAX_URDF_LINKS:
            raise UrdfError(f"{label}: more than {MAX_URDF_LINKS} links")
    # a material named and coloured inside a link's <visual> can be used by name elsewhere, as urdfdom reads it
    # (the top-level definition wins)
    for el in robot_el.iterfind("link/visual/material"):
        name, color = el.get("name"), el.find("color")
        if name and color is not None and name not in materials:
            materials[name] = np.clip(_floats(color.get("rgba"), 4, f"material '{name}' rgba"), 0.0, 1.0)
    if not links:
        raise UrdfError(f"{label}: no <link>")
    joints, names, parent_of = [], set(), {}
    for el in robot_el.iterfind("joint"):
        j = _read_joint(el, set(links))
        if j.name in names:
            raise UrdfError(f"joint '{j.name}' is defined twice")
        names.add(j.name)
        if j.child in parent_of:
            raise UrdfError(f"link '{j.child}' is the child of two joints ('{parent_of[j.child]}' and '{j.name}')")
        parent_of[j.child] = j.name
        joints.append(j)
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        if not roots:
            raise UrdfError(f"{label}: no root link (every link is a child: the joints form a cycle)")
        raise UrdfError(f"{label}: {len(roots)} root links ({', '.join(repr(r) for r in roots[:5])}): a URDF is "
                        f"one tree")
    children: dict = {}
    for j in joints:
        children.setdefault(j.parent, []).append(j)
    return _Tree(links, joints, roots[0], children, materials)


# ---- the model -------------------------------------------------------------------------------------------------

def load_urdf(source, *, package_paths=(), xacro_args=None, fixed_base: bool = True,
              name: str | None = None) -> RobotModel:
    """The :class:`RobotModel` of a URDF (module docstring: parsing, limits, inertias, base, mesh paths).

    Args:
        source: a path (``str`` or ``PathLike``; ``.xacro`` files are expanded) or URDF XML text (a ``str``
            starting with ``<``, or UTF-8 ``bytes``).
        package_paths: where ``package://`` URIs are looked for first: ``{package: directory}`` or directories.
        xacro_args: ``{name: value}`` for a ``.xacro`` file's ``<xacro:arg>``.
        fixed_base: weld the root link to the world (True) or give it a floating joint.
        name: the model's name (default: the ``<robot name>``).

    Raises:
        UrdfError (a ValueError) naming the link or joint and the reason.
    """
    text, base_dir, label = _read_source(source, xacro_args)
    robot_el = _parse_xml(text, label)
    links, joints, root, children, materials = _tree(robot_el, label)
    resolve = _mesh_resolver(base_dir, package_paths)
    if root == "world":
        fixed_base = True
    builder = _Builder(links, materials, resolve)
    builder.add_body(root, None, JOINT_FIXED_ROOT if fixed_base else JOINT_FLOATING, np.eye(3), np.zeros(3))
    # depth first, children in file order: parent before child
    stack = [(root, iter(children.get(root, ())))]
    reached = {root}
    while stack:
        link, it = stack[-1]
        j = next(it, None)
        if j is None:
            stack.pop()
            continue
        reached.add(j.child)
        body = builder.frame_body[link]
        Rf, xf = builder.frame_pose[link]
        Rj, xj = Rf @ j.rotation, xf + Rf @ j.position
        if j.kind == -1:
            builder.add_frame(j.child, body, Rj, xj)
        elif j.kind == JOINT_FLOATING:
            raise UrdfError(f"joint '{j.name}': a floating joint is allowed only at the root; load with "
                            f"fixed_base=False for a free-floating robot")
        else:
            builder.add_body(j.child, j, j.kind, Rj, xj, parent=body)
        stack.append((j.child, iter(children.get(j.child, ()))))
    unreached = [link for link in links if link not in reached]
    if unreached:
        raise UrdfError(f"{label}: links {', '.join(repr(u) for u in unreached[:5])} are not reached from the "
                        f"root '{root}' (the joints form a cycle)")
    return builder.model(name or robot_el.get("name") or "robot", text)


class _Builder:
    """Bodies and frames as the tree is walked."""

    def __init__(self, links, materials, resolve):
        self.links, self.materials, self.resolve = links, materials, resolve
        self.bodies: list[dict] = []
        self.frame_body: dict = {}
        self.frame_pose: dict = {}
        self.frame_order: list[str] = []
        self.shapes = 0

    def add_body(self, link, joint, kind, Rj, xj, parent=-1):
        self.bodies.append({"link": link, "joint": joint, "kind": kind, "parent": parent, "R": Rj, "x": xj,
                            "parts": [], "collisions": [], "visuals": []})
        self.add_frame(link, len(self.bodies) - 1, np.eye(3), np.zeros(3))

    def add_frame(self, link, body, R, x):
        self.frame_body[link] = body
        self.frame_pose[link] = (R, x)
        self.frame_order.append(link)
        el = self.links[link]
        mass, com, inertia = _inertial(el, link)
        b = self.bodies[body]
        b["parts"].append((mass, x + R @ com, R @ inertia @ R.T, link))
        self.shapes += len(el.findall("collision")) + len(el.findall("visual"))
        if self.shapes > MAX_URDF_SHAPES:
            raise UrdfError(f"link '{link}': more than {MAX_URDF_SHAPES} collision and visual shapes in the URDF")
        for key, tag in (("collisions", "collision"), ("visuals", "visual")):
            for g in _geometries(el, link, tag, self.materials, self.resolve):
                b[key].append(Geometry(g.kind, g.size, R @ g.rotation, x + R @ g.position, g.mesh_path,
                                       g.mesh_scale, g.rgba, g.link))

    @staticmethod
    def _merged(parts):
        """(mass, COM, inertia about the COM) of a body's links: Σ m, Σ m c / Σ m, Σ (I_k + parallel-axis term)."""
        masses = np.array([p[0] for p in parts])
        total = float(masses.sum())
        coms = np.array([p[1] for p in parts])
        com = masses @ coms / total if total > 0 else np.zeros(3)
        inertia = sum(parallel_axis(p[2], p[0], p[1] - com) for p in parts)
        return total, com, 0.5 * (inertia + inertia.T)

    def model(self, name: str, source: str) -> RobotModel:
        n = len(self.bodies)
        merged = [self._merged(b["parts"]) for b in self.bodies]
        mass = np.array([m[0] for m in merged])
        subtree = mass.copy()
        for i in range(n - 1, 0, -1):
            subtree[self.bodies[i]["parent"]] += subtree[i]
        for i, b in enumerate(self.bodies):
            if b["kind"] != JOINT_FIXED_ROOT and subtree[i] <= 0.0:
                joint = f"joint '{b['joint'].name}'" if b["joint"] is not None else "its floating joint"
                raise UrdfError(f"link '{b['link']}': no mass at or below it, so {joint} would have a singular "
                                f"mass matrix")
        dof_count = np.array([JOINT_DOFS[b["kind"]][0] for b in self.bodies], dtype=np.int64)
        q_count = np.array([JOINT_DOFS[b["kind"]][1] for b in self.bodies], dtype=np.int64)
        dof_start = np.concatenate([[0], np.cumsum(dof_count)[:-1]]).astype(np.int64)
        q_start = np.concatenate([[0], np.cumsum(q_count)[:-1]]).astype(np.int64)
        dofs = self._dofs(dof_count)
        mimic = self._mimic(dof_start, dof_count)
        frames = self.frame_order
        return RobotModel(
            name=name, body_names=tuple(b["link"] for b in self.bodies),
            parent=np.array([b["parent"] for b in self.bodies], dtype=np.int64),
            joint_names=tuple(b["joint"].name if b["joint"] is not None else "" for b in self.bodies),
            joint_type=np.array([b["kind"] for b in self.bodies], dtype=np.int64),
            joint_rotation=np.array([b["R"] for b in self.bodies]).reshape(n, 3, 3),
            joint_position=np.array([b["x"] for b in self.bodies]).reshape(n, 3),
            joint_axis=np.array([b["joint"].axis if b["joint"] is not None else np.zeros(3)
                                 for b in self.bodies]).reshape(n, 3),
            dof_start=dof_start, dof_count=dof_count, q_start=q_start, q_count=q_count,
            n_dofs=int(dof_count.sum()), n_q=int(q_count.sum()),
            mass=mass, com=np.array([m[1] for m in merged]).reshape(n, 3),
            inertia=np.array([m[2] for m in merged]).reshape(n, 3, 3),
            **dofs, **mimic,
            frame_names=tuple(frames), frame_body=np.array([self.frame_body[f] for f in frames], dtype=np.int64),
            frame_rotation=np.array([self.frame_pose[f][0] for f in frames]).reshape(len(frames), 3, 3),
            frame_position=np.array([self.frame_pose[f][1] for f in frames]).reshape(len(frames), 3),
            collisions=tuple(tuple(b["collisions"]) for b in self.bodies),
            visuals=tuple(tuple(b["visuals"]) for b in self.bodies), source=source)

    def _dofs(self, dof_count) -> dict:
        names, rows = [], []
        for b, count in zip(self.bodies, dof_count):
            j = b["joint"]
            base = j.name if j is not None else b["link"]
            suffixes = _DOF_SUFFIXES.get(b["kind"], ("",))
            for k in range(count):
                names.append(base + suffixes[k])
                if b["kind"] in (JOINT_REVOLUTE, JOINT_PRISMATIC):
                    rows.append((j.lower, j.upper, j.effort, j.velocity, j.damping, j.friction))
                elif j is not None:  # planar: no position limits
                    rows.append((-math.inf, math.inf, j.effort, j.velocity, j.damping, j.friction))
                else:  # the floating root
                    rows.append((-math.inf, math.inf, math.inf, math.inf, 0.0, 0.0))
        table = np.array(rows, dtype=float).reshape(len(rows), 6)
        return {"dof_names": tuple(names), "lower": table[:, 0].copy(), "upper": table[:, 1].copy(),
                "effort_limit": table[:, 2].copy(), "velocity_limit": table[:, 3].copy(),
                "damping": table[:, 4].copy(), "friction": table[:, 5].copy()}

    def _mimic(self, dof_start, dof_count) -> dict:
        by_joint = {b["joint"].name: i for i, b in enumerate(self.bodies) if b["joint"] is not None}
        pairs = []
        for i, b in enumerate(self.bodies):
            j = b["joint"]
            if j is None or j.mimic is None:
                continue
            leader, multiplier, offset = j.mimic
            what = f"joint '{j.name}': mimic"
            if dof_count[i] != 1:
                raise UrdfError(f"{what}: only a revolute, continuous or prismatic joint can mimic")
            if leader not in by_joint:
                raise UrdfError(f"{what}: no moving joint '{leader}' to follow")
            if dof_count[by_joint[leader]] != 1:
                raise UrdfError(f"{what}: the joint '{leader}' it follows has {dof_count[by_joint[leader]]} dofs")
            if leader == j.name or self.bodies[by_joint[leader]]["joint"].mimic is not None:
                raise UrdfError(f"{what}: the joint '{leader}' it follows is itself a mimic joint (chains are "
                                f"not supported)")
            pairs.append((dof_start[i], dof_start[by_joint[leader]], multiplier, offset))
        table = np.array(pairs, dtype=float).reshape(len(pairs), 4)
        return {"mimic_follower": table[:, 0].astype(np.int64), "mimic_leader": table[:, 1].astype(np.int64),
                "mimic_multiplier": table[:, 2].copy(), "mimic_offset": table[:, 3].copy()}
