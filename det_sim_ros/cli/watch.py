"""
What ``det_sim watch`` prints: a line per wall second, or one CSV row per sample.

The node publishes every sample on its JointState output topics
(det_sim_ros.ros.shell.OUTPUT_TOPICS) stamped with its sim time; a sample is complete once all
of them have arrived. The line shows the latest complete sample (per DET, or min / median / max
over more than four DETs), each value in engineering notation (1.790 mm, 200.2 nA) and shown as
0 below its quantity's resolution (the rest state's round-off, e.g. Δy = -4e-11 m); a plate's
height and tilt (the structure topic) follow. The CSV rows hold SI units (m, m/s, C, A), one
column per topic, field and DET. Which quantities, labels and resolutions: the output table
(det_sim_ros.scenes.outputs).

Every sample is kept while this process is slower than the node for a while (a busy core, a
terminal or pipe that takes the rows slowly): each output topic's reader keeps
:data:`QUEUE_DEPTH` messages (the node's writer keeps 10, so the reader's queue is what holds
them while Python is busy). A sample lost anyway (this whole process stopped longer than the
node's writer and the transport hold) shows as a gap in the sim time stamps, which advance by
one period per sample: :meth:`Watcher.loss_line` says how many and where, in one line.
"""

from __future__ import annotations

import collections
import math
import statistics

from ..io.contract import STRUCTURE_TOPIC
from ..ros.shell import OUTPUT_TOPICS
from ..scenes.outputs import (csv_fields, line_quantities, main_topic,
                              structure_line_quantities)

__all__ = ['Watcher', 'LINE_QUANTITIES', 'QUEUE_DEPTH']

QUEUE_DEPTH = 10000   # messages per output topic: 10 s of a 1 kHz node's samples

# (topic, field) -> (label, SI unit, resolution in it) of the live line, from the output table
# (det_sim_ros.scenes.outputs): a value below the resolution is round-off and shown as 0
LINE_QUANTITIES = line_quantities()
# a plate's structure outputs by published name: label, unit, resolution
STRUCTURE_QUANTITIES = structure_line_quantities()
PREFIXES = ((1e9, 'G'), (1e6, 'M'), (1e3, 'k'), (1.0, ''), (1e-3, 'm'), (1e-6, 'µ'),
            (1e-9, 'n'), (1e-12, 'p'))
CSV_FIELDS = csv_fields()   # (topic, field) columns, publishing order
NAMES_TOPIC = main_topic()   # the DET names of a sample: its main topic's
PER_DET_LIMIT = 4


def engineering(value: float, unit: str, resolution: float) -> str:
    """
    Return ``value`` (SI) with 4 significant digits and an SI prefix: 0.0002002 -> '200.2 µA'.

    A value whose magnitude is below ``resolution`` is '0 <unit>'; not finite: as it is.
    """
    if not math.isfinite(value):
        return f'{value} {unit}'
    if abs(value) < resolution:
        return f'0 {unit}'
    for factor, prefix in PREFIXES:   # the largest prefix that leaves >= 1 after rounding
        scaled = float(f'{value / factor:.4g}')
        if abs(scaled) >= 1.0:
            break
    return f'{scaled:.4g} {prefix}{unit}'


class Watcher:
    """
    Collects a node's output messages into samples and prints them.

    :param csv: one CSV row per complete sample; else :meth:`tick` prints a line a second.
    :param count: stop after this many rows or lines (0: never).
    """

    def __init__(self, csv: bool, count: int, stream):
        self.csv = csv
        self.count = count
        self.stream = stream
        self.printed = 0
        self._partial: dict[int, dict] = {}   # stamp ns -> {topic: JointState}
        self._latest = None                   # (stamp ns, {topic: JointState})
        self._shown = None
        self._next_line = None
        self._header = False
        self._structure = None                # the latest structure message (plates)
        self._last_stamp = None               # the latest complete sample's stamp (ns)
        self.samples = 0                      # complete samples taken
        self._steps = collections.Counter()   # stamp step (ns) -> how often
        self._gaps = []                       # (stamp before, stamp after) of unusual steps

    def subscribe(self, shell) -> None:
        """Subscribe to the node's output topics through ``shell`` (a NodeShell)."""
        for topic in OUTPUT_TOPICS + (STRUCTURE_TOPIC,):
            shell.subscribe(topic, self.take, depth=QUEUE_DEPTH)

    def waiting(self) -> bool:
        """Return True while no complete sample has arrived."""
        return self._latest is None

    def done(self) -> bool:
        """Return True once ``count`` rows or lines are printed."""
        return bool(self.count) and self.printed >= self.count

    def take(self, topic: str, msg) -> None:
        """Take one output message; a sample whose topics have all arrived is complete."""
        if topic == STRUCTURE_TOPIC:
            self._structure = msg
            return
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        parts = self._partial.setdefault(stamp, {})
        parts[topic] = msg
        if len(parts) < len(OUTPUT_TOPICS):
            return
        del self._partial[stamp]
        for older in [s for s in self._partial if s < stamp]:   # lost parts: never complete
            del self._partial[older]
        self._latest = (stamp, parts)
        self._note_step(stamp)
        if self.csv and not self.done():
            self._csv_row(stamp, parts)

    def _note_step(self, stamp: int) -> None:
        """Count the step from the previous sample (a step back: a reset, a new start)."""
        previous, self._last_stamp = self._last_stamp, stamp
        self.samples += 1
        if previous is None or stamp <= previous:
            return
        step = stamp - previous
        self._steps[step] += 1
        if step > 1.5 * min(self._steps):
            self._gaps.append((previous, stamp))

    def lost(self) -> int:
        """Return how many samples are missing between those taken (steps of many periods)."""
        if not self._steps:
            return 0
        period = min(self._steps)   # the node's period: the smallest step between samples
        return sum(count * (round(step / period) - 1) for step, count in self._steps.items())

    def loss_line(self) -> str:
        """Return one line saying how many samples were lost and where ('' if none)."""
        lost = self.lost()
        if not lost:
            return ''
        period = min(self._steps)
        gaps = [(a, b) for a, b in self._gaps if round((b - a) / period) > 1]
        where = ''
        if gaps:
            first = gaps[0]
            largest = max(gaps, key=lambda gap: gap[1] - gap[0])
            where = (f', the first after t = {first[0] * 1e-9:.3f} s, the largest '
                     f'{round((largest[1] - largest[0]) / period) - 1} after t = '
                     f'{largest[0] * 1e-9:.3f} s')
        return (f'{lost} sample(s) lost between the {self.samples} taken, in {len(gaps)} '
                f'gap(s){where} (this process was stopped or starved longer than the node'
                "'s writer holds its samples)")

    def tick(self, now: float) -> None:
        """Print the live line once a wall second (not with ``csv``)."""
        if self.csv or self.done():
            return
        if self._latest is None:   # the first line shows the first sample
            return
        if self._next_line is None:
            self._next_line = now
        if now < self._next_line:
            return
        self._next_line += 1.0
        if self._latest is self._shown:
            text = f't = {self._latest[0] * 1e-9:.3f} s (no new sample: paused?)'
        else:
            text = self._line(*self._latest)
        self._shown = self._latest
        self._print(text)

    def _print(self, text: str) -> None:
        self.stream.write(text + '\n')
        self.stream.flush()
        self.printed += 1

    def _line(self, stamp: int, parts: dict) -> str:
        names = list(parts[NAMES_TOPIC].name)
        values = {key: list(getattr(parts[key[0]], key[1])) for key in LINE_QUANTITIES}
        if len(names) <= PER_DET_LIMIT:
            cells = [f'{name}: ' + ' '.join(
                f'{label} {engineering(values[key][j], unit, resolution)}'
                for key, (label, unit, resolution) in LINE_QUANTITIES.items())
                for j, name in enumerate(names)]
        else:
            cells = [f'{label} ' + ' / '.join(engineering(v, unit, resolution) for v in (
                min(values[key]), statistics.median(values[key]), max(values[key])))
                for key, (label, unit, resolution) in LINE_QUANTITIES.items()]
            cells.insert(0, f'{len(names)} DETs, min / median / max:')
        structure = self._structure
        if structure is not None and self._stamp(structure) == stamp:
            shown = [(STRUCTURE_QUANTITIES[name], value)
                     for name, value in zip(structure.name, structure.position)
                     if name in STRUCTURE_QUANTITIES]
            cells.append('plate: ' + ' '.join(f'{label} {engineering(value, unit, resolution)}'
                                              for (label, unit, resolution), value in shown))
        return f't = {stamp * 1e-9:.3f} s  ' + '  '.join(cells)

    @staticmethod
    def _stamp(msg) -> int:
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def _csv_row(self, stamp: int, parts: dict) -> None:
        names = list(parts[NAMES_TOPIC].name)
        if not self._header:
            self._header = True
            self.stream.write(','.join(['t'] + [f'{topic}.{field}.{name}'
                                                for topic, field in CSV_FIELDS
                                                for name in names]) + '\n')
        row = [f'{stamp * 1e-9:.9f}']
        for topic, field in CSV_FIELDS:
            row += [repr(float(v)) for v in getattr(parts[topic], field)]
        self._print(','.join(row))
