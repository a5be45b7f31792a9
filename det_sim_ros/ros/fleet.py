"""
A fleet of sim_node processes on this host, from one YAML description (``det_sim fleet FILE``).

A fleet file lists nodes; each node runs as its own ``python -m det_sim_ros.cli.sim_node`` child
process in its own namespace, with its stdout and stderr in ``<log_dir>/<name>.log`` and its
MCAP log in ``<log_dir>/<name>/`` (unless ``log.path`` is given)::

    log_dir: fleet_logs            # relative to the working directory
    defaults:                      # optional, merged into every node
      scene: default
      mode: real_time
      params: {info_period: 0.0}
    nodes:
      - namespace: /cell_a
        scene: default             # a name in config/ or a path (relative to this file)
        overrides: {physics.Rs: 1.0e3}   # scene keys
        mode: lockstep             # real_time, free_run or lockstep
        params: {lockstep.sources: 1}    # other sim_node parameters
        host: lab-pc-1             # optional: start only on this host (--host)

Across hosts every host runs ``det_sim fleet`` with the same file: a node with ``host:`` starts
only on the host of that name (``--host``, default: this machine's host name); a node without
``host:`` starts on every host. SIGINT and SIGTERM are forwarded to every node; the command
exits 0 when all have stopped with exit code 0, 1 otherwise (one line per node that did not).
"""

from __future__ import annotations

import ctypes
import dataclasses
import os
import re
import signal
import socket
import subprocess
import sys
import time

import yaml

from .waiting import WAIT_OVER, WAIT_STARTED
from ..io.contract import MODES
from ..scenes.scene import load_scene, SceneError

__all__ = ['FleetError', 'FleetNode', 'load_fleet', 'Fleet', 'run_fleet']

READY = 'voltage command order'                  # the last line of a node's start-up
NODE_KEYS = {'namespace', 'scene', 'overrides', 'mode', 'params', 'host'}
TOP_KEYS = {'log_dir', 'defaults', 'nodes'}
_NAMESPACE = re.compile(r'^(/[A-Za-z][A-Za-z0-9_]*)+$')


class FleetError(ValueError):
    """A fleet file that cannot be used (reported as one line)."""


@dataclasses.dataclass
class FleetNode:
    """One sim_node of a fleet: where it runs and with which parameters."""

    namespace: str
    scene: str
    mode: str
    overrides: dict
    params: dict
    host: str | None
    log_file: str          # stdout + stderr of the process
    log_path: str          # MCAP log (sim_node's log.path)

    @property
    def name(self) -> str:
        """Return the namespace as a file name: /lab/cell_a -> lab_cell_a."""
        return self.namespace.strip('/').replace('/', '_')

    def parameters(self) -> dict:
        """Return every ROS parameter this node is started with."""
        return {'log.path': self.log_path, **self.params, **self.overrides,
                'scene_file': self.scene, 'mode': self.mode}

    def command(self, params_file: str) -> list:
        return [sys.executable, '-m', 'det_sim_ros.cli.sim_node', '--ros-args',
                '-r', f'__ns:={self.namespace}', '--params-file', params_file]


def _mapping(value, where):
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise FleetError(f'{where}: expected a mapping (key: value), got {value!r}')
    result = {}
    for key, item in value.items():
        if not isinstance(key, str) or not key:
            raise FleetError(f'{where}: keys must be parameter names, got {key!r}')
        if isinstance(item, str):
            try:
                item = float(item)    # YAML 1.1 reads 1e3 and 1.0e3 as text: a number here
            except ValueError:
                pass
        result[key] = item
    return result


def _known_keys(mapping: dict, allowed: set, where: str) -> None:
    """Raise one line naming the first key of ``mapping`` that is not ``allowed``."""
    bad = sorted(set(mapping) - allowed)
    if bad:
        raise FleetError(f'{where}: unknown key {bad[0]!r} (allowed: '
                         + ', '.join(sorted(allowed)) + ')')


def load_fleet(path: str, host: str | None = None, log_dir: str | None = None,
               check_scenes: bool = True) -> list:
    """
    Return the checked nodes of the fleet file ``path`` that run on ``host``.

    ``host`` None means every node. The checks: unique valid namespaces, known modes, known
    parameters, loadable scenes (with their overrides); :class:`FleetError` with one line
    otherwise.
    """
    data = _read_fleet_file(path)
    nodes = data.get('nodes')
    if not isinstance(nodes, list) or not nodes:
        raise FleetError(f'{path}: nodes: must be a non-empty list')
    base = os.path.dirname(os.path.abspath(path))
    folder = log_dir or data.get('log_dir') or 'fleet_logs'
    if not isinstance(folder, str):
        raise FleetError(f'{path}: log_dir: must be a path')
    folder = os.path.abspath(folder)     # like sim_node's log.path: relative to the cwd
    defaults = _mapping(data.get('defaults'), 'defaults')
    _known_keys(defaults, NODE_KEYS - {'namespace', 'host'}, 'defaults')
    result, seen = [], set()
    for i, entry in enumerate(nodes):
        node = _fleet_node(entry, f'nodes[{i}]', seen, defaults, base, folder, check_scenes)
        if host is None or node.host is None or node.host == host:
            result.append(node)
    names = [n.name for n in result]
    if len(set(names)) != len(names):
        raise FleetError('two namespaces give the same log file name (/a/b and /a_b)')
    return result


def _read_fleet_file(path: str) -> dict:
    """Read the fleet file ``path``: a mapping of known keys; :class:`FleetError` if not."""
    try:
        with open(path, encoding='utf-8') as stream:
            data = yaml.safe_load(stream)
    except OSError as exc:
        raise FleetError(f'cannot read fleet file {path}: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        where = getattr(exc, 'problem_mark', None)
        raise FleetError(f'{path}: not valid YAML'
                         + (f' (line {where.line + 1})' if where else '')) from None
    if not isinstance(data, dict):
        raise FleetError(f'{path}: expected a mapping with a nodes: list')
    _known_keys(data, TOP_KEYS, path)
    return data


def _fleet_node(entry, where: str, seen: set, defaults: dict, base: str, folder: str,
                check_scenes: bool) -> FleetNode:
    """
    Check one entry of the fleet file's ``nodes:`` list and return its node.

    ``where`` names the entry in errors; ``seen`` holds the namespaces of the entries before
    it (this one is added); ``base`` is the fleet file's folder, ``folder`` the log folder.
    """
    from .params import NODE_PARAMS
    if not isinstance(entry, dict):
        raise FleetError(f'{where}: expected a mapping with a namespace:')
    _known_keys(entry, NODE_KEYS, where)
    namespace = entry.get('namespace')
    if not isinstance(namespace, str) or not _NAMESPACE.match(namespace):
        raise FleetError(f'{where}: namespace: expected /name or /a/b (letters, digits, _), '
                         f'got {namespace!r}')
    where = f'node {namespace}'
    if namespace in seen:
        raise FleetError(f'{where}: namespace used twice')
    seen.add(namespace)
    scene = entry.get('scene', defaults.get('scene', 'default'))
    if not isinstance(scene, str):
        raise FleetError(f'{where}: scene: expected a name in config/ or a path')
    if os.sep in scene or scene.endswith(('.yaml', '.yml')):
        scene = os.path.join(base, scene)     # relative to the fleet file
    mode = entry.get('mode', defaults.get('mode', 'real_time'))
    if mode not in MODES:
        raise FleetError(f'{where}: mode: one of {", ".join(MODES)} (got {mode!r})')
    overrides = {**_mapping(defaults.get('overrides'), 'defaults: overrides'),
                 **_mapping(entry.get('overrides'), f'{where}: overrides')}
    params = {**_mapping(defaults.get('params'), 'defaults: params'),
              **_mapping(entry.get('params'), f'{where}: params')}
    unknown = sorted(k for k in params if k not in NODE_PARAMS)   # scene_file too
    if unknown:
        raise FleetError(f'{where}: params: unknown parameter {unknown[0]!r} (scene keys '
                         'go in overrides:)')
    if 'mode' in params or 'real_time' in params:
        raise FleetError(f'{where}: params: set the mode with mode:, not in params:')
    node_host = entry.get('host')
    if node_host is not None and not isinstance(node_host, str):
        raise FleetError(f'{where}: host: expected a host name')
    if check_scenes:
        try:
            load_scene(scene, overrides=overrides)
        except SceneError as exc:
            raise FleetError(f'{where}: {exc}') from None
    name = namespace.strip('/').replace('/', '_')
    return FleetNode(namespace, scene, mode, overrides, params, node_host,
                     os.path.join(folder, name + '.log'), os.path.join(folder, name))


def _nest(flat: dict) -> dict:
    """Nest {'a.b': 1} as {'a': {'b': 1}} (the params-file form of dotted parameter names)."""
    nested: dict = {}
    for key, value in flat.items():
        parts = key.split('.')
        where = nested
        for part in parts[:-1]:
            where = where.setdefault(part, {})
        where[parts[-1]] = value
    return nested


def _die_with_parent():
    """
    In the child: ask for SIGTERM when the fleet process dies, and SIGINT as in a terminal.

    SIGTERM comes even when the fleet process dies by SIGKILL, so no node is left running on
    its own; SIGINT is reset to its default because a background job inherits it ignored.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
    except OSError:
        pass


class Fleet:
    """The running child processes of a fleet (start, forward a signal, wait)."""

    def __init__(self, nodes: list, env: dict | None = None):
        self.nodes = list(nodes)
        self.env = dict(os.environ if env is None else env)
        self.procs: list = []
        self._outputs: list = []
        self._read = [0] * len(self.nodes)     # bytes of each node's log already looked at

    def start(self) -> 'Fleet':
        for node in self.nodes:
            os.makedirs(os.path.dirname(node.log_file), exist_ok=True)
            params_file = node.log_file[:-len('.log')] + '.params.yaml'
            with open(params_file, 'w', encoding='utf-8') as stream:
                yaml.safe_dump({'/**': {'ros__parameters': _nest(node.parameters())}}, stream)
            out = open(node.log_file, 'w', encoding='utf-8')
            self._outputs.append(out)
            # own session: a Ctrl-C in the terminal reaches the fleet process only, which
            # forwards it once to every node
            self.procs.append(subprocess.Popen(
                node.command(params_file), stdout=out, stderr=subprocess.STDOUT, env=self.env,
                stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=_die_with_parent))
        return self

    def signal(self, signum: int) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.send_signal(signum)

    def ready(self) -> list:
        """Return the nodes whose start-up has finished (their log shows the start-up line)."""
        done = []
        for node in self.nodes:
            try:
                with open(node.log_file, encoding='utf-8', errors='replace') as stream:
                    if READY in stream.read():
                        done.append(node)
            except OSError:
                pass
        return done

    def waits(self) -> list:
        """
        Return (node, message) for every wait line the nodes logged since the last call.

        A node logs a line when it has waited ``REPORT_AFTER_S`` for its controller's answers
        (lockstep) or its subscribers (``wait_for_subscribers``), and one when the wait is over
        (det_sim_ros.ros.waiting).
        """
        found = []
        for i, node in enumerate(self.nodes):
            try:
                with open(node.log_file, 'rb') as stream:
                    stream.seek(self._read[i])
                    data = stream.read()
            except OSError:
                continue
            complete = data.rfind(b'\n') + 1      # a line still being written: next time
            self._read[i] += complete
            for line in data[:complete].decode('utf-8', 'replace').splitlines():
                message = line.split(']: ', 1)[-1]
                if message.startswith((WAIT_STARTED, WAIT_OVER)):
                    found.append((node, message))
        return found

    def wait(self, stop_timeout: float) -> list:
        """
        Wait for every process; return the exit codes, in node order (-9: killed).

        Those still running ``stop_timeout`` s after the first call are killed.
        """
        deadline = time.monotonic() + stop_timeout
        codes = []
        for proc in self.procs:
            try:
                codes.append(proc.wait(timeout=max(0.0, deadline - time.monotonic())))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                codes.append(-signal.SIGKILL)
        for out in self._outputs:
            out.close()
        return codes


def _last_line(path):
    try:
        with open(path, encoding='utf-8', errors='replace') as stream:
            lines = [line.strip() for line in stream if line.strip()]
        return lines[-1] if lines else '(empty log)'
    except OSError:
        return '(no log)'


def _watch(fleet: Fleet, stop: dict, out):
    """
    Report the nodes as they start, wait and end waiting, until a stop signal or a node exits.

    Return (node, process) of a node that exited on its own (``stop`` then asks for SIGTERM),
    or None.
    """
    reported = set()
    while not stop['signal']:
        for node in fleet.ready():
            if node.namespace not in reported:
                reported.add(node.namespace)
                print(f'fleet: {node.namespace} running', file=out, flush=True)
        for node, message in fleet.waits():
            print(f'fleet: {node.namespace} {message}', file=out, flush=True)
        exited = [(n, p) for n, p in zip(fleet.nodes, fleet.procs) if p.poll() is not None]
        if exited:        # a node stopped on its own: stop the others
            node, proc = exited[0]
            print(f'fleet: {node.namespace} exited with code {proc.returncode} '
                  f'({_last_line(node.log_file)}); stopping the others', file=out, flush=True)
            stop['signal'] = signal.SIGTERM
            return exited[0]
        time.sleep(0.1)
    return None


def run_fleet(path: str, host: str | None = None, log_dir: str | None = None,
              stop_timeout: float = 20.0, out=None) -> int:
    """
    Run ``det_sim fleet``: start the nodes of ``path`` for ``host`` and wait for them.

    SIGINT and SIGTERM are forwarded to every node. Return 0 when every node stopped with exit
    code 0, else 1.
    """
    out = sys.stderr if out is None else out
    host = host or socket.gethostname()
    nodes = load_fleet(path, host=host, log_dir=log_dir)
    if not nodes:
        raise FleetError(f'{path}: no node runs on host {host!r} (host: keys)')
    stop = {'signal': 0}

    def on_signal(signum, frame):
        stop['signal'] = signum

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    fleet = Fleet(nodes)
    try:
        fleet.start()
        print(f'fleet: started {len(nodes)} node(s) on {host}: '
              + ', '.join(f'{n.namespace} ({n.mode}, pid {p.pid})'
                          for n, p in zip(nodes, fleet.procs))
              + f'; logs in {os.path.dirname(nodes[0].log_file)}', file=out, flush=True)
        early = _watch(fleet, stop, out)
        fleet.signal(stop['signal'])
        codes = fleet.wait(stop_timeout)
    finally:
        fleet.signal(signal.SIGTERM)     # an exception above: leave no node running
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    bad = [(n, c) for n, c in zip(nodes, codes) if c != 0]
    for node, code in bad:
        what = ('killed: not stopped within %g s' % stop_timeout if code == -signal.SIGKILL
                else f'exit code {code}')
        print(f'fleet: {node.namespace}: {what} (log {node.log_file})', file=out, flush=True)
    if not bad:
        print(f'fleet: all {len(nodes)} node(s) stopped cleanly', file=out, flush=True)
    return 1 if bad or early else 0
