"""
The log's MCAP writer (det_sim_ros.io.log.writer) on mcap's public record classes.

It writes the bytes mcap's own ``Writer`` writes, call for call, whatever the compression,
the chunk size, the flushes and the order of registrations and messages; the recorder's
packed path writes the bytes of its one-by-one path; an unknown compression is refused by name.
"""

import io
import random

from det_sim_ros.io.log.compression import compression, COMPRESSIONS
from det_sim_ros.io.log.writer import McapWriter
import pytest


class FlushedBytes(io.BytesIO):
    """A BytesIO that counts flushes (McapWriter's stream: write, tell, flush)."""

    flushes = 0

    def flush(self):
        self.flushes += 1


def _calls(seed: int):
    """Return a fixed random sequence of writer calls: registrations, messages, flushes."""
    rng = random.Random(seed)
    calls = [('add_metadata', ('det_sim_ros', {'version': '1', 'scene_yaml': 'a: 1\n'})),
             ('add_attachment', (5, 6, 'scene.yaml', 'application/yaml', b'a: 1\n'))]
    schemas = channels = 0
    t = 0
    for step in range(1500):
        if schemas == 0 or rng.random() < 0.003:
            schemas += 1
            calls.append(('register_schema', (f'pkg/msg/T{schemas}', 'ros2msg',
                                              b'float64 x\n' * schemas)))
        if channels == 0 or rng.random() < 0.01:
            channels += 1
            calls.append(('register_channel', (f'/topic{channels}', 'cdr',
                                               rng.randint(1, schemas),
                                               {'offered_qos_profiles': f'- depth: {channels}'})))
        t += rng.choice((0, 1000, 1000, 2500)) - (700 if rng.random() < 0.05 else 0)
        size = rng.choice((8, 40, 40, 300))
        calls.append(('add_message', (rng.randint(1, channels), max(t, 0),
                                      rng.randbytes(size), max(t, 0) + 3, step)))
        if rng.random() < 0.004:
            calls.append(('flush', ()))
    calls.append(('add_metadata', ('det_sim_ros.end', {'messages': '1500'})))
    return calls


def _write(writer, stream, calls) -> bytes:
    writer.start(profile='ros2', library='det_sim_ros test')
    for name, args in calls:
        getattr(writer, name)(*args)
    writer.finish()
    return stream.getvalue()


@pytest.mark.parametrize('name', sorted(COMPRESSIONS))
@pytest.mark.parametrize('chunk_size', [1, 2048, 1024 * 1024])
def test_the_writer_writes_the_bytes_of_mcaps_writer(name, chunk_size):
    """The same calls give the same file as mcap.writer.Writer with its defaults."""
    from mcap.writer import CompressionType, Writer
    calls = _calls(seed=chunk_size)
    kind = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
            'none': CompressionType.NONE}[name]   # (mcap's names, for the reference only)
    theirs = FlushedBytes()
    expected = _write(Writer(theirs, chunk_size=chunk_size, compression=kind), theirs, calls)
    ours = FlushedBytes()
    written = _write(McapWriter(ours, chunk_size=chunk_size, compression=compression(name)),
                     ours, calls)
    assert written == expected
    assert ours.flushes == theirs.flushes > 0


def test_the_writer_keeps_its_open_chunk_and_statistics_in_the_open():
    """The packer's seams: the open chunk's records, its index, the file's statistics."""
    stream = FlushedBytes()
    writer = McapWriter(stream, chunk_size=10_000, compression=compression('none'))
    writer.start('ros2', 'test')
    channel = writer.register_channel('/x', 'cdr', 0, {})
    writer.add_message(channel, 7, b'abc', 7, 0)
    writer.add_message(channel, 5, b'de', 5, 1)
    chunk = writer.chunk
    assert chunk.num_messages == 2 and (chunk.message_start_time, chunk.message_end_time) == (5, 7)
    assert [t for t, _ in chunk.message_indices[channel].records] == [7, 5]
    assert writer.statistics.message_count == 2
    assert dict(writer.statistics.channel_message_counts) == {channel: 2}
    writer.flush()
    assert writer.chunk.num_messages == 0 and not writer.chunk.records
    assert writer.statistics.chunk_count == 1


def test_without_the_packer_the_recorder_writes_the_same_file(tmp_path, monkeypatch):
    """
    Check that the recorder's one-by-one path writes the packed path's file.

    ``packing=False`` writes each message through McapWriter.add_message (mcap's Message
    record class): the same bytes as the packer's, over several chunks.
    """
    import time as time_module
    from det_sim_ros.io.contract import encode_joint_state, TOPIC_TYPES
    from det_sim_ros.io.log import Recorder
    monkeypatch.setattr(time_module, 'time_ns', lambda: 1234)   # the wall start in the metadata

    def write(path, packing):
        with Recorder(path, None, chunk_size=4096, flush_period_s=1e9,
                      packing=packing) as recorder:
            for k in range(300):
                data = [encode_joint_state(['det0'], [float(k)], stamp_ns=k)] * 2
                recorder.record_sample(k * 1000, ['deflection', 'charge'], data, TOPIC_TYPES)
            assert recorder.packing == packing
        return open(path, 'rb').read()
    assert write(tmp_path / 'plain.mcap', False) == write(tmp_path / 'packed.mcap', True)


def test_an_unknown_compression_stops_recording_with_the_choices(tmp_path):
    """A compression name not in the map: the recorder's fault lists the known ones, no file."""
    from det_sim_ros.io.log import Recorder
    recorder = Recorder(tmp_path / 'x.mcap', None, compression='gzip')
    assert not recorder.active
    assert "unknown compression 'gzip' (one of zstd, lz4, none)" in recorder.fault
    assert not (tmp_path / 'x.mcap').exists()
    recorder.close()
