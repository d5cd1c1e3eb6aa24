"""cgp_sim: the ROS 2 package `cgp_sim_ros` (ament_python) with its ROS-free core `cgp_core` and the
scenes / parameter files of `msgs_config`.

Installs, with pip or colcon alike:
- the Python packages `cgp_core`, `cgp_sim_ros` (with its subpackages: `ros` — the only one that needs rclpy —,
  `wire`, `drawing`, `render`, `sweep`), `msgs_config` (scenes, sweeps and parameter files as package data);
- the console scripts `cgp-sim` (the node), `cgp-sim-render` (bags to pictures, no ROS needed) and
  `cgp-sim-sweep` (many headless runs on Dask, results as Parquet tables; no ROS needed);
- the ament layout `ros2 run cgp_sim_ros sim_node` resolves:
  share/ament_index/resource_index/packages/cgp_sim_ros, share/cgp_sim_ros/package.xml,
  lib/cgp_sim_ros/sim_node (a data file, since pip ignores setup.cfg's install_scripts).
The interface package `cgp_sim_msgs` (msgs_config/cgp_sim_msgs) is a separate ament_cmake package, built by
colcon in a workspace or by `tools/build_msgs.py` into the venv (`make setup`).
"""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "cgp_sim_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Rigid bodies and boid flocks of the CGP lecture, live on ROS 2 and recorded to MCAP",
    long_description=open("README.md", encoding="utf-8").read(),
    long_description_content_type="text/markdown",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(include=["cgp_core", "cgp_core.*", "cgp_sim_ros", "cgp_sim_ros.*", "msgs_config"]),
    package_data={"msgs_config": ["scenes/*.yaml", "params/*.yaml", "sweeps/*.yaml", "foxglove/*.json",
                                  "meshes/*.stl", "meshes/*.obj", "robots/*.urdf"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/scenes", sorted(glob("msgs_config/scenes/*.yaml"))),
        (f"share/{PACKAGE}/params", sorted(glob("msgs_config/params/*.yaml"))),
        (f"share/{PACKAGE}/sweeps", sorted(glob("msgs_config/sweeps/*.yaml"))),
        (f"share/{PACKAGE}/foxglove", sorted(glob("msgs_config/foxglove/*.json"))),
        (f"share/{PACKAGE}/meshes", sorted(glob("msgs_config/meshes/*.stl") + glob("msgs_config/meshes/*.obj"))),
        (f"share/{PACKAGE}/robots", sorted(glob("msgs_config/robots/*.urdf"))),
        (f"lib/{PACKAGE}", ["scripts/sim_node"]),
    ],
    # ROS packages (rclpy, *_msgs) are not listed: they come from apt on a ROS install and from
    # requirements/ros.txt (PyPI wheels) in the venv; package.xml declares them for rosdep.
    # tbb: numba's work-stealing thread pool (cgp_core/jit.py); without it numba falls back to OpenMP
    install_requires=["numpy>=1.26", "scipy>=1.11", "numba>=0.60", "tbb>=2021.6", "PyYAML>=6.0", "mcap>=1.2",
                      "google-re2>=1.1", "zstandard>=0.22", "lz4>=4.3", "pillow>=10", "foxglove-sdk>=0.30.3,<0.31",
                      # cgp-sim-sweep: the Dask engine and the Parquet tables (cgp_sim_ros/sweep)
                      "dask[distributed]>=2024.8", "pyarrow>=15",
                      # robots from URDF / xacro (cgp_core/robots)
                      "yourdfpy>=0.0.56", "lxml>=5", "xacro>=2.0"],
    extras_require={
        "test": ["pytest>=8", "pytest-timeout>=2.3", "mcap-ros2-support>=0.5", "rosbags>=0.10", "psutil>=5.9",
                 "websockets>=15", "hypothesis>=6.100", "trimesh>=4.0",
                 "pin>=3", "example-robot-data>=4"],
        "bench": ["pybullet", "mujoco", "pyinstrument", "matplotlib", "python-fcl"],
        # MP4 output of cgp-sim-render (a wheel that ships ffmpeg); PNG and GIF need only Pillow
        "render": ["imageio-ffmpeg>=0.5"],
        # `cgp-sim-sweep plot` (the figures from a sweep's table); running a sweep never needs it
        "plot": ["matplotlib"],
    },
    entry_points={"console_scripts": ["cgp-sim = cgp_sim_ros.ros.cli:entry",
                                      "cgp-sim-render = cgp_sim_ros.render.cli:main",
                                      "cgp-sim-sweep = cgp_sim_ros.sweep.cli:main"]},
    zip_safe=False,
)
