"""
The scene's optional ``sensors:`` section: what each output topic's sensor does to its position.

One subsection per output topic whose ``position`` a sensor measures (:data:`SENSOR_TOPICS`,
the output table's rows with a sensor number: det_sim_ros.scenes.outputs),
each with the keys of :data:`SENSOR_SPEC`, and a ``seed`` for the sensor noise. Every key is
off by default, and a scene without the section (or with every key off) publishes the exact
state as before. Values are in the measured channel's unit (m for displacement and
deflection, C for charge, A for current); the model applied to them is
:mod:`det_sim_ros.sim.sensors`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping

from .keys import check_section, check_value, SceneError
from .outputs import sensor_topics

__all__ = ['SENSOR_TOPICS', 'SENSOR_SPEC', 'SENSOR_DEFAULTS', 'SEED_SPEC', 'SensorSpec',
           'Sensors', 'check_sensors', 'sensors_to_dict']

# output topic -> its stream number in the noise key (fixed: a log's noise must not depend on
# which topics a scene senses or in which order they are listed)
# (displacement 0, deflection 1, charge 2, current 3: the output table's sensor numbers)
SENSOR_TOPICS = sensor_topics()
_CHANNEL = 'channel unit'
_ANY = (-math.inf, False, math.inf)
_NON_NEGATIVE = (0.0, True, math.inf)
SENSOR_SPEC = {
    'noise_std': ('float', *_NON_NEGATIVE, _CHANNEL,
                  'sensor: standard deviation of the additive Gaussian noise (0 = none)'),
    'correlation_time': ('float', *_NON_NEGATIVE, 's', 'sensor: correlation time of the noise '
                         '(first-order coloured, Ornstein-Uhlenbeck; 0 = white)'),
    'quantization': ('float', *_NON_NEGATIVE, _CHANNEL,
                     'sensor: output step, values rounded to a multiple of it (0 = none)'),
    'bias': ('float', *_ANY, _CHANNEL, 'sensor: constant offset added to the reading'),
    'delay_samples': ('int', 0, True, 100000, 'samples',
                      'sensor: the reading published this many control periods late'),
    'dropout': ('float', 0.0, True, 1.0, '-',
                'sensor: probability that a sample is not published on the topic'),
    'range_min': ('float', *_ANY, _CHANNEL, 'sensor: lower saturation limit (range_min = '
                  'range_max = 0: no saturation)'),
    'range_max': ('float', *_ANY, _CHANNEL, 'sensor: upper saturation limit (range_min = '
                  'range_max = 0: no saturation)'),
}
SEED_SPEC = ('int', 0, True, 2 ** 63 - 1, '-', 'sensors: seed of the sensor noise and dropout')
SENSOR_DEFAULTS = {'noise_std': 0.0, 'correlation_time': 0.0, 'quantization': 0.0, 'bias': 0.0,
                   'delay_samples': 0, 'dropout': 0.0, 'range_min': 0.0, 'range_max': 0.0}


@dataclasses.dataclass(frozen=True)
class SensorSpec:
    """One topic's sensor (units of the measured channel; see :data:`SENSOR_SPEC`)."""

    noise_std: float = 0.0
    correlation_time: float = 0.0
    quantization: float = 0.0
    bias: float = 0.0
    delay_samples: int = 0
    dropout: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0

    @property
    def active(self) -> bool:
        """Return True if any knob is on (the topic's published values differ from the state)."""
        return self != _OFF

    @property
    def saturates(self) -> bool:
        """Return True if the reading is clipped to [range_min, range_max]."""
        return not (self.range_min == 0.0 and self.range_max == 0.0)


_OFF = SensorSpec()


class Sensors:
    """
    The scene's sensors: the noise seed and one :class:`SensorSpec` per sensed output topic.

    ``Sensors(seed, displacement=SensorSpec(...))``; a topic not given is off. Each topic of
    :data:`SENSOR_TOPICS` is an attribute (``sensors.charge``). Immutable and hashable.
    """

    __slots__ = ('seed', 'specs')

    def __init__(self, seed: int = 0, **specs: SensorSpec):
        unknown = [topic for topic in specs if topic not in SENSOR_TOPICS]
        if unknown:
            raise TypeError(f'Sensors: unknown topic(s) {unknown}; sensed topics: '
                            + ', '.join(SENSOR_TOPICS))
        object.__setattr__(self, 'seed', seed)
        object.__setattr__(self, 'specs', {topic: specs.get(topic, _OFF)
                                           for topic in SENSOR_TOPICS})

    def __getattr__(self, topic: str) -> SensorSpec:
        """Return one topic's :class:`SensorSpec` (``sensors.displacement``)."""
        try:
            return object.__getattribute__(self, 'specs')[topic]
        except KeyError:
            raise AttributeError(topic) from None

    def __setattr__(self, name, value):
        raise dataclasses.FrozenInstanceError(f'cannot assign to field {name!r}')

    def __eq__(self, other) -> bool:
        """Return True for the same seed and specs."""
        if not isinstance(other, Sensors):
            return NotImplemented
        return (self.seed, self.specs) == (other.seed, other.specs)

    def __hash__(self) -> int:
        """Hash of the seed and the specs."""
        return hash((self.seed, tuple(self.specs.items())))

    def __reduce__(self):
        """Pickle and copy by the constructor's arguments."""
        return _sensors, (self.seed, tuple(self.specs.items()))

    def __repr__(self) -> str:
        """Return Sensors(seed, topic=spec, ...) of the topics with a knob on."""
        on = ''.join(f', {topic}={spec!r}' for topic, spec in self.active.items())
        return f'Sensors(seed={self.seed!r}{on})'

    @property
    def active(self) -> dict:
        """Return topic -> SensorSpec of every topic with a knob on, in SENSOR_TOPICS order."""
        return {topic: spec for topic, spec in self.specs.items() if spec.active}

    def __bool__(self) -> bool:
        """Return True if any topic's sensor has a knob on."""
        return bool(self.active)


def _sensors(seed, specs) -> Sensors:
    return Sensors(seed, **dict(specs))


def _check_spec(topic: str, content) -> SensorSpec:
    if content is None:
        return _OFF
    values = check_section(f'sensors.{topic}', content, SENSOR_SPEC, SENSOR_DEFAULTS)
    if values['range_min'] > values['range_max'] or (
            values['range_min'] == values['range_max'] != 0.0):
        raise SceneError(f"scene key 'sensors.{topic}.range_min': must be below range_max "
                         f"(got {values['range_min']!r} and {values['range_max']!r}; both 0 = "
                         'no saturation)')
    return SensorSpec(**values)


def check_sensors(content) -> Sensors:
    """Return the optional ``sensors`` section, checked (one SceneError line for a bad value)."""
    if content is None:
        return Sensors()
    if not isinstance(content, dict):
        raise SceneError(f"scene key 'sensors': must be a mapping (got {content!r})")
    allowed = ['seed', *SENSOR_TOPICS]
    for key in content:
        if key not in allowed:
            raise SceneError(f'unknown scene key sensors.{key!r}; allowed: '
                             + ', '.join(allowed))
    seed = check_value('sensors.seed', content.get('seed', 0), SEED_SPEC)
    return Sensors(seed, **{topic: _check_spec(topic, content.get(topic))
                            for topic in SENSOR_TOPICS})


def sensors_to_dict(sensors: Sensors, full: bool = False) -> Mapping:
    """
    Return the section as a scene file holds it.

    Only the topics with a knob on (and the seed if set), unless ``full`` (every key: the
    node's read-only parameters).
    """
    data = {'seed': sensors.seed} if full or sensors.seed else {}
    for topic in SENSOR_TOPICS:
        spec = getattr(sensors, topic)
        if full or spec.active:
            data[topic] = dataclasses.asdict(spec)
    return data
