"""What a file on disk is, read from its ends: MCAP or not, finished or torn."""

from __future__ import annotations

import os

from .format import FOOTER_HEAD, FOOTER_SIZE, MAGIC

__all__ = ['is_torn', 'file_kind']


def is_torn(path: str) -> bool:
    """Return True for an MCAP file that does not end in a valid footer (a cut file)."""
    try:
        with open(path, 'rb') as stream:
            stream.seek(0, os.SEEK_END)
            size = stream.tell()
            if size < len(MAGIC) + FOOTER_SIZE:
                return True
            stream.seek(0)
            if stream.read(len(MAGIC)) != MAGIC:
                return True
            stream.seek(size - FOOTER_SIZE)
            end = stream.read(FOOTER_SIZE)
    except OSError:
        return False
    return end[-len(MAGIC):] != MAGIC or end[:len(FOOTER_HEAD)] != FOOTER_HEAD


def file_kind(path) -> str:
    """
    Return 'mcap' for a file that starts with the MCAP magic, 'empty' or 'other'.

    :raises OSError: a missing or unreadable file.
    """
    with open(path, 'rb') as stream:
        head = stream.read(len(MAGIC))
    return 'mcap' if head == MAGIC else 'empty' if not head else 'other'
