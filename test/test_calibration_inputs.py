"""
Test what ``det_sim fit`` reads and writes, and its one-line answers to bad input.

sim_node's own log (recorded offline as the node records it), a rig's rosbag2 MCAP with other
topic names and types through the mapping (JointState, Float64MultiArray and Float64, written
with the mcap package and the generic CDR codec) and a CSV file each fit to the parameter that
made them; the fitted scene loads as it is; bad input is one line and a non-zero exit.
"""

import contextlib
import io
import math
import os
import re

from det_sim_ros.calibration.synthetic import step_and_sine, synthetic_measurement
from det_sim_ros.cli.det_sim import main
from det_sim_ros.io.log import Recorder
from det_sim_ros.io.replay import simulate_to_log
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

T_END = 0.4           # s: a step and part of a sine; enough to fix Y to well within 1 %
Y_TRUE = 1.2e6        # Pa: the log's modulus (the default scene has 1.09e6)
STAMP0 = 1_700_000_000_000_000_000   # ns: a rig's wall-clock stamps


@pytest.fixture(scope='module')
def truth():
    return load_scene('default', {'physics.Y': Y_TRUE})


@pytest.fixture(scope='module')
def synthetic(truth):
    return synthetic_measurement(truth, step_and_sine(T_END, truth.dt), noise=0.01, seed=7,
                                 channels=('dy', 'charge'))


def run_cli(*argv):
    """Run ``det_sim`` in-process; return (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def fitted_y(path):
    return load_scene(str(path)).physics.Y


def _fit(tmp_path, *logs_and_options):
    out = tmp_path / 'fitted.yaml'
    code, stdout, stderr = run_cli('fit', *logs_and_options, '--params', 'Y', '--quiet',
                                   '--starts', '1', '--parallel', 'serial', '-o', out)
    assert code == 0, stderr
    return out, stdout


def test_progress_says_the_misfit_in_noise_units_and_the_time_up_front(tmp_path, truth):
    """
    Check the progress lines: the expected runs and time first, misfits in units of the noise.

    The weighted cost 0.5 |r|^2 of a start far off reads as a failure (1e17 on a noise floor of
    1e-12 m); its RMS in noise units is what the report states, and the lines must not show it.
    """
    sim = Simulator(truth)
    volts = step_and_sine(T_END, sim.dt)
    path = tmp_path / 'node.mcap'
    with Recorder(path, truth, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, lambda k: [float(volts[k])], len(volts))
    code, stdout, stderr = run_cli('fit', path, '--params', 'Y', '--start', 'Y=1.5e6',
                                   '--starts', '1', '--parallel', 'serial', '--no-plots',
                                   '-o', tmp_path / 'f.yaml')
    assert code == 0, stderr
    lines = [line for line in stderr.splitlines() if line.startswith('det_sim fit: ')]
    searching = next(n for n, line in enumerate(lines) if 'searching at' in line)
    assert re.search(r'one run takes [0-9.e-]+ s; expect about \d+ runs, ~\d+ s', lines[searching])
    steps = [line for line in lines if ', step ' in line]
    assert steps and all(re.search(r'misfit [0-9.e+-]+ x noise', line) for line in steps)
    assert not any('cost' in line for line in lines[searching:] if 'converged' not in line)


def test_sim_node_log_fits_and_the_scene_file_loads_as_it_is(tmp_path, truth):
    sim = Simulator(truth)
    volts = step_and_sine(T_END, sim.dt)
    path = tmp_path / 'node.mcap'
    with Recorder(path, truth, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, lambda k: [float(volts[k])], len(volts))
    # the log's scene is the base: the start is its own Y, so start from another
    out, stdout = _fit(tmp_path, path, '--start', 'Y=1.5e6')
    assert fitted_y(out) == pytest.approx(Y_TRUE, rel=1e-4)   # a noise-free log
    assert 'residual RMS per channel' in stdout and 'charge' in stdout
    assert os.path.exists(tmp_path / 'fitted_report.txt')
    assert os.path.exists(tmp_path / 'fitted.png')
    # as sim_node reads a scene file: through load_scene with the node's overrides
    assert load_scene(str(out), {'scene.initial_state': 'rest'}).physics.Y == fitted_y(out)


def _write_csv(path, synthetic):
    dy = synthetic.channels['dy'].values[:, 0]
    volts = np.append(synthetic.volts[:, 0], synthetic.volts[-1, 0])
    rows = ['t (s),v (V),dy (m)'] + [f'{k * synthetic.dt:.6f},{float(v)!r},{float(d)!r}'
                                     for k, (v, d) in enumerate(zip(volts, dy))]
    path.write_text('\n'.join(rows) + '\n')


def test_csv_fits(tmp_path, synthetic):
    path = tmp_path / 'rig.csv'
    _write_csv(path, synthetic)
    out, stdout = _fit(tmp_path, path, path, '--scene', 'default')   # two logs fit together
    assert fitted_y(out) == pytest.approx(Y_TRUE, rel=0.01)
    assert '2 log(s), ' in stdout
    default = load_scene('default')
    coarse = default.replace(**{'scene.n_ritz': 1, 'scene.shapes': default.ritz_level[0]})
    assert f'\n  coarse: {coarse.fidelity_label}, ' in stdout
    assert f'\n  scene: {default.fidelity_label}, ' in stdout


def test_no_coarse_searches_at_the_scene_level_alone(tmp_path, synthetic):
    path = tmp_path / 'rig.csv'
    _write_csv(path, synthetic)
    out, stdout = _fit(tmp_path, path, '--scene', 'default', '--no-coarse')
    assert fitted_y(out) == pytest.approx(Y_TRUE, rel=0.01)
    assert '\n  scene: exact buckling modes n_r=3, ' in stdout and '\n  coarse: ' not in stdout


def test_the_scene_file_keeps_the_digits_the_interval_gives_and_the_report_reads_plainly(
        tmp_path, synthetic):
    """
    Check the fitted scene's value: rounded to two significant digits of its standard error.

    And the report's words: the misfit in noise units, the starting points in plain words (no
    'residual variance (weighted)' or 'local searches' head lines, no bare costs).
    """
    import yaml
    import det_sim_ros
    from det_sim_ros.calibration.report import rounded
    result = det_sim_ros.fit([synthetic], ['Y'], scene='default', starts=1, parallel='serial')
    (estimate,) = result.estimates
    out = tmp_path / 'fitted.yaml'
    result.write(str(out), plot=False)
    written = yaml.safe_load(out.read_text())['sim_node']['ros__parameters']['physics']['Y']
    digits = 1 - math.floor(math.log10(estimate.se))
    assert written == round(estimate.value, digits) == rounded(estimate.value, estimate.se)
    assert abs(written - estimate.value) <= 0.05 * estimate.se     # far inside the interval
    report = result.report()
    assert 'misfit: the residuals are ' in report and 'times the noise' in report
    assert 'residual variance (weighted)' not in report and 'local searches' not in report
    assert re.search(r'\n  1: \([^)]*\) -> [\d.e+]+ x noise after \d+ runs', report), report


def _write_rig_log(path, synthetic):
    """Write a rig's rosbag2 MCAP: Float64 volts, JointState Δy in mm, Float64MultiArray charge."""
    from det_sim_ros.io.cdr import serialize
    from mcap.writer import Writer
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Float64MultiArray
    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='test')
        channels = {}
        for topic, kind in (('/amp/out', 'std_msgs/msg/Float64'),
                            ('/rig/joints', 'sensor_msgs/msg/JointState'),
                            ('/rig/adc', 'std_msgs/msg/Float64MultiArray')):
            schema = writer.register_schema(kind, 'ros2msg', b'')
            channels[topic] = writer.register_channel(topic, 'cdr', schema)
        dy = synthetic.channels['dy'].values[:, 0]
        charge = synthetic.channels['charge'].values[:, 0]
        for k in range(len(dy)):
            t_ns = STAMP0 + k * 1_000_000
            state = JointState(name=['base', 'slider'], position=[0.5, dy[k] * 1e3])
            state.header.stamp.sec, state.header.stamp.nanosec = divmod(t_ns, 10**9)
            messages = [('/rig/joints', state),
                        ('/rig/adc', Float64MultiArray(data=[9.0, charge[k] * 1e6]))]
            if k < len(synthetic.volts):
                messages.insert(0, ('/amp/out', Float64(data=float(synthetic.volts[k, 0]))))
            for topic, msg in messages:
                writer.add_message(channels[topic], t_ns, serialize(msg), t_ns)
        writer.finish()


def test_a_rig_log_with_other_topics_fits_through_the_mapping(tmp_path, synthetic):
    path = tmp_path / 'rig.mcap'
    _write_rig_log(path, synthetic)
    out, stdout = _fit(tmp_path, path, '--map', 'voltage=/amp/out',
                       '--map', 'dy=/rig/joints.position[slider]*1e-3',
                       '--map', 'charge=rig/adc.data[1]*1e-6')
    assert fitted_y(out) == pytest.approx(Y_TRUE, rel=0.01)
    assert 'charge' in stdout


def test_a_scale_applies_to_scalar_fields_too(tmp_path, synthetic):
    """
    Check each mapped value is the logged number times its scale, for a Float64's scalar field.

    The rig logs its voltage in kV and Δy in mm, each as a Float64 (a scalar ``data``, not an
    array element); the reference is the raw values the test wrote times the mapping's scale.
    """
    from det_sim_ros.calibration.logs import read_log
    from det_sim_ros.io.cdr import serialize
    from mcap.writer import Writer
    from std_msgs.msg import Float64
    volts_kv = synthetic.volts[:, 0] * 1e-3
    dy_mm = synthetic.channels['dy'].values[:, 0] * 1e3
    path = tmp_path / 'scalars.mcap'
    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='test')
        schema = writer.register_schema('std_msgs/msg/Float64', 'ros2msg', b'')
        channels = {topic: writer.register_channel(topic, 'cdr', schema)
                    for topic in ('/amp/kv', '/rig/dy_mm')}
        for k, value in enumerate(dy_mm):
            t_ns = STAMP0 + k * 1_000_000
            if k < len(volts_kv):
                writer.add_message(channels['/amp/kv'], t_ns,
                                   serialize(Float64(data=float(volts_kv[k]))), t_ns)
            writer.add_message(channels['/rig/dy_mm'], t_ns,
                               serialize(Float64(data=float(value))), t_ns)
        writer.finish()
    measured = read_log(str(path), ['voltage=/amp/kv*1e3', 'dy=/rig/dy_mm.data*1e-3'])
    # the same IEEE product on both sides: equal to within one rounding
    assert measured.volts[:, 0] == pytest.approx(volts_kv * 1e3, rel=1e-15)
    assert measured.channels['dy'].values[:, 0] == pytest.approx(dy_mm * 1e-3, rel=1e-15)


def _csv(tmp_path, text, name='bad.csv'):
    path = tmp_path / name
    path.write_text(text)
    return path


def _bad_inputs(tmp_path):
    """(case, argv after 'fit') for each kind of bad input."""
    good = _csv(tmp_path, 't,v,dy\n' + ''.join(f'{k * 1e-3},1000.0,0.0\n' for k in range(50)),
                'good.csv')
    return {
        'no command': [_csv(tmp_path, 't,dy\n0,0\n0.001,0\n'), '--params', 'Y'],
        'no command values': [_csv(tmp_path, 't,v,dy\n0,,0\n0.001,,0\n'), '--params', 'Y'],
        'no measured output': [_csv(tmp_path, 't,v\n0,1\n0.001,1\n'), '--params', 'Y'],
        'fewer samples than parameters': [_csv(tmp_path, 't,v,dy\n0,1,0\n0.001,1,0\n'),
                                          '--params', 'Y,m,eta_b'],
        'NaN': [_csv(tmp_path, 't,v,dy\n0,1,0\n0.001,1,nan\n0.002,1,0\n'), '--params', 'Y'],
        'unknown parameter': [good, '--params', 'Y,stiffness'],
        'bounds exclude the start': [good, '--params', 'Y', '--bounds', 'Y=2e6:3e6'],
        'missing file': [tmp_path / 'nothing.mcap', '--params', 'Y'],
        'not a sim_node log without a mapping': [_csv(tmp_path, 'not mcap', 'x.mcap'),
                                                 '--params', 'Y'],
        'bad mapping': [good, '--params', 'Y', '--map', 'dy=/a/b[1'],
    }


def test_bad_input_is_one_line_and_a_non_zero_exit(tmp_path):
    for case, argv in _bad_inputs(tmp_path).items():
        code, stdout, stderr = run_cli('fit', *argv, '--quiet', '-o', tmp_path / 'f.yaml')
        lines = stderr.strip().splitlines()
        assert code == 2, (case, code, stderr)
        assert len(lines) == 1 and lines[0].startswith('det_sim: error: '), (case, stderr)
        assert 'Traceback' not in stderr and not os.path.exists(tmp_path / 'f.yaml'), case


def test_a_fit_that_does_not_converge_says_so_and_writes_its_report(tmp_path, synthetic):
    path = tmp_path / 'rig.csv'
    dy = synthetic.channels['dy'].values[:, 0]
    rows = ['t,v,dy'] + [f'{k * 1e-3},{v},{d}' for k, (v, d) in enumerate(zip(
        np.append(synthetic.volts[:, 0], 0.0), dy))]
    path.write_text('\n'.join(rows) + '\n')
    code, stdout, stderr = run_cli('fit', path, '--params', 'Y,m', '--starts', '1',
                                   '--max-evaluations', '2', '--quiet', '--no-plots',
                                   '-o', tmp_path / 'f.yaml')
    assert code == 1
    assert 'did not converge' in stderr.strip().splitlines()[-1]
    assert 'DID NOT CONVERGE' in (tmp_path / 'f_report.txt').read_text()
    assert load_scene(str(tmp_path / 'f.yaml')).physics.Y > 0


@pytest.mark.parametrize('title', ['dy', 'Δy (m)', 'displacement [m]', 'DY'])
def test_a_csv_column_is_found_by_any_name_of_its_channel(tmp_path, title):
    """The header names of a channel (the output table's) in any case, a unit after them."""
    from det_sim_ros.calibration.measurement import read_csv
    rows = ''.join(f'{k * 1e-3},1000.0,{k * 1e-6}\n' for k in range(5))
    measured = read_csv(str(_csv(tmp_path, f't,v,{title}\n' + rows, 'named.csv')))
    assert list(measured.channels) == ['dy']
    assert measured.channels['dy'].values[:, 0].tolist() == [k * 1e-6 for k in range(5)]
