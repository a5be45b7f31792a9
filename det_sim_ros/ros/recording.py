"""
The node's MCAP recorder (det_sim_ros.io.mcap_log), opened from the ``log.*`` parameters.

It is on unless ``log.enabled`` is false. Its writer thread owns the file and flushes it.
"""

from __future__ import annotations

import os
from typing import Callable

__all__ = ['open_recorder']


def open_recorder(get: Callable, scene, qos_by_topic: dict, metadata: dict, namespace: str,
                  logger):
    """
    Open a background recorder fed the node's bytes; None when logging is off.

    The recorder is a :class:`~det_sim_ros.io.mcap_log.Recorder`. Logs where it writes and its
    limits; a log directory's unfinished logs (cut by a crash: power loss, SIGKILL inside a
    flush) are repaired first.

    :param get: a parameter's value by name.
    """
    if not get('log.enabled'):
        return None
    from ..io.mcap_log import Recorder, recover_unfinished
    path = get('log.path')
    if not path.endswith('.mcap') and os.path.isdir(path):
        for repaired, outcome in recover_unfinished(path):
            logger.warning(f'recovered unfinished log {repaired}: '
                           f"{outcome['messages']} messages readable")
    split, max_mb, max_files = get('log.split_mb'), get('log.max_mb'), get('log.max_files')
    recorder = Recorder(
        path, scene, qos_by_topic=qos_by_topic, split_mb=split, max_total_mb=max_mb,
        max_files=max_files, compression=get('log.compression'), namespace=namespace,
        background=True, metadata=metadata, on_fault=lambda text: logger.error(text))
    if recorder.active:
        logger.info(
            f'logging to {recorder.path} (a new file at every ~/reset'
            + (f' and after {split:g} MiB' if split else '') + '; log directory limit: '
            + (f'{max_mb:g} MiB' if max_mb else 'no size limit') + ', '
            + (f'{max_files} files' if max_files else 'no file limit')
            + ', oldest deleted first)')
        if recorder.deleted:
            logger.info(f'log limit: deleted {len(recorder.deleted)} old log file(s)')
    return recorder
