"""``python -m det_sim_ros.cli``: the ``det_sim`` command."""

import sys

from . import main

sys.exit(main())
