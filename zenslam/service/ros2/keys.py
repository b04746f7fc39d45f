"""rmw_zenoh's zenoh key expressions: topic data keys and the ROS-graph liveliness tokens.

As rmw_zenoh's design document (github.com/ros2/rmw_zenoh, docs/design.md on ``rolling``, the
branch Jazzy's and Rolling's rmw_zenoh_cpp are released from; sections "Graph Cache", "Namespaces",
"Nodes", "Publishers") describes them, and as its source builds them
(rmw_zenoh_cpp/src/detail/liveliness_utils.cpp at commit 3411fdec149fe0c932f24d4d79ef908eb81d7482:
``TopicInfo`` and ``Entity``; qos.cpp at 5e10d47b06c3fe327105d06a8350be455411ea5b for the QoS
defaults; rmw_node_data.cpp and rmw_publisher_data.cpp for the ids):

- data: ``<domain_id>/<fully qualified topic without its leading slash>/<DDS type name>/<type hash>``,
  e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c74...``; the type name is the DDS
  one (``pkg::msg::dds_::Type_``) and the hash the type's RIHS01 hash (REP 2011).
- liveliness: ``@ros2_lv/<domain_id>/<session zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node name>``
  for a node (kind ``NN``; its entity id is its node id), followed by
  ``/<topic>/<DDS type name>/<type hash>/<qos>`` for a publisher (``MP``) or subscription (``MS``).
  Names are "mangled": every ``/`` becomes ``%`` (the root namespace and enclave ``/`` become ``%``).
  Node and entity ids are numbers from one counter per ROS context (zenoh session), from 0.
- qos: ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<lease s>,<ns>``,
  each value left empty when it equals rmw_zenoh's default (reliable, volatile, keep-last, depth
  42, infinite durations, automatic liveliness); the numbers are rmw's enum values.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from zenslam.errors import ConfigError, MessageError

ADMIN_SPACE = "@ros2_lv"  # the liveliness tokens' prefix (a verbatim chunk: only matched literally)
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"  # liveliness entity kinds
ROOT_NAMESPACE = "/"
DEFAULT_ENCLAVE = "/"  # rcl's enclave when none is given

_ROS_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(msg|srv|action)/([A-Za-z][A-Za-z0-9_]*)$")
_DDS_TYPE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)::(msg|srv|action)::dds_::([A-Za-z][A-Za-z0-9_]*)_$")
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_TOPIC = re.compile(rf"^(/{_TOKEN})+$")
_NAMESPACE = re.compile(rf"^/$|^(/{_TOKEN})+$")
_NODE_NAME = re.compile(rf"^{_TOKEN}$")
_TYPE_HASH = re.compile(r"^RIHS01_[0-9a-f]{64}$")
_ZID = re.compile(r"^[0-9a-f]{1,32}$")

# rmw's enum values (rmw/types.h) as rmw_zenoh writes them into the QoS chunk.
_RELIABILITY = {"reliable": 1, "best_effort": 2}
_DURABILITY = {"transient_local": 1, "volatile": 2}
_HISTORY = {"keep_last": 1, "keep_all": 2}
_DEFAULT_DEPTH = 42  # rmw_zenoh's default history depth (qos.cpp)


@dataclass(frozen=True)
class Qos:
    """A ROS 2 QoS profile as far as rmw_zenoh's liveliness token states it."""

    reliability: Literal["reliable", "best_effort"] = "reliable"
    durability: Literal["volatile", "transient_local"] = "volatile"
    depth: int = 10  # messages kept (keep-last history); rclcpp's default QoS depth
    # keep_all with reliable: rmw_zenoh's publisher blocks instead of dropping when a subscriber lags
    history: Literal["keep_last", "keep_all"] = "keep_last"

    def __post_init__(self) -> None:
        if (
            self.reliability not in _RELIABILITY or self.durability not in _DURABILITY or self.history not in _HISTORY
            or self.depth < 1
        ):  # fmt: skip
            raise ConfigError(
                f"invalid ROS 2 QoS {self}: reliability must be one of {sorted(_RELIABILITY)}, "
                f"durability one of {sorted(_DURABILITY)}, history one of {sorted(_HISTORY)}, depth at least 1"
            )

    @property
    def blocks(self) -> bool:
        """Whether rmw_zenoh's publisher with this QoS blocks (reliable keep-all) rather than drops."""
        return self.reliability == "reliable" and self.history == "keep_all"

    def key_chunk(self) -> str:
        """The QoS chunk of a liveliness token (values equal to rmw_zenoh's defaults left empty)."""
        reliability = "" if self.reliability == "reliable" else str(_RELIABILITY[self.reliability])
        durability = "" if self.durability == "volatile" else str(_DURABILITY[self.durability])
        history = "" if self.history == "keep_last" else str(_HISTORY[self.history])
        depth = "" if self.depth == _DEFAULT_DEPTH or self.history == "keep_all" else str(self.depth)
        return f"{reliability}:{durability}:{history},{depth}:,:,:,,"


def check_domain_id(domain_id: int) -> int:
    """``domain_id`` if it is a ROS domain id (a non-negative integer), else ConfigError."""
    if isinstance(domain_id, bool) or not isinstance(domain_id, int) or domain_id < 0:
        raise ConfigError(f"ROS domain id {domain_id!r} must be a non-negative integer (ROS_DOMAIN_ID, default 0)")
    return domain_id


def check_topic(topic: str) -> str:
    """``topic`` if it is a fully qualified ROS 2 topic name (``/a/b``), else ConfigError."""
    if not isinstance(topic, str) or not _TOPIC.match(topic):
        raise ConfigError(
            f"ROS 2 topic {topic!r} is not a fully qualified topic name: give '/name' or '/namespace/name' "
            "(letters, digits and '_', each part starting with a letter or '_')"
        )
    return topic


def dds_type_name(ros_type: str) -> str:
    """The DDS type name rmw_zenoh keys by: ``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_``."""
    match = _ROS_TYPE.match(ros_type or "")
    if match is None:
        raise ConfigError(f"ROS 2 type {ros_type!r} is not of the form 'package/msg/Type'")
    package, kind, name = match.groups()
    return f"{package}::{kind}::dds_::{name}_"


def ros_type_name(dds_type: str) -> str:
    """The ROS type name of a DDS type name: ``sensor_msgs::msg::dds_::Image_`` -> ``sensor_msgs/msg/Image``."""
    match = _DDS_TYPE.match(dds_type or "")
    if match is None:
        raise MessageError(f"{dds_type!r} is not a DDS type name of the form 'package::msg::dds_::Type_'")
    package, kind, name = match.groups()
    return f"{package}/{kind}/{name}"


def _check_hash(type_hash: str) -> str:
    if not _TYPE_HASH.match(type_hash or ""):
        raise ConfigError(f"type hash {type_hash!r} is not a RIHS01 hash ('RIHS01_' and 64 lower-case hex digits)")
    return type_hash


def topic_key(domain_id: int, topic: str, type_name: str, type_hash: str) -> str:
    """The data key of ``topic`` (fully qualified) carrying ROS type ``type_name`` (``pkg/msg/Type``)."""
    return f"{check_domain_id(domain_id)}/{check_topic(topic)[1:]}/{dds_type_name(type_name)}/{_check_hash(type_hash)}"


def topic_subscription_key(domain_id: int, topic: str) -> str:
    """The key expression matching ``topic``'s data whatever its type and hash (one chunk each)."""
    return f"{check_domain_id(domain_id)}/{check_topic(topic)[1:]}/*/*"


def _split_topic_key(key: str) -> tuple[str, str, str, str]:
    chunks = str(key).split("/")
    if len(chunks) < 4 or not chunks[0].isdigit() or not _TYPE_HASH.match(chunks[-1]):
        raise MessageError(
            f"{key!r} is not an rmw_zenoh topic key '<domain>/<topic>/<type>/<RIHS01 hash>'"
        )
    return chunks[0], "/" + "/".join(chunks[1:-2]), chunks[-2], chunks[-1]


def type_name_of_key(key: str) -> str:
    """The ROS type name (``sensor_msgs/msg/Image``) of an rmw_zenoh topic key."""
    return ros_type_name(_split_topic_key(key)[2])


def topic_of_key(key: str) -> str:
    """The fully qualified topic name (``/camera/image_raw``) of an rmw_zenoh topic key."""
    return _split_topic_key(key)[1]


def mangle(name: str) -> str:
    """A ROS name as one key chunk: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def graph_key(domain_id: int) -> str:
    """Every liveliness token of the ROS graph of ``domain_id``."""
    return f"{ADMIN_SPACE}/{check_domain_id(domain_id)}/**"


@dataclass(frozen=True)
class NodeIdentity:
    """Who a node is on the ROS graph: its domain, zenoh session, id within the session and names."""

    domain_id: int
    zid: str  # the zenoh session id, lower-case hex as zenoh prints it
    node_id: int  # from the session's entity counter
    name: str
    namespace: str = ROOT_NAMESPACE
    enclave: str = DEFAULT_ENCLAVE

    def __post_init__(self) -> None:
        check_domain_id(self.domain_id)
        problems = []
        if not _ZID.match(self.zid):
            problems.append(f"zid {self.zid!r} must be a zenoh id in hex")
        if not _NODE_NAME.match(self.name or ""):
            problems.append(f"node name {self.name!r} must be letters, digits and '_', starting with a letter or '_'")
        for kind, value in (("namespace", self.namespace), ("enclave", self.enclave)):
            if not _NAMESPACE.match(value or ""):
                problems.append(f"{kind} {value!r} must be '/' or '/name[/name...]'")
        if self.node_id < 0:
            problems.append(f"node id {self.node_id} must be non-negative")
        if problems:
            raise ConfigError("invalid ROS 2 node identity: " + "; ".join(problems))

    def _prefix(self, entity_id: int, kind: str) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}"
        )


def node_token_key(node: NodeIdentity) -> str:
    """The liveliness token announcing ``node``."""
    return node._prefix(node.node_id, NODE)


def _endpoint_token_key(
    node: NodeIdentity, kind: str, entity_id: int, topic: str, type_name: str, type_hash: str, qos: Qos
) -> str:
    if entity_id < 0:
        raise ConfigError(f"entity id {entity_id} must be non-negative")
    return (
        f"{node._prefix(entity_id, kind)}/{mangle(check_topic(topic))}/{dds_type_name(type_name)}/"
        f"{_check_hash(type_hash)}/{qos.key_chunk()}"
    )


def publisher_token_key(
    node: NodeIdentity, entity_id: int, topic: str, type_name: str, type_hash: str, qos: Qos = Qos()
) -> str:
    """The liveliness token announcing a publisher of ``node`` on ``topic``."""
    return _endpoint_token_key(node, PUBLISHER, entity_id, topic, type_name, type_hash, qos)


def subscription_token_key(
    node: NodeIdentity, entity_id: int, topic: str, type_name: str, type_hash: str, qos: Qos = Qos()
) -> str:
    """The liveliness token announcing a subscription of ``node`` to ``topic``."""
    return _endpoint_token_key(node, SUBSCRIPTION, entity_id, topic, type_name, type_hash, qos)
