# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
import sys

import numpy as np

sys.path.insert(0, sys.argv[1] + "/tools")
from compare_trees import pile_scene

from cgp_core import World
from cgp_core.scene import parse_scene

w = World(parse_scene(pile_scene()))
for _t in range(300):
    w.step()
s = w.body_state; m = w.body_model
mov = m.inv_mass > 0
v = np.linalg.norm(s.linear_momentum[mov] * m.inv_mass[mov, None], axis=1)
print(sys.argv[1], "mean z %.4f  max |v| %.4f  mean |v| %.5f  max pen %.4f  contacts %d" % (s.position[mov, 2].mean(), v.max(), v.mean(), w.solver.stats["max_penetration"], w.solver.stats["contacts"]))
