"""
One running node per fully qualified name, settled without delaying the start.

Two nodes of one name (a fleet or a node started twice) would publish on the same topics and
answer the same services, and a controller could not tell them apart. Discovery is not instant
(det_sim_ros.ros.discovery; how long: docs/topics.md), so a look at the graph before
publishing would hold the first sample back by that long.

Instead each node claims its name at once and publishes from the start: on the hidden topic
``~/_name_claim`` (reliable, transient local: a node that comes later still receives it) it
announces its start time and a random instance id, and it listens there for the others'.
The older claim wins, by (start time, instance id): every node orders two claims the same way,
so of two or more nodes of one name exactly one goes on, whichever hears the other first, and a
running node is never the one refused. The younger stops itself with one FATAL line
(:attr:`NameClaim.refusal`, read by the spin loop); with ``allow_duplicate_name`` it logs one
warning and goes on.
"""

from __future__ import annotations

import os
import time
import weakref

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

__all__ = ['CLAIM_TOPIC', 'Claim', 'NameClaim', 'younger']

CLAIM_TOPIC = '~/_name_claim'


class Claim(tuple):
    """(start time in ns since the epoch, random 64-bit instance id): smaller is older."""

    __slots__ = ()

    def __new__(cls, start_ns: int, instance: int):
        return super().__new__(cls, (int(start_ns), int(instance)))

    def text(self) -> str:
        """Return the claim as its message's text: '<start_ns> <instance hex>'."""
        return f'{self[0]} {self[1]:016x}'

    @classmethod
    def parse(cls, text: str) -> 'Claim | None':
        """Return the claim of a message's text, or None if it is not one."""
        try:
            start, instance = text.split()
            return cls(int(start), int(instance, 16))
        except ValueError:
            return None


def younger(mine: Claim, other: Claim) -> bool:
    """Return True if ``mine`` loses to ``other``: it is the later claim (ties: larger id)."""
    return other != mine and other < mine


def _refusal(node) -> str:
    return (f'another node named {node.get_fully_qualified_name()} is running on this ROS '
            'domain (started twice?); stop it, give this one another name or namespace '
            '(--ros-args -r __node:=NAME or -r __ns:=/NAMESPACE), or set '
            'allow_duplicate_name:=true')


class NameClaim:
    """
    The node's claim on its name: announced at once, compared with every other one heard.

    ``refusal`` is '' while the node may run, else the one line it stops with.
    """

    def __init__(self, node, allow: bool):
        self.claim = Claim(time.time_ns(), int.from_bytes(os.urandom(8), 'little'))
        self.refusal = ''
        # weak: the node's subscription holds this object's callback, and a node whose start
        # failed must be freed at once (it holds its logger's /rosout publisher)
        self._node, self._allow, self._warned = weakref.ref(node), allow, False
        # a writer keeps its one claim for the nodes that come later; the reader's history is
        # shared by all writers of the (keyless) topic, so it keeps many: claims that arrive
        # together must not overwrite the older one before it is read
        claim_qos, reader_qos = (QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
                                 for depth in (1, 100))
        self._subscription = node.create_subscription(String, CLAIM_TOPIC, self._heard,
                                                      reader_qos)
        self._publisher = node.create_publisher(String, CLAIM_TOPIC, claim_qos)
        self._publisher.publish(String(data=self.claim.text()))

    def _heard(self, msg) -> None:
        other = Claim.parse(msg.data)
        node = self._node()
        if (node is None or other is None or not younger(self.claim, other) or self.refusal
                or self._warned):
            return
        if self._allow:
            self._warned = True
            node.get_logger().warning(_refusal(node).split(';')[0]
                                      + ' (allow_duplicate_name is true: started anyway)')
        else:
            self.refusal = _refusal(node)
