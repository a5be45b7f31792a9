"""
The two places the package reaches past rclpy's public API, checked against rclpy 7.1.5 (Jazzy).

Every other module uses rclpy's public API only (test_library_seams scans imports and attribute
access for it); an rclpy upgrade has this one module to re-check (test_rclpy_facade runs both
uses against the installed rclpy and names the version they were checked against).

- :data:`RCLError`: the error rclpy raises when rcl fails (``--ros-args`` it cannot parse, a
  context shut down mid-call). rclpy 7.1 exports it only from its pybind11 module; the node's
  start-up tells it apart from a bug (one line and exit 1, not a traceback).
- :func:`take_serialized`: the bytes of one message waiting in a raw subscription, taken now.
  The node runs several control periods in one timer callback (a free-run tick, a real-time
  catch-up) and applies the commands that arrived between two of them to the next period; the
  executor would deliver them only after the whole callback (test_node_io's catch-up test
  applies a command after the burst's 5th of 40 periods: through the executor alone it lands
  35 periods late). rclpy 7.1 has no public call that takes a message outside an executor.
"""

from __future__ import annotations

from rclpy._rclpy_pybind11 import RCLError

__all__ = ['CHECKED_AGAINST', 'RCLError', 'take_serialized']

CHECKED_AGAINST = '7.1.5'   # the rclpy version (importlib.metadata) these uses were checked on


def take_serialized(subscription) -> bytes | None:
    """
    Return the serialized bytes of the next message waiting in ``subscription``, or None.

    ``subscription`` was created with ``raw=True``; a message taken here never reaches the
    subscription's callback.
    """
    taken = subscription.handle.take_message(subscription.msg_type, True)
    return None if taken is None else taken[0]
