"""
What the node reports: the /diagnostics status and the periodic INFO line.

The /diagnostics status (level, message, key-value pairs) and the periodic INFO line are each
built in one place from named inputs. Keys and values: docs/real_time.md (/diagnostics).
Wall times in s, rates per wall second.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

__all__ = ['CommandCounts', 'diagnostics_message', 'RateWindow', 'ReportSchedule', 'status_line',
           'Window']


class Window(NamedTuple):
    """What happened between two reports."""

    rate_hz: float        # control periods run per wall second
    late_ticks: int
    slipped_s: float      # wall time dropped from the real-time schedule
    wall_s: float


class RateWindow:
    """Counts since the previous :meth:`take` (or since it was made)."""

    def __init__(self, steps: int = 0, late_ticks: int = 0, slipped_s: float = 0.0):
        self._start = (time.perf_counter(), steps, late_ticks, slipped_s)

    def take(self, steps: int, late_ticks: int, slipped_s: float,
             wall: float | None = None) -> Window:
        """
        Return the window up to now, given the running totals; the next one starts now.

        ``wall``: now on the wall clock (``time.perf_counter``), if the caller has read it.
        """
        now = (time.perf_counter() if wall is None else wall, steps, late_ticks, slipped_s)
        start, self._start = self._start, now
        wall = now[0] - start[0]
        rate = (now[1] - start[1]) / wall if wall > 0 else 0.0
        return Window(rate, now[2] - start[2], now[3] - start[3], wall)


class ReportSchedule:
    """
    When a periodic report (INFO line, /diagnostics) is due by the wall clock.

    A report's timer asks on its own grid; a pacing that starves the node's timers (free run)
    asks after each tick. A report is due at most once per ``period`` (s): timer callbacks that
    come late in a burst are one report, and a starved timer is made up for by the ticks.
    """

    def __init__(self, period: float, now: float):
        self.period = period
        self._last = now

    def due(self, now: float, on_timer: bool) -> bool:
        """Return True (and start the next period) if the report is due at ``now``."""
        # a timer on its own grid may come a little less than a period after a report that a
        # tick made: half a period tells its call from a late duplicate in a burst
        if now - self._last < self.period * (0.5 if on_timer else 1.0):
            return False
        self._last = now
        return True


class CommandCounts(NamedTuple):
    """The node's command counters (totals)."""

    received: int
    refused: int
    clamped: int
    last_refused: str     # the latest refusal's reason


def diagnostics_message(*, node_name: str, stamp, mode: str, paused: bool, simulator,
                        window: Window, achieved_rtf: float, pacing, late_ticks: int,
                        slipped_s: float, commands: CommandCounts, distrust: str,
                        recorder, wait=None, predictability=None) -> DiagnosticArray:
    """
    Build one /diagnostics message with the node's one status ``<node_name>: simulation``.

    :param simulator: the :class:`~det_sim_ros.sim.simulator.Simulator` (sim time, fault,
        voltages, stepper, power residual).
    :param pacing: the pacing's :class:`~det_sim_ros.ros.pacing.PacingReport` (lag, its
        warning, its own keys).
    :param late_ticks, slipped_s: the pacing's totals.
    :param distrust: why the results are not to be trusted ('' if they are).
    :param recorder: the MCAP :class:`~det_sim_ros.io.log.Recorder`, or None.
    :param predictability: the measure's keys (ros.predictability), or None.
    :param wait: what the node waits for (:class:`~det_sim_ros.ros.waiting.Wait`), or None;
        once it is shown it is the message of an OK status.
    """
    # the fully qualified name tells namespaced nodes apart (/arm1/sim_node: simulation)
    status = DiagnosticStatus(name=f'{node_name}: simulation', hardware_id=node_name)
    status.level, status.message = _level_and_message(simulator.fault, distrust,
                                                      pacing.warning, wait, paused)
    dt, wall = simulator.dt, window.wall_s
    residual = simulator.power_residual() if not simulator.fault else math.nan
    values = {
        'sim_time_s': f'{simulator.t:.6f}',
        'mode': mode,
        'paused': str(paused).lower(),
        'step_rate_hz': f'{window.rate_hz:.1f}',
        'real_time_factor': f'{achieved_rtf:.3f}',
        'window_s': f'{wall:.3f}',
        'lag_ms': f'{pacing.lag_steps * dt * 1e3:.1f}',
        'max_lag_ms': f'{pacing.max_lag_steps * dt * 1e3:.1f}',
        'late_ticks': str(late_ticks),
        'late_ticks_per_s': f'{window.late_ticks / wall:.1f}' if wall > 0 else '0.0',
        'slipped_s': f'{slipped_s:.3f}',
        'slipped_ms_per_s': f'{window.slipped_s / wall * 1e3:.1f}' if wall > 0 else '0.0',
        'refused_commands': str(commands.refused),
        'last_refused': commands.last_refused,
        'clamped_commands': str(commands.clamped),
        'commands_received': str(commands.received),
        'power_residual': f'{residual:.3e}',
        'voltage_V': str(simulator.u.tolist()),
        'fault': simulator.fault,
        'stepper': simulator.describe_stepper(),      # adaptive: the current step count
        'fidelity': simulator.scene.fidelity_label,
        'tolerance': f'{simulator.tolerance:g}',     # the resolved one ('auto': its level's)
        **pacing.values,
        'waiting_for': wait.text() if wait is not None else '',
        'waiting_s': f'{wait.seconds:.3f}' if wait is not None else '0.000',
        'internal_steps': str(simulator.steps_taken),
        **(predictability or {}),
    }
    if recorder is not None:
        values.update({'log_file': recorder.path, 'log_messages': str(recorder.messages),
                       'log_fault': recorder.fault})
        if recorder.fault and status.level == DiagnosticStatus.OK:
            status.level, status.message = DiagnosticStatus.WARN, recorder.fault
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = stamp
    return msg


def _level_and_message(fault: str, distrust: str, warning: str, wait, paused: bool) -> tuple:
    """Return the status level and message: the most significant of what is going on."""
    if fault:
        return DiagnosticStatus.ERROR, f'fault: {fault}'
    if distrust or warning:
        return DiagnosticStatus.WARN, distrust or warning
    if wait is not None and wait.shown():
        return DiagnosticStatus.OK, wait.text()
    return DiagnosticStatus.OK, 'paused' if paused else 'running'


def _fixed(value) -> str:
    """Return ``value`` with 3 decimals; one that rounds to zero is '0.000', never '-0.000'."""
    text = f'{value:.3f}'
    return '0.000' if text == '-0.000' else text   # the rest state's round-off (-4e-8 mm)


def _mm(values) -> str:
    if len(values) == 1:
        return _fixed(values[0])
    if len(values) <= 4:
        return '[' + ', '.join(_fixed(v) for v in values) + ']'
    return f'{_fixed(values.min())}..{_fixed(values.max())}'


def status_line(*, t: float, volts, q_mm, dy_mm, rtf: float, window_s: float,
                state: str) -> str:
    """
    Return the periodic INFO line.

    It holds the sim time (s), voltages (V), deflection and displacement (mm), the achieved
    real-time factor over the last ``window_s`` of wall time and the state (running, paused,
    FAULT, or what the node waits for).
    """
    v = volts.tolist() if len(volts) <= 4 else f'{volts.min():g}..{volts.max():g}'
    return (f't={t:.3f} s v={v} V q={_mm(q_mm)} mm dy={_mm(dy_mm)} mm RTF={rtf:.2f} '
            f'(over {window_s:.2f} s) {state}')
