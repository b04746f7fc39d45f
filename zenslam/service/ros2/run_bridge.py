"""``zenslam run --ros2-publish``: a run's poses, keyframe path and tf on ROS 2 topics, as rmw_zenoh puts them.

The run's hub process owns a ROS 2 node ``/zenslam`` on a zenoh session of its own (rmw_zenoh's
default: a peer connecting to the robot's router on tcp/localhost:7447, or ``--ros2-zenoh-config``),
so ``ros2 topic echo /zenslam/pose`` on the robot sees:

- ``/zenslam/pose`` geometry_msgs/msg/PoseStamped: the camera pose of every frame the frontend
  published a pose for, in frame ``map``, stamped with the frame's time;
- ``/tf`` tf2_msgs/msg/TFMessage: the same pose as the transform ``map`` -> ``camera_optical_frame``
  (zenslam's camera axes: x right, y down, z forward, REP 103's optical frame);
- ``/zenslam/path`` nav_msgs/msg/Path: the keyframe trajectory in ``map``, published again
  whenever the backend's map updates change it, and once more with the backend's final poses at
  the end of the run.
"""

from __future__ import annotations

import argparse
import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from zenslam.errors import ConfigError
from zenslam.schemas.codec import StampedPose
from zenslam.service.ros2 import cdr, keys
from zenslam.service.ros2.pose_messages import encode_path, encode_pose_stamped, encode_tf
from zenslam.service.ros2.publisher import Ros2Node
from zenslam.service.ros2.session import open_ros2_session
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Ros2PublishConfig:
    """Where and as what a run's results appear on the ROS 2 graph."""

    domain_id: int = 0  # ROS domain id (ROS_DOMAIN_ID)
    zenoh_config_file: Path | None = None  # zenoh JSON5 session config; None: rmw_zenoh's default (router on localhost:7447)
    node_name: str = "zenslam"
    pose_topic: str = "/zenslam/pose"
    path_topic: str = "/zenslam/path"
    tf_topic: str = "/tf"
    map_frame: str = "map"  # frame of the poses and the path; the parent of the camera in tf
    camera_frame: str = "camera_optical_frame"  # tf's child frame: zenslam's camera (z forward, y down)


class Ros2RunBridge:
    """Publishes what the run's hub receives: a PoseStamped and a tf per pose, a Path per change."""

    def __init__(self, node: Ros2Node, config: Ros2PublishConfig):
        self._config = config
        self._pose = node.publisher(config.pose_topic, cdr.POSE_STAMPED)
        self._path = node.publisher(config.path_topic, cdr.PATH, keys.Qos(depth=1))
        self._tf = node.publisher(config.tf_topic, cdr.TF_MESSAGE, keys.Qos(depth=100))  # tf2's broadcaster depth
        self._last_path: Trajectory | None = None
        self.poses_published = 0
        self.paths_published = 0

    def publish_pose(self, pose: StampedPose) -> None:
        """One frame's camera pose: PoseStamped and tf."""
        config = self._config
        self._pose.put(encode_pose_stamped(pose.stamp_ns, config.map_frame, pose.T_world_cam))
        self._tf.put(encode_tf(pose.stamp_ns, config.map_frame, config.camera_frame, pose.T_world_cam))
        self.poses_published += 1

    def publish_path(self, keyframes: Trajectory | None) -> None:
        """The keyframe trajectory as a Path stamped with its newest keyframe, unless it is unchanged."""
        if keyframes is None or len(keyframes.stamps_ns) == 0 or _same(keyframes, self._last_path):
            return
        stamp_ns = int(keyframes.stamps_ns[-1])
        self._path.put(encode_path(stamp_ns, self._config.map_frame, keyframes.stamps_ns, keyframes.T_world_cam))
        self._last_path = keyframes
        self.paths_published += 1


def _same(a: Trajectory, b: Trajectory | None) -> bool:
    return (
        b is not None
        and np.array_equal(a.stamps_ns, b.stamps_ns)
        and np.array_equal(np.asarray(a.T_world_cam), np.asarray(b.T_world_cam))
    )


@contextmanager
def open_run_bridge(config: Ros2PublishConfig | None) -> Iterator[Ros2RunBridge | None]:
    """The run's ROS 2 bridge while the block runs (None when ``config`` is None: not publishing)."""
    if config is None:
        yield None
        return
    with open_ros2_session(config.zenoh_config_file) as session, Ros2Node(session, config.node_name, config.domain_id) as node:
        bridge = Ros2RunBridge(node, config)
        yield bridge
        logger.info(
            "published %d poses and %d paths on ROS 2 domain %d", bridge.poses_published, bridge.paths_published, config.domain_id
        )


def domain_id_from(value: int | None) -> int:
    """``--ros-domain`` when given, else ROS_DOMAIN_ID from the environment as ROS 2 reads it, else 0."""
    if value is not None:
        return keys.check_domain_id(value)
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isdigit():
        raise ConfigError(f"ROS_DOMAIN_ID={text!r} is not a ROS domain id; set a non-negative integer or pass --ros-domain")
    return int(text)


def add_ros2_publish_arguments(parser: argparse.ArgumentParser) -> None:
    """``--ros2-publish``, ``--ros2-zenoh-config`` and (unless the parser has it already) ``--ros-domain``."""
    parser.add_argument(
        "--ros2-publish", action="store_true",
        help="publish the poses (/zenslam/pose), keyframe path (/zenslam/path) and tf (map -> camera_optical_frame) "
        "on ROS 2 topics as rmw_zenoh does, for ROS 2 nodes on rmw_zenoh_cpp",
    )
    parser.add_argument(
        "--ros2-zenoh-config", type=Path, default=None,
        help="zenoh JSON5 session config for the ROS 2 graph (default: rmw_zenoh's, a peer of the router on tcp/localhost:7447)",
    )
    if "--ros-domain" not in parser._option_string_actions:
        parser.add_argument(
            "--ros-domain", dest="ros_domain", type=int, default=None,
            help="ROS domain id of the ROS 2 topics (default: ROS_DOMAIN_ID, else 0)",
        )


def ros2_publish_config(args: argparse.Namespace) -> Ros2PublishConfig | None:
    """The bridge's configuration from ``args`` (None without ``--ros2-publish``)."""
    if not getattr(args, "ros2_publish", False):
        return None
    return Ros2PublishConfig(domain_id=domain_id_from(args.ros_domain), zenoh_config_file=args.ros2_zenoh_config)
