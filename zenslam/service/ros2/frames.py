"""Camera frames onto a ROS 2 graph as a ROS 2 camera driver on rmw_zenoh publishes them (``zenslam publish --ros2``).

Topics under ``topic_prefix`` (a fully qualified ROS 2 namespace, e.g. ``/camera``), following
image_transport's convention that an image and its CameraInfo share a namespace; the images are
rectified, so they are ``image_rect``:

- mono and RGB-D: ``<prefix>/image_rect`` (sensor_msgs/Image, mono8) and ``<prefix>/camera_info``;
- stereo: ``<prefix>/left/image_rect``, ``<prefix>/left/camera_info``, ``<prefix>/right/image_rect``,
  ``<prefix>/right/camera_info`` (the right P[0, 3] = -fx * baseline, as stereo_image_proc expects);
- RGB-D depth: ``<prefix>/depth/image_rect`` (32FC1, metres, registered to the image) and
  ``<prefix>/depth/camera_info``.

Every message of a frame carries the frame's stamp; CameraInfo goes with every image, as drivers do.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from zenslam.camera import PinholeCalibration
from zenslam.errors import ConfigError
from zenslam.runtime import bus
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.ros2 import cdr, keys
from zenslam.service.ros2.messages import encode_camera_info, encode_image
from zenslam.service.ros2.publisher import Ros2Node, Ros2Publisher

logger = logging.getLogger(__name__)

_LOSSLESS = keys.Qos(history="keep_all")  # reliable keep-all: rmw_zenoh's publisher blocks rather than drops


@dataclass(frozen=True)
class CameraTopics:
    """The image and CameraInfo topics of one camera."""

    image: str
    camera_info: str


def frame_topics(topic_prefix: str) -> dict[str, CameraTopics]:
    """The topics of each camera (``mono``, ``left``, ``right``, ``depth``) under ``topic_prefix``."""
    prefix = keys.check_topic(topic_prefix)

    def camera(namespace: str) -> CameraTopics:
        return CameraTopics(f"{namespace}/image_rect", f"{namespace}/camera_info")

    return {
        "mono": camera(prefix),
        "left": camera(f"{prefix}/left"),
        "right": camera(f"{prefix}/right"),
        "depth": camera(f"{prefix}/depth"),
    }


class _CameraPublisher:
    def __init__(self, node: Ros2Node, topics: CameraTopics, frame_id: str, calibration: PinholeCalibration, right: bool):
        # Reliable keep-all: a test or demo camera loses no frame on the way, as zenslam publish's
        # foxglove publisher does not (a lagging tracker still drops frames, counted, on its side).
        self.image = node.publisher(topics.image, cdr.IMAGE, _LOSSLESS)
        self.info = node.publisher(topics.camera_info, cdr.CAMERA_INFO, _LOSSLESS)
        self._frame_id, self._calibration, self._right = frame_id, calibration, right

    def put(self, stamp_ns: int, image) -> None:
        self.image.put(encode_image(stamp_ns, self._frame_id, image))
        self.info.put(encode_camera_info(stamp_ns, self._frame_id, self._calibration, right=self._right))

    @property
    def publishers(self) -> tuple[Ros2Publisher, Ros2Publisher]:
        return self.image, self.info


def _wait_for_subscribers(publishers: list[Ros2Publisher], timeout_s: float, stop: Callable[[], bool]) -> None:
    deadline = time.monotonic() + timeout_s
    while not all(p.has_subscribers for p in publishers):
        if time.monotonic() >= deadline or stop():
            missing = [p.topic for p in publishers if not p.has_subscribers]
            logger.warning("no subscriber to %s after %.1f s; publishing anyway", ", ".join(missing), timeout_s)
            return
        time.sleep(0.01)


def publish_frames_ros2(
    session: bus.Session,
    frames: Iterable[SensorFrame],
    calibration: PinholeCalibration,
    topic_prefix: str,
    domain_id: int = 0,
    rate: float = 1.0,
    *,
    node_name: str = "zenslam_camera",
    frame_id: str = "camera",
    wait_for_subscribers_s: float = 0.0,
    stop: Callable[[], bool] = lambda: False,
) -> int:
    """Publish ``frames`` (rectified, of ``calibration``) as a ROS 2 camera node on ``session``; returns
    how many frames were published.

    ``rate`` is the playback speed as a multiple of the frames' stamps (1: as recorded; 0: as fast as
    possible). The left (or only) camera's frame id is ``frame_id``, the right's ``<frame_id>_right``,
    the depth's ``frame_id`` (registered). Before the first frame, waits up to
    ``wait_for_subscribers_s`` seconds for every topic to have a subscriber. ``stop`` ends the
    playback early (checked between frames).
    """
    if rate < 0:
        raise ConfigError(f"rate {rate} must be a non-negative multiple of the recorded rate (0: as fast as possible)")
    topics = frame_topics(topic_prefix)
    published = 0
    with Ros2Node(session, node_name, domain_id) as node:
        cameras: dict[str, _CameraPublisher] = {}

        def camera(name: str, right: bool = False) -> _CameraPublisher:
            if name not in cameras:
                camera_frame = f"{frame_id}_right" if right else frame_id
                cameras[name] = _CameraPublisher(node, topics[name], camera_frame, calibration, right)
            return cameras[name]

        start_wall = start_stamp = None
        for frame in frames:
            if stop():
                break
            stereo = frame.right is not None
            targets = [(camera("left" if stereo else "mono"), frame.left)]
            if stereo:
                targets.append((camera("right", right=True), frame.right))
            if frame.depth_m is not None:
                targets.append((camera("depth"), frame.depth_m))
            if start_wall is None:
                if wait_for_subscribers_s > 0:
                    _wait_for_subscribers([p for c in cameras.values() for p in c.publishers], wait_for_subscribers_s, stop)
                start_wall, start_stamp = time.monotonic(), frame.stamp_ns
            elif rate > 0:
                due = start_wall + (frame.stamp_ns - start_stamp) * 1e-9 / rate
                time.sleep(max(0.0, due - time.monotonic()))
            for target, image in targets:
                target.put(frame.stamp_ns, image)
            published += 1
    logger.info("published %d frames on ROS 2 topics under %s (domain %d)", published, topic_prefix, domain_id)
    return published
