"""
Calibration: scene parameters fitted to measured logs (no ROS).

A rig's commanded voltages and measured outputs (sim_node's MCAP log, a rosbag2 MCAP through a
channel mapping, or a CSV file) are replayed through :func:`~det_sim_ros.sim.simulator.simulate`
and the chosen parameters fitted by weighted least squares; the result holds the fitted scene,
each parameter's standard error and 95 % interval, the correlations and the parameters the log
cannot identify. ``det_sim fit`` is its command line; docs/calibration.md describes both.

    measurement   a run on the simulator's grid; CSV files
    logs          MCAP logs: sim_node's own, or a rig's through a mapping
    parameters    the fitted keys, their bounds and scale
    problem       the weighted residual and its sensitivities (serial, threads, processes)
    intervals     standard errors, intervals, identifiability
    fitting       fit(): the multi-start least-squares search
    report        the text report, the scene file and the plot
"""

from .fitting import fit, FitResult
from .measurement import CalibrationError, Measurement

__all__ = ['fit', 'FitResult', 'CalibrationError', 'Measurement']
