"""
Studies on top of the simulator.

The elastica, fidelity against it, the paper's scenarios and the benchmarks behind
``det_sim bench``.
"""
