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

import dataclasses
import math
from typing import Sequence

import numpy as np

from ..core.kernel import SensorReader

__all__ = ['BLOCK', 'NoiseStreams', 'SensorBank', 'ReaderFields']

BLOCK = 1024                    # sample indices per block of variates (aligned: k // BLOCK)
_KEY_TAG = 0x6465745f73656e73   # the key's second word ('det_sens'): streams of this model
_DROPOUT_DET = 0                # a message's dropout draw: word 2 of its topic's DET 0 stream
_TO_UNIT = 2.0 ** -53


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


@dataclasses.dataclass(frozen=True)
class ReaderFields:
    """
    The named fields the compiled reader (``_ckernel.SensorReader``) is built from.

    Per channel: the output it reads (``source``), whether the value is ``y0 - output``
    (``relative``, the displacement), its ``delay`` in samples, quantization ``step`` (0: none)
    and saturation range [``low``, ``high``]; the output vector's length ``n_outputs``.
    """

    source: np.ndarray     # int64
    relative: np.ndarray   # int64, 0 or 1
    delay: np.ndarray      # int64
    y0: np.ndarray         # float64
    step: np.ndarray       # float64
    low: np.ndarray        # float64
    high: np.ndarray       # float64
    n_outputs: int


class SensorBank:
    """
    The sensors of the sensed topics, over one vector of channels.

    :param sensors: the scene's :class:`~det_sim_ros.scenes.sensors.Sensors`.
    :param layout: (topic, channels) of each sensed topic, in channel order (channel j of a
        topic is DET j).
    :param dt: the control period, s (for the correlation time).
    :param source: per channel, the index of its true value in the vectors given to
        :meth:`measure` (default: channel j is value j).
    :param y0: per channel, None, or y0 when the true value is y0 - the vector's value.
    :param n_outputs: the length of the vectors given to :meth:`measure` (default: channels).
    """

    def __init__(self, sensors, layout: Sequence[tuple[str, int]], dt: float,
                 source: Sequence[int] | None = None, y0: Sequence | None = None,
                 n_outputs: int | None = None):
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
        size = len(self._channels)
        n_outputs = size if n_outputs is None else int(n_outputs)
        y0 = [None] * size if y0 is None else list(y0)
        self.fields = ReaderFields(
            source=np.arange(size, dtype=np.int64) if source is None
            else np.array(source, dtype=np.int64),
            relative=np.array([v is not None for v in y0], dtype=np.int64),
            delay=column(lambda s: s.delay_samples).astype(np.int64),
            y0=np.array([0.0 if v is None else float(v) for v in y0]),
            step=np.where(quant > 0.0, quant, 0.0),
            low=column(lambda s: s.range_min if s.saturates else -math.inf),
            high=column(lambda s: s.range_max if s.saturates else math.inf),
            n_outputs=n_outputs)
        self._reader = SensorReader(self.fields)
        self.vector = np.zeros(n_outputs + size)   # read(): the output vector, the readings
        self.readings = self.vector[n_outputs:]
        self._dropout = np.array([spec.dropout for _, spec, _ in specs])
        self._drops = bool((self._dropout > 0.0).any())
        self._topic_first = np.cumsum([0] + [n for _, _, n in specs])[:-1]
        self._no_drop = (False,) * len(specs)
        self._block = -1
        self._ou_end: dict[int, np.ndarray] = {}   # block -> coloured noise at its last sample

    @property
    def size(self) -> int:
        """Return the number of channels."""
        return len(self._channels)

    # -- blocks of variates --------------------------------------------------------------------
    def _fill(self, block: int) -> None:
        """Make the offsets (bias + noise) and dropout flags of every sample of ``block``."""
        start = block * BLOCK
        normals = np.zeros((BLOCK, self.size))
        draws = {}   # (det, topic) -> (normals, uniforms): one Philox run per stream and block
        for j, (topic_id, det) in enumerate(self._channels):
            if self._noisy[j]:
                draws[det, topic_id] = self._streams.draws(det, topic_id, start, BLOCK)
                normals[:, j] = draws[det, topic_id][0]
        noise = normals * self._sigma
        if self._coloured.any():
            previous = self._ou_state_before(block)
            noise[:, self._coloured] = self._coloured_block(
                normals[:, self._coloured], previous, block)
        self._offset = np.ascontiguousarray(noise + self._bias)
        if self._drops:
            columns = []
            for i, p in enumerate(self._dropout):
                topic_id = self._channels[self._topic_first[i]][0]
                key = (_DROPOUT_DET, topic_id)
                if key not in draws and p > 0.0:
                    draws[key] = self._streams.draws(*key, start, BLOCK)
                columns.append((draws[key][1] < p).tolist() if p > 0.0 else [False] * BLOCK)
            self._dropped = list(zip(*columns))   # per sample: a tuple of flags per topic
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
        self._ou_end = {block: x[-1].copy()}   # (only the latest: a long run keeps one)
        return x

    # -- samples ---------------------------------------------------------------------------------
    def measure(self, k: int, out):
        """
        Return (the readings, dropped) for sample ``k`` of the output vector ``out``.

        The readings are :attr:`readings`, a view that the next call overwrites (and
        :attr:`vector` holds ``out`` before them); ``dropped``: per sensed topic, True if
        sample k is not published. Calls go in sample order; a ``k`` that does not follow the
        last call starts the delay line over (a reset). One compiled call per sample.
        """
        row = k - self._block * BLOCK
        if not 0 <= row < BLOCK:
            self._fill(k // BLOCK)
            row = k - self._block * BLOCK
        self._reader.read(out, k, self._offset, row, self.vector)
        return self.readings, (self._dropped[row] if self._drops else self._no_drop)

    def measure_run(self, values: np.ndarray, k0: int = 0):
        """
        Return (readings, dropped) of a whole run: ``values`` (n, inputs) from sample ``k0``.

        ``dropped`` is (n, topics); the same numbers as n calls of :meth:`measure` (a run of
        its own: the delay line starts at ``k0``).
        """
        values = np.ascontiguousarray(values, dtype=float)
        readings = np.empty((len(values), self.size))
        dropped = np.empty((len(values), len(self.topics)), dtype=bool)
        self._reader = SensorReader(self.fields)   # a run of its own
        for i, row in enumerate(values):
            readings[i], dropped[i] = self.measure(k0 + i, row)
        return readings, dropped
