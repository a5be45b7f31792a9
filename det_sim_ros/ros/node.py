"""
ROS 2 node: voltage commands in, the actuator's state out, on a fixed sim-time grid t = k dt.

The node only does I/O: all physics is in :class:`det_sim_ros.sim.simulator.Simulator`; when
periods run is its pacing's (det_sim_ros.ros.pacing), what it reports is built by
det_sim_ros.ros.diagnostics. Topic, parameter and service contract: docs/topics.md.
"""

from __future__ import annotations

import contextlib
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, qos_profile_sensor_data, QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger

from .commands import CommandInput
from .declaration import load_node_scene, validate_parameters
from .discovery import announce_early
from .live import open_live_view
from .markers import attach_markers
from .name_check import NameClaim
from .pacing import make_pacing
from .predictability import attach_predictability
from .rclpy_facade import RCLError, take_serialized
from .recording import open_recorder
from .reports import NodeReports
from .sensing import attach_outputs
from .spinning import (limit_middleware_start, make_executor, spin, spin_until_stopped,
                       StopRequested, StopSignals)
from .waiting import SubscriberGate
from ..io.contract import (CLOCK_TOPIC, COMMAND_TOPIC, DIAGNOSTICS_TOPIC, encode_clock,
                           JOINT_COMMAND_TOPIC, OutputContract, PREDICTABILITY_TOPIC,
                           rest_shortenings,
                           stamp_ns, structure_channels, STRUCTURE_TOPIC)
from ..physics.model import ModelDomainError
from ..scenes.outputs import main_topic
from ..scenes.scene import SceneError
from ..sim.simulator import Simulator

__all__ = ['SimNode', 'main', 'STRUCTURE_TOPIC', 'rest_shortenings',
           'structure_channels', 'make_executor', 'spin']

NODE_NAME = 'sim_node'
OUTPUT_HISTORY = 1000   # samples each output writer keeps for its reliable readers (1 s at 1 kHz)
# (the topic contract: names, types, channels, y0, the bytes on the wire: det_sim_ros.io.contract)


class SimNode(Node):
    """
    The simulator as a ROS 2 node (docs/topics.md has the topic contract).

    Per control period the node takes the commands that have arrived, steps the simulator,
    writes the CDR bytes of every output straight from the output vector
    (:class:`~det_sim_ros.io.contract.SampleEncoder`), publishes those bytes and hands the same
    bytes to the MCAP recorder. No message objects are built on that path.

    Two seams for tests and benchmarks: ``wall_clock`` (the real-time pacing's clock, s) and
    ``on_sample``, called with (k, output vector) after sample k has been published (free
    run: once it is computed; a tick's samples are published together at the tick's end).

    :param middleware_bound: a context manager factory around the middleware's calls of the
        start (the node and its DDS participant, the name claim's endpoints), not around the
        scene's preparation. The ``sim_node`` process passes
        :func:`~det_sim_ros.ros.spinning.limit_middleware_start`, which ends a stuck start;
        an embedding program (a test, the ``det_sim`` fixture) keeps the default, nothing,
        since that watchdog would end the whole program.
    :param kwargs: forwarded to :class:`rclpy.node.Node` (``context``, ``namespace``,
        ``parameter_overrides``, ...).
    """

    def __init__(self, middleware_bound=contextlib.nullcontext, **kwargs):
        # (what the node is started with is declared as given, then as checked: declaration)
        with middleware_bound():
            super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True,
                             **kwargs)
        try:
            # claimed first: the others' claims are heard while the scene is prepared
            with middleware_bound():
                self.name_claim = NameClaim(self)
            self._prepare()
        except Exception as exc:
            exc.logger_name = self.get_logger().name   # the FATAL line names the node as named
            # its claim must not outlive a start that failed: no later node may hear it, nor
            # find its name locked on this host
            self._release_name()
            super().destroy_node()
            raise

    def _release_name(self):
        claim = getattr(self, 'name_claim', None)   # (None: the claim itself failed)
        if claim is not None:
            claim.release()

    def _prepare(self):
        self.scene, scene_file = load_node_scene(self)
        self._pacing = make_pacing(self._p)
        started = time.perf_counter()
        self._sim = Simulator(self.scene, threads=self._p('threads'))
        self.det_names = list(self._sim.model.input_names)   # command and output order
        self._initial_text = (f'rest ({self.scene.rest_branch}, 0 V)'
                              if self.scene.initial_state == 'rest' else 'released from q0')
        self.y0 = rest_shortenings(self.scene)     # per DET, m
        # nothing is compiled at run time (the kernel is built at install): this is the model's
        # Ritz integrals, its stepper and the rest state's statics solve
        elapsed = time.perf_counter() - started
        self.get_logger().info(f'scene {scene_file!r} prepared in {elapsed:.2f} s (model, '
                               'stepper, rest state)')
        self.contract = OutputContract(self._sim.model, self.y0)
        self.structure_names = self.contract.structure_names
        self.steps_total = 0
        self.achieved_rtf = 0.0
        self.realtime_scheduling = False   # SCHED_FIFO in force (realtime_priority)
        self.paused = bool(self._p('start_paused'))
        self.wall_clock = time.perf_counter
        self.on_sample = None
        self._fault_reported = ''
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._start(scene_file)

    def _start(self, scene_file):
        """Create the endpoints, timers and the recorder; then sample 0 and the start-up line."""
        if self._p('qos_sensor_data') and self._p('qos_keep_all'):
            raise SceneError('parameters qos_sensor_data and qos_keep_all: choose one')
        refusal = self.name_claim.settle(self._p('allow_duplicate_name'))
        if refusal:   # before any publisher: nothing of a duplicate reaches the running node's
            raise SceneError(refusal)
        keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL)
        in_qos = keep_all if self._p('qos_keep_all') else QoSProfile(depth=10)
        # the outputs' writers keep a second of samples: a reader held up by a busy host (a
        # slow terminal, a stalled process) gets every one repaired, not only the last 10
        sensor_data = self._p('qos_sensor_data')
        out_qos = (qos_profile_sensor_data if sensor_data else keep_all
                   if self._p('qos_keep_all') else QoSProfile(depth=OUTPUT_HISTORY))
        # (a marker frame is large and only the newest matters: the inputs' depth)
        marker_qos = qos_profile_sensor_data if sensor_data else in_qos
        self._create_endpoints(in_qos, out_qos, marker_qos)
        self._gate = self._make_gate()
        self._pacing.start(self)
        self._reports = NodeReports(self, self._diag_pub, self._p('diagnostics_period'),
                                    self._p('info_period'),
                                    self.mode == 'lockstep' or not self._gate.open)
        qos = {topic: out_qos for topic in self._outputs.topics + self._outputs.truth_topics}
        qos.update({COMMAND_TOPIC: in_qos, JOINT_COMMAND_TOPIC: in_qos,
                    PREDICTABILITY_TOPIC: out_qos})
        # (before the recorder: the log's metadata says whether the measure runs)
        self._predictability = attach_predictability(self, self._p, out_qos)
        self._recorder = open_recorder(self._p, self.scene, qos, {
            'method': self._sim.method.name, 'substeps': self._sim.substeps_setting,
            'fidelity': self.scene.fidelity_label,
            'y0': repr(self.y0[0]) if len(self.y0) == 1 else repr(self.y0),
            'initial_state': self._initial_text,
            'x0': repr(self._sim.x0.tolist()),   # what ~/reset returns to
            'predictability_limit': (repr(self._p('predictability.limit'))
                                     if self._predictability.enabled else ''),
            'node': self.get_fully_qualified_name()}, self.get_namespace(), self.get_logger())
        self._predictability.log_to(self._recorder)
        self._commands = CommandInput(self._sim, self.det_names, self.scene.physics.v_max,
                                      self._recorder, self.get_logger(),
                                      self._pacing.command_received)
        if self._p('realtime_priority'):   # last: every thread of the node exists by now
            self.realtime_scheduling = self._pacing.apply_priority(
                self._p('realtime_priority'), self.get_logger())
        if self._gate.open:
            self._publish_sample(self.current_outputs())
        gate_text = ('' if self._gate.open else f', sample 0 once {self._gate.need} '
                     f'subscriber(s) of {self._gate.topic} matched')
        self.get_logger().info(
            f'scene {scene_file!r}: {self.scene.beam} beam, eps_b = {self.scene.eps_b:g}, '
            f'fidelity {self.scene.fidelity_label}, {self.scene.rate_hz:g} Hz, '
            f'{self._sim.describe_stepper()}, tolerance {self._sim.tolerance:g}'
            f'{" (auto: its level)" if self.scene.tolerance <= 0.0 else ""}; '
            f'{self._pacing.label()}{", paused" if self.paused else ""}{gate_text}; initial state '
            f'{self._initial_text}; {len(self.det_names)} DET(s), '
            f'voltage command order: [{", ".join(self.det_names)}]'
            + (f'; structure outputs [{", ".join(self.structure_names)}]'
               if self.structure_names else ''))

    def _make_gate(self) -> SubscriberGate:
        """Hold sample 0 until wait_for_subscribers subscriptions of the main topic matched."""
        publisher = self._output_pubs[main_topic()]
        gate = SubscriberGate(
            self._p('wait_for_subscribers'), publisher.topic_name,
            publisher.get_subscription_count,
            lambda: all(pub.wait_for_all_acked(Duration()) for pub in self._output_pubs.values()),
            time.perf_counter)
        if not gate.open:
            self._gate_timer = self.create_timer(0.01, self._poll_gate, clock=self._steady)
        return gate

    def _poll_gate(self):
        if self._gate.poll(lambda: self._publish_sample(self.current_outputs())):
            self.destroy_timer(self._gate_timer)
            self._pacing.run(self.running)

    def _create_endpoints(self, in_qos, out_qos, marker_qos):
        # the sample's messages (measured by the scene's sensors, if any, and their truth)
        self._outputs, self._output_pubs, self._truth_pubs, self._publish_outputs = attach_outputs(
            self, self.contract, out_qos)
        self._clock_pub = (self.create_publisher(ClockMsg, CLOCK_TOPIC, in_qos)
                           if self._pacing.publishes_clock else None)
        self._publish_clock = self._clock_pub.publish if self._clock_pub else None
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._markers = attach_markers(self, self._sim.model, self._p('markers.rate_hz'),
                                       self._p('markers.frame_id'), marker_qos)
        # commands arrive as CDR bytes (raw): decoded and checked by the contract, and logged
        # re-encoded with zero padding (equal commands give equal logs)
        self._command_subs = {
            topic: self.create_subscription(
                msg_type, topic, lambda data, topic=topic: self._commands.apply(topic, data),
                in_qos, raw=True)
            for topic, msg_type in ((COMMAND_TOPIC, Float64MultiArray),
                                    (JOINT_COMMAND_TOPIC, JointState))}
        self.create_service(SetBool, '~/pause', self._srv_pause)
        self.create_service(Trigger, '~/step', self._srv_step)
        self.create_service(Trigger, '~/reset', self._srv_reset)
        self.add_on_set_parameters_callback(validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._live = open_live_view(self)   # Foxglove WebSocket server, or None (ros.live)
        if self._live is not None:
            self._diag_pub = self._live.tap(self._diag_pub)

    # -- read-only accessors ----------------------------------------------------------------
    simulator = property(lambda self: self._sim, doc='The Simulator this node runs.')
    recorder = property(lambda self: self._recorder, doc='The MCAP Recorder, or None.')
    markers = property(lambda self: self._markers, doc='The NodeMarkers, or None (off).')
    live = property(lambda self: self._live, doc='The LiveView (ros.live), or None (off).')
    predictability = property(lambda self: self._predictability,
                              doc='The predictability measure (ros.predictability).')
    dt = property(lambda self: self._sim.dt, doc='The control period, s.')
    mode = property(lambda self: self._pacing.mode, doc='real_time, free_run or lockstep.')
    pacing = property(lambda self: self._pacing, doc='The Pacing of this mode (ros.pacing).')
    commands = property(lambda self: self._commands, doc='The CommandInput (its counters).')
    steady_clock = property(lambda self: self._steady, doc='The clock of the node timers.')
    output_publishers = property(lambda self: dict(self._output_pubs),
                                 doc='Topic -> the publisher of that output.')
    truth_publishers = property(lambda self: dict(self._truth_pubs),
                                doc='Sensed topic -> the publisher of its ~/truth topic.')
    outputs = property(lambda self: self._outputs, doc="A sample's messages (io.sensing).")
    clock_publisher = property(lambda self: self._clock_pub,
                               doc='The /clock publisher (None in real-time mode).')
    command_subscriptions = property(lambda self: dict(self._command_subs),
                                     doc='Topic -> the subscription of that command topic.')

    @property
    def running(self) -> bool:
        """Return True if neither paused, stopped by a fault nor waiting for subscribers."""
        return not self.paused and not self._sim.fault and self._gate.open

    def waiting(self):
        """Return what the node waits for (a :class:`~det_sim_ros.ros.waiting.Wait`) or None."""
        return self._gate.waiting() or self._pacing.waiting()

    def run_due_reports(self):
        """Publish /diagnostics and log the INFO line if they are due by the wall clock."""
        self._reports.run_due()

    def current_outputs(self) -> np.ndarray:
        """Return the simulator's output vector now."""
        return np.array(list(self._sim.outputs().values()))

    def subscriptions_matched(self) -> int:
        """Return the subscriptions matched by the output publishers, summed."""
        return sum(pub.get_subscription_count() for pub in self._output_pubs.values())

    def destroy_node(self):
        """Finish the MCAP log (indexed and complete), then destroy the node."""
        if self._recorder is not None:
            self._recorder.close()
        if self._live is not None:
            self._live.close()
        self._release_name()
        return super().destroy_node()

    # -- stepping ---------------------------------------------------------------------------
    def run_period(self, batch=None) -> bool:
        """
        Run one control period and publish it; False (and fault) if the model diverged.

        With ``batch`` its messages are added to the batch instead (see :meth:`send`).
        """
        # the commands that have arrived since the last period, also in a catch-up burst or a
        # free-run tick (the executor would deliver them only after the whole tick)
        for topic, sub in self._command_subs.items():
            while (data := take_serialized(sub)) is not None:
                self._commands.apply(topic, data)
        try:
            out = self._sim.step()
        except ModelDomainError as exc:
            self._enter_fault(str(exc))
            return False
        self.steps_total += 1
        published = self._publish_sample(out, batch)
        self._predictability.follow(self._sim, out)   # after: no delay to the sample
        return published

    def send(self, batch) -> bool:
        """
        Publish a batch of (t_ns, samples, marker frame or None) in order.

        /clock goes before each sample's outputs. Return False if the context has shut down
        meanwhile.
        """
        try:
            publish_clock, publishers = self._publish_clock, self._publish_outputs
            for t_ns, samples, frame in batch:
                if publish_clock is not None:   # first: a use_sim_time reader is at t_k
                    publish_clock(encode_clock(t_ns))
                for publish, data in zip(publishers, samples):
                    if data is not None:   # (None: the sensor dropped the sample)
                        publish(data)
                if frame is not None:
                    self._markers.publish(frame)
            if self._live is not None:
                self._live.send(batch)
        except RuntimeError:   # rclpy's RCLError: Ctrl-C shut the context down mid-tick
            if self.context.ok():
                raise
            self._pacing.stop()
            return False
        return True

    def _publish_sample(self, out, batch=None) -> bool:
        """Publish sample k (or add it to ``batch``), log it, then the hooks and markers."""
        # (every output is finite here: the kernel refuses a period or an outputs() call with
        # a non-finite output, so Simulator.step and .outputs raise before anything is sent)
        k = self._sim.k
        t_ns = stamp_ns(k, self._sim.dt)
        samples = self._outputs.encode(k, out, t_ns)
        self._pacing.sample_ready(k, samples)
        recorder = self._recorder
        if recorder is not None:   # (the log's order: the sample, then its marker frame)
            self._outputs.record(recorder, t_ns, samples)
        frame = None
        if self._markers is not None and not k % self._markers.every:
            frame = self._markers.frame_for(k, self._sim.x, self._sim.u, t_ns, recorder)
        if batch is not None:
            batch.append((t_ns, samples, frame))
        elif not self.send(((t_ns, samples, frame),)):
            return False
        if self.on_sample is not None:
            self.on_sample(k, out)
        return True

    def _enter_fault(self, reason):
        self._pacing.stop()
        if self._fault_reported != reason:
            self._fault_reported = reason
            self.get_logger().error(f'fault, integration stopped (call ~/reset): {reason}')
            self.publish_diagnostics()

    # -- services ---------------------------------------------------------------------------
    def set_paused(self, paused: bool) -> str:
        """Pause or resume (as ~/pause does); return the service's answer."""
        self.paused = bool(paused)
        self._pacing.run(self.running)
        return f"{'paused' if self.paused else 'running'} at t = {self._sim.t:.6g} s"

    def _srv_pause(self, request, response):
        response.message = self.set_paused(request.data)
        response.success = True
        return response

    def _srv_step(self, request, response):
        if not self.paused:
            response.success, response.message = False, 'not paused: call ~/pause first'
        elif not self._gate.open:
            response.success, response.message = False, self._gate.waiting().text()
        elif self._sim.fault:
            response.success, response.message = False, f'fault: {self._sim.fault}'
        else:
            response.success = self.run_period()
            response.message = (f't = {self._sim.t:.6g} s' if response.success
                                else f'fault: {self._sim.fault}')
        return response

    def _srv_reset(self, request, response):
        self._sim.reset()
        self._predictability.reset()
        self._pacing.reset()
        log = ''
        if self._recorder is not None:
            self._recorder.new_file()  # sim time restarts: one file per continuous run
            if self._recorder.active:
                log = f'; the log continues in {self._recorder.path}'
                self.get_logger().info(f'reset{log}')
        self._fault_reported = ''
        self._pacing.run(self.running)
        if self._gate.open:
            self._publish_sample(self.current_outputs())
        else:
            self._gate.restart()   # sample 0 goes out when the subscribers have matched
        response.success = True
        response.message = f'reset to t = 0, initial state {self._initial_text}, 0 V{log}'
        return response

    # -- parameters -------------------------------------------------------------------------
    def _p(self, name):
        return self.get_parameter(name).value

    def _apply_parameters(self, params):
        self._pacing.parameters_changed(self._p, {param.name for param in params})

    # -- reporting --------------------------------------------------------------------------
    def publish_diagnostics(self, now: float | None = None):
        """Publish the /diagnostics status for the window since the last one; return it."""
        return self._reports.publish_diagnostics(now)


def main(args=None):
    """
    Run the simulator node until SIGINT or SIGTERM; return the exit code.

    A stop exits 0 with the log finished; a start-up input that cannot be used (scene,
    parameter, initial state) exits 1 with one line.
    """
    from rclpy.signals import SignalHandlerOptions
    node = None
    code = 0
    with StopSignals() as stop, announce_early():   # (before the participant exists)
        try:
            with limit_middleware_start():
                rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            node = SimNode(middleware_bound=limit_middleware_start)
            stop.preparing = False
            if not stop.requested:
                code = spin_until_stopped(node, stop)
        except StopRequested:
            pass
        except (SceneError, ParameterException, ModelDomainError, RCLError) as exc:
            stop.end()                   # one line, exit 1: an input that cannot be used
            text = ' '.join(str(exc).split()) or type(exc).__name__
            rclpy.logging.get_logger(getattr(exc, 'logger_name', NODE_NAME)).fatal(
                f'cannot start: {text}')
            code = 1
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception:
            if not stop.requested:
                raise
            # a stop during the preparation that a library turned into its own error (e.g. a
            # C extension's initialisation): still a stop
        finally:
            stop.end()
            if node is not None:
                node.destroy_node()          # finishes and indexes the MCAP log
            rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
