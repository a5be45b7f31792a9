"""
Test both ends of every ranged node parameter: the maximum is accepted, beyond it refused.

Both ends of every ranged node parameter (det_sim_ros.ros.params.NODE_PARAMS): a value just
above the maximum, inf or NaN is refused with a reason, at run time (the current value stays)
and at start-up (one SceneError naming the parameter); the maximum itself is accepted.
"""

import math

from det_sim_ros.ros.node import SimNode
from det_sim_ros.ros.params import NODE_PARAMS
from det_sim_ros.scenes.scene import SceneError
import pytest
from rclpy.parameter import Parameter

QUIET = {'real_time': False, 'info_period': 0.0, 'log.enabled': False}


def _ranged(runtime):
    """Names of the numeric ranged parameters that can (runtime) or cannot be set running."""
    return sorted(name for name, (default, _, read_only, bounds) in NODE_PARAMS.items()
                  if bounds is not None and not isinstance(default, (str, bool))
                  and read_only != runtime)


RUNTIME = _ranged(runtime=True)
READ_ONLY = _ranged(runtime=False)


def _above(name):
    """
    Return values just above the maximum of the named parameter.

    Just above means beyond rclpy's 1e-6 relative edge tolerance; plus inf and NaN for a
    double.
    """
    default, hi = NODE_PARAMS[name][0], NODE_PARAMS[name][3][1]
    if isinstance(default, int):
        return [hi + 1, 2 ** 62]
    return [hi * (1.0 + 1e-3) + 1e-3, math.inf, math.nan]


def test_the_tables_have_both_kinds():
    assert {'real_time_factor', 'steps_per_tick', 'lockstep.timeout'} <= set(RUNTIME)
    assert {'threads', 'realtime_priority', 'diagnostics_period'} <= set(READ_ONLY)


@pytest.fixture
def node(ros_context):
    made = SimNode(context=ros_context, parameter_overrides=[
        Parameter(name, value=value) for name, value in QUIET.items()])
    yield made
    made.destroy_node()


@pytest.mark.ros
@pytest.mark.parametrize('name', RUNTIME)
def test_runtime_value_above_the_range_is_refused_and_the_old_value_kept(node, name):
    old = node.get_parameter(name).value
    for value in _above(name):
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful, (name, value)
        assert result.reason, (name, value)
        assert node.get_parameter(name).value == old, (name, value)
    hi = NODE_PARAMS[name][3][1]
    assert node.set_parameters([Parameter(name, value=hi)])[0].successful, name   # the edge
    assert node.set_parameters([Parameter(name, value=old)])[0].successful, name


@pytest.mark.ros
@pytest.mark.parametrize('name', RUNTIME + READ_ONLY)
def test_start_up_value_above_the_range_is_refused(ros_context, name):
    for value in _above(name):
        overrides = dict(QUIET, **{name: value})
        with pytest.raises(SceneError, match=f'{name}: out of range') as info:
            SimNode(context=ros_context, parameter_overrides=[
                Parameter(key, value=v) for key, v in overrides.items()])
        assert '\n' not in str(info.value)
