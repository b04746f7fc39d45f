"""A ROS 2 node's presence on a zenoh session, and its publishers, as rmw_zenoh makes them.

As rmw_zenoh does for an rclcpp node (rmw_node_data.cpp, rmw_publisher_data.cpp and
liveliness_utils.cpp at commit 3411fdec149fe0c932f24d4d79ef908eb81d7482; docs/design.md,
"Graph Cache", "Nodes", "Publishers"): the node declares a liveliness token (kind ``NN``), each
publisher a zenoh publisher on its topic key and a liveliness token (kind ``MP``) from which other
nodes' graph caches learn the topic's type and QoS (what ``ros2 topic list`` shows and what
``ros2 topic echo`` subscribes with), and every publication carries the attachment. A publisher's
GID is the XXH3-128 hash of its liveliness key (low 64 bits first, little-endian). Node and entity
ids count from 0 per session (one ROS context per session): the node is 0, its publishers 1, 2, ...
"""

from __future__ import annotations

import logging
import time

import xxhash

from zenslam.runtime import bus
from zenslam.service.ros2 import cdr, keys
from zenslam.service.ros2.attachment import Attachment, encode_attachment

logger = logging.getLogger(__name__)


def gid_of(liveliness_key: str) -> bytes:
    """The 16-byte GID rmw_zenoh gives the entity whose liveliness token is ``liveliness_key``."""
    return xxhash.xxh3_128_intdigest(liveliness_key.encode()).to_bytes(16, "little")


class Ros2Publisher:
    """Publishes CDR messages of one ROS 2 type on one topic; made by ``Ros2Node.publisher``."""

    def __init__(
        self, session: bus.Session, node: keys.NodeIdentity, entity_id: int, topic: str, ros_type: str, qos: keys.Qos
    ):
        type_hash = cdr.type_hash(ros_type)
        self.topic = topic
        self.ros_type = ros_type
        self.key = keys.topic_key(node.domain_id, topic, ros_type, type_hash)
        self.token_key = keys.publisher_token_key(node, entity_id, topic, ros_type, type_hash, qos)
        self.gid = gid_of(self.token_key)
        reliable = qos.reliability == "reliable"
        # As rmw_zenoh: drop rather than block unless the QoS is reliable keep-all.
        self._publisher = bus.declare_raw_publisher(session, self.key, reliable=reliable, block=qos.blocks)
        self._token = bus.declare_token(session, self.token_key)
        self._sequence_number = 1
        self._closed = False

    @property
    def has_subscribers(self) -> bool:
        """Whether some zenoh subscriber (a ROS 2 subscription among them) matches the topic key now."""
        return self._publisher.matching_status.matching

    def put(self, msg_bytes: bytes, source_timestamp_ns: int | None = None) -> None:
        """Publish one CDR message with rmw_zenoh's attachment (timestamp: now, system time, unless given)."""
        stamp = time.time_ns() if source_timestamp_ns is None else source_timestamp_ns
        attachment = encode_attachment(Attachment(self._sequence_number, stamp, self.gid))
        self._publisher.put(msg_bytes, attachment=attachment)
        self._sequence_number += 1

    def close(self) -> None:
        """Leave the graph (token first, as rmw_zenoh does) and undeclare the publisher."""
        if not self._closed:
            self._token.undeclare()
            self._publisher.undeclare()
            self._closed = True


class Ros2Node:
    """One ROS 2 node on a zenoh session: announces itself while open and makes publishers.

    Use with ``with``; closing undeclares the publishers and the node's token (the session stays open).
    """

    def __init__(self, session: bus.Session, name: str, domain_id: int = 0, namespace: str = keys.ROOT_NAMESPACE):
        self._session = session
        self.identity = keys.NodeIdentity(domain_id=domain_id, zid=str(session.zid()), node_id=0, name=name, namespace=namespace)
        self._next_entity_id = self.identity.node_id + 1
        self._publishers: list[Ros2Publisher] = []
        self.token_key = keys.node_token_key(self.identity)
        self._token = bus.declare_token(session, self.token_key)
        logger.info("ROS 2 node %s%s on domain %d (zenoh session %s)", namespace.rstrip("/") + "/", name, domain_id, self.identity.zid)

    def publisher(self, topic: str, ros_type: str, qos: keys.Qos = keys.Qos()) -> Ros2Publisher:
        """A publisher of ``ros_type`` (``pkg/msg/Type``) messages on the fully qualified ``topic``."""
        publisher = Ros2Publisher(self._session, self.identity, self._next_entity_id, topic, ros_type, qos)
        self._next_entity_id += 1
        self._publishers.append(publisher)
        return publisher

    def announce_subscription(self, topic: str, ros_type: str, qos: keys.Qos = keys.Qos()) -> bus.LivelinessToken:
        """Declare the liveliness token of a subscription of this node to ``topic`` (the zenoh subscriber
        itself is the caller's, on ``keys.topic_subscription_key``); undeclare it to leave the graph."""
        key = keys.subscription_token_key(self.identity, self._next_entity_id, topic, ros_type, cdr.type_hash(ros_type), qos)
        self._next_entity_id += 1
        return bus.declare_token(self._session, key)

    def close(self) -> None:
        for publisher in self._publishers:
            publisher.close()
        self._publishers.clear()
        if self._token is not None:
            self._token.undeclare()
            self._token = None

    def __enter__(self) -> Ros2Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
