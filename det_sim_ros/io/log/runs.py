"""
The runs in a set of log files: which files belong to one recorder's run, oldest run first.

A recorder names its first file ``<stem>.mcap`` (in a log directory ``det_sim_<date>-<time>
_<pid>.mcap``) and continues a run (a split, a ``~/reset``) in ``<stem>_001.mcap``,
``<stem>_002.mcap``, ...; every file's ``det_sim_ros`` metadata record holds its
``file_index`` (0 for the first) and the wall time it was opened (``wall_start_ns``). So a file
``<stem>_<n>.mcap`` whose file_index is n belongs to the run ``<stem>`` (also when the
directory's limit has deleted the first file); any other file starts a run of its own. A run's
start is the earliest wall start of its files (the file's modification time when a file has
no metadata, e.g. not a log at all: its reader then says what is wrong with it).
"""

from __future__ import annotations

import dataclasses
import os
import re

from .format import METADATA_NAME
from .reader import log_files, LogReader

__all__ = ['LogRun', 'log_runs']

_CONTINUED = re.compile(r'^(?P<stem>.+)_(?P<index>\d{3,})\.mcap$')


@dataclasses.dataclass(frozen=True)
class LogRun:
    """One recorder's run: its name (the first file's stem), files in order, wall start (ns)."""

    name: str
    files: tuple
    start_ns: int


def _file_facts(path: str) -> tuple[int | None, int]:
    """Return (file_index or None, wall start in ns) of one file."""
    info = {}
    try:
        reader = LogReader(path)
        reader.scan_info()
        info = reader.metadata.get(METADATA_NAME, {})
    except Exception:  # noqa: BLE001 - not a readable log: a run of its own, by its mtime
        pass
    try:
        index = int(info['file_index'])
    except (KeyError, ValueError):
        index = None
    try:
        start = int(info['wall_start_ns'])
    except (KeyError, ValueError):
        try:
            start = os.stat(path).st_mtime_ns
        except OSError:
            start = 0
    return index, start


def log_runs(paths) -> list[LogRun]:
    """
    Return the runs among ``paths`` (files and directories, as :func:`log_files` expands them).

    Oldest run first; a run's files in their order (file_index, then name).

    :raises FileNotFoundError: no MCAP files.
    """
    members: dict[str, list[tuple[int, str, int]]] = {}
    for path in log_files(paths):
        index, start = _file_facts(path)
        folder, name = os.path.split(path)
        match = _CONTINUED.match(name)
        if match and index is not None and index > 0 and int(match['index']) == index:
            key = os.path.join(folder, match['stem'])
        else:
            key = path[:-5] if path.endswith('.mcap') else path
        members.setdefault(key, []).append((index or 0, path, start))
    runs = [LogRun(os.path.basename(key), tuple(path for _, path, _ in sorted(files)),
                   min(start for _, _, start in files))
            for key, files in members.items()]
    return sorted(runs, key=lambda run: (run.start_ns, run.name))
