"""
Sensor models and their deterministic randomness, applied to each sample's published values.

A :class:`SensorBank` turns the true values of the sensed channels at sample k into what the
sensors read: the truth delayed by ``delay_samples``, plus ``bias`` and noise (white, or
first-order coloured with ``correlation_time``), rounded to ``quantization``, clipped to
[``range_min``, ``range_max``]; and per topic whether sample k is dropped (not published).

The randomness is counter-based (:class:`NoiseStreams`): every variate is a function of
(seed, DET, topic, sample index) only, through numpy's Philox4x64-10 with its key and counter
set, never of the order of calls, the host's load or the threads. Normal variates come from
two uniforms by Box-Muller (a fixed number of draws per variate, unlike numpy's ziggurat).
Variates are made for aligned blocks of :data:`BLOCK` sample indices at once, so the cost per
sample is a few vector operations.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

__all__ = ['BLOCK', 'NoiseStreams', 'SensorBank']

BLOCK = 1024                    # sample indices per block of variates (aligned: k // BLOCK)
_KEY_TAG = 0x6465745f73656e73   # the key's second word ('det_sens'): streams of this model
_DROPOUT_DET = 0                # a message's dropout draw: word 2 of its topic's DET 0 stream
_TO_UNIT = 2.0 ** -53
# up to this many channels a sample is read in Python floats (a numpy operation on a few values
# costs about 1 us, 20x a float operation); above, in numpy vectors. Both do the same IEEE
# operations in the same order, so they give the same readings bit for bit.
_LIST_LIMIT = 8
_WHOLE = 2.0 ** 52   # beyond it a float is a whole number: nothing to round (and no overflow)


class NoiseStreams:
    """
    Counter-based variates keyed by (seed, DET, topic, sample index).

    Sample k of stream (det, topic) is the Philox4x64-10 block of counter
    (k + 1, det, topic, 0) under key (seed, 'det_sens'): its first two words give one standard
    normal by Box-Muller, its third a uniform in [0, 1).
    """

    def __init__(self, seed: int):
        self.key = np.array([int(seed), _KEY_TAG], dtype=np.uint64)

    def words(self, det: int, topic: int, start: int, n: int) -> np.ndarray:
        """Return the Philox words of samples start .. start + n - 1, shape (n, 4), uint64."""
        # numpy's Philox adds 1 to the counter before each block: counter start gives k = start
        generator = np.random.Philox(key=self.key, counter=[start, det, topic, 0])
        return generator.random_raw(4 * n).reshape(n, 4)

    def draws(self, det: int, topic: int, start: int, n: int):
        """Return (standard normals, uniforms in [0, 1)) of samples start .. start + n - 1."""
        words = self.words(det, topic, start, n)
        u1 = 1.0 - (words[:, 0] >> np.uint64(11)) * _TO_UNIT   # (0, 1]: log(u1) is finite
        u2 = (words[:, 1] >> np.uint64(11)) * _TO_UNIT
        normals = np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * math.pi * u2)
        return normals, (words[:, 2] >> np.uint64(11)) * _TO_UNIT


class SensorBank:
    """
    The sensors of the sensed topics, over one vector of channels.

    :param sensors: the scene's :class:`~det_sim_ros.scenes.sensors.Sensors`.
    :param layout: (topic, channels) of each sensed topic, in the order their values are
        concatenated in the vectors given to :meth:`measure` (channel j of a topic is DET j).
    :param dt: the control period, s (for the correlation time).
    """

    def __init__(self, sensors, layout: Sequence[tuple[str, int]], dt: float):
        from ..scenes.sensors import SENSOR_TOPICS
        self.topics = [topic for topic, _ in layout]
        specs = [(SENSOR_TOPICS[topic], getattr(sensors, topic), n) for topic, n in layout]
        self._streams = NoiseStreams(sensors.seed)
        self._channels = [(topic_id, det) for topic_id, _, n in specs for det in range(n)]
        per = [(spec, n) for _, spec, n in specs]

        def column(value):
            return np.concatenate([np.full(n, value(spec), dtype=float) for spec, n in per])
        self._bias = column(lambda s: s.bias)
        self._sigma = column(lambda s: s.noise_std)
        tau = column(lambda s: s.correlation_time)
        self._coloured = (tau > 0.0) & (self._sigma > 0.0)
        ratio = np.where(self._coloured, dt / np.where(tau > 0.0, tau, 1.0), 0.0)
        self._decay = np.exp(-ratio)                        # a = e^(-dt/tau)
        self._drive = np.sqrt(-np.expm1(-2.0 * ratio))      # sqrt(1 - a^2)
        self._noisy = self._sigma > 0.0
        quant = column(lambda s: s.quantization)
        self._quantized = quant > 0.0
        self._step = np.where(self._quantized, quant, 1.0)
        self._low = column(lambda s: s.range_min if s.saturates else -math.inf)
        self._high = column(lambda s: s.range_max if s.saturates else math.inf)
        self._saturates = bool(np.isfinite(self._low).any())
        self._delay = column(lambda s: s.delay_samples).astype(np.intp)
        self._max_delay = int(self._delay.max()) if self._delay.size else 0
        self._dropout = np.array([spec.dropout for _, spec, _ in specs])
        self._drops = bool((self._dropout > 0.0).any())
        self._topic_first = np.cumsum([0] + [n for _, _, n in specs])[:-1]
        self._no_drop = np.zeros(len(specs), dtype=bool)
        self._columns = np.arange(len(self._channels))
        self._block = -1
        self.vectorised = self.size > _LIST_LIMIT
        self._path = (_ArrayPath if self.vectorised else _ListPath)(self)
        self._ou_end: dict[int, np.ndarray] = {}   # block -> coloured noise at its last sample
        self._last_k = None

    @property
    def size(self) -> int:
        """Return the number of channels."""
        return len(self._channels)

    # -- blocks of variates --------------------------------------------------------------------
    def _fill(self, block: int) -> None:
        """Make the offsets (bias + noise) and dropout flags of every sample of ``block``."""
        start = block * BLOCK
        normals = np.zeros((BLOCK, self.size))
        for j, (topic_id, det) in enumerate(self._channels):
            if self._noisy[j]:
                normals[:, j] = self._streams.draws(det, topic_id, start, BLOCK)[0]
        noise = normals * self._sigma
        if self._coloured.any():
            previous = self._ou_state_before(block)
            noise[:, self._coloured] = self._coloured_block(
                normals[:, self._coloured], previous, block)
        self._offset = noise + self._bias
        self._dropped = np.zeros((BLOCK, len(self.topics)), dtype=bool)
        for i, p in enumerate(self._dropout):
            if p > 0.0:
                topic_id = self._channels[self._topic_first[i]][0]
                uniforms = self._streams.draws(_DROPOUT_DET, topic_id, start, BLOCK)[1]
                self._dropped[:, i] = uniforms < p
        self._block = block

    def _ou_state_before(self, block: int):
        """Return the coloured noise at the sample before ``block`` (None for block 0)."""
        if block == 0:
            return None
        if block - 1 not in self._ou_end:   # out of order: the blocks before it, in order
            for earlier in range(block):
                if earlier not in self._ou_end:
                    self._fill(earlier)
        return self._ou_end[block - 1]

    def _coloured_block(self, normals, previous, block: int) -> np.ndarray:
        """
        Return the Ornstein-Uhlenbeck noise of one block (stationary, std sigma).

        The exact discretisation x_k = a x_(k-1) + sigma sqrt(1 - a^2) z_k, a = e^(-dt/tau), the
        first sample of the run x_0 = sigma z_0, summed over the block by doubling (log2 BLOCK
        vector steps; the same operations in the same order for a given block).
        """
        sigma, a = self._sigma[self._coloured], self._decay[self._coloured]
        x = normals * (sigma * self._drive[self._coloured])
        if previous is None:
            x[0] = normals[0] * sigma
        else:
            x[0] += a * previous
        power = a.copy()
        shift = 1
        while shift < len(x):   # x_k += a^s x_(k-s): after the steps, the full recursion
            x[shift:] = x[shift:] + power * x[:-shift]
            power = power * power
            shift *= 2
        self._ou_end[block] = x[-1].copy()
        return x

    # -- samples ---------------------------------------------------------------------------------
    def measure(self, k: int, values):
        """
        Return (the readings, dropped) for sample ``k`` of the channels' true ``values``.

        ``dropped``: per sensed topic, True if sample k is not published. Calls go in sample
        order; a ``k`` that does not follow the last call starts the delay line over (a reset).
        With :attr:`vectorised` values and readings are arrays, else lists of floats.
        """
        if self._last_k is None or k != self._last_k + 1:
            self._path.restart(k, values)
        self._last_k = k
        row = k - self._block * BLOCK
        if not 0 <= row < BLOCK:
            self._fill(k // BLOCK)
            self._path.block(self._offset, self._dropped)
            row = k - self._block * BLOCK
        return self._path.measure(k, row, values)

    def measure_run(self, values: np.ndarray, k0: int = 0):
        """
        Return (readings, dropped) of a whole run: ``values`` (n, channels) from sample ``k0``.

        ``dropped`` is (n, topics); the same numbers as n calls of :meth:`measure`.
        """
        values = np.asarray(values, dtype=float)
        readings = np.empty_like(values)
        dropped = np.empty((len(values), len(self.topics)), dtype=bool)
        self._last_k = None
        for i, row in enumerate(values):
            readings[i], dropped[i] = self.measure(k0 + i, row)
        self._last_k = None
        return readings, dropped


def _quantized(reading: float, step: float) -> float:
    """Return ``reading`` rounded to a multiple of ``step`` (half to even), as _ArrayPath."""
    levels = reading / step
    return round(levels) * step if abs(levels) < _WHOLE else reading


class _ListPath:
    """A sample's reading in Python floats (few channels)."""

    def __init__(self, bank: SensorBank):
        self.delays = bank._delay.tolist()
        self.max_delay = bank._max_delay
        # per channel: (step or 0, lower limit, upper limit)
        self.channels = list(zip([float(q) if on else 0.0
                                  for q, on in zip(bank._step, bank._quantized)],
                                 bank._low.tolist(), bank._high.tolist()))
        self.no_drop = tuple(bank._no_drop.tolist())
        self.drops = bank._drops

    def restart(self, k: int, values) -> None:
        self.first = k
        self.rows = self.max_delay + 1
        self.history = [list(values)] * self.rows

    def block(self, offset, dropped) -> None:
        self.offset = offset.tolist()
        self.dropped = [tuple(row) for row in dropped.tolist()] if self.drops else None

    def measure(self, k: int, row: int, values):
        if type(values) is not list:
            values = values.tolist() if hasattr(values, 'tolist') else list(values)
        if self.max_delay:
            history, rows, first = self.history, self.rows, self.first
            history[k % rows] = values
            values = [history[max(k - d, first) % rows][j] for j, d in enumerate(self.delays)]
        reading = []
        for value, offset, (step, low, high) in zip(values, self.offset[row], self.channels):
            value += offset
            if step:
                value = _quantized(value, step)
            reading.append(low if value < low else high if value > high else value)
        return reading, (self.dropped[row] if self.drops else self.no_drop)


class _ArrayPath:
    """A sample's reading in numpy vectors (many channels)."""

    def __init__(self, bank: SensorBank):
        self.bank = bank
        b = bank
        self.any_quantized = bool(b._quantized.any())
        self.steps = b._step

    def restart(self, k: int, values) -> None:
        b = self.bank
        self.first = k
        self.rows = b._max_delay + 1
        self.history = np.empty((self.rows, b.size))
        self.history[:] = values

    def block(self, offset, dropped) -> None:
        self.offset, self.dropped = offset, dropped

    def measure(self, k: int, row: int, values):
        b = self.bank
        values = np.asarray(values, dtype=float)
        if b._max_delay:
            self.history[k % self.rows] = values
            rows = np.maximum(k - b._delay, self.first) % self.rows
            values = self.history[rows, b._columns]
        reading = values + self.offset[row]
        if self.any_quantized:
            levels = reading / self.steps
            reading = np.where(b._quantized & (np.abs(levels) < _WHOLE),
                               np.rint(levels) * self.steps, reading)
        if b._saturates:
            reading = np.minimum(np.maximum(reading, b._low), b._high)
        return reading, (self.dropped[row] if b._drops else b._no_drop)
