"""
One running node per fully qualified name, settled before the node publishes anything.

Two nodes of one name (a fleet or a node started twice) would publish on the same topics and
answer the same services, and a controller could not tell them apart; a duplicate's samples
(from t = 0 again) would reach a running controller. So the name is settled before the node
creates any other publisher or steps.

Each node claims its name as soon as it exists, on the hidden topic ``~/_name_claim``
(reliable, transient local: a node that comes later still receives it): it announces its start
time and a random instance id, and listens there for the others'. The older claim wins, by
(start time, instance id): every node orders two claims the same way, so of two or more nodes
of one name exactly one goes on, whichever hears the other first, and a running node is never
the one refused. :meth:`NameClaim.settle` then waits for the others' claims while the scene is
prepared and for at least :data:`SETTLE_S` after the claim (how late a running node's claim
arrives, in steps of sim_node's announcement period: docs/topics.md), longer while claim
writers have matched whose claims have not arrived yet. A refused node raises before it
publishes. A claim heard later still stops the node (:attr:`NameClaim.refusal`, read by the
spin loop). With ``allow_duplicate_name`` there is no wait: one warning when another claim is
heard, and the node goes on.
"""

from __future__ import annotations

import os
import time
import weakref

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

__all__ = ['CLAIM_TOPIC', 'Claim', 'NameClaim', 'SETTLE_S', 'SETTLE_MAX_S', 'younger']

CLAIM_TOPIC = '~/_name_claim'
SETTLE_S = 0.75      # s after the claim before the node may publish (see the module doc)
SETTLE_MAX_S = 3.0   # s at most, while matched claim writers have not been heard yet


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

    ``refusal`` is '' while the node may run, else the one line it stops with. ``allow``:
    whether a duplicate only warns (None: not known yet, :meth:`settle` says).
    """

    def __init__(self, node, allow: bool | None = None):
        self.claim = Claim(time.time_ns(), int.from_bytes(os.urandom(8), 'little'))
        self.refusal = ''
        self._claimed_at = time.monotonic()
        self._heard_claims = set()
        self._older_heard = False
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

    def settle(self, allow: bool) -> str:
        """
        Wait until the name is settled; return the refusal ('' : the node may go on).

        Without ``allow``: spin the node's callbacks (only its claim subscription and
        parameter services exist yet) until an older claim is heard, or :data:`SETTLE_S` after
        the claim has passed and every matched claim writer has been heard (at most
        :data:`SETTLE_MAX_S`). With ``allow`` it returns at once.
        """
        self._allow = allow
        if self._older_heard:
            self._answer_older()
        node = self._node()
        if allow or node is None or self.refusal:
            return self.refusal
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
        try:
            while not self.refusal:
                waited = time.monotonic() - self._claimed_at
                unheard = self._subscription.get_publisher_count() > len(self._heard_claims)
                if waited >= SETTLE_MAX_S or (waited >= SETTLE_S and not unheard):
                    break
                executor.spin_once(timeout_sec=0.02 if waited >= SETTLE_S
                                   else min(0.02, SETTLE_S - waited))
        finally:
            executor.remove_node(node)
            executor.shutdown(timeout_sec=0.0)
        return self.refusal

    def _heard(self, msg) -> None:
        other = Claim.parse(msg.data)
        if other is None:
            return
        self._heard_claims.add(other)
        if younger(self.claim, other):
            self._older_heard = True
            if self._allow is not None:
                self._answer_older()

    def _answer_older(self) -> None:
        """Another node of this name is older: refuse, or warn once when allowed."""
        node = self._node()
        if node is None or self.refusal or self._warned:
            return
        if self._allow:
            self._warned = True
            node.get_logger().warning(_refusal(node).split(';')[0]
                                      + ' (allow_duplicate_name is true: started anyway)')
        else:
            self.refusal = _refusal(node)
