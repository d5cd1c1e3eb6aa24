"""The bytes, without ROS: what a message is on the wire and in a bag.

:mod:`.cdr` (numpy-built CDR of the messages the node publishes, and the MarkerArray reader of the renderer),
:mod:`.schemas` (what rosbag2 stores about a type and a topic: definitions, type hashes, QoS YAML),
:mod:`.bag` (the rosbag2-style MCAP bag writer: its own thread, crash-safe).  Nothing here imports rclpy or a
message package; the definitions are read from the installed ``.msg`` files.
"""
