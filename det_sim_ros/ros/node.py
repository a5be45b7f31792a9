"""
ROS 2 node: voltage commands in, the actuator's state out, on a fixed sim-time grid t = k dt.

The node only does I/O: all physics is in :class:`det_sim_ros.sim.simulator.Simulator`.
Topic, parameter and service contract: see README.md.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import time

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
from rclpy.qos import HistoryPolicy, qos_profile_sensor_data, QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger

from ..io.contract import (clamp_message, CLOCK_TOPIC, COMMAND_TOPIC, CommandDecoder, DIAGNOSTICS_TOPIC,
                       encode_clock, JOINT_COMMAND_TOPIC, MODES, OUTPUT_FIELDS, OutputContract,
                       rest_shortening, rest_shortenings, STRUCTURE_TOPIC, stamp_ns,
                       structure_channels, TOPIC_TYPES)
from .markers import attach_markers
from ..physics.model import ModelDomainError
from ..scenes.scene import load_scene, scene_to_dict, SceneError
from .params import check_node_value, flatten, NODE_PARAMS, SCENE_SECTIONS
from ..sim.simulator import Simulator

__all__ = ['SimNode', 'main', 'OUTPUT_TOPICS', 'STRUCTURE_TOPIC', 'rest_shortenings',
           'structure_channels', 'make_executor', 'spin']

NODE_NAME = 'sim_node'
# The topic contract (names, types, channels, y0, the bytes on the wire) is det_sim_ros.io.contract.
OUTPUT_TOPICS = {topic: mapping['position'] for topic, mapping in OUTPUT_FIELDS.items()}
_rest_shortening = rest_shortening   # y0 of one cell (kept for callers of the old name)


class SimNode(Node):
    """
    The simulator as a ROS 2 node (see README.md for the topic contract).

    Per control period the node takes the commands that have arrived, steps the simulator,
    writes the CDR bytes of every output straight from the output vector
    (:class:`~det_sim_ros.io.contract.SampleEncoder`), publishes those bytes and hands the same
    bytes to the MCAP recorder. No message objects are built on that path.

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
            from ..sim.integrators import get_method
            try:
                get_method(self.scene.method)
            except ValueError as exc:
                raise SceneError(f"scene key 'integrator.method': {exc}") from None
        self._declare_scene_parameters()
        self._declare_node_parameters(overrides)
        self.mode = self._p('mode') or ('real_time' if self._p('real_time') else 'free_run')
        if self.mode not in MODES:
            raise SceneError(f"parameter 'mode': one of {', '.join(MODES)} (got {self.mode!r})")

        started = time.perf_counter()
        self._sim = Simulator(self.scene, threads=self._p('threads'))
        self._dt = self._sim.dt
        model = self._sim.model
        self.det_names = list(model.input_names)   # voltage-command and output channel order
        self._initial_text = (f'rest ({self.scene.rest_branch}, 0 V)'
                              if self.scene.initial_state == 'rest' else 'released from q0')
        self.y0 = rest_shortenings(self.scene)     # per DET, m
        # nothing is compiled at run time (the kernel is built at install): this is the model's
        # Ritz integrals, its stepper and the rest state's statics solve
        self.get_logger().info(f'scene {scene_file!r} prepared in '
                               f'{time.perf_counter() - started:.2f} s (model, stepper, rest state)')
        self.contract = OutputContract(model, self.y0)
        self.structure_names = self.contract.structure_names
        self._encoder = self.contract.encoder()
        self._topics = tuple(self._encoder.topics)
        self._decoder = CommandDecoder(self.det_names, self.scene.physics.v_max)
        self.last_refused = ''

        # counters (reported on /diagnostics)
        self.refused_commands = 0
        self.clamped_commands = 0
        self.commands_received = 0
        self.steps_total = 0
        self.late_ticks = 0      # real-time ticks that found more than one period due
        self.slipped_s = 0.0     # wall time dropped because the lag exceeded max_lag, s
        # lockstep: answers to the latest sample, deadlines missed, wall time spent waiting
        self.answers = 0
        self.stale_answers = 0   # JointState commands stamped with an older sample
        self.missed_deadlines = 0
        self._missed_seen = 0    # missed deadlines at the last /diagnostics
        self.lockstep_wait_s = 0.0
        self._published_wall = time.perf_counter()
        self._stepping = False
        self._last_sample = ()          # the bytes of sample 0 (lockstep re-send)
        self._heard_by = 0              # subscriptions matched when sample 0 was published
        self._fault_reported = ''
        self._distrust_reported = ''
        # test and benchmark seams: the wall clock of the real-time pacing, and a function
        # called with (k, output vector) after sample k has been published (free run: once it
        # is computed; the tick's samples are published together at the tick's end)
        self.wall_clock = time.perf_counter
        self.on_sample = None

        # MCAP recording (issue 5): a Recorder fed the published bytes, or None
        self._recorder = None

        if self._p('qos_sensor_data') and self._p('qos_keep_all'):
            raise SceneError('parameters qos_sensor_data and qos_keep_all: choose one')
        keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL)
        in_qos = keep_all if self._p('qos_keep_all') else QoSProfile(depth=10)
        out_qos = qos_profile_sensor_data if self._p('qos_sensor_data') else in_qos
        self._output_pubs = [self.create_publisher(JointState, topic, out_qos)
                             for topic in self._encoder.topics]
        # Publisher.publish(bytes) is handle.publish_raw(bytes) behind a type check and a
        # destroy guard (~2.5 us per call); the node publishes through the handle directly
        self._publish_raw = [pub.handle.publish_raw for pub in self._output_pubs]
        self._clock_pub = (None if self.mode == 'real_time'
                           else self.create_publisher(ClockMsg, CLOCK_TOPIC, in_qos))
        self._publish_clock = self._clock_pub.handle.publish_raw if self._clock_pub else None
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._markers = attach_markers(self, model, self._p('markers.rate_hz'),
                                       self._p('markers.frame_id'), out_qos)
        # commands arrive as CDR bytes (raw): decoded and checked by the contract, and logged
        # re-encoded with zero padding (equal commands give equal logs)
        self._command_subs = [
            (topic, self.create_subscription(
                msg_type, topic, lambda data, topic=topic: self._on_command(topic, data), in_qos,
                raw=True))
            for topic, msg_type in ((COMMAND_TOPIC, Float64MultiArray),
                                    (JOINT_COMMAND_TOPIC, JointState))]
        self.create_service(SetBool, '~/pause', self._srv_pause)
        self.create_service(Trigger, '~/step', self._srv_step)
        self.create_service(Trigger, '~/reset', self._srv_reset)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self.realtime_scheduling = False   # SCHED_FIFO in force (realtime_priority)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.paused = bool(self._p('start_paused'))
        self._timer = None
        self._make_timer()
        self._diag_window = self._window_start()
        self._info_window = self._window_start()
        self.achieved_rtf = 0.0
        self._max_lag_seen = 0       # most steps behind since the last /diagnostics
        self.create_timer(self._p('diagnostics_period'), self._publish_diagnostics,
                          clock=self._steady)
        if self._p('info_period') > 0:
            self.create_timer(self._p('info_period'), self._log_info, clock=self._steady)
        self._start_recorder(out_qos, in_qos)
        if self._p('realtime_priority'):   # last: every thread of the node exists by now
            self._apply_realtime_priority(self._p('realtime_priority'))
        if self.mode == 'lockstep':
            self.create_timer(0.05, self._lockstep_resend, clock=self._steady)
        self._publish_sample(self._current_outputs())
        mode = ('real-time x%g' % self._rtf if self.mode == 'real_time' else
                self.mode.replace('_', '-'))
        self.get_logger().info(
            f'scene {scene_file!r}: {self.scene.beam} beam, eps_b = {self.scene.eps_b:g}, '
            f'{self.scene.rate_hz:g} Hz, {self._sim.describe_stepper()}; '
            f'{mode}{", paused" if self.paused else ""}; initial state {self._initial_text}; '
            f'{len(self.det_names)} DET(s), '
            f'voltage command order: [{", ".join(self.det_names)}]'
            + (f'; structure outputs [{", ".join(self.structure_names)}]'
               if self.structure_names else ''))

    # -- set-up ---------------------------------------------------------------------------
    def _start_recorder(self, out_qos, in_qos):
        """MCAP logging (det_sim_ros.io.mcap_log): on unless log.enabled is false."""
        if not self._p('log.enabled'):
            return
        from ..io.mcap_log import Recorder, recover_unfinished
        path = self._p('log.path')
        if not path.endswith('.mcap') and os.path.isdir(path):
            # a log cut by a crash (power loss, SIGKILL inside a flush): repaired at this start
            for repaired, outcome in recover_unfinished(path):
                self.get_logger().warning(f'recovered unfinished log {repaired}: '
                                          f"{outcome['messages']} messages readable")
        qos = {topic: out_qos for topic in self._encoder.topics}
        qos.update({COMMAND_TOPIC: in_qos, JOINT_COMMAND_TOPIC: in_qos})
        self._recorder = Recorder(
            path, self.scene, qos_by_topic=qos, split_mb=self._p('log.split_mb'),
            max_total_mb=self._p('log.max_mb'), max_files=self._p('log.max_files'),
            compression=self._p('log.compression'),
            namespace=self.get_namespace(), background=True,
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
            # (no flush timer here: the recorder's writer thread owns the writer and flushes)

    def _apply_realtime_priority(self, priority):
        """SCHED_FIFO for every thread of this process (the executor's, DDS's, the log
        writer's; threads started later inherit it). Real-time mode only: a free-running or
        lockstep node at FIFO would hold a core. Without permission: one warning, no change."""
        if self.mode != 'real_time':
            self.get_logger().warning(f'realtime_priority: only in real_time mode (mode is '
                                      f'{self.mode}); scheduling unchanged')
            return
        changed, refused = 0, ''
        for tid in sorted(int(t) for t in os.listdir('/proc/self/task')):
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
                changed += 1
            except ProcessLookupError:   # a thread that has just ended
                continue
            except (PermissionError, OSError) as exc:
                refused = exc.strerror or str(exc)
                break
        if refused:
            for tid in (int(t) for t in os.listdir('/proc/self/task')):   # all or nothing
                try:
                    os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                except OSError:
                    pass
            self.get_logger().warning(
                f'realtime_priority {priority}: SCHED_FIFO refused ({refused}); running with '
                'normal scheduling (grant CAP_SYS_NICE, or an rtprio limit in '
                '/etc/security/limits.conf)')
        else:
            self.get_logger().info(f'SCHED_FIFO priority {priority} for {changed} thread(s)')
        self.realtime_scheduling = not refused

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
        for name, value in flatten(scene_to_dict(self.scene)):
            if name.startswith('node.'):
                continue
            self._set_override(name, value)   # the scene's checked value (e.g. 1 -> 1.0)
            self.declare_parameter(name, value, ParameterDescriptor(
                description='scene value (read-only; set in the scene file or with -p at start)',
                read_only=True))

    def _declare_node_parameters(self, overrides):
        node_section = dict(flatten(self.scene.node))  # node: {log: {enabled: ...}} too
        for name, param in overrides.items():
            if name.startswith('node.'):
                node_section[name[5:]] = param.value
        unknown = sorted(set(node_section) - set(NODE_PARAMS))
        if unknown:
            raise SceneError(f"scene key 'node.{unknown[0]}': unknown (allowed: "
                             + ', '.join(NODE_PARAMS) + ')')
        for name, (default, description, read_only, bounds) in NODE_PARAMS.items():
            if name in overrides:          # -p name:=value wins over the scene file
                value = check_node_value(name, overrides[name].value, 'parameter ')
                self._set_override(name, value)
            else:
                value = check_node_value(name, node_section.get(name, default))
            descriptor = ParameterDescriptor(description=description, read_only=read_only)
            if bounds is not None and isinstance(default, float):
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(bounds[0]), to_value=float(bounds[1]), step=0.0)]
            elif bounds is not None and isinstance(default, int):
                descriptor.integer_range = [IntegerRange(
                    from_value=bounds[0], to_value=bounds[1], step=1)]
            self.declare_parameter(name, value, descriptor)
        self._rtf = self._p('real_time_factor')
        self._steps_per_tick = self._p('steps_per_tick')
        self._max_catchup = self._p('max_catchup_steps')
        self._max_lag = self._p('max_lag')
        self._sources = self._p('lockstep.sources')
        self._timeout = self._p('lockstep.timeout')

    def _p(self, name):
        return self.get_parameter(name).value

    def _make_timer(self):
        if self._timer is not None:
            self.destroy_timer(self._timer)
        self._resync()
        stopped = self.paused or bool(self._sim.fault)
        if self.mode == 'real_time':
            period, callback = self._dt / self._rtf, self._tick_real_time
        elif self.mode == 'free_run':
            period, callback = 1.0e-6, self._tick_free_run
        else:   # lockstep: commands drive the stepping; the timer is only the deadline
            period, callback = self._timeout or 3600.0, self._lockstep_deadline
            stopped = stopped or not self._timeout
        self._timer = self.create_timer(period, callback, clock=self._steady,
                                        autostart=not stopped)

    def _resync(self):
        """Restart the wall-clock reference: no catch-up for time spent paused or reset."""
        self._wall0 = self.wall_clock()
        self._k0 = self._sim.k

    def _run_timer(self, run):
        if run and not self._sim.fault:
            self._resync()
            if self.mode != 'lockstep' or self._timeout:
                self._timer.reset()
            if self.mode == 'lockstep':
                self._lockstep_advance()   # the answers may have come while paused
        else:
            self._timer.cancel()

    # -- stepping -------------------------------------------------------------------------
    def _steps_due(self, now) -> int:
        """Control periods the wall clock is ahead of sim time (real-time mode)."""
        # + 1e-6: a period is due at its boundary despite round-off (0.003 / 0.001 < 3)
        return self._k0 + int((now - self._wall0) * self._rtf / self._dt + 1e-6) - self._sim.k

    def _tick_real_time(self):
        """
        Run the periods that are due by the wall clock. More than one due is a late tick; a
        lag beyond max_lag is dropped from the wall clock (a slip: sim time then runs below
        real time), never from the sim steps.
        """
        if self.paused or self._sim.fault:
            return
        due = self._steps_due(self.wall_clock())
        if due <= 0:
            return
        if due > 1:
            self.late_ticks += 1
        allowed = 1 + int(self._max_lag / self._dt + 1e-9)   # steps due at the largest lag
        if due > allowed:
            excess = due - allowed
            self._k0 -= excess            # the wall-clock reference moves: sim time slips
            self.slipped_s += excess * self._dt / self._rtf
            due = allowed
        self._max_lag_seen = max(self._max_lag_seen, due - 1)
        for _ in range(min(due, self._max_catchup)):
            if not self._advance():
                return

    def _tick_free_run(self):
        """
        Run steps_per_tick periods, then publish their samples back to back. DDS spends about
        half the CPU per message on a burst that it spends on the same messages ~0.1 ms apart
        (it wakes its own and the subscribers' threads per message then; measured on the
        2-core test host), and free run has no wall-clock deadline to keep. Commands are still
        taken before every period.
        """
        if self.paused or self._sim.fault:
            return
        batch = []
        try:
            for _ in range(self._steps_per_tick):
                if not self._advance(batch):
                    return
        finally:
            self._send(batch)

    def _lockstep_advance(self):
        """Lockstep: run the next period once every expected source has answered."""
        if self._stepping or self.paused or self._sim.fault or self.answers < self._sources:
            return
        self.lockstep_wait_s += time.perf_counter() - self._published_wall
        self._advance()

    def _lockstep_deadline(self):
        """Lockstep timeout: the answers did not come; hold the voltages and go on."""
        if self.paused or self._sim.fault:
            return
        self.missed_deadlines += 1
        self.get_logger().warning(
            f'lockstep: {self.answers} of {self._sources} answer(s) to t = {self._sim.t:.6g} s '
            f'within {self._timeout:g} s; holding the voltages ({self.missed_deadlines} missed)',
            throttle_duration_sec=1.0)
        self.lockstep_wait_s += time.perf_counter() - self._published_wall
        self._advance()

    def _subscriptions_matched(self):
        return sum(pub.get_subscription_count() for pub in self._output_pubs)

    def _lockstep_resend(self):
        """
        Lockstep start (t = 0, also after ~/reset): a controller discovered after sample 0 was
        published never saw it, and both would wait forever. Re-send sample 0 (not logged)
        when new subscriptions have matched since, until it is answered.
        """
        if self._sim.k != 0 or self.answers >= self._sources or not self._last_sample:
            return
        matched = self._subscriptions_matched()
        if matched > self._heard_by:
            self._heard_by = matched
            if self._publish_clock is not None:
                self._publish_clock(encode_clock(0))
            for publish, data in zip(self._publish_raw, self._last_sample):
                publish(data)

    def _current_outputs(self):
        return np.array(list(self._sim.outputs().values()))

    def _take_commands(self):
        """
        Apply the commands that have arrived since the last period, also in a catch-up burst
        or a free-run tick (the executor would deliver them only after the whole tick).
        """
        for topic, sub in self._command_subs:
            while True:
                taken = sub.handle.take_message(sub.msg_type, True)
                if taken is None:
                    break
                self._on_command(topic, taken[0])

    def _advance(self, batch=None) -> bool:
        """Run one control period and publish it (or add its messages to ``batch``, see
        :meth:`_send`); False (and fault) if the model diverged."""
        self._stepping = True
        try:
            self._take_commands()
            try:
                out = self._sim.step()
            except ModelDomainError as exc:
                self._enter_fault(str(exc))
                return False
            self.steps_total += 1
            return self._publish_sample(out, batch)
        finally:
            self._stepping = False

    def _send(self, batch) -> bool:
        """Publish (t_ns, samples, marker frame or None) in order, /clock before each sample's
        outputs."""
        try:
            publish_clock, publishers = self._publish_clock, self._publish_raw
            for t_ns, samples, frame in batch:
                if publish_clock is not None:   # first: a use_sim_time reader is at t_k
                    publish_clock(encode_clock(t_ns))
                for publish, data in zip(publishers, samples):
                    publish(data)
                if frame is not None:
                    self._markers.publish(frame)
        except RuntimeError:   # rclpy's RCLError: Ctrl-C shut the context down mid-tick
            if self.context.ok():
                raise
            self._timer.cancel()
            return False
        return True

    def _publish_sample(self, out, batch=None) -> bool:
        """Publish sample k (or add it to ``batch``), log it, then the hooks and markers."""
        # (every output is finite here: the kernel refuses a period or an outputs() call with
        # a non-finite output, so Simulator.step and .outputs raise before anything is sent)
        k = self._sim.k
        t_ns = stamp_ns(k, self._dt)
        samples = self._encoder.encode(out, t_ns)
        if self.mode == 'lockstep':   # a new sample: wait for its answers
            self.answers = 0
            self._published_wall = time.perf_counter()
            if self._timeout and not self.paused:
                self._timer.reset()
            if k == 0:
                self._last_sample = samples
                self._heard_by = self._subscriptions_matched()
        recorder = self._recorder
        if recorder is not None:   # (the log's order: the sample, then its marker frame)
            recorder.record_sample(t_ns, self._topics, samples, TOPIC_TYPES)
        frame = None
        if self._markers is not None and not k % self._markers.every:
            frame = self._markers.frame_for(k, self._sim.x, self._sim.u, t_ns, recorder)
        if batch is not None:
            batch.append((t_ns, samples, frame))
        elif not self._send(((t_ns, samples, frame),)):
            return False
        if self.on_sample is not None:
            self.on_sample(k, out)
        return True

    def _enter_fault(self, reason):
        self._timer.cancel()
        if self._fault_reported != reason:
            self._fault_reported = reason
            self.get_logger().error(f'fault, integration stopped (call ~/reset): {reason}')
            self._publish_diagnostics()

    # -- commands -------------------------------------------------------------------------
    def _on_command(self, topic, data):
        """A command's CDR bytes: decode, check, log (at the period it applies to), hold."""
        self.commands_received += 1
        command = self._decoder.decode(topic, data, self._sim.u)
        if self._recorder is not None and command.canonical:
            self._recorder.record(topic, command.canonical, stamp_ns(self._sim.k, self._dt),
                                  TOPIC_TYPES[topic])
        if command.volts is None:
            self._refuse(command.reason + ('' if command.reason.startswith(
                JOINT_COMMAND_TOPIC + ':') else '; holding the previous voltages'))
        if command.volts is not None:
            check = self._sim.set_input(command.volts)
            if not check.accepted:   # the contract's checks are the simulator's; not expected
                self._refuse(f'{topic}: {check.reason}; holding the previous voltages')
            elif command.clamped:
                self.clamped_commands += 1
                self.get_logger().warning(
                    clamp_message(topic, command.clamped, self.scene.physics.v_max),
                    throttle_duration_sec=1.0)
        if self.mode == 'lockstep':
            self._count_answer(command)

    def _count_answer(self, command):
        """
        Lockstep: a JointState command answers the sample its header stamp names (an unset
        stamp, 0, the latest); a Float64MultiArray the latest sample. A refused command
        answers too (the voltages are held). Answers to older samples are applied but do not
        count.
        """
        k = self._sim.k
        if command.stamp_ns:
            answered = int(round(command.stamp_ns * 1e-9 / self._dt))
            if answered < k:
                self.stale_answers += 1
                return
        self.answers += 1
        self._lockstep_advance()

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
        self.answers = 0   # answers to the old run's last sample do not start the new one
        if self._recorder is not None:
            self._recorder.new_file()  # sim time restarts: one file per continuous run
            if self._recorder.active:
                self.get_logger().info(f'reset: the log continues in a new file after '
                                       f'{self._recorder.path}')
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
            if param.name == 'lockstep.timeout' and not (
                    isinstance(value, float) and math.isfinite(value) and value >= 0.0):
                return SetParametersResult(
                    successful=False, reason=f'lockstep.timeout must be >= 0 s (got {value!r})')
            if param.name == 'lockstep.sources' and not (isinstance(value, int) and value >= 1):
                return SetParametersResult(
                    successful=False, reason=f'lockstep.sources must be >= 1 (got {value!r})')
            if param.name == 'max_lag' and not (
                    isinstance(value, float) and math.isfinite(value) and value >= 0.0):
                return SetParametersResult(successful=False,
                                           reason=f'max_lag must be >= 0 s (got {value!r})')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params):
        self._steps_per_tick = self._p('steps_per_tick')
        self._max_catchup = self._p('max_catchup_steps')
        self._max_lag = self._p('max_lag')
        self._sources = self._p('lockstep.sources')
        if any(p.name == 'lockstep.timeout' for p in params):
            self._timeout = self._p('lockstep.timeout')
            if self._timer is not None and self.mode == 'lockstep':
                self._make_timer()
        if self.mode == 'lockstep':
            self._lockstep_advance()   # fewer sources may already have answered
        if any(p.name == 'real_time_factor' for p in params):
            self._rtf = self._p('real_time_factor')
            if self._timer is not None:
                self._make_timer()

    # -- reporting ------------------------------------------------------------------------
    def _window_start(self):
        return (time.perf_counter(), self.steps_total, self.late_ticks, self.slipped_s)

    def _window(self, window):
        """Step rate, late ticks and slipped wall time since ``window``; the next window."""
        now = self._window_start()
        wall = now[0] - window[0]
        rate = (now[1] - window[1]) / wall if wall > 0 else 0.0
        return rate, now[2] - window[2], now[3] - window[3], wall, now

    def _publish_diagnostics(self):
        rate, late, slipped, wall, self._diag_window = self._window(self._diag_window)
        self.achieved_rtf = rate * self._dt
        real_time = self.mode == 'real_time'
        running = not self.paused and not self._sim.fault
        lag = 0
        if real_time and running:
            lag = max(0, self._steps_due(self.wall_clock()) - 1)
        max_lag = max(lag, self._max_lag_seen)
        self._max_lag_seen = 0
        # the fully qualified name tells namespaced nodes apart (/arm1/sim_node: simulation)
        node_name = self.get_fully_qualified_name()
        status = DiagnosticStatus(name=f'{node_name}: simulation', hardware_id=node_name)
        distrust = self._sim.trust_issue()
        if distrust and not self._distrust_reported:
            # once, until it clears (a reset): the text changes every time (the residual and
            # the voltages), which had logged it every diagnostics period
            self.get_logger().warning(distrust)
        self._distrust_reported = distrust
        status.level, status.message = DiagnosticStatus.OK, 'paused' if self.paused else 'running'
        if self._sim.fault:
            status.level, status.message = DiagnosticStatus.ERROR, f'fault: {self._sim.fault}'
        elif distrust:
            status.level, status.message = DiagnosticStatus.WARN, distrust
        elif real_time and running and wall > 0 and slipped > 0.01 * wall:
            # a user-visible slowdown: more than 1 % of the window's wall time dropped
            status.level = DiagnosticStatus.WARN
            status.message = (f'below real time: RTF {self.achieved_rtf:.3f} of '
                              f'{self._rtf:g} (slipped {slipped * 1e3:.0f} ms in the last '
                              f'{wall:.1f} s)')
        elif self.mode == 'lockstep' and self.missed_deadlines > self._missed_seen:
            status.level = DiagnosticStatus.WARN
            status.message = (f'lockstep: {self.missed_deadlines - self._missed_seen} missed '
                              f'deadline(s) in the last {wall:.1f} s (the controller did not '
                              f'answer within {self._timeout:g} s)')
        elif real_time and running and max_lag * self._dt > 0.5 * self._max_lag > 0.0:
            status.level = DiagnosticStatus.WARN
            status.message = (f'lagging: up to {max_lag * self._dt * 1e3:.0f} ms behind the '
                              f'wall clock (slips beyond {self._max_lag * 1e3:g} ms)')
        residual = self._sim.power_residual() if not self._sim.fault else math.nan
        values = {
            'sim_time_s': f'{self._sim.t:.6f}',
            'mode': self.mode,
            'paused': str(self.paused).lower(),
            'step_rate_hz': f'{rate:.1f}',
            'real_time_factor': f'{self.achieved_rtf:.3f}',
            'lag_ms': f'{lag * self._dt * 1e3:.1f}',
            'max_lag_ms': f'{max_lag * self._dt * 1e3:.1f}',
            'late_ticks': str(self.late_ticks),
            'late_ticks_per_s': f'{late / wall:.1f}' if wall > 0 else '0.0',
            'slipped_s': f'{self.slipped_s:.3f}',
            'slipped_ms_per_s': f'{slipped / wall * 1e3:.1f}' if wall > 0 else '0.0',
            'refused_commands': str(self.refused_commands),
            'last_refused': self.last_refused,
            'clamped_commands': str(self.clamped_commands),
            'commands_received': str(self.commands_received),
            'power_residual': f'{residual:.3e}',
            'voltage_V': str(self._sim.u.tolist()),
            'fault': self._sim.fault,
            'stepper': self._sim.describe_stepper(),      # adaptive: the current step count
            **({'lockstep_answers': f'{self.answers} of {self._sources}',
                'lockstep_missed_deadlines': str(self.missed_deadlines),
                'lockstep_stale_answers': str(self.stale_answers),
                'lockstep_wait_s': f'{self.lockstep_wait_s:.3f}'}
               if self.mode == 'lockstep' else {}),
            'internal_steps': str(self._sim.steps_taken),
        }
        recorder = self._recorder
        if recorder is not None:
            values.update({'log_file': recorder.path, 'log_messages': str(recorder.messages),
                           'log_fault': recorder.fault})
            if recorder.fault and status.level == DiagnosticStatus.OK:
                status.level, status.message = DiagnosticStatus.WARN, recorder.fault
        self._missed_seen = self.missed_deadlines
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)

    def _log_info(self):
        rate, _, _, _, self._info_window = self._window(self._info_window)
        out = self._current_outputs()
        state = 'FAULT' if self._sim.fault else ('paused' if self.paused else 'running')
        q = self.contract.values(out, 'deflection', 'position') * 1e3
        dy = self.contract.values(out, 'displacement', 'position') * 1e3

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


def make_executor(context=None):
    """
    The executor sim_node spins in: rclpy's EventsExecutor (about 6 µs per timer callback here
    against ~100 µs for the SingleThreadedExecutor; bench/node_rate.py measures both). Spin it
    with :func:`spin`.
    """
    from rclpy.experimental import EventsExecutor
    return EventsExecutor(context=context)


def spin(executor, context=None):
    """
    Spin until the context shuts down. EventsExecutor.spin() (rclpy 7.1) does not return on
    Ctrl-C while no event comes in (e.g. paused); spin_once with a timeout does (it raises
    ExternalShutdownException).
    """
    context = context or rclpy.get_default_context()
    while context.ok():
        executor.spin_once(timeout_sec=0.1)


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
    executor = make_executor(node.context)
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
