"""``cgp-sim-render``: a bag's markers to pictures (PNG, GIF, MP4), without ROS and without a display.

Modules: :mod:`.bagread` (the marker topic of an MCAP bag, read with the ``mcap`` library),
:mod:`.primitives` (markers on display → world-frame triangles and spheres), :mod:`.raster` (camera and the
z-buffer rasterizer), :mod:`.cli` (the command, the output writers).  Nothing here imports rclpy: the
messages are decoded by :func:`cgp_sim_ros.wire.cdr.read_marker_array`.
"""
