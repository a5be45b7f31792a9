"""
Start-up check that no other node of this node's fully qualified name is in the ROS graph.

Two nodes of one name (a fleet or a node started twice) would publish on the same topics and
answer the same services, and a controller could not tell them apart. Discovery is not
instant: with Fast DDS on the localhost discovery range a new process sees an already running
participant from 0.1 s up to 3.1 s after ``rclpy.init`` (the running one announces itself every
3 s). Waiting that long before the first sample would cost every start 3.4 s, so the node looks
once when it is created and then keeps watching for :data:`DISCOVERY_WINDOW_S` while it runs; a
duplicate found in that window stops it with the same one-line refusal.
"""

from __future__ import annotations

import time
import weakref

from rclpy.clock import Clock, ClockType

from ..scenes.scene import SceneError

__all__ = ['DISCOVERY_WINDOW_S', 'check_unique_name', 'note_node_created']

DISCOVERY_WINDOW_S = 3.5   # s after the context's first node: Fast DDS's 3 s announcements
POLL_S = 0.05              # s between two looks at the graph

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
    Refuse a duplicate now, and watch for one during the discovery window.

    A duplicate already in the graph raises :class:`SceneError` at once (nothing was published).
    Until :data:`DISCOVERY_WINDOW_S` after the context's first node a steady timer looks again
    every :data:`POLL_S`: a duplicate found then is put in ``node.refusal``, which the spin loop
    of ``sim_node``'s main raises (one FATAL line, the log finished, exit 1). With ``allow`` the
    node never refuses, and logs one warning if it finds one.
    """
    note_node_created(node.context)
    deadline = _first_node_time[node.context] + DISCOVERY_WINDOW_S
    if not allow and _others(node) > 0:
        raise SceneError(_refusal(node))
    timer = None

    def look():
        found = _others(node) > 0
        if found or time.monotonic() >= deadline:
            timer.cancel()
        if found and not allow:
            node.refusal = SceneError(_refusal(node))
        elif found:
            node.get_logger().warning(_refusal(node).split(';')[0] + ' (allow_duplicate_name '
                                      'is true: started anyway)')
    timer = node.create_timer(POLL_S, look, clock=Clock(clock_type=ClockType.STEADY_TIME))
