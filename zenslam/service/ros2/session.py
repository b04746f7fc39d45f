"""The zenoh session zenslam joins a ROS 2 graph with: rmw_zenoh's default session configuration, or a file.

rmw_zenoh's nodes run as zenoh peers that connect to a router on the same machine
(``ros2 run rmw_zenoh_cpp rmw_zenohd``, listening on tcp/localhost:7447), with multicast scouting
off; they learn about each other through the router and then talk peer to peer
(rmw_zenoh_cpp/config/DEFAULT_RMW_ZENOH_SESSION_CONFIG.json5, docs/design.md "Router"). zenslam
does the same by default, so it appears on the robot's graph like any node; a zenoh JSON5 file
(rmw_zenoh's ``ZENOH_SESSION_CONFIG_URI`` file works) replaces that for other setups.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from zenslam.errors import BusError
from zenslam.runtime import bus

RMW_ZENOH_ROUTER = "tcp/localhost:7447"  # where rmw_zenohd listens by default


def ros2_zenoh_config(config_file: Path | None = None) -> zenoh.Config:
    """``config_file`` as a zenoh config, or rmw_zenoh's default session settings when None."""
    if config_file is not None:
        return bus.zenoh_config_from_file(config_file, "ROS 2 zenoh config")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("connect/endpoints", json.dumps([RMW_ZENOH_ROUTER]))
    config.insert_json5("listen/endpoints", json.dumps(["tcp/localhost:0"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


@contextmanager
def open_ros2_session(config_file: Path | None = None) -> Iterator[zenoh.Session]:
    """A zenoh session on the ROS 2 graph (see ``ros2_zenoh_config``), closed on exit."""
    try:
        session = zenoh.open(ros2_zenoh_config(config_file))
    except zenoh.ZError as exc:
        where = config_file or f"rmw_zenoh's default settings (router {RMW_ZENOH_ROUTER})"
        raise BusError(f"cannot open the ROS 2 zenoh session with {where}: {exc}") from exc
    try:
        yield session
    finally:
        session.close()
