"""
Test the replay of MCAP logs: bit-exact re-simulation, timed republishing, CLI.

Replay of MCAP logs: bit-exact re-simulation, republishing with the recorded timing, CLI
(``det_sim_replay`` and ``det_sim replay``).
"""

import threading

from det_sim_ros.cli import main as det_sim
from det_sim_ros.cli import main_replay as main
from det_sim_ros.io.log import LogReader, Recorder
from det_sim_ros.io.replay import OUTPUT_FIELDS, resimulate, simulate_to_log
from det_sim_ros.ros.play import play
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

# the paper's one-term model: the fidelity is not the subject of these tests, and its
# numbers are the ones pinned here
PAPER = {'scene.fidelity': 'paper'}

N_STEPS = 400


def _commands(k):
    if k % 40 == 0:
        return [300.0 + 7.0 * k]
    if k == 333:
        return [float('nan')]  # refused by the model, as in the node
    return None


def _write_log(path, scene, joint_commands=False, n_steps=N_STEPS, commands=_commands):
    sim = Simulator(scene)
    recorder = Recorder(path, scene, metadata={'method': sim.method.name,
                                               'substeps': sim.substeps_setting})
    simulate_to_log(recorder, sim, commands, n_steps, joint_commands=joint_commands)
    recorder.close()
    assert recorder.fault == ''
    return str(path)


@pytest.fixture(scope='module')
def scene():
    return load_scene('default', PAPER)


@pytest.fixture(scope='module')
def log_path(tmp_path_factory, scene):
    return _write_log(tmp_path_factory.mktemp('replay') / 'run.mcap', scene)


def test_resim_reproduces_the_log_bit_for_bit(log_path):
    """
    Check that re-simulation reproduces the log bit for bit.

    Same scene + same stepper: every logged output is reproduced exactly (deviation 0.0).
    """
    result = resimulate(log_path)
    assert result.fault == '' and result.skipped == 0 and result.complete
    assert result.steps == N_STEPS and result.commands == N_STEPS // 40 + 1
    assert set(result.compared) == {f'{topic}.{field} ({name})'
                                    for topic, fields in OUTPUT_FIELDS.items()
                                    for field, name in fields.items()}
    assert all(count == N_STEPS + 1 for count in result.compared.values())
    assert all(value == 0.0 for value in result.max_deviation.values())
    assert result.ok(tolerance=0.0)


def test_resim_joint_state_commands(tmp_path, scene):
    path = _write_log(tmp_path / 'joint.mcap', scene, joint_commands=True, n_steps=120)
    result = resimulate(path)
    assert result.commands == 3 and result.ok()


def _other_substeps(log_path):
    return str(int(LogReader(log_path).info['substeps']) + 7)


def test_resim_detects_a_different_stepper(log_path):
    result = resimulate(log_path, substeps=int(_other_substeps(log_path)))
    assert result.fault == '' and not result.ok()
    assert max(result.max_deviation.values()) > 0.0


def test_resim_cli_exit_codes(log_path, capsys):
    assert main(['resim', log_path]) == 0
    out = capsys.readouterr().out
    assert 'bit-exact' in out and 'deflection.position (q)' in out
    other = _other_substeps(log_path)
    assert main(['resim', log_path, '--substeps', other]) == 1
    assert 'MISMATCH' in capsys.readouterr().out
    assert main(['resim', log_path, '--substeps', other, '--tolerance', '1.0']) == 0


def test_resim_of_a_cut_log(tmp_path, log_path):
    """Check that a log cut short (as by SIGKILL) re-simulates exactly up to the cut."""
    data = open(log_path, 'rb').read()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:len(data) // 2])
    result = resimulate(str(cut))
    assert not result.complete and result.fault == ''
    assert 0 < result.steps < N_STEPS
    assert all(value == 0.0 for value in result.max_deviation.values())


def test_info_and_recover_cli(tmp_path, log_path, capsys):
    assert main(['info', log_path]) == 0
    out = capsys.readouterr().out
    assert '/deflection' in out and 'finished' in out
    data = open(log_path, 'rb').read()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:len(data) * 2 // 3])
    assert main(['recover', str(cut), str(tmp_path / 'fixed.mcap')]) == 0
    assert 'source was unfinished' in capsys.readouterr().out
    fixed = LogReader(tmp_path / 'fixed.mcap')
    assert list(fixed.messages()) and fixed.complete
    assert resimulate(str(tmp_path / 'fixed.mcap')).ok()


def test_det_sim_replay_verb_is_the_same_command(tmp_path, log_path, capsys):
    """
    Check that ``det_sim replay`` and ``det_sim_replay`` print the same and exit alike.

    ``det_sim replay ...`` and ``det_sim_replay ...`` print the same and exit alike.
    """
    other = _other_substeps(log_path)
    for argv in (['info', log_path], ['resim', log_path],
                 ['resim', log_path, '--substeps', other]):
        code = main(argv)
        alone = capsys.readouterr()
        assert det_sim(['replay'] + argv) == code
        assert capsys.readouterr() == alone
    assert main([]) == 2 and det_sim(['replay']) == 2
    assert 'required: command' in capsys.readouterr().err


@pytest.mark.parametrize('argv, message', [
    (['resim', 'nowhere.mcap'], 'No such file'),
    (['info', 'nowhere.mcap'], 'No such file'),
    (['recover', 'nowhere.mcap', 'out.mcap'], 'No such file'),
    (['resim', 'NOT_MCAP'], 'not an MCAP file'),
])
def test_replay_errors_are_one_line(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / 'NOT_MCAP').write_bytes(b'not an mcap file')
    for run, prog in ((main, 'det_sim_replay'), (lambda a: det_sim(['replay'] + a), 'det_sim')):
        assert run(argv) == 1
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and err.startswith(f'{prog}: error: ') and message in err


def test_ros_args_end_the_line(log_path):
    """
    Check that ``--ros-args`` at the end of a replay line is taken whole, for the player node.

    ``--ros-args ...`` at the end of a replay line is taken whole (the player node's).
    """
    from det_sim_ros.cli.det_sim import build_parser
    args = build_parser().parse_args(['replay', 'play', log_path, '--rate', '0', '--ros-args',
                                      '-r', '__ns:=/x', '-p', 'use_sim_time:=true'])
    assert args.log == [log_path] and args.rate == 0.0
    assert args.ros_args == ['-r', '__ns:=/x', '-p', 'use_sim_time:=true']
    args = build_parser().parse_args(['replay', 'info', log_path, '--ros-args', '-r', 'a:=b'])
    assert args.ros_args == ['-r', 'a:=b']


def _subscribe(context, topics):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    node = rclpy.create_node('replay_listener', context=context)
    received = []
    lock = threading.Lock()

    def callback(topic):
        def on_message(msg):
            with lock:
                received.append((topic, msg))
        return on_message
    for topic in topics:
        node.create_subscription(JointState, topic, callback(topic), 1000)
    from rclpy.qos import qos_profile_sensor_data
    node.create_subscription(Clock, '/clock', callback('/clock'), qos_profile_sensor_data)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    return node, executor, thread, received


def _stamp(msg):
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def _wait_matched(player_node, topics, context):
    import time
    deadline = time.monotonic() + 30.0  # discovery; not a timing assertion
    while time.monotonic() < deadline:
        counts = [player_node.count_subscribers(t) for t in topics]
        if all(counts):
            return
        time.sleep(0.05)
    raise AssertionError('subscribers were not discovered')


@pytest.mark.ros
def test_play_preserves_order_stamps_and_rate(tmp_path, scene, ros_context):
    import time

    import rclpy
    path = _write_log(tmp_path / 'short.mcap', scene, n_steps=60)
    everything = list(LogReader(path).messages())
    logged = [(m.topic, m.log_time) for m in everything if m.topic == '/deflection']
    node, executor, thread, received = _subscribe(ros_context, ['/deflection'])
    player = rclpy.create_node('det_sim_replay', context=ros_context)
    try:
        # create the publishers before playing so that nothing is lost to discovery
        from sensor_msgs.msg import JointState
        player.create_publisher(JointState, '/deflection', 10)
        _wait_matched(player, ['/deflection'], ros_context)
        rate = 2.0
        stats = play(path, node=player, rate=rate, clock=True, topics=['/deflection'])
        assert stats.published == {'/deflection': 61} and stats.clock == 61
        # the player never publishes ahead of the recorded timing divided by the rate
        start = stats.schedule[0][1]
        for wall, log_time in stats.schedule:
            assert wall >= (log_time - start) / 1e9 / rate
        deadline = time.monotonic() + 30.0
        while (len([r for r in received if r[0] == '/deflection']) < 61
               or not any(r[0] == '/clock' for r in received)):
            assert time.monotonic() < deadline, 'messages were lost'
            time.sleep(0.02)
        stamps = [_stamp(msg) for topic, msg in received if topic == '/deflection']
        assert stamps == [t for _, t in logged]  # order and header stamps preserved
        clocks = [msg.clock.sec * 10**9 + msg.clock.nanosec
                  for topic, msg in received if topic == '/clock']
        assert clocks == sorted(clocks) and set(clocks) <= {t for _, t in logged}
        assert clocks  # best effort: some may be dropped, but not all

        # start offset and loop
        received.clear()
        stats = play(path, node=player, rate=0, start_offset=0.030, loop=True, max_loops=2,
                     topics=['/deflection'])
        first = everything[0].log_time + 30_000_000  # the offset counts from the log start
        expected = [t for _, t in logged if t >= first]
        assert stats.loops == 2 and stats.published['/deflection'] == 2 * len(expected)
        deadline = time.monotonic() + 30.0
        while len([r for r in received if r[0] == '/deflection']) < 2 * len(expected):
            assert time.monotonic() < deadline, 'messages were lost'
            time.sleep(0.02)
        stamps = [_stamp(msg) for topic, msg in received if topic == '/deflection']
        assert stamps == expected + expected
    finally:
        executor.shutdown()
        thread.join(timeout=10)
        player.destroy_node()
        node.destroy_node()


@pytest.mark.ros
def test_node_log_resimulates_bit_for_bit(tmp_path, harness):
    """
    Check that the node's own log re-simulates bit for bit.

    The node's own log (free-run, commands at arbitrary steps, a reset) re-simulates exactly.
    """
    h = harness(**{'log.path': str(tmp_path / 'logs'), 'steps_per_tick': 5})
    recorder = h.node.recorder
    assert recorder is not None and recorder.active
    for volts in (800.0, 1500.0, 400.0):
        h.command([volts])
        h.spin_until(lambda: h.node.commands.received >= 1, 'command')
        h.spin_until_sim_time(h.node.simulator.t + 0.02)
    h.joint_command(['det0'], [1200.0])
    h.spin_until_sim_time(h.node.simulator.t + 0.02)
    h.call('reset')
    h.command([600.0])
    h.spin_until_sim_time(0.03)
    h.close()   # destroys the node: the recorder closes its file
    assert recorder.fault == '' and len(recorder.paths) == 2  # reset starts a new file
    for path in recorder.paths:
        result = resimulate(path)
        assert result.complete and result.commands >= 1 and result.steps > 0
        assert result.ok(tolerance=0.0), result.table()
        assert all(v == 0.0 for v in result.max_deviation.values())


def _plate_commands(k):
    if k % 40 == 0:
        return [300.0 + 7.0 * k, 2500.0 - 5.0 * k]
    if k == 333:
        return [1000.0, float('nan')]  # refused by the model, as in the node
    return None


@pytest.mark.parametrize('joint_commands', [False, True])
def test_resim_plate_log(tmp_path, joint_commands):
    """
    Check that a logged plate run re-simulates bit for bit, structure topic included.

    Two DETs: a logged plate run (vector or named joint commands) re-simulates bit-for-bit,
    every topic names both DETs, and the structure topic is compared too.
    """
    scene = load_scene('plate', PAPER)
    path = _write_log(tmp_path / 'plate.mcap', scene, joint_commands=joint_commands,
                      n_steps=200, commands=_plate_commands)
    reader = LogReader(path)
    seen = {}
    for message in reader.messages():
        name = message.topic.rsplit('/', 1)[-1]
        seen.setdefault(name, list(message.decode().name) if name != 'voltage_command' else None)
    assert seen['displacement'] == ['left', 'right']
    assert seen['structure'] == ['plate_dy', 'plate_phi']
    if joint_commands:
        assert seen['voltage_command_joint'] == ['left', 'right']
    result = resimulate(path)
    assert result.ok(tolerance=0.0), result.table()
    assert 'structure.position (plate_y, plate_phi)' in result.compared
    assert all(count == 201 for count in result.compared.values())
    assert all(value == 0.0 for value in result.max_deviation.values())


@pytest.mark.ros
def test_node_plate_log_resimulates_bit_for_bit(tmp_path, harness):
    """
    Check that the node's log of a plate run re-simulates bit for bit.

    The node's log of a plate run (vector and joint commands) re-simulates exactly, the
    per-DET y0 logged as a list.
    """
    h = harness(scene_file='plate', steps_per_tick=5, **{'log.path': str(tmp_path / 'logs')})
    recorder = h.node.recorder
    for volts in ([800.0, 1500.0], [400.0, 3000.0]):
        h.command(volts)
        h.spin_until_sim_time(h.node.simulator.t + 0.02)
    h.joint_command(['left'], [2000.0])
    h.spin_until_sim_time(h.node.simulator.t + 0.02, 'structure')
    h.close()   # destroys the node: the recorder closes its file
    assert recorder.fault == '' and len(recorder.paths) == 1
    assert LogReader(recorder.paths[0]).info['y0'].startswith('[')
    result = resimulate(recorder.paths[0])
    assert result.complete and result.commands == 3 and result.steps > 0
    assert result.ok(tolerance=0.0), result.table()
    assert any(key.startswith('structure.') for key in result.compared)


def test_command_decoding_refuses_repeated_and_empty_names():
    """
    Check that command decoding refuses repeated and empty name lists.

    Resim reads joint commands as the node does (both decode with det_sim_ros.io.contract): a
    repeated or empty name list is refused.
    """
    from det_sim_ros.io.contract import CommandDecoder, encode_joint_state
    decoder = CommandDecoder(['left', 'right'], 3000.0)
    held = [1.0, 2.0]

    def volts(names, values):
        data = encode_joint_state(names, values)
        return decoder.decode('voltage_command_joint', data, held).volts
    assert volts(['right'], [5.0]) == [1.0, 5.0]
    assert volts(['left', 'left'], [5.0, 6.0]) is None
    assert volts([], []) is None


# -- a re-simulation starts from the logged initial state, not the scene's -------------------

MOVED_START_COMMANDS = {0: [0.0], 40: [2500.0], 90: [1200.0]}
MOVED_START_STEPS = 150


def _record_from(tmp_path, x0, log_x0=True):
    """
    Run the default scene from ``x0`` and log it as the node logs it; return the path.

    With ``log_x0`` False the log lacks the 'x0' metadata (a re-simulation then starts from
    the scene's own initial state).
    """
    sim = Simulator(load_scene('default', PAPER))
    sim.x0 = np.array(x0, dtype=float)
    sim.reset()
    path = tmp_path / 'moved_start.mcap'
    metadata = {'method': sim.method.name, 'substeps': sim.substeps_setting}
    if log_x0:
        metadata['x0'] = repr(sim.x0.tolist())
    with Recorder(path, sim.scene, metadata=metadata) as recorder:
        simulate_to_log(recorder, sim, MOVED_START_COMMANDS, MOVED_START_STEPS)
    return str(path)


def _moved_start():
    """Return the scene's initial state with the deflection, its rate and the charge moved."""
    sim = Simulator(load_scene('default', PAPER))
    scene_x0 = sim.x0
    x0 = scene_x0.copy()
    names = sim.model.state_names
    x0[names.index('q[0]')] *= 0.8          # deflection: 80 % of the rest value, m
    x0[names.index('q_dot[0]')] = 0.3       # m/s
    assert not np.array_equal(x0, scene_x0)
    return x0


def test_resimulation_starts_from_the_logged_initial_state(tmp_path):
    path = _record_from(tmp_path, _moved_start())
    result = resimulate(path)
    assert result.ok(), result.table()
    assert result.steps == MOVED_START_STEPS and result.commands == len(MOVED_START_COMMANDS)
    assert all(v == 0.0 for v in result.max_deviation.values()), result.table()


def test_a_log_without_its_initial_state_resimulates_from_the_scenes_and_deviates(tmp_path):
    """
    Check that the test above can fail.

    The same run logged without its initial state re-simulates from the scene's own and
    deviates.
    """
    path = _record_from(tmp_path, _moved_start(), log_x0=False)
    result = resimulate(path)
    assert max(result.max_deviation.values()) > 0.0
    assert not result.ok()
