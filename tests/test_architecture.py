"""ARCHITECTURE.md's rules, checked on the sources: every module is in its module maps (and the maps name no
module that is not there); ``cgp_core`` never imports ROS and ``cgp_sim_ros`` imports it only in
``cgp_sim_ros/ros/`` (parsed, and imported where no ROS package can be); no import cycle; no function of
``cgp_core`` or ``cgp_sim_ros`` with more than 10 parameters or a tuple of more than 4 returned; no module reaching into
another's private attributes (``node._pending``)."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ARCHITECTURE = (REPO / "ARCHITECTURE.md").read_text()
PACKAGES = ("cgp_core", "cgp_sim_ros")
#: the subpackage of cgp_sim_ros that may import ROS; every other module of it must not
ROS_SIDE = "cgp_sim_ros/ros"

#: ROS packages by name (and below, by the name patterns of interface packages)
ROS = ("rclpy", "rosidl", "rosidl_runtime_py", "rpyutils", "rcl_interfaces", "builtin_interfaces", "std_msgs",
       "geometry_msgs", "nav_msgs", "visualization_msgs", "rosgraph_msgs", "std_srvs", "cgp_sim_msgs",
       "tf2_msgs", "simulation_interfaces", "action_msgs", "ament_index_python")


def _is_ros(module: str) -> bool:
    top = module.split(".")[0]
    return top in ROS or top.startswith(("rcl", "rosidl", "ament_")) or top.endswith(("_msgs", "_srvs",
                                                                                       "_interfaces"))


def _modules(package: str) -> list[Path]:
    return sorted(p for p in (REPO / package).rglob("*.py") if "__pycache__" not in p.parts)


def _ros_free_modules() -> list[Path]:
    return [p for p in _modules("cgp_sim_ros") if not p.is_relative_to(REPO / ROS_SIDE)]


def _dotted(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


# ---- the module maps ---------------------------------------------------------------------------------------

def _map_entries(package: str) -> set[str]:
    """The module paths (relative to ``package``) ARCHITECTURE.md's "<package> module map" names: each row's
    first cell names its subject (``jit.py``, ``boids/``, ``ros/node.py``); a ``name.py`` in the row is a module
    beside the subject (inside it, for a directory), a ``dir/name.py`` one relative to the package."""
    section = ARCHITECTURE.split(f"## {package} module map", 1)[1].split("\n## ", 1)[0]
    named = set()
    for row in (line for line in section.splitlines() if line.startswith("|")):
        cells = row.split("|")
        subjects = re.findall(r"`([^`]+)`", cells[1])
        if not subjects:
            continue  # the header
        first = subjects[0]
        base = first if first.endswith("/") else first.rpartition("/")[0] + "/" if "/" in first else ""
        for token in re.findall(r"`([^`\s]+)`", row):
            if token.endswith(".py"):
                named.add(token if "/" in token else base + token)
            elif token.endswith("/"):
                named.add(token)
    return named


@pytest.mark.parametrize("package", PACKAGES)
def test_every_module_is_in_the_module_map(package):
    """Every module has a line in ARCHITECTURE.md (a subpackage's ``__init__.py``: the subpackage named), and
    every module the map names exists."""
    named = _map_entries(package)
    root = REPO / package
    files = {p.relative_to(root).as_posix() for p in _modules(package)} - {"__init__.py"}
    directories = {f.rpartition("/")[0] + "/" for f in files if "/" in f}
    missing = sorted(f for f in files if f not in named
                     and not (f.endswith("/__init__.py") and any(n.startswith(f[:-len("__init__.py")])
                                                                 for n in named)))
    assert not missing, f"not in ARCHITECTURE.md's {package} module map: {', '.join(missing)}"
    stale = sorted(n for n in named if n not in files and n not in directories)
    assert not stale, f"ARCHITECTURE.md's {package} module map names what is not there: {', '.join(stale)}"


# ---- ROS where it belongs ---------------------------------------------------------------------------------

def _imports(path: Path):
    """(line, imported module, guarded) for every import statement of a module, at any depth; ``guarded``: inside
    a ``try`` that handles ImportError (an optional dependency)."""
    tree = ast.parse(path.read_text(), str(path))
    package = _dotted(path) if path.name == "__init__.py" else _dotted(path).rpartition(".")[0]
    guarded_nodes = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and any(
                isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError")
                for h in node.handlers):
            guarded_nodes.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            names = [module] + [f"{module}.{a.name}" for a in node.names]
        else:
            continue
        for name in names:
            yield node.lineno, name, id(node) in guarded_nodes


def test_the_sources_import_ros_only_on_the_ros_side():
    """Parsed, so that a function-level import counts too: cgp_core imports neither ROS nor cgp_sim_ros; the
    modules of cgp_sim_ros outside ros/ import no ROS package (an optional one only behind an ImportError
    handler, which the import test below shows works without it) and nothing from ros/."""
    findings = {}  # (module, line) -> what it imports
    for path in _modules("cgp_core"):
        findings.update({(path.relative_to(REPO), line): name for line, name, _ in _imports(path)
                         if _is_ros(name) or name.split(".")[0] == "cgp_sim_ros"})
    for path in _ros_free_modules():
        findings.update({(path.relative_to(REPO), line): name for line, name, guarded in _imports(path)
                         if (_is_ros(name) and not guarded) or name.startswith("cgp_sim_ros.ros")})
    assert not findings, "ROS imported outside cgp_sim_ros/ros/:\n" + "\n".join(
        f"{path}:{line}: {name}" for (path, line), name in sorted(findings.items()))
    assert len(_ros_free_modules()) > 10  # the check sees the ROS-free side at all


_NO_ROS = """
import importlib.abc, sys
ROS = {ros!r}
class NoRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        top = name.split('.')[0]
        if top in ROS or top.startswith(('rcl', 'rosidl', 'ament_')) or top.endswith(('_msgs', '_srvs',
                                                                                       '_interfaces')) \\
                or name.startswith({blocked!r}):
            raise ImportError(f'ROS package {{name}} imported')
sys.meta_path.insert(0, NoRos())
"""


def _run_without_ros(code: str, blocked: tuple[str, ...]) -> subprocess.CompletedProcess:
    """``code`` in a Python where importing any ROS package, or a module starting with one of ``blocked``, fails
    (the source tree's packages: the repository is the working directory)."""
    setup = _NO_ROS.format(ros=ROS, blocked=blocked)
    return subprocess.run([sys.executable, "-c", setup + textwrap.dedent(code)], capture_output=True, text=True,
                          cwd=REPO, timeout=600)


def test_core_runs_without_any_ros_package():
    """cgp_core imports and steps a scene in a process where importing any ROS package fails."""
    code = """
        from cgp_core.world import World
        w = World.from_scene('default')
        z0 = w.body_state.position[0, 2]
        for _ in range(30):
            w.step()
        assert w.body_state.position[0, 2] < z0
        assert not any(m.split('.')[0] in ROS for m in sys.modules)
        print('ok')
    """
    out = _run_without_ros(code, blocked=("cgp_sim_ros",))
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_the_ros_free_side_of_cgp_sim_ros_runs_without_any_ros_package(tmp_path):
    """Every module of cgp_sim_ros outside ros/ imports where no ROS package (nor cgp_sim_ros.ros) can be
    imported, and what they are for works there: a bag written (its schema found in the ament index without
    ament_index_python) holds the marker written into it, read back with the renderer's reader."""
    modules = [_dotted(p) for p in _ros_free_modules()]
    code = f"""
        import importlib
        for name in {modules!r}:
            importlib.import_module(name)
        import numpy as np
        from cgp_sim_ros.wire import cdr
        from cgp_sim_ros.wire.bag import BagWriter
        from cgp_sim_ros.render.bagread import open_marker_stream
        data = cdr.marker_array([cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE_LIST, ns='a',
                                                             points=np.eye(3)))])
        with BagWriter({str(tmp_path / "bag")!r}) as bag:
            bag.add_topic('/cgp_sim/markers', 'visualization_msgs/msg/MarkerArray')
            bag.write('/cgp_sim/markers', data, 1, 1)
        stream = open_marker_stream({str(tmp_path / "bag")!r})
        (t, raw), = list(stream.messages())
        markers = cdr.read_marker_array(raw)
        assert t == 1 and markers[0].points.tolist() == np.eye(3).tolist(), markers
        loaded = sorted(m for m in sys.modules if m.split('.')[0] in ROS or m.startswith('cgp_sim_ros.ros'))
        print('ok', len({modules!r}), loaded)
    """
    out = _run_without_ros(code, blocked=("cgp_sim_ros.ros",))
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"ok {len(modules)} []", out.stdout + out.stderr


# ---- the shape of the code -------------------------------------------------------------------------------

def _project_import_graph() -> dict[str, set[str]]:
    modules = {_dotted(p): p for package in PACKAGES for p in _modules(package)}
    graph = {name: set() for name in modules}
    for name, path in modules.items():
        for _, imported, _ in _imports(path):
            while imported and imported not in modules:
                imported = imported.rpartition(".")[0]
            # a module importing its own package (`from . import x`) depends on x, not on the package itself
            if imported and imported != name and not name.startswith(imported + "."):
                graph[name].add(imported)
    return graph


def test_no_import_cycle():
    """No two modules of the project import each other, directly or around a loop (function-level imports
    count: a cycle held together by one is still a cycle)."""
    graph = _project_import_graph()
    assert "cgp_sim_ros.ros.node" in graph["cgp_sim_ros.ros.cli"]  # the graph sees function-level imports
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    cycles = []

    def visit(name: str, path: list[str]) -> None:
        state[name] = 1
        for target in sorted(graph[name]):
            if state.get(target) == 1:
                cycles.append(" -> ".join(path[path.index(target):] + [target]))
            elif target not in state:
                visit(target, path + [target])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


#: the most parameters a function takes, and the most values it returns as a bare tuple
MAX_PARAMETERS, MAX_RETURNED = 10, 4


def _signature_findings(tree: ast.AST, where: str) -> list[str]:
    """Every function of ``tree`` with more than MAX_PARAMETERS parameters (``self`` / ``cls`` do not count;
    ``*args`` and ``**kwargs`` count one each) or a ``return`` of a bare tuple of more than MAX_RETURNED values."""
    findings = []
    for node in ast.walk(tree):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        a = node.args
        names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
        count = len(names) - (names[:1] in (["self"], ["cls"])) + (a.vararg is not None) + (a.kwarg is not None)
        at = f"{where}:{node.lineno} {node.name}"
        if count > MAX_PARAMETERS:
            findings.append(f"{at}: {count} parameters")
        findings += [f"{at}: returns {len(r.value.elts)} values" for r in ast.walk(node) if isinstance(r, ast.Return)
                     and isinstance(r.value, ast.Tuple) and len(r.value.elts) > MAX_RETURNED]
    return findings


@pytest.mark.parametrize("package", PACKAGES)
def test_no_function_takes_more_than_10_parameters_or_returns_more_than_4_values(package):
    """Arrays travel in named bundles (``typing.NamedTuple``: ``ContactSet``, the solver's ``Manifolds`` / ``Rows``,
    the flock's ``BoidArrays`` ...), not as long argument lists or positional tuples.  The rule has no exemption
    for compiled kernels: a small kernel that returns a vector's components (a contact point's normal,
    separation and point; two tangents) returns a NamedTuple of numbers (``ContactPoint``, ``Tangents``), which
    numba keeps in registers like a bare tuple (no allocation) and which names what a bare tuple only numbers."""
    findings = []
    for path in _modules(package):
        findings += _signature_findings(ast.parse(path.read_text(), str(path)), str(path.relative_to(REPO)))
    assert not findings, "\n".join(findings)


def test_the_signature_check_finds_long_signatures_and_bare_tuples():
    """The check fails where it should: the solver's old signature and a scalar kernel returning a bare 7-tuple
    are found, their bundled forms are not."""
    tree = ast.parse(textwrap.dedent("""
        def solve_step(a, b, n, s, p, k, f, e, im, mv, ii, x, P, L, F, T, h, ok, on, of, op, vi, vt, rt, ws, rr, i):
            return a, b, n, s, p, k, f, e, im, mv, ii, x, P, L, F, T, h
        def sphere_sphere_point(ax, ay, az, ra, bx, by, bz, rb):
            return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0
        def solve_step_bundled(contacts, bodies, memory, settings, profile):
            return Solved(contacts, bodies, memory, settings, profile), memory
        def sphere_sphere_point_bundled(ax, ay, az, ra, bx, by, bz, rb):
            return ContactPoint(0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
        class Solver:
            def method(self, a, b, c, d, e, f, g, h, i, j):
                return a, b, c, d
    """))
    assert _signature_findings(tree, "x") == ["x:2 solve_step: 27 parameters", "x:2 solve_step: returns 17 values",
                                              "x:4 sphere_sphere_point: returns 7 values"]


def _own_private_names(tree: ast.AST) -> set[str]:
    """The private names a module defines: functions, classes, attributes it assigns (``self._x = ...``),
    module-level names."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Attribute):
            names.add(node.target.attr)
    return {n for n in names if n.startswith("_")}


def test_no_module_of_cgp_sim_ros_reaches_into_another_objects_private_attributes():
    """``x._name`` only on ``self`` / ``cls``, or for a name the module itself defines (its own helper
    classes); never on the node outside ros/node.py: a collaborator uses the node's public methods, not
    ``node._pending``."""
    findings = []
    for path in _modules("cgp_sim_ros"):
        tree = ast.parse(path.read_text(), str(path))
        own = _own_private_names(tree)
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")):
                continue
            receiver = node.value
            if isinstance(receiver, ast.Name) and receiver.id in ("self", "cls"):
                continue
            on_the_node = (receiver.id if isinstance(receiver, ast.Name) else
                           receiver.attr if isinstance(receiver, ast.Attribute) else "") in ("node", "_node")
            if node.attr not in own or (on_the_node and path != REPO / ROS_SIDE / "node.py"):
                findings.append(f"{path.relative_to(REPO)}:{node.lineno}: {ast.unparse(node)}")
    assert not findings, "private attributes of other modules' objects:\n" + "\n".join(findings)
