"""The writer's output file, a complete MCAP between flushes (:class:`TailStream`)."""

from __future__ import annotations

import os

from .format import PROVISIONAL_END

__all__ = ['TailStream']


class TailStream:
    """
    The writer's output file: records collected in memory, written at each flush.

    Each flush writes them in one ``pwrite``, followed by the provisional end, at the offset where
    the next flush continues (so the provisional end is overwritten by it). Between flushes the
    file on disk is always a complete MCAP. :meth:`finish` writes the writer's real end (after
    ``Writer.finish``).
    """

    def __init__(self, path: str):
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._committed = 0
        self._pending = bytearray()

    def write(self, data) -> int:
        """Collect ``data`` (written at the next flush)."""
        self._pending += data
        return len(data)

    def tell(self) -> int:
        """Return the file's size once what is collected is written."""
        return self._committed + len(self._pending)

    def _commit(self, tail: bytes) -> None:
        data = memoryview(bytes(self._pending) + tail)
        offset = self._committed
        while data:
            n = os.pwrite(self._fd, data, offset)
            offset += n
            data = data[n:]
        self._committed += len(self._pending)
        self._pending.clear()

    def flush(self) -> None:
        """Write what is collected and the provisional end after it."""
        self._commit(PROVISIONAL_END)

    def finish(self) -> None:
        """Write what is pending (the writer's real end) and cut off any stale bytes."""
        self._commit(b'')
        os.ftruncate(self._fd, self._committed)

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)
