"""Issue 36 (bad input): property-based fuzzing (Hypothesis) of a robot spawn request's URDF, in-process, through
the node's path (``{robot: {urdf_xml: ...}}`` → :meth:`World.prepare_spawn` → ``add_spawned``).

For any URDF text — a generated tree of links and joints whose numbers are float64's edges and whose types and
tags may be wrong, or arbitrary text with or without a ``<!DOCTYPE``: the spawn is refused with a named error
(SceneError / EditError, never another exception, never the text of an entity), or the robot is added, steps
finitely (or is put back with an event: what the world does with any robot that blows up) and is deleted again.
``make fuzz FUZZ_EXAMPLES=5000`` runs it longer, as tests/test_fuzz_inputs.py."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from cgp_core.editing import EditError
from cgp_core.scene import SceneError
from cgp_core.world import World

FUZZ_EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "0"))
FUZZ = settings(max_examples=FUZZ_EXAMPLES or 40, derandomize=not FUZZ_EXAMPLES, deadline=None if FUZZ_EXAMPLES
                else 20000, suppress_health_check=list(HealthCheck))

NUMBERS = st.one_of(
    st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-308, 5e-324, 1e308, -1e308, math.inf, -math.inf, math.nan, 1e9, 1e10,
                     2.0**63]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-2, 2),
    st.floats(0.01, 2),
)
NUMBER_TEXT = st.one_of(NUMBERS.map(repr), st.sampled_from(["", "x", "1 2", "1e", "0x10", "--1", "١"]))
JOINT_TYPES = st.sampled_from(["revolute", "continuous", "prismatic", "fixed", "floating", "planar", "spinning", ""])
SECRET = "CGP-FUZZ-SECRET"


PLAUSIBLE = st.floats(0.05, 1.0).map(repr)
REAL_JOINTS = st.sampled_from(["revolute", "continuous", "prismatic", "fixed"])


def triple(numbers):
    return st.lists(numbers, min_size=3, max_size=3).map(" ".join)


@st.composite
def urdf(draw, plausible: bool = False) -> str:
    """A URDF's text: 1 to 4 links joined in a tree (or not); ``plausible``: every number a small positive one,
    every joint type a real one and every parent an earlier link (most are accepted), else anything (most are
    refused)."""
    number = PLAUSIBLE if plausible else NUMBER_TEXT
    kinds = REAL_JOINTS if plausible else JOINT_TYPES
    links = draw(st.integers(1, 4))
    parts = ["<robot name='fuzz'>"]
    for i in range(links):
        mass = draw(st.one_of(number, st.floats(0.1, 5).map(repr)))
        moment = draw(st.one_of(number, st.floats(0.001, 1).map(repr)))
        shapes = [f"<box size='{draw(triple(PLAUSIBLE))}'/>", f"<box size='{draw(triple(number))}'/>",
                  f"<sphere radius='{draw(number)}'/>",
                  f"<cylinder radius='{draw(number)}' length='{draw(number)}'/>"]
        if not plausible:
            shapes += ["<mesh filename='/dev/zero'/>", "<cone/>", ""]
        shape = draw(st.sampled_from(shapes))
        inertial = (f"<inertial><origin xyz='{draw(triple(number))}'/><mass value='{mass}'/><inertia "
                    f"ixx='{moment}' iyy='{moment}' izz='{moment}' ixy='{'0' if plausible else draw(number)}' "
                    f"ixz='0' iyz='0'/></inertial>")
        parts.append(f"<link name='l{i}'>{inertial if draw(st.booleans()) or i == 0 or plausible else ''}"
                     f"<collision><geometry>{shape}</geometry></collision></link>")
    for i in range(1, links):
        parents = [f"l{k}" for k in range(i)] + ([] if plausible else [f"l{i}", "nowhere"])
        limit = (f"<limit lower='-{draw(number)}' upper='{draw(number)}' effort='{draw(number)}' "
                 f"velocity='{draw(number)}'/>") if plausible or draw(st.booleans()) else ""
        parts.append(f"<joint name='j{i}' type='{draw(kinds)}'><parent link='{draw(st.sampled_from(parents))}'/>"
                     f"<child link='l{i}'/><origin xyz='{draw(triple(number))}' rpy='{draw(triple(number))}'/>"
                     f"<axis xyz='{draw(triple(number))}'/>{limit}</joint>")
    parts.append("</robot>")
    text = "".join(parts)
    if not plausible and draw(st.booleans()):  # cut it anywhere, or put a DOCTYPE with an entity in front
        text = draw(st.sampled_from([text[:draw(st.integers(0, len(text)))],
                                     f'<!DOCTYPE r [<!ENTITY s "{SECRET}">]>' + text.replace("fuzz", "&s;"),
                                     text]))
    return text


@pytest.fixture(scope="module")
def world():
    return World.from_scene("zero_g")


@FUZZ
@given(st.one_of(urdf(plausible=True), urdf(), st.text(max_size=200).map(lambda t: "<" + t)))
@example("<robot name='r'><link name='a'/></robot>")
@example(f'<!DOCTYPE r [<!ENTITY s "{SECRET}">]><robot name="&s;"><link name="a"/></robot>')
@example("<robot name='r'><link name='a'><inertial><mass value='1'/><inertia ixx='1' iyy='1' izz='1e9'/>"
         "</inertial></link></robot>")
def test_any_urdf_text_is_refused_by_name_or_simulates(world, text):
    name = "fuzzed"
    try:
        prepared = world.prepare_spawn({"robot": {"urdf_xml": text, "fixed_base": True}}, name=name,
                                       taken=set(world.entity_names()), position=(3e4, 3e4, 3e4))
    except (SceneError, EditError) as exc:
        message = str(exc)
        assert "internal error" not in message and SECRET not in message
        assert "robot.urdf_xml" in message or "robot" in message, message
        event("refused")
        return
    event("accepted")
    world.add_spawned(prepared)
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            world.step()
        assert np.isfinite(world.robots.q).all() and np.isfinite(world.robots.qd).all()
        assert np.isfinite(world.body_state.position).all()
        state = world.entity_state(name)
        assert np.isfinite(state.position).all() and np.isfinite(state.orientation).all()
        world.take_events()
    finally:
        world.delete(name)
    assert world.robots is None
