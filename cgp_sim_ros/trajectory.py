"""The node's side of ``~/robots/<robot>/joint_trajectory`` (trajectory_msgs/JointTrajectory): the interpolation
lives in the core (:mod:`cgp_core.robots.trajectory`, joint_trajectory_controller's rules: cubic Hermite between
points with velocities, linear without, the last point held), shared with a scene robot's ``trajectory:`` key;
:mod:`cgp_sim_ros.ros.commands` decodes the message and calls :func:`check_trajectory` and :func:`sample` from
here.  A ROS trajectory or joint command replaces the robot's scene trajectory (``World.stop_trajectory``)."""

from __future__ import annotations

from cgp_core.robots.trajectory import (
    MAX_TRAJECTORY_JOINTS,
    MAX_TRAJECTORY_POINTS,
    Trajectory,
    TrajectoryError,
    check_trajectory,
    sample,
)

__all__ = ["MAX_TRAJECTORY_JOINTS", "MAX_TRAJECTORY_POINTS", "Trajectory", "TrajectoryError", "check_trajectory",
           "sample"]
