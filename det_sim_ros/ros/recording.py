"""
The node's MCAP recorder (det_sim_ros.io.log), opened from the ``log.*`` parameters.

It is on unless ``log.enabled`` is false. Its writer thread owns the file and flushes it. A
log that cannot be opened at start refuses the start; one that fails later stops logging only.
"""

from __future__ import annotations

import errno
import os
from typing import Callable

__all__ = ['open_recorder']


def open_recorder(get: Callable, scene, qos_by_topic: dict, metadata: dict, namespace: str,
                  logger):
    """
    Open a background recorder fed the node's bytes; None when logging is off.

    The recorder is a :class:`~det_sim_ros.io.log.Recorder`. Logs where it writes and its
    limits; a log directory's unfinished logs (cut by a crash: power loss, SIGKILL inside a
    flush) are repaired first.

    :param get: a parameter's value by name.
    """
    if not get('log.enabled'):
        return None
    from ..io.log import Recorder, recover_unfinished
    from ..scenes.scene import SceneError
    path = get('log.path')
    try:
        _check_writable(path)
        if not path.endswith('.mcap') and os.path.isdir(path):
            for repaired, outcome in recover_unfinished(path):
                logger.warning(f'recovered unfinished log {repaired}: '
                               f"{outcome['messages']} messages readable")
    except OSError as exc:
        where = f'{exc.filename}: ' if exc.filename and exc.filename != path else ''
        raise SceneError(f'parameter log.path {path!r}: cannot write a log there '
                         f'({where}{exc.strerror or exc})') from None
    split, max_mb, max_files = get('log.split_mb'), get('log.max_mb'), get('log.max_files')
    recorder = Recorder(
        path, scene, qos_by_topic=qos_by_topic, split_mb=split, max_total_mb=max_mb,
        max_files=max_files, compression=get('log.compression'), namespace=namespace,
        background=True, metadata=metadata, on_fault=lambda fault: None)
    # a start-up input that cannot be used, not a fault at run time: its fault is this start's
    # one FATAL line, not a line of the recorder's own
    if not recorder.active:
        recorder.close()
        raise SceneError(f'parameter log.path {path!r}: cannot write a log there '
                         f"({recorder.fault.split(': ', 1)[-1]})")
    recorder.on_fault = logger.error   # a disk that fails later: ERROR, /diagnostics, runs on
    logger.info(
        f'logging to {recorder.path} (a new file at every ~/reset'
        + (f' and after {split:g} MiB' if split else '') + '; log directory limit: '
        + (f'{max_mb:g} MiB' if max_mb else 'no size limit') + ', '
        + (f'{max_files} files' if max_files else 'no file limit')
        + ', oldest deleted first)')
    if recorder.deleted:
        logger.info(f'log limit: deleted {len(recorder.deleted)} old log file(s)')
    return recorder


def _check_writable(path: str) -> None:
    """Create the log directory (a log file's directory); OSError if it cannot be written."""
    as_file = path.endswith('.mcap') or (os.path.exists(path) and not os.path.isdir(path))
    if as_file and os.path.isdir(path):   # a directory named *.mcap
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), path)
    folder = (os.path.dirname(path) or os.curdir) if as_file else path
    os.makedirs(folder, exist_ok=True)
    target = path if os.path.exists(path) and as_file else folder
    if not os.access(target, os.W_OK if target == path else os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), target)
