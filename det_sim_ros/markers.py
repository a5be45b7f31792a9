"""
The actuator's shape as ``visualization_msgs/MarkerArray`` (RViz, Foxglove 3D panel).

:class:`MarkerFrames` turns a model state into the serialized CDR bytes of one MarkerArray
(no rclpy needed): per DET, namespace = the DET name, ids 0/1 the beams' centre lines
(LINE_STRIP), 2 the DET (CUBE, blue at 0 V to red at v_max), 3 the reference point on beam A
(SPHERE: its x is the published deflection q); for plate scenes namespace 'plate', id 0 (CUBE).
Geometry: :mod:`det_sim_ros.geometry`.

Frames: by default one frame per DET, ``<namespace>/<DET name>`` (``det0``, ``arm1/left``),
each cell at its frame's origin; the plate is drawn in the first DET's frame (the others are
placed relative to it by the user's transforms: see README). With ``frame_id`` set, all DETs
are drawn in that one frame, side by side (:func:`det_sim_ros.geometry.layout_offsets`).

Speed: the message layout is fixed for a model, so it is serialized once with sentinel values
in the fields that move, their byte offsets are located, and each frame only writes the new
numbers into a copy of those bytes (tens of microseconds per frame; building rclpy Point
objects cost about 20x more).

:class:`NodeMarkers` is the node's side: the publisher on ``markers`` and the display-rate
throttle (every N-th control sample, N = rate_hz / display rate, so the cost per simulated
second is bounded and the frames are stamped on the sample grid). A frame that would show
nothing new (no coordinate moved by more than 0.1 µm, the same voltages) is not sent, except
once per simulated second: markers persist in RViz and Foxglove until replaced, so a settled
actuator costs about one frame per simulated second.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from .geometry import ActuatorGeometry

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


def _sentinel(k: int) -> float:
    """A float64 that cannot occur in a real frame (a subnormal-range tag)."""
    return (k + 1) * 1.0e-300


class MarkerFrames:
    """
    Serialized MarkerArray frames of one model (see the module docstring).

    :param frame_prefix: prepended to the DET names to form the per-DET frame ids (e.g.
        'arm1/'); ignored when ``frame_id`` is given.
    :param frame_id: one frame for everything (cells laid out side by side), or '' for one
        frame per DET.
    """

    def __init__(self, model, frame_prefix: str = '', frame_id: str = '', n_points: int = 41):
        from visualization_msgs.msg import Marker, MarkerArray
        from .mcap_log import serialize
        self.geometry = geo = ActuatorGeometry(model, n_points)
        self.v_max = model.scene.physics.v_max
        names = geo.names
        common = bool(frame_id)
        self.frames = [frame_id if common else f'{frame_prefix}{name}' for name in names]
        offsets = geo.offsets if common else np.zeros_like(geo.offsets)
        self._offsets = offsets
        tags = iter(range(10 ** 6))
        slots = []   # (kind, marker index, field tag or tags)
        markers = []

        def marker(ns, mid, kind, frame, color, scale):
            m = Marker(ns=ns, id=mid, type=kind, action=Marker.ADD)
            m.header.frame_id = frame
            m.pose.orientation.w = 1.0
            m.scale.x, m.scale.y, m.scale.z = scale
            m.color.r, m.color.g, m.color.b, m.color.a = color
            m.frame_locked = True
            markers.append(m)
            return m

        def tag_point(p):
            t = next(tags)
            p.x, p.y, p.z = _sentinel(t), 0.0, 0.0
            return t

        self._cell_slots = []
        n = geo.n_points
        for i, name in enumerate(names):
            frame = self.frames[i]
            slot = {}
            for mid in (0, 1):
                m = marker(name, mid, Marker.LINE_STRIP, frame, BEAM_COLOR,
                           (BEAM_LINE_WIDTH, 0.0, 0.0))
                m.pose.position.x, m.pose.position.y, m.pose.position.z = offsets[i]
                from geometry_msgs.msg import Point
                m.points = [Point() for _ in range(n)]
                slot[f'beam{mid}'] = tag_point(m.points[0])
            det = marker(name, 2, Marker.CUBE, frame, (0.2, 0.3, 1.0, 0.6), (0.0, 0.0, 0.0))
            slot['det_pose'] = tag_point(det.pose.position)
            t = next(tags)
            det.scale.x = _sentinel(t)
            slot['det_scale'] = t
            slot['det_color'] = len(markers) - 1
            ref = marker(name, 3, Marker.SPHERE, frame, REFERENCE_COLOR, (REFERENCE_DIAMETER,) * 3)
            slot['ref_pose'] = tag_point(ref.pose.position)
            self._cell_slots.append(slot)
        self._plate_slot = None
        if geo.has_plate:
            width = model.scene.structure['plate_width']
            depth = max(ph.A0 / ph.l0 for ph in model.scene.cell_physics())
            plate = marker('plate', 0, Marker.CUBE, self.frames[0], PLATE_COLOR,
                           (depth, width + depth, PLATE_THICKNESS))
            self._plate_slot = tag_point(plate.pose.position)
            self._plate_shift = -geo.offsets[0] if not common else np.zeros(3)
        # colour of each DET: four float32 right after scale; locate with a float32 sentinel
        color_tags = {}
        for i, slot in enumerate(self._cell_slots):
            m = markers[slot['det_color']]
            value = float(np.float32(1.0e-30 * (i + 1)))
            m.color.r = value
            color_tags[i] = value
        stamp_tag = 0x5A5A0000
        for k, m in enumerate(markers):
            m.header.stamp.sec = stamp_tag + k
        self.n_markers = len(markers)
        raw = serialize(MarkerArray(markers=markers))

        def find(packed):
            at = raw.find(packed)
            if at < 0 or raw.find(packed, at + 1) >= 0:
                raise RuntimeError('marker layout: a sentinel is missing or not unique')
            return at

        def f64(t):
            return find(struct.pack('<d', _sentinel(t)))

        for slot in self._cell_slots:
            for key in ('beam0', 'beam1', 'det_pose', 'det_scale', 'ref_pose'):
                slot[key] = f64(slot[key])
        for i, slot in enumerate(self._cell_slots):
            slot['det_color'] = find(struct.pack('<f', color_tags[i]))
        if self._plate_slot is not None:
            self._plate_slot = f64(self._plate_slot)
        self._stamps = np.array([find(struct.pack('<i', stamp_tag + k))
                                 for k in range(len(markers))])
        # every moving field is rewritten in every frame, so one buffer is reused; CDR aligns
        # relative to the 4-byte encapsulation header, so the views start at byte 4
        self._buffer = np.frombuffer(bytearray(raw), dtype=np.uint8)
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
        self._stamp_index = np.concatenate([index(o, 2, size=4) for o in self._stamps])
        self._stamp_values = np.zeros(2 * self.n_markers, dtype=np.uint32)
        self._samplers = list(zip(geo.slices, geo.samplers, self._offsets))
        self._cell_maps = [self._cell_map(sampler, off) for sampler, off in
                           zip(geo.samplers, self._offsets)]
        self._colored_for = None
        self._last_sent = None    # (values, volts, stamp) of frame_if_moved's last frame
        self.skipped = 0

    @staticmethod
    def _cell_map(sampler, off):
        """
        A cell's frame values as V = V0 + Kq q + Ke e(w'): the deflections are linear in the
        Ritz coordinates q and the heights linear in the shortening density e at the Gauss
        nodes, so a frame costs a few matrix products (the frame is per control sample in the
        node's thread: fewer numpy calls is what makes it cheap). Order: beam A x (n), z (n),
        beam B x, z, DET centre (3), DET size (3), reference point (3).
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
            # one coordinate: e is a polynomial in q, so V = V0 + q (K1 + q (K2 + q^2 K4))
            b1 = sampler.B1[:, 0]
            K2 = Ke @ (b1 * b1)
            K4 = (0.125 * Ke @ b1 ** 4) if sampler.kinematics == 'consistent' else 0.0 * K2
            if sampler.kinematics == 'consistent':
                K2 = 0.5 * K2
            poly = (Kq[:, 0].copy(), K2, K4)
        return V0, Kq, Ke, sampler.B1, sampler.kinematics, k + 5, k + 3, poly

    def frame(self, x, u, stamp_ns: int) -> bytes:
        """CDR bytes of the MarkerArray at state x, voltages u, stamped ``stamp_ns`` (sim time)."""
        return self.pack(self.values(x), u, stamp_ns)

    def frame_if_moved(self, x, u, stamp_ns: int) -> bytes | None:
        """The frame, or None when it would show what the last frame returned here showed: no
        drawn coordinate moved by more than :data:`MOVE_TOLERANCE`, the voltages are the
        same, and less than :data:`KEEPALIVE_S` of sim time has passed (markers persist in
        RViz and Foxglove until replaced, so a settled actuator needs no new frames; the
        keep-alive serves viewers that join later)."""
        values = self.values(x)
        volts = list(u) if np.ndim(u) else [u]
        last = self._last_sent
        if (last is not None and volts == last[1] and stamp_ns - last[2] < KEEPALIVE_NS
                and float(np.max(np.abs(values - last[0]))) <= MOVE_TOLERANCE):
            self.skipped += 1
            return None
        self._last_sent = (values.copy(), volts, stamp_ns)
        return self.pack(values, u, stamp_ns)

    def values(self, x) -> np.ndarray:
        """Every drawn coordinate that moves (m; the plate's orientation as a quaternion), in
        the order of the frame's fields."""
        parts, heights = [], []
        for (s, sampler, _), (V0, Kq, Ke, B1, kinematics, i_h, i_thick, poly) in zip(
                self._samplers, self._cell_maps):
            if poly is not None:
                q = float(x[s.start])
                K1, K2, K4 = poly
                values = V0 + q * (K1 + q * (K2 + (q * q) * K4))
            else:
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
            w = self.geometry.scene.structure['plate_width']
            tilt = math.atan2(heights[-1] - heights[0], w)   # > 0: the right side is higher
            centre = self._plate_shift + (0.0, 0.0, sum(heights) / len(heights)
                                          + 0.5 * PLATE_THICKNESS)
            half = 0.5 * tilt              # rotation about x: quaternion (sin, 0, 0, cos)
            parts.append((*centre, math.sin(half), 0.0, 0.0, math.cos(half)))
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def pack(self, values, u, stamp_ns: int) -> bytes:
        """The frame's bytes from :meth:`values`, the voltages and the stamp."""
        self._f64[self._f64_index] = values
        volts = list(u) if np.ndim(u) else [u] * len(self._samplers)
        if volts != self._colored_for:            # the DET colour changes with its voltage
            self._colored_for = volts
            level = np.clip(np.asarray(volts, dtype=float) / self.v_max, 0.0, 1.0)
            colors = np.empty((len(self._samplers), 4))
            colors[:, 0] = 0.2 + 0.8 * level
            colors[:, 1] = 0.3
            colors[:, 2] = 1.0 - 0.8 * level
            colors[:, 3] = 0.6
            self._f32[self._f32_index] = colors.reshape(-1)
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        stamps = self._stamp_values
        stamps[0::2], stamps[1::2] = sec, nanosec
        self._u32[self._stamp_index] = stamps
        return self._buffer.tobytes()


class NodeMarkers:
    """The node's marker publisher: a frame every ``every`` control samples (see module doc)."""

    def __init__(self, node, model, display_hz: float, frame_id: str, qos):
        from visualization_msgs.msg import MarkerArray
        self.every = max(1, int(round(model.scene.rate_hz / display_hz)))
        namespace = node.get_namespace().strip('/')
        self.frames = MarkerFrames(model, frame_prefix=f'{namespace}/' if namespace else '',
                                   frame_id=frame_id)
        self.publisher = node.create_publisher(MarkerArray, MARKER_TOPIC, qos)
        self._publish_raw = self.publisher.handle.publish_raw
        self.published = 0

    def on_sample(self, k: int, x, u, stamp_ns: int, recorder=None) -> None:
        """Publish (and record) a frame if sample k is on the display grid."""
        data = self.frame_for(k, x, u, stamp_ns, recorder)
        if data is not None:
            self.publish(data)

    def frame_for(self, k: int, x, u, stamp_ns: int, recorder=None) -> bytes | None:
        """The frame of sample k (recorded) if it is on the display grid and shows a change
        (:meth:`MarkerFrames.frame_if_moved`), else None; the caller publishes it
        (:meth:`publish`), e.g. with the other messages of a burst."""
        if k % self.every:
            return None
        data = self.frames.frame_if_moved(x, u, stamp_ns)
        if data is None:
            return None
        if recorder is not None:
            recorder.record(MARKER_TOPIC, data, stamp_ns, type_name=MARKER_TYPE)
        return data

    def publish(self, data: bytes) -> None:
        self._publish_raw(data)   # (Publisher.publish's type check and guard skipped)
        self.published += 1


def attach_markers(node, model, display_hz: float, frame_id: str, qos):
    """The node's :class:`NodeMarkers`, or None when the display rate is 0 (off)."""
    if not display_hz or display_hz <= 0.0:
        return None
    return NodeMarkers(node, model, display_hz, frame_id, qos)
