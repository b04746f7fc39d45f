"""CDR serialisation of ROS 2 messages through rosbags' Jazzy typestore, and the RIHS01 type hashes.

rosbags (pypi.org/project/rosbags) carries the message definitions of each ROS distribution and
serialises them as rmw's CDR (encapsulation header, then little-endian CDR); ``hash_rihs01`` hashes
a type's description as REP 2011 and rosidl do (its hashes equal the ones ROS 2 Jazzy's message
packages ship, e.g. std_msgs/msg/String's ``RIHS01_df668c74...`` quoted in rmw_zenoh's design).
Every failure to decode becomes a MessageError naming the topic and the type.
"""

from __future__ import annotations

import functools
from typing import Any

from zenslam.errors import MessageError

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMU = "sensor_msgs/msg/Imu"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

_NS_PER_S = 1_000_000_000
_INT32_MAX = 2**31 - 1


@functools.cache
def typestore() -> Any:
    """rosbags' typestore of ROS 2 Jazzy's message definitions (built once per process)."""
    # rosbags is imported here, by the processes that speak ROS 2: a run's hub imports this module
    # for its --ros2-publish options whether or not it publishes.
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def msg_class(ros_type: str) -> Any:
    """The rosbags dataclass of ``ros_type`` (``pkg/msg/Type``)."""
    return typestore().types[ros_type]


@functools.cache
def type_hash(ros_type: str) -> str:
    """The RIHS01 hash of ``ros_type`` (``RIHS01_`` and 64 hex digits), as rmw_zenoh keys data by."""
    if ros_type not in typestore().types:
        raise MessageError(f"ROS 2 type {ros_type!r} is not one of ROS 2 Jazzy's message types")
    return typestore().hash_rihs01(ros_type)


def serialize(message: Any, ros_type: str) -> bytes:
    """The CDR bytes of ``message`` (a rosbags message of ``ros_type``), as rmw publishes them."""
    try:
        return bytes(typestore().serialize_cdr(message, ros_type))
    except Exception as exc:  # rosbags raises struct, numpy and its own errors for bad field values
        raise MessageError(f"cannot encode a {ros_type}: {exc}") from exc


def deserialize(payload: bytes | bytearray | memoryview, ros_type: str, topic: str | None) -> Any:
    """The rosbags message of ``ros_type`` in ``payload``; MessageError naming ``topic`` when it is not one."""
    try:
        return typestore().deserialize_cdr(bytes(payload), ros_type)
    except Exception as exc:  # truncated, garbled or oversized: struct, numpy, unicode or rosbags errors
        raise MessageError(f"{where(topic)}: {len(payload)} bytes are not a CDR {ros_type}: {exc}") from exc


def where(topic: str | None) -> str:
    """How an error names the message's origin."""
    return f"ROS 2 topic {topic}" if topic else "ROS 2 message"


def stamp_ns_of(stamp: Any) -> int:
    """Nanoseconds of a builtin_interfaces/msg/Time."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


def time_msg(stamp_ns: int) -> Any:
    """The builtin_interfaces/msg/Time of ``stamp_ns`` (seconds must fit its int32)."""
    sec, nanosec = divmod(int(stamp_ns), _NS_PER_S)
    if not -_INT32_MAX - 1 <= sec <= _INT32_MAX:
        raise MessageError(f"stamp {stamp_ns} ns does not fit a ROS 2 Time (int32 seconds)")
    return msg_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame_id: str) -> Any:
    """A std_msgs/msg/Header."""
    return msg_class("std_msgs/msg/Header")(stamp=time_msg(stamp_ns), frame_id=frame_id)
