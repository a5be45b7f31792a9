"""
The actuator's shape as ``visualization_msgs/MarkerArray`` (RViz, Foxglove 3D panel).

:class:`MarkerFrames` turns a model state into the serialized CDR bytes of one MarkerArray
(no rclpy needed): per DET, namespace = the DET name, ids 0/1 the beams' centre lines
(LINE_STRIP), 2 the DET (CUBE, blue at 0 V to red at v_max), 3 the reference point on beam A
(SPHERE: its x is the published deflection q); for plate scenes namespace 'plate', id 0 (CUBE).
Geometry: :mod:`det_sim_ros.physics.geometry`.

Frames: by default one frame per DET, ``<namespace>/<DET name>`` (``det0``, ``arm1/left``),
each cell at its frame's origin; the plate is drawn in the first DET's frame (the others are
placed relative to it by the user's transforms: docs/visualization.md). With ``frame_id`` set,
all DETs are drawn in that one frame, side by side (:func:`.geometry.layout_offsets`).

Speed: the message layout is fixed for a model, so it is serialized once with sentinel values
in the fields that move, their byte offsets are located, and each frame only writes the new
numbers into a copy of those bytes, far cheaper than building rclpy Point objects per frame
(the cost: docs/performance.md, 'Markers', from ``bench/marker_cost.py``).

:class:`NodeMarkers` is the node's side: the publisher on ``markers`` and the display-rate
throttle (every N-th control sample, N = rate_hz / display rate, so the cost per simulated
second is bounded and the frames are stamped on the sample grid); viewers get at most two frames
per display period of wall time (a free run would send them many times as many as a display
shows). No frame is built while nobody subscribes to ``markers`` and the log is off. A frame
that would show nothing new (no coordinate moved by more than 0.1 µm, the same voltages) is not
sent, except once per simulated second: markers persist in RViz and Foxglove until replaced, so
a settled actuator costs about one frame per simulated second.
"""

from __future__ import annotations

import math
import struct
import time
import types
from typing import NamedTuple

import numpy as np

from ..physics.geometry import ActuatorGeometry, DET_WIDTH_MIN

__all__ = ['MarkerFrames', 'NodeMarkers', 'MARKER_TOPIC', 'MARKER_TYPE', 'attach_markers']

MARKER_TOPIC = 'markers'
MARKER_TYPE = 'visualization_msgs/msg/MarkerArray'
BEAM_LINE_WIDTH = 1.0e-3     # m, drawn width of the beams' centre lines
REFERENCE_DIAMETER = 2.0e-3  # m
PLATE_THICKNESS = 2.0e-3     # m
BEAM_COLOR = (0.85, 0.85, 0.85, 1.0)
REFERENCE_COLOR = (1.0, 0.8, 0.0, 1.0)
PLATE_COLOR = (0.4, 0.6, 0.4, 0.8)
# the node sends a frame only if something moved by more than this (m; far below what a
# display of mm deflections shows) or the voltage changed, and at least every KEEPALIVE_S
MOVE_TOLERANCE = 1.0e-7
KEEPALIVE_S = 1.0
KEEPALIVE_NS = int(KEEPALIVE_S * 1e9)
# MarkerFrames' ways of building a frame, fastest first
FRAME_PATHS = ('compiled', 'stacked', 'general')


class _StackedCells(NamedTuple):
    """One-coordinate cells as one map (see MarkerFrames._stack_polynomial_cells)."""

    maps: np.ndarray                    # (cells, values, 4): V = maps @ (1, q, q^2, q^4)
    height: int                         # index of the cell height in a cell's values
    thickness: int                      # index of the drawn DET thickness (set per frame)
    thickness_times_height: np.ndarray  # n d0 l0 per cell (m^2): thickness = this / height
    coordinate: np.ndarray              # each cell's q in the state vector


def _sentinel(k: int) -> float:
    """Return a float64 that cannot occur in a real frame (a subnormal-range tag)."""
    return (k + 1) * 1.0e-300


class _Template(NamedTuple):
    """A frame's bytes with the byte offsets of the fields that move (see MarkerFrames)."""

    raw: bytes
    cells: list          # per DET: field -> offset (beam0/1: first point, det_*, ref_pose)
    plate: int | None    # the plate's position
    stamps: np.ndarray   # each marker's header stamp


_STAMP_TAG = 0x5A5A0000   # int32 sentinels of the markers' stamps: this + marker index


def _tagged_markers(model, geo, frames, offsets):
    """
    Return the frame's markers, every moving field holding a unique sentinel.

    Return (markers, per DET field -> sentinel tag, the plate's tag or None, per DET the
    float32 colour sentinel).
    """
    from geometry_msgs.msg import Point
    from visualization_msgs.msg import Marker
    tags = iter(range(10 ** 6))
    markers = []

    def marker(ns, mid, kind, frame, color, scale):
        m = Marker(ns=ns, id=mid, type=kind, action=Marker.ADD)
        m.header.frame_id = frame
        m.header.stamp.sec = _STAMP_TAG + len(markers)
        m.pose.orientation.w = 1.0
        m.scale.x, m.scale.y, m.scale.z = scale
        m.color.r, m.color.g, m.color.b, m.color.a = color
        m.frame_locked = True
        markers.append(m)
        return m

    def tag(obj, field='x'):
        t = next(tags)
        setattr(obj, field, _sentinel(t))
        return t

    cells, colors = [], []
    for i, name in enumerate(geo.names):
        slot = {}
        for mid in (0, 1):
            m = marker(name, mid, Marker.LINE_STRIP, frames[i], BEAM_COLOR,
                       (BEAM_LINE_WIDTH, 0.0, 0.0))
            m.pose.position.x, m.pose.position.y, m.pose.position.z = offsets[i]
            m.points = [Point() for _ in range(geo.n_points)]
            slot[f'beam{mid}'] = tag(m.points[0])
        det = marker(name, 2, Marker.CUBE, frames[i], (0.2, 0.3, 1.0, 0.6), (0.0, 0.0, 0.0))
        slot['det_pose'] = tag(det.pose.position)
        slot['det_scale'] = tag(det.scale)
        # colour: four float32 right after scale; located with a float32 sentinel
        det.color.r = float(np.float32(1.0e-30 * (i + 1)))
        colors.append(det.color.r)
        ref = marker(name, 3, Marker.SPHERE, frames[i], REFERENCE_COLOR,
                     (REFERENCE_DIAMETER,) * 3)
        slot['ref_pose'] = tag(ref.pose.position)
        cells.append(slot)
    plate = None
    if geo.has_plate:
        width = model.scene.structure['plate_width']
        depth = max(ph.A0 / ph.l0 for ph in model.scene.cell_physics())
        plate = tag(marker('plate', 0, Marker.CUBE, frames[0], PLATE_COLOR,
                           (depth, width + depth, PLATE_THICKNESS)).pose.position)
    return markers, cells, plate, colors


def _sentinel_template(markers, cells, plate, colors) -> _Template:
    """Return the markers' CDR bytes (io.cdr, serialized once) and where each sentinel landed."""
    from visualization_msgs.msg import MarkerArray
    from ..io.cdr import serialize
    raw = serialize(MarkerArray(markers=markers))

    def find(packed):
        at = raw.find(packed)
        if at < 0 or raw.find(packed, at + 1) >= 0:
            raise RuntimeError('marker layout: a sentinel is missing or not unique')
        return at

    def f64(t):
        return find(struct.pack('<d', _sentinel(t)))

    located = []
    for slot, color in zip(cells, colors):
        offsets = {key: f64(t) for key, t in slot.items()}
        offsets['det_color'] = find(struct.pack('<f', color))
        located.append(offsets)
    stamps = np.array([find(struct.pack('<i', _STAMP_TAG + k)) for k in range(len(markers))])
    return _Template(raw, located, None if plate is None else f64(plate), stamps)


class MarkerFrames:
    """
    Serialized MarkerArray frames of one model (see the module docstring).

    :param frame_prefix: prepended to the DET names to form the per-DET frame ids (e.g.
        'arm1/'); ignored when ``frame_id`` is given.
    :param frame_id: one frame for everything (cells laid out side by side), or '' for one
        frame per DET.
    :param paths: the ways of building a frame allowed, fastest first (:data:`FRAME_PATHS`);
        the first one this model supports is used (:attr:`path`). All give the same frames:
        'compiled' (frames.c, stacked cells without a plate), 'stacked' (numpy, cells of one
        coordinate each), 'general' (numpy, any model).
    """

    def __init__(self, model, frame_prefix: str = '', frame_id: str = '', n_points: int = 41,
                 paths=FRAME_PATHS):
        unknown = set(paths) - set(FRAME_PATHS)
        if unknown or not paths:
            raise ValueError(f'paths: expected some of {FRAME_PATHS}, got {tuple(paths)}')
        self.geometry = geo = ActuatorGeometry(model, n_points)
        self.v_max = model.scene.physics.v_max
        common = bool(frame_id)
        self.frames = [frame_id if common else f'{frame_prefix}{name}' for name in geo.names]
        offsets = geo.offsets if common else np.zeros_like(geo.offsets)
        self._offsets = offsets
        template = _sentinel_template(*_tagged_markers(model, geo, self.frames, offsets))
        self._cell_slots, self._plate_slot = template.cells, template.plate
        if template.plate is not None:
            self._plate_shift = -geo.offsets[0] if not common else np.zeros(3)
        self._stamps = template.stamps
        self.n_markers = len(template.stamps)
        raw, n = template.raw, geo.n_points
        # every moving field is rewritten in every frame, so one buffer is reused; CDR aligns
        # relative to the 4-byte encapsulation header, so the views start at byte 4
        self._raw = bytearray(raw)
        self._buffer = np.frombuffer(self._raw, dtype=np.uint8)
        self.size = len(raw)
        body = self._buffer[4:]
        self._f64 = body[:len(body) // 8 * 8].view('<f8')
        self._f32 = body[:len(body) // 4 * 4].view('<f4')
        self._u32 = body[:len(body) // 4 * 4].view('<u4')

        def index(offset, count, stride=1, size=8):
            if (offset - 4) % size:
                raise RuntimeError('marker layout: a field is not aligned')
            return (offset - 4) // size + stride * np.arange(count)

        f64, f32 = [], []
        for slot in self._cell_slots:
            for key in ('beam0', 'beam1'):
                f64 += [index(slot[key], n, 3), index(slot[key] + 16, n, 3)]   # x, z
            f64 += [index(slot[key], 3) for key in ('det_pose', 'det_scale', 'ref_pose')]
            f32.append(index(slot['det_color'], 4, size=4))
        if self._plate_slot is not None:
            f64.append(index(self._plate_slot, 7))                 # position, orientation
        self._f64_index = np.concatenate(f64)
        self._f32_index = np.concatenate(f32)
        stamp_index = np.concatenate([index(o, 2, size=4) for o in self._stamps])
        self._stamp_index = (stamp_index[0::2].copy(), stamp_index[1::2].copy())   # sec, ns
        self._samplers = list(zip(geo.slices, geo.samplers, self._offsets))
        self._cell_maps = [self._cell_map(sampler, off) for sampler, off in
                           zip(geo.samplers, self._offsets)]
        self._colored_for = None
        self._last_sent = None    # frame_if_moved's last frame: (volts, stamp, values or None)
        self.skipped = 0
        self._stacked = (self._stack_polynomial_cells()
                         if {'compiled', 'stacked'} & set(paths) else None)
        self._compiled = self._compile() if 'compiled' in paths else None
        if self._compiled is None and self._stacked is not None and 'stacked' not in paths:
            self._stacked = None
        if self.path not in paths:
            raise ValueError(f'paths {tuple(paths)}: none of them can draw this model')

    @property
    def path(self) -> str:
        """Return the way frames are built: 'compiled', 'stacked' or 'general' (``paths``)."""
        if self._compiled is not None:
            return 'compiled'
        return 'general' if self._stacked is None else 'stacked'

    @property
    def frame_map(self):
        """Return the compiled builder (``core.kernel.FrameMap``); None off the 'compiled' path."""
        return self._compiled

    @staticmethod
    def _cell_map(sampler, off):
        """
        Return a cell's frame values as V = V0 + Kq q + Ke e(w').

        The deflections are linear in the Ritz coordinates q and the heights linear in the
        shortening density e at the Gauss nodes, so a frame costs a few matrix products (the frame
        is per control sample in the node's thread: fewer numpy calls is what makes it cheap).
        Order: beam A x (n), z (n), beam B x, z, DET centre (3), DET size (3), reference point (3).
        """
        n, r = sampler.n_samples, sampler.S.shape[1]
        paper = sampler.kinematics not in ('consistent', 'exact')
        cum = sampler.half_cumulative if paper else sampler.cumulative   # paper: e = w'^2
        m = 4 * n + 9
        V0, Kq, Ke = np.zeros(m), np.zeros((m, r)), np.zeros((m, cum.shape[1]))
        Kq[:n], Kq[2 * n:3 * n] = sampler.S, -sampler.S
        V0[n:2 * n] = V0[3 * n:4 * n] = sampler.s
        Ke[n:2 * n] = Ke[3 * n:4 * n] = -cum
        top, k = cum[-1], 4 * n                  # height h = l - y(l)
        V0[k:k + 3] = off[0], off[1], off[2] + 0.5 * sampler.length
        Ke[k + 2] = -0.5 * top
        V0[k + 3:k + 6] = 0.0, sampler.det_width, sampler.length   # thickness: per frame
        Ke[k + 5] = -top
        ref = sampler.ref_index
        V0[k + 6:k + 9] = off[0], off[1], off[2] + sampler.s[ref]
        Kq[k + 6] = sampler.S[ref]
        Ke[k + 8] = -cum[ref]
        poly = None
        if r == 1 and sampler.kinematics in ('paper', 'consistent'):
            # one coordinate: e is a polynomial in q, so V = V0 + K1 q + K2 q^2 + K4 q^4
            b1 = sampler.B1[:, 0]
            K2 = Ke @ (b1 * b1)
            K4 = (0.125 * Ke @ b1 ** 4) if sampler.kinematics == 'consistent' else 0.0 * K2
            if sampler.kinematics == 'consistent':
                K2 = 0.5 * K2
            poly = (Kq[:, 0].copy(), K2, K4)
        return V0, Kq, Ke, sampler.B1, sampler.kinematics, k + 5, k + 3, poly

    def _stack_polynomial_cells(self):
        """
        Return the cells as one stacked map when every drawn value is a polynomial in q.

        That is when each cell has one coordinate and paper or consistent kinematics:
        V = P @ (1, q, q^2, q^4) for all cells in one matrix product; else None (the general path
        of :meth:`values`). A frame then takes a handful of numpy calls instead of one per drawn
        quantity; what a frame costs in the node: docs/performance.md, 'Markers'
        (``bench/marker_cost.py``).
        """
        maps = self._cell_maps
        if (any(poly is None for *_, poly in maps) or len({len(m[0]) for m in maps}) != 1
                or len({(m[5], m[6]) for m in maps}) != 1):
            return None
        return _StackedCells(
            maps=np.stack([np.column_stack([V0, *poly]) for V0, *_, poly in maps]),
            height=maps[0][5], thickness=maps[0][6],
            thickness_times_height=np.array([s.physics.n * s.physics.d0 * s.physics.l0
                                             for s in self.geometry.samplers]),
            coordinate=np.array([s.start for s, _, _ in self._samplers]))

    def _compile(self):
        """
        Return the compiled frame builder of stacked cells without a plate, or None.

        The builder is _ckernel.FrameMap (frames.c); with None the numpy path builds the frames. It
        computes what :meth:`values` computes, in the same order (the same bits), compares with the
        last frame it wrote, and writes values and stamps into the frame bytes in one call.
        """
        if self._stacked is None or self._plate_slot is not None:
            return None
        try:
            from ..core.kernel import FrameMap
        except ImportError:   # an old build of the extension: the numpy path
            return None
        st = self._stacked
        fields = types.SimpleNamespace(
            maps=np.ascontiguousarray(st.maps), n_values=st.maps.shape[1],
            height=st.height, thickness=st.thickness,
            thickness_times_height=st.thickness_times_height,
            coordinate=st.coordinate.astype(np.int64),
            position=(4 + 8 * self._f64_index).astype(np.int64),   # bytes; in values' order
            stamp_position=np.asarray(self._stamps, dtype=np.int64),   # sec; nanosec at +4
            frame_size=self.size, min_thickness=DET_WIDTH_MIN, tolerance=MOVE_TOLERANCE)
        return FrameMap(fields)

    def _coordinates(self, x):
        """Return the stacked cells' coordinates: a float for one cell, else an array."""
        index = self._stacked.coordinate
        return float(x[index[0]]) if len(index) == 1 else x[index]

    def _stacked_values(self, q):
        """:meth:`values` of stacked cells at their coordinates q (a new array)."""
        st = self._stacked
        P = st.maps
        if isinstance(q, float):
            q2 = q * q     # (the compiled FrameMap sums in this order: the same bits)
            values = P[0, :, 0] + P[0, :, 1] * q + P[0, :, 2] * q2 + P[0, :, 3] * (q2 * q2)
            values[st.thickness] = max(st.thickness_times_height[0] / values[st.height],
                                       DET_WIDTH_MIN)
            heights = (values[st.height],)
        else:
            q1 = q[:, None]
            q2 = q1 * q1
            cells = P[:, :, 0] + P[:, :, 1] * q1 + P[:, :, 2] * q2 + P[:, :, 3] * (q2 * q2)
            heights = cells[:, st.height]
            cells[:, st.thickness] = np.maximum(st.thickness_times_height / heights,
                                                DET_WIDTH_MIN)
            values = cells.reshape(-1)
        if self._plate_slot is None:
            return values
        return np.concatenate((values, self._plate_values(heights[0], heights[-1],
                                                          sum(heights) / len(heights))))

    def _plate_values(self, first_height, last_height, mean_height):
        """Return the plate's centre and orientation (quaternion) on the cells' moving ends."""
        w = self.geometry.scene.structure['plate_width']
        tilt = math.atan2(last_height - first_height, w)   # > 0: the right side is higher
        centre = self._plate_shift + (0.0, 0.0, mean_height + 0.5 * PLATE_THICKNESS)
        half = 0.5 * tilt              # rotation about x: quaternion (sin, 0, 0, cos)
        return (*centre, math.sin(half), 0.0, 0.0, math.cos(half))

    def frame(self, x, u, stamp_ns: int) -> bytes:
        """CDR bytes of the MarkerArray at state x, voltages u, stamped ``stamp_ns`` (sim time)."""
        return self.pack(self.values(x), u, stamp_ns)

    def frame_if_moved(self, x, u, stamp_ns: int) -> bytes | None:
        """
        Return the frame, or None when it would show what the last one showed.

        None when, since the last frame returned here, no drawn coordinate moved by more than
        :data:`MOVE_TOLERANCE`, the voltages are the same, and less than :data:`KEEPALIVE_S` of sim
        time has passed (markers persist in RViz and Foxglove until replaced, so a settled actuator
        needs no new frames; the keep-alive serves viewers that join later).
        """
        volts = self._volts(u)
        last = self._last_sent
        force = last is None or volts != last[0] or stamp_ns - last[1] >= KEEPALIVE_NS
        if self._compiled is not None:   # the same bytes as below, in one compiled call
            if not self._compiled.update(x, self._raw, force, int(stamp_ns)):
                self.skipped += 1
                return None
            self._last_sent = (volts, stamp_ns, None)
            self._color(volts)
            return bytes(self._raw)
        values = self.values(x)
        if not force and float(np.max(np.abs(values - last[2]))) <= MOVE_TOLERANCE:
            self.skipped += 1
            return None
        self._last_sent = (volts, stamp_ns, values)   # (values() returns a new array)
        return self.pack(values, u, stamp_ns)

    def _volts(self, u) -> list:
        """Return the voltages as a list, one per DET (a scalar stands for all)."""
        if isinstance(u, np.ndarray):
            return u.tolist()
        return list(u) if np.ndim(u) else [u] * len(self._samplers)

    def values(self, x) -> np.ndarray:
        """Return the moving drawn coordinates (m; plate: quaternion) in field order; new array."""
        if self._stacked is not None:
            return self._stacked_values(self._coordinates(x))
        parts, heights = [], []
        for (s, sampler, _), (V0, Kq, Ke, B1, kinematics, i_h, i_thick, _) in zip(
                self._samplers, self._cell_maps):
            q = x[s]
            wp = B1 @ q
            e = wp * wp
            if kinematics == 'consistent':
                e = e * (0.5 + 0.125 * e)
            elif kinematics == 'exact':
                e = 1.0 - np.sqrt(np.maximum(1.0 - e, 0.0))
            values = V0 + Kq @ q + Ke @ e
            h = float(values[i_h])
            values[i_thick] = sampler.det_thickness(h)
            heights.append(h)
            parts.append(values)
        if self._plate_slot is not None:
            parts.append(self._plate_values(heights[0], heights[-1], sum(heights) / len(heights)))
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def pack(self, values, u, stamp_ns: int) -> bytes:
        """Return the frame's bytes from :meth:`values`, the voltages and the stamp."""
        self._f64[self._f64_index] = values
        self._color(self._volts(u))
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        self._u32[self._stamp_index[0]] = sec
        self._u32[self._stamp_index[1]] = nanosec
        return self._buffer.tobytes()

    def _color(self, volts) -> None:
        """Write each DET's colour (blue 0 V, red v_max) to the frame if the voltages changed."""
        if volts != self._colored_for:
            self._colored_for = volts
            level = np.clip(np.asarray(volts, dtype=float) / self.v_max, 0.0, 1.0)
            colors = np.empty((len(self._samplers), 4))
            colors[:, 0] = 0.2 + 0.8 * level
            colors[:, 1] = 0.3
            colors[:, 2] = 1.0 - 0.8 * level
            colors[:, 3] = 0.6
            self._f32[self._f32_index] = colors.reshape(-1)


class NodeMarkers:
    """
    The node's marker publisher: a frame every ``every`` control samples (see module doc).

    The log records every frame of the display grid (sim time). Viewers get at most one frame
    per half display period of *wall* time: in real time that is every frame (a catch-up burst
    aside), while a free run would otherwise send frames many times faster than any display shows
    them, at a cost to the node's DDS threads and the viewer (docs/performance.md, 'Markers';
    ``bench/marker_cost.py``). A frame held
    back from viewers is sent at the next chance if nothing newer comes.
    """

    def __init__(self, node, model, display_hz: float, frame_id: str, qos,
                 clock=time.monotonic):
        from visualization_msgs.msg import MarkerArray
        self.every = max(1, int(round(model.scene.rate_hz / display_hz)))
        namespace = node.get_namespace().strip('/')
        self.frames = MarkerFrames(model, frame_prefix=f'{namespace}/' if namespace else '',
                                   frame_id=frame_id)
        self.publisher = node.create_publisher(MarkerArray, MARKER_TOPIC, qos)
        self._publish = self.publisher.publish   # (publish(bytes): the frame serialized)
        self._viewers = self.publisher.get_subscription_count
        self._clock = clock
        self._min_gap_s = 0.5 / display_hz     # wall s between two frames sent to viewers
        self._shown_at = -math.inf
        self._pending = None    # the newest frame held back from viewers
        self.published = 0
        self.held_back = 0      # frames logged but not sent (the wall-clock cap)

    def on_sample(self, k: int, x, u, stamp_ns: int, recorder=None) -> None:
        """Publish (and record) a frame if sample k is on the display grid."""
        data = self.frame_for(k, x, u, stamp_ns, recorder)
        if data is not None:
            self.publish(data)

    def frame_for(self, k: int, x, u, stamp_ns: int, recorder=None) -> bytes | None:
        """
        Return the frame of sample k if it is on the display grid and shows a change.

        The frame is recorded; a change as :meth:`MarkerFrames.frame_if_moved` sees it; else None.
        The caller publishes it (:meth:`publish`), e.g. with the other messages of a burst.
        """
        if k % self.every:
            return None
        now = self._clock()
        show = now - self._shown_at >= self._min_gap_s and self._viewers() > 0
        if recorder is None and not show:   # nobody would see it (now): skip the work
            return None
        data = self.frames.frame_if_moved(x, u, stamp_ns)
        if data is not None and recorder is not None:
            recorder.record(MARKER_TOPIC, data, stamp_ns, type_name=MARKER_TYPE)
        if not show:
            if data is not None:
                self._pending = data
                self.held_back += 1
            return None
        if data is None:    # nothing moved since the frame viewers have not seen yet
            data = self._pending
        self._pending = None
        if data is not None:
            self._shown_at = now
        return data

    def add_viewers(self, count) -> None:
        """Count ``count()`` more viewers beside DDS subscriptions (the live view's clients)."""
        subscriptions = self.publisher.get_subscription_count
        self._viewers = lambda: subscriptions() + count()

    def publish(self, data: bytes) -> None:
        self._publish(data)
        self.published += 1


def attach_markers(node, model, display_hz: float, frame_id: str, qos):
    """Return the node's :class:`NodeMarkers`, or None when the display rate is 0 (off)."""
    if not display_hz or display_hz <= 0.0:
        return None
    return NodeMarkers(node, model, display_hz, frame_id, qos)
