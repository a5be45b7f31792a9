"""det_sim_ros: dielectric elastomer transducers coupled with buckled beams, simulated for ROS 2."""

__version__ = '0.1.0'
