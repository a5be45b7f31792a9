"""
A recorded sim_node log served to Foxglove or Lichtblick as if the node were running.

:class:`LogPlayer` reads an MCAP log (one file, split files or a run's directory) once for its
topics, schemas and time range, then plays its messages in file order on a
:class:`~det_sim_ros.io.live_server.LiveServer`, paced by their log times (sim time) at a chosen
speed. The server offers the protocol's playback control: Foxglove's play, pause, seek and
speed buttons drive the player. Playing starts when the first client subscribes (after
``settle_s``, so that all its subscriptions are in), unless it starts paused.
"""

from __future__ import annotations

import os
import threading
import time

from .live_server import LiveServer, require_sdk
from .log import LogReader

__all__ = ['LogPlayer', 'LogSummary']

SETTLE_S = 0.5   # wall s between a client's first subscription and the start of playing


class LogSummary:
    """A log's topics (-> type), schemas (-> ros2msg bytes), time range and duration (ns)."""

    def __init__(self, paths):
        reader = LogReader(paths)
        self.files = reader.files
        self.start = self.end = None
        self.count = 0
        self.duration_ns = 0   # sim time run through: a reset's restart at t = 0 adds none
        last = None
        for message in reader.messages():
            t = message.log_time
            self.start = t if self.start is None else min(self.start, t)
            self.end = t if self.end is None else max(self.end, t)
            self.duration_ns += max(0, t - last) if last is not None else 0
            last = t
            self.count += 1
        if not self.count:
            raise ValueError(f'{", ".join(self.files)}: no readable message'
                             + (f' ({reader.errors[0]})' if reader.errors else ''))
        self.topics = dict(reader.topics)
        self.definitions = dict(reader.definitions)
        self.errors = list(reader.errors)


class LogPlayer:
    """
    Play a log to the clients of a Foxglove WebSocket server.

    :param paths: the log (a file, files or a directory of split files).
    :param speed: sim seconds per wall second at the start (Foxglove may change it).
    :param paused: wait for a play request instead of playing when a client subscribes.
    """

    def __init__(self, paths, host: str = '127.0.0.1', port: int = 8765, speed: float = 1.0,
                 paused: bool = False, settle_s: float = SETTLE_S):
        require_sdk()
        from foxglove.websocket import PlaybackStatus
        self._status_kind = PlaybackStatus
        self.log = LogSummary(paths)
        self._paths = paths
        self._lock = threading.Condition()
        self._speed = float(speed)
        self._status = PlaybackStatus.Paused
        self._autostart = not paused
        self._settle_s = settle_s
        self._first_subscription = None   # wall time of a client's first subscription
        self._seek_to = self.log.start    # a seek to apply before the next message
        self._position = self.log.start
        self._stopping = False
        self.served = 0
        self.finished = threading.Event()
        name = 'det_sim view ' + os.path.basename(self.log.files[0])
        self.server = LiveServer(host, port, name=name, listener=self,
                                 playback_range=(self.log.start, self.log.end))
        self._channels = {topic: self.server.channel(topic, type_name,
                                                     self.log.definitions.get(type_name))
                          for topic, type_name in self.log.topics.items()}
        self._thread = threading.Thread(target=self._play, name='det_sim view', daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """Return the server's ws:// address."""
        return self.server.url

    def stop(self) -> None:
        """Stop playing and the server."""
        with self._lock:
            self._stopping = True
            self._lock.notify_all()
        self._thread.join(timeout=2.0)
        self.server.stop()

    # -- the server's callbacks (its threads) ------------------------------------------------
    def on_subscribe(self, client, channel) -> None:
        with self._lock:
            if self._first_subscription is None:
                self._first_subscription = time.monotonic()
                self._lock.notify_all()

    def on_playback_control_request(self, request):
        from foxglove.websocket import PlaybackCommand
        with self._lock:
            self._autostart = False
            self._speed = max(float(request.playback_speed), 1e-3)
            if request.seek_time is not None:
                self._seek_to = min(max(int(request.seek_time), self.log.start), self.log.end)
                self._position = self._seek_to
            playing = request.playback_command == PlaybackCommand.Play
            self._status = self._status_kind.Playing if playing else self._status_kind.Paused
            self._lock.notify_all()
            return self._state(request.request_id, request.seek_time is not None)

    def _state(self, request_id=None, did_seek=False):
        from foxglove.websocket import PlaybackState
        return PlaybackState(self._status, self._position, self._speed, did_seek, request_id)

    # -- the player thread -----------------------------------------------------------------
    def _messages_from(self, t_ns: int):
        for message in LogReader(self._paths).messages():
            if message.log_time >= t_ns:
                yield message

    def _play(self) -> None:
        messages, anchor = None, None   # anchor: (log time, wall time) that pace the messages
        pending, last_time, seeked = None, None, False
        while True:
            with self._lock:
                if self._stopping:
                    return
                if self._autostart and self._first_subscription is not None \
                        and time.monotonic() - self._first_subscription >= self._settle_s:
                    self._autostart = False
                    self._status = self._status_kind.Playing
                    self.server.playback_state(self._state())
                if self._seek_to is not None:
                    messages, anchor, pending = self._messages_from(self._seek_to), None, None
                    self._seek_to, seeked = None, True
                    self.finished.clear()
                if self._status != self._status_kind.Playing:
                    self._lock.wait(0.05)
                    anchor = None
                    continue
                speed = self._speed
            message = pending if pending is not None else next(messages, None)
            pending = None
            if message is None:
                with self._lock:
                    if self._seek_to is None:
                        self._status = self._status_kind.Ended
                        self._position = self.log.end
                        self.server.playback_state(self._state())
                        self.finished.set()
                continue
            t = message.log_time
            if anchor is None:
                anchor = (t, time.monotonic())
            due = anchor[1] + (t - anchor[0]) * 1e-9 / speed
            with self._lock:
                while not self._stopping and self._seek_to is None \
                        and self._status == self._status_kind.Playing \
                        and self._speed == speed and (wait := due - time.monotonic()) > 0:
                    self._lock.wait(wait)
                if self._stopping or self._seek_to is not None:
                    continue
                if self._status != self._status_kind.Playing or self._speed != speed:
                    pending, anchor = message, None   # paused or a new speed: pace it anew
                    continue
            if t != last_time:   # (a seek back is not a new session: the client seeked)
                self.server.time(t, new_session_on_jump=not seeked)
                last_time, seeked = t, False
            self._channels[message.topic].log(message.data, log_time=t)
            self._position = t
            self.served += 1
