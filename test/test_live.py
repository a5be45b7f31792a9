"""
The live view (Foxglove WebSocket) of sim_node and of its logs, seen by an independent client.

The client here is the `websockets` package speaking the Foxglove WebSocket protocol
(subprotocol foxglove.sdk.v1) by hand, decoding with mcap_ros2's dynamic decoder built from the
schemas the server sends: nothing of det_sim_ros reads the bytes. One node process serves both
a working client and a stalled one (connected, subscribed, never reading).
"""

import asyncio
import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time

from conftest import child_env, ChildProcess
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import pytest

websockets = pytest.importorskip('websockets')   # (the 'test' extra has both)
pytest.importorskip('foxglove')

SUBPROTOCOL = 'foxglove.sdk.v1'
TIMEOUT = 60.0   # s; a safety net only: a wait that hits it fails the test
# s for what follows a client's message at once (a refusal on /diagnostics, published every
# second): a broken refusal fails in seconds, not at the safety net
PROMPT = 10.0
NODE = [sys.executable, '-m', 'det_sim_ros.cli.sim_node']
VIEW = [sys.executable, '-m', 'det_sim_ros.cli', 'view']


def port_of(line: str) -> int:
    return int(line.split('ws://127.0.0.1:')[1].split()[0].rstrip(':;'))


class Client:
    """A Foxglove WebSocket client: channels, decoded messages, time, status, service calls."""

    def __init__(self, ws):
        self.ws = ws
        self.channels = {}      # channel id -> advertised channel
        self.services = {}      # name -> service id
        self.decoders = {}
        self.messages = {}      # topic -> [(log time, decoded message)]
        self.times = []
        self.statuses = []
        self.sessions = []
        self.responses = {}
        self.subscribed = {}    # subscription id -> channel id
        self.parameters = {}
        self.playback_states = {}   # request id -> (status, time, speed, did seek)

    @classmethod
    async def connect(cls, port, **kwargs):
        # no keepalive pings of the test client's own: a pong waits in the socket behind the
        # samples this client has not read yet, so on a busy host its 20 s ping timeout closed
        # the connection while the server answered everything (the server's side is the test)
        kwargs.setdefault('ping_interval', None)
        ws = await websockets.connect(f'ws://127.0.0.1:{port}', subprotocols=[SUBPROTOCOL],
                                      max_size=None, close_timeout=1.0, **kwargs)
        return cls(ws)

    def topic_channels(self):
        return {channel['topic']: channel for channel in self.channels.values()}

    def take(self, frame) -> None:
        if isinstance(frame, str):
            message = json.loads(frame)
            op = message['op']
            if op == 'serverInfo':
                self.sessions.append(message['sessionId'])
            elif op == 'advertise':
                for channel in message['channels']:
                    self.channels[channel['id']] = channel
            elif op == 'advertiseServices':
                self.services.update({s['name']: s['id'] for s in message['services']})
            elif op == 'status':
                self.statuses.append(message['message'])
            elif op == 'parameterValues':
                self.parameters.update({p['name']: p.get('value')
                                        for p in message['parameters']})
            return
        op = frame[0]
        if op == 1:      # message data: subscription id, log time, payload
            sub, log_time = struct.unpack_from('<IQ', frame, 1)
            channel = self.channels[self.subscribed[sub]]
            decoder = self.decoders.get(channel['id'])
            if decoder is None:
                decoder = self.decoders[channel['id']] = DecoderFactory().decoder_for(
                    channel['encoding'], Schema(
                        id=channel['id'], name=channel['schemaName'],
                        encoding=channel['schemaEncoding'], data=channel['schema'].encode()))
            self.messages.setdefault(channel['topic'], []).append(
                (log_time, decoder(frame[13:])))
        elif op == 2:    # time
            self.times.append(struct.unpack_from('<Q', frame, 1)[0])
        elif op == 5:    # playback state: status, time, speed, did seek, request id
            status, position, speed, did_seek, length = struct.unpack_from('<BQfBI', frame, 1)
            request = frame[19:19 + length].decode()
            self.playback_states[request] = (status, position, speed, bool(did_seek))
        elif op == 3:    # service call response: service id, call id, encoding, payload
            _, call, length = struct.unpack_from('<III', frame, 1)
            self.responses[call] = json.loads(frame[13 + length:])

    async def pump(self, until, what, timeout=TIMEOUT):
        deadline = time.monotonic() + timeout
        while not until():
            left = deadline - time.monotonic()
            if left <= 0:
                pytest.fail(f'no {what} within {timeout} s')
            try:
                self.take(await asyncio.wait_for(self.ws.recv(), left))
            except asyncio.TimeoutError:
                pass

    async def subscribe_all(self):
        subscriptions = [{'id': 100 + cid, 'channelId': cid} for cid in self.channels]
        self.subscribed.update({s['id']: s['channelId'] for s in subscriptions})
        await self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subscriptions}))

    async def advertise(self, channel_id, topic, schema_name, encoding='json'):
        await self.ws.send(json.dumps({'op': 'advertise', 'channels': [{
            'id': channel_id, 'topic': topic, 'encoding': encoding, 'schemaName': schema_name}]}))

    async def publish(self, channel_id, payload: bytes):
        await self.ws.send(b'\x01' + struct.pack('<I', channel_id) + payload)

    async def call(self, name, request: dict, call_id):
        await self.ws.send(b'\x02' + struct.pack('<III', self.services[name], call_id, 4)
                           + b'json' + json.dumps(request).encode())
        await self.pump(lambda: call_id in self.responses, f'answer of {name}')
        return self.responses[call_id]

    async def playback(self, command, speed, seek_ns, request_id):
        """Send a playback control request (command 0 play, 1 pause; seek_ns None: no seek)."""
        head = struct.pack('<BfBQI', command, speed, seek_ns is not None, seek_ns or 0,
                           len(request_id))
        await self.ws.send(b'\x03' + head + request_id.encode())

    def latest(self, topic):
        return self.messages[topic][-1][1]


def stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def diagnostic_values(client):
    """Return the key/value pairs of the latest /diagnostics status of sim_node."""
    status = client.latest('/diagnostics').status[0]
    return {kv.key: kv.value for kv in status.values}


async def stalled_client(port, ready: threading.Event, hold_s: float, seen: list):
    """
    Connect with a tiny receive buffer, subscribe to everything, then read nothing for hold_s.

    Afterwards read what is left (until the server closes or 2 s pass) into ``seen``: the
    /deflection log times this client got.
    """
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(('127.0.0.1', port))
    client = await Client.connect(port, sock=sock, max_queue=1, ping_interval=None)
    await client.pump(lambda: len(client.channels) >= 5, 'channels (stalled client)')
    await client.subscribe_all()
    client.ws.transport.pause_reading()   # from here on nothing is read
    ready.set()
    await asyncio.sleep(hold_s)
    client.ws.transport.resume_reading()
    deflection = {sub for sub, cid in client.subscribed.items()
                  if client.channels[cid]['topic'] == '/deflection'}
    end = time.monotonic() + 2.0
    try:
        while (left := end - time.monotonic()) > 0:
            frame = await asyncio.wait_for(client.ws.recv(), left)
            if isinstance(frame, bytes) and frame[0] == 1:
                sub, log_time = struct.unpack_from('<IQ', frame, 1)
                if sub in deflection:
                    seen.append(log_time)
    except (asyncio.TimeoutError, websockets.ConnectionClosed):
        pass   # (the server may drop a client that stalled long enough)
    await client.ws.close()


async def watch_node(port):
    """Watch, command, reset and set parameters of the node as a client; return the client."""
    client = await Client.connect(port)
    outputs = ('/displacement', '/deflection', '/charge', '/current')
    wanted = outputs + ('/markers', '/diagnostics', '/sim_node/truth/displacement')
    await client.pump(lambda: set(wanted) <= set(client.topic_channels())
                      and '/sim_node/reset' in client.services, 'channels and services')
    channels = client.topic_channels()
    for topic in wanted:
        assert channels[topic]['encoding'] == 'cdr'
        assert channels[topic]['schemaEncoding'] == 'ros2msg'
    assert channels['/displacement']['schemaName'] == 'sensor_msgs/msg/JointState'
    assert 'MSG: std_msgs/Header' in channels['/displacement']['schema']
    assert channels['/markers']['schemaName'] == 'visualization_msgs/msg/MarkerArray'
    await client.subscribe_all()
    await client.pump(lambda: len(client.messages.get('/displacement', ())) >= 300
                      and client.times and client.messages.get('/diagnostics')
                      and client.messages.get('/markers')
                      and client.messages.get('/sim_node/truth/displacement'),
                      'samples, time, diagnostics, markers and truth')
    # the stamps follow sim time: one sample per 1 ms period, log time = header stamp, and the
    # time the server sends is the sample's
    samples = client.messages['/displacement']
    stamps = [stamp(msg) for _, msg in client.messages['/deflection']]
    assert all(b - a == 1_000_000 for a, b in zip(stamps, stamps[1:])), 'a period missing'
    assert all(log_time == stamp(msg) for log_time, msg in samples)
    assert stamps[0] <= client.times[-1] <= stamps[-1] + 1_000_000_000
    assert list(samples[-1][1].name) == ['det0']
    # a JSON voltage command, as Foxglove's Publish panel sends it, moves the actuator
    await client.advertise(1, '/voltage_command', 'std_msgs/msg/Float64MultiArray')
    await client.publish(1, b'{"data": [2500]}')
    truth = '/sim_node/truth/displacement'   # (the measured one is noisy, may drop a sample)
    await client.pump(lambda: client.latest(truth).position[0] > 1e-4, 'the rise of dy')
    # malformed commands are refused with the reason, on /diagnostics and to the client
    await client.publish(1, b'{"data": "high"}')
    await client.pump(lambda: 'must be a list of numbers' in diagnostic_values(client).get(
        'last_refused', ''), 'the refusal of a malformed command on /diagnostics',
        timeout=PROMPT)
    assert any('must be a list of numbers' in s for s in client.statuses)
    await client.publish(1, b'{"data": [1000, 2000]}')
    await client.pump(lambda: 'expected 1 voltage' in diagnostic_values(client).get(
        'last_refused', ''), 'the refusal of a command of the wrong length', timeout=PROMPT)
    # reset: a new session (the client clears its buffers), then samples from t = 0 again
    sessions = len(client.sessions)
    answer = await client.call('/sim_node/reset', {}, call_id=7)
    assert answer['success'] and answer['message'].startswith('reset to t = 0')
    count = len(samples)

    def restarted():   # the reset's sample 0 and a few after it (after those sent before)
        after = [stamp(msg) for _, msg in samples[count:]]
        return 0 in after and len(after) - after.index(0) > 5
    await client.pump(lambda: len(client.sessions) > sessions and restarted(),
                      'a new session and samples from t = 0 after the reset')
    after = [stamp(msg) for _, msg in samples[count:]]
    restart = after.index(0)
    assert all(b - a == 1_000_000 for a, b in zip(after[restart:], after[restart + 1:]))
    # a runtime parameter through the protocol's parameters capability
    await client.ws.send(json.dumps({'op': 'getParameters', 'parameterNames': ['max_lag'],
                                     'id': 'p1'}))
    await client.pump(lambda: 'max_lag' in client.parameters, 'the value of max_lag')
    assert client.parameters['max_lag'] == 0.05
    await client.ws.send(json.dumps({'op': 'setParameters', 'id': 'p2', 'parameters': [
        {'name': 'max_lag', 'value': 0.2}, {'name': 'real_time_factor', 'value': -1}]}))
    await client.pump(lambda: client.parameters['max_lag'] == 0.2
                      and 'real_time_factor' in client.parameters, 'the parameters set')
    assert client.parameters['real_time_factor'] == 1.0   # refused: unchanged, and why
    await client.pump(lambda: any('real_time_factor' in s for s in client.statuses),
                      'the reason real_time_factor was refused', timeout=PROMPT)
    await client.ws.close()
    return client


def live_node(tmp_path, **params):
    """Start sim_node with the live view on a free port, logging to tmp_path; (node, port)."""
    params = {'scene.fidelity': 'paper', 'live.enabled': 'true', 'live.port': 0,
              'log.path': tmp_path, 'info_period': '0.0', **params}
    args = [f'{name}:={value}' for name, value in params.items()]
    node = ChildProcess(NODE + ['--ros-args'] + [word for arg in args for word in ('-p', arg)],
                        tmp_path)
    return node, port_of(node.wait_for('live view on ws://'))


@pytest.mark.ros
def test_node_live_view(tmp_path):
    node, port = live_node(tmp_path, scene_file='sensor_laser', diagnostics_period=0.25)
    try:
        node.wait_for('voltage command order')
        ready, seen = threading.Event(), []
        stalled = threading.Thread(target=asyncio.run, args=(
            stalled_client(port, ready, 10.0, seen),), daemon=True)
        stalled.start()
        assert ready.wait(TIMEOUT)
        asyncio.run(watch_node(port))
        stalled.join(TIMEOUT)
        assert not stalled.is_alive()
    finally:
        code = node.stop()
    assert code == 0, ''.join(node.lines)
    # the node lost no period while a client stalled: every 1 ms sample of each run is in
    # the log (two files: before and after the reset)
    from mcap.reader import make_reader
    files = sorted(f for f in os.listdir(tmp_path) if f.endswith('.mcap'))
    assert len(files) == 2, files
    logged = 0
    for name in files:
        with open(tmp_path / name, 'rb') as stream:
            times = [message.log_time for _, channel, message in
                     make_reader(stream).iter_messages(topics=['/deflection'])]
        assert times == [k * 1_000_000 for k in range(len(times))], name
        assert len(times) > 100
        logged += len(times)
    # and the stall was real: the stalled client missed at least the second's worth of samples
    # its buffers could have held (the server dropped its oldest, or the client)
    assert len(seen) < logged - 1000, (len(seen), logged)


@pytest.mark.ros
def test_view_serves_a_log_from_start_to_end(tmp_path):
    from det_sim_ros.io.log import Recorder
    from det_sim_ros.io.replay import simulate_to_log
    from det_sim_ros.scenes.scene import load_scene
    from det_sim_ros.sim.simulator import Simulator
    from mcap.reader import make_reader
    scene = load_scene('default', overrides={'scene.fidelity': 'paper'})
    sim = Simulator(scene)
    run = tmp_path / 'run'
    recorder = Recorder(str(run), scene, split_mb=0.0)
    simulate_to_log(recorder, sim, lambda k: [2500.0] if k == 20 else None, 400)
    recorder.close()
    [log] = os.listdir(run)
    with open(run / log, 'rb') as stream:
        logged = {}
        for _, channel, message in make_reader(stream).iter_messages():
            logged.setdefault(channel.topic, []).append(message.log_time)
    view = ChildProcess(VIEW + [str(run), '--port', '0', '--speed', '4'], tmp_path)
    try:
        port = port_of(view.wait_for('on ws://'))

        async def watch():
            client = await Client.connect(port)
            await client.pump(lambda: set(logged) <= set(client.topic_channels()), 'channels')
            await client.subscribe_all()
            await client.pump(lambda: all(len(client.messages.get(topic, ())) == len(times)
                                          for topic, times in logged.items()),
                              'every message of the log')
            first_pass = {topic: list(got) for topic, got in client.messages.items()}
            view.wait_for('end of the log')
            # playback control, as Foxglove's seek bar sends it: play from the middle at x8
            middle = logged['/displacement'][len(logged['/displacement']) // 2]
            await client.playback(0, 8.0, middle, 'seek1')
            await client.pump(lambda: 'seek1' in client.playback_states, 'the playback state')
            status, position, speed, did_seek = client.playback_states['seek1']
            assert (status, position, speed, did_seek) == (0, middle, 8.0, True)   # playing
            again = client.messages['/displacement']
            await client.pump(lambda: len(again) > len(first_pass['/displacement']),
                              'a sample after the seek')
            assert again[len(first_pass['/displacement'])][0] == middle
            await client.playback(1, 8.0, None, 'pause1')
            await client.pump(lambda: 'pause1' in client.playback_states, 'the pause')
            assert client.playback_states['pause1'][0] == 1   # paused
            await client.ws.close()
            return client, first_pass
        client, first_pass = asyncio.run(watch())
    finally:
        view_stopped = view.stop()
    assert view_stopped == 0, ''.join(view.lines)
    for topic, times in logged.items():
        assert [t for t, _ in first_pass[topic]] == times, topic
    displacement = [msg.position[0] for _, msg in first_pass['/displacement']]
    # at rest Δy = y0 - y is zero up to rounding (y ~ 1e-3 m: ~1e-16 m); 2500 V from k = 20
    # lift it by tenths of a millimetre
    assert abs(displacement[0]) < 1e-9 and max(displacement) > 1e-4
    assert [stamp(msg) for _, msg in first_pass['/displacement']] == logged['/displacement']


@pytest.mark.ros
def test_without_the_extra_or_with_the_port_taken_the_node_refuses_in_one_line(tmp_path):
    blocked = tmp_path / 'blocked'
    (blocked / 'foxglove').mkdir(parents=True)
    (blocked / 'foxglove' / '__init__.py').write_text("raise ImportError('not installed')\n")
    args = ['--ros-args', '-p', 'scene.fidelity:=paper', '-p', 'live.enabled:=true', '-p',
            'log.enabled:=false', '-p', 'allow_duplicate_name:=true']
    env = child_env()
    env['PYTHONPATH'] = os.pathsep.join([str(blocked), env['PYTHONPATH']])
    run = subprocess.run(NODE + args, cwd=tmp_path, env=env, text=True, capture_output=True,
                         timeout=TIMEOUT)
    fatal = [line for line in (run.stdout + run.stderr).splitlines() if 'FATAL' in line]
    assert run.returncode == 1 and len(fatal) == 1, run.stdout + run.stderr
    assert "parameter live.enabled: the live view needs foxglove-sdk: install the extra 'live'" \
        in fatal[0]
    run = subprocess.run(VIEW + ['any.mcap'], cwd=tmp_path, env=env, text=True,
                         capture_output=True, timeout=TIMEOUT)
    assert run.returncode == 2 and run.stderr.startswith('det_sim: error: the live view needs '
                                                         "foxglove-sdk: install the extra 'live'")
    assert len(run.stderr.splitlines()) == 1
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        run = subprocess.run(NODE + args + ['-p', f'live.port:={port}'], cwd=tmp_path,
                             env=child_env(), text=True, capture_output=True, timeout=TIMEOUT)
    fatal = [line for line in (run.stdout + run.stderr).splitlines() if 'FATAL' in line]
    assert run.returncode == 1 and len(fatal) == 1, run.stdout + run.stderr
    assert f'parameter live.port: cannot listen on 127.0.0.1:{port} (' in fatal[0]


@pytest.mark.parametrize('topic, payload, reason', [
    ('voltage_command', b'{"data": "high"}', "JSON field 'data' must be a list of numbers"),
    ('voltage_command', b'{"data": [true]}', "JSON field 'data' must be a list of numbers"),
    ('voltage_command', b'{"volts": [1]}', 'JSON needs "data"'),
    ('voltage_command', b'[2500]', 'JSON must be an object'),
    ('voltage_command', b'{"data": [2500', 'not JSON'),
    ('voltage_command', b'\xff', 'not JSON'),
    ('voltage_command_joint', b'{"name": [1], "position": [2]}', 'must be a list of strings'),
])
def test_a_client_command_that_is_not_a_message_is_refused(topic, payload, reason):
    from det_sim_ros.io.live_server import command_bytes
    with pytest.raises(ValueError, match=reason.replace('[', r'\[')):
        command_bytes(topic, payload, 'json')


def test_a_client_json_command_is_the_cdr_a_dds_publisher_sends():
    from det_sim_ros.io.contract import CommandDecoder
    from det_sim_ros.io.live_server import command_bytes
    decoder = CommandDecoder(['det0', 'det1'], 5000.0)
    command = decoder.decode('voltage_command', command_bytes(
        'voltage_command', b'{"data": [2500, 1000.5]}', 'json'), [0.0, 0.0])
    assert command.volts == [2500.0, 1000.5] and not command.reason
    joint = decoder.decode('voltage_command_joint', command_bytes(
        'voltage_command_joint', b'{"name": ["det1"], "position": [300]}', 'json'), [1.0, 2.0])
    assert joint.volts == [1.0, 300.0]
    # NaN reaches the node's own checks, which refuse it as they refuse it from DDS
    nan = decoder.decode('voltage_command', command_bytes(
        'voltage_command', b'{"data": [NaN, 1]}', 'json'), [0.0, 0.0])
    assert nan.volts is None and 'non-finite voltage on det0' in nan.reason, nan.reason


@pytest.mark.ros
def test_live_rate_serves_every_nth_sample_and_the_log_keeps_all(tmp_path):
    node, port = live_node(tmp_path, **{'live.rate_hz': 100, 'allow_duplicate_name': 'true'})
    try:
        async def watch():
            client = await Client.connect(port)
            await client.pump(lambda: '/displacement' in client.topic_channels(), 'channels')
            await client.subscribe_all()
            await client.pump(lambda: len(client.messages.get('/displacement', ())) >= 20,
                              'samples')
            await client.ws.close()
            return client
        client = asyncio.run(watch())
    finally:
        node_stopped = node.stop()
    assert node_stopped == 0, ''.join(node.lines)
    stamps = [stamp(msg) for _, msg in client.messages['/displacement']]
    assert all(b - a == 10_000_000 for a, b in zip(stamps, stamps[1:])), stamps[:5]
    from mcap.reader import make_reader
    [log] = [f for f in os.listdir(tmp_path) if f.endswith('.mcap')]
    with open(tmp_path / log, 'rb') as stream:
        times = [message.log_time for _, _, message in
                 make_reader(stream).iter_messages(topics=['/displacement'])]
    assert times == [k * 1_000_000 for k in range(len(times))] and times[-1] >= stamps[-1]


async def flood_and_disconnect(port, commands: int):
    """
    Flood the node with ``commands`` voltage commands, then leave mid-call.

    The commands go as fast as the socket takes them, then a parameter set and a service call,
    and the client closes without waiting for their answers.
    """
    client = await Client.connect(port)
    await client.pump(lambda: '/sim_node/step' in client.services, 'services')
    await client.advertise(1, '/voltage_command', 'std_msgs/msg/Float64MultiArray')
    for k in range(commands):
        await client.publish(1, b'{"data": [%d]}' % (k % 3000))
    await client.ws.send(json.dumps({'op': 'setParameters', 'id': 'p', 'parameters': [
        {'name': 'max_lag', 'value': 0.1}]}))
    await client.ws.send(b'\x02' + struct.pack('<III', client.services['/sim_node/step'], 1, 4)
                         + b'json{}')
    await client.ws.close()


@pytest.mark.ros
def test_a_client_that_floods_stalls_and_leaves_mid_call_costs_the_node_no_period(tmp_path):
    flood = 20_000
    node, port = live_node(tmp_path, diagnostics_period=0.25,
                           **{'allow_duplicate_name': 'true'})
    try:
        ready, seen = threading.Event(), []
        stalled = threading.Thread(target=asyncio.run, args=(
            stalled_client(port, ready, 8.0, seen),), daemon=True)
        stalled.start()
        assert ready.wait(TIMEOUT)
        asyncio.run(flood_and_disconnect(port, flood))

        async def watch():
            client = await Client.connect(port)
            await client.pump(lambda: '/diagnostics' in client.topic_channels(), 'channels')
            await client.subscribe_all()

            def settled():   # every command of the flood applied or refused, none waiting
                if not client.messages.get('/diagnostics'):
                    return False
                values = diagnostic_values(client)
                return (int(values['commands_received'])
                        + int(values['live_requests_refused']) >= flood
                        and values['live_requests_waiting'] == '0')
            await client.pump(settled, 'every command of the flood accounted for')
            await client.ws.close()
            return diagnostic_values(client)
        values = asyncio.run(watch())
        stalled.join(TIMEOUT)
        assert not stalled.is_alive()
    finally:
        code = node.stop()
    assert code == 0, ''.join(node.lines)
    # every command the client sent is either applied or counted as refused (queue full);
    # the parameter set and the service call after them are refused too if they found it full
    accounted = int(values['commands_received']) + int(values['live_requests_refused'])
    assert flood <= accounted <= flood + 2, values
    assert int(values['live_requests_refused']) > 0   # the flood did fill the queue
    # the queues stayed within their bounds, and said so
    assert int(values['live_requests_most']) <= int(values['live_requests_limit']) == 64
    assert int(values['live_samples_most']) <= 5000
    assert values['live_request_errors'] == '0'
    # the node lost no period: every 1 ms sample is in the log, in sim time
    from mcap.reader import make_reader
    [log] = [f for f in os.listdir(tmp_path) if f.endswith('.mcap')]
    with open(tmp_path / log, 'rb') as stream:
        times = [message.log_time for _, _, message in
                 make_reader(stream).iter_messages(topics=['/deflection'])]
    assert times == [k * 1_000_000 for k in range(len(times))] and len(times) > 1000


def small_log(folder, periods=400):
    from det_sim_ros.io.log import Recorder
    from det_sim_ros.io.replay import simulate_to_log
    from det_sim_ros.scenes.scene import load_scene
    from det_sim_ros.sim.simulator import Simulator
    scene = load_scene('default', overrides={'scene.fidelity': 'paper'})
    recorder = Recorder(str(folder), scene, split_mb=0.0)
    simulate_to_log(recorder, Simulator(scene), lambda k: [2500.0] if k == 20 else None,
                    periods)
    recorder.close()
    [log] = os.listdir(folder)
    return folder / log


def test_a_seek_starts_at_the_chunk_that_holds_its_time(tmp_path):
    from det_sim_ros.io.log_view import LogSummary
    from mcap.reader import make_reader
    log = small_log(tmp_path / 'run', 3000)
    with open(log, 'rb') as stream:   # mcap's own index of the file's chunks
        chunks = sorted(make_reader(stream).get_summary().chunk_indexes,
                        key=lambda c: c.chunk_start_offset)
        stream.seek(0)
        every = [(channel.topic, message.log_time) for _, channel, message
                 in make_reader(stream).iter_messages(log_time_order=False)]
    assert len(chunks) > 10
    summary = LogSummary(log)
    for t in (0, 1, 1_500_000_000, 2_000_000_001, 2_999_000_000):
        file, offset = summary.place_before(t)
        at = [c.chunk_start_offset for c in chunks].index(offset)   # a chunk's start
        assert file == 0 and (at == 0 or chunks[at].message_start_time < t)
        assert at + 1 == len(chunks) or chunks[at + 1].message_start_time >= t
        read = [(m.topic, m.log_time) for m in summary.reader.messages(start=(file, offset))]
        first = next(k for k, (_, time_) in enumerate(every) if time_ >= t)
        # from the chunk on, the log's messages in order: those from t on all among them
        assert read == every[len(every) - len(read):] and len(every) - len(read) <= first


def test_the_player_lets_its_lock_go_before_it_calls_the_server(tmp_path):
    """
    Check that every call into the SDK lets a callback from another thread take the lock.

    The SDK runs the player's callbacks on its threads while it holds a lock of its own, and the
    player calls the SDK (playback state, time): holding the player's lock through such a call
    deadlocks the two. Here every such call first waits for a callback run from another thread,
    as the SDK's would be: it must get the player's lock meanwhile.
    """
    from det_sim_ros.io.log_view import LogPlayer
    log = small_log(tmp_path / 'run')
    player = LogPlayer(log, port=0, paused=True)
    got_the_lock = []

    def as_the_sdk_runs_it(call):
        def call_with_a_callback_meanwhile(*args, **kwargs):
            done = threading.Event()

            def sdk_thread():
                player.on_subscribe(None, None)   # a callback: it takes the player's lock
                done.set()
            threading.Thread(target=sdk_thread, daemon=True).start()
            got_the_lock.append(done.wait(2.0))
            return call(*args, **kwargs)
        return call_with_a_callback_meanwhile
    player.server.playback_state = as_the_sdk_runs_it(player.server.playback_state)
    player.server.time = as_the_sdk_runs_it(player.server.time)
    try:
        async def play():
            client = await Client.connect(player.server.port)
            await client.pump(lambda: client.channels, 'channels')
            await client.playback(0, 1.0, 0, 'play')
            await client.ws.close()
        asyncio.run(play())
        assert player.finished.wait(30.0) and not player.failed
    finally:
        player.stop()
    assert len(got_the_lock) >= 2 and all(got_the_lock), got_the_lock


def test_a_speed_beyond_what_the_player_serves_is_capped_and_the_client_told(tmp_path):
    from det_sim_ros.io.log_view import LogPlayer, MAX_MESSAGES_PER_S
    log = small_log(tmp_path / 'run')
    player = LogPlayer(log, port=0, speed=1000.0, paused=True)
    try:
        span_s = (player.log.end - player.log.start) * 1e-9
        assert player.max_speed == pytest.approx(MAX_MESSAGES_PER_S * span_s / player.log.count)
        assert player.speed == player.max_speed < 1000.0

        async def ask():
            client = await Client.connect(player.server.port)
            await client.pump(lambda: client.channels, 'channels')
            await client.playback(1, 1000.0, None, 'fast')
            await client.pump(lambda: 'fast' in client.playback_states, 'the playback state')
            await client.ws.close()
            return client.playback_states['fast']
        _, _, speed, _ = asyncio.run(ask())
        assert speed == pytest.approx(player.max_speed, rel=1e-6)   # (sent as a float32)
    finally:
        player.stop()


@pytest.mark.ros
def test_view_exits_with_the_reason_when_its_player_dies(tmp_path):
    log = small_log(tmp_path / 'run')
    view = ChildProcess(VIEW + [str(log), '--port', '0', '--paused'], tmp_path)
    port = port_of(view.wait_for('on ws://'))
    os.remove(log)   # the player cannot read it any more

    async def play():
        client = await Client.connect(port)
        await client.pump(lambda: client.channels, 'channels')
        await client.playback(0, 1.0, 0, 'play')
        await client.ws.close()
    asyncio.run(play())
    view.wait_for('the player stopped')
    view.proc.wait(timeout=view.TIMEOUT)   # it exits by itself: a Ctrl-C now would race it
    code = view.stop()
    assert code == 1, ''.join(view.lines)
    assert any('det_sim view: error: the player stopped: FileNotFoundError' in line
               for line in view.lines), ''.join(view.lines)
