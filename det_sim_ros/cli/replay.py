"""
``det_sim_replay``: the ``replay`` verb of ``det_sim`` as a command of its own.

It runs as the console script and as ``python -m det_sim_ros.cli.replay``.
"""

import sys

from .det_sim import main_replay as main

__all__ = ['main']

if __name__ == '__main__':
    sys.exit(main())
