"""Work-precision benchmark script: see det_sim_ros/analysis/benchmark.py (also `det_sim bench`)."""

import sys

from det_sim_ros.analysis.benchmark import main

if __name__ == '__main__':
    sys.exit(main())
