"""
Several "hosts" on one Linux machine, for tests and benchmarks of fleets across hosts (root only).

:class:`NetnsHosts` makes N network namespaces (the hosts) joined by a bridge that lives in a
namespace of its own. The hosts' addresses are on a private subnet that exists only inside those
namespaces: no default route, no link to the root namespace, nothing outside them touched.
Processes run on a host through ``ip netns exec``; :meth:`NetnsHosts.ros_env` gives them unicast
DDS discovery (``ROS_STATIC_PEERS``) over UDP only (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``, so
shared memory cannot short-cut the network path).

A host's link can be a lossy one: ``NetnsHosts(3, lossy={1: (0.001, 0.01)})`` joins host 1
through :func:`relay` (two TAP devices and a process copying frames between them, adding a
delay and dropping frames at random) instead of a veth pair: this kernel has no ``tc netem``.
Everything is removed by :meth:`NetnsHosts.remove` (also namespaces left by a killed run).
"""

from __future__ import annotations

import fcntl
import os
import random
import re
import select
import struct
import subprocess
import sys
import time

__all__ = ['NetnsHosts', 'NetnsError', 'relay', 'can_make_namespaces']

PREFIX = 'detsim'                  # namespace names: detsim<pid>_<n>_h<i>, ..._br
_NAME = re.compile(rf'^{PREFIX}(\d+)_\d+_(h\d+|br)$')
STEP_TIMEOUT = 20.0                # s: any one ip command (bounds a hang, never a measurement)


class NetnsError(RuntimeError):
    """A namespace step failed (the command and its message, one line)."""


def can_make_namespaces() -> str:
    """Return '' when this process can make network namespaces and TAP devices, else why not."""
    if sys.platform != 'linux':
        return 'network namespaces need Linux'
    if os.geteuid() != 0:
        return 'network namespaces need root'
    if not os.path.exists('/dev/net/tun'):
        return 'no /dev/net/tun'
    try:
        subprocess.run(['ip', '-V'], capture_output=True, timeout=STEP_TIMEOUT, check=True)
    except (OSError, subprocess.SubprocessError):
        return "no 'ip' command (iproute2)"
    probe = f'{PREFIX}{os.getpid()}_0_h0'     # (a name remove_stale knows)
    try:                                       # root in a container may still lack the right
        _ip('netns', 'add', probe)
        _ip('-n', probe, 'link', 'add', 'br0', 'type', 'bridge')
    except NetnsError as exc:
        return f'cannot make a network namespace with a bridge: {exc}'
    finally:
        try:
            if probe in _namespaces():
                _ip('netns', 'del', probe)
        except NetnsError:
            pass
    return ''


def _ip(*args, timeout=STEP_TIMEOUT):
    try:
        proc = subprocess.run(['ip', *args], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise NetnsError(f"'ip {' '.join(args)}' did not finish within {timeout:g} s") from None
    if proc.returncode != 0:
        raise NetnsError(f"'ip {' '.join(args)}': {proc.stderr.strip()}")
    return proc.stdout


def _namespaces():
    return [line.split()[0] for line in _ip('netns', 'list').splitlines() if line.strip()]


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale() -> list:
    """Delete the namespaces of earlier runs whose process is gone (a SIGKILLed test)."""
    removed = []
    for name in _namespaces():
        match = _NAME.match(name)
        if match and not _alive(int(match.group(1))):
            _kill_inside(name)
            _ip('netns', 'del', name)
            removed.append(name)
    return removed


def _kill_inside(name):
    """SIGKILL every process still in namespace ``name`` (none is expected)."""
    try:
        pids = _ip('netns', 'pids', name).split()
    except NetnsError:
        return
    for pid in pids:
        try:
            os.kill(int(pid), 9)
        except (ProcessLookupError, ValueError):
            pass


class NetnsHosts:
    """
    ``n`` hosts (network namespaces) on one bridge, addresses ``<subnet>.1`` ... ``.n`` /24.

    :param lossy: host index -> (delay s, loss probability) for a link through :func:`relay`.
    Use as a context manager, or call :meth:`create` and then :meth:`remove` in a finally.
    """

    _count = 0

    def __init__(self, n: int, subnet: str = '10.231.77', lossy: dict | None = None,
                 seed: int = 1):
        NetnsHosts._count += 1
        base = f'{PREFIX}{os.getpid()}_{NetnsHosts._count}'
        self.n = n
        self.hosts = [f'{base}_h{i}' for i in range(n)]
        self.bridge = f'{base}_br'
        self.addresses = [f'{subnet}.{i + 1}' for i in range(n)]
        self.lossy = dict(lossy or {})
        self.seed = seed
        self.relays: list = []
        self.procs: list = []

    # -- life cycle ----------------------------------------------------------------------------
    def __enter__(self):
        try:
            return self.create()
        except BaseException:
            self.remove()
            raise

    def __exit__(self, *exc):
        self.remove()

    def create(self) -> 'NetnsHosts':
        remove_stale()
        br = self.bridge
        _ip('netns', 'add', br)
        _ip('-n', br, 'link', 'set', 'lo', 'up')
        _ip('-n', br, 'link', 'add', 'br0', 'type', 'bridge')
        _ip('-n', br, 'link', 'set', 'br0', 'up')
        for i, host in enumerate(self.hosts):
            _ip('netns', 'add', host)
            _ip('-n', host, 'link', 'set', 'lo', 'up')
            if i in self.lossy:
                self._relay_link(i)
            else:
                _ip('-n', br, 'link', 'add', f'port{i}', 'type', 'veth', 'peer', 'name', 'eth0',
                    'netns', host)
            _ip('-n', br, 'link', 'set', f'port{i}', 'master', 'br0')
            _ip('-n', br, 'link', 'set', f'port{i}', 'up')
            _ip('-n', host, 'addr', 'add', f'{self.addresses[i]}/24', 'dev', 'eth0')
            _ip('-n', host, 'link', 'set', 'eth0', 'up')
        return self

    def _relay_link(self, i):
        """
        Join host i to the bridge through a relay process (in the bridge namespace).

        Host i's eth0 and the bridge port are TAP devices of the relay, which copies frames
        between them with a delay and random loss.
        """
        delay, loss = self.lossy[i]
        proc = subprocess.Popen(
            ['ip', 'netns', 'exec', self.bridge, sys.executable, os.path.abspath(__file__),
             'relay', f'tap{i}', f'port{i}', str(delay), str(loss), str(self.seed + i)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
        self.relays.append(proc)
        ready, _, _ = select.select([proc.stdout], [], [], STEP_TIMEOUT)
        line = proc.stdout.readline() if ready else ''
        if line.strip() != 'ready':
            raise NetnsError(f'relay for host {i} did not start: {line.strip()} '
                             f'{proc.stderr.read() if proc.poll() is not None else ""}'.strip())
        _ip('-n', self.bridge, 'link', 'set', f'tap{i}', 'netns', self.hosts[i])
        _ip('-n', self.hosts[i], 'link', 'set', f'tap{i}', 'name', 'eth0')

    def remove(self) -> None:
        """Stop what runs on the hosts and the relays, delete every namespace made here."""
        for proc in self.procs + self.relays:
            if proc.poll() is None:
                proc.kill()
            try:
                proc.wait(timeout=STEP_TIMEOUT)
            except subprocess.TimeoutExpired:
                pass
        existing = set(_namespaces())
        for name in self.hosts + [self.bridge]:
            if name in existing:
                _kill_inside(name)
                _ip('netns', 'del', name)

    # -- running things on a host --------------------------------------------------------------
    def ros_env(self, base: dict | None = None, **extra) -> dict:
        """Return an environment: unicast discovery with every host as a static peer, UDP only."""
        return dict(base if base is not None else os.environ,
                    ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                    ROS_STATIC_PEERS=';'.join(self.addresses),
                    FASTDDS_BUILTIN_TRANSPORTS='UDPv4', **extra)

    def packets_received(self, host: int) -> int:
        """Return the packets host ``host`` has received on its link (eth0) so far."""
        text = _ip('-n', self.hosts[host], '-s', '-o', 'link', 'show', 'eth0')
        return int(text.split('RX:')[1].split('\\')[1].split()[1])

    def command(self, host: int, args: list) -> list:
        return ['ip', 'netns', 'exec', self.hosts[host], *args]

    def popen(self, host: int, args: list, **kwargs) -> subprocess.Popen:
        """Start ``args`` on host ``host`` (killed by :meth:`remove` if still running)."""
        proc = subprocess.Popen(self.command(host, args), **kwargs)
        self.procs.append(proc)
        return proc


# -- the lossy link ------------------------------------------------------------------------------
TUNSETIFF = 0x400454CA
IFF_TAP, IFF_NO_PI = 0x0002, 0x1000


def _tap(name):
    fd = os.open('/dev/net/tun', os.O_RDWR | os.O_NONBLOCK)
    fcntl.ioctl(fd, TUNSETIFF, struct.pack('16sH', name.encode(), IFF_TAP | IFF_NO_PI))
    return fd


def relay(name_a: str, name_b: str, delay: float, loss: float, seed: int = 1) -> None:
    """
    Make TAP devices ``name_a`` and ``name_b`` and copy every Ethernet frame between them.

    The devices are made in this namespace. Each direction is delayed by ``delay`` s (frames
    keep their order) and dropped with probability ``loss`` (a seeded generator). Prints
    'ready' once both exist; runs until killed.
    """
    rng = random.Random(seed)
    fds = [_tap(name_a), _tap(name_b)]
    print('ready', flush=True)
    queue = []          # (due time, fd to write to, frame), due times ascending
    head = 0
    while True:
        now = time.monotonic()
        while head < len(queue) and queue[head][0] <= now:
            _, fd, frame = queue[head]
            head += 1
            try:
                os.write(fd, frame)
            except OSError:       # the device is down (host being removed): drop
                pass
        if head > 1024:
            del queue[:head]
            head = 0
        timeout = max(0.0, queue[head][0] - now) if head < len(queue) else 1.0
        readable, _, _ = select.select(fds, [], [], timeout)
        now = time.monotonic()
        for fd in readable:
            other = fds[1] if fd == fds[0] else fds[0]
            while True:
                try:
                    frame = os.read(fd, 65536)
                except BlockingIOError:
                    break
                except OSError:
                    break
                if loss > 0 and rng.random() < loss:
                    continue
                queue.append((now + delay, other, frame))


if __name__ == '__main__':
    if len(sys.argv) == 7 and sys.argv[1] == 'relay':
        relay(sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5]), int(sys.argv[6]))
    else:
        print('usage: python test/netns_hosts.py relay TAP_A TAP_B DELAY_S LOSS SEED',
              file=sys.stderr)
        sys.exit(2)
