"""
The output table (det_sim_ros.scenes.outputs): one row added is one output everywhere.

A row appended to ``OUTPUTS`` before anything reads it (in a fresh interpreter: as if the row
were in the source) must appear in the topic contract and the published bytes, in the log,
``det_sim watch``'s line and CSV, ``det_sim plot``'s panels and summary, and the scene's
``sensors`` section with its own noise stream; the existing outputs and their sensor noise stay
bit for bit. With a fit channel the row is fittable: ``det_sim fit`` reads it from a sim_node
log and fits a parameter against it alone.
"""

import json
import os
import subprocess
import sys

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


# the same row with a fit channel: a log of it, read by the fit, and Rs fitted from v_p alone
# (v_p = v - Rs i_DE: the series resistor's drop, ~1-2 V at 2.5 kV, is what identifies Rs)
FIT_SCRIPT = r"""
import dataclasses, json, os, sys
from det_sim_ros.scenes import outputs
outputs.OUTPUTS = outputs.OUTPUTS + (outputs.OutputQuantity(
    'voltage', 'position', 'v_p', 'v', 'DET voltage v_p', 'V', 'kV', 1e-3, 1e-3, sensor=4,
    fit=outputs.FitChannel('v_det', ('det_voltage',), 1e-3, 'kV', 1e-3)),)
from det_sim_ros.calibration.fitting import fit
from det_sim_ros.calibration.logs import read_log
from det_sim_ros.calibration.report import report_text
from det_sim_ros.io.log import Recorder
from det_sim_ros.io.replay import simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator

scene = load_scene('default', {'scene.fidelity': 'paper'})
commands = {0: [2500.0], 20: [1000.0]}
sim = Simulator(scene)
v_p = sim.model.channel('v_p')[0]
truth = [float(sim.outputs()['v_p'])]
for k in range(40):
    if k in commands:
        sim.set_input(commands[k])
    truth.append(float(sim.step()[v_p]))
path = os.path.join(sys.argv[1], 'fit.mcap')
sim = Simulator(scene)
with Recorder(path, scene, metadata={'method': sim.method.name}) as recorder:
    simulate_to_log(recorder, sim, commands, 40)
measurement = read_log(path)
alone = dataclasses.replace(measurement, channels={'v_det': measurement.channels['v_det']})
result = fit([alone], 'Rs', start={'Rs': 3.0e3}, sigma={'v_det': 1e-3}, starts=1,
             candidates=1, coarse=False, parallel='serial')
print(json.dumps({
    'channels': list(measurement.channels),
    'index': measurement.channels['v_det'].index.tolist(),
    'measured': measurement.channels['v_det'].values[:, 0].tolist(), 'v_p': truth,
    'Rs': [scene.physics.Rs, result.estimates[0].start, result.scene.physics.Rs],
    'converged': result.converged, 'report': report_text(result),
}))
"""


def _run(tmp_path, which, script=SCRIPT):
    env = {**os.environ, 'PYTHONHASHSEED': '0'}
    done = subprocess.run([sys.executable, '-c', script, which, str(tmp_path)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_every_row_is_published_and_logged_as_its_model_output(tmp_path):
    """
    Check each row against what a sim_node log holds, the model's outputs computed apart.

    Per sample the log holds one message per row's topic, in the rows' order; each row's
    field is its model output per DET (y0 - y for the displacement), bit for bit; the fit
    reads its channels from those topics; the live line, the CSV and the plot show each row.
    """
    from det_sim_ros.calibration.logs import read_log
    from det_sim_ros.io.contract import rest_shortenings
    from det_sim_ros.io.log import LogReader, Recorder
    from det_sim_ros.io.messages import decode_joint_state
    from det_sim_ros.io.replay import simulate_to_log
    from det_sim_ros.scenes.scene import load_scene
    from det_sim_ros.sim.simulator import Simulator
    scene = load_scene('plate', {'scene.fidelity': 'paper'})   # two DETs
    commands = {0: [2500.0, 1000.0], 5: [0.0, 3000.0]}
    sim = Simulator(scene)
    names = sim.output_names
    truth = [dict(zip(names, sim.outputs().values()))]
    for k in range(10):
        if k in commands:
            sim.set_input(commands[k])
        truth.append(dict(zip(names, sim.step().tolist())))
    per_det = {quantity: [names[i] for i in sim.model.channel(quantity)]
               for quantity in {row.quantity for row in outputs.OUTPUTS}}
    y0 = rest_shortenings(scene)
    path = str(tmp_path / 'run.mcap')
    with Recorder(path, scene, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, Simulator(scene), commands, 10)
    samples = {}
    for message in LogReader(path).messages():
        topic = message.topic.lstrip('/')
        if topic in OUTPUT_FIELDS:
            samples.setdefault(message.log_time, []).append((topic, message.data))
    assert len(samples) == 11
    for k, (t_ns, messages) in enumerate(sorted(samples.items())):
        assert [topic for topic, _ in messages] == list(outputs.output_topics())
        decoded = {topic: decode_joint_state(data) for topic, data in messages}
        for row in outputs.OUTPUTS:
            want = [truth[k][name] for name in per_det[row.quantity]]
            if row.relative_to_y0:
                want = [y - v for y, v in zip(y0, want)]
            assert list(getattr(decoded[row.topic], row.field)) == want, (k, row)
    measurement = read_log(path)
    for name, row in outputs.fit_channels().items():
        assert measurement.channels[name].values.tolist() == [
            list(decode_joint_state(data).position) for _, messages in sorted(samples.items())
            for topic, data in messages if topic == row.topic]
    # the consumers show every row: watch's CSV columns and the plot's panels, the line each
    # sensed topic's position
    rows = [(row.topic, row.field) for row in outputs.OUTPUTS]
    assert list(CSV_FIELDS) == list(PANELS) == rows
    assert list(LINE_QUANTITIES) == [(t, 'position') for t in SENSOR_TOPICS]
    assert OUTPUT_TOPICS == outputs.output_topics()
    assert set(OUTPUT_UNITS) == set(OUTPUT_FIELDS) and RELATIVE_TO_Y0 == {
        (row.topic, row.field) for row in outputs.OUTPUTS if row.relative_to_y0}


def test_the_noise_stream_numbers_stay_as_they_are():
    """The noise streams are keyed on these numbers: changing one changes every noisy log."""
    assert SENSOR_TOPICS == {'displacement': 0, 'deflection': 1, 'charge': 2, 'current': 3}


def test_the_structure_rows_are_on_the_structure_topic(tmp_path):
    """A plate's log holds the structure topic's names in the structure table's order."""
    from det_sim_ros.io.contract import STRUCTURE_TOPIC
    from det_sim_ros.io.log import LogReader, Recorder
    from det_sim_ros.io.messages import decode_joint_state
    from det_sim_ros.io.replay import simulate_to_log
    from det_sim_ros.scenes.scene import load_scene
    from det_sim_ros.sim.simulator import Simulator
    scene = load_scene('plate', {'scene.fidelity': 'paper'})
    path = str(tmp_path / 'plate.mcap')
    sim = Simulator(scene)
    with Recorder(path, scene, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, {0: [2500.0, 0.0]}, 3)
    logged = [decode_joint_state(m.data) for m in LogReader(path).messages()
              if m.topic.lstrip('/') == STRUCTURE_TOPIC]
    assert logged and all(list(msg.name) == [name for name, _ in STRUCTURE_NAMES.values()]
                          for msg in logged)
    assert list(STRUCTURE_QUANTITIES) == list(PANELS_STRUCTURE) == [
        row.name for row in outputs.STRUCTURE_OUTPUTS]


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


@pytest.mark.ros   # a child interpreter (the table is read at import)
def test_one_added_row_with_a_fit_channel_is_fittable(tmp_path):
    done = _run(tmp_path, str(tmp_path), FIT_SCRIPT.replace('sys.argv[1]', 'sys.argv[2]'))
    # the fit reads the new topic from sim_node's log as its channel, beside the others
    assert done['channels'] == ['dy', 'charge', 'current', 'v_det']
    assert done['index'] == list(range(41)) and done['measured'] == done['v_p']   # bit for bit
    # fitted against it alone: Rs back from 3 kOhm to the scene's 2 kOhm (noise-free data:
    # 1e-6 bounds the search's stopping point, not the data)
    true, start, fitted = done['Rs']
    assert start == 3.0e3 and done['converged']
    assert fitted == pytest.approx(true, rel=1e-6)
    # the report states the channel's residuals in its report unit
    rows = [line for line in done['report'].splitlines() if ' v_det ' in line]
    assert len(rows) == 1 and rows[0].rstrip().endswith(' kV'), done['report']
