"""
The recorder's files: their names, when one is split, and the bounded log directory.

A path ending in ``.mcap`` (or an existing non-directory, such as a device) is written as given;
otherwise it is a directory in which ``<prefix>_<date>-<time>_<pid>.mcap`` is created. Split
files continue the first one's name as ``<stem>_001.mcap``, ``<stem>_002.mcap``, ... When a file
is opened or flushed, the oldest files of this recorder's name pattern in its directory are
deleted until the rest fits ``max_total_mb`` and ``max_files`` (never the file being written).
"""

from __future__ import annotations

import bisect
import os
import re
import time

__all__ = ['LogRotation']


def _first_path(path: str, prefix: str) -> str:
    if path.endswith('.mcap') or (os.path.exists(path) and not os.path.isdir(path)):
        folder = os.path.dirname(path)
        if folder:
            os.makedirs(folder, exist_ok=True)
        return path
    os.makedirs(path, exist_ok=True)
    stamp = time.strftime('%Y%m%d-%H%M%S')
    base = os.path.join(path, f'{prefix}_{stamp}_{os.getpid()}')
    candidate, n = base + '.mcap', 1
    while os.path.exists(candidate):
        candidate, n = f'{base}-{n}.mcap', n + 1
    return candidate


class LogRotation:
    """
    File rotation (next path, due splits) and retention (oldest files deleted).

    Rotation: the next file's path, whether a split is due; retention: the oldest files
    deleted to respect the limits. :attr:`paths`: the files written, in order; :attr:`deleted`:
    the old files removed.

    :raises OSError: the path's directory cannot be made.
    """

    def __init__(self, path, prefix: str = 'det_sim', *, split_mb: float = 0.0,
                 split_s: float = 0.0, max_total_mb: float = 0.0, max_files: int = 0):
        path = os.fspath(path)
        self.paths: list[str] = []
        self.deleted: list[str] = []
        self.split_bytes = int(float(split_mb) * 1024 * 1024)
        self.split_ns = int(float(split_s) * 1e9)
        self.max_total_bytes = int(float(max_total_mb) * 1024 * 1024)
        self.max_files = int(max_files)
        self.file_start_t: int | None = None   # log time of the current file's first message
        self._old_files: list[tuple[str, int]] = []   # (path, size), oldest first
        self._prefix = prefix
        self._prefix_dir = not (path.endswith('.mcap')
                                or (os.path.exists(path) and not os.path.isdir(path)))
        self._base = _first_path(path, prefix)

    # -- rotation ----------------------------------------------------------------------------
    def next_path(self) -> str:
        """Return the path of the next file (the first, then the splits)."""
        if not self.paths:
            return self._base
        stem = self._base[:-5] if self._base.endswith('.mcap') else self._base
        return f'{stem}_{len(self.paths):03d}.mcap'

    def add(self, path: str) -> None:
        """Note a file created at ``path`` (now the current one, in :attr:`paths`)."""
        self.paths.append(path)
        self.file_start_t = None

    def starts(self, t: int) -> bool:
        """Note log time ``t`` of a message; True if it is the current file's first."""
        if self.file_start_t is None:
            self.file_start_t = t
            return True
        return False

    def split_due(self, t: int, size: int) -> bool:
        """
        Return whether the current file has reached split_mb or its time span.

        ``size``: the current file's bytes; ``t``: the log time of the message being written.
        """
        return bool((self.split_ns and t - self.file_start_t >= self.split_ns)
                    or self.size_reached(size))

    def size_reached(self, size: int) -> bool:
        """Return whether a file of ``size`` bytes is due to be split."""
        return bool(self.split_bytes and size >= self.split_bytes)

    def run_end(self, times, end: int) -> int:
        """
        Return how many log ``times`` (at most ``end``) belong in the current file.

        ``times`` are non-decreasing.
        """
        if not self.split_ns:
            return end
        return bisect.bisect_left(times, self.file_start_t + self.split_ns, 0, end)

    # -- retention ---------------------------------------------------------------------------
    @property
    def bounded(self) -> bool:
        """Return whether the directory has limits (max_total_mb or max_files)."""
        return bool(self.max_total_bytes or self.max_files)

    def _pattern(self):
        stem = self._base[:-5] if self._base.endswith('.mcap') else self._base
        folder = os.path.dirname(stem) or '.'
        if self._prefix_dir:
            return folder, re.compile(re.escape(self._prefix) + r'_.*\.mcap$')
        return folder, re.compile(re.escape(os.path.basename(stem)) + r'(_\d{3})?\.mcap$')

    def opened(self, current: str, size: int) -> None:
        """
        Note an opened file: list the pattern's other files, then enforce the limits.

        The other files of the pattern are listed oldest first.
        """
        if not self.bounded:
            return
        folder, pattern = self._pattern()
        found = []
        for name in os.listdir(folder):
            path = os.path.join(folder, name)
            if pattern.match(name) and os.path.abspath(path) != os.path.abspath(current):
                try:
                    st = os.stat(path)
                except OSError:
                    continue
                found.append((st.st_mtime, name, path, st.st_size))
        self._old_files = [(path, size) for _, _, path, size in sorted(found)]
        self.enforce(size)

    def closed(self, path: str) -> None:
        """Note a finished file: it is an old file now."""
        try:
            self._old_files.append((path, os.path.getsize(path)))
        except OSError:
            pass

    def enforce(self, current_size: int) -> None:
        """
        Delete the oldest files until the directory is within the limits.

        The limits are max_total_mb / max_files, counted with the current file of
        ``current_size`` bytes.
        """
        if not self.bounded:
            return
        while self._old_files and (
                (self.max_files and len(self._old_files) + 1 > self.max_files)
                or (self.max_total_bytes
                    and sum(size for _, size in self._old_files) + current_size
                    > self.max_total_bytes)):
            path, _ = self._old_files.pop(0)
            try:
                os.remove(path)
                self.deleted.append(path)
            except FileNotFoundError:
                pass
