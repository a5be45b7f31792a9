"""
The free-run node's periodic reports are paced by the wall clock.

In free run the always-due stepping timer starves the node's other timers in the
EventsExecutor, which then fire late in bursts: INFO lines and /diagnostics came several within
a few ms, each with an RTF over a window of a few ms. Each report is now due at most once per
period and says the wall-time window of its RTF.
"""

import re

import pytest

pytestmark = pytest.mark.ros

PERIOD = 0.05    # s, info_period and diagnostics_period


def test_free_run_reports_are_paced_by_the_wall_clock(harness):
    """
    Check that free-run INFO lines and /diagnostics come once per period, not in bursts.

    Thirty INFO lines and thirty /diagnostics messages of a free-running node: each says the
    wall-time window its figures (RTF, step rate) cover, and no window is shorter than half a
    period (a burst of late timer callbacks gave windows of a few ms).
    """
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile
    h = harness(real_time=False, info_period=PERIOD, diagnostics_period=PERIOD)
    lines = []
    h.test.create_subscription(
        Log, '/rosout', lambda msg: lines.append(msg.msg) if msg.msg.startswith('t=') else None,
        QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    name = h.node.get_fully_qualified_name()
    ours = lambda: [m for m in h.diagnostics   # noqa: E731 - not another node's on the domain
                    if m.status and m.status[0].hardware_id == name]
    h.spin_until(lambda: len(lines) >= 30 and len(ours()) >= 30, '30 reports')
    info_windows = [float(re.search(r'RTF=\S+ \(over (\S+) s\)', line).group(1))
                    for line in lines]
    diag_windows = [float({kv.key: kv.value for kv in m.status[0].values}['window_s'])
                    for m in ours()]
    assert min(info_windows) >= 0.5 * PERIOD, lines
    assert min(diag_windows) >= 0.5 * PERIOD, diag_windows
    assert h.node.simulator.k > 0


if __name__ == '__main__':
    pytest.main([__file__])
