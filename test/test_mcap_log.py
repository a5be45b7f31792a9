"""
MCAP run logs: rosbag2 conventions, faults, crash safety.

The rosbag2 conventions are checked by three independent readers.
"""

import os
import pathlib
import shutil
import signal
import struct
import subprocess
import sys
import textwrap

from conftest import child_env
from det_sim_ros import __version__
from det_sim_ros.io.log import (logged_scene, LogReader, message_definition, qos_profiles_yaml,
                                Recorder, recover)
from det_sim_ros.io.replay import OUTPUT_FIELDS, simulate_to_log
from det_sim_ros.scenes.scene import load_scene, scene_to_dict
from det_sim_ros.sim.simulator import Simulator
import pytest
import yaml

# the paper's one-term model: the fidelity is not the subject of these tests, and it keeps
# them light
PAPER = {'scene.fidelity': 'paper'}

N_STEPS = 300
OUTPUT_TOPICS = ['/' + t for t in OUTPUT_FIELDS]


def _command(k):
    return [500.0 + 5.0 * k] if k % 25 == 0 else None


@pytest.fixture(scope='module')
def logged_run(tmp_path_factory):
    """Return a run of the default scene logged in-process, plus the expected values."""
    scene = load_scene('default', PAPER)
    sim = Simulator(scene)
    path = str(tmp_path_factory.mktemp('log') / 'run.mcap')
    recorder = Recorder(path, scene, metadata={'method': sim.method.name,
                                               'substeps': sim.substeps_setting})
    simulate_to_log(recorder, sim, _command, N_STEPS)
    recorder.close()
    assert recorder.fault == ''
    reference = Simulator(scene)
    expected = []
    for k in range(N_STEPS):
        if _command(k) is not None:
            reference.set_input(_command(k))
        expected.append(reference.step().copy())
    return path, scene, expected, reference.output_names


def test_message_definition_rosbag2_style():
    text = message_definition('sensor_msgs/msg/JointState')
    assert text.startswith(open(os.path.join(sys.prefix, 'share', 'sensor_msgs', 'msg',
                                             'JointState.msg')).read())
    delimiter = '=' * 80
    assert f'\n{delimiter}\nMSG: std_msgs/Header\n' in text
    assert f'\n{delimiter}\nMSG: builtin_interfaces/Time\n' in text
    assert text.count('MSG: ') == 2
    multi = message_definition('std_msgs/msg/Float64MultiArray')
    assert 'MSG: std_msgs/MultiArrayLayout' in multi
    assert 'MSG: std_msgs/MultiArrayDimension' in multi

    # Both third-party parsers accept the definitions.
    from mcap_ros2._dynamic import generate_dynamic
    from rosbags.typesys import get_types_from_msg
    for name in ('sensor_msgs/msg/JointState', 'std_msgs/msg/Float64MultiArray',
                 'rosgraph_msgs/msg/Clock', 'diagnostic_msgs/msg/DiagnosticArray'):
        assert name in generate_dynamic(name, message_definition(name))
        assert name in get_types_from_msg(message_definition(name), name)


def test_qos_yaml_jazzy_form():
    from rclpy.qos import qos_profile_sensor_data
    from rosbags.rosbag2.metadata import parse_qos
    default, = parse_qos(qos_profiles_yaml())
    assert (default.history.name, default.depth, default.reliability.name,
            default.durability.name, default.liveliness.name) == (
        'KEEP_LAST', 10, 'RELIABLE', 'VOLATILE', 'AUTOMATIC')
    assert (default.deadline.sec, default.deadline.nsec) == (9223372036, 854775807)
    sensor, = parse_qos(qos_profiles_yaml(qos_profile_sensor_data))
    assert (sensor.depth, sensor.reliability.name) == (5, 'BEST_EFFORT')


def test_reader_mcap_ros2_decoder(logged_run):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    path, _, expected, names = logged_run
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert summary.statistics.message_count == 4 * (N_STEPS + 1) + N_STEPS // 25
        for schema in summary.schemas.values():
            assert schema.encoding == 'ros2msg' and schema.name.count('/') == 2
        for channel in summary.channels.values():
            assert channel.message_encoding == 'cdr'
            assert 'offered_qos_profiles' in channel.metadata
        q = names.index('q')
        deflection = [(m.log_time, msg) for _, c, m, msg in reader.iter_decoded_messages(
            topics=['/deflection'])]
    assert len(deflection) == N_STEPS + 1  # the initial state at t = 0, then every step
    for k, (log_time, msg) in enumerate(deflection[1:]):
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert stamp == log_time
        assert msg.position[0] == expected[k][q]  # bit-identical through CDR


def test_reader_rosbags_anyreader(logged_run):
    from rosbags.highlevel import AnyReader
    path, _, expected, names = logged_run
    with AnyReader([pathlib.Path(path)]) as reader:
        topics = {c.topic: c for c in reader.connections}
        assert set(topics) == set(OUTPUT_TOPICS) | {'/voltage_command'}
        assert topics['/charge'].msgtype == 'sensor_msgs/msg/JointState'
        qos = topics['/charge'].ext.offered_qos_profiles[0]
        assert qos.reliability.name == 'RELIABLE' and qos.depth == 10
        times, charge = [], []
        for connection, timestamp, raw in reader.messages(connections=reader.connections):
            times.append(timestamp)
            if connection.topic == '/charge':
                charge.append(reader.deserialize(raw, connection.msgtype).position[0])
    assert times == sorted(times)
    assert charge[1:] == [row[names.index('q_p')] for row in expected]


def test_reader_plain_mcap_and_rclpy(logged_run):
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    path, scene, expected, names = logged_run
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name: a.data for a in reader.iter_attachments()}
        commands, current = [], []
        last = -1
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert message.log_time >= last and message.publish_time == message.log_time
            last = message.log_time
            if channel.topic == '/voltage_command':
                commands.append((message.log_time,
                                 list(deserialize_message(message.data, Float64MultiArray).data)))
            elif channel.topic == '/current':
                current.append(deserialize_message(message.data, JointState).position[0])
    assert commands == [(round(k * scene.dt * 1e9), _command(k))
                        for k in range(N_STEPS) if _command(k) is not None]
    assert current[1:] == [row[names.index('i_DE')] for row in expected]
    info = metadata['det_sim_ros']
    assert info['version'] == __version__ and info['time_base'] == 'sim_time'
    assert yaml.safe_load(attachments['scene.yaml']) == scene_to_dict(logged_scene(scene),
                                                                      wrap=True)
    assert load_scene(yaml.safe_load(info['scene_yaml'])) == logged_scene(scene)
    assert metadata['det_sim_ros.end']['messages'] == str(4 * (N_STEPS + 1) + N_STEPS // 25)


def test_log_time_never_decreases(tmp_path):
    from std_msgs.msg import Float64MultiArray
    recorder = Recorder(tmp_path / 'clamp.mcap', None)
    for t in (5, 10, 7, 10, 12):
        assert recorder.record('x', Float64MultiArray(data=[float(t)]), t)
    recorder.close()
    assert recorder.clamped == 1
    reader = LogReader(tmp_path / 'clamp.mcap')
    assert [m.log_time for m in reader.messages()] == [5, 10, 10, 10, 12]
    assert [m.decode().data[0] for m in reader.messages()] == [5, 10, 7, 10, 12]
    assert reader.complete


def test_unwritable_path_reports_and_never_raises(tmp_path):
    from std_msgs.msg import Float64MultiArray
    blocker = tmp_path / 'a_file'
    blocker.write_text('not a directory')
    faults = []
    recorder = Recorder(blocker / 'sub' / 'run.mcap', None, on_fault=faults.append)
    assert recorder.fault and faults == [recorder.fault] and not recorder.active
    assert recorder.record('x', Float64MultiArray(data=[1.0]), 0) is False
    assert recorder.dropped == 1
    recorder.close()


@pytest.mark.skipif(not os.path.exists('/dev/full'), reason='needs /dev/full')
def test_disk_full_reports_and_never_raises():
    from std_msgs.msg import Float64MultiArray
    recorder = Recorder('/dev/full', None, flush_period_s=0.0)
    for k in range(10):
        recorder.record('x', Float64MultiArray(data=[1.0]), k)  # must not raise
    recorder.close()
    assert 'No space left' in recorder.fault


def test_split_by_size_and_duration(tmp_path):
    from std_msgs.msg import Float64MultiArray
    scene = load_scene('default', PAPER)
    recorder = Recorder(tmp_path, scene, split_mb=0.002, chunk_size=1024)
    for k in range(400):
        recorder.record('voltage_command', Float64MultiArray(data=[float(k)] * 4), k * 1000)
    recorder.close()
    assert len(recorder.paths) > 1
    for path in recorder.paths:  # every file stands alone: finished, with the scene
        part = LogReader(path)
        assert list(part.messages()) and part.complete and part.scene_yaml
    whole = LogReader(tmp_path)
    assert [m.decode().data[0] for m in whole.messages()] == [float(k) for k in range(400)]

    by_time = Recorder(tmp_path / 'timed.mcap', scene, split_s=0.1)
    for k in range(250):
        by_time.record('voltage_command', Float64MultiArray(data=[float(k)]), k * 1_000_000)
    by_time.close()
    assert len(by_time.paths) == 3


CHILD = textwrap.dedent("""
    import sys, time
    from std_msgs.msg import Float64MultiArray
    from det_sim_ros.io.log import Recorder
    recorder = Recorder(sys.argv[1], None, flush_period_s=0.02, background=sys.argv[2] == 'bg')
    flushes = 0
    k = 0
    try:
        while True:
            recorder.record('voltage_command', Float64MultiArray(data=[float(k)]), k * 1000000)
            k += 1
            if recorder.flushes != flushes:
                flushes = recorder.flushes
                print(recorder.flushed_messages, flush=True)
            time.sleep(0.0002)
    finally:
        print('closing', flush=True)
""")


def _start_child(path, mode='sync'):
    env = child_env()
    return subprocess.Popen([sys.executable, '-c', CHILD, str(path), mode], stdout=subprocess.PIPE,
                            text=True, env=env)


def _wait_flushes(child, count):
    flushed = 0
    for _ in range(count):
        line = child.stdout.readline()
        assert line, 'the child stopped early'
        flushed = int(line)
    return flushed


@pytest.mark.ros
@pytest.mark.parametrize('mode', ['sync', 'bg'])
def test_sigkill_loses_at_most_the_last_flush_period(tmp_path, mode):
    """A SIGKILL keeps everything written up to the last flush (with the writer thread too)."""
    from mcap.reader import make_reader
    path = tmp_path / 'killed.mcap'
    child = _start_child(path, mode)
    try:
        flushed = _wait_flushes(child, 5)
    finally:
        child.kill()  # SIGKILL
        child.wait(timeout=60)
    reader = LogReader(path)
    values = [m.decode().data[0] for m in reader.messages()]
    assert not reader.complete
    assert len(values) >= flushed > 0
    assert values == [float(k) for k in range(len(values))]  # nothing before the cut is lost
    # the killed file is a valid MCAP up to its last flush (a provisional end after
    # every flush): mcap's own reader and rosbags read it without a manual step
    with open(path, 'rb') as stream:
        standard = [m.data for _, _, m in make_reader(stream).iter_messages()]
    assert len(standard) == len(values)
    from pathlib import Path
    from rosbags.highlevel import AnyReader
    with AnyReader([Path(path)]) as bag:
        assert sum(1 for _ in bag.messages()) == len(values)
    # recover() turns it into a finished, indexed file
    outcome = recover(path, str(tmp_path / 'recovered.mcap'))
    assert outcome == {'messages': len(values), 'complete': False}
    with open(tmp_path / 'recovered.mcap', 'rb') as stream:
        reader = make_reader(stream)
        assert reader.get_summary().statistics.message_count == len(values)
        assert {m.name for m in reader.iter_metadata()} >= {'det_sim_ros'}


@pytest.mark.ros
@pytest.mark.parametrize('mode', ['sync', 'bg'])
def test_sigint_finishes_the_file(tmp_path, mode):
    from mcap.reader import make_reader
    path = tmp_path / 'interrupted.mcap'
    child = _start_child(path, mode)
    try:
        flushed = _wait_flushes(child, 3)
        child.send_signal(signal.SIGINT)
        assert child.stdout.read().strip().endswith('closing')
    finally:
        child.wait(timeout=60)
    with open(path, 'rb') as stream:
        reader = make_reader(stream)  # seeking reader: needs the footer and summary
        count = reader.get_summary().statistics.message_count
        values = [m.data for _, _, m in reader.iter_messages()]
        end = {m.name: m.metadata for m in reader.iter_metadata()}['det_sim_ros.end']
    assert count == len(values) == int(end['messages']) >= flushed


def test_an_interrupt_right_after_a_write_still_counts_it(tmp_path, monkeypatch):
    """SIGINT between writing a message and counting it: the end counters match the file."""
    from mcap.reader import make_reader
    from std_msgs.msg import Float64MultiArray
    from det_sim_ros.io.log import file as log_file
    path = tmp_path / 'cut.mcap'
    recorder = Recorder(str(path), None)
    for k in range(3):
        recorder.record('voltage_command', Float64MultiArray(data=[float(k)]), k * 1000000)
    write = log_file.LogFile.add

    def write_then_interrupt(self, *args):
        write(self, *args)
        raise KeyboardInterrupt
    monkeypatch.setattr(log_file.LogFile, 'add', write_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        recorder.record('voltage_command', Float64MultiArray(data=[3.0]), 3000000)
    recorder.close()
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        count = reader.get_summary().statistics.message_count
        end = {m.name: m.metadata for m in reader.iter_metadata()}['det_sim_ros.end']
    assert count == int(end['messages']) == 4


def test_cdr_serializer_matches_rclpy_and_rosbags():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import deserialize_message
    from rosbags.typesys import get_typestore, Stores
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Empty, Float64MultiArray

    from det_sim_ros.io.log import serialize, type_name_of
    store = get_typestore(Stores.ROS2_JAZZY)
    joint = JointState(name=['det0', 'det1'], position=[1.0, -2.5], velocity=[3.0])
    joint.header.stamp.sec, joint.header.frame_id = 7, 'beam'
    status = DiagnosticStatus(level=b'\x02', name='log', message='disk full',
                              values=[KeyValue(key='path', value='/x')])
    for msg in (joint, JointState(), Float64MultiArray(data=[0.5, 1e300]), Clock(), Empty(),
                DiagnosticArray(status=[status, DiagnosticStatus()])):
        data = serialize(msg)
        assert deserialize_message(data, type(msg)) == msg
        store.deserialize_cdr(data, type_name_of(msg))  # strict: no trailing bytes
        assert serialize(msg) == data


def test_flush_by_sim_time_bounds_the_loss_whatever_the_speed(tmp_path):
    """
    Check that flushes every flush_sim_s of log time bound the loss at any speed.

    A frozen wall clock (a free run far faster than real time): the writer still flushes
    every flush_sim_s of log time, so at most that much sim time is only in memory.
    """
    from std_msgs.msg import Float64MultiArray
    recorder = Recorder(tmp_path / 'fast.mcap', None, clock=lambda: 0.0, flush_sim_s=0.05)
    for k in range(1001):                                  # 1 s of sim time at 1 kHz
        recorder.record('x', Float64MultiArray(data=[float(k)]), k * 1_000_000)
    assert recorder.flushes == 20
    on_disk = [m.log_time for m in LogReader(tmp_path / 'fast.mcap').messages()]
    assert 1.0 - on_disk[-1] * 1e-9 <= 0.05                # readable up to the last flush
    recorder.close()


def test_torn_file_is_recovered_in_place(tmp_path):
    """A file cut inside a write (power loss): recover_unfinished repairs it in place."""
    from mcap.reader import make_reader
    from std_msgs.msg import Float64MultiArray
    from det_sim_ros.io.log import is_torn, recover_unfinished
    live = tmp_path / 'live' / 'run.mcap'
    recorder = Recorder(live, None, flush_sim_s=0.01)
    for k in range(100):
        recorder.record('x', Float64MultiArray(data=[float(k)]), k * 1_000_000)
    path = tmp_path / 'det_sim_torn.mcap'    # the file on disk now, as a crash leaves it
    shutil.copyfile(live, path)
    recorder.close()
    with open(path, 'r+b') as stream:
        stream.truncate(os.path.getsize(path) - 20)     # the provisional end cut
    assert is_torn(str(path))
    good = tmp_path / 'det_sim_good.mcap'
    with Recorder(good, None) as other:
        other.record('x', Float64MultiArray(data=[1.0]), 0)
    repaired = recover_unfinished(str(tmp_path))
    assert [p for p, _ in repaired] == [str(path)] and not is_torn(str(path))
    with open(path, 'rb') as stream:
        values = [m.data for _, _, m in make_reader(stream).iter_messages()]
    assert len(values) == repaired[0][1]['messages'] >= 90
    assert recover_unfinished(str(tmp_path)) == []          # nothing left to repair


def test_log_directory_is_bounded(tmp_path):
    """
    Check that max_files / max_total_mb delete the oldest of the recorder's own files.

    Never the current one, never other files.
    """
    from std_msgs.msg import Float64MultiArray
    folder = tmp_path / 'logs'
    folder.mkdir()
    (folder / 'notes.mcap.txt').write_text('not ours')
    made = []
    for run in range(5):
        rec = Recorder(folder, None, max_files=3, prefix='det_sim')
        for k in range(50):
            rec.record('x', Float64MultiArray(data=[float(k)] * 100), k * 1_000_000)
        rec.new_file()                    # as a reset does
        rec.record('x', Float64MultiArray(data=[0.0]), 0)
        rec.close()
        made += rec.paths
        os.utime(rec.paths[-1])
    left = sorted(p for p in os.listdir(folder) if p.endswith('.mcap'))
    assert len(left) == 3 and {os.path.join(folder, p) for p in left} <= set(made[-3:])
    assert (folder / 'notes.mcap.txt').exists()
    big = Recorder(folder, None, max_total_mb=0.01, chunk_size=1024)   # 10 KiB in all
    for k in range(2000):
        big.record('x', Float64MultiArray(data=[float(k)] * 10), k * 1_000_000)
    assert big.deleted and [p for p in os.listdir(folder) if p.endswith('.mcap')] == \
        [os.path.basename(big.path)]
    big.close()


def _write_samples(path, fast, background=False, stress=False, dropouts=False):
    """
    500 samples of four topics and a command every 7th.

    ``stress``: what ends a run of the batched writer, often: log times that step back (clamped), a
    longer payload every 37th sample, a flush every 20 us of log time, a new file every 150 us, a
    writer queue of 5. ``dropouts``: every 9th sample lacks one topic (a sensor's dropped sample,
    each layout one tuple as the node gives it), inside the batched writer's runs.
    """
    from det_sim_ros.io.contract import encode_float64_multi_array, encode_joint_state, TOPIC_TYPES
    options = {'flush_sim_s': 2e-5, 'split_s': 1.5e-4, 'max_queue': 5} if stress else {}
    recorder = Recorder(path, load_scene('default', PAPER), chunk_size=2048,
                        background=background,
                        flush_period_s=1e9, packing=fast,   # False: one by one, add_message
                        **options)   # no wall-clock flushes: comparable
    topics = ['deflection', 'displacement', 'charge', 'current']
    layouts = [tuple(topics[:j] + topics[j + 1:]) for j in range(len(topics))]
    written = 0
    for k in range(500):
        t = k * 1000 - (2500 if stress and k % 11 == 5 else 0)
        if k % 7 == 0:
            recorder.record('voltage_command', encode_float64_multi_array([float(k)]),
                            t, TOPIC_TYPES['voltage_command'])
        names = ['det0' + ('_long' if stress and k % 37 == 3 else '')]
        data = [encode_joint_state(names, [k + i / 10.0], stamp_ns=k * 1000)
                for i in range(len(topics))]
        if dropouts and k % 9 == 4:
            gone = k // 9 % len(topics)
            recorder.record_sample(t, layouts[gone], data[:gone] + data[gone + 1:], TOPIC_TYPES)
        else:
            recorder.record_sample(t, topics, data, TOPIC_TYPES)
        written += len(topics) - (dropouts and k % 9 == 4)
        if fast and not background:
            assert recorder.packing
    recorder.close()
    assert recorder.fault == '' and recorder.messages == written + 72
    assert (recorder.clamped > 0) == stress
    return recorder.paths


@pytest.mark.parametrize('background, stress, dropouts', [
    (False, False, False), (True, False, False), (False, True, False), (True, True, False),
    (True, False, True), (True, True, True)])
def test_fast_sample_path_writes_the_same_file_as_add_message(tmp_path, monkeypatch, background,
                                                              stress, dropouts):
    """
    Check that the batched sample writer gives the bytes of one-by-one add_message calls.

    record_sample's batched writer (compiled record packing, runs of samples), record's
    single messages (and the writer thread) give the bytes add_message gives (mcap's Message
    record class; test_mcap_writer: the file is mcap.writer.Writer's, call for call):
    records, chunk indexes and statistics; also when clamped times, other payload sizes,
    flushes and file splits end the runs, and with samples that lack a topic inside them.
    """
    import time as time_module
    monkeypatch.setattr(time_module, 'time_ns', lambda: 1234)   # the wall start in the metadata
    slow = _write_samples(tmp_path / 'slow.mcap', fast=False, stress=stress, dropouts=dropouts)
    fast = _write_samples(tmp_path / 'fast.mcap', fast=True, background=background,
                          stress=stress, dropouts=dropouts)
    assert len(fast) == len(slow) == (4 if stress else 1)
    for slow_path, fast_path in zip(slow, fast):
        assert open(slow_path, 'rb').read() == open(fast_path, 'rb').read()
    from mcap.reader import make_reader
    count = 0
    for fast_path in fast:
        with open(fast_path, 'rb') as stream:
            count += make_reader(stream).get_summary().statistics.message_count
    assert count == 500 * 4 + 72 - (56 if dropouts else 0)


def test_pack_records_is_the_records_of_one_by_one_writes():
    """
    Check that pack_records writes the records of one-by-one writes.

    pack_records (core.kernel): MCAP Message records (opcode 5, length, channel, sequence, log
    and publish time, payload), sequences counting up per sample; it stops before a row of
    other payload sizes and refuses bad arguments.
    """
    from det_sim_ros.core.kernel import pack_records
    rows = [[b'ab', b'xyz'], (b'cd', b'uvw'), [b'e', b'rst']]
    records, count = pack_records((3, 70000 % 65536), [5, 9], [10, 2**40, 2**41], rows,
                                  (2, 3))
    assert count == 2
    head = struct.Struct('<BQHIQQ')
    expected = b''.join(head.pack(5, 22 + len(p), ch, first + j, t, t) + p
                        for j, (row, t) in enumerate(zip(rows[:2], [10, 2**40]))
                        for ch, first, p in zip((3, 70000 % 65536), (5, 9), row))
    assert records == expected
    assert pack_records((1,), [0], [], [], (1,)) == (b'', 0)
    for bad in [((70000,), [0], [1], [[b'a']], (1,)),      # channel id beyond uint16
                ((1,), [-1], [1], [[b'a']], (1,)),         # negative sequence
                ((1,), [0], [-1], [[b'a']], (1,)),         # negative time
                ((1, 2), [0], [1], [[b'a']], (1,)),        # lengths disagree
                ((1,), [0], [], [[b'a']], (1,))]:          # a row without a time
        with pytest.raises(ValueError):
            pack_records(*bad)


def test_background_queue_stays_bounded_when_the_writer_falls_behind(tmp_path):
    """
    Check that the writer queue stays bounded when the writer thread falls behind.

    A free run records faster than the writer thread gets the GIL: past max_queue records
    the recording thread writes the queue itself, so memory and what a SIGKILL could lose stay
    bounded; everything lands, in order.
    """
    from det_sim_ros.io.contract import encode_joint_state, TOPIC_TYPES
    recorder = Recorder(tmp_path / 'bounded.mcap', None, background=True, max_queue=8)
    topics = ['deflection', 'displacement']
    longest = 0
    for k in range(3000):
        data = [encode_joint_state(['det0'], [float(k)], stamp_ns=k * 1000)] * len(topics)
        recorder.record_sample(k * 1000, topics, data, TOPIC_TYPES)
        longest = max(longest, recorder.queued)
    recorder.close()
    assert longest <= 8 and recorder.caught_up > 0
    assert recorder.fault == '' and recorder.messages == 6000 and recorder.dropped == 0
    times = [m.log_time for m in LogReader(tmp_path / 'bounded.mcap').messages(['/deflection'])]
    assert times == [k * 1000 for k in range(3000)]


def test_background_recording_drops_nothing_while_the_writer_switches_files(
        tmp_path, monkeypatch):
    """
    Check that records queued while the writer thread switches files all land.

    The writer thread owns the MCAP writer (None for a moment between two files): records
    queued meanwhile by the node's thread must all land, none counted as dropped.
    """
    import threading
    import time as _time
    from std_msgs.msg import Float64MultiArray
    from det_sim_ros.io.log import file as log_file
    switching = threading.Event()

    class SlowToOpen(log_file.TailStream):   # the gap between closing a file and the next
        def __init__(self, path):
            if switching.is_set() or not path.endswith('_001.mcap'):
                return super().__init__(path)
            switching.set()
            _time.sleep(0.2)
            super().__init__(path)
    monkeypatch.setattr(log_file, 'TailStream', SlowToOpen)
    recorder = Recorder(tmp_path / 'bg.mcap', None, background=True)
    recorder.record('x', Float64MultiArray(data=[0.0]), 0)
    recorder.new_file()
    assert switching.wait(5.0)
    for k in range(1, 50):           # recorded while the writer has no file
        recorder.record('x', Float64MultiArray(data=[float(k)]), k * 1_000_000)
    recorder.close()
    assert recorder.dropped == 0
    values = [m.decode().data[0] for path in recorder.paths
              for m in LogReader(path).messages()]
    assert values == [float(k) for k in range(50)]
