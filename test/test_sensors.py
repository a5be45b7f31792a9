"""The sensor model (det_sim_ros.sim.sensors) and the scene's sensors section, offline."""

import math

from det_sim_ros.scenes.scene import load_scene, scene_to_dict, SceneError
from det_sim_ros.sim.sensors import BLOCK, NoiseStreams, SensorBank
import numpy as np
import pytest

N = 60000
DT = 1e-3


def bank(layout=(('displacement', 1),), seed=0, **knobs):
    """Return a SensorBank of the default scene with ``knobs`` on every topic of ``layout``."""
    overrides = {f'sensors.{topic}.{key}': value for topic, _ in layout
                 for key, value in knobs.items()}
    overrides['sensors.seed'] = seed
    scene = load_scene('default', overrides)
    return SensorBank(scene.sensors, list(layout), DT)


def test_white_noise_mean_and_sigma_within_2_percent():
    readings, _ = bank(noise_std=2e-6, bias=3e-6).measure_run(np.zeros((N, 1)))
    assert abs(readings.mean() - 3e-6) <= 0.02 * 3e-6
    assert abs(readings.std() - 2e-6) <= 0.02 * 2e-6


def test_coloured_noise_sigma_and_autocorrelation_at_one_correlation_time():
    lag = 3
    readings, _ = bank(noise_std=1e-6, correlation_time=lag * DT).measure_run(np.zeros((N, 1)))
    x = readings[:, 0]
    assert abs(x.std() - 1e-6) <= 0.02 * 1e-6
    rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert abs(rho - math.exp(-1)) <= 0.05 * math.exp(-1)
    white, _ = bank(noise_std=1e-6).measure_run(np.zeros((N, 1)))
    assert abs(np.corrcoef(white[:-lag, 0], white[lag:, 0])[0, 1]) < 0.02


def test_delay_is_exact_in_samples():
    truth = np.arange(2000, dtype=float)[:, None] * 1e-6
    readings, _ = bank(delay_samples=7).measure_run(truth)
    assert np.array_equal(readings[7:], truth[:-7])
    assert np.array_equal(readings[:7], np.repeat(truth[:1], 7, axis=0))   # before: sample 0


def test_dropout_rate_within_binomial_99_percent_bounds():
    p = 0.1
    _, dropped = bank(dropout=p).measure_run(np.zeros((N, 1)))
    half_width = 2.576 * math.sqrt(N * p * (1 - p))
    assert abs(int(dropped.sum()) - N * p) <= half_width
    # a sample's dropout does not depend on its noise draw's use: same flags with noise on
    _, noisy = bank(dropout=p, noise_std=1e-6).measure_run(np.zeros((N, 1)))
    assert np.array_equal(dropped, noisy)


def test_quantization_bias_and_saturation_are_exact():
    truth = np.linspace(-3e-6, 3e-6, 4001)[:, None]
    q, b, lo, hi = 2.5e-7, 1e-7, -2e-6, 1.5e-6
    readings, _ = bank(quantization=q, bias=b, range_min=lo, range_max=hi).measure_run(truth)
    expected = np.clip(np.rint((truth + b) / q) * q, lo, hi)
    assert np.array_equal(readings, expected)
    inside = (readings > lo) & (readings < hi)
    assert np.all(np.rint(readings[inside] / q) * q == readings[inside])
    assert readings.min() == lo and readings.max() == hi
    only_bias, _ = bank(bias=b).measure_run(truth)
    assert np.array_equal(only_bias, truth + b)


def test_same_seed_identical_other_seed_different():
    knobs = {'noise_std': 1e-6, 'correlation_time': 0.01, 'dropout': 0.2}
    layout = (('displacement', 2), ('charge', 2))
    runs = [bank(layout, seed, **knobs).measure_run(np.zeros((3000, 4))) for seed in (5, 5, 6)]
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert not np.any(runs[0][0] == runs[2][0])
    assert not np.array_equal(runs[0][1], runs[2][1])
    # every channel has its own stream: DET 0 and DET 1, displacement and charge all differ
    readings = runs[0][0]
    assert len({tuple(readings[:10, j]) for j in range(4)}) == 4


def test_draws_are_keyed_by_sample_index_not_by_call_order():
    streams = NoiseStreams(11)
    whole, uniforms = streams.draws(3, 2, 0, 3 * BLOCK)
    for start, n in ((0, 1), (1500, 1), (BLOCK - 1, 3), (2 * BLOCK + 5, 100)):
        normals, u = streams.draws(3, 2, start, n)
        assert np.array_equal(normals, whole[start:start + n])
        assert np.array_equal(u, uniforms[start:start + n])
    sensor = bank(noise_std=1e-6, correlation_time=0.005, delay_samples=2, dropout=0.3)
    first = sensor.measure_run(np.ones((2500, 1)))
    again = sensor.measure_run(np.ones((2500, 1)))   # a restart at sample 0: the same run
    assert np.array_equal(first[0], again[0]) and np.array_equal(first[1], again[1])
    fresh = bank(noise_std=1e-6, correlation_time=0.005, delay_samples=2, dropout=0.3)
    fresh.measure_run(np.ones((10, 1)), k0=2 * BLOCK)   # a late block first: the OU chain
    assert np.array_equal(fresh.measure_run(np.ones((2500, 1)))[0], first[0])


def test_readings_are_never_nan_and_quantization_never_overflows():
    truth = np.array([[0.0], [1e300], [-1e300], [3e-300], [1.0]])
    readings, _ = bank(quantization=1e-300, noise_std=1e-6).measure_run(truth)
    assert np.all(np.isfinite(readings))


def test_no_sensor_section_and_all_off_are_the_same_scene():
    plain = load_scene('default')
    off = load_scene('default', {'sensors.displacement.noise_std': 0.0})
    assert plain == off and not off.sensors
    assert 'sensors' not in scene_to_dict(off)
    on = load_scene('default', {'sensors.displacement.noise_std': 1e-6})
    assert on.sensors and load_scene(scene_to_dict(on)) == on


@pytest.mark.parametrize('key, value, words', [
    ('sensors.displacement.dropout', 1.5, 'out of range [0, 1]'),
    ('sensors.displacement.dropout', -0.1, 'out of range [0, 1]'),
    ('sensors.charge.noise_std', -1e-9, 'out of range [0, inf]'),
    ('sensors.current.quantization', -1e-6, 'out of range [0, inf]'),
    ('sensors.deflection.correlation_time', -0.1, 'out of range [0, inf]'),
    ('sensors.displacement.delay_samples', 2.5, 'must be an integer'),
    ('sensors.displacement.range_min', 1e-3, 'must be below range_max'),
    ('sensors.displacement.noise', 1.0, "unknown scene key sensors.displacement.'noise'"),
    ('sensors.structure.noise_std', 1.0, "unknown scene key sensors.'structure'"),
    ('sensors.seed', -1, 'out of range'),
])
def test_bad_sensor_values_are_one_line_scene_errors(key, value, words):
    with pytest.raises(SceneError) as error:
        load_scene('default', {key: value})
    assert words in str(error.value) and '\n' not in str(error.value)
    assert 'sensors.' in str(error.value)


NOISY = {'sensors.seed': 7, 'sensors.displacement.noise_std': 2e-6,
         'sensors.displacement.correlation_time': 3e-3, 'sensors.displacement.dropout': 0.2,
         'sensors.displacement.delay_samples': 2, 'sensors.charge.quantization': 1e-8,
         'sensors.current.bias': 1e-6, 'sensors.current.range_min': -1e-4,
         'sensors.current.range_max': 1e-4}


def _noisy_log(path, overrides=NOISY, n=300):
    from det_sim_ros.io.log import Recorder
    from det_sim_ros.io.replay import simulate_to_log
    from det_sim_ros.sim.simulator import Simulator
    scene = load_scene('default', overrides)
    sim = Simulator(scene)
    with Recorder(str(path), scene, metadata={'method': sim.method.name}) as recorder:
        simulate_to_log(recorder, sim, {0: [2500.0], 150: [500.0]}, n)
    return scene


def test_noisy_log_holds_measured_and_truth_and_resimulates_bit_exact(tmp_path, monkeypatch):
    from det_sim_ros.io import replay
    from det_sim_ros.io.log.reader import LogReader
    from det_sim_ros.io.replay import resimulate
    from det_sim_ros.io.sensing import measured_run
    from det_sim_ros.sim.simulator import simulate, Simulator
    path = tmp_path / 'noisy.mcap'
    scene = _noisy_log(path)
    counts = {}
    for message in LogReader(str(path)).messages():
        counts[message.topic] = counts.get(message.topic, 0) + 1
    assert counts['/sim_node/truth/displacement'] == counts['/deflection'] == 301
    assert counts['/sim_node/truth/charge'] == counts['/sim_node/truth/current'] == 301
    assert '/sim_node/truth/deflection' not in counts
    sim = Simulator(scene)
    readings = measured_run(sim, simulate(sim, [2500.0] * 150 + [500.0] * 150, 0.3))
    assert counts['/displacement'] == int(readings['displacement'].received.sum()) < 301
    result = resimulate(str(path))
    assert result.ok(), result.table()
    assert result.compared['truth/displacement.position (y)'] == 301
    assert result.compared['displacement.position (y)'] == counts['/displacement']
    # the noise is what is re-simulated: other streams (another seed) do not reproduce the log
    other_seed = load_scene('default', {**NOISY, 'sensors.seed': NOISY['sensors.seed'] + 1})
    monkeypatch.setattr(replay, 'scene_from_log', lambda reader: other_seed)
    changed = resimulate(str(path))
    assert not changed.ok()
    assert changed.max_deviation['truth/displacement.position (y)'] == 0.0


def test_every_knob_off_logs_the_same_bytes(tmp_path):
    from det_sim_ros.io.log.reader import LogReader
    off = {'sensors.displacement.noise_std': 0.0, 'sensors.charge.dropout': 0.0}
    logs = []
    for name, overrides in (('plain', {}), ('off', off)):
        _noisy_log(tmp_path / f'{name}.mcap', overrides, 50)
        logs.append([(m.topic, m.log_time, bytes(m.data))
                     for m in LogReader(str(tmp_path / f'{name}.mcap')).messages()])
    assert logs[0] == logs[1]


def test_laser_preset_is_the_default_scene_read_by_a_laser_sensor():
    preset, default = load_scene('sensor_laser'), load_scene('default')
    assert preset.physics == default.physics and preset.rate_hz == default.rate_hz
    assert list(preset.sensors.active) == ['displacement']
    laser = preset.sensors.displacement
    assert laser.quantization * 2 ** 16 == laser.range_max - laser.range_min == 0.01
    assert 0 < laser.noise_std < laser.quantization * 10 and laser.delay_samples == 1


def test_noisy_array_logs_the_same_with_one_or_two_threads(tmp_path):
    from det_sim_ros.io.log.reader import LogReader
    from det_sim_ros.io.log import Recorder
    from det_sim_ros.io.replay import simulate_to_log
    from det_sim_ros.sim.simulator import Simulator
    scene = load_scene('array', {'structure.copies': 4, **NOISY})
    logs = []
    for threads in (1, 2):
        path = tmp_path / f'threads{threads}.mcap'
        sim = Simulator(scene, threads=threads)
        with Recorder(str(path), scene) as recorder:
            simulate_to_log(recorder, sim, {0: [2000.0] * 4, 60: [900.0] * 4}, 120)
        logs.append([(m.topic, m.log_time, bytes(m.data))
                     for m in LogReader(str(path)).messages()])
    topics = {topic for topic, _, _ in logs[0]}
    assert logs[0] == logs[1] and len(topics) == 8 and '/sim_node/truth/charge' in topics


def test_a_noisy_log_plots_its_published_outputs(tmp_path):
    from det_sim_ros.io.logplot import read_log
    path = tmp_path / 'noisy.mcap'
    _noisy_log(path)
    data = read_log(str(path))
    lengths = {channel.title: len(channel.t) for channel in data.channels}
    assert 200 < lengths['displacement Δy'] < 301   # the published samples, not the truth
    assert lengths['charge q_p'] == lengths['current i_DE'] == 301
