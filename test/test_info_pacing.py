"""
The free-run node's periodic reports are paced by the wall clock.

In free run the always-due stepping timer starves the node's other timers in the
EventsExecutor, which then fire late in bursts: INFO lines and /diagnostics came several within
a few ms, each with an RTF over a window of a few ms. Each report is now due at most once per
period and says the wall-time window of its RTF.
"""

import re

import pytest

PERIOD = 0.1     # s, info_period and diagnostics_period


def stamp_s(stamp):
    return stamp.sec + stamp.nanosec * 1e-9


def test_free_run_reports_are_paced_by_the_wall_clock(harness):
    """
    Check that free-run INFO lines and /diagnostics come once per period, not in bursts.

    Eight INFO lines and eight /diagnostics messages of a free-running node: no two of a kind
    closer than half a period (the node's own log and header stamps), and every INFO line says
    the wall-time window of its RTF.
    """
    h = harness(real_time=False, info_period=PERIOD, diagnostics_period=PERIOD)
    records = []
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile
    h.test.create_subscription(
        Log, '/rosout', lambda msg: records.append(msg) if msg.msg.startswith('t=') else None,
        QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    h.spin_until(lambda: len(records) >= 8 and len(h.diagnostics) >= 8, 'eight reports')
    info_stamps = [stamp_s(r.stamp) for r in records]
    diag_stamps = [stamp_s(m.header.stamp) for m in h.diagnostics]
    for stamps in (info_stamps, diag_stamps):
        gaps = [b - a for a, b in zip(stamps, stamps[1:])]
        assert min(gaps) >= 0.5 * PERIOD, gaps
    windows = [float(re.search(r'RTF=\S+ \(over (\S+) s\)', r.msg).group(1)) for r in records]
    assert min(windows) > 0.0, [r.msg for r in records]   # (0.0: a window under 0.05 s)
    assert h.node.simulator.k > 0


if __name__ == '__main__':
    pytest.main([__file__])
