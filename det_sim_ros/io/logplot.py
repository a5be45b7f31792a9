"""
``det_sim plot LOG.mcap``: every channel of a sim_node log against sim time.

The plot is one PNG (one panel per quantity, every DET a line, the voltage commands as
steps), with a text summary. Single, plate and array logs alike; no ROS graph needed.

Speed (a 10-minute 1 kHz log holds 2.4 million messages): the CDR payloads of a topic mostly
share one byte layout (the same DET names, the same array lengths), so they are grouped by
length, parsed once per group and read as numpy columns at the parsed offsets; a row whose
fixed bytes differ from its group's first row is decoded one by one (det_sim_ros.io.cdr).
Lines longer than the plot has pixels are drawn as their min/max envelope per pixel column,
which keeps every extreme.
"""

from __future__ import annotations

import dataclasses
import math
import os
import struct

import numpy as np

from .cdr import CdrError, deserialize, Reader
from .contract import basename, COMMAND_TOPICS, JOINT_COMMAND_TOPIC, PREDICTABILITY_TOPIC
from .log import file_kind, LogReader
from .sensing import is_truth_topic
from ..scenes.outputs import plot_panels, structure_panels

__all__ = ['LogData', 'Channel', 'read_log', 'summary', 'plot_log', 'LogPlotError',
           'PANELS']


class LogPlotError(ValueError):
    """A log that cannot be plotted (one line)."""


# (topic, field) -> (panel title, unit label, scale to the unit), from the output table
# (det_sim_ros.scenes.outputs); structure channels get one panel each (PANELS_STRUCTURE), by
# published name
PANELS = plot_panels()
PANELS_STRUCTURE = structure_panels()
# the node's predictability measure (det_sim_ros.ros.predictability): its own panel, and the
# stretches where it is beyond its limit (the log's metadata 'predictability_limit') shaded
PANEL_PREDICTABILITY = ('twin distance (path robust below the limit)', '% of stroke', 100.0)
DEFAULT_PREDICTABILITY_LIMIT = 0.05
ENVELOPE_COLUMNS = 2000


@dataclasses.dataclass
class Channel:
    """One published quantity: sample times (s) and values (n_samples, n_channels)."""

    title: str
    unit: str
    t: np.ndarray
    values: np.ndarray
    names: list


@dataclasses.dataclass
class LogData:
    """What :func:`read_log` found: the applied voltages as steps, the output channels."""

    files: list
    det_names: list
    voltage_t: np.ndarray          # s, times of the applied-voltage changes (0 first)
    voltage: np.ndarray            # (n_changes, n_dets), V, held from each time on
    channels: list                 # Channel per panel, in PANELS order
    commands: int
    refused: int
    complete: bool
    t_end: float
    not_robust: list = dataclasses.field(default_factory=list)   # [(t0, t1)] s, shaded


# -- CDR layouts (read by det_sim_ros.io.cdr's Reader) -------------------------------------------

def _joint_state_layout(data):
    """
    Return the offsets of a little-endian JointState payload.

    The stamp, the names, and (offset, n) of the three arrays; None for big endian (the column
    reader views the bytes as little endian).
    """
    r = Reader(data)
    if not r.little:
        return None
    stamp = r.take(8, 4)
    r.string()                                   # frame_id
    names = r.strings()
    arrays = {field: r.doubles_at() for field in ('position', 'velocity', 'effort')}
    return {'stamp': stamp, 'names': names, 'arrays': arrays, 'end': r.pos}


def _multiarray_layout(data):
    """Offsets of a little-endian Float64MultiArray payload: (offset, n) of data."""
    r = Reader(data)
    if not r.little:
        return None
    for _ in range(r.count(12)):                 # layout.dim
        r.string()
        r.u32()
        r.u32()
    r.u32()                                      # data_offset
    return {'names': None, 'arrays': {'data': r.doubles_at()}, 'stamp': None, 'end': r.pos}


def _columns(by_length, layout_of, decode_slow):
    """
    Read one topic's payloads vectorized, grouped by payload length.

    ``by_length``: length -> (order, log times, uint8 matrix of the payloads). Returns groups
    (order, log times, layout, matrix) and the rows decoded one by one (order, log time,
    message).
    """
    groups, slow = [], []
    for length, (order, times, matrix) in by_length.items():
        try:
            layout = layout_of(matrix[0].tobytes())
        except (CdrError, struct.error, UnicodeDecodeError, IndexError):
            layout = None
        if layout is None or layout['end'] != length:
            slow += [(int(o), int(t), decode_slow(row.tobytes()))
                     for o, t, row in zip(order, times, matrix)]
            continue
        fixed = np.ones(length, dtype=bool)      # bytes every row of this layout shares
        if layout['stamp'] is not None:
            fixed[layout['stamp']:layout['stamp'] + 8] = False
        for at, n in layout['arrays'].values():
            fixed[at:at + 8 * n] = False
        same = np.all(matrix[:, fixed] == matrix[0, fixed], axis=1)
        if not np.all(same):
            slow += [(int(o), int(t), decode_slow(row.tobytes()))
                     for o, t, row in zip(order[~same], times[~same], matrix[~same])]
            order, times, matrix = order[same], times[same], matrix[same]
        groups.append((order, times, layout, matrix))
    return groups, slow


def _doubles(matrix, at, n):
    return np.ascontiguousarray(matrix[:, at:at + 8 * n]).view('<f8').reshape(len(matrix), n)


# -- reading: the columns of LogReader's record blocks ------------------------------------------

class _Scan:
    """
    All messages of a log as per-topic uint8 matrices grouped by payload length.

    Each record block of :meth:`LogReader.blocks` (a chunk's records, walked once by the reader)
    is read with numpy at its message offsets. Reading stops quietly at a torn record (a file
    cut by a crash: ``complete`` False), as the reader does.
    """

    def __init__(self, reader):
        self.topics = {}        # topic -> {'type': str, 'parts': {length: [(order, t, M)]}}
        self._order = 0
        for block in reader.blocks():
            self._block(block, reader.channels)
        self.complete = reader.complete

    def _block(self, block, channels):
        if not block.positions:
            return
        arr = np.frombuffer(block.raw, dtype=np.uint8)
        channel, log_time, payload_start, size = block.columns()
        order = self._order + np.arange(len(channel))
        self._order += len(channel)
        key = channel.astype(np.int64) * (1 << 32) + size
        for k in np.unique(key):
            sel = key == k
            ch, dl = int(k >> 32), int(k & 0xFFFFFFFF)
            info = channels.get(ch)
            if info is None or is_truth_topic(info[0]):   # (the plot shows the published)
                continue
            start = payload_start[sel]
            matrix = arr[start[:, None] + np.arange(dl)] if dl else np.zeros((len(start), 0),
                                                                             np.uint8)
            entry = self.topics.setdefault(info[0], {'type': info[1], 'parts': {}})
            entry['parts'].setdefault(dl, []).append((order[sel], log_time[sel], matrix))

    def by_length(self, topic):
        """Return payload length -> (order, log times ns, matrix) of one topic (basename match)."""
        out = {}
        for name, entry in self.topics.items():
            if basename(name) != topic:
                continue
            for dl, parts in entry['parts'].items():
                out.setdefault(dl, []).extend(parts)
        return {dl: tuple(np.concatenate(col) for col in zip(*parts))
                for dl, parts in out.items()}

    def type_of(self, topic):
        """Return the type name of a topic (basename match), '' if absent."""
        return next((e['type'] for name, e in self.topics.items() if basename(name) == topic),
                    '')

    def basenames(self):
        """Return the topics' last names, sorted."""
        return sorted({basename(name) for name in self.topics})


def _check_magic(files):
    for path in files:
        if file_kind(path) != 'mcap':
            raise LogPlotError(f'{path}: not an MCAP file')


def _scene(reader):
    import yaml
    from ..scenes.scene import load_scene
    text = reader.scene_yaml
    if not text:
        return None
    return load_scene(yaml.safe_load(text))


def read_log(paths) -> LogData:
    """Read a sim_node log (file, split files or a directory) into arrays (see module doc)."""
    try:
        reader = LogReader(paths)
        _check_magic(reader.files)
        scan = _Scan(reader)
        reader.scan_info()
    except LogPlotError:
        raise
    except FileNotFoundError as exc:
        raise LogPlotError(str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - unreadable, ...
        raise LogPlotError(f'cannot read {paths}: {type(exc).__name__}: {exc}') from None
    try:
        scene = _scene(reader)
    except Exception as exc:  # noqa: BLE001
        raise LogPlotError(f'{reader.files[0]}: the logged scene is invalid: {exc}') from None
    topics = scan.basenames()
    outputs = [t for t in topics if t not in COMMAND_TOPICS
               and scan.type_of(t).endswith('/JointState')]
    if not outputs and not any(t in topics for t in COMMAND_TOPICS):
        raise LogPlotError(f'{reader.files[0]}: no sim_node topics in the log '
                           f'(found: {", ".join(topics) or "no messages"})')
    det_names = list(scene.det_names) if scene is not None else []
    channels = []
    t_end = 0.0
    for topic in outputs:
        type_name = scan.type_of(topic)
        t, names, fields = _read_joint_states(scan.by_length(topic),
                                              lambda d, ty=type_name: deserialize(ty, d))
        if topic == PREDICTABILITY_TOPIC:
            if 'position' in fields:
                title, unit, scale = PANEL_PREDICTABILITY
                channels.append(Channel(title, unit, t, fields['position'] * scale, names))
            continue
        if not det_names and topic != 'structure':
            det_names = names
        if t.size:
            t_end = max(t_end, float(t[-1]))
        for field, values in fields.items():
            if topic == 'structure':
                for j, name in enumerate(names):
                    title, unit, scale = PANELS_STRUCTURE.get(name, (name, '', 1.0))
                    channels.append(Channel(title, unit, t, values[:, j:j + 1] * scale, [name]))
            elif (topic, field) in PANELS:
                title, unit, scale = PANELS[topic, field]
                channels.append(Channel(title, unit, t, values * scale, names))
    titles = [p[0] for p in PANELS.values()] + [p[0] for p in PANELS_STRUCTURE.values()]
    channels.sort(key=lambda c: titles.index(c.title) if c.title in titles else len(titles))
    v_max = scene.physics.v_max if scene is not None else math.inf
    n_det = len(det_names) or 1
    times, volts, n_commands, refused = _applied_voltages(scan, det_names, n_det, v_max,
                                                          deserialize)
    if times.size:
        t_end = max(t_end, float(times[-1]))
    return LogData(reader.files, det_names or [f'det{i}' for i in range(n_det)], times, volts,
                   channels, n_commands, refused, scan.complete, t_end,
                   _not_robust(channels, _logged_limit(reader)))


def _logged_limit(reader) -> float:
    try:
        return float(reader.info.get('predictability_limit') or DEFAULT_PREDICTABILITY_LIMIT)
    except (ValueError, AttributeError):
        return DEFAULT_PREDICTABILITY_LIMIT


def _not_robust(channels, limit: float) -> list:
    """Return [(t0, t1)] where the logged twin distance is beyond ``limit`` (a fraction)."""
    channel = next((c for c in channels if c.title == PANEL_PREDICTABILITY[0]), None)
    if channel is None or not channel.t.size:
        return []
    order = np.argsort(channel.t, kind='stable')
    t, beyond = channel.t[order], channel.values[order, 0] / PANEL_PREDICTABILITY[2] > limit
    edges = np.flatnonzero(np.diff(np.r_[False, beyond, False].astype(int)))
    return [(float(t[a]), float(t[min(b, t.size - 1)])) for a, b in zip(edges[0::2],
                                                                        edges[1::2])]


def _read_joint_states(by_length, decode):
    """Sample times (s), channel names and {field: (n, k) values} of one JointState topic."""
    groups, slow = _columns(by_length, _joint_state_layout, decode)
    parts = []    # (order, t, {field: values}, names)
    for order, _, layout, matrix in groups:
        st = layout['stamp']
        sec = np.ascontiguousarray(matrix[:, st:st + 4]).view('<i4').reshape(-1)
        nsec = np.ascontiguousarray(matrix[:, st + 4:st + 8]).view('<u4').reshape(-1)
        fields = {f: _doubles(matrix, at, n) for f, (at, n) in layout['arrays'].items() if n}
        parts.append((order, sec + nsec * 1e-9, fields, layout['names']))
    for order, _, msg in slow:
        fields = {f: np.array([getattr(msg, f)]) for f in ('position', 'velocity', 'effort')
                  if len(getattr(msg, f))}
        parts.append((np.array([order]), np.array([msg.header.stamp.sec
                                                   + msg.header.stamp.nanosec * 1e-9]),
                      fields, list(msg.name)))
    if not parts:
        return np.zeros(0), [], {}
    # the channel set of most samples (the node always publishes all channels)
    counts = {}
    for p in parts:
        counts[tuple(p[3])] = counts.get(tuple(p[3]), 0) + len(p[0])
    names = list(max(counts, key=counts.get))
    keep = [p for p in parts if list(p[3]) == names]
    order = np.concatenate([p[0] for p in keep])
    sort = np.argsort(order, kind='stable')
    t = np.concatenate([p[1] for p in keep])[sort]
    fields = {}
    for field in ('position', 'velocity'):
        if all(field in p[2] for p in keep):
            fields[field] = np.concatenate([p[2][field] for p in keep])[sort]
    return t, names, fields


def _applied_voltages(scan, det_names, n_det, v_max, deserialize):
    """Return the voltages the node held, as steps: (times s, (n, n_det) V, commands, refused)."""
    events = []    # (order, log time ns, values, joint names or None)
    for topic in COMMAND_TOPICS:
        type_name = scan.type_of(topic)
        if not type_name:
            continue
        joint = topic == JOINT_COMMAND_TOPIC
        groups, slow = _columns(scan.by_length(topic),
                                _joint_state_layout if joint else _multiarray_layout,
                                lambda d: deserialize(type_name, d))
        field = 'position' if joint else 'data'
        for order, times, layout, matrix in groups:
            at, n = layout['arrays'][field]
            names = layout['names'] if joint else None
            events += [(o, t, v, names) for o, t, v in zip(order.tolist(), times.tolist(),
                                                           _doubles(matrix, at, n).tolist())]
        events += [(o, t, list(getattr(msg, field)), list(msg.name) if joint else None)
                   for o, t, msg in slow]
    events.sort()
    held = [0.0] * n_det
    out_t, out_v = [0.0], [list(held)]
    refused = 0
    names = det_names or [f'det{i}' for i in range(n_det)]
    index = {name: i for i, name in enumerate(names)}
    for _, t_ns, values, joint_names in events:
        volts = values
        if joint_names is not None:      # a subset by name; the others hold (as the node)
            if (not joint_names or len(joint_names) != len(values)
                    or any(n not in index for n in joint_names)):
                volts = None
            else:
                volts = list(held)
                for n, v in zip(joint_names, values):
                    volts[index[n]] = v
        if volts is None or len(volts) != n_det or not all(math.isfinite(v) for v in volts):
            refused += 1
            continue
        volts = [min(max(v, 0.0), v_max) for v in volts]
        if volts != held:
            held = volts
            out_t.append(t_ns * 1e-9)
            out_v.append(list(held))
    return np.array(out_t), np.array(out_v, dtype=float), len(events), refused


# -- output --------------------------------------------------------------------------------------

def summary(data: LogData) -> str:
    """Plain-text summary: span, commands, and per channel and DET min / max / final."""
    unfinished = '' if data.complete else ' (UNFINISHED: the readable part)'
    lines = [f"log: {', '.join(data.files)}" + unfinished,
             f'DETs: {", ".join(data.det_names)}; sim time 0 .. {data.t_end:.6g} s; '
             f'{data.commands} commands ({data.refused} refused), '
             f'{len(data.voltage_t) - 1} voltage changes']
    width = max([len(n) for n in data.det_names] + [8])
    lines.append(f"{'quantity':<28} {'channel':<{width}} {'samples':>8} {'min':>12} "
                 f"{'max':>12} {'final':>12}")
    v = data.voltage
    for j, name in enumerate(data.det_names):
        lines.append(f"{'voltage (V)':<28} {name:<{width}} {len(data.voltage_t):>8} "
                     f'{v[:, j].min():>12.6g} {v[:, j].max():>12.6g} {v[-1, j]:>12.6g}')
    for ch in data.channels:
        label = f'{ch.title} ({ch.unit})'
        for j, name in enumerate(ch.names):
            col = ch.values[:, j]
            if col.size:
                lines.append(f'{label:<28} {name:<{width}} {col.size:>8} {col.min():>12.6g} '
                             f'{col.max():>12.6g} {col[-1]:>12.6g}')
            else:
                lines.append(f'{label:<28} {name:<{width}} {0:>8}')
    return '\n'.join(lines) + '\n'


def _envelope(t, y, columns=ENVELOPE_COLUMNS):
    """(t, y) reduced to min and max per column when longer than 2 x columns."""
    n = len(t)
    if n <= 2 * columns:
        return t, y
    edges = np.linspace(0, n, columns + 1).astype(int)
    lo = np.minimum.reduceat(y, edges[:-1])
    hi = np.maximum.reduceat(y, edges[:-1])
    tt = np.repeat(t[edges[:-1]], 2)
    yy = np.empty(2 * columns)
    yy[0::2], yy[1::2] = lo, hi
    return tt, yy


def plot_log(data: LogData, path: str, dpi: int = 80, title: str = '') -> str:
    """Write the PNG (one panel per quantity, all DETs) and return its path."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    panels = 1 + len(data.channels)
    fig, axes = plt.subplots(panels, 1, figsize=(11, 1.9 * panels + 0.6), sharex=True,
                             squeeze=False)
    axes = axes[:, 0]
    many = len(data.det_names) > 10
    t_end = data.t_end if data.t_end > 0 else 1.0
    tv = np.r_[data.voltage_t, t_end]
    for j, name in enumerate(data.det_names):
        v = np.r_[data.voltage[:, j], data.voltage[-1, j]]
        axes[0].step(tv, v, where='post', lw=1.0, label=None if many else name)
    axes[0].set_ylabel('V')
    axes[0].set_title('applied voltage (commands, held)', fontsize=9, loc='left')
    for ax, ch in zip(axes[1:], data.channels):
        for j, name in enumerate(ch.names):
            tt, yy = _envelope(ch.t, ch.values[:, j])
            ax.plot(tt, yy, lw=0.8, label=None if many else name)
        ax.set_ylabel(ch.unit)
        ax.set_title(ch.title, fontsize=9, loc='left')
    for ax in axes:
        ax.grid(alpha=0.3)
        for start, end in data.not_robust:   # the path not robust there: shaded
            ax.axvspan(start, end, color='r', alpha=0.12, lw=0)
        if not many and ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc='upper right')
    if many:
        axes[0].text(0.99, 0.95, f'{len(data.det_names)} DETs', transform=axes[0].transAxes,
                     ha='right', va='top', fontsize=8)
    axes[-1].set_xlabel('sim time (s)')
    axes[-1].set_xlim(0.0, t_end)
    fig.suptitle(title or os.path.basename(data.files[0]), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
