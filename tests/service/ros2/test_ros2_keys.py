"""rmw_zenoh's key expressions, compared with literal keys written from its design document and source."""

from __future__ import annotations

import pytest
import zenoh

from zenslam.errors import ConfigError, MessageError
from zenslam.service.ros2 import cdr, keys

# Published RIHS01 hashes of ROS 2 Jazzy's message packages (the same strings appear in other
# rmw_zenoh-compatible projects' tables and in `ros2 topic info -v` output); String's is the one the
# rmw_zenoh design document's example key carries.
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
POSE_STAMPED_HASH = "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
IMAGE_HASH = "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
CAMERA_INFO_HASH = "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275"
IMU_HASH = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
COMPRESSED_IMAGE_HASH = "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"
ZID = "d579c999b844e3b3f1b7067d92de1e1c"


@pytest.mark.parametrize(
    ("ros_type", "expected"),
    [
        ("std_msgs/msg/String", STRING_HASH),
        (cdr.POSE_STAMPED, POSE_STAMPED_HASH),
        (cdr.IMAGE, IMAGE_HASH),
        (cdr.CAMERA_INFO, CAMERA_INFO_HASH),
        (cdr.IMU, IMU_HASH),
        (cdr.COMPRESSED_IMAGE, COMPRESSED_IMAGE_HASH),
    ],
)
def test_type_hashes_are_the_published_jazzy_hashes(ros_type, expected):
    assert cdr.type_hash(ros_type) == expected


def test_topic_key_is_the_design_documents_layout():
    assert keys.topic_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == (
        "0/chatter/std_msgs::msg::dds_::String_/" + STRING_HASH
    )
    assert keys.topic_key(0, "/zenslam/pose", cdr.POSE_STAMPED, POSE_STAMPED_HASH) == (
        "0/zenslam/pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
    )
    assert keys.topic_key(7, "/robot/camera/image_raw", cdr.IMAGE, IMAGE_HASH) == (
        "7/robot/camera/image_raw/sensor_msgs::msg::dds_::Image_/" + IMAGE_HASH
    )


def test_subscription_key_matches_any_type_of_the_topic_only():
    wildcard = zenoh.KeyExpr(keys.topic_subscription_key(7, "/robot/camera/image_raw"))
    assert str(wildcard) == "7/robot/camera/image_raw/*/*"
    assert wildcard.intersects(zenoh.KeyExpr("7/robot/camera/image_raw/sensor_msgs::msg::dds_::Image_/" + IMAGE_HASH))
    assert not wildcard.intersects(zenoh.KeyExpr("0/robot/camera/image_raw/sensor_msgs::msg::dds_::Image_/" + IMAGE_HASH))
    assert not wildcard.intersects(zenoh.KeyExpr("7/robot/camera/image_raw/compressed/sensor_msgs::msg::dds_::CompressedImage_/" + IMAGE_HASH))


def test_type_and_topic_of_a_key():
    key = "3/robot/camera/image_raw/sensor_msgs::msg::dds_::Image_/" + IMAGE_HASH
    assert keys.type_name_of_key(key) == "sensor_msgs/msg/Image"
    assert keys.topic_of_key(key) == "/robot/camera/image_raw"
    with pytest.raises(MessageError, match="not an rmw_zenoh topic key"):
        keys.type_name_of_key("zenslam/run/frontend/pose")
    with pytest.raises(MessageError, match="not a DDS type name"):
        keys.type_name_of_key("0/chatter/String/" + STRING_HASH)


def test_liveliness_tokens_are_rmw_zenohs():
    node = keys.NodeIdentity(domain_id=0, zid=ZID, node_id=0, name="zenslam")
    assert keys.node_token_key(node) == f"@ros2_lv/0/{ZID}/0/0/NN/%/%/zenslam"
    assert keys.publisher_token_key(node, 1, "/zenslam/pose", cdr.POSE_STAMPED, POSE_STAMPED_HASH) == (
        f"@ros2_lv/0/{ZID}/0/1/MP/%/%/zenslam/%zenslam%pose/geometry_msgs::msg::dds_::PoseStamped_/"
        f"{POSE_STAMPED_HASH}/::,10:,:,:,,"
    )
    namespaced = keys.NodeIdentity(domain_id=3, zid=ZID, node_id=2, name="cam", namespace="/robot/front")
    sensor_qos = keys.Qos(reliability="best_effort", depth=5)
    assert keys.subscription_token_key(namespaced, 4, "/robot/front/image", cdr.IMAGE, IMAGE_HASH, sensor_qos) == (
        f"@ros2_lv/3/{ZID}/2/4/MS/%/%robot%front/cam/%robot%front%image/sensor_msgs::msg::dds_::Image_/"
        f"{IMAGE_HASH}/2::,5:,:,:,,"
    )
    assert keys.graph_key(3) == "@ros2_lv/3/**"


def test_qos_chunk_leaves_rmw_zenohs_defaults_empty():
    assert keys.Qos(depth=42).key_chunk() == "::,:,:,:,,"
    assert keys.Qos(durability="transient_local", depth=1).key_chunk() == ":1:,1:,:,:,,"


@pytest.mark.parametrize("topic", ["pose", "/a//b", "/a/*", "/a/", "/1abc", ""])
def test_bad_topic_names_are_refused(topic):
    with pytest.raises(ConfigError, match="fully qualified"):
        keys.topic_key(0, topic, cdr.POSE_STAMPED, POSE_STAMPED_HASH)


def test_bad_domain_type_and_hash_are_refused():
    with pytest.raises(ConfigError, match="domain id"):
        keys.topic_subscription_key(-1, "/a")
    with pytest.raises(ConfigError, match="package/msg/Type"):
        keys.topic_key(0, "/a", "PoseStamped", POSE_STAMPED_HASH)
    with pytest.raises(ConfigError, match="RIHS01"):
        keys.topic_key(0, "/a", cdr.POSE_STAMPED, "RIHS01_abc")
    with pytest.raises(ConfigError, match="node name"):
        keys.NodeIdentity(domain_id=0, zid=ZID, node_id=0, name="my node")
