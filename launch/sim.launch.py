"""
Start sim_node from a ROS 2 install: ``ros2 launch det_sim_ros sim.launch.py``.

Launch arguments (``name:=value``)::

    scene     scene file path or installed scene name (default, plate, array, ...)
    ns        the node's namespace, e.g. arm1: topics /arm1/voltage_command, ... ('' = none)
    mode      real_time, free_run or lockstep ('' = from the scene's node.real_time)
    log_path  MCAP log directory or .mcap file

Every value reaches the node as a parameter (scene_file, mode, log.path); the node checks it
at start and stops with one FATAL line if it cannot use it. docs/shell.md has the equivalent
``sim_node --ros-args ...`` line.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

ARGUMENTS = {
    'scene': ('default', 'scene file path or installed scene name (default, plate, array)'),
    'ns': ('', "the node's namespace ('' = none)"),
    'mode': ('', "real_time, free_run or lockstep ('' = from the scene's node.real_time)"),
    'log_path': ('./det_sim_logs', 'MCAP log directory or .mcap file'),
}
# node parameter -> launch argument (each value passed as a string, never parsed as YAML)
PARAMETERS = {'scene_file': 'scene', 'mode': 'mode', 'log.path': 'log_path'}


def generate_launch_description():
    """Return the launch description: the arguments and one sim_node."""
    declared = [DeclareLaunchArgument(name, default_value=default, description=text)
                for name, (default, text) in ARGUMENTS.items()]
    parameters = {name: ParameterValue(LaunchConfiguration(argument), value_type=str)
                  for name, argument in PARAMETERS.items()}
    node = Node(package='det_sim_ros', executable='sim_node', name='sim_node',
                namespace=LaunchConfiguration('ns'), parameters=[parameters],
                output='screen', emulate_tty=True)
    return LaunchDescription(declared + [node])
