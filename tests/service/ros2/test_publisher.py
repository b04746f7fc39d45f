"""A Ros2Node's publications over zenoh on loopback: the key, the attachment and the graph tokens a
ROS 2 node on rmw_zenoh would see."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from zenslam.runtime import bus
from zenslam.service.ros2 import cdr, keys
from zenslam.service.ros2.attachment import decode_attachment
from zenslam.service.ros2.messages import encode_pose_stamped
from zenslam.service.ros2.publisher import Ros2Node, gid_of
from zenslam.service.ros2.session import open_ros2_session

POSE_KEY = "0/zenslam/pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"


def test_gid_is_xxh3_128_low_half_first():
    # XXH3-128 of the empty input is 99aa06d3014798d86001c324468d497f (high 64 bits printed first).
    assert gid_of("") == bytes.fromhex("99aa06d3014798d86001c324468d497f")[::-1]


def _wait_for(condition, what: str, timeout_s: float = 20.0):
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.01)


@pytest.fixture
def ros_graph(tmp_path):
    """A listening zenoh session standing for the robot's router and a ROS 2 subscriber, and the JSON5
    config with which zenslam's ROS 2 session connects to it."""
    endpoint = bus.free_tcp_endpoint()
    config = zenoh.Config()
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config_file = tmp_path / "ros2_session.json5"
    config_file.write_text(json.dumps({"mode": "peer", "connect": {"endpoints": [endpoint]},
                                       "scouting": {"multicast": {"enabled": False}}}))  # fmt: skip
    with zenoh.open(config) as robot:
        yield robot, config_file


def test_publication_round_trip_with_attachment_and_graph_tokens(ros_graph):
    robot, config_file = ros_graph
    tokens = robot.liveliness().declare_subscriber(keys.graph_key(0), zenoh.handlers.FifoChannel(64), history=True)
    samples = robot.declare_subscriber(keys.topic_subscription_key(0, "/zenslam/pose"), zenoh.handlers.FifoChannel(16))
    with open_ros2_session(config_file) as session, Ros2Node(session, "zenslam") as node:
        publisher = node.publisher("/zenslam/pose", cdr.POSE_STAMPED)
        zid = str(session.zid())
        expected_tokens = {
            f"@ros2_lv/0/{zid}/0/0/NN/%/%/zenslam",
            f"@ros2_lv/0/{zid}/0/1/MP/%/%/zenslam/%zenslam%pose/geometry_msgs::msg::dds_::PoseStamped_/"
            "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8/::,10:,:,:,,",
        }
        seen: set[str] = set()

        def tokens_arrived():
            while (sample := tokens.try_recv()) is not None:
                seen.add(str(sample.key_expr))
            return expected_tokens <= seen

        subscription = node.announce_subscription("/camera/image_rect", cdr.IMAGE, keys.Qos(reliability="best_effort", depth=5))
        expected_tokens.add(
            f"@ros2_lv/0/{zid}/0/2/MS/%/%/zenslam/%camera%image_rect/sensor_msgs::msg::dds_::Image_/"
            "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47/2::,5:,:,:,,"
        )
        _wait_for(tokens_arrived, "the node's, the publisher's and the subscription's liveliness tokens")
        subscription.undeclare()
        _wait_for(lambda: publisher.has_subscribers, "the subscription to reach the publisher")
        for i in range(3):
            publisher.put(encode_pose_stamped(1000 + i, "map", np.eye(4)), source_timestamp_ns=5_000 + i)
        received = []

        def publications_arrived():
            while (sample := samples.try_recv()) is not None:
                received.append(sample)
            return len(received) >= 3

        _wait_for(publications_arrived, "three publications")
        assert publisher.token_key in expected_tokens
    typestore = get_typestore(Stores.ROS2_JAZZY)
    for i, sample in enumerate(received):
        assert str(sample.key_expr) == POSE_KEY
        attachment = decode_attachment(sample.attachment.to_bytes())
        assert (attachment.sequence_number, attachment.source_timestamp_ns) == (i + 1, 5_000 + i)
        assert attachment.source_gid == gid_of(publisher.token_key) == publisher.gid
        pose = typestore.deserialize_cdr(sample.payload.to_bytes(), cdr.POSE_STAMPED)
        assert (pose.header.stamp.nanosec, pose.header.frame_id, pose.pose.orientation.w) == (1000 + i, "map", 1.0)
    tokens.undeclare()
    samples.undeclare()
