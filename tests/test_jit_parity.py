"""The compiled kernels (cgp_core.jit) and the very same functions run as plain Python (NUMBA_DISABLE_JIT=1) give
the same results, bit for bit: the default scene's bodies, placed so that in a few ticks every contact kernel
runs (ground under a sphere, a box, a capsule and a particle body; box–box against the pillar; box–capsule;
sphere–sphere between the ball and the particle body), stepped in two processes, one compiled, one not.

Bit-identical is possible because the kernels use only IEEE-exact operations in a fixed order (+ − × ÷, sqrt,
comparisons; sin/cos/atan2 from the same C library), no fastmath (so no reassociation or fused multiply-add),
and no LAPACK call (the manifold pseudo-inverse is our own Jacobi loop).
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

SCRIPT = r"""
import sys
import numpy as np
from cgp_core import World
from cgp_core.jit import JIT_DISABLED

assert JIT_DISABLED == (sys.argv[2] == "plain"), "NUMBA_DISABLE_JIT did not reach the child"
w = World.from_scene("default")
w.flocks = []
s, names = w.body_state, w.body_model.names
place = {"ball": (1.6, 1.4, 0.32), "crate": (5.15, 0.0, 0.28), "capsule": (5.0, 0.0, 0.78),
         "tetromino": (1.8, 2.0, 0.18)}
for name, xyz in place.items():
    s.position[names.index(name)] = xyz
s.linear_momentum[names.index("ball")] = (0.6, 1.0, -2.0)
w.sleep_enabled = False
out = []
for _ in range(int(sys.argv[3])):
    w.step()
    out.append(np.concatenate((s.position, s.orientation, s.linear_momentum, s.angular_momentum), axis=1))
np.save(sys.argv[1], np.array(out))
print(w.solver.stats)
"""


#: the end of the robot scripts below: step ``w`` argv[3] ticks, each tick's position, orientation and momenta of every
#: body saved to argv[1]
RECORD_BODIES = r"""
s = w.body_state
out = []
for _ in range(int(sys.argv[3])):
    w.step()
    out.append(np.concatenate((s.position, s.orientation, s.linear_momentum, s.angular_momentum), axis=1).ravel())
np.save(sys.argv[1], np.array(out))
"""

#: issue 35's one loop: an arm turning into a crate that the ground's friction holds back (the robot's rows and the
#: body rows solved together from the 21st tick on: cgp_core.robots.coupled)
ROBOT_SCRIPT = r"""
import sys
import numpy as np
from cgp_core import World
from cgp_core.jit import JIT_DISABLED
from cgp_core.scene import scene_from_dict

assert JIT_DISABLED == (sys.argv[2] == "plain"), "NUMBA_DISABLE_JIT did not reach the child"
crate = {"name": "crate", "shape": "box", "size": [0.1, 0.1, 0.3], "mass": 0.3, "friction": 0.4,
         "position": [0.48 * np.cos(0.35), 0.48 * np.sin(0.35), 0.15]}
arm = {"name": "arm", "urdf": "arm.urdf", "joints": {"shoulder_lift": 1.2, "elbow": 1.3, "wrist": -0.3}}
w = World(scene_from_dict({"world": {"substeps": 4}, "robots": [arm], "bodies": [crate]}, "<parity>"))
w.robots.command("arm", ["shoulder_pan"], velocity=[1.0])
""" + RECORD_BODIES

#: issue 35's one position loop (cgp_core.robots.coupled.relax_together): two crates started 1 cm deep in the held
#: upper arm, under a fixed shelf, no gravity (tests/test_robot_world.py's squeeze): the crate–crate and crate–shelf
#: rows are corrected in the robot's position loop, from the first tick
SQUEEZE_SCRIPT = r"""
import sys
import numpy as np
from cgp_core import World
from cgp_core.jit import JIT_DISABLED
from cgp_core.scene import scene_from_dict

assert JIT_DISABLED == (sys.argv[2] == "plain"), "NUMBA_DISABLE_JIT did not reach the child"
z = 0.2 + 0.025 - 0.01
bodies = []
for i in range(2):
    bodies.append({"name": f"crate{i}", "shape": "box", "size": [0.06, 0.06, 0.06], "mass": 0.4,
                   "position": [0.25, 0.0, z + 0.03]})
    z += 0.06
bodies.append({"name": "shelf", "shape": "box", "size": [0.2, 0.2, 0.02], "fixed": True, "mass": 1.0,
               "position": [0.25, 0.0, z + 0.01]})
arm = {"name": "arm", "urdf": "arm.urdf", "hold": True,
       "joints": {"shoulder_lift": float(np.pi / 2), "elbow": float(-np.pi / 2), "wrist": 0.0}}
w = World(scene_from_dict({"world": {"gravity": [0, 0, 0], "ground": False, "substeps": 4}, "robots": [arm],
                           "bodies": bodies}, "<parity>"))
""" + RECORD_BODIES


def run(tmp_path, mode: str, ticks: int, script: str = SCRIPT) -> np.ndarray:
    env = os.environ.copy()
    env.pop("NUMBA_DISABLE_JIT", None)
    if mode == "plain":
        env["NUMBA_DISABLE_JIT"] = "1"
    path = tmp_path / f"{mode}.npy"
    done = subprocess.run([sys.executable, "-c", script, str(path), mode, str(ticks)], env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return np.load(path)


def test_compiled_and_plain_python_kernels_give_the_same_bits(tmp_path):
    ticks = 24
    compiled = run(tmp_path, "compiled", ticks)
    plain = run(tmp_path, "plain", ticks)
    assert compiled.shape == plain.shape == (ticks, 5, 13)  # position, orientation, P, L of 5 bodies
    # the bodies did collide: in free fall for 0.4 s they would have dropped 0.8 m, through the ground
    assert compiled[-1, :4, 2].min() > 0.1
    np.testing.assert_array_equal(compiled, plain)


def test_the_one_loop_of_robot_and_body_rows_gives_the_same_bits_compiled_and_plain(tmp_path):
    ticks = 40
    compiled = run(tmp_path, "compiled", ticks, ROBOT_SCRIPT)
    plain = run(tmp_path, "plain", ticks, ROBOT_SCRIPT)
    crate = compiled[:, 0:13]  # the crate is the scene's first body
    assert np.linalg.norm(crate[-1, :2] - crate[0, :2]) > 0.01  # the arm reached it and pushed it
    np.testing.assert_array_equal(compiled, plain)


def test_the_one_position_loop_gives_the_same_bits_compiled_and_plain(tmp_path):
    ticks = 8
    compiled = run(tmp_path, "compiled", ticks, SQUEEZE_SCRIPT)
    plain = run(tmp_path, "plain", ticks, SQUEEZE_SCRIPT)
    lower, upper = compiled[:, 2], compiled[:, 13 + 2]  # the crates' heights
    # the loop moved both crates (measured: the lower one up by 1.9 mm by the 4th tick, the upper one by 0.2 mm)
    assert np.abs(lower - lower[0]).max() > 1e-3 and upper[-1] - upper[0] > 1e-4
    np.testing.assert_array_equal(compiled, plain)
