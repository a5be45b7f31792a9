"""
The per-DET output quantities sim_node publishes: one table every consumer is derived from.

Each row of :data:`OUTPUTS` is one JointState field of one output topic: the model output it
publishes (``Model.channel``: one value per DET), how people read it (the live line's label,
the plot's title, the display unit and its scale from SI) and, for a topic's ``position``, the
stream number of its sensor noise. The topic contract (det_sim_ros.io.contract), the scene's
``sensors`` section (det_sim_ros.scenes.sensors), the node shell and ``det_sim watch``,
``det_sim plot`` and ``det_sim fit`` (a row's :class:`FitChannel`: the channel a measurement
names it by) read this table; adding an output is one row here plus the model output it names.
One row is the main topic (:func:`main_topic`): the one sim_node's start waits for subscribers
of and ``det_sim watch`` takes the DET names from. The structure topic's outputs (a plate's
height and tilt) are the second, smaller table :data:`STRUCTURE_OUTPUTS`.

The table lives in the scenes layer, the lowest layer that needs it: the scene's ``sensors``
section has one subsection per sensed topic. It describes the published channels and imports
nothing, so every layer above may read it.

Order matters and is part of the contract: the rows' topic order is the order the node
publishes a sample's messages in (and a log holds them in); the sensor numbers key the noise
streams, so they are fixed per topic and never reused (a log's noise must not change when a
row is added).
"""

from __future__ import annotations

import dataclasses

__all__ = ['FitChannel', 'OutputQuantity', 'OUTPUTS', 'main_topic', 'fit_channels',
           'output_fields', 'output_units', 'relative_to_y0', 'output_topics', 'sensor_topics',
           'line_quantities', 'csv_fields', 'plot_panels',
           'StructureQuantity', 'STRUCTURE_OUTPUTS', 'structure_names',
           'structure_line_quantities', 'structure_panels']


@dataclasses.dataclass(frozen=True)
class FitChannel:
    """
    How ``det_sim fit`` names and weighs a measured output (a topic's ``position``).

    :param name: the channel's name in a measurement, a mapping (``--map NAME=...``), the
        ``--sigma`` option and the report.
    :param csv_names: the CSV header names that mean this channel (besides ``name``; a
        header's first word, any case).
    :param noise_floor: the smallest noise level (SI units): a noise-free channel still gets a
        finite weight.
    :param report_unit: the unit of the report's residuals and plots; ``report_scale`` takes
        SI to it.
    """

    name: str
    csv_names: tuple[str, ...]
    noise_floor: float
    report_unit: str
    report_scale: float


@dataclasses.dataclass(frozen=True)
class OutputQuantity:
    """
    One published field: ``topic``'s JointState ``field`` holds model output ``quantity``.

    :param label: its short name on the ``det_sim watch`` line.
    :param title: its panel title in ``det_sim plot``.
    :param unit: its SI unit (on the wire, in logs and CSV).
    :param display_unit: the plot's unit; ``display_scale`` takes SI to it (m -> mm: 1e3).
    :param resolution: in ``unit``: the live line shows smaller magnitudes as 0 (round-off).
    :param sensor: the sensor noise stream number of a ``position`` field (None: no sensor);
        fixed per topic, never reused.
    :param relative_to_y0: published as y0_i - value (the displacement from rest).
    :param fit: the channel ``det_sim fit`` measures it as (None: not fitted).
    :param main: the main topic's row (exactly one).
    """

    topic: str
    field: str
    quantity: str
    label: str
    title: str
    unit: str
    display_unit: str
    display_scale: float
    resolution: float
    sensor: int | None = None
    relative_to_y0: bool = False
    fit: FitChannel | None = None
    main: bool = False


# resolutions: a nanometre of a millimetre stroke, a picocoulomb of ~10 µC, a nanoampere of
# ~mA currents are round-off
OUTPUTS: tuple[OutputQuantity, ...] = (
    OutputQuantity('deflection', 'position', 'q', 'q', 'deflection q', 'm', 'mm', 1e3, 1e-9,
                   sensor=1),
    OutputQuantity('deflection', 'velocity', 'q_dot', 'dq/dt', 'deflection rate dq/dt', 'm/s',
                   'm/s', 1.0, 1e-9),
    OutputQuantity('displacement', 'position', 'y', 'dy', 'displacement Δy', 'm', 'mm', 1e3,
                   1e-9, sensor=0, relative_to_y0=True, main=True,
                   fit=FitChannel('dy', ('Δy', 'displacement'), 1e-12, 'um', 1e6)),
    OutputQuantity('charge', 'position', 'q_p', 'q_p', 'charge q_p', 'C', 'µC', 1e6, 1e-12,
                   sensor=2, fit=FitChannel('charge', ('q_p',), 1e-15, 'uC', 1e6)),
    OutputQuantity('current', 'position', 'i_DE', 'i', 'current i_DE', 'A', 'mA', 1e3, 1e-9,
                   sensor=3, fit=FitChannel('current', ('i_de',), 1e-12, 'mA', 1e3)),
)


def _rows(rows):
    return OUTPUTS if rows is None else tuple(rows)


def output_topics(rows=None) -> tuple[str, ...]:
    """Return the output topics in publishing order."""
    return tuple(dict.fromkeys(row.topic for row in _rows(rows)))


def main_topic(rows=None) -> str:
    """Return the main topic: the one row marked ``main``'s."""
    main = [row.topic for row in _rows(rows) if row.main]
    if len(main) != 1:
        raise ValueError(f'output table: exactly one row is the main topic (got {main})')
    return main[0]


# the fit's names of the time and the voltage (a CSV's columns, a mapping's channel)
_NOT_FIT_NAMES = ('t', 'time', 'v', 'voltage')


def fit_channels(rows=None) -> dict[str, OutputQuantity]:
    """Return fit channel name -> its row (a topic's position), in publishing order."""
    channels = {}
    for row in _rows(rows):
        if row.fit is None:
            continue
        if (row.field != 'position' or row.fit.name in channels
                or row.fit.name in _NOT_FIT_NAMES):
            raise ValueError(f'output table: a fit channel is a position field, named once and '
                             f'not {", ".join(_NOT_FIT_NAMES)} (got {row.fit.name!r} on '
                             f'{row.topic}.{row.field})')
        channels[row.fit.name] = row
    return channels


def output_fields(rows=None) -> dict[str, dict[str, str]]:
    """Return topic -> JointState field -> model output, in publishing order."""
    fields: dict[str, dict[str, str]] = {}
    for row in _rows(rows):
        fields.setdefault(row.topic, {})[row.field] = row.quantity
    return fields


def output_units(rows=None) -> dict[str, tuple[str, ...]]:
    """Return topic -> the SI unit of each of its fields, in field order."""
    return {topic: tuple(row.unit for row in _rows(rows) if row.topic == topic)
            for topic in output_topics(rows)}


def relative_to_y0(rows=None) -> frozenset:
    """Return the (topic, field) pairs published as y0_i - value."""
    return frozenset((row.topic, row.field) for row in _rows(rows) if row.relative_to_y0)


def sensor_topics(rows=None) -> dict[str, int]:
    """Return topic -> its sensor noise stream number, in stream order."""
    sensed = sorted((row.sensor, row.topic) for row in _rows(rows) if row.sensor is not None)
    numbers = [number for number, _ in sensed]
    if len(set(numbers)) != len(numbers):
        raise ValueError(f'output table: sensor stream numbers must differ (got {numbers})')
    return {topic: number for number, topic in sensed}


def line_quantities(rows=None) -> dict[tuple[str, str], tuple[str, str, float]]:
    """
    Return (topic, field) -> (label, SI unit, resolution) of the live line.

    The line shows what sensors measure (each topic's position), in sensor stream order.
    """
    by_topic = {(row.topic, row.field): row for row in _rows(rows)}
    return {(topic, 'position'): (by_topic[(topic, 'position')].label,
                                  by_topic[(topic, 'position')].unit,
                                  by_topic[(topic, 'position')].resolution)
            for topic in sensor_topics(rows)}


def csv_fields(rows=None) -> tuple[tuple[str, str], ...]:
    """Return the (topic, field) columns of ``det_sim watch --csv``, in publishing order."""
    return tuple((row.topic, row.field) for row in _rows(rows))


def plot_panels(rows=None) -> dict[tuple[str, str], tuple[str, str, float]]:
    """Return (topic, field) -> (panel title, display unit, scale from SI), publishing order."""
    return {(row.topic, row.field): (row.title, row.display_unit, row.display_scale)
            for row in _rows(rows)}


@dataclasses.dataclass(frozen=True)
class StructureQuantity:
    """
    One output of the structure topic: model structure output ``output`` published as ``name``.

    The published value is ``sign`` * (output - output at rest at 0 V), in the displacement's
    sign; ``label`` to ``resolution`` as in :class:`OutputQuantity`.
    """

    output: str
    name: str
    sign: float
    label: str
    title: str
    unit: str
    display_unit: str
    display_scale: float
    resolution: float


STRUCTURE_OUTPUTS: tuple[StructureQuantity, ...] = (
    # m: y0_plate - plate_y = mean of the two displacements
    StructureQuantity('plate_y', 'plate_dy', -1.0, 'height', 'plate height Δy', 'm', 'mm', 1e3,
                      1e-9),
    # rad: phi - phi0 = (dy_right - dy_left) / w
    StructureQuantity('plate_phi', 'plate_phi', 1.0, 'tilt', 'plate tilt φ − φ0', 'rad', 'mrad',
                      1e3, 1e-9),
)


def structure_names(rows=None) -> dict[str, tuple[str, float]]:
    """Return model structure output -> (published name, sign)."""
    return {row.output: (row.name, row.sign)
            for row in (STRUCTURE_OUTPUTS if rows is None else rows)}


def structure_line_quantities(rows=None) -> dict[str, tuple[str, str, float]]:
    """Return published name -> (label, SI unit, resolution) on the live line."""
    return {row.name: (row.label, row.unit, row.resolution)
            for row in (STRUCTURE_OUTPUTS if rows is None else rows)}


def structure_panels(rows=None) -> dict[str, tuple[str, str, float]]:
    """Return published name -> (panel title, display unit, scale from SI)."""
    return {row.name: (row.title, row.display_unit, row.display_scale)
            for row in (STRUCTURE_OUTPUTS if rows is None else rows)}
