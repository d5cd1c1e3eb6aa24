"""cgp_core: the ROS-free physics core of cgp_sim."""
