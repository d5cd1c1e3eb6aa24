"""cgp_sim_ros: the rclpy node over cgp_core."""
