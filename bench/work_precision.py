"""Work-precision benchmark script: ``det_sim bench`` (det_sim_ros/cli/verbs/bench.py, the
measurements in det_sim_ros/analysis/benchmark.py), with the same options."""

import sys

from det_sim_ros.cli import main

if __name__ == '__main__':
    sys.exit(main(['bench', *sys.argv[1:]]))
