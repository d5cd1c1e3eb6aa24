"""cgp_sim_ros: the ROS 2 node over cgp_core, and the ROS-free parts it is built from.

Only :mod:`cgp_sim_ros.ros` imports rclpy or ROS messages (tested: ``tests/test_architecture.py``); everything
else here runs where ROS is not installed:

- :mod:`cgp_sim_ros.interface`: the node's interface as data (topic, service and parameter names, defaults,
  limits);
- :mod:`cgp_sim_ros.wire`: the bytes — CDR writer and reader, rosbag2's schemas, the MCAP bag writer;
- :mod:`cgp_sim_ros.drawing`: what the markers show — the fish, and the level of detail of big flocks;
- :mod:`cgp_sim_ros.render`: ``cgp-sim-render``, a bag's markers to pictures;
- :mod:`cgp_sim_ros.progress` (the progress line) and :mod:`cgp_sim_ros.warmup` (the kernel compilation
  ``make setup`` runs);
- :mod:`cgp_sim_ros.ros`: the rclpy side — ``SimNode`` and its collaborators, ``cgp-sim``.
"""
