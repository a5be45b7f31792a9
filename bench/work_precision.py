"""
Work-precision benchmark script: ``det_sim bench``, with the same options.

The verb is det_sim_ros/cli/verbs/bench.py, the measurements det_sim_ros/analysis/benchmark.py.
"""

import sys

from det_sim_ros.cli import main

if __name__ == '__main__':
    sys.exit(main(['bench', *sys.argv[1:]]))
