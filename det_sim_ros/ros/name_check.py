"""
Start-up check that no other node of this node's fully qualified name is in the ROS graph.

Two nodes of one name (a fleet or a node started twice) would publish on the same topics and
answer the same services, and a controller could not tell them apart. Discovery is not instant.
A running ``sim_node`` announces itself every 0.1 s for its first 2 s, every 0.25 s after
(det_sim_ros.ros.discovery); a new participant then saw it at most 0.61 s after its creation
(280 creations, one to three at a time, 90 of them beside a busy core, the running node past
its first 2 s, localhost discovery range). At Fast DDS's own 3 s period 12 of 60 took more than
0.75 s, one 3.0 s, and the check would have let those duplicates start. So the check looks
until :data:`DISCOVERY_WINDOW_S` after the node's creation, the scene's preparation included,
before anything is published; only the newcomer looks, so the running node is never the one
refused.
"""

from __future__ import annotations

import time
import weakref

from rclpy.clock import Clock, ClockType

from ..scenes.scene import SceneError

__all__ = ['DISCOVERY_WINDOW_S', 'check_unique_name', 'note_node_created']

DISCOVERY_WINDOW_S = 0.75  # s after the context's first node: 1.2x the longest discovery seen
POLL_S = 0.05              # s between two looks at the graph
# an allowed duplicate is only warned about, which delays nothing: that look goes on past a
# Fast DDS default announcement period (3 s), for a running node past its early announcements
WARN_WINDOW_S = 3.5        # s after the context's first node
WARN_POLL_S = 0.25         # s between two of those looks

_first_node_time = weakref.WeakKeyDictionary()   # context -> monotonic time of its first node


def note_node_created(context) -> None:
    """Note when ``context`` got its first node (discovery runs from then on)."""
    _first_node_time.setdefault(context, time.monotonic())


def _others(node) -> int:
    """Return how many other nodes of ``node``'s name and namespace the graph holds."""
    me = (node.get_name(), node.get_namespace())
    return node.get_node_names_and_namespaces().count(me) - 1


def _refusal(node) -> str:
    return (f'another node named {node.get_fully_qualified_name()} is running on this ROS '
            'domain (started twice?); stop it, give this one another name or namespace '
            '(--ros-args -r __node:=NAME or -r __ns:=/NAMESPACE), or set '
            'allow_duplicate_name:=true')


def check_unique_name(node, allow: bool) -> None:
    """
    Refuse to start (:class:`SceneError`) when another node of this name is in the graph.

    Without ``allow`` this looks until :data:`DISCOVERY_WINDOW_S` after the context's first
    node (at once when a duplicate shows up); with ``allow`` it does not wait, and a timer logs
    a warning when it finds one, until :data:`WARN_WINDOW_S`.
    """
    note_node_created(node.context)
    if allow:
        _warn_when_seen(node, _first_node_time[node.context] + WARN_WINDOW_S)
        return
    deadline = _first_node_time[node.context] + DISCOVERY_WINDOW_S
    while True:
        if _others(node) > 0:
            raise SceneError(_refusal(node))
        left = deadline - time.monotonic()
        if left <= 0.0:
            return
        time.sleep(min(POLL_S, left))


def _warn_when_seen(node, give_up: float) -> None:
    """Log one warning when another node of this name shows up in the graph before ``give_up``."""
    timer = None

    def look():
        if _others(node) > 0:
            timer.cancel()
            node.get_logger().warning(_refusal(node).split(';')[0] + ' (allow_duplicate_name '
                                      'is true: started anyway)')
        elif time.monotonic() >= give_up:
            timer.cancel()
    timer = node.create_timer(WARN_POLL_S, look, clock=Clock(clock_type=ClockType.STEADY_TIME))
