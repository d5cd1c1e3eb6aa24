"""``cgp-sim-sweep``: many headless simulations from one sweep file, on Dask, into Parquet tables.

A *sweep file* (YAML, read as scenes are: :func:`cgp_core.scene.parse_yaml`) names a base scene, a grid of
overrides by key path into it, seeds, a duration, what to record and optional *chains* (runs that start from
the previous run's final state).  Every run steps exactly what the node steps (:class:`cgp_core.world.World`),
headless, with no ROS graph.  The modules:

- :mod:`.spec`    the sweep file: validation (errors name the file, the key and the reason), key paths,
                  the plan (every run resolved into a scene dict), run identities, the code version;
- :mod:`.runner`  what a worker runs: one task (a run, or a chain of runs) → measured tables;
- :mod:`.store`   the output directory: one Parquet fragment per run (atomic rename), the combined tables;
- :mod:`.engine`  Dask: a LocalCluster or ``--scheduler``, the workers' version check, retries, progress,
                  Ctrl-C;
- :mod:`.plot`    the standard figures from the tables (matplotlib, an optional dependency);
- :mod:`.cli`     the command.

Nothing here imports rclpy or a ROS message package: the runs execute on Dask workers that may have no ROS
(``tests/test_sweep.py`` imports it where rclpy cannot be imported).
"""

from .spec import Sweep, SweepError, load_sweep  # noqa: F401
