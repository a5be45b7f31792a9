"""
The ROS-free topic contract: output bytes, command decoding and checks.

The bytes of every output equal the simulator's values (read by rclpy and by rosbags); no
rclpy import.
"""

import math
import struct
import subprocess
import sys

from conftest import child_env
from det_sim_ros.io.contract import (CdrError, clamp_message, Command, CommandDecoder,
                                     decode_float64_multi_array, decode_joint_state, encode_clock,
                                     encode_float64_multi_array, encode_joint_state, JOINT_STATE,
                                     OUTPUT_FIELDS, OutputContract)
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest


def _run(scene, volts, n):
    sim = Simulator(scene)
    sim.set_input(volts)
    for _ in range(n):
        out = sim.step()
    return sim, out.copy()


@pytest.mark.parametrize('scene_name, overrides', [
    ('default', {}), ('plate', {}),
    ('array', {'structure.copies': 3, 'structure.spread': 0.05}),
    ('array', {'structure.copies': 20, 'structure.spread': 0.05})])   # the numpy path
def test_encoded_samples_decode_to_exactly_the_simulator_values(scene_name, overrides):
    from rclpy.serialization import deserialize_message
    from rosbags.typesys import get_typestore, Stores
    from sensor_msgs.msg import JointState
    store = get_typestore(Stores.ROS2_JAZZY)
    scene = load_scene(scene_name, overrides)
    n = len(scene.cell_physics())
    sim, out = _run(scene, [2500.0] * n, 37)
    contract = OutputContract(sim.model)
    encoder = contract.encoder()
    t_ns = 37_000_000
    data = encoder.encode(out, t_ns)
    assert len(data) == len(contract.topics)
    y_index = sim.model.channel('y')
    for topic, payload in zip(encoder.topics, data):
        ours = deserialize_message(payload, JointState)
        theirs = store.deserialize_cdr(payload, JOINT_STATE)   # strict: no trailing bytes
        plain = decode_joint_state(payload)
        for msg in (ours, theirs):
            stamp = msg.header.stamp
            assert stamp.sec * 10**9 + stamp.nanosec == t_ns
            assert list(msg.name) == contract.names(topic)
        assert plain.stamp_ns == t_ns and plain.name == contract.names(topic)
        if topic == contract.structure_topic:
            expected = {'position': contract.structure(out)}
        else:
            expected = {field: np.array([out[i] for i in sim.model.channel(output)])
                        for field, output in OUTPUT_FIELDS[topic].items()}
            if topic == 'displacement':   # y0_i - y_i, y0 from the statics of cell i
                expected['position'] = contract.y0 - out[y_index]
        for field in ('position', 'velocity', 'effort'):
            want = expected.get(field, np.array([]))
            for got in (np.array(getattr(ours, field)), np.array(getattr(theirs, field)),
                        np.array(getattr(plain, field))):
                assert got.tobytes() == want.tobytes(), (topic, field)   # bit for bit
    # a second sample reuses the buffers: earlier bytes objects are not changed
    first = list(data)
    out2 = sim.step().copy()
    second = encoder.encode(out2, t_ns + 1_000_000)
    assert first == data and second != first
    assert decode_joint_state(second[0]).stamp_ns == t_ns + 1_000_000


@pytest.mark.parametrize('scene_name, overrides', [
    ('default', {}), ('plate', {}), ('array', {'structure.copies': 20}),
    ('default', {'scene.fidelity': 'exact', 'scene.n_ritz': 2})])
def test_compiled_encoding_is_the_reference_bytes(scene_name, overrides):
    """
    Check that the compiled encoder writes the struct-packed reference's bytes.

    The compiled encoder (SampleCodec) writes the struct-packed reference's bytes, for
    simulator states and random output vectors (signed zeros, tiny and huge values), stamps
    from 0 to 2^31 s; it refuses an output vector too short for the contract.
    """
    scene = load_scene(scene_name, overrides)
    sim, out = _run(scene, [1800.0] * len(scene.cell_physics()), 11)
    encoder = OutputContract(sim.model).encoder()
    rng = np.random.default_rng(7)
    vectors = [out, np.zeros_like(out), -np.zeros_like(out),
               rng.standard_normal(out.size) * 10.0 ** rng.integers(-300, 300, out.size)]
    for vector in vectors:
        for t_ns in (0, 11_000_000, 2**31 * 10**9 - 1):
            reference = encoder.encode_values(encoder.values(vector), t_ns)
            assert encoder.encode(vector, t_ns) == reference
            assert encoder.encode(list(vector), t_ns) == reference   # any float sequence
            assert decode_joint_state(reference[0]).stamp_ns == t_ns
    with pytest.raises(ValueError, match='outputs'):
        encoder.encode(out[:max(encoder.wire.source)], 0)


def test_displacement_and_rest_state():
    """Δy = y0 - y, y0 from the statics; the initial state of the default scene is at rest."""
    scene = load_scene('default')
    sim = Simulator(scene)
    contract = OutputContract(sim.model)
    from det_sim_ros.physics.statics import rest_shortening
    assert contract.y0.tolist() == [rest_shortening(scene)]
    sim, out = _run(scene, [3000.0], 300)
    dy = contract.values(out, 'displacement', 'position')
    assert dy[0] == contract.y0[0] - out[sim.model.output_names.index('y')]
    assert dy[0] > 1e-3   # 3 kV lengthens the DET: the beam deflects further, y0 - y > 0


def test_cdr_round_trips_and_matches_rclpy():
    from rclpy.serialization import deserialize_message, serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    joint = encode_joint_state(['a', 'bb', 'ccc'], [1.0, 2.0, 3.0], [], [0.5], 12_345_678_901,
                               'frame')
    msg = deserialize_message(joint, JointState)
    assert msg.name == ['a', 'bb', 'ccc'] and list(msg.effort) == [0.5]
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 345_678_901)
    assert msg.header.frame_id == 'frame'
    # rclpy's bytes (padding uninitialised, trailing bytes) decode to the same fields
    decoded = decode_joint_state(serialize_message(msg))
    assert decoded.name == ['a', 'bb', 'ccc'] and decoded.position == [1.0, 2.0, 3.0]
    assert decoded.stamp_ns == 12_345_678_901 and decoded.effort == [0.5]
    array = Float64MultiArray(data=[1.5, -2.0])
    array.layout.dim = [MultiArrayDimension(label='x', size=2, stride=2)]
    raw = serialize_message(array)
    values, dims, offset = decode_float64_multi_array(raw)
    assert values == [1.5, -2.0] and dims == [('x', 2, 2)] and offset == 0
    assert deserialize_message(encode_float64_multi_array(values, dims), Float64MultiArray) \
        == array
    clock = deserialize_message(encode_clock(3_000_000_007), Clock)
    assert (clock.clock.sec, clock.clock.nanosec) == (3, 7)


def test_big_endian_cdr_is_read():
    body = struct.pack('>I', 0) + struct.pack('>I', 0) + struct.pack('>I', 2) + bytes(4) \
        + struct.pack('>2d', 7.0, 8.0)
    assert decode_float64_multi_array(b'\x00\x00\x00\x00' + body)[0] == [7.0, 8.0]


@pytest.mark.parametrize('data', [b'', b'\x01\x02\x00\x00', b'\x00\x01\x00\x00\x01',
                                  b'\x00\x01\x00\x00' + struct.pack('<I', 10**6)])
def test_malformed_bytes_raise_cdr_error(data):
    with pytest.raises(CdrError):
        decode_float64_multi_array(data)
    with pytest.raises(CdrError):
        decode_joint_state(data)


def test_command_rules_per_channel():
    decoder = CommandDecoder(['left', 'right'], v_max=3000.0)
    held = [100.0, 200.0]
    ok = decoder.decode('voltage_command', encode_float64_multi_array([1000.0, 2000.0]), held)
    assert ok.volts == [1000.0, 2000.0] and not ok.reason and not ok.clamped
    assert decode_float64_multi_array(ok.canonical)[0] == [1000.0, 2000.0]
    nan = decoder.decode('voltage_command', encode_float64_multi_array([1.0, math.nan]), held)
    assert nan.volts is None and 'non-finite voltage on right' in nan.reason
    assert 'left' not in nan.reason
    short = decoder.decode('voltage_command', encode_float64_multi_array([1.0]), held)
    assert short.volts is None and 'expected 2 voltage(s) [left, right], got 1' in short.reason
    clamped = decoder.decode('voltage_command', encode_float64_multi_array([-5.0, 4000.0]), held)
    assert clamped.volts == [-5.0, 4000.0]   # the simulator clamps; the decoder names them
    assert clamped.clamped == ('left: -5 V', 'right: 4000 V')
    subset = decoder.decode('voltage_command_joint',
                            encode_joint_state(['right'], [700.0], stamp_ns=5), held)
    assert subset.volts == [100.0, 700.0] and subset.stamp_ns == 5
    unknown = decoder.decode('voltage_command_joint', encode_joint_state(['det0'], [1.0]), held)
    assert unknown.volts is None and 'unknown DET name' in unknown.reason
    counts = decoder.decode('voltage_command_joint',
                            encode_joint_state(['left', 'right'], [1.0]), held)
    assert counts.volts is None and '2 name(s) but 1 position value(s)' in counts.reason
    bad = decoder.decode('voltage_command_joint', encode_joint_state(['left'], [math.inf]), held)
    assert bad.volts is None and 'non-finite voltage on left' in bad.reason
    twice = decoder.decode('voltage_command_joint',
                           encode_joint_state(['left', 'left'], [1.0, 2.0]), held)
    assert twice.volts is None and "['left'] given more than once" in twice.reason
    empty = decoder.decode('voltage_command_joint', encode_joint_state([], []), held)
    assert empty.volts is None and 'empty JointState' in empty.reason
    torn = decoder.decode('voltage_command', b'\x00\x01\x00\x00\x05', held)
    assert torn.volts is None and 'malformed' in torn.reason and not torn.canonical


@pytest.mark.parametrize('n', [1, 2, 100])
def test_vector_command_fast_path_gives_what_the_general_path_gives(n):
    """
    Check that a plain Float64MultiArray command read by one unpack reads as in general.

    A plain Float64MultiArray command is read by one unpack: same voltages and canonical
    bytes as the general reader, whatever its padding held (rclpy leaves it uninitialised);
    anything else (dims, an offset, a wrong count, NaN, out of range, big endian, too short)
    takes the general path and its reasons.
    """
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64MultiArray
    names = [f'd{i}' for i in range(n)]
    decoder = CommandDecoder(names, v_max=3000.0)
    held = [0.0] * n
    volts = [1000.0 + i for i in range(n)]

    def general(data):   # the reader without the fast path
        values, dims, offset = decode_float64_multi_array(data)
        return decoder.from_vector(values, encode_float64_multi_array(values, dims, offset))
    plain = encode_float64_multi_array(volts)
    dirty = plain[:16] + b'\xab\xcd\xef\x01' + plain[20:]      # garbage in the padding
    for data in (plain, dirty, serialize_message(Float64MultiArray(data=volts)), plain + b'\0'):
        fast = decoder.decode('voltage_command', data, held)
        assert fast == general(data) and fast.canonical == plain
    others = [encode_float64_multi_array(volts, dims=[('x', n, n)]),
              encode_float64_multi_array(volts, data_offset=1),
              encode_float64_multi_array(volts + [1.0]), encode_float64_multi_array([-1.0] * n),
              encode_float64_multi_array([math.nan] * n), plain[:-1]]
    for data in others:
        assert decoder.decode('voltage_command', data, held) == (
            general(data) if len(data) != len(plain) - 1 else
            Command(None, 'voltage_command: malformed message (truncated CDR message '
                          f'({len(data)} bytes))'))
    big = b'\x00\x00\x00\x00' + struct.pack(f'>III4x{n}d', 0, 0, n, *volts)
    assert decoder.decode('voltage_command', big, held).volts == volts


@pytest.mark.ros
def test_contract_and_replay_need_no_rclpy(tmp_path):
    """The contract, the recorder and re-simulation run without importing rclpy."""
    code = (
        'import sys\n'
        'from det_sim_ros.io import contract\n'
        'from det_sim_ros.io.log import Recorder\n'
        'from det_sim_ros.io.replay import resimulate, simulate_to_log\n'
        'from det_sim_ros.scenes.scene import load_scene\n'
        'from det_sim_ros.sim.simulator import Simulator\n'
        'scene = load_scene("plate")\n'
        'sim = Simulator(scene)\n'
        f'recorder = Recorder({str(tmp_path / "run.mcap")!r}, scene, metadata={{\n'
        '    "method": sim.method.name, "substeps": sim.substeps_setting})\n'
        'simulate_to_log(recorder, sim, lambda k: [1000.0 + k, 2000.0] if k % 7 == 0 else None,'
        ' 50, joint_commands=True)\n'
        'recorder.close()\n'
        f'result = resimulate({str(tmp_path / "run.mcap")!r})\n'
        'assert result.ok(0.0) and result.commands == 8, result.table()\n'
        'assert not [m for m in sys.modules if m.startswith("rclpy")], "rclpy imported"\n'
        'print("ok")\n')
    env = child_env()
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          env=env, timeout=600)
    assert proc.returncode == 0 and proc.stdout.strip() == 'ok', proc.stderr


def test_inputs_within_is_the_generator_check():
    """
    Check that simulator.inputs_within answers as all(0 <= v <= v_max) does.

    simulator.inputs_within (sum, min, max in C) answers as all(0 <= v <= v_max) does, for
    NaN, infinities, signed zeros, subnormals, overflowing sums and random lists.
    """
    import random
    from det_sim_ros.sim.simulator import inputs_within
    nan, inf = float('nan'), float('inf')
    pool = [0.0, -0.0, 1.0, 3000.0, 3000.0000001, -1e-300, 5e-324, nan, inf, -inf, 1e308,
            -1e308, 1500.0]
    rng = random.Random(1)
    for n in (1, 2, 3, 100):
        for _ in range(3000):
            values = [rng.choice(pool) if rng.random() < 0.3 else rng.uniform(-10.0, 3010.0)
                      for _ in range(n)]
            assert inputs_within(values, 3000.0) == all(0.0 <= v <= 3000.0 for v in values)


def test_sample_codec_refuses_inconsistent_fields():
    """
    Check that SampleCodec checks its named fields.

    SampleCodec (core.kernel) checks its named fields: a value or stamp outside the messages, a
    bad op, offsets that do not span the template; it is built once.
    """
    import dataclasses
    from det_sim_ros.core.kernel import SampleCodec
    encoder = OutputContract(Simulator(load_scene('default')).model).encoder()
    wire = encoder.wire
    size = len(wire.template)
    bad = [dataclasses.replace(wire, position=wire.position + size),
           dataclasses.replace(wire, op=wire.op + 3),
           dataclasses.replace(wire, source=wire.source - 1000),
           dataclasses.replace(wire, stamp_position=wire.stamp_position + size),
           dataclasses.replace(wire, template=wire.template + b'\0'),
           dataclasses.replace(wire, a=wire.a[:-1])]
    for fields in bad:
        with pytest.raises(ValueError):
            SampleCodec(fields)
    codec = SampleCodec(wire)
    with pytest.raises(RuntimeError):
        codec.__init__(wire)
    with pytest.raises(TypeError):
        codec.encode([0.0] * 3, 0)   # not a buffer of float64


# What each published field carries, stated here from the README's topic table, independently
# of contract.OUTPUT_FIELDS (the table the encoder is built from): a swapped or misrouted field
# in that table makes the comparison below fail.
PUBLISHED = {('deflection', 'position'): 'q', ('deflection', 'velocity'): 'q_dot',
             ('displacement', 'position'): 'y', ('charge', 'position'): 'q_p',
             ('current', 'position'): 'i_DE'}


def _output(sim, out, name, det):
    """Return the simulator's value of output ``name`` of DET ``det``, by its output name."""
    names = list(sim.model.output_names)
    key = name if name in names else f'{name}[{det}]'
    return float(out[names.index(key)])


def _independent_mismatches(scene, sim, out, encoder, t_ns):
    """
    Return the encoder's fields, decoded by rclpy, that differ from the simulator's.

    The simulator's values: the displacement y0 - y with y0 from each cell's statics; the
    plate: the mean and the tilt of the two displacements.
    """
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from det_sim_ros.physics.statics import rest_shortening
    dets = list(scene.det_names)
    y0 = [float(rest_shortening(scene.cell_scene(i))) for i in range(len(dets))]
    dy = [y0[i] - _output(sim, out, 'y', det) for i, det in enumerate(dets)]
    wrong = []
    for topic, data in zip(encoder.topics, encoder.encode(out, t_ns)):
        msg = deserialize_message(data, JointState)
        if msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec != t_ns:
            wrong.append((topic, 'stamp'))
        if topic == 'structure':
            w = scene.structure['plate_width']
            want = {'plate_dy': 0.5 * (dy[0] + dy[1]), 'plate_phi': (dy[1] - dy[0]) / w}
            got = dict(zip(msg.name, msg.position))
            wrong += [(topic, name) for name in want
                      if not math.isclose(got.get(name, math.nan), want[name], rel_tol=1e-6,
                                          abs_tol=1e-12)]
            continue
        if list(msg.name) != dets:
            wrong.append((topic, 'name'))
        for field in ('position', 'velocity', 'effort'):
            output = PUBLISHED.get((topic, field))
            if output is None:
                want = []
            elif output == 'y':
                want = dy
            else:
                want = [_output(sim, out, output, det) for det in dets]
            if list(getattr(msg, field)) != want:
                wrong.append((topic, field))
    return wrong


@pytest.mark.parametrize('scene_name, overrides', [
    ('default', {}), ('plate', {}), ('array', {'structure.copies': 3, 'structure.spread': 0.05})])
def test_samples_read_by_rclpy_are_the_simulator_values(scene_name, overrides):
    """
    Check that the encoder's bytes, decoded by rclpy, hold the simulator's outputs.

    The encoder's bytes, decoded by rclpy's own deserializer, hold on each topic and field
    the simulator's output of the README's table, per DET by name.
    """
    scene = load_scene(scene_name, overrides)
    sim, out = _run(scene, [2200.0] * len(scene.cell_physics()), 23)
    encoder = OutputContract(sim.model).encoder()
    assert _independent_mismatches(scene, sim, out, encoder, 23_000_000) == []


def test_the_independent_check_sees_a_swapped_field(monkeypatch):
    """The check above fails when the contract's field table routes a field wrongly."""
    from det_sim_ros.io import contract
    scene = load_scene('default')
    sim, out = _run(scene, [2200.0], 23)
    monkeypatch.setitem(contract.OUTPUT_FIELDS, 'deflection',
                        {'position': 'q_dot', 'velocity': 'q'})
    encoder = OutputContract(sim.model).encoder()
    assert _independent_mismatches(scene, sim, out, encoder, 23_000_000) == [
        ('deflection', 'position'), ('deflection', 'velocity')]


def test_commands_and_clock_read_by_rclpy():
    """
    Check that command and clock bytes, decoded by rclpy, hold the encoded values.

    Float64MultiArray, JointState and Clock bytes of the contract.
    """
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    array = deserialize_message(encode_float64_multi_array([1.0, -2.5, 3e-300],
                                                           [('volts', 3, 3)], 1),
                                Float64MultiArray)
    assert list(array.data) == [1.0, -2.5, 3e-300] and array.layout.data_offset == 1
    dim = array.layout.dim[0]
    assert (dim.label, dim.size, dim.stride) == ('volts', 3, 3)
    joint = deserialize_message(encode_joint_state(['left', 'right'], [10.0, 20.0], [1.5],
                                                   [-1.0, -2.0], 2**31 * 10**9 - 1, 'f'),
                                JointState)
    assert (list(joint.name), list(joint.position), list(joint.velocity),
            list(joint.effort)) == (['left', 'right'], [10.0, 20.0], [1.5], [-1.0, -2.0])
    assert (joint.header.stamp.sec, joint.header.stamp.nanosec, joint.header.frame_id) == (
        2**31 - 1, 999_999_999, 'f')
    for t_ns in (0, 1, 5_123_456_789):
        clock = deserialize_message(encode_clock(t_ns), Clock).clock
        assert clock.sec * 10**9 + clock.nanosec == t_ns


def test_clock_bytes_are_the_writers_layout():
    """encode_clock's one pack is the CDR Writer's bytes of a Clock (a header and a stamp)."""
    from det_sim_ros.io.cdr import Writer
    for t_ns in (0, 7, 3_000_000_007, 2**31 * 10**9 - 1):
        w = Writer()
        w.stamp(t_ns)
        assert encode_clock(t_ns) == w.to_bytes()


def test_the_clamp_warning_names_the_channel_then_the_value():
    """Check the warning the node logs for a clamped command, from the contract's decoding."""
    for names, volts, expected in (
            (['det0'], [-5.0], 'det0: -5 V clamped to [0, 3000] V (voltage_command)'),
            (['left', 'right'], [3500.0, 10.0],
             'left: 3500 V clamped to [0, 3000] V (voltage_command)')):
        command = CommandDecoder(names, 3000.0).decode(
            'voltage_command', encode_float64_multi_array(volts), [0.0] * len(names))
        assert clamp_message('voltage_command', command.clamped, 3000.0) == expected
