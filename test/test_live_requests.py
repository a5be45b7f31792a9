"""
What a live-view client is told about its requests, and what a request it saw fail does.

sim_node runs in-process (the lockstep fixture's node, with ``live.enabled``); its executor
spins in a thread the test can hold, so the node can be made to not answer. The client is the
`websockets` package speaking the Foxglove WebSocket protocol by hand (test_live.Client):
the statuses and parameter values checked are the bytes the server sent it.
"""

import asyncio
import json
import threading
import time

import pytest

from test_live import Client, TIMEOUT

pytest.importorskip('websockets')
pytest.importorskip('foxglove')
pytestmark = pytest.mark.ros


class Spinner:
    """sim_node's executor, spun in a thread while ``on`` is set (held while it is not)."""

    def __init__(self, sim):
        self.on, self._done = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._spin, args=(sim.executor,), daemon=True)
        self._thread.start()

    def _spin(self, executor):
        while not self._done.is_set():
            if self.on.is_set():
                executor.spin_once(timeout_sec=0.01)
            else:
                time.sleep(0.01)

    def stop(self):
        self._done.set()
        self._thread.join(TIMEOUT)


@pytest.fixture
def live_sim():
    from det_sim_ros.ros.testing import LockstepSim
    sim = LockstepSim('default', overrides={'scene.fidelity': 'paper'},
                      params={'live.enabled': True, 'live.port': 0})
    sim.start(wait=False)
    spinner = Spinner(sim)
    try:
        yield sim, spinner
    finally:
        spinner.stop()
        sim.close()


def statuses_with(client, text):
    return [s for s in client.statuses if text in s]


def test_a_parameter_set_the_client_saw_time_out_never_takes_effect(live_sim):
    sim, spinner = live_sim
    from det_sim_ros.ros.live import ANSWER_TIMEOUT_S

    async def client_side():
        client = await Client.connect(sim.node.live.port)
        await client.pump(lambda: '/diagnostics' in client.topic_channels(), 'channels')
        # the executor is held: the node cannot answer
        await client.ws.send(json.dumps({'op': 'setParameters', 'id': 'late', 'parameters': [
            {'name': 'max_lag', 'value': 0.2}]}))
        await client.pump(lambda: statuses_with(client, 'parameters not set'),
                          'the status of the set that timed out')
        [status] = statuses_with(client, 'parameters not set')
        assert 'max_lag' in status and f'did not answer within {ANSWER_TIMEOUT_S:g} s' in status
        assert 'nothing was done' in status
        spinner.on.set()   # the node answers again; what it answers comes after the set
        await client.ws.send(json.dumps({'op': 'getParameters', 'id': 'after',
                                         'parameterNames': ['max_lag']}))
        await client.pump(lambda: 'max_lag' in client.parameters, 'the value of max_lag')
        await client.ws.close()
        return client
    client = asyncio.run(client_side())
    assert client.parameters['max_lag'] == 0.05   # the default: the set never ran
    assert sim.node.get_parameter('max_lag').value == 0.05
    counters = sim.node.live.counters()
    assert counters['live_requests_timed_out'] == '1' and counters['live_requests_waiting'] == '0'


@pytest.mark.parametrize('topic, schema, payload, reason', [
    ('/voltage_command', 'std_msgs/msg/Float64MultiArray', b'{"data": [NaN]}',
     'command refused: voltage_command: non-finite voltage on det0'),
    ('/voltage_command', 'std_msgs/msg/Float64MultiArray', b'{"data": [1000, 2000]}',
     'command refused: voltage_command: expected 1 voltage'),
    ('/voltage_command_joint', 'sensor_msgs/msg/JointState',
     b'{"name": ["det7"], "position": [100]}',
     "command refused: voltage_command_joint: unknown DET name(s) ['det7']"),
    ('/voltage_command', 'std_msgs/msg/Float64MultiArray', b'{"data": [-500]}',
     'command clamped: det0: -500 V clamped to [0, 3000] V (voltage_command)'),
    ('/voltage_command', 'std_msgs/msg/Float64MultiArray', b'{"data": [1e9]}',
     'command clamped: det0: 1e+09 V clamped to [0, 3000] V (voltage_command)'),
])
def test_a_client_reads_why_its_command_was_refused_or_clamped(
        live_sim, topic, schema, payload, reason):
    sim, spinner = live_sim
    spinner.on.set()

    async def client_side():
        client = await Client.connect(sim.node.live.port)
        await client.pump(lambda: '/diagnostics' in client.topic_channels(), 'channels')
        await client.advertise(1, topic, schema)
        await client.publish(1, payload)
        await client.pump(lambda: statuses_with(client, 'command '), 'a status of the command')
        await client.ws.close()
        return client
    client = asyncio.run(client_side())
    assert any(s.startswith(reason) for s in client.statuses), client.statuses
    counts = sim.node.commands.counts()
    assert counts.received == 1
    assert (counts.refused, counts.clamped) == ((1, 0) if 'refused' in reason else (0, 1))


@pytest.fixture
def quick_live_sim(monkeypatch):
    """Run the live_sim node with a short answer timeout (0.3 s: pending after 0.6 s)."""
    from det_sim_ros.ros import live
    monkeypatch.setattr(live, 'ANSWER_TIMEOUT_S', 0.3)
    from det_sim_ros.ros.testing import LockstepSim
    sim = LockstepSim('default', overrides={'scene.fidelity': 'paper'},
                      params={'live.enabled': True, 'live.port': 0})
    sim.start(wait=False)
    spinner = Spinner(sim)
    spinner.on.set()
    try:
        yield sim
    finally:
        spinner.stop()
        sim.close()


def test_a_set_that_runs_long_is_told_pending_then_set(quick_live_sim):
    """
    Check a parameter set the node started and finishes late: pending, then set; never 'not set'.

    A post-set callback of the node (rclpy's public hook) holds the set on the executor thread
    until the client has been told pending; released, the set ends and the client reads that
    it took effect, and it did.
    """
    sim = quick_live_sim
    release = threading.Event()

    def hold(parameters):
        if any(p.name == 'max_lag' for p in parameters):
            release.wait(TIMEOUT)
    sim.node.add_post_set_parameters_callback(hold)

    async def client_side():
        client = await Client.connect(sim.node.live.port)
        await client.pump(lambda: '/diagnostics' in client.topic_channels(), 'channels')
        await client.ws.send(json.dumps({'op': 'setParameters', 'id': 'long', 'parameters': [
            {'name': 'max_lag', 'value': 0.2}]}))
        await client.pump(lambda: statuses_with(client, 'parameters pending'), 'pending')
        release.set()
        await client.pump(lambda: statuses_with(client, 'parameters set'), 'its outcome')
        await client.ws.close()
        return client
    client = asyncio.run(client_side())
    [pending] = statuses_with(client, 'parameters pending')
    assert pending.startswith('parameters pending (max_lag): the node started it')
    assert statuses_with(client, 'parameters set') == ['parameters set (max_lag)']
    assert not statuses_with(client, 'not set')
    assert sim.node.get_parameter('max_lag').value == 0.2
    assert sim.node.live.counters()['live_requests_pending'] == '1'


# A real WebSocket client per child: forked by this helper (single-threaded, so a fork is
# safe), it subscribes to every channel, advertises a command channel, reads the answer to a
# parameter request (the server has taken the subscription and the channel by then) and prints
# its pid; the test SIGKILLs it mid-stream.
KILLED_CLIENTS = """
import asyncio, json, os, sys, websockets
async def client(port):
    ws = await websockets.connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1'],
                                  max_size=None)
    channels = []
    while not channels:
        message = await ws.recv()
        if isinstance(message, str) and json.loads(message)['op'] == 'advertise':
            channels = [c['id'] for c in json.loads(message)['channels']]
    await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
        {'id': 100 + c, 'channelId': c} for c in channels]}))
    await ws.send(json.dumps({'op': 'advertise', 'channels': [{
        'id': 1, 'topic': '/voltage_command', 'encoding': 'json',
        'schemaName': 'std_msgs/msg/Float64MultiArray'}]}))
    await ws.send(json.dumps({'op': 'getParameters', 'id': 'p', 'parameterNames': ['mode']}))
    while True:
        message = await ws.recv()
        if isinstance(message, str) and json.loads(message)['op'] == 'parameterValues':
            break
    print(os.getpid(), len(channels), flush=True)
    while True:
        await ws.recv()
port = int(sys.argv[1])
for line in sys.stdin:
    pid = os.fork()
    if pid == 0:
        asyncio.run(client(port))
        os._exit(0)
    os.waitpid(pid, 0)   # (SIGKILLed by the test)
"""


def test_clients_killed_mid_stream_leave_nothing_behind(live_sim):
    """
    Check 100 clients SIGKILLed while subscribed with a command channel: nothing grows.

    Each one is subscribed to every channel and has advertised a command channel when it is
    killed (no close handshake); afterwards the live view's per-client state (subscriptions,
    command channels, waiting requests) is back where it started, and nobody watches.
    """
    import os
    import signal
    import subprocess
    import sys
    from conftest import child_env
    sim, spinner = live_sim
    spinner.on.set()
    view = sim.node.live
    before = view.counters()
    helper = subprocess.Popen([sys.executable, '-c', KILLED_CLIENTS, str(view.port)],
                              env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True, bufsize=1)
    seen = []
    try:
        for _ in range(100):
            helper.stdin.write('go\n')
            pid, channels = map(int, helper.stdout.readline().split())
            seen.append((int(view.counters()['live_subscriptions']),
                         int(view.counters()['live_client_channels'])))
            os.kill(pid, signal.SIGKILL)
        helper.stdin.close()
        helper.wait(TIMEOUT)
    finally:
        helper.kill()
        helper.wait()
    assert all(subs >= channels and commands >= 1 for subs, commands in seen), seen[:5]
    deadline = time.monotonic() + TIMEOUT   # the server notices each reset connection
    while (view.counters()['live_subscriptions'] != before['live_subscriptions']
           or view.counters()['live_client_channels'] != before['live_client_channels']) \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    after = view.counters()
    for key in ('live_subscriptions', 'live_client_channels', 'live_requests_waiting'):
        assert after[key] == before[key] == '0', (key, after)
    assert not view.watched
