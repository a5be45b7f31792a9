"""
The output table (det_sim_ros.scenes.outputs): one row added is one output everywhere.

A row appended to ``OUTPUTS`` before anything reads it (in a fresh interpreter: as if the row
were in the source) must appear in the topic contract and the published bytes, in the log,
``det_sim watch``'s line and CSV, ``det_sim plot``'s panels and summary, and the scene's
``sensors`` section with its own noise stream; the existing outputs and their sensor noise stay
bit for bit.
"""

import json
import os
import subprocess
import sys

from det_sim_ros.calibration.logs import NODE_TOPICS
from det_sim_ros.cli.watch import CSV_FIELDS, LINE_QUANTITIES, STRUCTURE_QUANTITIES
from det_sim_ros.io.contract import OUTPUT_FIELDS, OUTPUT_UNITS, RELATIVE_TO_Y0, STRUCTURE_NAMES
from det_sim_ros.io.logplot import PANELS, PANELS_STRUCTURE
from det_sim_ros.ros.shell import OUTPUT_TOPICS
from det_sim_ros.scenes import outputs
from det_sim_ros.scenes.sensors import SENSOR_TOPICS
import pytest

# the DET voltage v_p (a model output no topic publishes) as a fifth output topic
SCRIPT = r"""
import io, json, os, sys, types
import numpy as np
from det_sim_ros.scenes import outputs
if sys.argv[1] == 'row':
    outputs.OUTPUTS = outputs.OUTPUTS + (outputs.OutputQuantity(
        'voltage', 'position', 'v_p', 'v', 'DET voltage v_p', 'V', 'kV', 1e-3, 1e-3, sensor=4),)
from det_sim_ros.cli.watch import Watcher
from det_sim_ros.io import logplot
from det_sim_ros.io.contract import OUTPUT_FIELDS, OUTPUT_UNITS, OutputContract, TOPIC_TYPES
from det_sim_ros.io.log import LogReader, Recorder
from det_sim_ros.io.messages import decode_joint_state
from det_sim_ros.io.replay import simulate_to_log
from det_sim_ros.ros.shell import OUTPUT_TOPICS
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator

sensed = {'sensors.seed': 3, 'sensors.displacement.noise_std': 1e-6}
if sys.argv[1] == 'row':
    sensed['sensors.voltage.noise_std'] = 5.0
scene = load_scene('default', {'scene.fidelity': 'paper', **sensed})
commands = {0: [2500.0], 20: [1000.0]}
sim = Simulator(scene)
model = sim.model
truth = [list(sim.outputs().values())]
for k in range(40):
    if k in commands:
        sim.set_input(commands[k])
    truth.append(sim.step().tolist())
path = os.path.join(sys.argv[2], sys.argv[1] + '.mcap')
sim = Simulator(scene)
with Recorder(path, scene, metadata={'method': sim.method.name}) as recorder:
    simulate_to_log(recorder, sim, commands, 40)
logged = {}
for message in LogReader(path).messages():
    logged.setdefault(message.topic, []).append(list(decode_joint_state(message.data).position)
                                                if 'voltage_command' not in message.topic
                                                else None)
data = logplot.read_log(path)

def msg(position, velocity=()):
    header = types.SimpleNamespace(stamp=types.SimpleNamespace(sec=1, nanosec=0))
    return types.SimpleNamespace(header=header, name=['det0'], position=list(position),
                                 velocity=list(velocity))

lines = {}
for csv in (False, True):
    stream = io.StringIO()
    watcher = Watcher(csv=csv, count=1, stream=stream)
    for topic in OUTPUT_TOPICS:
        watcher.take(topic, msg([2.5e3 if topic == 'voltage' else 1e-3], [0.0]))
    watcher.tick(0.0)
    lines[csv] = stream.getvalue()
v_p = model.channel('v_p')
print(json.dumps({
    'fields': OUTPUT_FIELDS, 'units': OUTPUT_UNITS, 'shell': OUTPUT_TOPICS,
    'types': sorted(TOPIC_TYPES), 'contract': OutputContract(model).topics,
    'v_p': [[row[i] for i in v_p] for row in truth],
    'logged': logged, 'sensed': list(scene.sensors.active),
    'panels': {c.title: [c.unit, c.values.tolist()] for c in data.channels},
    'summary': logplot.summary(data), 'line': lines[False], 'csv': lines[True],
}))
"""


def _run(tmp_path, which):
    env = {**os.environ, 'PYTHONHASHSEED': '0'}
    done = subprocess.run([sys.executable, '-c', SCRIPT, which, str(tmp_path)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_the_tables_are_the_output_table():
    """Every consumer's table is read off the rows (the public names stay)."""
    assert OUTPUT_FIELDS == {'deflection': {'position': 'q', 'velocity': 'q_dot'},
                             'displacement': {'position': 'y'}, 'charge': {'position': 'q_p'},
                             'current': {'position': 'i_DE'}}
    assert OUTPUT_UNITS == {'deflection': ('m', 'm/s'), 'displacement': ('m',),
                            'charge': ('C',), 'current': ('A',)}
    assert RELATIVE_TO_Y0 == {('displacement', 'position')}
    assert OUTPUT_TOPICS == ('deflection', 'displacement', 'charge', 'current')
    # the noise streams are keyed on these numbers: changing one changes every noisy log
    assert SENSOR_TOPICS == {'displacement': 0, 'deflection': 1, 'charge': 2, 'current': 3}
    assert list(LINE_QUANTITIES) == [(t, 'position') for t in SENSOR_TOPICS]
    assert list(CSV_FIELDS) == list(PANELS) == [(r.topic, r.field) for r in outputs.OUTPUTS]
    assert PANELS[('charge', 'position')] == ('charge q_p', 'µC', 1e6)
    # the structure topic's table: the contract's names and signs, watch's line, the plot
    assert STRUCTURE_NAMES == {'plate_y': ('plate_dy', -1.0), 'plate_phi': ('plate_phi', 1.0)}
    assert list(STRUCTURE_QUANTITIES) == list(PANELS_STRUCTURE) == ['plate_dy', 'plate_phi']
    assert PANELS_STRUCTURE['plate_phi'] == ('plate tilt φ − φ0', 'mrad', 1e3)
    # calibration fits the measured channels it names (its own vocabulary) from output topics
    assert set(NODE_TOPICS) <= set(OUTPUT_FIELDS)


def test_a_sensor_number_used_twice_is_refused():
    rows = outputs.OUTPUTS + (outputs.OutputQuantity(
        'voltage', 'position', 'v_p', 'v', 'DET voltage', 'V', 'V', 1.0, 1e-3, sensor=2),)
    with pytest.raises(ValueError, match='sensor stream numbers must differ'):
        outputs.sensor_topics(rows)


@pytest.mark.ros   # a child interpreter (the table is read at import)
def test_one_added_row_is_published_logged_watched_plotted_and_sensed(tmp_path):
    before, after = _run(tmp_path, 'plain'), _run(tmp_path, 'row')
    # the contract and the shell
    assert after['fields'] == {**before['fields'], 'voltage': {'position': 'v_p'}}
    assert after['units']['voltage'] == ['V']
    assert after['shell'] == before['shell'] + ['voltage']
    assert after['contract'] == before['contract'] + ['voltage']
    assert set(after['types']) - set(before['types']) == {'voltage'}
    # the log: the new topic's truth is the model's v_p bit for bit; it is sensed (noise of
    # 5 V on ~kV) and its own noise stream leaves the other topics' bytes as they were
    assert '/voltage' not in before['logged']
    assert after['sensed'] == ['displacement', 'voltage']
    assert after['logged']['/sim_node/truth/voltage'] == after['v_p']
    measured = after['logged']['/voltage']
    assert measured != after['v_p'] and len(measured) == len(after['v_p'])
    for topic, values in before['logged'].items():
        assert after['logged'][topic] == values, topic
    # watch: the line and the CSV columns
    assert after['line'].rstrip('\n').endswith('v 2.5 kV')
    assert before['line'] == after['line'].replace(' v 2.5 kV', '')
    assert after['csv'].splitlines()[0].endswith(',voltage.position.det0')
    # plot: its own panel in the display unit (kV: the SI values times 1e-3, one rounding)
    unit, values = after['panels']['DET voltage v_p']
    assert unit == 'kV'
    assert [v for (v,) in values] == pytest.approx([v * 1e-3 for (v,) in measured], rel=1e-15)
    assert 'DET voltage v_p' in after['summary'] and 'DET voltage' not in before['summary']
