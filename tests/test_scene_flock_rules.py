"""Issue 14's scene keys (rules, couzin, neighbors, fright_radius, predator): every bad value is reported with
the file, the key path and the reason, all problems of a file at once; good values reach FlockParams; the
built-in scenes of the issue load and say what they are."""

from __future__ import annotations

import pytest
import yaml

from cgp_core.boids import Flock
from cgp_core.scene import SceneError, builtin_scene_dir, load_scene, parse_scene

COUZIN = "{name: s, count: 10, rules: couzin, bounds: {mode: none}"

BAD = {
    "unknown rules": ("flocks: [{name: s, count: 10, rules: boids}]", "flocks[0] (s).rules",
                      "must be one of reynolds, couzin, got 'boids'"),
    "couzin block on a reynolds flock": ("flocks: [{name: s, count: 10, couzin: {speed: 2}}]",
                                         "flocks[0] (s).couzin", "only applies to rules: couzin"),
    "reynolds key on a couzin flock": (f"flocks: [{COUZIN}, weights: {{cohesion: 1}}}}]", "flocks[0] (s).weights",
                                       "does not apply to rules: couzin"),
    "radius on a couzin flock": (f"flocks: [{COUZIN}, radius: 3}}]", "flocks[0] (s).radius",
                                 "does not apply to rules: couzin"),
    "unknown couzin key": (f"flocks: [{COUZIN}, couzin: {{repulsion: 1}}}}]", "flocks[0] (s).couzin.repulsion",
                           "unknown key (valid: attraction_width, field_of_view_deg, noise, orientation_width, "
                           "repulsion_radius, speed, turning_rate_deg)"),
    "negative zone": (f"flocks: [{COUZIN}, couzin: {{orientation_width: -1}}}}]",
                      "flocks[0] (s).couzin.orientation_width", "must be >= 0, got -1"),
    "zero speed": (f"flocks: [{COUZIN}, couzin: {{speed: 0}}}}]", "flocks[0] (s).couzin.speed", "must be > 0, got 0"),
    "turning rate as text": (f"flocks: [{COUZIN}, couzin: {{turning_rate_deg: fast}}}}]",
                             "flocks[0] (s).couzin.turning_rate_deg", "must be a number, got a string 'fast'"),
    "field of view over 360": (f"flocks: [{COUZIN}, couzin: {{field_of_view_deg: 400}}}}]",
                               "flocks[0] (s).couzin.field_of_view_deg", "must be in [0, 360] degrees"),
    "no zones at all": (f"flocks: [{COUZIN}, couzin: {{repulsion_radius: 0, orientation_width: 0, "
                        "attraction_width: 0}}]", "flocks[0] (s).couzin",
                        "repulsion_radius + orientation_width + attraction_width must be > 0"),
    "negative noise": (f"flocks: [{COUZIN}, couzin: {{noise: -0.1}}}}]", "flocks[0] (s).couzin.noise",
                       "must be >= 0, got -0.1"),
    "couzin not a mapping": (f"flocks: [{COUZIN}, couzin: [1, 2]}}]", "flocks[0] (s).couzin",
                             "must be a mapping, got a list"),
    "unknown neighbour mode": ("flocks: [{name: s, count: 10, neighbors: {mode: nearest}}]",
                               "flocks[0] (s).neighbors.mode", "must be one of metric, topological, got 'nearest'"),
    "k zero": ("flocks: [{name: s, count: 10, neighbors: {mode: topological, k: 0}}]", "flocks[0] (s).neighbors.k",
               "must be >= 1, got 0"),
    "k not an integer": ("flocks: [{name: s, count: 10, neighbors: {mode: topological, k: 6.5}}]",
                         "flocks[0] (s).neighbors.k", "must be an integer, got float 6.5"),
    "unknown neighbors key": ("flocks: [{name: s, count: 10, neighbors: {mode: metric, radius: 3}}]",
                              "flocks[0] (s).neighbors.radius", "unknown key (valid: k, mode)"),
    "topological in a periodic box": ("flocks: [{name: s, count: 10, neighbors: {mode: topological}, "
                                      "bounds: {mode: wrap}}]", "flocks[0] (s)",
                                      "neighbor_mode 'topological' does not support bounds_mode 'wrap'"),
    "negative fright radius": ("flocks: [{name: s, count: 10, fright_radius: -2}]", "flocks[0] (s).fright_radius",
                               "must be >= 0, got -2"),
    "predator not a boolean": ("bodies: [{name: shark, shape: sphere, radius: 1, predator: 1}]",
                               "bodies[0] (shark).predator", "must be true or false, got int 1"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_values_name_file_key_and_reason(case):
    text, key, reason = BAD[case]
    with pytest.raises(SceneError) as error:
        parse_scene(text, "bad.yaml")
    expected = f"bad.yaml: {key}: {reason}"
    assert any(line.startswith(expected) for line in str(error.value).splitlines()), str(error.value)


def test_every_problem_of_a_file_is_reported_at_once():
    text = (f"flocks: [{COUZIN}, couzin: {{speed: 0, noise: -1}}, min_speed: 1}}, "
            "{name: t, count: 5, neighbors: {mode: topo}}]")
    with pytest.raises(SceneError) as error:
        parse_scene(text, "many.yaml")
    assert error.value.problems == [
        "flocks[0] (s).min_speed: does not apply to rules: couzin (its zones, speed and field of perception are set "
        "in the couzin block)",
        "flocks[0] (s).couzin.speed: must be > 0, got 0",
        "flocks[0] (s).couzin.noise: must be >= 0, got -1",
        "flocks[1] (t).neighbors.mode: must be one of metric, topological, got 'topo'",
    ]


def test_good_values_reach_the_flock():
    scene = parse_scene("""
bodies: [{name: shark, shape: sphere, radius: 1, predator: true}, {name: rock, shape: sphere, radius: 1}]
flocks:
  - name: school
    count: 100
    rules: couzin
    couzin: {repulsion_radius: 1.0, orientation_width: 2.0, attraction_width: 14.0, field_of_view_deg: 270.0,
             turning_rate_deg: 40.0, speed: 3.0, noise: 0.05}
    spawn: {center: [0, 0, 20], extent: [10, 10, 10]}
    bounds: {mode: none}
    neighbors: {mode: topological, k: 7}
    fright_radius: 6.0
  - {name: birds, count: 20, neighbors: {mode: metric, k: 7}}
""")
    school, birds = scene.flocks
    assert school.rules == "couzin" and school.couzin.orientation_width == 2.0 and school.couzin.speed == 3.0
    assert school.radius == 17.0 and school.min_speed == school.max_speed == 3.0  # from the zones and s
    assert school.neighbor_mode == "topological" and school.neighbor_k == 7 and school.fright_radius == 6.0
    assert birds.rules == "reynolds" and birds.neighbor_mode == "metric"
    assert [b.predator for b in scene.bodies] == [True, False]


@pytest.mark.parametrize("name", ["couzin_torus", "predator"])
def test_the_issue_scenes_load_and_describe_themselves(name):
    scene = load_scene(name)
    raw = yaml.safe_load((builtin_scene_dir() / f"{name}.yaml").read_text())
    assert len(raw["description"]) > 80
    assert scene.flocks[0].rules == "couzin"
    Flock(scene.flocks[0]).step(1 / 60)
