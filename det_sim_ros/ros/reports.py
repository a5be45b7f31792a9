"""
The node's periodic reports: /diagnostics, the INFO line, what a waiting node waits for.

Each report is due at most once per period by the wall clock. In free run the stepping timer
is always due and rclpy's EventsExecutor then starves the other timers, which fire late and in
bursts; the free-run tick therefore also runs whatever report is due (:meth:`NodeReports.
run_due`). Rates are measured over the wall-time window since the report's last run.
"""

from __future__ import annotations

import time

from .diagnostics import diagnostics_message, RateWindow, ReportSchedule, status_line
from .waiting import WaitLog
from ..scenes.outputs import main_topic

__all__ = ['NodeReports']

WAIT_CHECK_S = 0.25   # s of wall time between two looks at what a waiting node waits for


class NodeReports:
    """
    /diagnostics and the INFO line of one node, paced by the wall clock.

    :param node: the :class:`~det_sim_ros.ros.node.SimNode` reported on.
    :param publisher: its /diagnostics publisher.
    :param diagnostics_period, info_period: wall seconds between two reports (0: no INFO line).
    :param watch_waits: log what the node waits for (lockstep, or sample 0 held back).
    """

    def __init__(self, node, publisher, diagnostics_period: float, info_period: float,
                 watch_waits: bool):
        self._node = node
        self._publisher = publisher
        self._diag_window, self._info_window = RateWindow(), RateWindow()
        self._distrust_reported = ''
        now = time.perf_counter()
        self._schedules = {self.publish_diagnostics: ReportSchedule(diagnostics_period, now)}
        if info_period > 0:
            self._schedules[self.log_info] = ReportSchedule(info_period, now)
        for report, schedule in self._schedules.items():
            node.create_timer(schedule.period, lambda report=report: self._timed(report),
                              clock=node.steady_clock)
        self._wait_log = WaitLog(node.get_logger().info)
        if watch_waits:
            node.create_timer(WAIT_CHECK_S, lambda: self._wait_log.check(node.waiting()),
                              clock=node.steady_clock)

    def _timed(self, report) -> None:
        now = time.perf_counter()
        if self._schedules[report].due(now, True):
            report(now)

    def run_due(self) -> None:
        """Run every report that is due by the wall clock."""
        now = time.perf_counter()
        for report, schedule in self._schedules.items():
            if schedule.due(now, False):
                report(now)

    def publish_diagnostics(self, now: float | None = None):
        """Publish the /diagnostics status for the window since the last one; return it."""
        node = self._node
        pacing, sim = node.pacing, node.simulator
        window = self._diag_window.take(node.steps_total, pacing.late_ticks, pacing.slipped_s,
                                        now)
        node.achieved_rtf = window.rate_hz * sim.dt
        report = pacing.report(window.rate_hz, window.slipped_s, window.wall_s)
        distrust = sim.trust_issue()
        if distrust and not self._distrust_reported:
            # once, until it clears (a reset): the text changes every time (the residual and
            # the voltages)
            node.get_logger().warning(distrust)
        self._distrust_reported = distrust
        msg = diagnostics_message(
            node_name=node.get_fully_qualified_name(), stamp=node.get_clock().now().to_msg(),
            mode=pacing.mode, paused=node.paused, simulator=sim, window=window,
            achieved_rtf=node.achieved_rtf, pacing=report, late_ticks=pacing.late_ticks,
            slipped_s=pacing.slipped_s, distrust=distrust, recorder=node.recorder,
            commands=node.commands.counts(), wait=node.waiting(),
            predictability=node.predictability.values())
        self._publisher.publish(msg)
        return msg

    def log_info(self, now: float | None = None) -> None:
        """Log the periodic status line (time, voltages, q, Δy, real-time factor, state)."""
        node = self._node
        pacing, sim = node.pacing, node.simulator
        window = self._info_window.take(node.steps_total, pacing.late_ticks, pacing.slipped_s,
                                        now)
        out, wait = node.current_outputs(), node.waiting()
        state = ('FAULT' if sim.fault else 'paused' if node.paused
                 else wait.text() if wait is not None and wait.shown() else 'running')
        node.get_logger().info(status_line(
            t=sim.t, volts=sim.u, rtf=window.rate_hz * sim.dt, window_s=window.wall_s,
            state=state, q_mm=node.contract.values(out, 'deflection', 'position') * 1e3,
            dy_mm=node.contract.values(out, main_topic(), 'position') * 1e3))
