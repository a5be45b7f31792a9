"""
ROS 2 node: voltage commands in, the actuator's state out, on a fixed sim-time grid t = k dt.

The node only does I/O: all physics is in :class:`det_sim_ros.simulator.Simulator`.
Topic, parameter and service contract: see README.md.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import sys
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger

from .model import ModelDomainError
from .scene import load_scene, scene_to_dict, SceneError
from .simulator import Simulator

__all__ = ['SimNode', 'main', 'OUTPUT_TOPICS', 'STRUCTURE_TOPIC', 'rest_shortenings',
           'structure_channels']

NODE_NAME = 'sim_node'
SCENE_SECTIONS = ('scene', 'physics', 'integrator', 'structure', 'dets')
# topic: (per-DET model output, unit); one value per DET in voltage-command order (the names in
# scene structure.dets); displacement is y0_i - y_i, computed here
OUTPUT_TOPICS = {
    'deflection': ('q', 'm'),
    'displacement': ('y', 'm'),
    'charge': ('q_p', 'C'),
    'current': ('i_DE', 'A'),
}
# Topic of the structure outputs (only for a structure that has them: the plate). Published
# relative to rest (0 V) and in the displacement's sign: value = sign * (output - output at rest).
# model structure output -> (published name, sign)
STRUCTURE_TOPIC = 'structure'
STRUCTURE_NAMES = {
    'plate_y': ('plate_dy', -1.0),     # m: y0_plate - plate_y = mean of the two displacements
    'plate_phi': ('plate_phi', 1.0),   # rad: phi - phi0 = (dy_right - dy_left) / w
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
    'log.split_mb': (256.0, 'start a new log file after this many MiB (0 = one file per run '
                     'and reset; then log.max_mb cannot cut a long run)', True, (0.0, 1.0e6)),
    'log.max_mb': (2048.0, "keep the log directory's det_sim_*.mcap files under this many MiB "
                   'in all, oldest deleted first (0 = no limit)', True, (0.0, 1.0e9)),
    'log.max_files': (100, "keep at most this many det_sim_*.mcap files in the log directory, "
                      'oldest deleted first (0 = no limit)', True, (0, 1000000)),
    'info_period': (5.0, 'seconds between INFO status lines (wall clock), 0 = off', True,
                    (0.0, 3600.0)),
}


def _rest_shortening(scene) -> float:
    """
    End shortening y0 (m) of the stable buckled equilibrium at 0 V (a single-cell scene).

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


def rest_shortenings(scene) -> list:
    """
    Rest shortening y0_i (m) of each cell in DET order: cell i alone at 0 V
    (``scene.cell_scene(i)``). Cells with identical physics share one statics solve, so an array
    of identical copies costs one solve; an array with spread costs one per copy (about 20 ms).
    """
    cells = scene.cell_physics()
    template = scene.cell_scene(0)
    solved = {}
    for physics in cells:
        if physics not in solved:
            solved[physics] = _rest_shortening(dataclasses.replace(template, physics=physics))
    return [solved[physics] for physics in cells]


def structure_channels(model, y0) -> tuple:
    """
    The structure topic's contract for a model: (output indices, published names, signs, rest
    values). Empty for structures without outputs ('single', 'array').

    The structure outputs are linear in the cells' end shortenings (Model.structure_map P), so
    their rest values are P @ y0.
    """
    names = tuple(model.structure_output_names)
    if not names:
        return (), (), (), ()
    P = np.asarray(model.structure_map, dtype=float)
    rest = P @ np.asarray(y0, dtype=float)
    indices = tuple(model.output_names.index(name) for name in names)
    published = tuple(STRUCTURE_NAMES.get(name, (name, 1.0))[0] for name in names)
    signs = tuple(STRUCTURE_NAMES.get(name, (name, 1.0))[1] for name in names)
    return indices, published, signs, tuple(float(r) for r in rest)


def _name_list(names, limit=6) -> str:
    names = list(names)
    if len(names) <= limit:
        return ', '.join(names)
    return ', '.join(names[:limit]) + f', ... ({len(names)} channels)'


def _flatten(data, prefix=''):
    for key, value in data.items():
        if isinstance(value, dict):
            yield from _flatten(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def _check_node_value(name, value, where='scene key node.'):
    """A node parameter's value checked against its type and range (an integer is accepted
    for a double); :class:`SceneError` naming the key otherwise."""
    default, bounds = NODE_PARAMS[name][0], NODE_PARAMS[name][3]
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    kind = {bool: 'true or false', int: 'an integer', str: 'a string',
            float: 'a number'}[type(default)]
    if not ok:
        raise SceneError(f"{where}{name}: must be {kind} (got {value!r})")
    if bounds is not None and not (math.isfinite(value) and bounds[0] <= value <= bounds[1]):
        raise SceneError(f'{where}{name}: out of range [{bounds[0]:g}, {bounds[1]:g}] '
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
        if 'scene_file' in overrides and not isinstance(overrides['scene_file'].value, str):
            raise SceneError(f"parameter scene_file: must be a string (a name in config/ or a "
                             f"path; got {overrides['scene_file'].value!r})")
        scene_file = self.declare_parameter('scene_file', 'default', ParameterDescriptor(
            description='scene file: a name in config/ or a path', read_only=True)).value
        scene_overrides = {name: p.value for name, p in overrides.items()
                           if name.split('.')[0] in SCENE_SECTIONS or name == 'rate_hz'}
        self.scene = load_scene(scene_file, overrides=scene_overrides)
        if self.scene.method != 'auto':      # checked here, before the (long) preparation
            from .integrators import get_method
            try:
                get_method(self.scene.method)
            except ValueError as exc:
                raise SceneError(f"scene key 'integrator.method': {exc}") from None
        self._declare_scene_parameters()
        self._declare_node_parameters(overrides)

        self.get_logger().info(f'preparing scene {scene_file!r} (the first start after an install '
                               'compiles the model kernels: up to a minute)')
        self._sim = Simulator(self.scene)
        self._dt = self._sim.dt
        model = self._sim.model
        self.det_names = list(model.input_names)   # voltage-command and output channel order
        self._det_index = {name: i for i, name in enumerate(self.det_names)}
        self._channels = {topic: model.channel(out) for topic, (out, _) in OUTPUT_TOPICS.items()}
        self._qdot = model.channel('q_dot')
        self._initial_text = (f'rest ({self.scene.rest_branch}, 0 V)'
                              if self.scene.initial_state == 'rest' else 'released from q0')
        self.y0 = rest_shortenings(self.scene)     # per DET, m
        self._y0 = np.array(self.y0)
        (self._struct_idx, self.structure_names, signs,
         rest) = structure_channels(model, self.y0)
        self._struct_sign, self._struct_rest = np.array(signs), np.array(rest)
        self.last_refused = ''

        # counters (reported on /diagnostics)
        self.refused_commands = 0
        self.clamped_commands = 0
        self.commands_received = 0
        self.overruns = 0
        self.steps_total = 0
        self.lateness_log = None  # set to a list to record real-time tick lateness (bench)
        self._fault_reported = ''
        self._distrust_reported = ''

        # MCAP recording hook (issue 5): an object with record(topic, msg, sim_time_ns), or None.
        # Called for every published output and every received command.
        self._recorder = None

        out_qos = qos_profile_sensor_data if self._p('qos_sensor_data') else QoSProfile(depth=10)
        self._pubs = {topic: self.create_publisher(JointState, topic, out_qos)
                      for topic in OUTPUT_TOPICS}
        self._msgs = {topic: JointState(name=list(self.det_names)) for topic in OUTPUT_TOPICS}
        if self.structure_names:
            self._pubs[STRUCTURE_TOPIC] = self.create_publisher(JointState, STRUCTURE_TOPIC,
                                                                out_qos)
            self._msgs[STRUCTURE_TOPIC] = JointState(name=list(self.structure_names))
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
            f'{self.scene.rate_hz:g} Hz, {self._sim.describe_stepper()}; '
            f'{mode}{", paused" if self.paused else ""}; initial state {self._initial_text}; '
            f'{len(self.det_names)} DET(s), '
            f'voltage command order: [{", ".join(self.det_names)}]'
            + (f'; structure outputs [{", ".join(self.structure_names)}]'
               if self.structure_names else ''))

    # -- set-up ---------------------------------------------------------------------------
    def _start_recorder(self, out_qos):
        """MCAP logging (det_sim_ros.mcap_log): on unless log.enabled is false."""
        if not self._p('log.enabled'):
            return
        from .mcap_log import Recorder, recover_unfinished
        path = self._p('log.path')
        if not path.endswith('.mcap') and os.path.isdir(path):
            # a log cut by a crash (power loss, SIGKILL inside a flush): repaired at this start
            for repaired, outcome in recover_unfinished(path):
                self.get_logger().warning(f'recovered unfinished log {repaired}: '
                                          f"{outcome['messages']} messages readable")
        qos = {topic: out_qos for topic in self._pubs}
        qos.update({'voltage_command': QoSProfile(depth=10),
                    'voltage_command_joint': QoSProfile(depth=10)})
        self._recorder = Recorder(
            path, self.scene, qos_by_topic=qos, split_mb=self._p('log.split_mb'),
            max_total_mb=self._p('log.max_mb'), max_files=self._p('log.max_files'),
            namespace=self.get_namespace(),
            metadata={'method': self._sim.method.name, 'substeps': self._sim.substeps_setting,
                      'y0': repr(self.y0[0]) if len(self.y0) == 1 else repr(self.y0),
                      'initial_state': self._initial_text,
                      'x0': repr(self._sim.x0.tolist()),   # what ~/reset returns to
                      'node': self.get_fully_qualified_name()},
            on_fault=lambda text: self.get_logger().error(text))
        if self._recorder.active:
            split, max_mb, max_files = (self._p('log.split_mb'), self._p('log.max_mb'),
                                        self._p('log.max_files'))
            self.get_logger().info(
                f'logging to {self._recorder.path} (a new file at every ~/reset'
                + (f' and after {split:g} MiB' if split else '') + '; log directory limit: '
                + (f'{max_mb:g} MiB' if max_mb else 'no size limit') + ', '
                + (f'{max_files} files' if max_files else 'no file limit')
                + ', oldest deleted first)')
            if self._recorder.deleted:
                self.get_logger().info(f'log limit: deleted {len(self._recorder.deleted)} '
                                       'old log file(s)')
            self.create_timer(self._recorder.flush_period_s, self._recorder.maybe_flush,
                              clock=self._steady)

    def destroy_node(self):
        """Finish the MCAP log (indexed and complete), then destroy the node."""
        if self._recorder is not None:
            self._recorder.close()
        return super().destroy_node()

    def _set_override(self, name, value):
        """Replace a -p override by its checked value: rclpy refuses an override whose type
        differs from the declared one (an integer given for a double, e.g. physics.Rs:=1)."""
        if name in self._parameter_overrides:
            self._parameter_overrides[name] = Parameter(name, value=value)

    def _declare_scene_parameters(self):
        """Expose the loaded scene as read-only parameters (set them in the scene file)."""
        for name, value in _flatten(scene_to_dict(self.scene)):
            if name.startswith('node.'):
                continue
            self._set_override(name, value)   # the scene's checked value (e.g. 1 -> 1.0)
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
            if name in overrides:          # -p name:=value wins over the scene file
                value = _check_node_value(name, overrides[name].value, 'parameter ')
                self._set_override(name, value)
            else:
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
            if topic == 'displacement':
                values = (self._y0 - out[indices]).tolist()
            else:
                values = out[indices].tolist()
                if topic == 'deflection':
                    msg.velocity = out[self._qdot].tolist()
            msg.position = values
            self._pubs[topic].publish(msg)
            if self._recorder is not None:
                self._recorder.record(topic, msg, t_ns)
        if self.structure_names:
            msg = self._msgs[STRUCTURE_TOPIC]
            msg.header.stamp = stamp
            msg.position = (self._struct_sign * (out[list(self._struct_idx)]
                                                 - self._struct_rest)).tolist()
            self._pubs[STRUCTURE_TOPIC].publish(msg)
            if self._recorder is not None:
                self._recorder.record(STRUCTURE_TOPIC, msg, t_ns)
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
        if not names:
            return self._refuse('voltage_command_joint: empty JointState (no DET name); name '
                                f'one or more of {self.det_names}')
        unknown = [name for name in names if name not in self._det_index]
        if unknown:
            return self._refuse(f'voltage_command_joint: unknown DET name(s) {unknown} '
                                f'(expected {self.det_names})')
        repeated = sorted({name for name in names if names.count(name) > 1})
        if repeated:
            return self._refuse(f'voltage_command_joint: DET name(s) {repeated} given more '
                                'than once; name each DET at most once')
        volts = self._sim.u.tolist()
        for name, value in zip(names, values):
            volts[self._det_index[name]] = value
        self._apply_command(volts, 'voltage_command_joint')

    def _record_command(self, topic, msg):
        self.commands_received += 1
        if self._recorder is not None:
            self._recorder.record(topic, msg, int(round(self._sim.k * self._dt * 1e9)))

    def _apply_command(self, volts, topic):
        """Hold a full voltage vector (DET order); the checks are the simulator's, named here."""
        check = self._sim.set_input(volts)
        if not check.accepted:
            reason = check.reason
            if len(volts) != len(self.det_names):
                reason = (f'expected {len(self.det_names)} voltage(s) '
                          f'[{_name_list(self.det_names)}], got {len(volts)}')
            else:
                bad = [name for name, v in zip(self.det_names, volts)
                       if not (isinstance(v, (int, float)) and math.isfinite(v))]
                if bad:
                    reason = f'non-finite voltage on {_name_list(bad)}'
            self._refuse(f'{topic}: {reason}; holding the previous voltages')
        elif check.clamped:
            self.clamped_commands += 1
            v_max = self.scene.physics.v_max
            named = [f'{name} {v:g} V' for name, v in zip(self.det_names, volts)
                     if not 0.0 <= v <= v_max]
            self.get_logger().warning(f'{topic}: voltage clamped to [0, {v_max:g}] V on '
                                      f'{_name_list(named)}', throttle_duration_sec=1.0)

    def _refuse(self, reason):
        self.refused_commands += 1
        self.last_refused = reason
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
            if self._recorder.active:
                self.get_logger().info(f'reset: the log continues in {self._recorder.path}')
        self._fault_reported = ''
        self._run_timer(not self.paused)
        self._publish_sample(self._current_outputs())
        response.success = True
        response.message = f'reset to t = 0, initial state {self._initial_text}, 0 V'
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
        distrust = self._sim.trust_issue()
        if distrust and distrust != self._distrust_reported:
            self.get_logger().warning(distrust)          # once per cause, until a reset
        self._distrust_reported = distrust
        if self._sim.fault:
            status.level, status.message = DiagnosticStatus.ERROR, f'fault: {self._sim.fault}'
        elif distrust:
            status.level, status.message = DiagnosticStatus.WARN, distrust
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
            'last_refused': self.last_refused,
            'clamped_commands': str(self.clamped_commands),
            'power_residual': f'{residual:.3e}',
            'voltage_V': str(self._sim.u.tolist()),
            'fault': self._sim.fault,
            'stepper': self._sim.describe_stepper(),      # adaptive: the current step count
            'internal_steps': str(self._sim.steps_taken),
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
        out = self._current_outputs()
        state = 'FAULT' if self._sim.fault else ('paused' if self.paused else 'running')
        q = out[self._channels['deflection']] * 1e3
        dy = (self._y0 - out[self._channels['displacement']]) * 1e3

        def mm(values):
            if len(values) == 1:
                return f'{values[0]:.3f}'
            if len(values) <= 4:
                return '[' + ', '.join(f'{v:.3f}' for v in values) + ']'
            return f'{values.min():.3f}..{values.max():.3f}'

        volts = self._sim.u
        v = volts.tolist() if len(volts) <= 4 else f'{volts.min():g}..{volts.max():g}'
        self.get_logger().info(
            f't={self._sim.t:.3f} s v={v} V q={mm(q)} mm dy={mm(dy)} mm '
            f'RTF={rate * self._dt:.2f} {state}')


class _StopRequested(BaseException):
    """SIGINT/SIGTERM during start-up: unwinds the preparation (nothing to finish yet)."""


class _StopSignals:
    """
    SIGINT and SIGTERM end the node cleanly at any moment, exit code 0 and a finished log.

    rclpy's own handlers shut the context down from inside the signal handler, while a
    stepping-timer callback may be publishing: that callback then fails (``RCLError:
    publisher's context is invalid``, ``failed to initialize wait set``) and the node exits with
    a traceback. Here the handlers only take note: during start-up (scene, model, first compile)
    they unwind it at once; once running, the spin loop stops between two callbacks (so no
    callback and no log write is ever cut in half), then the log is finished and the context
    shut down, in that order.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.requested = 0            # the signal number once a stop was asked for
        self.preparing = True
        self._previous = {}

    def __enter__(self):
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum, frame):
        self.requested = signum
        if self.preparing:
            self.preparing = False
            raise _StopRequested()


def _spin_until_stopped(node, stop) -> None:
    """Run the node's callbacks until a stop signal (checked at least every 0.1 s)."""
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while not stop.requested and node.context.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=0.0)


def main(args=None):
    """
    Run the simulator node until SIGINT or SIGTERM (exit 0, log finished); exit 1 with one
    line for a start-up input that cannot be used (scene, parameter, initial state).
    """
    from rclpy.signals import SignalHandlerOptions
    node = None
    code = 0
    with _StopSignals() as stop:
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            node = SimNode()
            stop.preparing = False
            if not stop.requested:
                _spin_until_stopped(node, stop)
        except _StopRequested:
            pass
        except (SceneError, ParameterException, ModelDomainError, RCLError) as exc:
            stop.preparing = False       # one line, exit 1: an input that cannot be used
            text = ' '.join(str(exc).split()) or type(exc).__name__
            rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {text}')
            code = 1
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception:
            if not stop.requested:
                raise
            # a stop during the preparation that a library turned into its own error (e.g. a
            # C extension's initialisation): still a stop
        finally:
            stop.preparing = False
            if node is not None:
                node.destroy_node()          # finishes and indexes the MCAP log
            rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
