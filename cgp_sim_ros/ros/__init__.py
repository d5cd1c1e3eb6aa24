"""The rclpy side of cgp_sim_ros: the only subpackage that imports rclpy and ROS messages.

:mod:`.node` (``SimNode``, the timer-driven adapter, and the home of its public surface), its collaborators
:mod:`.parameters`, :mod:`.commands`, :mod:`.publishing`, :mod:`.messages`, :mod:`.tf`, :mod:`.recorder`,
:mod:`.sim_services`, :mod:`.foxglove_server`, :mod:`.process`, :mod:`.pace`; the QoS profiles
(:mod:`.qos`); the ``cgp-sim`` command (:mod:`.cli`).
"""
