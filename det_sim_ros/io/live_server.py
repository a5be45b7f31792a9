"""
A Foxglove WebSocket server for sim_node's messages and for recorded logs, without ROS.

It speaks the Foxglove WebSocket protocol (subprotocol ``foxglove.sdk.v1``) through the
``foxglove-sdk`` package (the optional extra ``live``), whose server runs on native threads:
Foxglove and Lichtblick connect to it as a data source. Every channel carries the ROS 2 CDR
bytes the node publishes and the log records, with the type's complete ``ros2msg`` definition
(:func:`det_sim_ros.io.schemas.message_definition`) as schema; time is sent with the protocol's
time capability; a jump back in time (a reset, a seek) starts a new session, so a client clears
its buffers instead of drawing the jump.

Clients may publish voltage commands: JSON as Foxglove's Publish panel sends it
(``{"data": [2500]}`` on voltage_command, ``{"name": [...], "position": [...]}`` on
voltage_command_joint) or CDR; :func:`command_bytes` turns either into the CDR bytes a DDS
command carries, so the node checks them as it checks those.
"""

from __future__ import annotations

import json
import threading

from .contract import COMMAND_TOPIC, JOINT_COMMAND_TOPIC
from .messages import encode_float64_multi_array, encode_joint_state
from .schemas import message_definition

__all__ = ['EXTRA_HINT', 'LiveUnavailable', 'require_sdk', 'LiveServer', 'ClientCommands',
           'command_bytes', 'foxglove_url']

EXTRA_HINT = "install the extra 'live': pip install 'det_sim_ros[live]'"
# per client: messages queued before its oldest is dropped (the SDK's default); a stalled
# client loses its oldest samples, the node never waits for it
BACKLOG = 1024


class LiveUnavailable(RuntimeError):
    """The live view cannot start (no foxglove-sdk, a port in use, ...): a one-line reason."""


def require_sdk():
    """Return the foxglove module; :class:`LiveUnavailable` naming the extra without it."""
    try:
        import foxglove
        import foxglove.websocket
    except ImportError:
        raise LiveUnavailable(f'the live view needs foxglove-sdk: {EXTRA_HINT}') from None
    return foxglove


def foxglove_url(host: str, port: int) -> str:
    """Return the address to give Foxglove's 'Open connection' (Foxglove WebSocket)."""
    return f"ws://{'127.0.0.1' if host in ('', '0.0.0.0') else host}:{port}"


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _numbers(payload: dict, key: str, topic: str) -> list:
    values = payload.get(key, [])
    if not isinstance(values, list) or not all(_number(v) for v in values):
        raise ValueError(f'{topic}: JSON field {key!r} must be a list of numbers '
                         f'(got {json.dumps(values)[:80]})')
    return [float(v) for v in values]


def command_bytes(topic: str, payload: bytes, encoding: str) -> bytes:
    """
    Return the CDR bytes of a client's command on ``topic`` (a command topic's last name).

    ``encoding`` 'cdr' passes the bytes through; 'json' builds the message from the fields a
    DDS publisher would set: ``data`` (voltage_command), ``name`` and ``position``
    (voltage_command_joint); NaN and infinities pass on to the node's checks. Raise
    ValueError with the reason for anything else.
    """
    if encoding == 'cdr':
        return bytes(payload)
    if encoding != 'json':
        raise ValueError(f'{topic}: message encoding {encoding!r} not accepted (json or cdr)')
    try:
        message = json.loads(bytes(payload).decode('utf-8'))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f'{topic}: not JSON ({exc})') from None
    if not isinstance(message, dict):
        raise ValueError(f'{topic}: JSON must be an object such as '
                         + ('{"data": [2500]}' if topic == COMMAND_TOPIC else
                            '{"name": ["det0"], "position": [2500]}'))
    if topic == COMMAND_TOPIC:
        if 'data' not in message:
            raise ValueError(f'{topic}: JSON needs "data": one voltage per DET, e.g. '
                             '{"data": [2500]}')
        return encode_float64_multi_array(_numbers(message, 'data', topic))
    if topic == JOINT_COMMAND_TOPIC:
        names = message.get('name', [])
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise ValueError(f'{topic}: JSON field "name" must be a list of strings')
        return encode_joint_state(names, _numbers(message, 'position', topic),
                                  _numbers(message, 'velocity', topic),
                                  _numbers(message, 'effort', topic))
    raise ValueError(f'{topic}: not a command topic')


class ClientCommands:
    """
    The command channels clients advertised: (client, channel) -> (command topic, encoding).

    :param topics: resolved topic name -> command topic (voltage_command, ...); a client may
        also advertise the last name alone.
    """

    def __init__(self, topics: dict[str, str]):
        self._topics = dict(topics)
        self._topics.update({name: name for name in topics.values()})
        self._channels: dict[tuple[int, int], tuple[str, str]] = {}

    def advertise(self, client: int, channel: int, topic: str, encoding: str) -> str:
        """Note a client's channel; return why it is not a command channel ('' if it is)."""
        command = self._topics.get(topic)
        if command is None:
            return (f'{topic}: not a command topic of this node (accepted: '
                    + ', '.join(sorted(t for t in self._topics if t.startswith('/'))) + ')')
        self._channels[(client, channel)] = (command, encoding)
        return ''

    def __len__(self) -> int:
        """Return how many command channels the clients have advertised now."""
        return len(self._channels)

    def unadvertise(self, client: int, channel: int) -> None:
        """Forget a client's channel."""
        self._channels.pop((client, channel), None)

    def command(self, client: int, channel: int, payload: bytes) -> tuple[str, bytes]:
        """Return (command topic, CDR bytes) of a client's message; ValueError: the reason."""
        found = self._channels.get((client, channel))
        if found is None:
            raise ValueError(f'client channel {channel}: not an advertised command topic')
        topic, encoding = found
        return topic, command_bytes(topic, payload, encoding)


class LiveServer:
    """
    One Foxglove WebSocket server and its channels (ROS 2 CDR with ros2msg schemas).

    :param host, port: where to listen (port 0: a free port; :attr:`port` says which).
    :param listener: an object with any of foxglove's ``ServerListener`` methods (client
        messages, parameters, playback); subscriptions are counted here first.
    :param services: foxglove ``Service`` objects (the Services capability is offered if any).
    :param parameters: offer the Parameters capability.
    :param client_publish: offer the ClientPublish capability (JSON and CDR).
    :param playback_range: (start, end) ns of a recorded log: offer PlaybackControl.
    """

    def __init__(self, host: str, port: int, *, name: str = 'det_sim_ros', listener=None,
                 services=(), parameters: bool = False, client_publish: bool = False,
                 playback_range: tuple[int, int] | None = None):
        foxglove = require_sdk()
        from foxglove.websocket import Capability
        self._foxglove = foxglove
        self._context = foxglove.Context()   # this server's channels only
        self._subscribed: set[tuple[int, int]] = set()
        self._lock = threading.Lock()
        self.watched = False         # some client subscribes to some channel
        self._last_time = None
        self.sessions = 1
        capabilities = [Capability.Time]
        if client_publish:
            capabilities.append(Capability.ClientPublish)
        if parameters:
            capabilities.append(Capability.Parameters)
        if services:
            capabilities.append(Capability.Services)
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, capabilities=capabilities,
                server_listener=_Listener(self, listener),
                supported_encodings=['json', 'cdr'], services=list(services) or None,
                context=self._context, playback_time_range=playback_range,
                message_backlog_size=BACKLOG)
        except RuntimeError as exc:   # FoxgloveError: Failed to bind port: Address in use ...
            text = str(exc).split('FoxgloveError: ', 1)[-1]
            raise LiveUnavailable(f'cannot listen on {host}:{port} ({text})') from None
        self.host = host
        self.port = self._server.port
        self.url = foxglove_url(host, self.port)

    @property
    def subscriptions(self) -> int:
        """Return how many (client, channel) subscriptions there are now."""
        with self._lock:
            return len(self._subscribed)

    @property
    def app_url(self) -> str:
        """Return the Foxglove web app's address that opens this server as its data source."""
        return self._server.app_url() or ''

    def channel(self, topic: str, type_name: str, schema: bytes | None = None):
        """Return a new CDR channel of ``type_name`` (schema: the log's, else the .msg text)."""
        data = schema if schema is not None else message_definition(type_name).encode()
        return self._foxglove.Channel(
            topic, schema=self._foxglove.Schema(name=type_name, encoding='ros2msg', data=data),
            message_encoding='cdr', context=self._context)

    def time(self, t_ns: int, new_session_on_jump: bool = True) -> None:
        """Send the time; a time before the last starts a new session (clients clear)."""
        last = self._last_time
        if new_session_on_jump and last is not None and t_ns < last:
            self._server.clear_session()
            self.sessions += 1
        self._last_time = t_ns
        self._server.broadcast_time(t_ns)

    def restart_time(self) -> None:
        """Start a new session now (clients clear their buffers), e.g. before a seek."""
        self._server.clear_session()
        self.sessions += 1
        self._last_time = None

    def status(self, message: str, error: bool = False) -> None:
        """Show a status message in the clients (a refused command, a bad channel)."""
        level = self._foxglove.StatusLevel
        self._server.publish_status(message, level.Error if error else level.Warning)

    def publish_parameters(self, parameters) -> None:
        """Send parameter values to the clients that subscribed to them."""
        self._server.publish_parameter_values(parameters)

    def playback_state(self, state) -> None:
        """Send a playback state (a foxglove ``PlaybackState``) to every client."""
        self._server.broadcast_playback_state(state)

    def subscribed(self, client: int, channel: int, on: bool) -> None:
        """Count a client's subscription (the listener calls it on the SDK's thread)."""
        with self._lock:
            (self._subscribed.add if on else self._subscribed.discard)((client, channel))
            self.watched = bool(self._subscribed)

    def stop(self) -> None:
        """Stop the server (clients see the connection close)."""
        self._server.stop()


def _listener_base():
    from foxglove.websocket import ServerListener
    return ServerListener


class _Listener:
    """Count subscriptions, then hand every callback to the owner's listener (if it has it)."""

    def __init__(self, server: LiveServer, owner):
        self._server, self._owner = server, owner
        self._default = _listener_base()

    def __getattr__(self, name):
        handler = getattr(self._owner, name, None)
        return handler if handler is not None else getattr(self._default, name).__get__(self)

    def on_subscribe(self, client, channel) -> None:
        self._server.subscribed(client.id, channel.id, True)
        if hasattr(self._owner, 'on_subscribe'):
            self._owner.on_subscribe(client, channel)

    def on_unsubscribe(self, client, channel) -> None:
        self._server.subscribed(client.id, channel.id, False)
        if hasattr(self._owner, 'on_unsubscribe'):
            self._owner.on_unsubscribe(client, channel)
