"""publish_frames_ros2: stereo and RGB-D frames arrive on rmw_zenoh's keys as a camera driver's Image and
CameraInfo messages (read back with rosbags' deserializer and with zenslam's decoders)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.runtime import bus
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.ros2 import keys
from zenslam.service.ros2.attachment import decode_attachment
from zenslam.service.ros2.frames import frame_topics, publish_frames_ros2
from zenslam.service.ros2.messages import decode_camera_info, decode_image
from zenslam.service.ros2.session import open_ros2_session

IMAGE = "sensor_msgs::msg::dds_::Image_/RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
CAMERA_INFO = "sensor_msgs::msg::dds_::CameraInfo_/RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275"
STEREO = PinholeCalibration(400.0, 401.0, 4.0, 3.0, 8, 6, baseline_m=0.25)


def _frames(count: int, stereo: bool, depth: bool) -> list[SensorFrame]:
    rng = np.random.default_rng(3)
    return [
        SensorFrame(
            index=i, stamp_ns=1_000_000_000 + 50_000_000 * i,
            left=rng.integers(0, 255, (6, 8), dtype=np.uint8),
            right=rng.integers(0, 255, (6, 8), dtype=np.uint8) if stereo else None,
            depth_m=rng.uniform(0.5, 4.0, (6, 8)).astype(np.float32) if depth else None,
        )
        for i in range(count)
    ]  # fmt: skip


@pytest.fixture
def robot(tmp_path):
    """A listening zenoh session (the robot's side) and the config zenslam's ROS 2 session connects with."""
    endpoint = bus.free_tcp_endpoint()
    config = zenoh.Config()
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config_file = tmp_path / "ros2.json5"
    # Multicast scouting off, as in rmw_zenoh's default session: on, this session would find the
    # sessions of tests running in parallel and receive their frames.
    config_file.write_text(json.dumps({"mode": "peer", "connect": {"endpoints": [endpoint]},
                                       "listen": {"endpoints": ["tcp/127.0.0.1:0"]},
                                       "scouting": {"multicast": {"enabled": False}}}))  # fmt: skip
    with zenoh.open(config) as session:
        yield session, config_file


def _publish_and_collect(robot, frames, calibration, expected_keys):
    session, config_file = robot
    subscriber = session.declare_subscriber("5/cam/**", zenoh.handlers.FifoChannel(256))
    with open_ros2_session(config_file) as zenslam_session:
        count = publish_frames_ros2(
            zenslam_session, frames, calibration, "/cam", domain_id=5, rate=0.0, wait_for_subscribers_s=20.0
        )
    assert count == len(frames)
    received: dict[str, list[zenoh.Sample]] = {}
    deadline = time.monotonic() + 20.0
    while sum(map(len, received.values())) < len(expected_keys) * len(frames) and time.monotonic() < deadline:
        sample = subscriber.try_recv()
        if sample is None:
            time.sleep(0.01)
            continue
        received.setdefault(str(sample.key_expr), []).append(sample)
    subscriber.undeclare()
    assert set(received) == set(expected_keys)
    assert all(len(samples) == len(frames) for samples in received.values())
    return received


def test_stereo_frames_on_rmw_zenoh_keys(robot):
    frames = _frames(3, stereo=True, depth=False)
    left_image, right_image = f"5/cam/left/image_rect/{IMAGE}", f"5/cam/right/image_rect/{IMAGE}"
    left_info, right_info = f"5/cam/left/camera_info/{CAMERA_INFO}", f"5/cam/right/camera_info/{CAMERA_INFO}"
    received = _publish_and_collect(robot, frames, STEREO, [left_image, right_image, left_info, right_info])
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for i, frame in enumerate(frames):
        msg = typestore.deserialize_cdr(received[left_image][i].payload.to_bytes(), "sensor_msgs/msg/Image")
        assert (msg.encoding, msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec) == (
            "mono8", "camera", 1, 50_000_000 * i
        )
        np.testing.assert_array_equal(decode_image(received[right_image][i].payload.to_bytes()).image, frame.right)
        assert decode_attachment(received[right_image][i].attachment.to_bytes()).sequence_number == i + 1
    left = decode_camera_info(received[left_info][0].payload.to_bytes())
    right = decode_camera_info(received[right_info][0].payload.to_bytes())
    assert right.frame_id == "camera_right"
    assert left.stereo_calibration(right) == STEREO


def test_rgbd_frames_publish_the_depth_in_metres(robot):
    frames = _frames(2, stereo=False, depth=True)
    image, depth = f"5/cam/image_rect/{IMAGE}", f"5/cam/depth/image_rect/{IMAGE}"
    expected = [image, depth, f"5/cam/camera_info/{CAMERA_INFO}", f"5/cam/depth/camera_info/{CAMERA_INFO}"]
    received = _publish_and_collect(robot, frames, PinholeCalibration(400.0, 401.0, 4.0, 3.0, 8, 6), expected)
    decoded = decode_image(received[depth][1].payload.to_bytes())
    assert decoded.encoding == "32FC1"
    np.testing.assert_array_equal(decoded.image, frames[1].depth_m)
    np.testing.assert_array_equal(decode_image(received[image][0].payload.to_bytes()).image, frames[0].left)


def test_topics_and_bad_arguments():
    assert frame_topics("/cam")["left"].camera_info == "/cam/left/camera_info"
    assert keys.check_topic(frame_topics("/robot/front")["mono"].image) == "/robot/front/image_rect"
    with pytest.raises(ConfigError, match="fully qualified"):
        frame_topics("cam")
    with pytest.raises(ConfigError, match="rate"):
        publish_frames_ros2(None, [], STEREO, "/cam", rate=-1.0)
