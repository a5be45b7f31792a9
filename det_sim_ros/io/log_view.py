"""
A recorded sim_node log served to Foxglove or Lichtblick as if the node were running.

:class:`LogPlayer` reads an MCAP log (one file, split files or a run's directory) once for its
topics, schemas and time range, then plays its messages in file order on a
:class:`~det_sim_ros.io.live_server.LiveServer`, paced by their log times (sim time) at a chosen
speed. The server offers the protocol's playback control: Foxglove's play, pause, seek and
speed buttons drive the player. Playing starts when the first client subscribes (after
``settle_s``, so that all its subscriptions are in), unless it starts paused.

A seek starts reading at the block (MCAP chunk) that holds the time asked for, found in an
index of the blocks' places and first times built in the one pass. The speed is capped so
that at most ``MAX_MESSAGES_PER_S`` messages a wall second are served (:attr:`LogPlayer.
max_speed`, stated when a speed asked for is capped); the time is sent at most
``TIME_RATE_HZ`` times a wall second. A player thread that dies sets :attr:`LogPlayer.failed`.
"""

from __future__ import annotations

import bisect
import os
import threading
import time

import numpy as np

from .live_server import LiveServer, require_sdk
from .log import LogReader

__all__ = ['LogPlayer', 'LogSummary', 'MAX_MESSAGES_PER_S', 'TIME_RATE_HZ']

SETTLE_S = 0.5   # wall s between a client's first subscription and the start of playing
# messages served per wall second at most: below what the player and a client on one core keep
# up with (docs/visualization.md has the rate measured); a 1 kHz node's log, a handful of
# messages a period, plays several times faster than real time
MAX_MESSAGES_PER_S = 50_000
TIME_RATE_HZ = 50      # the time goes to the clients at most this often (wall)


class LogSummary:
    """
    A log's topics (-> type), schemas (type -> ros2msg bytes), time range, duration (ns), size.

    ``reader``: the :class:`LogReader` that read it through (it can start at a block's place);
    ``places`` and ``first_times``: each block's place and its first log time, in file order.
    """

    def __init__(self, paths):
        self.reader = reader = LogReader(paths)
        self.files = reader.files
        self.start = self.end = None
        self.count = 0
        self.places, self.first_times = [], []
        self.duration_ns = 0   # sim time run through: a reset's restart at t = 0 adds none
        previous = None        # the last message's time before this block
        for block in reader.blocks():
            if not block.positions:
                continue
            columns = block.columns()
            times = columns.log_time[np.isin(columns.channel, list(reader.channels))]
            if not len(times):
                continue
            first, last = int(times.min()), int(times.max())
            self.places.append(block.place)
            self.first_times.append(first)
            self.start = first if self.start is None else min(self.start, first)
            self.end = last if self.end is None else max(self.end, last)
            self.count += len(times)
            steps = np.diff(times if previous is None else np.concatenate([[previous], times]))
            self.duration_ns += int(np.sum(np.maximum(steps, 0)))
            previous = int(times[-1])
        if not self.count:
            raise ValueError(f'{", ".join(self.files)}: no readable message'
                             + (f' ({reader.errors[0]})' if reader.errors else ''))
        self.topics = dict(reader.topics)
        self.definitions = dict(reader.definitions)
        self.errors = list(reader.errors)

    def place_before(self, t_ns: int) -> tuple[int, int]:
        """Return the place of the last block that starts before ``t_ns`` (else the first)."""
        index = bisect.bisect_left(self.first_times, t_ns) - 1
        return self.places[max(index, 0)]


class LogPlayer:
    """
    Play a log to the clients of a Foxglove WebSocket server.

    :param paths: the log (a file, files or a directory of split files).
    :param speed: sim seconds per wall second at the start (Foxglove may change it).
    :param paused: wait for a play request instead of playing when a client subscribes.

    :attr:`max_speed`: the fastest it plays (``MAX_MESSAGES_PER_S`` over the log's messages
    per sim second); a faster speed, asked here or by a client, is capped to it.
    ``failed``: why the player thread stopped ('' while it runs).
    """

    def __init__(self, paths, host: str = '127.0.0.1', port: int = 8765, speed: float = 1.0,
                 paused: bool = False, settle_s: float = SETTLE_S):
        require_sdk()
        from foxglove.websocket import PlaybackStatus
        self._status_kind = PlaybackStatus
        self.log = LogSummary(paths)
        span_s = (self.log.end - self.log.start) * 1e-9
        self.max_speed = (MAX_MESSAGES_PER_S * span_s / self.log.count if span_s > 0
                          else float('inf'))
        self.asked_speed = float(speed)
        self.failed = ''
        self._lock = threading.Condition()
        self._speed = self._capped(speed)
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
        self._thread = threading.Thread(target=self._run, name='det_sim view', daemon=True)
        self._thread.start()

    @property
    def speed(self) -> float:
        """Return the speed it plays at now (sim s per wall s)."""
        return self._speed

    def _capped(self, speed: float) -> float:
        return min(max(float(speed), 1e-3), self.max_speed)

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
            self._speed = self._capped(request.playback_speed)   # the state says which
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
        """Yield the messages from ``t_ns`` on, read from the block that holds it."""
        for message in self.log.reader.messages(start=self.log.place_before(t_ns)):
            if message.log_time >= t_ns:
                yield message

    def _run(self) -> None:
        try:
            self._play()
        except Exception as exc:  # noqa: BLE001 - said by the caller (det_sim view exits)
            self.failed = f'{type(exc).__name__}: {exc}'
            self.finished.set()

    def _play(self) -> None:
        messages, anchor = None, None   # anchor: (log time, wall time) that pace the messages
        pending, last_time, seeked, time_sent, served = None, None, False, 0.0, None
        while True:
            state = None   # a playback state to send, after the lock is let go: the SDK's
            with self._lock:   # callbacks take this lock while the SDK holds its own
                if self._stopping:
                    return
                if self._autostart and self._first_subscription is not None \
                        and time.monotonic() - self._first_subscription >= self._settle_s:
                    self._autostart = False
                    self._status = self._status_kind.Playing
                    state = self._state()
                if self._seek_to is not None:
                    messages, anchor, pending = self._messages_from(self._seek_to), None, None
                    self._seek_to, seeked = None, True
                    self.finished.clear()
                playing = self._status == self._status_kind.Playing
                speed = self._speed
            if state is not None:
                self.server.playback_state(state)
            if not playing:
                with self._lock:
                    if self._status != self._status_kind.Playing and self._seek_to is None \
                            and not self._stopping:
                        self._lock.wait(0.05)
                anchor = None
                continue
            message = pending if pending is not None else next(messages, None)
            pending = None
            if message is None:
                with self._lock:
                    if self._seek_to is None:
                        self._status = self._status_kind.Ended
                        self._position = self.log.end
                        state = self._state()
                if state is not None:
                    if served is not None and served != last_time:   # (the time's last word)
                        self.server.time(served, new_session_on_jump=False)
                        last_time = served
                    self.server.playback_state(state)
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
            now = time.monotonic()
            if t != last_time and (seeked or now - time_sent >= 1.0 / TIME_RATE_HZ):
                # (a seek back is not a new session: the client seeked)
                self.server.time(t, new_session_on_jump=not seeked)
                last_time, seeked, time_sent = t, False, now
            self._channels[message.topic].log(message.data, log_time=t)
            self._position = served = t
            self.served += 1
