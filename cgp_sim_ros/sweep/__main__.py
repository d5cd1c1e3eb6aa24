import sys

from .cli import main

if __name__ == "__main__":  # `python -m cgp_sim_ros.sweep`; importing the module runs nothing
    sys.exit(main())
