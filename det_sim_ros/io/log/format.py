"""
The MCAP bytes this package writes and scans itself.

The magic, the opcodes it reads, the Message record's head (the one Python statement of the
layout ``core/_csrc`` ``pack_records`` writes), the names of the package's own records, and the
provisional end written after every flush.
"""

from __future__ import annotations

import struct

__all__ = ['MAGIC', 'MESSAGE_HEAD', 'MESSAGE_FIELDS', 'MESSAGE_HEAD_LENGTH', 'OP_HEADER',
           'OP_FOOTER', 'OP_SCHEMA', 'OP_CHANNEL', 'OP_MESSAGE', 'OP_CHUNK', 'OP_MESSAGE_INDEX',
           'OP_ATTACHMENT', 'OP_METADATA', 'OP_DATA_END', 'RECORD_HEAD', 'PROVISIONAL_END',
           'FOOTER_HEAD', 'FOOTER_SIZE', 'LIBRARY', 'METADATA_NAME', 'END_METADATA_NAME',
           'SCENE_ATTACHMENT']

LIBRARY = 'det_sim_ros'
METADATA_NAME = 'det_sim_ros'            # the run's metadata record, at the start of a file
END_METADATA_NAME = 'det_sim_ros.end'    # the counters, when a file is closed
SCENE_ATTACHMENT = 'scene.yaml'

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = \
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
OP_ATTACHMENT, OP_METADATA, OP_DATA_END = 0x09, 0x0C, 0x0F
RECORD_HEAD = struct.Struct('<BQ')   # every record: opcode, length of the rest

# A Message record: opcode, length (22 + payload), channel id, sequence, log time, publish time,
# then the payload. MESSAGE_FIELDS: each field's byte offset in the record.
MESSAGE_HEAD = struct.Struct('<BQHIQQ')
MESSAGE_FIELDS = {'opcode': 0, 'length': 1, 'channel': 9, 'sequence': 11, 'log_time': 15,
                  'publish_time': 23, 'payload': MESSAGE_HEAD.size}
MESSAGE_HEAD_LENGTH = MESSAGE_HEAD.size - RECORD_HEAD.size   # the length field's part of it


# DataEnd (opcode 0x0f, crc 0 = not computed) + Footer (0x02: summary_start 0 = no summary,
# summary_offset_start 0, crc 0) + magic: the smallest valid end of an MCAP file
FOOTER_HEAD = bytes((OP_FOOTER,)) + (20).to_bytes(8, 'little')
PROVISIONAL_END = (bytes((OP_DATA_END,)) + (4).to_bytes(8, 'little') + bytes(4) + FOOTER_HEAD
                   + bytes(20) + MAGIC)
FOOTER_SIZE = len(FOOTER_HEAD) + 20 + len(MAGIC)
