"""
One MCAP file being written in the rosbag2 conventions.

Its start (header, the run's metadata record and scene attachment), its schemas and
channels, its messages (through the record packer, or one by one through
``McapWriter.add_message``: the same bytes), its flushes and its end (the counters' metadata
record, the summary).
"""

from __future__ import annotations

import os
import time
from typing import Mapping

from .compression import compression as compression_kind
from .format import END_METADATA_NAME, LIBRARY, METADATA_NAME, SCENE_ATTACHMENT
from .packing import RecordPacker
from .tail_stream import TailStream
from .writer import McapWriter
from ..schemas import message_definition, qos_profiles_yaml

__all__ = ['LogFile', 'file_info', 'scene_text', 'logged_scene', 'package_version']


class LogFile:
    """
    An open MCAP file (see the module docstring): created here, started by :meth:`start`.

    :param packing: write messages through the :class:`RecordPacker`.
    """

    def __init__(self, path: str, *, chunk_size: int, compression: str, packing: bool = True):
        self._compression = compression_kind(compression)   # (a bad name: no file made)
        self.stream = TailStream(path)
        self._chunk_size = chunk_size
        self._packing = packing
        self.writer = self.packer = None
        self.channels: dict[str, int] = {}      # topic -> channel id
        self.sample_plans: dict[tuple, tuple] = {}   # sample topics -> (names, channel ids)
        self._schemas: dict[str, int] = {}

    def start(self, version: str, info: Mapping[str, str], scene_yaml: str,
              log_time: int) -> None:
        """
        Write the header, the run's metadata record and the scene attachment; flush.

        The metadata record is ``info`` (:func:`file_info`: its ``wall_start_ns`` is filled in
        here); there is no scene attachment for ''; all at log time ``log_time``.
        """
        writer = McapWriter(self.stream, chunk_size=self._chunk_size,
                            compression=self._compression)
        writer.start(profile='ros2', library=f'{LIBRARY} {version}')
        wall_ns = time.time_ns()
        info = dict(info)
        if info.get('wall_start_ns') is None:   # (the run's metadata may give its own)
            info['wall_start_ns'] = str(wall_ns)
        writer.add_metadata(METADATA_NAME, info)
        if scene_yaml:
            writer.add_attachment(create_time=wall_ns, log_time=log_time,
                                  name=SCENE_ATTACHMENT, media_type='application/yaml',
                                  data=scene_yaml.encode())
        writer.flush()
        self.writer = writer
        self.packer = RecordPacker(writer) if self._packing else None

    def size(self) -> int:
        """Return the file's size once everything written is flushed."""
        return self.stream.tell()

    def register(self, topic: str, type_name: str, qos=None) -> int:
        """Return a channel for ``topic`` (its type's schema on first use); its id."""
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            schema_id = self.writer.register_schema(
                name=type_name, encoding='ros2msg', data=message_definition(type_name).encode())
            self._schemas[type_name] = schema_id
        channel_id = self.writer.register_channel(
            topic=topic, message_encoding='cdr', schema_id=schema_id,
            metadata={'offered_qos_profiles': qos_profiles_yaml(qos), 'topic_type_hash': ''})
        self.channels[topic] = channel_id
        return channel_id

    def add(self, channel_id: int, sequence: int, data: bytes, log_time: int) -> None:
        """Write one message (its publish time is its log time)."""
        if self.packer is not None:   # the same records, one pack (cheaper: docs/performance.md)
            self.packer.add(((channel_id, sequence, data),), log_time)
        else:
            self.writer.add_message(channel_id=channel_id, log_time=log_time, data=data,
                                    publish_time=log_time, sequence=sequence)

    def message_count(self) -> int:
        """Return the messages this file holds, as its summary will count them."""
        return self.writer.statistics.message_count

    def flush(self) -> None:
        """End the chunk and write everything (and the provisional end) to disk."""
        self.writer.flush()

    def finish(self, counters: Mapping[str, str]) -> None:
        """Write the end metadata ``counters`` and the summary, and close the file."""
        try:
            self.writer.add_metadata(END_METADATA_NAME, dict(counters))
            self.writer.finish()
            self.stream.finish()
        finally:
            self.stream.close()

    def abandon(self) -> None:
        """After a fault: finish the file if the error allows it, close it (never raises)."""
        try:
            if self.writer is not None:
                self.writer.finish()
            self.stream.finish()
        except Exception:  # noqa: BLE001 - keep what can be kept
            pass
        try:
            self.stream.close()
        except Exception:  # noqa: BLE001
            pass


def file_info(version: str, scene_yaml: str, file_index: int,
              metadata: Mapping[str, str]) -> dict:
    """Return a file's ``det_sim_ros`` metadata record (``wall_start_ns`` added when opened)."""
    info = {'version': version, 'scene_yaml': scene_yaml, 'time_base': 'sim_time',
            'ros_distro': os.environ.get('ROS_DISTRO', 'jazzy'), 'wall_start_ns': None,
            'file_index': str(file_index)}
    info.update(metadata)
    return info


def scene_text(scene) -> str:
    """
    Return the YAML text stored in a log for a Scene, its YAML text or mapping ('' for None).

    A Scene's tolerance is stored as the number it resolves to (an 'auto' 0 is not).
    """
    if scene is None:
        return ''
    if isinstance(scene, str):
        return scene
    import yaml
    from ...scenes.scene import scene_to_dict
    data = scene if isinstance(scene, Mapping) else scene_to_dict(logged_scene(scene), wrap=True)
    return yaml.safe_dump(data, sort_keys=False)


def logged_scene(scene):
    """
    Return a Scene as a log stores it: its tolerance, Ritz family and terms as they resolve.

    Not 'auto' (0): a log re-simulates as recorded whatever the auto tables say later.
    """
    from ...sim.integrators import integration_tolerance
    shapes, n_ritz = scene.ritz_level
    return scene.replace(**{'integrator.tolerance': integration_tolerance(scene),
                            'scene.shapes': shapes, 'scene.n_ritz': n_ritz})


def package_version() -> str:
    """det_sim_ros's version ('unknown' for a partial install)."""
    try:
        from ... import __version__
        return __version__
    except Exception:  # pragma: no cover - partial installs
        return 'unknown'
