"""
The checks ``det_sim replay`` runs on its log files before it reads them.

A file that is not a sim_node log (missing, empty, not MCAP, no scene, a directory without
``*.mcap`` files) is refused with one line (:class:`LogFileError`, exit code 1). A torn file
(cut inside a record: a power loss, a copy that stopped) is readable up to the cut; the
subcommands say so in one line (:func:`torn_files`, :func:`torn_note`) and exit 1, and
``recover`` rewrites its readable part as a finished file.
"""

from __future__ import annotations

import os

__all__ = ['LogFileError', 'open_log', 'torn_files', 'torn_note']


class LogFileError(ValueError):
    """A file that ``det_sim replay`` cannot use (reported as one line, exit code 1)."""


def _check_bytes(path: str) -> None:
    """Refuse a file that is empty or does not start with the MCAP magic."""
    from ..io.log import file_kind
    if os.path.isdir(path):
        raise LogFileError(f'{path}: a directory inside a directory (give the log files)')
    kind = file_kind(path)      # a missing file: FileNotFoundError, one line
    if kind == 'empty':
        raise LogFileError(f'{path}: an empty file, not an MCAP log')
    if kind != 'mcap':
        raise LogFileError(f'{path}: not an MCAP file (it does not start with the MCAP magic)')


def torn_files(files) -> list[str]:
    """Return those of ``files`` that are torn: they do not end in a valid MCAP footer."""
    from ..io.log import is_torn
    return [path for path in files if is_torn(path)]


def torn_note(files, done: str = 'only its readable part was read') -> str:
    """Return the one line about the torn ``files`` ('' if there are none)."""
    if not files:
        return ''
    return (f'{files[0]}: torn (the file ends inside a record), {done}; '
            f'`det_sim_replay recover {files[0]} FIXED.mcap` writes that part as a finished file'
            + (f' ({len(files)} torn files)' if len(files) > 1 else ''))


def open_log(paths):
    """
    Return a LogReader of ``paths`` (files or directories) once they pass the checks.

    :raises LogFileError: no log files, an empty or non-MCAP file, or a log without the scene
        of the run (not a sim_node log, or torn before its scene).
    :raises OSError: a missing or unreadable file.
    """
    from ..io.log import log_files, LogReader
    try:
        files = log_files(paths)
    except FileNotFoundError as exc:   # a directory without logs
        raise LogFileError(f'{exc} (a sim_node log is a .mcap file)') from None
    for path in files:
        _check_bytes(path)
    reader = LogReader(files)
    if not reader.scene_yaml:
        first = files[0]
        if torn_files([first]):
            raise LogFileError(f'{first}: torn before the scene of the run (nothing readable)')
        raise LogFileError(f'{first}: not a sim_node log (it holds no det_sim_ros scene)')
    return reader
