"""cgp_core: the ROS-free physics core of cgp_sim (numpy, scipy; never ROS).

Public API: :class:`World` (load a scene, step, read state, apply a force at a point), the scene loader
(:func:`load_scene`, :func:`parse_scene`, :class:`SceneError`), the state containers (:class:`BodyModel`,
:class:`BodyState`, :class:`Shape`), the flocks (:class:`Flock`, :class:`FlockParams`) and what editing a running
world returns or raises (:class:`EntityState`, :class:`EditError`).
"""

from .bodies import BodyModel, BodyState, Shape
from .boids import Flock, FlockParams
from .editing import EditError, EntityState
from .scene import Scene, SceneError, builtin_scene_names, load_scene, parse_scene
from .world import World, WorldEvent
from .wrenches import WrenchError

__all__ = [
    "BodyModel", "BodyState", "EditError", "EntityState", "Flock", "FlockParams", "Scene", "SceneError", "Shape",
    "World", "WorldEvent",
    "WrenchError", "builtin_scene_names", "load_scene", "parse_scene",
]
