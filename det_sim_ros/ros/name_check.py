"""
One running node per fully qualified name, settled before the node publishes anything.

Two nodes of one name (a fleet or a node started twice) would publish on the same topics and
answer the same services, and a controller could not tell them apart; a duplicate's samples
(from t = 0 again) would reach a running controller. So the name is settled before the node
creates any other publisher or steps, in two parts.

On this host, at once: the node takes the host's lock on (ROS domain id, fully qualified name)
(:class:`~det_sim_ros.ros.host_lock.HostNameLock`: one network namespace, released when the
process ends, SIGKILL included). A node that finds it held by another process is a duplicate on
this host and is refused before it claims or publishes anything. A node that takes it is the
only one of its name on this host, and it need not wait for DDS to find the others of this
host: it publishes as soon as it has started.

Across hosts, through DDS: each node that took the lock claims its name on the hidden topic
``~/_name_claim`` (reliable, transient local: a node that comes later still receives it): it
announces a random instance id and whether it is *established*, and listens there for the
others'. A node is established once it has held its claim for :data:`ESTABLISHED_S` (its own
steady clock: longer than DDS takes to bring the claims of the nodes already running) and it
then announces its claim again, established. Of two claims, an established one wins over one
that is not; else the smaller instance id wins. No wall clock is compared, so a skewed clock
changes nothing: a node that has run for :data:`ESTABLISHED_S` is never the one refused by a
newcomer, and of nodes started within that time of each other exactly one goes on, whichever
claim each hears first (every node orders two claims the same way, and a node's state only
goes from starting to established, so its latest claim settles it). Claims that arrived
while the scene was prepared are read before the node publishes; a claim heard later stops the
node (:attr:`NameClaim.refusal`, read by the spin loop). So a duplicate on another host is
stopped as soon as DDS brings the established claim (0.19-0.70 s after its own claim in the
measurements of docs/topics.md), and its first samples of that time can reach the other
host's subscribers. Waiting that long before every start would delay every lone node's first
sample for a case that is a misconfiguration of several hosts, which ROS itself does not
check at all; a node on one host, started twice, is caught before it publishes.

Where the host lock is unavailable (not Linux, or ``DET_SIM_HOST_LOCK=off`` in the
environment: :func:`host_lock_wanted`) DDS alone settles the name: :meth:`NameClaim.settle`
waits for the others' claims while the scene is prepared and for at least :data:`SETTLE_S`
after the claim (how late a running node's claim arrives, in steps of sim_node's announcement
period: docs/topics.md), longer while claim writers have matched whose claims have not arrived
yet. With ``ROS_AUTOMATIC_DISCOVERY_RANGE=OFF`` the node discovers no other node, not even of
this host: it takes no lock and does not wait. With ``allow_duplicate_name`` there is no wait
and no refusal: one warning when another node of the name is found, and the node goes on.
"""

from __future__ import annotations

import contextlib
import os
import time
import weakref

from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from .host_lock import HELD_ELSEWHERE, HostNameLock, LockState, UNAVAILABLE

__all__ = ['CLAIM_TOPIC', 'Claim', 'discovers_no_other_node', 'ESTABLISHED_S',
           'host_lock_wanted', 'NameClaim', 'SETTLE_S', 'SETTLE_MAX_S', 'yields']

CLAIM_TOPIC = '~/_name_claim'
SETTLE_S = 0.75      # s after the claim before the node may publish, without a host lock
SETTLE_MAX_S = 3.0   # s at most, while matched claim writers have not been heard yet
# s after its claim before a node's claim wins over newcomers': longer than any wait for the
# claims of DDS, so a node never establishes before it has settled its own name
ESTABLISHED_S = SETTLE_MAX_S + 2.0


class Claim(tuple):
    """(established, random 64-bit instance id): see :func:`yields` for their order."""

    __slots__ = ()

    def __new__(cls, established: bool, instance: int):
        return super().__new__(cls, (bool(established), int(instance)))

    @property
    def established(self) -> bool:
        """Return True once the node has held its claim for :data:`ESTABLISHED_S`."""
        return self[0]

    @property
    def instance(self) -> int:
        """Return the claim's random instance id."""
        return self[1]

    def text(self) -> str:
        """Return the claim as its message's text: 'established|starting <instance hex>'."""
        return f"{'established' if self.established else 'starting'} {self.instance:016x}"

    @classmethod
    def parse(cls, text: str) -> 'Claim | None':
        """Return the claim of a message's text, or None if it is not one."""
        try:
            state, instance = text.split()
            if state not in ('established', 'starting'):
                return None
            return cls(state == 'established', int(instance, 16))
        except ValueError:
            return None


def yields(mine: Claim, other: Claim) -> bool:
    """
    Return True if ``mine`` loses to ``other`` (another node's; its own, heard back: False).

    An established claim wins over one that is not; of two alike, the smaller instance id.
    """
    return (other.instance != mine.instance
            and (not other.established, other.instance) < (not mine.established,
                                                           mine.instance))


def _refusal(node, holder: str = '') -> str:
    where = f' (on this host, {holder})' if holder else ''
    return (f'another node named {node.get_fully_qualified_name()} is running on this ROS '
            f'domain{where} (started twice?); stop it, give this one another name or namespace '
            '(--ros-args -r __node:=NAME or -r __ns:=/NAMESPACE), or set '
            'allow_duplicate_name:=true')


class NameClaim:
    """
    The node's claim on its name: the host's lock taken, the claim announced, others compared.

    ``refusal`` is '' while the node may run, else the one line it stops with. ``allow``:
    whether a duplicate only warns (None: not known yet, :meth:`settle` says).
    """

    def __init__(self, node, allow: bool | None = None):
        self.refusal = ''
        self._heard_instances = set()
        self._timer = None
        self._winner_heard = False
        # weak: the node's subscription holds this object's callback, and a node whose start
        # failed must be freed at once (it holds its logger's /rosout publisher)
        self._node, self._allow, self._warned = weakref.ref(node), allow, False
        self._subscription = self._publisher = None
        # taken before the claim exists: a node of this host refused by the lock never
        # announces a claim, so no running node of this host can hear itself outranked
        self._host_lock = (None if discovers_no_other_node() else
                           HostNameLock(node.context.get_domain_id(),
                                        node.get_fully_qualified_name(),
                                        enabled=host_lock_wanted()))
        if self.host_lock_state is not HELD_ELSEWHERE:
            self._announce(node)

    @property
    def host_lock_state(self) -> LockState | None:
        """Return the host lock's state; None when the node discovers no other node (no lock)."""
        return None if self._host_lock is None else self._host_lock.state

    def _announce(self, node) -> None:
        self.claim = Claim(False, int.from_bytes(os.urandom(8), 'little'))
        self._claimed_at = time.monotonic()
        # a writer keeps its one claim for the nodes that come later; the reader's history is
        # shared by all writers of the (keyless) topic, so it keeps many: claims that arrive
        # together must not overwrite another before it is read
        claim_qos, reader_qos = (QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
                                 for depth in (1, 100))
        self._subscription = node.create_subscription(String, CLAIM_TOPIC, self._heard,
                                                      reader_qos)
        self._publisher = node.create_publisher(String, CLAIM_TOPIC, claim_qos)
        self._publisher.publish(String(data=self.claim.text()))
        # the node's own steady clock: neither sim time nor a wall clock another host may skew
        self._timer = node.create_timer(ESTABLISHED_S, self._establish,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _establish(self) -> None:
        """Announce the claim again, established (once, unless the node is refused)."""
        self._timer.cancel()
        if not self.refusal and not self.claim.established:
            self.claim = Claim(True, self.claim.instance)
            self._publisher.publish(String(data=self.claim.text()))

    def settle(self, allow: bool) -> str:
        """
        Settle the name; return the refusal ('' : the node may go on).

        Another node of this host holds the name: the refusal at once (with ``allow``, one
        warning, and the node claims its name too). This node holds the host's lock (or
        discovers no other node): the claims that arrived by now are read, and the node goes
        on. No host lock on this system: the node's callbacks are spun (only its claim
        subscription and parameter services exist yet) until a winning claim is heard, or
        :data:`SETTLE_S` after the claim has passed and every matched claim writer has been
        heard (at most :data:`SETTLE_MAX_S`). With ``allow`` there is no wait.
        """
        self._allow = allow
        node = self._node()
        if self.host_lock_state is HELD_ELSEWHERE:
            self._answer_winner()
            if allow and node is not None and self._publisher is None:
                self._announce(node)
            return self.refusal
        if self._winner_heard:
            self._answer_winner()
        if node is None or self.refusal:
            return self.refusal
        if self.host_lock_state is UNAVAILABLE and not allow:
            self._wait_for_claims(node)
        else:
            self._read_arrived_claims(node)
        return self.refusal

    def release(self) -> None:
        """Let the host's lock on the name go (the node is destroyed)."""
        if self._host_lock is not None:
            self._host_lock.release()

    def _wait_for_claims(self, node) -> None:
        """Spin until a winning claim, or until the claims of DDS have settled the name."""
        with _executor(node) as executor:
            while not self.refusal:
                waited = time.monotonic() - self._claimed_at
                unheard = (self._subscription.get_publisher_count()
                           > len(self._heard_instances))
                if waited >= SETTLE_MAX_S or (waited >= SETTLE_S and not unheard):
                    break
                executor.spin_once(timeout_sec=0.02 if waited >= SETTLE_S
                                   else min(0.02, SETTLE_S - waited))

    def _read_arrived_claims(self, node) -> None:
        """Run what has arrived (no wait) until a round brings no new claim, or a refusal."""
        with _executor(node) as executor:
            heard = -1
            while not self.refusal and len(self._heard_instances) != heard:
                heard = len(self._heard_instances)
                executor.spin_once(timeout_sec=0.0)

    def _heard(self, msg) -> None:
        other = Claim.parse(msg.data)
        if other is None:
            return
        self._heard_instances.add(other.instance)
        if yields(self.claim, other):
            self._winner_heard = True
            if self._allow is not None:
                self._answer_winner()

    def _answer_winner(self) -> None:
        """Another node of this name wins: refuse, or warn once when allowed."""
        node = self._node()
        if node is None or self.refusal or self._warned:
            return
        holder = (self._host_lock.holder() if self.host_lock_state is HELD_ELSEWHERE
                  else '')
        if self._allow:
            self._warned = True
            node.get_logger().warning(_refusal(node, holder).partition('; stop it')[0]
                                      + ' (allow_duplicate_name is true: started anyway)')
        else:
            self.refusal = _refusal(node, holder)


@contextlib.contextmanager
def _executor(node):
    """Yield an executor of the node's callbacks alone, for its start-up (before its spin)."""
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        yield executor
    finally:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=0.0)


def discovers_no_other_node(environ=os.environ) -> bool:
    """Return True if ROS_AUTOMATIC_DISCOVERY_RANGE is OFF: no other node, even of this host."""
    return environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip().upper() == 'OFF'


def host_lock_wanted(environ=os.environ) -> bool:
    """
    Return False if DET_SIM_HOST_LOCK is off: no host lock, DDS alone settles the name.

    As on a system without one: the node waits for the claims of DDS before it publishes. For
    a test of the path across hosts on one host, or processes of one network namespace that
    must not share names' locks.
    """
    return environ.get('DET_SIM_HOST_LOCK', '').strip().lower() not in ('off', '0', 'false')
