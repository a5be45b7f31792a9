"""
The node's parameters declared in ROS from the ROS-free table (det_sim_ros.ros.params).

The scene's values are declared read-only, the node parameters with their descriptions and
ranges; a change at run time must pass the checks here.
"""

from __future__ import annotations

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.parameter import Parameter

from .params import (node_parameter_values, NODE_PARAMS, Param, runtime_refusal,
                     SCENE_PARAM_DESCRIPTION, scene_parameters, SCENE_SECTIONS,
                     unknown_parameters)
from ..scenes.scene import load_scene, SceneError

__all__ = ['declare_parameters', 'descriptor', 'load_node_scene', 'validate_parameters']


def load_node_scene(node):
    """
    Load the node's scene and declare every parameter; return (scene, scene file name).

    The scene is the ``scene_file`` parameter with the scene keys given as overrides (``-p
    physics.Rs:=...``); the integration method is checked here, before the long preparation.
    """
    overrides = dict(getattr(node, '_parameter_overrides', {}) or {})
    if 'scene_file' in overrides and not isinstance(overrides['scene_file'].value, str):
        raise SceneError(f'parameter scene_file: must be a string (a name in config/ or a '
                         f"path; got {overrides['scene_file'].value!r})")
    scene_file = node.declare_parameter('scene_file', 'default', ParameterDescriptor(
        description='scene file: a name in config/ or a path', read_only=True)).value
    scene = load_scene(scene_file, overrides={
        name: p.value for name, p in overrides.items()
        if name.split('.')[0] in SCENE_SECTIONS or name == 'rate_hz'})
    if scene.method != 'auto':
        from ..sim.integrators import get_method
        try:
            get_method(scene.method)
        except ValueError as exc:
            raise SceneError(f"scene key 'integrator.method': {exc}") from None
    declare_parameters(node, scene, {name: p.value for name, p in overrides.items()})
    _check_names(node, overrides)
    return scene, scene_file


def _check_names(node, overrides) -> None:
    """Warn about (or, with strict_parameters, refuse) the names the node does not declare."""
    sentences = unknown_parameters(overrides, node.get_parameters_by_prefix(''))
    if sentences and node.get_parameter('strict_parameters').value:
        raise SceneError('; '.join(sentences) + ' (strict_parameters is true)')
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


def declare_parameters(node, scene, overrides: dict) -> None:
    """
    Declare the scene's values (read-only) and the node parameters on ``node``.

    ``overrides`` (name -> value) are the ``-p`` values the node was started with; each is
    replaced by its checked value, since rclpy refuses an override whose type differs from the
    declared one (an integer given for a double, e.g. physics.Rs:=1).
    """
    given = node._parameter_overrides      # rclpy's: read when a parameter is declared

    def declare(name, value, param_descriptor):
        if name in given:
            given[name] = Parameter(name, value=value)
        node.declare_parameter(name, value, param_descriptor)
    for name, value in scene_parameters(scene):
        declare(name, value, ParameterDescriptor(description=SCENE_PARAM_DESCRIPTION,
                                                 read_only=True))
    for name, value in node_parameter_values(scene.node, overrides).items():
        declare(name, value, descriptor(NODE_PARAMS[name]))


def validate_parameters(params) -> SetParametersResult:
    """Refuse a change that :func:`runtime_refusal` refuses (the on-set-parameters callback)."""
    for param in params:
        reason = runtime_refusal(param.name, param.value)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
    return SetParametersResult(successful=True)
