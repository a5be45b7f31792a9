"""
A measured run on the simulator's time grid: the held voltages and the measured outputs.

Every source (a sim_node log, a rig's rosbag2 MCAP through a mapping, a CSV file) ends up as a
:class:`Measurement`: the grid t_k = k dt from the first sample, the voltage held over each
period (zero-order hold, as sim_node applies a command from the period it arrives in until the
next one) and, per measured channel, the grid indices it was sampled at and its values. Units
are SI: s, V, m (Δy), C (charge), A (current).
"""

from __future__ import annotations

import csv
import dataclasses
import math
from typing import Mapping, Sequence

import numpy as np

from ..scenes.outputs import fit_channels

__all__ = ['CalibrationError', 'Channel', 'Measurement', 'CHANNELS', 'on_grid', 'read_csv',
           'noise_level']

# measured channel -> (model output per DET, published relative to the rest state at 0 V):
# the output table's rows with a fit channel (det_sim_ros.scenes.outputs)
CHANNELS = {name: (row.quantity, row.relative_to_y0) for name, row in fit_channels().items()}
# smallest noise level per channel (SI units): a noise-free channel still gets a finite weight
NOISE_FLOOR = {name: row.fit.noise_floor for name, row in fit_channels().items()}
# a d-th difference of white noise of level sigma has variance binom(2d, d) sigma^2
_DIFFERENCE_ORDER = 3
_DIFFERENCE_GAIN = math.sqrt(math.comb(2 * _DIFFERENCE_ORDER, _DIFFERENCE_ORDER))
_MAD_TO_SIGMA = 1.4826   # the median absolute deviation of a normal sample, in sigmas


class CalibrationError(ValueError):
    """Input a fit cannot use (a log, a CSV file, a parameter, bounds); one line."""


@dataclasses.dataclass
class Channel:
    """
    One measured output.

    ``index``: grid indices k of the samples; ``values``: (samples, DETs); ``sigma``: the noise
    level per DET (None: estimated from the data by :func:`noise_level`).
    """

    name: str
    index: np.ndarray
    values: np.ndarray
    sigma: np.ndarray | None = None


@dataclasses.dataclass
class Measurement:
    """
    A run on the grid t_k = k dt.

    ``volts``: (periods, DETs), the voltage held from t_k to t_k+1; ``channels``: measured
    outputs by name (:data:`CHANNELS`); ``scene``: the scene a sim_node log recorded (else None).
    """

    source: str
    dt: float
    volts: np.ndarray
    channels: dict
    scene: object = None

    @property
    def periods(self) -> int:
        """Return the number of control periods: grid points minus one."""
        return len(self.volts)

    @property
    def t(self) -> np.ndarray:
        """Return the grid times t_k, s (periods + 1 of them)."""
        return np.arange(self.periods + 1) * self.dt

    @property
    def samples(self) -> int:
        """Return the number of measured values (all channels and DETs)."""
        return sum(channel.values.size for channel in self.channels.values())


def _finite(source: str, what: str, times, values) -> None:
    bad = ~(np.isfinite(times) & np.all(np.isfinite(values.reshape(len(values), -1)), axis=1))
    if np.any(bad):
        k = int(np.argmax(bad))
        raise CalibrationError(f'{source}: {what} sample {k} is not a finite number '
                               f'(t = {times[k]!r}, value {values[k].tolist()!r})')


def _sample_period(source: str, times: np.ndarray) -> float:
    steps = np.diff(np.unique(times))
    if steps.size == 0 or not np.median(steps) > 0.0:
        raise CalibrationError(f'{source}: the measured samples do not advance in time: cannot '
                               'tell the sample rate')
    return float(np.median(steps))


def on_grid(source: str, commands: tuple, samples: Mapping[str, tuple], dt: float | None = None,
            scene=None) -> Measurement:
    """
    Put timed commands and samples on the grid t_k = t_0 + k dt (zero-order hold).

    :param commands: (times (s), voltages (n, DETs)); a command at t applies from the period
        nearest to t on; before the first one the input is 0 V, as at sim_node's start.
    :param samples: channel name -> (times (s), values (n, DETs)).
    :param dt: the sample period, s (default: the median spacing of the measured samples).
    :raises CalibrationError: no command, no measured output, a NaN, an unknown channel.
    """
    times, volts = (np.asarray(a, dtype=float) for a in commands)
    volts = volts.reshape(len(times), -1) if times.size else volts
    if times.size == 0:
        raise CalibrationError(f'{source}: no voltage command in the log (the fit replays the '
                               'commands through the model)')
    samples = {name: (np.asarray(t, dtype=float), np.asarray(v, dtype=float).reshape(len(t), -1))
               for name, (t, v) in samples.items() if len(t)}
    if not samples:
        raise CalibrationError(f'{source}: no measured output ({", ".join(CHANNELS)}) in the '
                               'log')
    unknown = sorted(set(samples) - set(CHANNELS))
    if unknown:
        raise CalibrationError(f'{source}: unknown channel {unknown[0]!r}; the channels are '
                               + ', '.join(CHANNELS))
    _finite(source, 'voltage', times, volts)
    for name, (t, v) in samples.items():
        _finite(source, name, t, v)
    if dt is None:
        dt = _sample_period(source, next(iter(samples.values()))[0])
    t0 = min([times.min()] + [t.min() for t, _ in samples.values()])
    channels = {}
    for name, (t, v) in samples.items():
        k = np.rint((t - t0) / dt).astype(np.int64)
        # the last sample at a grid point counts (a duplicate stamp is a resend)
        last = len(k) - 1 - np.unique(k[::-1], return_index=True)[1]
        channels[name] = Channel(name, k[last], v[last])
    periods = int(max(c.index[-1] for c in channels.values()))
    held = np.zeros((periods, volts.shape[1]))
    order = np.argsort(times, kind='stable')
    for k, value in zip(np.rint((times[order] - t0) / dt).astype(np.int64), volts[order]):
        if k < periods:
            held[max(k, 0):] = value
    return Measurement(source, float(dt), held, channels, scene)


def noise_level(channel: Channel) -> np.ndarray:
    """
    Return the noise level of each DET's samples of a channel (SI units).

    From the third differences of consecutive samples (a smooth signal has almost none, white
    noise of level sigma has sqrt(20) sigma): their median absolute deviation, which the few
    fast transients (steps, snap-through) do not move. At least :data:`NOISE_FLOOR`.
    """
    values = channel.values
    floor = NOISE_FLOOR.get(channel.name, 1e-12)
    if len(values) <= _DIFFERENCE_ORDER + 1:
        return np.full(values.shape[1], floor)
    diffs = np.diff(values, _DIFFERENCE_ORDER, axis=0)
    mad = np.median(np.abs(diffs - np.median(diffs, axis=0)), axis=0)
    peak = np.max(np.abs(values), axis=0)
    return np.maximum(_MAD_TO_SIGMA * mad / _DIFFERENCE_GAIN, np.maximum(floor, 1e-9 * peak))


# column -> the header names that mean it (lower case: a header's first word is compared so)
_CSV_NAMES = {'t': ('t', 'time'), 'v': ('v', 'voltage'),
              **{name: tuple(alias.lower() for alias in (name, *row.fit.csv_names))
                 for name, row in fit_channels().items()}}


def _csv_columns(path: str, header: Sequence[str]) -> dict:
    found = {}
    for i, title in enumerate(header):
        key = title.strip().split(' ')[0].lower()   # 't (s)', 'dy [m]' name the unit after
        for name, aliases in _CSV_NAMES.items():
            if key in aliases:
                found[name] = i
    for need in ('t', 'v'):
        if need not in found:
            raise CalibrationError(f'{path}: no column {need!r} in the header {list(header)} '
                                   f'(t, v and at least one of {", ".join(CHANNELS)})')
    return found


def read_csv(path: str, dt: float | None = None, scene=None) -> Measurement:
    """
    Read a CSV file with a header: ``t`` (s), ``v`` (V) and measured channels (:data:`CHANNELS`).

    An empty cell is a value not measured in that row; text that is not a number (``nan``
    included) is refused with one line.
    """
    try:
        with open(path, newline='', encoding='utf-8') as stream:
            rows = list(csv.reader(stream))
    except UnicodeDecodeError:
        raise CalibrationError(f'{path}: not a text CSV file') from None
    if not rows:
        raise CalibrationError(f'{path}: empty file')
    columns = _csv_columns(path, rows[0])
    data = {name: ([], []) for name in columns if name != 't'}
    for line, row in enumerate(rows[1:], start=2):
        cells = {name: row[i].strip() if i < len(row) else '' for name, i in columns.items()}
        if not any(cells.values()):
            continue
        try:
            t = float(cells['t'])
            for name, (times, values) in data.items():
                if cells[name]:
                    values.append(float(cells[name]))
                    times.append(t)
        except ValueError as exc:
            raise CalibrationError(f'{path}, line {line}: {exc}') from None
    commands = data.pop('v')
    return on_grid(path, commands, data, dt, scene)
