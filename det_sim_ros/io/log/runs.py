"""
The runs in a set of log files: which files belong to one recorder's run, oldest run first.

A recorder names its first file ``<stem>.mcap`` (in a log directory ``det_sim_<date>-<time>
_<pid>.mcap``) and continues a run (a split, a ``~/reset``) in ``<stem>_001.mcap``,
``<stem>_002.mcap``, ...; every file's ``det_sim_ros`` metadata record holds its
``file_index`` (0 for the first) and the wall time it was opened (``wall_start_ns``). So a file
``<stem>_<n>.mcap`` whose file_index is n belongs to the run ``<stem>`` (also when the
directory's limit has deleted the first file); any other file starts a run of its own. A run's
start is the earliest wall start of its files.

A file without that metadata record (empty, not MCAP, unreadable, torn before the record, or
another program's MCAP file) belongs to no run: :attr:`LogRuns.unreadable` names it and why,
so a foreign file in a log directory is never taken for its newest run.
"""

from __future__ import annotations

import dataclasses
import os
import re

from .format import METADATA_NAME
from .reader import log_files, LogReader
from .sniff import file_kind

__all__ = ['LogRun', 'log_runs', 'LogRuns']

_CONTINUED = re.compile(r'^(?P<stem>.+)_(?P<index>\d{3,})\.mcap$')


@dataclasses.dataclass(frozen=True)
class LogRun:
    """One recorder's run: its name (the first file's stem), files in order, wall start (ns)."""

    name: str
    files: tuple
    start_ns: int


class LogRuns(list):
    """The runs of a set of files, oldest first; :attr:`unreadable`: (path, why) of the others."""

    def __init__(self, runs=(), unreadable=()):
        super().__init__(runs)
        self.unreadable = tuple(unreadable)

    def unreadable_line(self, limit: int = 3) -> str:
        """Return one line naming the files left out and why ('' if none)."""
        if not self.unreadable:
            return ''
        named = '; '.join(f'{path} ({why})' for path, why in self.unreadable[:limit])
        more = len(self.unreadable) - limit
        return (f'left out {len(self.unreadable)} file(s) that are not sim_node logs: {named}'
                + (f'; and {more} more' if more > 0 else ''))


def _file_facts(path: str) -> tuple[int | None, int | None, str]:
    """Return (file_index or None, wall start in ns, '') of a log; (None, None, why) if none."""
    try:
        kind = file_kind(path)
        if kind != 'mcap':
            return None, None, 'empty' if kind == 'empty' else 'not an MCAP file'
        reader = LogReader(path)
        reader.scan_info()
        info = reader.metadata.get(METADATA_NAME, {})
    except OSError as exc:
        return None, None, f'unreadable: {exc.strerror or exc}'
    except Exception as exc:  # noqa: BLE001 - whatever a damaged file raises: not a run
        return None, None, f'unreadable: {type(exc).__name__}'
    try:
        start = int(info['wall_start_ns'])
    except (KeyError, ValueError):
        return None, None, ('torn before its det_sim_ros metadata' if reader.errors else
                            "no det_sim_ros metadata: another program's file")
    try:
        index = int(info['file_index'])
    except (KeyError, ValueError):
        index = None
    return index, start, ''


def log_runs(paths) -> LogRuns:
    """
    Return the runs among ``paths`` (files and directories, as :func:`log_files` expands them).

    Oldest run first; a run's files in their order (file_index, then name). Files that are not
    sim_node logs are in no run: the result's :attr:`~LogRuns.unreadable`.

    :raises FileNotFoundError: no MCAP files.
    """
    members: dict[str, list[tuple[int, str, int]]] = {}
    unreadable = []
    for path in log_files(paths):
        index, start, why = _file_facts(path)
        if why:
            unreadable.append((path, why))
            continue
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
    return LogRuns(sorted(runs, key=lambda run: (run.start_ns, run.name)), unreadable)
