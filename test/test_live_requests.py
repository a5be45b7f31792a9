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
