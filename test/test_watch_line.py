"""
What ``det_sim watch`` prints per line: engineering notation, round-off as 0, a plate's height.

The Watcher is fed messages shaped as the node's JointState outputs (no ROS needed).
"""

import io
from types import SimpleNamespace

from det_sim_ros.cli.watch import engineering, Watcher
import pytest


@pytest.mark.parametrize('value, unit, resolution, shown', [
    (1.79e-3, 'm', 1e-9, '1.79 mm'),
    (-3.972e-11, 'm', 1e-9, '0 m'),           # the rest state's round-off, not -3.972e-08 mm
    (2.002e-7, 'A', 1e-9, '200.2 nA'),         # not 0.0002002 mA
    (12.34e-6, 'C', 1e-12, '12.34 µC'),
    (-5.2e-4, 'rad', 1e-9, '-520 µrad'),
    (0.99996, 'm', 1e-9, '1 m'),               # rounds up into the next prefix
    (3000.0, 'V', 1e-3, '3 kV'),
])
def test_engineering_notation(value, unit, resolution, shown):
    assert engineering(value, unit, resolution) == shown


def _msg(names, position, velocity=(), stamp_ns=1_500_000_000):
    header = SimpleNamespace(stamp=SimpleNamespace(sec=stamp_ns // 10**9,
                                                   nanosec=stamp_ns % 10**9))
    return SimpleNamespace(header=header, name=list(names), position=list(position),
                           velocity=list(velocity))


def test_a_plate_line_shows_each_det_and_the_plate_height_and_tilt():
    stream = io.StringIO()
    watcher = Watcher(csv=False, count=1, stream=stream)
    dets = ('left', 'right')
    watcher.take('structure', _msg(('plate_dy', 'plate_phi'), (1.2e-3, -2.5e-3)))
    watcher.take('displacement', _msg(dets, (1.0e-3, 1.4e-3)))
    watcher.take('deflection', _msg(dets, (5.1e-3, 5.2e-3), (0.0, 0.0)))
    watcher.take('charge', _msg(dets, (1.5e-5, 0.0)))
    watcher.take('current', _msg(dets, (2.002e-7, -1e-12)))
    watcher.tick(0.0)
    assert stream.getvalue() == (
        't = 1.500 s  left: dy 1 mm q 5.1 mm q_p 15 µC i 200.2 nA  '
        'right: dy 1.4 mm q 5.2 mm q_p 0 C i 0 A  plate: height 1.2 mm tilt -2.5 mrad\n')


def _sample(watcher, stamp_ns, topics=('displacement', 'deflection', 'charge', 'current')):
    for topic in topics:
        watcher.take(topic, _msg(('det0',), (0.0,), (0.0,), stamp_ns=stamp_ns))


def test_lost_samples_are_counted_where_they_are_missing():
    """
    Check the loss line against stamps fed with known holes, a lost part and a reset.

    Periods of 1 ms: 0..4, then 8..9 (5, 6, 7 missing), 10 lacks a topic (never complete),
    11, then a reset back to 0 and 1 (a step back is a new start, not a loss).
    """
    watcher = Watcher(csv=True, count=0, stream=io.StringIO())
    for k in (0, 1, 2, 3, 4, 8, 9):
        _sample(watcher, k * 1_000_000)
    _sample(watcher, 10_000_000, topics=('displacement', 'deflection'))
    for k in (11, 0, 1):
        _sample(watcher, k * 1_000_000)
    assert watcher.lost() == 4
    assert watcher.loss_line().startswith(
        '4 sample(s) lost between the 10 taken, in 2 gap(s), the first after t = 0.004 s, '
        'the largest 3 after t = 0.004 s (')
    quiet = Watcher(csv=True, count=0, stream=io.StringIO())
    for k in range(5):
        _sample(quiet, k * 1_000_000)
    assert quiet.lost() == 0 and quiet.loss_line() == ''
