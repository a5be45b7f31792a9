"""
The node's output messages per sample: plain, or measured by the scene's sensors with the truth.

The messages themselves are det_sim_ros.io.sensing's (the same objects the offline recorder
and re-simulation use); here they get their publishers. With sensors the node also publishes
``~/truth/<topic>`` for every sensed topic: each truth message goes out only while its topic has
a subscriber (told by the publisher's matched event, so a node nobody watches the truth of
does not pay DDS for it), and is always logged when recording.
"""

from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks
from sensor_msgs.msg import JointState

from ..io.sensing import make_outputs, TRUTH

__all__ = ['TruthPublisher', 'attach_outputs']


class TruthPublisher:
    """
    Publish a truth message's bytes while the topic has a subscriber (a matched event).

    :param on_change: called after a matched event has set :attr:`heard`.
    """

    def __init__(self, node, topic: str, qos, on_change=None):
        self.heard = False
        self._on_change = on_change
        self.publisher = node.create_publisher(
            JointState, topic, qos,
            event_callbacks=PublisherEventCallbacks(matched=self._matched))
        self._publish = self.publisher.publish

    def _matched(self, status) -> None:
        self.heard = status.current_count > 0
        if self._on_change is not None:
            self._on_change()

    def __call__(self, data: bytes) -> None:
        """Publish ``data`` if the topic has a subscriber."""
        if self.heard:
            self._publish(data)


def attach_outputs(node, contract, qos):
    """
    Create the output publishers of ``node`` and its sample messages.

    Return (outputs, output topic -> publisher, truth topic -> publisher, the publish
    functions in the order of ``outputs.encode``: the output topics, then the truth topics up
    to the last one with a subscriber). That list changes in place as truth subscribers come
    and go, so a sample's loop over it stops after the measured messages while nobody watches
    the truth.
    """
    sim = node.simulator
    outputs = make_outputs(contract, node.scene, len(sim.output_names), node.get_name())
    publishers = {topic: node.create_publisher(JointState, topic, qos)
                  for topic in outputs.topics}
    measured = [pub.publish for pub in publishers.values()]   # (publish(bytes): serialized)
    publish, truth = list(measured), []

    def heard_changed():
        last = max((j + 1 for j, t in enumerate(truth) if t.heard), default=0)
        publish[:] = measured + truth[:last]   # (by position: truth j after the outputs)
    truth += [TruthPublisher(node, f'~/{TRUTH}/{topic}', qos, heard_changed)
              for topic in outputs.sensed]
    return outputs, publishers, {topic: t.publisher for topic, t in zip(outputs.sensed, truth)}, \
        publish
