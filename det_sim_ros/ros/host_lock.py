"""
A node's name locked on this host: of two nodes of one name in one ROS domain, one holds it.

The lock is an abstract Unix socket address (Linux) named from a hash of the ROS domain id and
the node's fully qualified name. One socket at a time can be bound to it, so taking it is one
system call and tells at once whether another process of this host holds the name; the kernel
unbinds it when the process ends, however it ends (SIGKILL included), so no lock outlives its
node. Nothing is written to the file system: a read-only one, a missing runtime directory or a
cleaned /tmp change nothing.

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
import socket
import sys

__all__ = ['HostNameLock', 'LockState', 'lock_address']


class LockState(enum.Enum):
    """Who holds a name's lock, as seen by the process that tried to take it."""

    HELD = 'held by this process'
    HELD_ELSEWHERE = 'held by another process of this host'
    UNAVAILABLE = 'no host lock on this system'


HELD, HELD_ELSEWHERE, UNAVAILABLE = LockState


def lock_address(domain_id: int, name: str) -> bytes:
    """Return the abstract socket address of (domain id, fully qualified name): a fixed length."""
    digest = hashlib.sha256(f'{int(domain_id)}\n{name}'.encode()).hexdigest()[:32]
    return b'\0det_sim_ros/node_name/' + digest.encode()


class HostNameLock:
    """
    The lock on one (domain id, fully qualified name) on this host, taken when made.

    :attr:`state` says whether this process holds it; :meth:`release` lets it go (a node that
    ends without it releases it with its process).
    """

    def __init__(self, domain_id: int, name: str):
        self._socket = None
        self.state = self._take(lock_address(domain_id, name))

    def _take(self, address: bytes) -> LockState:
        if not sys.platform.startswith('linux'):
            return UNAVAILABLE
        try:
            # (Python's sockets are not inherited by child processes: only this one holds it)
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        except OSError:
            return UNAVAILABLE
        try:
            sock.bind(address)
        except OSError as exc:
            sock.close()
            return HELD_ELSEWHERE if exc.errno == errno.EADDRINUSE else UNAVAILABLE
        self._socket = sock
        return HELD

    def release(self) -> None:
        """Let the name go (the next node of this name on this host may take it)."""
        if self._socket is not None:
            self._socket.close()
            self._socket = None
