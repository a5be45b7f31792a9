"""
Replay of MCAP run logs: re-simulate a log bit-for-bit, or republish it with its timing.

``det_sim_replay resim LOG`` feeds the logged voltage commands through the model with the
logged scene and stepper, and compares with the logged outputs. The timing rule is the node's:
a command logged at sim time t_k is applied before the step from t_k to t_{k+1}; an output
stamped t_k is the result of the step that ended at t_k (t_0: the initial state). With the same
scene and stepper the outputs are reproduced bit-for-bit (the simulator is fixed-step and
deterministic), so the default tolerance is 0.

``det_sim_replay play LOG`` republishes the logged topics with their recorded timing (``--rate``,
``--start-offset``, ``--loop``, ``--clock`` to publish /clock from the log time), so a
controller can be tested against a recorded run.

``det_sim_replay info LOG`` and ``det_sim_replay recover LOG OUT`` print a summary and rewrite a
crashed (unfinished) log as a finished, indexed file.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import math
import sys
import time
from typing import Callable, Iterable, Mapping, Sequence

from .contract import basename as _basename
from .contract import (COMMAND_TOPIC, COMMAND_TOPICS, CdrError, CommandDecoder,
                       decode_joint_state, encode_float64_multi_array, encode_joint_state,
                       JOINT_COMMAND_TOPIC, OUTPUT_FIELDS, OutputContract, rest_shortening,
                       rest_shortenings, stamp_ns, TOPIC_TYPES)
from .mcap_log import LogReader, Recorder, recover

__all__ = ['OUTPUT_FIELDS', 'COMMAND_TOPICS', 'ResimResult', 'resimulate', 'play', 'PlayStats',
           'simulate_to_log', 'OutputContract', 'rest_shortening', 'rest_shortenings', 'main']

# The topic contract (topics, channels, y0, structure outputs, commands) is det_sim_ros.io.contract;
# a log holds the per-DET y0 as metadata 'y0' (a float for one DET, a list for several).


def _logged_y0(text: str | None, n: int) -> list[float] | None:
    """Metadata 'y0' (a float for one DET, a list for several), None if absent or not n values."""
    if not text:
        return None
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return None
    values = value if isinstance(value, (list, tuple)) else [value]
    return [float(v) for v in values] if len(values) == n else None


def _logged_x0(text: str | None, n: int):
    """Metadata 'x0' (the initial state vector the run started from), None if absent or not n
    finite values."""
    if not text:
        return None
    try:
        values = [float(v) for v in ast.literal_eval(text)]
    except (ValueError, SyntaxError, TypeError):
        return None
    return values if len(values) == n and all(math.isfinite(v) for v in values) else None


# -- re-simulation -------------------------------------------------------------------------------

@dataclasses.dataclass
class ResimResult:
    """Outcome of :func:`resimulate`."""

    max_deviation: dict[str, float]  # 'topic.field (output)' -> max |logged - resimulated|
    compared: dict[str, int]         # same keys -> number of samples compared
    commands: int = 0
    steps: int = 0
    skipped: int = 0                 # logged outputs that could not be matched to a step
    fault: str = ''
    complete: bool = True            # the log was a finished file
    method: str = ''
    substeps: int = 0                # 0: adaptive

    def ok(self, tolerance: float = 0.0) -> bool:
        """True if every compared output is within ``tolerance`` and nothing went wrong."""
        return (not self.fault and bool(self.compared) and self.skipped == 0
                and all(v <= tolerance for v in self.max_deviation.values()))

    def table(self) -> str:
        """A plain-text table of the deviations."""
        width = max([len(k) for k in self.max_deviation] + [6])
        lines = [f"{'output':<{width}}  {'samples':>8}  max |deviation|"]
        for key, value in self.max_deviation.items():
            lines.append(f'{key:<{width}}  {self.compared[key]:>8}  {value:.6g}')
        stepping = f'x {self.substeps}' if self.substeps else 'adaptive'
        lines.append(f'{self.commands} commands, {self.steps} steps, stepper {self.method} '
                     f'{stepping}' + ('' if self.complete else ', log unfinished (recovered)')
                     + (f', {self.skipped} outputs unmatched' if self.skipped else '')
                     + (f', fault: {self.fault}' if self.fault else ''))
        return '\n'.join(lines)


def _scene_from_log(reader: LogReader):
    import yaml
    from ..scenes.scene import load_scene
    text = reader.scene_yaml
    if not text:
        raise ValueError(f'{reader.files[0]}: the log holds no scene (det_sim_ros metadata)')
    data = yaml.safe_load(text)
    inner = data
    if isinstance(data, dict) and len(data) == 1:
        (only,) = data.values()
        if isinstance(only, dict) and 'ros__parameters' in only:
            inner = only['ros__parameters']
    section = inner.get('scene') if isinstance(inner, dict) else None
    if isinstance(section, dict):
        # logs written before scene.initial_state existed started released from q0
        section.setdefault('initial_state', 'released')
    return load_scene(data)


def resimulate(log, method: str | None = None, substeps: int | None = None,
               output_fields: Mapping[str, Mapping[str, str]] | None = None) -> ResimResult:
    """
    Re-run a logged run in-process and compare with its logged outputs.

    :param log: an MCAP file, a list of split files or a directory.
    :param method, substeps: the stepper (default: as logged in the ``det_sim_ros`` metadata,
        else the scene's).
    """
    import numpy as np
    from ..physics.model import ModelDomainError
    from ..sim.simulator import Simulator

    reader = LogReader(log)
    info = reader.info
    scene = _scene_from_log(reader)
    if method is None:
        method = info.get('method') or None
    if substeps is None and info.get('substeps'):
        substeps = int(info['substeps'])
    fields = dict(output_fields or OUTPUT_FIELDS)
    sim = Simulator(scene, method=method, substeps=substeps)
    x0 = _logged_x0(info.get('x0'), sim.model.n_states)
    if x0 is not None:   # the logged initial state itself (bit-exact even if its solve changes)
        sim.x0 = np.array(x0)
        sim.reset()
    det_names = list(sim.model.input_names)
    contract = OutputContract(sim.model, _logged_y0(info.get('y0'), sim.model.n_inputs), fields)
    decoder = CommandDecoder(det_names, scene.physics.v_max)
    structure_key = (f"{contract.structure_topic}.position "
                     f"({', '.join(contract.structure_outputs)})")
    dt_ns = sim.dt * 1e9
    result = ResimResult({}, {}, method=sim.method.name, substeps=sim.substeps_setting)
    initial = sim.outputs()
    current = np.array([initial[name] for name in sim.output_names])

    def advance_to(k: int) -> bool:
        nonlocal current
        while sim.k < k:
            try:
                current = sim.step().copy()
            except ModelDomainError as exc:
                result.fault = str(exc)
                return False
            result.steps += 1
        return sim.k == k

    for message in reader.messages():
        name = _basename(message.topic)
        if name in COMMAND_TOPICS:
            k = round(message.log_time / dt_ns)
            if not advance_to(k):
                if result.fault:
                    break
                result.skipped += 1
                continue
            command = decoder.decode(name, message.data, sim.u.tolist())
            if command.volts is not None:   # a command the node refused is logged, not applied
                sim.set_input(command.volts)
            result.commands += 1
        elif name in fields or (name == contract.structure_topic
                                and contract.structure_names):
            try:
                msg = decode_joint_state(message.data)
            except CdrError:
                result.skipped += 1
                continue
            k = round(msg.stamp_ns / dt_ns)
            if not advance_to(k):
                if result.fault:
                    break
                result.skipped += 1
                continue
            if name in fields:
                names = det_names
                compare = [(f'{name}.{field} ({output})', field,
                            contract.values(current, name, field))
                           for field, output in fields[name].items()]
            else:
                names = list(contract.structure_names)
                compare = [(structure_key, 'position', contract.structure(current))]
            for key, field, expected in compare:
                logged = np.asarray(getattr(msg, field), dtype=float)
                if logged.size == 0:
                    continue
                if logged.shape != expected.shape or list(msg.name) != names:
                    deviation = math.inf   # a different channel count or order
                else:
                    deviation = float(np.max(np.abs(logged - expected)))
                if math.isnan(deviation):
                    deviation = math.inf
                result.max_deviation[key] = max(result.max_deviation.get(key, 0.0), deviation)
                result.compared[key] = result.compared.get(key, 0) + 1
    result.complete = reader.complete
    return result


# -- offline recording (what the node does, without a ROS graph) ---------------------------------

def simulate_to_log(recorder: Recorder, sim, commands: Mapping[int, Sequence[float]] | Callable,
                    n_steps: int, joint_commands: bool = False) -> None:
    """
    Run ``sim`` (any number of DETs) for ``n_steps`` and record commands and outputs as the node
    does, with the node's bytes (joint commands name every DET; the structure topic when the
    scene has one). Needs no ROS.

    The initial state is recorded at t_0, then each step's outputs at its end time.

    :param commands: step index -> voltages, or a function k -> voltages or None, applied (and
        recorded at t_k) before the step from t_k to t_{k+1}.
    """
    import numpy as np
    get = commands if callable(commands) else commands.get
    contract = OutputContract(sim.model)
    encoder = contract.encoder()
    t_ns = stamp_ns(sim.k, sim.dt)
    initial = np.array(list(sim.outputs().values()))
    recorder.record_sample(t_ns, encoder.topics, encoder.encode(initial, t_ns), TOPIC_TYPES)
    for _ in range(n_steps):
        k = sim.k
        volts = get(k)
        if volts is not None:
            t_ns = stamp_ns(k, sim.dt)
            volts = [float(v) for v in volts]
            if joint_commands:
                recorder.record(JOINT_COMMAND_TOPIC, encode_joint_state(contract.det_names, volts),
                                t_ns, TOPIC_TYPES[JOINT_COMMAND_TOPIC])
            else:
                recorder.record(COMMAND_TOPIC, encode_float64_multi_array(volts), t_ns,
                                TOPIC_TYPES[COMMAND_TOPIC])
            sim.set_input(volts)
        out = sim.step()
        t_ns = stamp_ns(sim.k, sim.dt)
        recorder.record_sample(t_ns, encoder.topics, encoder.encode(out, t_ns), TOPIC_TYPES)


# -- republishing --------------------------------------------------------------------------------

@dataclasses.dataclass
class PlayStats:
    """What :func:`play` published."""

    published: dict[str, int] = dataclasses.field(default_factory=dict)
    clock: int = 0
    loops: int = 0
    # (wall seconds since the pass started, log time ns) of each published message, per pass
    schedule: list[tuple[float, int]] = dataclasses.field(default_factory=list)
    unknown_types: list[str] = dataclasses.field(default_factory=list)


def qos_from_yaml(text: str | None):
    """An rclpy QoSProfile from ``offered_qos_profiles`` YAML (reliable, depth 10 if empty)."""
    import yaml
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
    profiles = yaml.safe_load(text) if text else None
    if not profiles:
        return QoSProfile(depth=10)
    first = profiles[0]

    def policy(enum, value, default):
        if isinstance(value, int):
            return enum(value)
        try:
            return enum[str(value).upper()]
        except KeyError:
            return default

    return QoSProfile(
        history=policy(HistoryPolicy, first.get('history'), HistoryPolicy.KEEP_LAST),
        depth=max(1, int(first.get('depth', 10) or 10)),
        reliability=policy(ReliabilityPolicy, first.get('reliability'),
                           ReliabilityPolicy.RELIABLE),
        durability=policy(DurabilityPolicy, first.get('durability'), DurabilityPolicy.VOLATILE))


def play(log, node=None, rate: float = 1.0, start_offset: float = 0.0, loop: bool = False,
         clock: bool = False, topics: Iterable[str] | None = None, max_loops: int | None = None,
         sleep: Callable[[float], None] = time.sleep,
         now: Callable[[], float] = time.monotonic) -> PlayStats:
    """
    Republish a log's messages (raw CDR) with their recorded timing.

    The message with log time t is published no earlier than (t - t_start) / rate after the
    pass started (``rate <= 0`` or inf: as fast as possible); t_start is the first log time
    plus ``start_offset`` seconds. With ``clock``, /clock (rosgraph_msgs/Clock) is published
    with each new log time before the messages at that time, and a logged /clock is skipped.
    Needs ``rclpy.init()``; creates a node ``det_sim_replay`` unless ``node`` is given.
    """
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    own_node = node is None
    if own_node:
        node = rclpy.create_node('det_sim_replay')
    context = node.context
    stats = PlayStats()
    publishers = {}
    clock_pub = None
    if clock:
        clock_pub = node.create_publisher(
            Clock, '/clock', QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
    wanted = None if topics is None else {t if t.startswith('/') else '/' + t for t in topics}
    fast = not rate or rate <= 0 or math.isinf(rate)
    try:
        while True:
            reader = LogReader(log)
            start_ns = None
            wall0 = None
            last_clock = None
            for message in reader.messages():
                if not context.ok():
                    return stats
                if start_ns is None:
                    start_ns = message.log_time + round(start_offset * 1e9)
                if message.log_time < start_ns:
                    continue
                if wanted is not None and message.topic not in wanted:
                    continue
                if clock and message.topic == '/clock':
                    continue
                if wall0 is None:
                    wall0 = now()
                if not fast:
                    target = wall0 + (message.log_time - start_ns) / 1e9 / rate
                    while context.ok():
                        remaining = target - now()
                        if remaining <= 0:
                            break
                        sleep(min(remaining, 0.05))
                if clock_pub is not None and message.log_time != last_clock:
                    stamp = Clock()
                    stamp.clock.sec, stamp.clock.nanosec = divmod(message.log_time, 1_000_000_000)
                    clock_pub.publish(stamp)
                    stats.clock += 1
                    last_clock = message.log_time
                publisher = publishers.get(message.topic)
                if publisher is None:
                    try:
                        from .cdr import message_class as _message_class
                        cls = _message_class(message.type_name)
                    except Exception:  # noqa: BLE001 - a type this install does not have
                        publishers[message.topic] = False
                        stats.unknown_types.append(message.type_name)
                        node.get_logger().warning(
                            f'skipping {message.topic}: type {message.type_name} not available')
                        continue
                    publisher = node.create_publisher(cls, message.topic,
                                                      qos_from_yaml(reader.qos.get(message.topic)))
                    publishers[message.topic] = publisher
                if publisher is False:
                    continue
                publisher.publish(message.data)
                stats.published[message.topic] = stats.published.get(message.topic, 0) + 1
                stats.schedule.append((now() - wall0, message.log_time))
            stats.loops += 1
            if not loop or (max_loops is not None and stats.loops >= max_loops):
                return stats
    finally:
        if own_node:
            node.destroy_node()


# -- command line --------------------------------------------------------------------------------

def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='det_sim_replay', description='Re-simulate or republish det_sim_ros MCAP logs.')
    sub = parser.add_subparsers(dest='command', required=True)
    resim = sub.add_parser('resim', help='re-simulate a log and compare with its outputs')
    resim.add_argument('log', nargs='+', help='MCAP file(s) or a directory of split files')
    resim.add_argument('--tolerance', type=float, default=0.0,
                       help='largest accepted |deviation| (default 0: bit-exact)')
    resim.add_argument('--method', default=None, help='stepper (default: as logged)')
    resim.add_argument('--substeps', type=int, default=None, help='substeps (default: as logged)')
    play_p = sub.add_parser('play', help='republish a log with its recorded timing')
    play_p.add_argument('log', nargs='+')
    play_p.add_argument('-r', '--rate', type=float, default=1.0, help='rate factor (0: max)')
    play_p.add_argument('--start-offset', type=float, default=0.0, help='skip the first S s')
    play_p.add_argument('-l', '--loop', action='store_true')
    play_p.add_argument('--clock', action='store_true', help='publish /clock from log time')
    play_p.add_argument('--topics', nargs='*', default=None)
    info = sub.add_parser('info', help='summarize a log')
    info.add_argument('log', nargs='+')
    rec = sub.add_parser('recover', help='rewrite an unfinished log as a finished file')
    rec.add_argument('log')
    rec.add_argument('output')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point ``det_sim_replay``; returns the exit code."""
    raw = list(sys.argv[1:] if argv is None else argv)
    ros_args = []
    if '--ros-args' in raw:
        cut = raw.index('--ros-args')
        raw, ros_args = raw[:cut], raw[cut:]
    args = _parser().parse_args(raw)
    if args.command == 'resim':
        result = resimulate(args.log, method=args.method, substeps=args.substeps)
        print(result.table())
        ok = result.ok(args.tolerance)
        print('bit-exact' if ok and not any(result.max_deviation.values()) else
              ('within tolerance' if ok else 'MISMATCH'))
        return 0 if ok else 1
    if args.command == 'info':
        reader = LogReader(args.log)
        counts: dict[str, int] = {}
        first = last = None
        for message in reader.messages():
            counts[message.topic] = counts.get(message.topic, 0) + 1
            first = message.log_time if first is None else first
            last = message.log_time
        print(f'files: {", ".join(reader.files)}')
        print(f"profile: {reader.profile}; det_sim_ros {reader.info.get('version', '?')}; "
              f"{'finished' if reader.complete else 'UNFINISHED (readable part shown)'}")
        if first is not None:
            print(f'log time: {first / 1e9:.6f} .. {last / 1e9:.6f} s')
        for topic, count in counts.items():
            print(f'  {topic}  [{reader.topics.get(topic, "?")}]  {count} messages')
        return 0
    if args.command == 'recover':
        outcome = recover(args.log, args.output)
        print(f"{outcome['messages']} messages written to {args.output}"
              + ('' if outcome['complete'] else ' (source was unfinished)'))
        return 0
    import rclpy
    from rclpy.executors import ExternalShutdownException
    rclpy.init(args=['det_sim_replay'] + ros_args)
    try:
        stats = play(args.log, rate=args.rate, start_offset=args.start_offset, loop=args.loop,
                     clock=args.clock, topics=args.topics)
        print(f'published {sum(stats.published.values())} messages'
              + (f', {stats.clock} clock ticks' if args.clock else ''))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == '__main__':  # pragma: no cover
    sys.exit(main())
