"""Robots: a URDF's kinematic tree as a static model (:mod:`.model`), loaded by :mod:`.urdf`, and the compiled
recursive algorithms on it (:mod:`.algorithms`: kinematics, Jacobians, CRBA, RNEA, forward dynamics)."""

from .algorithms import (
    angular_jacobian,
    bias_forces,
    body_velocities,
    forward_dynamics,
    forward_kinematics,
    frame_poses,
    integrate_positions,
    inverse_dynamics,
    mass_matrix,
    motion_subspace,
    point_jacobian,
)
from .model import (
    JOINT_BALL,
    JOINT_FIXED_ROOT,
    JOINT_FLOATING,
    JOINT_PLANAR,
    JOINT_PRISMATIC,
    JOINT_REVOLUTE,
    Geometry,
    RobotArrays,
    RobotModel,
    neutral_positions,
    plane_basis,
    robot_arrays,
)
from .urdf import UrdfError, load_urdf

__all__ = ["JOINT_FIXED_ROOT", "JOINT_FLOATING", "JOINT_REVOLUTE", "JOINT_PRISMATIC", "JOINT_PLANAR", "JOINT_BALL",
           "Geometry",
           "RobotModel", "RobotArrays", "robot_arrays", "neutral_positions", "plane_basis", "UrdfError", "load_urdf",
           "forward_kinematics", "frame_poses", "motion_subspace", "body_velocities", "point_jacobian",
           "angular_jacobian", "mass_matrix", "inverse_dynamics", "bias_forces", "forward_dynamics",
           "integrate_positions"]
