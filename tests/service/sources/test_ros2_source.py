"""The ros2: source over a real zenoh session: frames as ros2/frames.py publishes them in rmw_zenoh's layout."""

from __future__ import annotations

import threading

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.runtime import bus
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.ros2.frames import publish_frames_ros2
from zenslam.service.sources import open_bus_family
from zenslam.service.sources.bus_source import BusFrames
from zenslam.service.sources.config import SourceConfig

CAMERA = PinholeCalibration(40.0, 40.0, 15.5, 11.5, 32, 24, 0.15)


def test_stereo_frames_from_ros2_topics_end_with_the_publishers_tokens():
    rng = np.random.default_rng(4)
    published = [
        SensorFrame(k, 10**9 + k * 10**8, rng.integers(0, 256, (24, 32), dtype=np.uint8), rng.integers(0, 256, (24, 32), dtype=np.uint8))
        for k in range(3)
    ]
    with bus.open_session(bus.BusConfig()) as session:
        stop = threading.Event()
        frames = BusFrames(session, open_bus_family("ros2:/cam", ros_domain=3), SourceConfig(idle_timeout_s=0), stop.is_set)
        got = []
        consumer = threading.Thread(target=lambda: got.extend(frames.frames()))
        consumer.start()
        publish_frames_ros2(session, published, CAMERA, "/cam", domain_id=3, rate=0.0, wait_for_subscribers_s=30.0)
        consumer.join(60)
        stop.set()
    assert not consumer.is_alive()  # the stream ended with the publisher's liveliness tokens
    assert got and got[0].sensor == "stereo" and got[0].calibration == CAMERA
    last = got[-1]
    assert last.frame.stamp_ns == published[-1].stamp_ns
    np.testing.assert_array_equal(last.frame.left, published[-1].left)
    np.testing.assert_array_equal(last.frame.right, published[-1].right)
    assert len(got) + frames.dropped == len(published) and frames.rejected == {}
