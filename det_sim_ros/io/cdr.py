"""
CDR (XCDR1, the encoding ROS 2 and rosbag2 use): the package's one writer and one reader.

Also the generic message codec built on them from a rosidl message class's ``SLOT_TYPES``
(rosidl's generated classes only: no rclpy).

Layout rules: a 4-byte encapsulation header (0x00 0x01 = little endian, 0x00 0x00 = big endian,
then two option bytes), then the fields; a primitive of size s is aligned to a multiple of s
counted from the end of the header; a string is a uint32 length (with the NUL) and its bytes;
a sequence is a uint32 count and its items; a fixed array is its items; an empty message is one
uint8. Padding is written as zeros, so equal messages give equal bytes (rclpy's own serializer
leaves padding and trailing bytes uninitialised, which strict readers such as rosbags refuse).

The compiled encoders (``core/_csrc/wire/wire.c``) are the fast paths of :class:`Writer`'s layouts;
this module is the reference the tests hold them to.
"""

from __future__ import annotations

import importlib
import struct
import sys
from typing import Callable, Sequence

import numpy as np

__all__ = ['CdrError', 'HEADER_LE', 'NS', 'Writer', 'Reader', 'serialize', 'deserialize',
           'message_class', 'split_type']

HEADER_LE = b'\x00\x01\x00\x00'
NS = 1_000_000_000
_LITTLE = sys.byteorder == 'little'
_ZEROS = bytes(8)
_U32 = struct.Struct('<I')


class CdrError(ValueError):
    """Bytes that are not a valid CDR message of the expected type."""


class Writer:
    """Little-endian CDR into :attr:`buf` (the encapsulation header first)."""

    def __init__(self):
        self.buf = bytearray(HEADER_LE)

    def align(self, size: int) -> None:
        """Zero padding up to a multiple of ``size`` counted from the end of the header."""
        pad = -(len(self.buf) - 4) % size
        if pad:
            self.buf += _ZEROS[:pad]

    def u32(self, value: int) -> None:
        """Write a uint32."""
        self.align(4)
        self.buf += _U32.pack(value)

    def i32(self, value: int) -> None:
        """Write an int32."""
        self.align(4)
        self.buf += struct.pack('<i', value)

    def primitive(self, packer: struct.Struct, value) -> None:
        """Write one value packed by ``packer`` (aligned to its size)."""
        self.align(packer.size)
        self.buf += packer.pack(value)

    def string(self, text: str) -> None:
        """Write a UTF-8 string, its length counting the NUL."""
        data = text.encode()
        self.u32(len(data) + 1)
        self.buf += data
        self.buf += b'\0'

    def strings(self, texts: Sequence[str]) -> None:
        """Write a string sequence."""
        self.u32(len(texts))
        for text in texts:
            self.string(text)

    def numbers(self, code: str, values, counted: bool = True) -> int:
        """
        Write a sequence or fixed array of one primitive type; return its first value's offset.

        A sequence if ``counted``, else a fixed array, of struct ``code`` values; the offset is
        for in-place updates.
        """
        n = len(values)
        if counted:
            self.u32(n)
        if n:
            self.align(struct.calcsize(code))
        offset = len(self.buf)
        if not n:
            return offset
        if isinstance(values, (bytes, bytearray)):
            self.buf += values
        elif _LITTLE and getattr(values, 'typecode', None) == code:
            self.buf += values.tobytes()   # array.array, as rosidl stores sequences
        elif isinstance(values, np.ndarray):
            self.buf += np.ascontiguousarray(values, dtype='<' + code).tobytes()
        elif code == 'B' and isinstance(values[0], (bytes, str)):
            self.buf += b''.join(v if isinstance(v, bytes) else v.encode() for v in values)
        else:
            self.buf += struct.pack(f'<{n}{code}', *values)
        return offset

    def doubles(self, values) -> int:
        """Write a float64 sequence; return the offset of its first value."""
        return self.numbers('d', np.asarray(values, dtype='<f8').reshape(-1))

    def stamp(self, t_ns: int) -> None:
        """Write a builtin_interfaces/Time (int32 sec, uint32 nanosec) of ``t_ns``."""
        sec, nanosec = divmod(int(t_ns), NS)
        self.i32(sec)
        self.u32(nanosec)

    def to_bytes(self) -> bytes:
        """Return the message's bytes."""
        return bytes(self.buf)


class Reader:
    """
    CDR of either byte order (from the encapsulation header), checked against its length.

    :raises CdrError: an unknown header, a value past the end, a bad string.
    """

    def __init__(self, data):
        data = bytes(data)
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
            raise CdrError('not CDR: unknown encapsulation header '
                           f'{data[:4].hex() if data else "(empty)"}')
        self.data = data
        self.order = '<' if data[1] == 1 else '>'
        self.little = data[1] == 1
        self.pos = 4

    def take(self, size: int, align: int) -> int:
        """Skip the padding to ``align`` and ``size`` bytes; their offset."""
        self.pos += -(self.pos - 4) % align
        start = self.pos
        self.pos += size
        if self.pos > len(self.data):
            raise CdrError(f'truncated CDR message ({len(self.data)} bytes)')
        return start

    def primitive(self, code: str):
        """Read one primitive value of struct ``code``."""
        size = struct.calcsize(code)
        return struct.unpack_from(self.order + code, self.data, self.take(size, size))[0]

    def u32(self) -> int:
        """Read a uint32."""
        return struct.unpack_from(self.order + 'I', self.data, self.take(4, 4))[0]

    def i32(self) -> int:
        """Read an int32."""
        return struct.unpack_from(self.order + 'i', self.data, self.take(4, 4))[0]

    def count(self, item_size: int) -> int:
        """
        Read a sequence's count, checked to fit in what is left.

        Its items are of ``item_size`` bytes at least.
        """
        n = self.u32()
        if n * max(item_size, 1) > len(self.data) - self.pos:
            raise CdrError(f'sequence of {n} items does not fit in {len(self.data)} bytes')
        return n

    def string(self) -> str:
        """Read a string."""
        n = self.count(1)
        start = self.take(n, 1)
        raw = self.data[start:start + n]
        if n == 0 or raw[-1] != 0:
            raise CdrError('string without its terminating NUL')
        try:
            return raw[:-1].decode()
        except UnicodeDecodeError as exc:
            raise CdrError(f'string is not UTF-8: {exc}') from None

    def strings(self) -> list[str]:
        """Read a string sequence."""
        return [self.string() for _ in range(self.count(5))]

    def numbers_at(self, code: str, n: int | None = None) -> tuple[int, int]:
        """
        Skip a sequence or fixed array of primitives; return its (offset, count).

        A sequence if ``n`` is None (counted), else a fixed array of ``n`` primitives of struct
        ``code``.
        """
        size = struct.calcsize(code)
        if n is None:
            n = self.count(size)
        if not n:
            return self.pos, 0
        return self.take(size * n, size), n

    def numbers(self, code: str, n: int | None = None) -> tuple:
        """Read the values of a sequence (``n`` None) or fixed array of primitives."""
        start, n = self.numbers_at(code, n)
        return struct.unpack_from(f'{self.order}{n}{code}', self.data, start) if n else ()

    def doubles(self) -> list[float]:
        """Read a float64 sequence."""
        return list(self.numbers('d'))

    def doubles_at(self) -> tuple[int, int]:
        """(offset, count) of a float64 sequence, skipped."""
        return self.numbers_at('d')

    def stamp(self) -> int:
        """Read a builtin_interfaces/Time, in ns."""
        sec = self.i32()
        return sec * NS + self.u32()


# -- the generic codec: rosidl message classes ---------------------------------------------------

_CODES = {'boolean': '?', 'octet': 'B', 'char': 'B', 'uint8': 'B', 'int8': 'b', 'int16': 'h',
          'uint16': 'H', 'int32': 'i', 'uint32': 'I', 'int64': 'q', 'uint64': 'Q', 'float': 'f',
          'double': 'd'}
# what rosidl's Python classes hold for a single value of these types
_FROM_BYTE = {'octet': lambda v: bytes((v,)), 'char': chr}


def split_type(name: str) -> tuple[str, str, str]:
    """('pkg', 'msg', 'Type') of 'pkg/msg/Type' or 'pkg/Type'."""
    parts = name.split('/')
    if len(parts) == 2:
        return parts[0], 'msg', parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise ValueError(f'not a ROS type name (pkg/msg/Type): {name!r}')


def message_class(type_name: str):
    """Return the rosidl Python class of ``'pkg/msg/Type'``."""
    package, kind, type_ = split_type(type_name)
    return getattr(importlib.import_module(f'{package}.{kind}'), type_)


def _rosidl():
    from rosidl_parser import definition
    return definition


def _field_writer(slot_type) -> Callable:
    """``write(writer, value)`` for one rosidl field type."""
    d = _rosidl()
    if isinstance(slot_type, d.BasicType):
        packer = struct.Struct('<' + _type_code(slot_type))
        pack, size, to_int = packer.pack, packer.size, packer.format.endswith('B')

        def write_basic(w, value):   # (Writer.primitive, inlined: the most frequent field)
            if to_int and isinstance(value, (bytes, str)):
                value = ord(value)
            buf = w.buf
            pad = -(len(buf) - 4) % size
            if pad:
                buf += _ZEROS[:pad]
            buf += pack(value)
        return write_basic
    if isinstance(slot_type, (d.UnboundedString, d.BoundedString)):
        return Writer.string
    if isinstance(slot_type, d.NamespacedType):
        return _message_writer(message_class('/'.join(slot_type.namespaces + [slot_type.name])))
    if isinstance(slot_type, (d.AbstractSequence, d.Array)):
        counted = not isinstance(slot_type, d.Array)
        item = slot_type.value_type
        if isinstance(item, d.BasicType):
            code = _type_code(item)
            return lambda w, values: w.numbers(code, values, counted)
        write_item = _field_writer(item)

        def write_items(w, values):
            if counted:
                w.u32(len(values))
            for value in values:
                write_item(w, value)
        return write_items
    raise TypeError(f'CDR: field type {type(slot_type).__name__} is not supported')


def _type_code(basic) -> str:
    code = _CODES.get(basic.typename)
    if code is None:
        raise TypeError(f'CDR: field type {basic.typename} is not supported')
    return code


_WRITERS: dict[type, Callable] = {}
_READERS: dict[type, Callable] = {}


def _message_writer(cls) -> Callable:
    writer = _WRITERS.get(cls)
    if writer is None:
        names = list(cls.get_fields_and_field_types())
        parts = [(name, _field_writer(slot)) for name, slot in zip(names, cls.SLOT_TYPES)]

        def writer(w, msg):
            if not parts:   # an empty message holds one uint8
                w.buf += b'\0'
            for name, write in parts:
                write(w, getattr(msg, name))
        _WRITERS[cls] = writer
    return writer


def serialize(msg) -> bytes:
    """
    Return the CDR bytes of a rosidl message, as rosbag2 stores them.

    The encapsulation header is included.

    :raises TypeError: a field type CDR here does not cover (wide strings).
    """
    w = Writer()
    _message_writer(type(msg))(w, msg)
    return w.to_bytes()


def _field_reader(slot_type) -> Callable:
    """``read(reader)`` -> the value rosidl's Python class holds for one field type."""
    d = _rosidl()
    if isinstance(slot_type, d.BasicType):
        code = _type_code(slot_type)
        convert = _FROM_BYTE.get(slot_type.typename)
        if convert is None:
            return lambda r: r.primitive(code)
        return lambda r: convert(r.primitive(code))
    if isinstance(slot_type, (d.UnboundedString, d.BoundedString)):
        return Reader.string
    if isinstance(slot_type, d.NamespacedType):
        return _message_reader(message_class('/'.join(slot_type.namespaces + [slot_type.name])))
    if isinstance(slot_type, (d.AbstractSequence, d.Array)):
        size = slot_type.size if isinstance(slot_type, d.Array) else None
        item = slot_type.value_type
        if isinstance(item, d.BasicType):
            code = _type_code(item)
            convert = _FROM_BYTE.get(item.typename) or (bool if code == '?' else None)
            if convert is not None:
                return lambda r: [convert(v) for v in r.numbers(code, size)]
            return lambda r: list(r.numbers(code, size))
        read_item = _field_reader(item)
        return lambda r: [read_item(r) for _ in range(r.count(1) if size is None else size)]
    raise TypeError(f'CDR: field type {type(slot_type).__name__} is not supported')


def _message_reader(cls) -> Callable:
    reader = _READERS.get(cls)
    if reader is None:
        names = list(cls.get_fields_and_field_types())
        parts = [(name, _field_reader(slot)) for name, slot in zip(names, cls.SLOT_TYPES)]

        def reader(r):
            if not parts:
                r.take(1, 1)
            return cls(**{name: read(r) for name, read in parts})
        _READERS[cls] = reader
    return reader


def deserialize(cls, data):
    """
    Return the rosidl message of class ``cls`` decoded from CDR ``data``.

    ``cls`` may also be its type name, 'pkg/msg/Type'. Either byte order is read; trailing
    bytes, as rclpy's serializer leaves them, are ignored.

    :raises CdrError: malformed bytes.
    """
    if isinstance(cls, str):
        cls = message_class(cls)
    return _message_reader(cls)(Reader(data))
