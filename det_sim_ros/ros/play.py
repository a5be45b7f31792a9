"""
Republishing MCAP run logs on a ROS graph with their recorded timing.

This is ``det_sim replay play`` and ``det_sim_replay play``: a controller can be tested
against a recorded run.

The offline half of replay (re-simulation, offline recording) is det_sim_ros.io.replay; its
public names are re-exported here, so that one import gives both halves.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable, Iterable

from ..io.cdr import message_class
from ..io.log import LogReader
from ..io.replay import (COMMAND_TOPICS, OUTPUT_FIELDS, OutputContract, ResimResult,
                         resimulate, rest_shortening, rest_shortenings, simulate_to_log)

__all__ = ['play', 'PlayStats', 'qos_from_yaml', 'message_class',
           # re-exported from det_sim_ros.io.replay
           'OUTPUT_FIELDS', 'COMMAND_TOPICS', 'ResimResult', 'resimulate', 'simulate_to_log',
           'OutputContract', 'rest_shortening', 'rest_shortenings']

NODE_NAME = 'det_sim_replay'


@dataclasses.dataclass
class PlayStats:
    """What :func:`play` published."""

    published: dict[str, int] = dataclasses.field(default_factory=dict)
    clock: int = 0
    loops: int = 0
    # (wall seconds since the pass started, log time ns) of each published message, per pass
    schedule: list[tuple[float, int]] = dataclasses.field(default_factory=list)
    unknown_types: list[str] = dataclasses.field(default_factory=list)


def qos_from_yaml(text: str | None):
    """Build an rclpy QoSProfile from ``offered_qos_profiles`` YAML (empty: reliable, depth 10)."""
    import yaml
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
    profiles = yaml.safe_load(text) if text else None
    if not profiles:
        return QoSProfile(depth=10)
    first = profiles[0]

    def policy(enum, value, default):
        if isinstance(value, int):
            return enum(value)
        try:
            return enum[str(value).upper()]
        except KeyError:
            return default

    return QoSProfile(
        history=policy(HistoryPolicy, first.get('history'), HistoryPolicy.KEEP_LAST),
        depth=max(1, int(first.get('depth', 10) or 10)),
        reliability=policy(ReliabilityPolicy, first.get('reliability'),
                           ReliabilityPolicy.RELIABLE),
        durability=policy(DurabilityPolicy, first.get('durability'), DurabilityPolicy.VOLATILE))


def play(log, node=None, rate: float = 1.0, start_offset: float = 0.0, loop: bool = False,
         clock: bool = False, topics: Iterable[str] | None = None, max_loops: int | None = None,
         sleep: Callable[[float], None] = time.sleep,
         now: Callable[[], float] = time.monotonic) -> PlayStats:
    """
    Republish a log's messages (raw CDR) with their recorded timing.

    The message with log time t is published no earlier than (t - t_start) / rate after the
    pass started (``rate <= 0`` or inf: as fast as possible); t_start is the first log time
    plus ``start_offset`` seconds. With ``clock``, /clock (rosgraph_msgs/Clock) is published
    with each new log time before the messages at that time, and a logged /clock is skipped.
    Needs ``rclpy.init()``; creates a node ``det_sim_replay`` unless ``node`` is given.
    """
    import rclpy
    own_node = node is None
    if own_node:
        node = rclpy.create_node(NODE_NAME)
    player = _Player(node, rate, start_offset, clock, topics, sleep, now)
    try:
        while player.play_pass(LogReader(log)):
            player.stats.loops += 1
            if not loop or (max_loops is not None and player.stats.loops >= max_loops):
                break
        return player.stats
    finally:
        if own_node:
            node.destroy_node()


class _Player:
    """
    Publishes one log pass after another through one node.

    It keeps a publisher per topic (made on first use with the logged QoS), publishes /clock
    from the log time, and keeps the recorded timing.
    """

    def __init__(self, node, rate, start_offset, clock, topics, sleep, now):
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        self.node = node
        self.context = node.context
        self.stats = PlayStats()
        self.rate = rate
        self.start_offset = start_offset
        self.fast = not rate or rate <= 0 or math.isinf(rate)
        self.wanted = (None if topics is None
                       else {t if t.startswith('/') else '/' + t for t in topics})
        self.clock = clock
        self._clock_message = Clock
        self._clock_pub = None
        if clock:
            self._clock_pub = node.create_publisher(
                Clock, '/clock', QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self._publishers = {}
        self.sleep, self.now = sleep, now

    def play_pass(self, reader) -> bool:
        """Publish the log once; False if the context was shut down meanwhile."""
        start_ns = wall0 = last_clock = None
        for message in reader.messages():
            if not self.context.ok():
                return False
            if start_ns is None:
                start_ns = message.log_time + round(self.start_offset * 1e9)
            if not self._wanted(message, start_ns):
                continue
            if wall0 is None:
                wall0 = self.now()
            if not self.fast:
                self._wait_until(wall0 + (message.log_time - start_ns) / 1e9 / self.rate)
            if self._clock_pub is not None and message.log_time != last_clock:
                self._publish_clock(message.log_time)
                last_clock = message.log_time
            publisher = self._publisher(message, reader)
            if publisher is None:
                continue
            publisher.publish(message.data)
            published = self.stats.published
            published[message.topic] = published.get(message.topic, 0) + 1
            self.stats.schedule.append((self.now() - wall0, message.log_time))
        return True

    def _wanted(self, message, start_ns) -> bool:
        if message.log_time < start_ns:
            return False
        if self.wanted is not None and message.topic not in self.wanted:
            return False
        return not (self.clock and message.topic == '/clock')

    def _wait_until(self, target: float) -> None:
        while self.context.ok():
            remaining = target - self.now()
            if remaining <= 0:
                break
            self.sleep(min(remaining, 0.05))

    def _publish_clock(self, log_time: int) -> None:
        stamp = self._clock_message()
        stamp.clock.sec, stamp.clock.nanosec = divmod(log_time, 1_000_000_000)
        self._clock_pub.publish(stamp)
        self.stats.clock += 1

    def _publisher(self, message, reader):
        """Return the topic's publisher; None for a type this install does not have."""
        publisher = self._publishers.get(message.topic)
        if publisher is None:
            try:
                cls = message_class(message.type_name)
            except Exception:  # noqa: BLE001 - a type this install does not have
                self._publishers[message.topic] = False
                self.stats.unknown_types.append(message.type_name)
                self.node.get_logger().warning(
                    f'skipping {message.topic}: type {message.type_name} not available')
                return None
            publisher = self.node.create_publisher(
                cls, message.topic, qos_from_yaml(reader.qos.get(message.topic)))
            self._publishers[message.topic] = publisher
        return None if publisher is False else publisher
