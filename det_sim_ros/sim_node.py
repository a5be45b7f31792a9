"""
ROS 2 node: voltage commands in, the actuator's state out, on a fixed sim-time grid t = k dt.

The node only does I/O: all physics is in :class:`det_sim_ros.simulator.Simulator`.
Topic, parameter and service contract: see README.md.
"""

from __future__ import annotations

import math
import sys
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger

from .model import ModelDomainError
from .scene import load_scene, scene_to_dict, SceneError
from .simulator import Simulator

__all__ = ['SimNode', 'main', 'OUTPUT_TOPICS']

NODE_NAME = 'sim_node'
SCENE_SECTIONS = ('scene', 'physics', 'integrator')
# topic: (output name, unit); displacement is y0 - y, computed here
OUTPUT_TOPICS = {
    'deflection': ('q', 'm'),
    'displacement': ('y', 'm'),
    'charge': ('q_p', 'C'),
    'current': ('i_DE', 'A'),
}
# name: (default, description, read_only, range (lo, hi) or None)
NODE_PARAMS = {
    'real_time': (True, 'true: sim time follows the wall clock; false: free-run as fast as '
                  'possible and publish /clock', True, None),
    'real_time_factor': (1.0, 'real-time mode: sim seconds per wall second', False,
                         (1.0e-3, 1.0e3)),
    'steps_per_tick': (10, 'free-run mode: control periods per timer tick', False, (1, 100000)),
    'max_catchup_steps': (1000, 'real-time mode: most steps run in one tick; the rest run in '
                          'later ticks and count as overrun (never skipped)', False, (1, 1000000)),
    'qos_sensor_data': (False, 'outputs best-effort SensorDataQoS instead of reliable depth 10',
                        True, None),
    'start_paused': (False, 'start paused (resume with ~/pause false, or ~/step)', True, None),
    'diagnostics_period': (1.0, 'seconds between /diagnostics messages (wall clock)', True,
                           (0.01, 3600.0)),
    'log.enabled': (True, 'record the run to MCAP: commands in, outputs out, scene (issue 5)',
                    True, None),
    'log.path': ('./det_sim_logs', 'MCAP log directory (a new file per run) or a .mcap file',
                 True, None),
    'log.split_mb': (0.0, 'start a new log file after this many MiB (0 = one file per run)',
                     True, (0.0, 1.0e6)),
    'info_period': (5.0, 'seconds between INFO status lines (wall clock), 0 = off', True,
                    (0.0, 3600.0)),
}


def _rest_shortening(scene) -> float:
    """
    End shortening y0 (m) of the stable buckled equilibrium at 0 V.

    Uses :func:`det_sim_ros.statics.rest_shortening` when available, otherwise settles the
    simulator at 0 V for 1.5 s of sim time.
    """
    try:
        from .statics import rest_shortening
    except ImportError:
        sim = Simulator(scene)
        for _ in range(int(round(1.5 / sim.dt))):
            sim.step()
        return sim.outputs()['y']
    return float(rest_shortening(scene))


def _flatten(data, prefix=''):
    for key, value in data.items():
        if isinstance(value, dict):
            yield from _flatten(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def _check_node_value(name, value):
    default = NODE_PARAMS[name][0]
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    if not ok:
        raise SceneError(f"scene key 'node.{name}': must be of type {type(default).__name__} "
                         f'(got {value!r})')
    return value


class SimNode(Node):
    """
    The simulator as a ROS 2 node (see README.md for the topic contract).

    :param kwargs: forwarded to :class:`rclpy.node.Node` (``context``, ``namespace``,
        ``parameter_overrides``, ...).
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        overrides = dict(getattr(self, '_parameter_overrides', {}) or {})
        scene_file = self.declare_parameter('scene_file', 'default', ParameterDescriptor(
            description='scene file: a name in config/ or a path', read_only=True)).value
        scene_overrides = {name: p.value for name, p in overrides.items()
                           if name.split('.')[0] in SCENE_SECTIONS or name == 'rate_hz'}
        self.scene = load_scene(scene_file, overrides=scene_overrides)
        self._declare_scene_parameters()
        self._declare_node_parameters(overrides)

        self.get_logger().info(f'preparing scene {scene_file!r} (the first start after an install '
                               'compiles the model kernels: up to a minute)')
        self._sim = Simulator(self.scene)
        self._dt = self._sim.dt
        names = self._sim.output_names
        n = self._sim.model.n_inputs
        self.det_names = [f'det{i}' for i in range(n)]
        self._det_index = {name: i for i, name in enumerate(self.det_names)}
        self._channels = {topic: self._output_indices(names, out, n)
                          for topic, (out, _) in OUTPUT_TOPICS.items()}
        self._qdot = self._output_indices(names, 'q_dot', n)
        self.y0 = _rest_shortening(self.scene)

        # counters (reported on /diagnostics)
        self.refused_commands = 0
        self.clamped_commands = 0
        self.commands_received = 0
        self.overruns = 0
        self.steps_total = 0
        self.lateness_log = None  # set to a list to record real-time tick lateness (bench)
        self._fault_reported = ''

        # MCAP recording hook (issue 5): an object with record(topic, msg, sim_time_ns), or None.
        # Called for every published output and every received command.
        self._recorder = None

        out_qos = qos_profile_sensor_data if self._p('qos_sensor_data') else QoSProfile(depth=10)
        self._pubs = {topic: self.create_publisher(JointState, topic, out_qos)
                      for topic in OUTPUT_TOPICS}
        self._msgs = {topic: JointState(name=list(self.det_names)) for topic in OUTPUT_TOPICS}
        self._clock_pub = (None if self._p('real_time')
                           else self.create_publisher(ClockMsg, '/clock', QoSProfile(depth=10)))
        self._clock_msg = ClockMsg()
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(Float64MultiArray, 'voltage_command', self._on_command, 10)
        self.create_subscription(JointState, 'voltage_command_joint', self._on_joint_command, 10)
        self.create_service(SetBool, '~/pause', self._srv_pause)
        self.create_service(Trigger, '~/step', self._srv_step)
        self.create_service(Trigger, '~/reset', self._srv_reset)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.paused = bool(self._p('start_paused'))
        self._timer = None
        self._make_timer()
        self._diag_window = (time.perf_counter(), self.steps_total)
        self._info_window = self._diag_window
        self.achieved_rtf = 0.0
        self.create_timer(self._p('diagnostics_period'), self._publish_diagnostics,
                          clock=self._steady)
        if self._p('info_period') > 0:
            self.create_timer(self._p('info_period'), self._log_info, clock=self._steady)
        self._start_recorder(out_qos)
        self._publish_sample(self._current_outputs())
        mode = 'real-time x%g' % self._rtf if self._p('real_time') else 'free-run'
        self.get_logger().info(
            f'scene {scene_file!r}: {self.scene.beam} beam, eps_b = {self.scene.eps_b:g}, '
            f'{self.scene.rate_hz:g} Hz, {self._sim.method.name} x{self._sim.substeps}; '
            f'{mode}{", paused" if self.paused else ""}; DETs {self.det_names}')

    # -- set-up ---------------------------------------------------------------------------
    def _start_recorder(self, out_qos):
        """MCAP logging (det_sim_ros.mcap_log): on unless log.enabled is false."""
        if not self._p('log.enabled'):
            return
        from .mcap_log import Recorder
        qos = {topic: out_qos for topic in OUTPUT_TOPICS}
        qos.update({'voltage_command': QoSProfile(depth=10),
                    'voltage_command_joint': QoSProfile(depth=10)})
        self._recorder = Recorder(
            self._p('log.path'), self.scene, qos_by_topic=qos, split_mb=self._p('log.split_mb'),
            namespace=self.get_namespace(),
            metadata={'method': self._sim.method.name, 'substeps': self._sim.substeps,
                      'y0': repr(self.y0), 'node': self.get_fully_qualified_name()},
            on_fault=lambda text: self.get_logger().error(text))
        if self._recorder.active:
            self.get_logger().info(f'logging to {self._recorder.path}')
            self.create_timer(self._recorder.flush_period_s, self._recorder.maybe_flush,
                              clock=self._steady)

    def destroy_node(self):
        """Finish the MCAP log (indexed and complete), then destroy the node."""
        if self._recorder is not None:
            self._recorder.close()
        return super().destroy_node()

    def _declare_scene_parameters(self):
        """Expose the loaded scene as read-only parameters (set them in the scene file)."""
        for name, value in _flatten(scene_to_dict(self.scene)):
            if name.startswith('node.'):
                continue
            self.declare_parameter(name, value, ParameterDescriptor(
                description='scene value (read-only; set in the scene file or with -p at start)',
                read_only=True))

    def _declare_node_parameters(self, overrides):
        node_section = dict(_flatten(self.scene.node))  # node: {log: {enabled: ...}} too
        for name, param in overrides.items():
            if name.startswith('node.'):
                node_section[name[5:]] = param.value
        unknown = sorted(set(node_section) - set(NODE_PARAMS))
        if unknown:
            raise SceneError(f"scene key 'node.{unknown[0]}': unknown (allowed: "
                             + ', '.join(NODE_PARAMS) + ')')
        for name, (default, description, read_only, bounds) in NODE_PARAMS.items():
            value = _check_node_value(name, node_section.get(name, default))
            descriptor = ParameterDescriptor(description=description, read_only=read_only)
            if bounds is not None and isinstance(default, float):
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(bounds[0]), to_value=float(bounds[1]), step=0.0)]
            elif bounds is not None:
                descriptor.integer_range = [IntegerRange(
                    from_value=bounds[0], to_value=bounds[1], step=1)]
            self.declare_parameter(name, value, descriptor)
        self._rtf = self._p('real_time_factor')
        self._steps_per_tick = self._p('steps_per_tick')
        self._max_catchup = self._p('max_catchup_steps')

    @staticmethod
    def _output_indices(names, base, n):
        if base in names and n == 1:
            return [names.index(base)]
        return [names.index(f'{base}_{i}') for i in range(n)]

    def _p(self, name):
        return self.get_parameter(name).value

    def _make_timer(self):
        if self._timer is not None:
            self.destroy_timer(self._timer)
        self._resync()
        if self._p('real_time'):
            period, callback = self._dt / self._rtf, self._tick_real_time
        else:
            period, callback = 1.0e-6, self._tick_free_run
        stopped = self.paused or bool(self._sim.fault)
        self._timer = self.create_timer(period, callback, clock=self._steady,
                                        autostart=not stopped)

    def _resync(self):
        """Restart the wall-clock reference: no catch-up for time spent paused or reset."""
        self._wall0 = time.perf_counter()
        self._k0 = self._sim.k

    def _run_timer(self, run):
        if run and not self._sim.fault:
            self._resync()
            self._timer.reset()
        else:
            self._timer.cancel()

    # -- stepping -------------------------------------------------------------------------
    def _tick_real_time(self):
        if self.paused or self._sim.fault:
            return
        now = time.perf_counter()
        wall_step = self._dt / self._rtf
        target = self._k0 + int((now - self._wall0) / wall_step)
        due = target - self._sim.k
        if due <= 0:
            return
        if due > 1:
            self.overruns += 1
        log = self.lateness_log
        for _ in range(min(due, self._max_catchup)):
            if log is not None:
                log.append(time.perf_counter() - self._wall0
                           - (self._sim.k + 1 - self._k0) * wall_step)
            if not self._advance():
                return

    def _tick_free_run(self):
        if self.paused or self._sim.fault:
            return
        for _ in range(self._steps_per_tick):
            if not self._advance():
                return

    def _current_outputs(self):
        return np.array(list(self._sim.outputs().values()))

    def _advance(self) -> bool:
        """Run one control period and publish it; False (and fault) if the model diverged."""
        try:
            out = self._sim.step()
        except ModelDomainError as exc:
            self._enter_fault(str(exc))
            return False
        self.steps_total += 1
        return self._publish_sample(out)

    def _publish_sample(self, out) -> bool:
        if not np.all(np.isfinite(out)):
            self._sim.fault = self._sim.fault or f'non-finite output at t = {self._sim.t:.6g} s'
            self._enter_fault(self._sim.fault)
            return False
        t_ns = int(round(self._sim.k * self._dt * 1e9))
        stamp = Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)
        for topic, indices in self._channels.items():
            msg = self._msgs[topic]
            msg.header.stamp = stamp
            values = [float(out[i]) for i in indices]
            if topic == 'displacement':
                values = [self.y0 - v for v in values]
            elif topic == 'deflection':
                msg.velocity = [float(out[i]) for i in self._qdot]
            msg.position = values
            self._pubs[topic].publish(msg)
            if self._recorder is not None:
                self._recorder.record(topic, msg, t_ns)
        if self._clock_pub is not None:
            self._clock_msg.clock = stamp
            self._clock_pub.publish(self._clock_msg)
        return True

    def _enter_fault(self, reason):
        self._timer.cancel()
        if self._fault_reported != reason:
            self._fault_reported = reason
            self.get_logger().error(f'fault, integration stopped (call ~/reset): {reason}')
            self._publish_diagnostics()

    # -- commands -------------------------------------------------------------------------
    def _on_command(self, msg):
        self._record_command('voltage_command', msg)
        self._apply_command(list(msg.data), 'voltage_command')

    def _on_joint_command(self, msg):
        self._record_command('voltage_command_joint', msg)
        names, values = list(msg.name), list(msg.position)
        if len(names) != len(values):
            return self._refuse(f'voltage_command_joint: {len(names)} name(s) but '
                                f'{len(values)} position value(s)')
        unknown = [name for name in names if name not in self._det_index]
        if unknown or not names:
            return self._refuse(f'voltage_command_joint: unknown DET name(s) {unknown or names} '
                                f'(expected {self.det_names})')
        volts = self._sim.u.tolist()
        for name, value in zip(names, values):
            volts[self._det_index[name]] = value
        self._apply_command(volts, 'voltage_command_joint')

    def _record_command(self, topic, msg):
        self.commands_received += 1
        if self._recorder is not None:
            self._recorder.record(topic, msg, int(round(self._sim.k * self._dt * 1e9)))

    def _apply_command(self, volts, topic):
        check = self._sim.set_input(volts)
        if not check.accepted:
            self._refuse(f'{topic}: {check.reason}; holding {self._sim.u.tolist()} V')
        elif check.clamped:
            self.clamped_commands += 1
            self.get_logger().warning(f'{topic}: {check.reason}', throttle_duration_sec=1.0)

    def _refuse(self, reason):
        self.refused_commands += 1
        self.get_logger().warning(f'command refused: {reason}', throttle_duration_sec=1.0)

    # -- services -------------------------------------------------------------------------
    def _srv_pause(self, request, response):
        self.paused = bool(request.data)
        self._run_timer(not self.paused)
        response.success = True
        response.message = f"{'paused' if self.paused else 'running'} at t = {self._sim.t:.6g} s"
        return response

    def _srv_step(self, request, response):
        if not self.paused:
            response.success, response.message = False, 'not paused: call ~/pause first'
        elif self._sim.fault:
            response.success, response.message = False, f'fault: {self._sim.fault}'
        else:
            response.success = self._advance()
            response.message = (f't = {self._sim.t:.6g} s' if response.success
                                else f'fault: {self._sim.fault}')
        return response

    def _srv_reset(self, request, response):
        self._sim.reset()
        if self._recorder is not None:
            self._recorder.new_file()  # sim time restarts: one file per continuous run
        self._fault_reported = ''
        self._run_timer(not self.paused)
        self._publish_sample(self._current_outputs())
        response.success, response.message = True, 'reset to t = 0, initial state, 0 V'
        return response

    # -- parameters -----------------------------------------------------------------------
    def _validate_parameters(self, params):
        for param in params:
            value = param.value
            if param.name == 'real_time_factor' and not (
                    isinstance(value, float) and math.isfinite(value) and value > 0.0):
                return SetParametersResult(successful=False,
                                           reason=f'real_time_factor must be > 0 (got {value!r})')
            if param.name in ('steps_per_tick', 'max_catchup_steps') and not (
                    isinstance(value, int) and value >= 1):
                return SetParametersResult(successful=False,
                                           reason=f'{param.name} must be >= 1 (got {value!r})')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params):
        self._steps_per_tick = self._p('steps_per_tick')
        self._max_catchup = self._p('max_catchup_steps')
        if any(p.name == 'real_time_factor' for p in params):
            self._rtf = self._p('real_time_factor')
            if self._timer is not None:
                self._make_timer()

    # -- reporting ------------------------------------------------------------------------
    def _window_rate(self, window):
        now = time.perf_counter()
        wall, steps = now - window[0], self.steps_total - window[1]
        rate = steps / wall if wall > 0 else 0.0
        return rate, (now, self.steps_total)

    def _publish_diagnostics(self):
        rate, self._diag_window = self._window_rate(self._diag_window)
        self.achieved_rtf = rate * self._dt
        backlog = 0
        if self._p('real_time') and not self.paused and not self._sim.fault:
            elapsed = time.perf_counter() - self._wall0
            backlog = max(0, self._k0 + int(elapsed * self._rtf / self._dt) - self._sim.k - 1)
        status = DiagnosticStatus(name=f'{self.get_name()}: simulation', hardware_id='det_sim_ros')
        if self._sim.fault:
            status.level, status.message = DiagnosticStatus.ERROR, f'fault: {self._sim.fault}'
        elif backlog > 0:
            status.level, status.message = DiagnosticStatus.WARN, f'behind by {backlog} steps'
        else:
            status.level = DiagnosticStatus.OK
            status.message = 'paused' if self.paused else 'running'
        residual = self._sim.power_residual() if not self._sim.fault else math.nan
        values = {
            'sim_time_s': f'{self._sim.t:.6f}',
            'mode': 'real_time' if self._p('real_time') else 'free_run',
            'paused': str(self.paused).lower(),
            'step_rate_hz': f'{rate:.1f}',
            'real_time_factor': f'{self.achieved_rtf:.3f}',
            'overruns': str(self.overruns),
            'backlog_steps': str(backlog),
            'refused_commands': str(self.refused_commands),
            'clamped_commands': str(self.clamped_commands),
            'power_residual': f'{residual:.3e}',
            'voltage_V': str(self._sim.u.tolist()),
            'fault': self._sim.fault,
        }
        recorder = self._recorder
        if recorder is not None:
            values.update({'log_file': recorder.path, 'log_messages': str(recorder.messages),
                           'log_fault': recorder.fault})
            if recorder.fault and status.level == DiagnosticStatus.OK:
                status.level, status.message = DiagnosticStatus.WARN, recorder.fault
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)

    def _log_info(self):
        rate, self._info_window = self._window_rate(self._info_window)
        out = self._sim.outputs()
        state = 'FAULT' if self._sim.fault else ('paused' if self.paused else 'running')
        self.get_logger().info(
            f't={self._sim.t:.3f} s v={self._sim.u.tolist()} V q={out["q"] * 1e3:.3f} mm '
            f'dy={(self.y0 - out["y"]) * 1e3:.3f} mm RTF={rate * self._dt:.2f} {state}')


def main(args=None):
    """Run the simulator node until Ctrl-C; exit 1 with one line for a malformed scene."""
    rclpy.init(args=args)
    node = None
    try:
        node = SimNode()
        rclpy.spin(node)
    except SceneError as exc:
        rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {exc}')
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
