"""Issue 8, scenes: every kind of bad scene gets a clear error naming the file, the key path and the reason,
all problems of a file at once, before anything is built (core tests for every case), and through `cgp-sim`
the node does not start: exit status 2, the message on stderr, nothing published.  Plus the security side
of reading input: YAML's safe subset only (a `!!python` tag is an error, never executed), and no
eval / exec / pickle anywhere in the package sources.
"""

from __future__ import annotations

import ast
import math
import os
from pathlib import Path

import pytest
import yaml
from geometry_msgs.msg import PoseArray

from cgp_core import scene
from cgp_core.scene import MAX_SCENE_BYTES, SceneError, builtin_scene_names, load_scene, parse_scene

REPO = Path(__file__).resolve().parents[1]
SPHERE = "{name: ball, shape: sphere, radius: 0.5, mass: 1.0}"


def scene_error(text: str, source: str = "scene.yaml") -> SceneError:
    with pytest.raises(SceneError) as info:
        parse_scene(text, source)
    return info.value


# (YAML text, the key path the error must name, what it must say about it)
BAD_SCENES = {
    "malformed YAML": ("bodies: [\n  {name: a, shape: sphere", "line 3, column", "malformed YAML"),
    "tab indentation": ("world:\n\tgravity: [0, 0, 0]\n", "line 2", "malformed YAML"),
    "top level a list": ("- ball\n- crate\n", "top level", "must be a mapping"),
    # unknown keys (typos), with the valid ones listed
    "unknown top-level key": ("bodys: []\n", "bodys",
                              "unknown key (valid: bodies, description, flocks, joints, named_poses, robots, tags, "
                              "world)"),
    "unknown world key": ("world: {gravty: [0, 0, 0]}\n", "world.gravty", "unknown key (valid: angular_damping, "),
    "unknown body key": ("bodies: [{name: a, shape: sphere, radius: 1, mass: 1, colour: [1, 0, 0, 1]}]",
                         "bodies[0].colour", "unknown key"),
    "unknown flock key": ("flocks: [{name: f, count: 5, spwan: {center: [0, 0, 1]}}]", "flocks[0].spwan",
                          "unknown key"),
    "key for another shape": ("bodies: [{name: a, shape: sphere, radius: 1, size: [1, 1, 1], mass: 1}]",
                              "bodies[0] (a).size", "does not apply to shape sphere (it is for box)"),
    "duplicate key": ("bodies:\n  - name: a\n    shape: sphere\n    radius: 1\n    mass: 1\n    mass: 2\n",
                      "line 6, column 5", "duplicate key (first given at line 5, column 5)"),
    # wrong types
    "radius a string": ("bodies: [{name: a, shape: sphere, radius: big, mass: 1}]", "bodies[0] (a).radius",
                        "must be a number, got a string 'big'"),
    "quoted number": ("bodies: [{name: a, shape: sphere, radius: 1, density: '1e3'}]",
                      "bodies[0] (a).density", "got a string '1e3' (a number in quotes is text in YAML: write it "
                      "without the quotes)"),
    "mass a list": ("bodies: [{name: a, shape: sphere, radius: 1, mass: [1]}]", "bodies[0] (a).mass",
                    "must be a number, got a list"),
    "fixed a string": ("bodies: [{name: a, shape: sphere, radius: 1, mass: 1, fixed: 'yes'}]",
                       "bodies[0] (a).fixed", "must be true or false"),
    "gravity of 2": ("world: {gravity: [0, -9.81]}", "world.gravity", "must be a list of 3 numbers"),
    "position a string": ("bodies: [{name: a, shape: sphere, radius: 1, mass: 1, position: origin}]",
                          "bodies[0] (a).position", "must be a list of 3 numbers, got a string 'origin'"),
    "integrator unknown": ("world: {integrator: verlet}", "world.integrator", "must be one of "),
    "shape unknown": ("bodies: [{name: a, shape: cone, radius: 1, mass: 1}]", "bodies[0] (a).shape",
                      "must be one of sphere, box, capsule, particles"),
    "count not an integer": ("flocks: [{name: f, count: 2.5}]", "flocks[0] (f).count", "must be an integer"),
    "count a boolean": ("flocks: [{name: f, count: true}]", "flocks[0] (f).count", "got a boolean"),
    "name not a string": ("bodies: [{name: 12, shape: sphere, radius: 1, mass: 1}]", "bodies[0].name",
                          "must be a string (a ROS-safe name), got int 12"),
    # non-finite and absurd numbers
    "mass NaN": ("bodies: [{name: a, shape: sphere, radius: 1, mass: .nan}]", "bodies[0] (a).mass",
                 "must be finite"),
    "radius infinite": ("bodies: [{name: a, shape: sphere, radius: .inf, mass: 1}]", "bodies[0] (a).radius",
                        "must be finite"),
    "integer beyond float": ("bodies: [{name: a, shape: sphere, radius: 1, mass: 1" + "0" * 400 + "}]",
                             "bodies[0] (a).mass", "must be finite"),
    "count above the bound": ("flocks: [{name: f, count: 100000000}]", "flocks[0] (f).count",
                              "must be <= 100000"),
    # negative / zero mass and sizes
    "negative mass": ("bodies: [{name: a, shape: sphere, radius: 1, mass: -2}]", "bodies[0] (a).mass",
                      "must be > 0, got -2"),
    "zero mass": ("bodies: [{name: a, shape: sphere, radius: 1, mass: 0}]", "bodies[0] (a).mass",
                  "must be > 0, got 0"),
    "zero density": ("bodies: [{name: a, shape: box, size: [1, 1, 1], density: 0}]", "bodies[0] (a).density",
                     "must be > 0"),
    "negative radius": ("bodies: [{name: a, shape: sphere, radius: -0.5, mass: 1}]", "bodies[0] (a).radius",
                        "must be > 0, got -0.5"),
    "zero box side": ("bodies: [{name: a, shape: box, size: [1, 0, 1], mass: 1}]", "bodies[0] (a).size[1]",
                      "must be > 0, got 0"),
    "zero capsule length": ("bodies: [{name: a, shape: capsule, radius: 0.2, length: 0, mass: 1}]",
                            "bodies[0] (a).length", "must be > 0"),
    "zero particle mass": ("bodies: [{name: a, shape: particles, particles: [[0, 0, 0, 1], [1, 0, 0, 0], "
                           "[0, 1, 0, 1]]}]", "bodies[0] (a).particles[1]", "particle mass must be > 0"),
    "missing size": ("bodies: [{name: a, shape: box, mass: 1}]", "bodies[0] (a).size", "missing"),
    # degenerate inertia
    "collinear particles": ("bodies: [{name: rod, shape: particles, particles: [[0, 0, 0, 1], [1, 0, 0, 1], "
                            "[2, 0, 0, 1]]}]", "bodies[0] (rod).particles",
                            "singular inertia tensor: the particles are (nearly) collinear"),
    "one particle": ("bodies: [{name: dot, shape: particles, particles: [[0, 0, 0, 1]]}]",
                     "bodies[0] (dot).particles", "a single particle has no rotational inertia"),
    "coincident particles": ("bodies: [{name: p, shape: particles, particles: [[1, 1, 1, 1], [1, 1, 1, 2], "
                             "[1, 1, 1, 1]]}]", "bodies[0] (p).particles", "all particles are at the same point"),
    "zero quaternion": ("bodies: [{name: a, shape: sphere, radius: 1, mass: 1, orientation: [0, 0, 0, 0]}]",
                        "bodies[0] (a).orientation", "zero quaternion"),
    # names
    "duplicate body names": (f"bodies: [{SPHERE}, {SPHERE}]", "bodies[1].name", "duplicate name 'ball'"),
    "body and flock share a name": (f"bodies: [{SPHERE}]\nflocks: [{{name: ball, count: 3}}]",
                                    "flocks[0].name", "duplicate name 'ball'"),
    "name with a space": ("bodies: [{name: 'my ball', shape: sphere, radius: 1, mass: 1}]", "bodies[0].name",
                          "'my ball' is not a ROS-safe name"),
    "name with a slash": ("bodies: [{name: 'a/b', shape: sphere, radius: 1, mass: 1}]", "bodies[0].name",
                          "not a ROS-safe name"),
    "name starting with a digit": ("bodies: [{name: 2nd, shape: sphere, radius: 1, mass: 1}]",
                                   "bodies[0].name", "not a ROS-safe name"),
    "name not ASCII": ("bodies: [{name: bäll, shape: sphere, radius: 1, mass: 1}]", "bodies[0].name",
                       "not a ROS-safe name"),
    "empty name": ("flocks: [{name: '', count: 3}]", "flocks[0].name", "'' is not a ROS-safe name"),
    "name too long": ("bodies: [{name: " + "b" * 65 + ", shape: sphere, radius: 1, mass: 1}]", "bodies[0].name",
                      "is 65 characters long; names are at most 64"),
    "missing name": ("bodies: [{shape: sphere, radius: 1, mass: 1}]", "bodies[0].name", "missing"),
    # flocks
    "flock count 0": ("flocks: [{name: f, count: 0}]", "flocks[0] (f).count", "must be >= 1, got 0"),
    "flock count negative": ("flocks: [{name: f, count: -5}]", "flocks[0] (f).count", "must be >= 1"),
    "flock radius 0": ("flocks: [{name: f, count: 10, radius: 0}]", "flocks[0] (f).radius", "must be > 0, got 0"),
    "flock radius negative": ("flocks: [{name: f, count: 10, radius: -2}]", "flocks[0] (f).radius",
                              "must be > 0, got -2"),
    "flock separation beyond radius": ("flocks: [{name: f, count: 10, radius: 1, separation_radius: 2}]",
                                       "flocks[0] (f)", "separation_radius (2.0) must be smaller than radius"),
    "flock speeds crossed": ("flocks: [{name: f, count: 10, min_speed: 3, max_speed: 1}]", "flocks[0] (f)",
                             "min_speed (3.0) must not exceed max_speed (1.0)"),
    "flock missing count": ("flocks: [{name: f}]", "flocks[0] (f).count", "missing"),
}


@pytest.mark.parametrize("case", list(BAD_SCENES))
def test_a_bad_scene_is_an_error_naming_file_key_and_reason(case):
    text, key, reason = BAD_SCENES[case]
    error = scene_error(text, "/scenes/bad.yaml")
    message = str(error)
    assert any(line.startswith("/scenes/bad.yaml: ") and key in line and reason in line
               for line in message.splitlines()), message
    assert len(message) < 1000, "errors stay readable whatever the input"


def test_every_problem_of_a_file_is_reported_at_once():
    text = """
world: {gravity: [0, 0], substeps: 0}
bodies:
  - {name: a, shape: sphere, radius: -1, mass: 1}
  - {name: a, shape: box, size: [1, 1, 1], mass: 0}
  - {name: rod, shape: particles, particles: [[0, 0, 0, 1], [0, 0, 1, 1]]}
flocks:
  - {name: fish, count: 0, radius: 0}
"""
    problems = scene_error(text).problems
    expected = ["world.gravity", "world.substeps", "bodies[0] (a).radius", "bodies[1].name", "bodies[1] (a).mass",
                "bodies[2] (rod).particles", "flocks[0] (fish).count", "flocks[0] (fish).radius"]
    for key in expected:
        assert any(p.startswith(key + ":") for p in problems), (key, problems)


def test_huge_scenes_give_short_errors():
    """A scene can be large (16 MB) or alias-expand to far more: an error message quotes a bounded excerpt.
    Nine levels of nine-fold aliases are 9^9 ≈ 387 million numbers if printed whole."""
    lines = ["l0: &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for level in range(1, 9):
        lines.append(f"l{level}: &l{level} [" + ", ".join([f"*l{level - 1}"] * 9) + "]")
    text = "description:\n" + "".join(f"  {line}\n" for line in lines)
    text += "bodies: [{name: p, shape: particles, particles: *l8}]\n"
    message = str(scene_error(text))
    assert "bodies[0] (p).particles[0]: must be a list of 4 numbers, got a list" in message
    assert max(len(line) for line in message.splitlines()) < 200 and len(message) < 2000, message
    # a million problems (e.g. one per bad particle) are all kept but the message lists the first 50
    bad_rows = "[" + ", ".join(["[0, 0, 0]"] * 2000) + "]"
    error = scene_error(f"bodies: [{{name: p, shape: particles, particles: {bad_rows}}}]")
    assert len(error.problems) == 2000 and str(error).count("\n") == 50
    assert str(error).endswith("... and 1950 more problems")


# ---- numbers as users write them (YAML 1.2 floats) -------------------------------------------------------


@pytest.mark.parametrize("text, value", [
    ("1e3", 1000.0), ("1.0e3", 1000.0), ("1E3", 1000.0), ("2.5e-1", 0.25), ("+1.5", 1.5), (".5", 0.5),
    ("-.5", -0.5), ("1.", 1.0), ("1e+3", 1000.0),
    # YAML 1.1 forms read as before
    ("1.0e+3", 1000.0), ("1_000.5", 1000.5), ("7", 7),
])
def test_yaml_12_floats_are_numbers(text, value):
    """PyYAML resolves by YAML 1.1, where `1e3` and `1.0e3` are text; the scene loader reads YAML 1.2's floats
    as numbers: they reach the body's mass (and its inertia) as the number written."""
    spec = parse_scene(f"bodies: [{{name: a, shape: sphere, radius: 0.5, mass: 2, "
                       f"angular_velocity: [{text}, 0, 0]}}]").bodies[0]
    assert spec.angular_velocity[0] == value
    data = yaml.load(f"v: {text}", Loader=scene._SceneLoader)["v"]
    assert type(data) is type(value) and data == value


def test_masses_and_vectors_written_with_exponents():
    """The issue's cases: `mass: 1e3`, `mass: 1.0e3` and `-2E-4` are the numbers they say (the mass reaches
    the inertia: a solid sphere's 2/5 m r²)."""
    bodies = parse_scene("bodies: [{name: a, shape: sphere, radius: 0.5, mass: 1e3},\n"
                         "         {name: b, shape: sphere, radius: 0.5, mass: 1.0e3}]\n"
                         "world: {gravity: [0, -2E-4, -9.81e0]}").bodies
    for body in bodies:
        assert body.mass == 1000.0 and body.inertia_body[0, 0] == pytest.approx(0.4 * 1000.0 * 0.25)
    assert list(parse_scene("world: {gravity: [0, -2E-4, -9.81e0]}").world.gravity) == [0.0, -2e-4, -9.81]


@pytest.mark.parametrize("text", ["'1e3'", '"1.0e3"', "1e", "e3", "1.2.3", "1e3.5", "0x1p3", "1e3e3", "inf",
                                  "nan", "1 e3", "1_e3"])
def test_what_yaml_12_does_not_call_a_float_stays_text(text):
    """Quoted scalars and anything outside YAML 1.2's float grammar stay strings (and a number key rejects
    them, naming what was written)."""
    data = yaml.load(f"v: {text}", Loader=scene._SceneLoader)["v"]
    assert isinstance(data, str)
    message = str(scene_error(f"bodies: [{{name: a, shape: sphere, radius: 0.5, mass: {text}}}]"))
    assert "bodies[0] (a).mass: must be a number, got a string" in message
    quoted = text[0] in "'\""
    assert ("a number in quotes is text in YAML" in message) == quoted, message


@pytest.mark.parametrize("text", [".inf", "-.inf", "+.inf", ".Inf", ".INF", ".nan", ".NaN", ".NAN"])
def test_yaml_infinities_and_nans_are_still_read_as_floats_and_refused(text):
    data = yaml.load(f"v: {text}", Loader=scene._SceneLoader)["v"]
    assert isinstance(data, float) and not math.isfinite(data)
    assert "bodies[0] (a).mass: must be finite" in str(
        scene_error(f"bodies: [{{name: a, shape: sphere, radius: 0.5, mass: {text}}}]"))


def test_the_yaml_12_floats_do_not_change_pyyaml_itself():
    """The resolver is the scene loader's own: yaml.SafeLoader (used by other code in the process) is as
    before, and the scene loader still rejects duplicate keys and Python tags."""
    assert yaml.safe_load("v: 1e3")["v"] == "1e3"
    assert "duplicate key (first given" in str(scene_error("bodies: [{name: a, shape: sphere, radius: 1, mass: 1e3, "
                                                     "mass: 2e3}]"))
    assert "could not determine a constructor" in str(scene_error("mass: !!python/object/apply:os.getcwd []"))


def test_scene_files_that_cannot_be_read(tmp_path):
    missing = tmp_path / "missing.yaml"
    with pytest.raises(SceneError, match="no such scene file"):
        load_scene(str(missing))
    with pytest.raises(SceneError, match="is a directory, not a scene file"):
        load_scene(str(tmp_path) + "/")
    latin1 = tmp_path / "latin1.yaml"
    latin1.write_bytes("description: caf\xe9\n".encode("latin-1"))
    with pytest.raises(SceneError, match="not UTF-8 text"):
        load_scene(str(latin1))
    huge = tmp_path / "huge.yaml"
    with open(huge, "wb") as f:  # sparse: no 16 MB actually written
        f.truncate(MAX_SCENE_BYTES + 1)
    with pytest.raises(SceneError, match=f"scenes are limited to {MAX_SCENE_BYTES}"):
        load_scene(str(huge))


@pytest.mark.parametrize("name", ["defualt", "Default", "zero-g", "boxes"])
def test_an_unknown_builtin_scene_name_lists_the_valid_ones(name):
    with pytest.raises(SceneError) as info:
        load_scene(name)
    valid = builtin_scene_names()
    assert {"default", "zero_g"} <= set(valid)
    assert f"{name}: no built-in scene of that name; built-in scenes: {', '.join(valid)}" in str(info.value)


# ---- security ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("tag", ["!!python/object/apply:os.system", "!!python/object/new:os.system",
                                 "!!python/name:os.system", "!!python/module:os"])
def test_python_tags_are_errors_never_executed(tmp_path, tag):
    marker = tmp_path / "executed"
    command = f"touch {marker}"
    argument = f"[{command!r}]" if "object" in tag else "''"
    for text in (f"bodies: {tag} {argument}\n", f"description: {tag} {argument}\n"):
        error = scene_error(text, "evil.yaml")
        assert "malformed YAML" in str(error) and "could not determine a constructor for the tag" in str(error)
    assert not marker.exists()


def _package_sources() -> list[Path]:
    out = []
    for package in ("cgp_core", "cgp_sim_ros", "msgs_config", "tools", "scripts"):
        out += [p for p in (REPO / package).rglob("*") if p.suffix == ".py" or p.parent.name == "scripts"
                and p.is_file() and not p.suffix]
    return sorted(p for p in out if "__pycache__" not in p.parts and p.is_file())


def test_no_eval_exec_pickle_or_unsafe_yaml_in_the_sources():
    """A guard on top of the behavioural tests: no code path can turn input into code.  Parsed, not grepped,
    so comments and strings do not count and aliases (`from pickle import loads`) do."""
    banned_calls = {"eval", "exec", "compile", "__import__", "execfile"}
    banned_modules = {"pickle", "cPickle", "_pickle", "dill", "cloudpickle", "marshal", "shelve", "jsonpickle"}
    # The one exception, by file: the node and its own spawn worker process (issue 38) hand each other jobs and
    # results as pickles over a private pipe — what the node itself made, and what its own code made in the
    # worker; no file, request or message is ever unpickled (a request's YAML and mesh files are parsed in the
    # worker by the safe parsers above, and only their result travels back).
    pickle_allowed = {Path("cgp_sim_ros/workers.py")}
    banned_yaml = {"unsafe_load", "full_load", "unsafe_load_all", "full_load_all", "load_all", "UnsafeLoader",
                   "FullLoader", "Loader"}
    findings = []
    sources = _package_sources()
    assert any(p.parent.name == "scene" and p.name == "loading.py" for p in sources)
    assert any(p.name == "node.py" for p in sources)
    for path in sources:
        tree = ast.parse(path.read_text(), str(path))
        where = lambda node: f"{path.relative_to(REPO)}:{node.lineno}"  # noqa: E731
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in banned_calls:
                findings.append(f"{where(node)}: {node.func.id}()")
            if isinstance(node, ast.Import) and not (path.relative_to(REPO) in pickle_allowed
                                                     and [a.name for a in node.names] == ["pickle"]):
                findings += [f"{where(node)}: import {a.name}" for a in node.names
                             if a.name.split(".")[0] in banned_modules]
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in banned_modules:
                findings.append(f"{where(node)}: from {node.module} import ...")
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "yaml":
                if node.attr in banned_yaml:
                    findings.append(f"{where(node)}: yaml.{node.attr}")
                if node.attr == "load":  # allowed only with a SafeLoader subclass, checked below
                    call = next((c for c in ast.walk(tree) if isinstance(c, ast.Call) and c.func is node), None)
                    loader = next((k.value for k in call.keywords if k.arg == "Loader"), None) if call else None
                    if not isinstance(loader, ast.Name):
                        findings.append(f"{where(node)}: yaml.load without a named Loader")
                    else:
                        loaders = {n.name: n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)}
                        bases = [ast.unparse(b) for b in loaders[loader.id].bases] if loader.id in loaders else []
                        # cgp_core.user_input's _BaseLoader: yaml.CSafeLoader (libyaml) or yaml.SafeLoader
                        if bases not in (["yaml.SafeLoader"], ["_BaseLoader"]):
                            findings.append(f"{where(node)}: yaml.load(Loader={loader.id}) is not a SafeLoader")
    assert not findings, "\n".join(findings)
    # and the loader the scene parser uses really is a SafeLoader (what the AST check above relies on)
    from cgp_core import scene

    assert issubclass(scene._SceneLoader, yaml.constructor.SafeConstructor)
    assert not issubclass(scene._SceneLoader, (yaml.constructor.FullConstructor, yaml.constructor.UnsafeConstructor))
    assert scene._SceneLoader.__mro__[1] in (yaml.SafeLoader, getattr(yaml, "CSafeLoader", yaml.SafeLoader))


# ---- through the node -----------------------------------------------------------------------------------


def test_cgp_sim_refuses_bad_scenes_before_it_starts(start_node, probe, tmp_path):
    """Through the installed `cgp-sim`: exit 2, the error on stderr with file, key and reason, nothing
    published (no node of these ever publishes ~/bodies/poses).  All started at once."""
    marker = tmp_path / "executed"
    files = {
        "malformed.yaml": "bodies: [\n  {name: a, shape: sphere\n",
        "several.yaml": "bodies:\n  - {name: rod, shape: particles, particles: [[0, 0, 0, 1], [1, 0, 0, 1]]}\n"
                        "  - {name: rod, shape: sphere, radius: 0.2, mass: 0}\n"
                        "flocks:\n  - {name: fish, count: 0}\n",
        "evil.yaml": f"description: !!python/object/apply:os.system ['touch {marker}']\n",
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    cases = [
        (str(tmp_path / "malformed.yaml"), ["malformed.yaml: malformed YAML: line 3, column 1"]),
        (str(tmp_path / "several.yaml"), ["several.yaml: bodies[0] (rod).particles: singular inertia tensor",
                                          "several.yaml: bodies[1].name: duplicate name 'rod'",
                                          "several.yaml: bodies[1] (rod).mass: must be > 0",
                                          "several.yaml: flocks[0] (fish).count: must be >= 1"]),
        (str(tmp_path / "evil.yaml"), ["evil.yaml: malformed YAML", "could not determine a constructor"]),
        (str(tmp_path / "missing.yaml"), ["missing.yaml: no such scene file"]),
        ("zero-g", ["zero-g: no built-in scene of that name; built-in scenes: "
                    + ", ".join(builtin_scene_names())]),
    ]
    poses = probe.subscribe("/cgp_sim/bodies/poses", PoseArray)
    nodes = [start_node("--scene", scene) for scene, _ in cases]
    ros_args_node = start_node("--ros-args", "-p", f"scene:={tmp_path / 'several.yaml'}")
    for node, (scene_text, says) in zip(nodes + [ros_args_node], cases + [cases[1]]):
        assert node.wait(30) == 2, (scene_text, node.log())
        log = node.log()
        assert log.startswith("cgp-sim: scene: "), log
        assert all(s in log for s in says), (says, log)
        assert "Traceback" not in log and "[INFO]" not in log, log
    probe.spin_for(0.2)
    assert not poses.messages
    assert not marker.exists()


def test_a_bad_scene_on_the_command_line_is_refused_before_the_kernels_compile(start_node, tmp_path):
    """Right after an install or an edit nothing is cached and `cgp-sim` compiles its kernels first (half a minute
    and more on 2 cores): a scene named on the command line that does not load is refused before that, as
    `--scene` and as `--ros-args -p [node:]scene:=...` (an empty numba cache stands for the fresh install)."""
    cache = tmp_path / "empty_numba_cache"
    cache.mkdir()
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    cases = [(("--scene", str(tmp_path / "typo.yaml")), "typo.yaml: no such scene file"),
             (("--ros-args", "-p", "scene:=zero-g"), "zero-g: no built-in scene of that name"),
             (("--ros-args", "-p", "cgp_sim:scene:=zero-g"), "zero-g: no built-in scene of that name")]
    nodes = [start_node(*args, env=env) for args, _ in cases]
    for node, (args, says) in zip(nodes, cases):
        assert node.wait(60) == 2, (args, node.log())
        log = node.log()
        assert log.startswith("cgp-sim: scene: ") and says in log, (args, log)
        assert "compiling the simulation kernels" not in log, (args, log)


def test_a_scene_on_the_command_line_is_loaded_once(tmp_path):
    """`cgp-sim` loads a scene named on its command line before the kernels' compile (above) and hands what it
    loaded to the node: a scene file is read and built once, not again in the node (a big mesh's BVH would be
    built twice)."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import sys
        import cgp_core.scene, cgp_core.world
        from cgp_sim_ros.ros import cli
        loads = []
        original = cgp_core.scene.load_scene
        def counted(source, *args, **kwargs):
            loads.append(str(source))
            return original(source, *args, **kwargs)
        cgp_core.scene.load_scene = cgp_core.world.load_scene = counted
        status = cli.main(["cgp-sim", *sys.argv[1:], "--duration", "0.05", "--realtime", "false"])
        print("LOADS", status, loads)
    """)
    path = tmp_path / "two_boxes.yaml"
    path.write_text("bodies:\n  - {name: a, shape: box, size: [1, 1, 1], mass: 1, position: [0, 0, 1]}\n"
                    "  - {name: b, shape: box, size: [1, 1, 1], mass: 1, position: [0, 0, 3]}\n")
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")  # (what is counted here is the loads, not the kernels)
    out = subprocess.run([sys.executable, "-c", code, "--scene", str(path)], capture_output=True, text=True,
                         timeout=120, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    assert f"LOADS 0 [{str(path)!r}]" in out.stdout, out.stdout[-2000:] + out.stderr[-2000:]
