"""
What ``det_sim watch`` prints: a line per wall second, or one CSV row per sample.

The node publishes every sample on four JointState topics (det_sim_ros.ros.shell.OUTPUT_TOPICS)
stamped with its sim time; a sample is complete once all four have arrived. The line shows the
latest complete sample in mm, µC and mA (per DET, or min / median / max over more than four
DETs); the CSV rows hold SI units (m, m/s, C, A), one column per topic, field and DET.
"""

from __future__ import annotations

import statistics

from ..ros.shell import OUTPUT_TOPICS

__all__ = ['Watcher', 'LINE_QUANTITIES']

# (topic, field) -> (label, unit, scale from SI) of the live line
LINE_QUANTITIES = {('displacement', 'position'): ('dy', 'mm', 1e3),
                   ('deflection', 'position'): ('q', 'mm', 1e3),
                   ('charge', 'position'): ('q_p', 'uC', 1e6),
                   ('current', 'position'): ('i', 'mA', 1e3)}
CSV_FIELDS = (('deflection', 'position'), ('deflection', 'velocity'),
              ('displacement', 'position'), ('charge', 'position'), ('current', 'position'))
PER_DET_LIMIT = 4


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

    def subscribe(self, shell) -> None:
        """Subscribe to the node's output topics through ``shell`` (a NodeShell)."""
        for topic in OUTPUT_TOPICS:
            shell.subscribe(topic, self.take)

    def waiting(self) -> bool:
        """Return True while no complete sample has arrived."""
        return self._latest is None

    def done(self) -> bool:
        """Return True once ``count`` rows or lines are printed."""
        return bool(self.count) and self.printed >= self.count

    def take(self, topic: str, msg) -> None:
        """Take one output message; a sample whose topics have all arrived is complete."""
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        parts = self._partial.setdefault(stamp, {})
        parts[topic] = msg
        if len(parts) < len(OUTPUT_TOPICS):
            return
        del self._partial[stamp]
        for older in [s for s in self._partial if s < stamp]:   # lost parts: never complete
            del self._partial[older]
        self._latest = (stamp, parts)
        if self.csv and not self.done():
            self._csv_row(stamp, parts)

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
        names = list(parts['displacement'].name)
        values = {key: [v * scale for v in getattr(parts[key[0]], key[1])]
                  for key, (_, _, scale) in LINE_QUANTITIES.items()}
        if len(names) <= PER_DET_LIMIT:
            cells = [f'{name}: ' + ' '.join(f'{label} {values[key][j]:.4g} {unit}' for key, (
                label, unit, _) in LINE_QUANTITIES.items()) for j, name in enumerate(names)]
        else:
            cells = [f'{label} [{unit}] {min(values[key]):.4g} / '
                     f'{statistics.median(values[key]):.4g} / {max(values[key]):.4g}'
                     for key, (label, unit, _) in LINE_QUANTITIES.items()]
            cells.insert(0, f'{len(names)} DETs, min / median / max:')
        return f't = {stamp * 1e-9:.3f} s  ' + '  '.join(cells)

    def _csv_row(self, stamp: int, parts: dict) -> None:
        names = list(parts['displacement'].name)
        if not self._header:
            self._header = True
            self.stream.write(','.join(['t'] + [f'{topic}.{field}.{name}'
                                                for topic, field in CSV_FIELDS
                                                for name in names]) + '\n')
        row = [f'{stamp * 1e-9:.9f}']
        for topic, field in CSV_FIELDS:
            row += [repr(float(v)) for v in getattr(parts[topic], field)]
        self._print(','.join(row))
