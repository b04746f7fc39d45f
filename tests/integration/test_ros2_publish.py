"""End to end: ``zenslam run synthetic --ros2-publish`` puts one PoseStamped (and one tf) per tracked
frame and the keyframe Path on rmw_zenoh's keys, where a ROS 2 node on rmw_zenoh subscribes."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from zenslam.runtime import bus
from zenslam.service.evaluation.trajectory_io import read_tum
from zenslam.service.ros2.attachment import decode_attachment

pytestmark = pytest.mark.integration

FRAMES = 15
DOMAIN = 3
# Written from rmw_zenoh's layout, <domain>/<topic>/<DDS type>/<RIHS01 hash of ROS 2 Jazzy's type>.
POSE_KEY = f"{DOMAIN}/zenslam/pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
TF_KEY = f"{DOMAIN}/tf/tf2_msgs::msg::dds_::TFMessage_/RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
PATH_KEY = f"{DOMAIN}/zenslam/path/nav_msgs::msg::dds_::Path_/RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b"


def _drain(subscriber) -> list[zenoh.Sample]:
    samples = []
    while (sample := subscriber.try_recv()) is not None:
        samples.append(sample)
    return samples


@pytest.mark.slow(15)
def test_run_publishes_a_pose_per_tracked_frame_on_rmw_zenohs_keys(tmp_path: Path):
    endpoint = bus.free_tcp_endpoint()
    ros2_config = tmp_path / "ros2_session.json5"
    ros2_config.write_text(json.dumps({"mode": "peer", "connect": {"endpoints": [endpoint]},
                                       "scouting": {"multicast": {"enabled": False}}}))  # fmt: skip
    robot_config = zenoh.Config()
    robot_config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    robot_config.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(robot_config) as robot:
        poses = robot.declare_subscriber(POSE_KEY, zenoh.handlers.FifoChannel(1024))
        tfs = robot.declare_subscriber(TF_KEY, zenoh.handlers.FifoChannel(1024))
        paths = robot.declare_subscriber(PATH_KEY, zenoh.handlers.FifoChannel(1024))
        command = [sys.executable, "-m", "zenslam.service.cli", "run", "synthetic", "--max-frames", str(FRAMES),
                   "--ros2-publish", "--ros-domain", str(DOMAIN), "--ros2-zenoh-config", str(ros2_config),
                   "--output", str(tmp_path), "--run-id", "it-ros2", "--no-progress"]  # fmt: skip
        result = subprocess.run(command, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]
        tracked = read_tum(tmp_path / "it-ros2" / "trajectory.tum")
        received: dict[str, list[zenoh.Sample]] = {"pose": [], "tf": [], "path": []}
        deadline = time.monotonic() + 10.0  # publications put before the run ended may still be in transit
        while len(received["pose"]) < len(tracked.stamps_ns) and time.monotonic() < deadline:
            for name, subscriber in (("pose", poses), ("tf", tfs), ("path", paths)):
                received[name] += _drain(subscriber)
            time.sleep(0.01)
        for name, subscriber in (("tf", tfs), ("path", paths)):
            received[name] += _drain(subscriber)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    assert len(tracked.stamps_ns) == FRAMES
    assert len(received["pose"]) == len(received["tf"]) == FRAMES
    stamps, positions = [], []
    for i, sample in enumerate(received["pose"]):
        assert decode_attachment(sample.attachment.to_bytes()).sequence_number == i + 1
        pose = typestore.deserialize_cdr(sample.payload.to_bytes(), "geometry_msgs/msg/PoseStamped")
        assert pose.header.frame_id == "map"
        stamps.append(pose.header.stamp.sec * 10**9 + pose.header.stamp.nanosec)
        positions.append([pose.pose.position.x, pose.pose.position.y, pose.pose.position.z])
    np.testing.assert_array_equal(stamps, tracked.stamps_ns)
    np.testing.assert_allclose(positions, tracked.T_world_cam[:, :3, 3], atol=1e-6)  # trajectory.tum keeps 6+ decimals
    tf = typestore.deserialize_cdr(received["tf"][-1].payload.to_bytes(), "tf2_msgs/msg/TFMessage")
    assert (tf.transforms[0].header.frame_id, tf.transforms[0].child_frame_id) == ("map", "camera_optical_frame")
    assert received["path"], "no keyframe Path was published"
    keyframes = read_tum(tmp_path / "it-ros2" / "keyframes.tum")
    path = typestore.deserialize_cdr(received["path"][-1].payload.to_bytes(), "nav_msgs/msg/Path")
    np.testing.assert_array_equal(
        [p.header.stamp.sec * 10**9 + p.header.stamp.nanosec for p in path.poses], keyframes.stamps_ns
    )
