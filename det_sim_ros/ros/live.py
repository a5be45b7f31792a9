"""
sim_node's live view: what the node publishes, served to Foxglove or Lichtblick over WebSocket.

With ``live.enabled`` the node runs a Foxglove WebSocket server
(:class:`det_sim_ros.io.live_server.LiveServer`, the ``live`` extra) beside DDS. It serves
every output topic, the truth topics, ``markers`` and ``/diagnostics`` under the node's
resolved topic names, as the same CDR bytes DDS and the log get, and the sim time. While no
client subscribes a period costs one flag test. A client may publish voltage commands (JSON or
CDR; checked as DDS commands are), call the node's services (JSON requests) and get and set its
parameters. Everything a client asks runs on the node's executor thread (a short poll timer),
never on the server's threads, through a bounded queue (a full queue refuses; a request not
run within ``ANSWER_TIMEOUT_S`` is cancelled and never runs; one that started and has not
finished within twice that is told pending, and its outcome follows as a status). Refused,
clamped and failed requests are told to the clients as status messages; refusals, timeouts,
failures and samples dropped are counted on /diagnostics (``live_*`` keys), and so are the
clients' subscriptions and command channels. docs/visualization.md has the details.
"""

from __future__ import annotations

from array import array
import json
import threading
import time

from diagnostic_msgs.msg import KeyValue
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message

from ..io.contract import COMMAND_TOPICS, DIAGNOSTICS_TOPIC, JOINT_STATE, stamp_ns, TOPIC_TYPES
from ..io.live_queues import Busy, CallQueue, Pending, SampleQueue
from ..io.live_server import ClientCommands, LiveServer, LiveUnavailable, require_sdk
from ..io.schemas import type_name_of
from ..scenes.scene import SceneError

__all__ = ['LiveView', 'open_live_view', 'POLL_S', 'FLUSH_S', 'ANSWER_TIMEOUT_S',
           'QUEUE_REQUESTS', 'QUEUE_SAMPLES']

POLL_S = 0.02             # wall s between two looks at what clients asked (commands, calls)
FLUSH_S = 0.02            # wall s between two bursts of messages to the clients (50 Hz)
QUEUE_SAMPLES = 5000      # samples waiting for the sender at most (then the oldest go)
ANSWER_TIMEOUT_S = 5.0    # a service call or parameter request the node has not run by then fails
# client requests waiting for the executor at most (then refused): a poll runs them all, and
# at tens of us each 64 cost the node's executor ~2 ms per poll
QUEUE_REQUESTS = 64
STATUS_REPEAT_S = 1.0     # wall s: the same status text is sent to the clients once per this
_HIDDEN_SERVICE_PACKAGES = ('rcl_interfaces',)   # parameters: the Parameters capability


def open_live_view(node) -> 'LiveView | None':
    """
    Start the node's live view from its ``live.*`` parameters; None when ``live.enabled`` is off.

    Raise :class:`SceneError` with one line if it cannot start (no ``live`` extra, port in use).
    """
    get = node.get_parameter
    if not get('live.enabled').value:
        return None
    try:
        require_sdk()
        view = LiveView(node, get('live.host').value, get('live.port').value,
                        get('live.rate_hz').value)
    except LiveUnavailable as exc:
        name = 'live.enabled' if 'foxglove-sdk' in str(exc) else 'live.port'
        raise SceneError(f'parameter {name}: {exc}') from None
    node.get_logger().info(
        f'live view on {view.url}: in Foxglove or Lichtblick, Open connection > Foxglove '
        f'WebSocket > {view.url} (or open {view.app_url})')
    return view


class _DiagnosticsTap:
    """The /diagnostics publisher: the live view's counters added, every message served live."""

    def __init__(self, publisher, view: 'LiveView'):
        self._publisher, self._view = publisher, view

    def publish(self, msg) -> None:
        if msg.status:
            msg.status[0].values.extend(KeyValue(key=key, value=value)
                                        for key, value in self._view.counters().items())
        self._publisher.publish(msg)
        self._view.diagnostics(msg)


class _StatusThrottle:
    """Lets a status text through once per ``period_s`` (a flood of one refusal is one line)."""

    def __init__(self, period_s: float):
        self._period_s = period_s
        self._last: dict[str, float] = {}
        self._lock = threading.Lock()

    def allows(self, text: str) -> bool:
        now = time.monotonic()
        with self._lock:
            if now - self._last.get(text, -self._period_s) < self._period_s:
                return False
            if len(self._last) > 256:   # (old texts: forgotten, not kept forever)
                self._last.clear()
            self._last[text] = now
            return True


class LiveView:
    """
    The node's Foxglove WebSocket server: its channels, client commands, services, parameters.

    :param node: the :class:`~det_sim_ros.ros.node.SimNode` (its publishers, services and
        parameters exist).
    :param rate_hz: output samples served per simulated second (0: every one).
    """

    def __init__(self, node, host: str, port: int, rate_hz: float = 0.0):
        self._node = node
        # sim ns between two served samples (1: every one), and the next one's earliest time
        self._every_ns = int(round(1e9 / rate_hz)) if rate_hz > 0 else 1
        self._next_ns = 0
        self._last_ns = -1     # the last sample's time seen (a reset goes back)
        self._calls = CallQueue(QUEUE_REQUESTS, ANSWER_TIMEOUT_S, on_error=self._failed)
        self._statuses = _StatusThrottle(STATUS_REPEAT_S)
        outputs = node.outputs
        outs, truth = node.output_publishers, node.truth_publishers
        self._commands = ClientCommands({node.command_subscriptions[t].topic_name: t
                                         for t in COMMAND_TOPICS})
        self._server = server = LiveServer(
            host, port, name=node.get_fully_qualified_name(), listener=self,
            services=self._services(node), parameters=True, client_publish=True)
        self.url, self.app_url = server.url, server.app_url
        # one channel per message of a sample, in the order of outputs.encode
        self._sample_channels = (
            [server.channel(outs[t].topic_name, TOPIC_TYPES[t]) for t in outputs.topics]
            + [server.channel(truth[t].topic_name, JOINT_STATE) for t in outputs.sensed])
        markers = node.markers
        self._marker_channel = None
        if markers is not None:
            self._marker_channel = server.channel(markers.publisher.topic_name,
                                                  type_name_of(markers.publisher.msg_type))
            markers.add_viewers(lambda: int(self._marker_channel.has_sinks()))
        self._diagnostics_channel = server.channel(DIAGNOSTICS_TOPIC,
                                                   TOPIC_TYPES[DIAGNOSTICS_TOPIC])
        node.create_timer(POLL_S, self._calls.run_pending, clock=node.steady_clock)
        # the clients' messages go out from a thread of their own, in bursts: a websocket
        # send costs ~1 us in a burst and tens of us alone (the server's thread wakes for it)
        self._samples = SampleQueue(QUEUE_SAMPLES)
        self._stopping = threading.Event()
        self._sender = threading.Thread(target=self._flush_every, args=(FLUSH_S,),
                                        name='live view', daemon=True)
        self._sender.start()
        node.add_post_set_parameters_callback(self._parameters_changed)

    @property
    def port(self) -> int:
        """Return the port the server listens on."""
        return self._server.port

    @property
    def watched(self) -> bool:
        """Return True while some client subscribes to some channel."""
        return self._server.watched

    @property
    def sessions(self) -> int:
        """Return how many sessions the clients have seen (a reset starts a new one)."""
        return self._server.sessions

    def tap(self, publisher) -> _DiagnosticsTap:
        """Return ``publisher`` (/diagnostics) with the live counters, its messages served live."""
        return _DiagnosticsTap(publisher, self)

    def counters(self) -> dict[str, str]:
        """
        Return the live view's counters, as /diagnostics shows them (docs/real_time.md).

        Client requests waiting for the node (now, at most so far, the bound), refused for a
        full queue, timed out (cancelled), answered pending (started, not finished in time),
        failed with an exception; samples waiting for the sender (now, at most so far) and
        dropped from its full queue; the clients' subscriptions and command channels now (a
        client that leaves, however it leaves, takes its own with it).
        """
        calls, samples = self._calls, self._samples
        return {'live_requests_waiting': str(len(calls)), 'live_requests_most': str(calls.most),
                'live_requests_limit': str(calls.limit),
                'live_requests_refused': str(calls.refused),
                'live_requests_timed_out': str(calls.timed_out),
                'live_requests_pending': str(calls.pending),
                'live_request_errors': str(calls.failed),
                'live_samples_waiting': str(len(samples)), 'live_samples_most': str(samples.most),
                'live_samples_dropped': str(samples.dropped),
                'live_subscriptions': str(self._server.subscriptions),
                'live_client_channels': str(len(self._commands))}

    # -- the node's messages ------------------------------------------------------------------
    def send(self, batch) -> None:
        """Queue a batch of (t_ns, sample messages, marker frame or None) for the clients."""
        if self._server.watched:   # (nobody subscribes: nothing to do)
            self._samples.put(batch)

    def _flush_every(self, period_s: float) -> None:
        """Serve what the node queued, every ``period_s`` (the sender thread)."""
        while not self._stopping.wait(period_s):
            self._flush()

    def _flush(self) -> None:
        """Serve the queued samples, marker frames and the time, in order."""
        server, queue = self._server, self._samples.take()
        channels, markers, served = self._sample_channels, self._marker_channel, None
        while queue:
            t_ns, samples, frame = queue.popleft()
            if t_ns < self._last_ns:   # back in time: a reset; clients clear their buffers
                server.restart_time()
                self._next_ns = 0
            self._last_ns = t_ns
            if t_ns >= self._next_ns:
                self._next_ns, served = t_ns + self._every_ns, t_ns
                for channel, data in zip(channels, samples):
                    if data is not None:
                        channel.log(data, log_time=t_ns)
            if frame is not None:
                markers.log(frame, log_time=t_ns)
        if served is not None:   # the time of the last sample served
            server.time(served)

    def diagnostics(self, msg) -> None:
        """Serve a /diagnostics message (stamped with the sim time now)."""
        if self._server.watched:
            sim = self._node.simulator
            self._diagnostics_channel.log(serialize_message(msg),
                                          log_time=stamp_ns(sim.k, sim.dt))

    def close(self) -> None:
        """Stop the sender thread and the server."""
        self._stopping.set()
        self._sender.join(timeout=2.0)
        self._server.stop()

    # -- client publish (server threads) ----------------------------------------------------
    def on_client_advertise(self, client, channel) -> None:
        reason = self._commands.advertise(client.id, channel.id, channel.topic, channel.encoding)
        if reason:
            self._server.status(f'{self._node.get_name()}: {reason}; its messages are ignored')

    def on_client_unadvertise(self, client, client_channel_id: int) -> None:
        self._commands.unadvertise(client.id, client_channel_id)

    def on_message_data(self, client, client_channel_id: int, data: bytes) -> None:
        try:
            topic, cdr = self._commands.command(client.id, client_channel_id, data)
        except ValueError as exc:
            reason = str(exc)
            self._post(lambda: self._node.commands.refuse(reason))
            self._status(f'command refused: {reason}', error=True)
            return
        self._post(lambda: self._apply(topic, cdr))

    def _post(self, work) -> None:
        try:
            self._calls.post(work)
        except Busy as exc:   # counted by the queue (live_requests_refused)
            self._status(f'command refused: {exc}', error=True)

    def _apply(self, topic: str, cdr: bytes) -> None:
        commands = self._node.commands
        refused, clamped = commands.refused, commands.clamped
        commands.apply(topic, cdr)
        if commands.refused != refused:
            self._status(f'command refused: {commands.last_refused}', error=True)
        elif commands.clamped != clamped:   # as the node warns a DDS sender's clamp
            self._status(f'command clamped: {commands.last_clamped}')

    def _failed(self, exc: Exception) -> None:
        """Log a posted work's exception and tell the clients (the executor thread)."""
        text = f'a client request failed: {type(exc).__name__}: {exc}'
        self._node.get_logger().error(text, throttle_duration_sec=1.0)
        self._status(text, error=True)

    def _status(self, text: str, error: bool = False) -> None:
        if self._statuses.allows(text):
            self._server.status(text, error=error)

    # -- services (server threads; run on the executor thread) ------------------------------
    def _services(self, node) -> list:
        from foxglove import Service, ServiceSchema
        services = []
        for service in node.services:
            type_name = type_name_of(service.srv_type)
            if type_name.split('/')[0] in _HIDDEN_SERVICE_PACKAGES:
                continue
            services.append(Service(name=node.resolve_service_name(service.srv_name),
                                    schema=ServiceSchema(name=type_name),
                                    handler=self._service_handler(service)))
        return services

    def _service_handler(self, service):
        def handle(request) -> bytes:
            srv_type = service.srv_type
            message = srv_type.Request()
            fields = json.loads(bytes(request.payload) or b'{}') if request.payload else {}
            if not isinstance(fields, dict):
                raise ValueError('the request must be a JSON object')
            for name, value in fields.items():
                if name not in message.get_fields_and_field_types():
                    raise ValueError(f'{type_name_of(srv_type)} request has no field {name!r}')
                setattr(message, name, value)
            name = _service_name(self._node, service)
            response = self._calls.call(lambda: service.callback(message, srv_type.Response()),
                                        late=lambda ok, value: self._status(
                                            f'{name} finished after its answer: '
                                            + (_fields_json(value) if ok else f'failed: {value}'),
                                            error=not ok))
            return _fields_json(response).encode()
        return handle

    # -- parameters (server threads; run on the executor thread) ----------------------------
    def on_get_parameters(self, client, param_names, request_id=None) -> list:
        try:
            return self._calls.call(lambda: self._values(param_names))
        except (Busy, TimeoutError) as exc:
            self._status(f'parameters not read: {exc}', error=True)
            return []

    def on_set_parameters(self, client, parameters, request_id=None) -> list:
        names = [p.name for p in parameters]
        listed = ', '.join(names)
        try:   # one call: set and read back, so that a timeout leaves nothing half done
            refusals, values = self._calls.call(
                lambda: (self._set(parameters), self._values(names)),
                late=lambda ok, value: self._set_late(listed, ok, value))
        except Pending as exc:   # it goes on: the outcome follows (_set_late)
            self._status(f'parameters pending ({listed}): {exc}')
            return []
        except (Busy, TimeoutError) as exc:   # cancelled: none of them is set
            self._status('parameters not set (' + ', '.join(names) + f'): {exc}', error=True)
            return []
        if refusals:
            self._status('parameters refused: ' + '; '.join(refusals), error=True)
        return values

    def _set_late(self, listed: str, ok: bool, outcome) -> None:
        """Tell the clients how a set they were told pending ended (the executor thread)."""
        if not ok:
            self._status(f'parameters not set ({listed}): {type(outcome).__name__}: '
                         f'{outcome}', error=True)
        elif outcome[0]:
            self._status('parameters refused: ' + '; '.join(outcome[0]), error=True)
        else:
            self._status(f'parameters set ({listed})')

    def _values(self, names) -> list:
        from foxglove import Parameter as LiveParameter
        node = self._node
        names = list(names) or sorted(node.list_parameters([], 0).names)
        found = [name for name in names if node.has_parameter(name)]
        return [LiveParameter(p.name, value=_native(p.value))
                for p in node.get_parameters(found)]

    def _set(self, parameters) -> list[str]:
        node, refusals = self._node, []
        for given in parameters:
            name, value = given.name, given.get_value()
            if not node.has_parameter(name):
                refusals.append(f'{name}: no such parameter')
                continue
            if node.get_parameter(name).type_ == Parameter.Type.DOUBLE and isinstance(value, int) \
                    and not isinstance(value, bool):
                value = float(value)   # a client's JSON writes 2.0 as 2
            try:
                result = node.set_parameters([Parameter(name, value=value)])[0]
            except Exception as exc:  # noqa: BLE001 - a type rclpy refuses, told to the client
                refusals.append(f'{name}: {exc}')
                continue
            if not result.successful:
                refusals.append(f'{name}: {result.reason}')
        return refusals

    def _parameters_changed(self, params) -> None:
        from foxglove import Parameter as LiveParameter
        self._server.publish_parameters([LiveParameter(p.name, value=_native(p.value))
                                         for p in params])


def _service_name(node, service) -> str:
    """Return a service's resolved name (/arm1/sim_node/pause)."""
    return node.resolve_service_name(service.srv_name)


def _fields_json(message) -> str:
    """Return a ROS message's fields as JSON (a service response for a client)."""
    return json.dumps({name: getattr(message, name)
                       for name in message.get_fields_and_field_types()})


def _native(value):
    """Return a parameter value as the SDK takes it (arrays as lists)."""
    return value.tolist() if isinstance(value, array) else (
        list(value) if isinstance(value, (tuple, list)) else value)
