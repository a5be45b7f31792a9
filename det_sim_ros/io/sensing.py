"""
Sensed outputs: the messages of a sample as the scene's sensors read it, and the truth beside it.

With sensors in the scene (:mod:`det_sim_ros.scenes.sensors`) every output topic carries what
its sensor reads (:class:`~det_sim_ros.sim.sensors.SensorBank`), and each sensed topic's true
values go on ``~/truth/<topic>`` (the node's private namespace: ``sim_node/truth/<topic>``
relative to its namespace), the same type. A sample a sensor drops is not published on that
topic; its truth still is. Without sensors the outputs are the plain contract's
(:class:`PlainOutputs`), byte for byte as before. No ROS here: the node, the offline recorder
(:func:`det_sim_ros.io.replay.simulate_to_log`) and re-simulation use the same objects.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .contract import JOINT_STATE, OutputContract, RELATIVE_TO_Y0, SampleWire, TOPIC_TYPES
from ..core.kernel import SampleCodec
from ..scenes.outputs import main_topic
from ..sim.sensors import SensorBank

__all__ = ['TRUTH', 'truth_topic', 'is_truth_topic', 'PlainOutputs', 'SensedOutputs',
           'make_outputs', 'MeasuredOutputs', 'SensorReadings', 'measured_run']

TRUTH = 'truth'


def truth_topic(topic: str, node_name: str = 'sim_node') -> str:
    """Return the truth topic of an output, relative to the node's namespace (~/truth/topic)."""
    return f'{node_name}/{TRUTH}/{topic}'


def is_truth_topic(name: str) -> bool:
    """Return True if a logged topic name is a truth topic ('/ns/sim_node/truth/charge')."""
    parts = name.strip('/').split('/')
    return len(parts) >= 2 and parts[-2] == TRUTH


class PlainOutputs:
    """A sample's messages without sensors: the contract's bytes of every output topic."""

    sensed = ()
    truth_topics = ()

    def __init__(self, contract: OutputContract):
        self._encoder = contract.encoder()
        self.topics = tuple(self._encoder.topics)

    def encode(self, k: int, out, t_ns: int) -> list:
        """Return the bytes of each output topic (then truth topic) for sample ``k``."""
        return self._encoder.encode(out, t_ns)

    def record(self, recorder, t_ns: int, samples) -> None:
        """Hand a sample's messages to the MCAP recorder."""
        recorder.record_sample(t_ns, self.topics, samples, TOPIC_TYPES)

    @staticmethod
    def heard(samples) -> bool:
        """Return True if the sample's main topic is published (a controller answers it)."""
        return True


class SensedOutputs:
    """
    A sample's messages with sensors: measured output topics, then the sensed topics' truth.

    :meth:`encode` returns the bytes per output topic (None where the sensor dropped the
    sample), then per sensed topic its truth's bytes. The measured bytes are one compiled call
    (the contract's :class:`~det_sim_ros.io.contract.SampleWire` reading the sensed positions
    from the readings appended to the output vector), as are the truth's.

    :param n_outputs: the length of the simulator's output vector.
    """

    def __init__(self, contract: OutputContract, sensors, dt: float, n_outputs: int,
                 node_name: str = 'sim_node'):
        truth = contract.encoder()
        self.topics = tuple(truth.topics)
        self.sensed = tuple(sensors.active)
        n = len(contract.det_names)
        self.truth_topics = tuple(truth_topic(topic, node_name) for topic in self.sensed)
        self.types = {**TOPIC_TYPES, **{topic: JOINT_STATE for topic in self.truth_topics}}
        self._truth_index = [self.topics.index(topic) for topic in self.sensed]
        wire = truth.wire
        source, op = wire.source.copy(), wire.op.copy()
        channels = []   # per sensed channel: (output index, y0 or None)
        for topic in self.sensed:
            slot = truth.slots[(topic, 'position')]
            for i in range(slot.start, slot.stop):
                channels.append((int(wire.source[i]), float(wire.a[i]) if wire.op[i] else None))
                source[i], op[i] = n_outputs + len(channels) - 1, 0
        self.bank = SensorBank(sensors, [(topic, n) for topic in self.sensed], dt,
                               [i for i, _ in channels], [y0 for _, y0 in channels], n_outputs)
        measured = dataclasses.replace(wire, source=source, op=op)
        self._codec = SampleCodec(_with_messages_of(measured, wire, self._truth_index))
        self._sensed_index = [self.topics.index(topic) for topic in self.sensed]
        self._main = self.topics.index(main_topic())
        self._logged = {}   # dropped flags -> (topics, indices) of the logged messages
        self._all_topics = self.topics + self.truth_topics

    def encode(self, k: int, out, t_ns: int) -> list:
        """Return sample ``k``'s measured bytes per output topic (None: dropped), then truth."""
        bank = self.bank
        _, dropped = bank.measure(k, out)
        samples = self._codec.encode(bank.vector, t_ns)   # measured, then truth: one call
        if True in dropped:
            for i, gone in zip(self._sensed_index, dropped):
                if gone:
                    samples[i] = None
        return samples

    def heard(self, samples) -> bool:
        """Return True if the sample's main topic is published (a controller answers it)."""
        return samples[self._main] is not None

    def record(self, recorder, t_ns: int, samples) -> None:
        """Hand a sample's messages (the published measured ones and the truth) to the log."""
        if None not in samples:   # (the same topics object each time: the log's fast path)
            recorder.record_sample(t_ns, self._all_topics, samples, self.types)
            return
        key = tuple(data is None for data in samples)
        plan = self._logged.get(key)
        if plan is None:
            indices = [i for i, gone in enumerate(key) if not gone]
            plan = self._logged[key] = (tuple(self._all_topics[i] for i in indices), indices)
        topics, indices = plan
        recorder.record_sample(t_ns, topics, [samples[i] for i in indices], self.types)


def _with_messages_of(wire: SampleWire, other: SampleWire, messages) -> SampleWire:
    """Return ``wire`` with messages ``messages`` of ``other`` appended (bytes and values)."""
    template, starts = [wire.template], list(wire.message_start)
    stamps = list(wire.stamp_position)
    extra = {name: [getattr(wire, name)] for name in ('source', 'op', 'a', 'b', 'position')}
    for m in messages:
        begin, end = int(other.message_start[m]), int(other.message_start[m + 1])
        shift = starts[-1] - begin
        template.append(other.template[begin:end])
        starts.append(starts[-1] + end - begin)
        stamps.append(int(other.stamp_position[m]) + shift)
        inside = (other.position >= begin) & (other.position < end)
        for name in ('source', 'op', 'a', 'b'):
            extra[name].append(getattr(other, name)[inside])
        extra['position'].append(other.position[inside] + shift)
    return SampleWire(template=b''.join(template),
                      message_start=np.array(starts, dtype=np.int64),
                      stamp_position=np.array(stamps, dtype=np.int64),
                      **{name: np.concatenate(parts) for name, parts in extra.items()})


def make_outputs(contract: OutputContract, scene, n_outputs: int, node_name: str = 'sim_node'):
    """Return the scene's sample messages: :class:`SensedOutputs` with sensors, else plain."""
    if not scene.sensors:
        return PlainOutputs(contract)
    return SensedOutputs(contract, scene.sensors, scene.dt, n_outputs, node_name)


class MeasuredOutputs:
    """
    What sim_node's output topics carry at each sample of an offline run, read sample by sample.

    For a closed loop offline: ``read(k, out)`` with the simulator's sample index and output
    vector gives topic -> the published positions (the sensor's readings on a sensed topic,
    None where it dropped the sample; the contract's values elsewhere), the same numbers the
    node publishes for the same run. Samples go in order from 0 (or from a reset).
    """

    def __init__(self, sim):
        self.contract = OutputContract(sim.model)
        self._sensed = (SensedOutputs(self.contract, sim.scene.sensors, sim.dt,
                                      len(sim.output_names)) if sim.scene.sensors else None)

    def read(self, k: int, out) -> dict:
        """Return topic -> positions (an array per DET, or None: not published) at sample k."""
        values = {topic: self.contract.values(out, topic, 'position')
                  for topic in self.contract.fields}
        if self._sensed is not None:
            readings, dropped = self._sensed.bank.measure(k, np.ascontiguousarray(out))
            n = len(self.contract.det_names)
            for j, topic in enumerate(self._sensed.sensed):
                values[topic] = None if dropped[j] else readings[j * n:(j + 1) * n].copy()
        return values


@dataclasses.dataclass
class SensorReadings:
    """One sensed topic over an offline run: per sample and DET, true and measured, received."""

    truth: np.ndarray      # (samples, DETs), the channel's unit
    measured: np.ndarray   # (samples, DETs): what the sensor read (also where dropped)
    received: np.ndarray   # (samples,) bool: False where the sample was not published


def measured_run(sim, result) -> dict:
    """
    Return topic -> :class:`SensorReadings` of an offline run (:func:`simulate`'s result).

    The same readings the node publishes for the same run (samples from ``result.t[0]``).
    """
    sensors = sim.scene.sensors
    contract = OutputContract(sim.model)
    outputs = np.column_stack([result[name] for name in sim.output_names])
    n = len(contract.det_names)
    topics = list(sensors.active)
    columns = [np.zeros((len(outputs), 0))]
    for topic in topics:
        values = outputs[:, contract.index[(topic, 'position')]]
        columns.append(contract.y0 - values if (topic, 'position') in RELATIVE_TO_Y0 else values)
    truth = np.hstack(columns)
    bank = SensorBank(sensors, [(topic, n) for topic in topics], sim.dt)
    k0 = int(round(result.t[0] / sim.dt))   # (the true values are given: source j = value j)
    measured, dropped = bank.measure_run(truth, k0)
    return {topic: SensorReadings(truth[:, j * n:(j + 1) * n], measured[:, j * n:(j + 1) * n],
                                  ~dropped[:, j])
            for j, topic in enumerate(topics)}
