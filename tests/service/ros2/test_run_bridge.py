"""``--ros2-publish``'s options: the domain from the option or ROS_DOMAIN_ID, and the configuration made."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from zenslam.errors import ConfigError
from zenslam.service.ros2.run_bridge import (
    Ros2PublishConfig,
    add_ros2_publish_arguments,
    domain_id_from,
    ros2_publish_config,
)


def _parser(with_domain: bool = False) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    if with_domain:  # another option group (the ros2: source) may have declared --ros-domain already
        parser.add_argument("--ros-domain", dest="ros_domain", type=int, default=None)
    add_ros2_publish_arguments(parser)
    return parser


def test_domain_comes_from_the_option_then_ros_domain_id(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "12")
    assert domain_id_from(4) == 4
    assert domain_id_from(None) == 12
    monkeypatch.setenv("ROS_DOMAIN_ID", "")
    assert domain_id_from(None) == 0
    monkeypatch.setenv("ROS_DOMAIN_ID", "abc")
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID='abc'"):
        domain_id_from(None)


@pytest.mark.parametrize("with_domain", [False, True])
def test_publish_config_from_the_options(monkeypatch, with_domain):
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    parser = _parser(with_domain)
    assert ros2_publish_config(parser.parse_args([])) is None
    args = parser.parse_args(["--ros2-publish", "--ros-domain", "7", "--ros2-zenoh-config", "ros.json5"])
    assert ros2_publish_config(args) == Ros2PublishConfig(domain_id=7, zenoh_config_file=Path("ros.json5"))
    assert ros2_publish_config(parser.parse_args(["--ros2-publish"])).domain_id == 0
