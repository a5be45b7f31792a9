"""
The log's MCAP writer and reader against mcap's own, side by side.

The numbers io/log/writer.py and io/log/reader.py cite at their tops (docs/logging.md).

Writing: one run of the default node's output samples (its topics' CDR bytes, flushed every 50
samples as at the default flush_sim_s and a 1 ms period, zstd, 1 MiB chunks) written by
``mcap.writer.Writer``, by this package's McapWriter message by message (with mcap's own
MessageIndex.write, and with the one-pack one), by its record packer sample by sample (the
recorder's path) and in runs of 50 (the writer thread's path). Every variant must write the
same bytes (checked); the time is CPU per sample, best of three.

Reading: the finished file read message by message by mcap's readers (``make_reader``: the
seeking one, which uses the summary; ``NonSeekingReader``: a scan) and by LogReader, and as
columns (LogReader.blocks, which mcap has no counterpart of); then the file cut inside a chunk
(a torn file): what each reader returns.

Run: python bench/mcap_library.py [samples]   (under the shared lock: flock ... python ...);
``--quick``: 500 samples (a smoke run).
"""

from __future__ import annotations

import io
import os
import sys
import tempfile
import time

from det_sim_ros.io.contract import OutputContract, TOPIC_TYPES
from det_sim_ros.io.log import writer as writer_module
from det_sim_ros.io.log.compression import compression
from det_sim_ros.io.log.packing import RecordPacker
from det_sim_ros.io.log.reader import LogReader
from det_sim_ros.io.log.writer import McapWriter
from det_sim_ros.io.schemas import message_definition
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
from mcap.reader import make_reader, NonSeekingReader
from mcap.records import MessageIndex as McapMessageIndex
from mcap.writer import CompressionType, Writer
import numpy as np

FLUSH_EVERY = 50


class Flushed(io.BytesIO):
    """A BytesIO with the flush both writers call."""

    def flush(self):
        """Nothing to write out."""


def _samples(n: int) -> tuple[list, list]:
    sim = Simulator(load_scene('default'))
    encoder = OutputContract(sim.model).encoder()
    out = np.asarray(sim.step(), dtype=np.float64)
    return encoder.topics, [encoder.encode(out + 1e-9 * k, k * 1_000_000) for k in range(n)]


def _start(writer, topics) -> list[int]:
    writer.start(profile='ros2', library='det_sim_ros bench')
    schema = writer.register_schema(name=TOPIC_TYPES[topics[0]], encoding='ros2msg',
                                    data=message_definition(TOPIC_TYPES[topics[0]]).encode())
    return [writer.register_channel(topic=f'/{topic}', message_encoding='cdr',
                                    schema_id=schema, metadata={}) for topic in topics]


def _one_by_one(writer, topics, samples) -> None:
    channels = _start(writer, topics)
    for k, data in enumerate(samples):
        t = k * 1_000_000
        for channel, payload in zip(channels, data):
            writer.add_message(channel_id=channel, log_time=t, data=payload, publish_time=t,
                               sequence=k)
        if k % FLUSH_EVERY == FLUSH_EVERY - 1:
            writer.flush()
    writer.finish()


def _packed(writer, topics, samples, run: int) -> None:
    channels = tuple(_start(writer, topics))
    packer = RecordPacker(writer)
    sizes = tuple(map(len, samples[0]))
    for k0 in range(0, len(samples), run):
        block = samples[k0:k0 + run]
        if run == 1:
            packer.add_sample(channels, [k0] * len(channels), block[0], k0 * 1_000_000)
        else:
            times = [(k0 + j) * 1_000_000 for j in range(len(block))]
            assert packer.pack_run(channels, [k0] * len(channels), times, block,
                                   sizes) == len(block)
        if (k0 + len(block)) % FLUSH_EVERY == 0:
            writer.flush()
    writer.finish()


def _writer():
    def make(stream):
        return McapWriter(stream, chunk_size=1024 * 1024, compression=compression('zstd'))
    return make


def _time(write, topics, samples) -> tuple[float, bytes]:
    best, data = float('inf'), b''
    for _ in range(3):
        stream = Flushed()
        start = time.process_time()
        write(stream, topics, samples)
        best = min(best, time.process_time() - start)
        data = stream.getvalue()
    return best, data


def writing(topics, samples) -> tuple[dict, bytes]:
    def theirs(stream, topics, samples):
        _one_by_one(Writer(stream, chunk_size=1024 * 1024, compression=CompressionType.ZSTD),
                    topics, samples)

    def ours(stream, topics, samples):
        _one_by_one(_writer()(stream), topics, samples)

    def mcap_index(write):
        def with_mcap_index(stream, topics, samples):
            packed_index = writer_module.MessageIndex
            writer_module.MessageIndex = McapMessageIndex
            try:
                write(stream, topics, samples)
            finally:
                writer_module.MessageIndex = packed_index
        return with_mcap_index

    def per_sample(stream, topics, samples):
        _packed(_writer()(stream), topics, samples, 1)

    def runs(stream, topics, samples):
        _packed(_writer()(stream), topics, samples, FLUSH_EVERY)

    rows, reference = {}, None
    for label, write in (('mcap.writer.Writer, add_message', theirs),
                         ("McapWriter.add_message, mcap's MessageIndex.write", mcap_index(ours)),
                         ('McapWriter.add_message (one-pack MessageIndex)', ours),
                         ("RecordPacker.add_sample, mcap's MessageIndex.write",
                          mcap_index(per_sample)),
                         ('RecordPacker.add_sample (the recorder)', per_sample),
                         ("RecordPacker.pack_run, runs of 50, mcap's MessageIndex.write",
                          mcap_index(runs)),
                         ('RecordPacker.pack_run, runs of 50 (the writer thread)', runs)):
        seconds, data = _time(write, topics, samples)
        reference = data if reference is None else reference
        rows[label] = (seconds / len(samples) * 1e6, data == reference)
    return rows, reference


def _mcap_seeking(path):
    with open(path, 'rb') as stream:
        for _ in make_reader(stream).iter_messages(log_time_order=False):
            yield 1


def _mcap_scan(path):
    with open(path, 'rb') as stream:
        for _ in NonSeekingReader(stream).iter_messages(log_time_order=False):
            yield 1


def _ours(path):
    for _ in LogReader(path).messages():
        yield 1


def _ours_columns(path):
    for block in LogReader(path).blocks():
        yield len(block.columns().log_time)


def _torn(read, path) -> str:
    """Return what a reader gives of a torn file: its messages, then the error it raised."""
    count = 0
    try:
        for n in read(path):
            count += n
    except Exception as exc:  # noqa: BLE001 - what the reader does with a torn file
        return f'{count} messages, then raises {type(exc).__name__}'
    return f'{count} messages'


def reading(data: bytes, n_messages: int) -> dict:
    rows = {}
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, 'run.mcap')
        torn = os.path.join(folder, 'torn.mcap')
        with open(path, 'wb') as stream:
            stream.write(data)
        with open(torn, 'wb') as stream:
            stream.write(data[:len(data) * 2 // 3])
        for label, read in (('mcap make_reader (seeking, summary), file order', _mcap_seeking),
                            ('mcap NonSeekingReader (scan), file order', _mcap_scan),
                            ('LogReader.messages', _ours),
                            ('LogReader.blocks -> columns', _ours_columns)):
            best = float('inf')
            for _ in range(3):
                start = time.process_time()
                count = sum(read(path))
                best = min(best, time.process_time() - start)
            assert count == n_messages, (label, count)
            rows[label] = (best / n_messages * 1e6, _torn(read, torn))
    return rows


def main(n: int = 20000) -> None:
    topics, samples = _samples(n)
    print(f'{n} samples of {len(topics)} topics ({sum(map(len, samples[0]))} payload bytes '
          f'each), zstd, 1 MiB chunks, a flush every {FLUSH_EVERY} samples; CPU, best of 3')
    rows, data = writing(topics, samples)
    print('| writing | us per sample | same bytes as mcap.writer.Writer |')
    print('| --- | --- | --- |')
    for label, (us, same) in rows.items():
        print(f'| {label} | {us:.1f} | {"yes" if same else "NO"} |')
    print()
    print('| reading the finished file | us per message | the file cut at 2/3 |')
    print('| --- | --- | --- |')
    for label, (us, torn) in reading(data, n * len(topics)).items():
        print(f'| {label} | {us:.2f} | {torn} |')


if __name__ == '__main__':
    main(*((500,) if sys.argv[1:] == ['--quick'] else (int(a) for a in sys.argv[1:])))
