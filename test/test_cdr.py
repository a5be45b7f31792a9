"""
The one CDR codec (det_sim_ros.io.cdr) against rclpy's serializer and rosbags.

Its generic message writer and reader agree with rclpy's serializer and with rosbags, for
every field kind the ROS messages of a log use.
"""

import struct

from det_sim_ros.io import cdr
import pytest


def _messages():
    from builtin_interfaces.msg import Duration
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Point
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import CameraInfo, CompressedImage, JointState
    from std_msgs.msg import ByteMultiArray, Empty, Float64MultiArray, UInt8MultiArray
    from visualization_msgs.msg import Marker, MarkerArray
    joint = JointState(name=['det0', 'det1'], position=[1.0, -2.5], velocity=[3.0])
    joint.header.stamp.sec, joint.header.frame_id = 7, 'beam'
    status = DiagnosticStatus(level=b'\x02', name='log', message='disk full',
                              values=[KeyValue(key='path', value='/x')])
    camera = CameraInfo(height=3, width=4, d=[0.1, 0.2], distortion_model='plumb_bob')
    camera.k[0], camera.p[11] = 5.0, -1.0
    marker = Marker(ns='det0', id=3, type=Marker.LINE_STRIP, frame_locked=True,
                    points=[Point(x=1.0, y=2.0, z=3.0), Point()],
                    lifetime=Duration(sec=1, nanosec=2), text='ü')
    marker.color.r = 0.25
    marker.texture = CompressedImage(format='png', data=[1, 2, 255])
    return [joint, JointState(), Float64MultiArray(data=[0.5, 1e300]), Clock(), Empty(),
            DiagnosticArray(status=[status, DiagnosticStatus()]), camera,
            MarkerArray(markers=[marker, Marker()]), UInt8MultiArray(data=[0, 7, 255]),
            ByteMultiArray(data=[b'\x01', b'\xff'])]


@pytest.mark.parametrize('index', range(10))
def test_generic_codec_matches_rclpy_and_rosbags(index):
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import get_typestore, Stores
    from det_sim_ros.io.schemas import type_name_of
    msg = _messages()[index]
    data = cdr.serialize(msg)
    assert deserialize_message(data, type(msg)) == msg          # rclpy reads our bytes
    get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(data, type_name_of(msg))   # strict
    assert cdr.deserialize(type(msg), data) == msg               # our reader, our bytes
    assert cdr.deserialize(type(msg), serialize_message(msg)) == msg   # and rclpy's bytes
    assert cdr.deserialize(type_name_of(msg), data) == msg       # by type name
    assert cdr.serialize(msg) == data                            # zero padding: stable


def test_generic_reader_sees_a_changed_field():
    """The comparisons above can fail: a flipped byte in a value decodes to another message."""
    from sensor_msgs.msg import JointState
    msg = JointState(name=['a'], position=[1.0])
    data = bytearray(cdr.serialize(msg))
    data[data.find(struct.pack('<d', 1.0)) + 7] ^= 0x40      # position[0]'s last byte
    assert cdr.deserialize(JointState, bytes(data)) != msg


def test_writer_layout_rules():
    """
    Check the writer's layout rules: alignment, strings, sequences, zero padding.

    Alignment is counted from the end of the header, strings carry their NUL, sequences are
    counted, fixed arrays not.
    """
    w = cdr.Writer()
    w.primitive(struct.Struct('<B'), 1)
    w.doubles([2.0])
    w.string('ab')
    w.numbers('h', [3, 4], counted=False)
    assert w.to_bytes() == (cdr.HEADER_LE + b'\x01' + bytes(3) + struct.pack('<I', 1)
                            + struct.pack('<d', 2.0) + struct.pack('<I', 3) + b'ab\0'
                            + b'\0' + struct.pack('<2h', 3, 4))
    r = cdr.Reader(w.to_bytes())
    assert (r.primitive('B'), r.doubles(), r.string(), r.numbers('h', 2)) == (1, [2.0], 'ab',
                                                                              (3, 4))


def test_reader_refuses_malformed_bytes():
    from sensor_msgs.msg import JointState
    good = cdr.serialize(JointState(name=['a']))
    for bad in (b'', b'\x01\x01\x00\x00', good[:-3], good[:8] + struct.pack('<I', 10**6)):
        with pytest.raises(cdr.CdrError):
            cdr.deserialize(JointState, bad)


def test_wide_strings_are_refused_with_a_clear_error():
    from rosidl_parser import definition

    class WideText:   # a message class as rosidl generates them, with a wstring field
        SLOT_TYPES = (definition.UnboundedWString(),)
        text = 'x'

        @staticmethod
        def get_fields_and_field_types():
            return {'text': 'wstring'}
    with pytest.raises(TypeError, match='UnboundedWString is not supported'):
        cdr.serialize(WideText())
