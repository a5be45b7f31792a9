"""
The node's parameters declared in ROS from the ROS-free table (det_sim_ros.ros.params).

The scene's values are declared read-only, the node parameters with their descriptions and
ranges; a change at run time must pass the checks here.
"""

from __future__ import annotations

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.time_source import USE_SIM_TIME_NAME
from rclpy.type_description_service import START_TYPE_DESCRIPTION_SERVICE_PARAM

from .params import (node_parameter_values, NODE_PARAMS, Param, runtime_refusal,
                     SCENE_PARAM_DESCRIPTION, scene_parameters, SCENE_SECTIONS,
                     unknown_parameters)
from ..scenes.scene import load_scene, SceneError

__all__ = ['declare_parameters', 'descriptor', 'load_node_scene', 'RCLPY_OWN_PARAMETERS',
           'validate_parameters']

# the parameters every rclpy Node declares itself (test_node_parameters checks the list)
RCLPY_OWN_PARAMETERS = frozenset({USE_SIM_TIME_NAME, START_TYPE_DESCRIPTION_SERVICE_PARAM})


def load_node_scene(node):
    """
    Load the node's scene and declare every parameter; return (scene, scene file name).

    ``node`` was built with ``automatically_declare_parameters_from_overrides``: what it was
    started with (``-p``, a params file, ``parameter_overrides``) is declared as given, so it
    is read here through rclpy's public API. The scene is the ``scene_file`` parameter with the
    scene keys given as overrides (``-p physics.Rs:=...``); the integration method is checked
    here, before the long preparation.
    """
    overrides = node.get_parameters_by_prefix('')   # the overrides and rclpy's own
    if 'scene_file' in overrides and not isinstance(overrides['scene_file'].value, str):
        raise SceneError(f'parameter scene_file: must be a string (a name in config/ or a '
                         f"path; got {overrides['scene_file'].value!r})")
    given = {name: p.value for name, p in overrides.items()}
    scene_file = given.get('scene_file', 'default')
    scene = load_scene(scene_file, overrides={
        name: value for name, value in given.items()
        if name.split('.')[0] in SCENE_SECTIONS or name == 'rate_hz'})
    if scene.method != 'auto':
        from ..sim.integrators import get_method
        try:
            get_method(scene.method)
        except ValueError as exc:
            raise SceneError(f"scene key 'integrator.method': {exc}") from None
    declared = declare_parameters(node, scene, scene_file, given)
    _check_names(node, set(overrides) - RCLPY_OWN_PARAMETERS, declared | RCLPY_OWN_PARAMETERS)
    return scene, scene_file


def _check_names(node, given, known) -> None:
    """
    Warn about (or, with strict_parameters, refuse) the names the node does not declare.

    An unknown name is undeclared again: the node shows only the parameters it has.
    """
    sentences = unknown_parameters(given, known)
    if sentences and node.get_parameter('strict_parameters').value:
        raise SceneError('; '.join(sentences) + ' (strict_parameters is true)')
    for name in given - known:
        node.undeclare_parameter(name)
    for sentence in sentences:
        node.get_logger().warning(sentence)


def descriptor(param: Param) -> ParameterDescriptor:
    """Build a node parameter's descriptor: its description, read-only flag and range."""
    result = ParameterDescriptor(description=param.description, read_only=param.read_only)
    bounds, default = param.bounds, param.default
    if bounds is not None and isinstance(default, float):
        result.floating_point_range = [FloatingPointRange(
            from_value=float(bounds[0]), to_value=float(bounds[1]), step=0.0)]
    elif bounds is not None and isinstance(default, int):
        result.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1], step=1)]
    return result


def declare_parameters(node, scene, scene_file: str, overrides: dict) -> set:
    """
    Declare the scene file, the scene's values (read-only) and the node parameters on ``node``.

    ``overrides`` (name -> value) are the values the node was started with, each already
    declared as given (:func:`load_node_scene`); such a one is declared again with its checked
    value and type (an integer given for a double, e.g. physics.Rs:=1, becomes a double).
    Return the names declared.
    """
    declared = set()

    def declare(name, value, param_descriptor):
        if name in overrides:   # declared as given (never read-only)
            node.undeclare_parameter(name)
        node.declare_parameter(name, value, param_descriptor, ignore_override=True)
        declared.add(name)
    declare('scene_file', scene_file, ParameterDescriptor(
        description='scene file: a name in config/ or a path', read_only=True))
    for name, value in scene_parameters(scene):
        declare(name, value, ParameterDescriptor(description=SCENE_PARAM_DESCRIPTION,
                                                 read_only=True))
    for name, value in node_parameter_values(scene.node, overrides).items():
        declare(name, value, descriptor(NODE_PARAMS[name]))
    return declared


def validate_parameters(params) -> SetParametersResult:
    """Refuse a change that :func:`runtime_refusal` refuses (the on-set-parameters callback)."""
    for param in params:
        reason = runtime_refusal(param.name, param.value)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
    return SetParametersResult(successful=True)
