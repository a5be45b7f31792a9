"""
A node's name locked on this host: of two nodes of one name in one ROS domain, one holds it.

The lock is a listening abstract Unix socket address (Linux) named from a hash of the ROS
domain id and the node's fully qualified name. One socket at a time can be bound to it, so
taking it is one system call and tells at once whether another process of this host holds the
name; the kernel unbinds it when the last descriptor of the socket is closed, so when the
process ends, however it ends (SIGKILL included), no lock outlives its node. Nothing is written
to the file system: a read-only one, a missing runtime directory or a cleaned /tmp change
nothing.

A descriptor is shared by ``fork()``: a child forked by the node's process (a
``ProcessPoolExecutor`` or ``multiprocessing`` worker of a script or test that runs a node in
its own process) would keep the socket bound after its parent died. So a forked child closes
its copy at once (``os.register_at_fork``; closing a copy leaves the parent's bound), and to
it the lock is held by another process; ``exec`` closes it too (the descriptor is
close-on-exec). A child made by a bare C ``fork()`` that runs no Python would keep it until it
exits or execs.

A process refused finds out who holds the name by connecting to it: the kernel tells the peer's
pid (``SO_PEERCRED``, that of the process that took the lock), and ``/proc`` its command line
(:meth:`HostNameLock.holder`). The holder never accepts, so each such connection waits in its
socket's backlog until the holder ends; the backlog is bounded (:data:`NAMED_REFUSALS`), and
past it a refusal says the holder is unknown.

Its scope is the network namespace, the scope of DDS's localhost: the processes of one host
(any user's: their nodes meet over DDS too), a container on the host's network, share it; a
container or network namespace with a network of its own is another host, to DDS as to this
lock (the fleet tests' hosts are network namespaces of one machine, test/netns_hosts.py).
Where there are no abstract socket addresses (not Linux) the lock is :data:`UNAVAILABLE` and
DDS alone settles the name (det_sim_ros.ros.name_check).
"""

from __future__ import annotations

import enum
import errno
import hashlib
import os
import socket
import struct
import sys
import weakref

__all__ = ['command_line', 'HostNameLock', 'LockState', 'lock_address', 'NAMED_REFUSALS']

NAMED_REFUSALS = 64   # refused processes that can learn the holder's pid from one holder


class LockState(enum.Enum):
    """Who holds a name's lock, as seen by the process that tried to take it."""

    HELD = 'held by this process'
    HELD_ELSEWHERE = 'held by another process of this host'
    UNAVAILABLE = 'no host lock on this system'


HELD, HELD_ELSEWHERE, UNAVAILABLE = LockState

_HELD_LOCKS = weakref.WeakSet()   # the locks this process holds: a forked child lets them go


def _forked_child_lets_go() -> None:
    for lock in list(_HELD_LOCKS):
        lock._let_go_in_child()


if hasattr(os, 'register_at_fork'):
    os.register_at_fork(after_in_child=_forked_child_lets_go)


def lock_address(domain_id: int, name: str) -> bytes:
    """Return the abstract socket address of (domain id, fully qualified name): a fixed length."""
    digest = hashlib.sha256(f'{int(domain_id)}\n{name}'.encode()).hexdigest()[:32]
    return b'\0det_sim_ros/node_name/' + digest.encode()


class HostNameLock:
    """
    The lock on one (domain id, fully qualified name) on this host, taken when made.

    :attr:`state` says whether this process holds it; :meth:`release` lets it go (a node that
    ends without it releases it with its process); :meth:`holder` says who holds it when
    another process does.
    """

    def __init__(self, domain_id: int, name: str, enabled: bool = True):
        """Take the lock (``enabled`` False: take nothing, the lock is :data:`UNAVAILABLE`)."""
        self._socket = None
        self._address = lock_address(domain_id, name)
        self.state = self._take(self._address) if enabled else UNAVAILABLE
        if self.state is HELD:
            _HELD_LOCKS.add(self)

    def _take(self, address: bytes) -> LockState:
        if not sys.platform.startswith('linux'):
            return UNAVAILABLE
        try:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)   # close-on-exec
        except OSError:
            return UNAVAILABLE
        try:
            sock.bind(address)
        except OSError as exc:
            sock.close()
            return HELD_ELSEWHERE if exc.errno == errno.EADDRINUSE else UNAVAILABLE
        try:
            sock.listen(NAMED_REFUSALS)   # the peer credentials a refused process reads
        except OSError:
            pass
        self._socket = sock
        return HELD

    def holder(self) -> str:
        """
        Return who holds the name, for a refusal: 'pid N: COMMAND LINE', or why it is unknown.

        Only meaningful when :attr:`state` is HELD_ELSEWHERE.
        """
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
                probe.setblocking(False)
                probe.connect(self._address)
                pid = struct.unpack('3i', probe.getsockopt(
                    socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize('3i')))[0]
        except OSError:
            return 'holder unknown'
        if pid <= 0:
            return 'holder in another pid namespace'
        return f'pid {pid}: {command_line(pid)}'

    def release(self) -> None:
        """Let the name go (the next node of this name on this host may take it)."""
        _HELD_LOCKS.discard(self)
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def _let_go_in_child(self) -> None:
        """In a forked child: close this process's copy; the parent still holds the lock."""
        self.release()
        self.state = HELD_ELSEWHERE


def command_line(pid: int, limit: int = 200) -> str:
    """Return a process's command line, at most ``limit`` characters, or why it is unknown."""
    try:
        with open(f'/proc/{pid}/cmdline', 'rb') as stream:
            words = stream.read().rstrip(b'\0').split(b'\0')
    except OSError:
        return '(command line unreadable)'
    text = ' '.join(word.decode(errors='replace') for word in words) or '(no command line)'
    text = ''.join(c if c.isprintable() else ' ' for c in text)   # one line
    return text if len(text) <= limit else text[:limit - 3] + '...'
