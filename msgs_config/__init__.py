"""Configuration shipped with cgp_sim: built-in scenes and parameter files (and, next to them, the sources of
the `cgp_sim_msgs` interface package, built by CMake, not part of this Python package)."""
