"""The compiled kernel (C, det_sim_ros/core/_csrc) and its one facade, :mod:`.kernel`."""
