"""Playing a dataset or scene onto the bus as a camera driver would (``zenslam publish``).

Each frame goes out under one key prefix in the layout of sources/zenoh_family.py: ``foxglove``
format sends the camera's foxglove.CameraCalibration and then its images (foxglove.RawImage
``mono8``, or a lossless PNG foxglove.CompressedImage; RGB-D depth as RawImage ``32FC1``), each
stamped with the frame's recorded stamp; ``zenslam`` format sends one zenslam.SensorFrame on the
prefix itself. Every payload's zenoh encoding names its protobuf schema. A liveliness token on the
prefix says the camera is up; it goes when publishing ends, which ends a ``zenoh:`` source's stream.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Literal

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import FrameReadError
from zenslam.runtime import bus
from zenslam.schemas import codec
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.pacer import Pacer
from zenslam.service.sources import foxglove_images as fox
from zenslam.service.sources.frame import Source

logger = logging.getLogger(__name__)

PublishFormat = Literal["foxglove", "zenslam"]
ImageFormat = Literal["raw", "png"]


@dataclass(frozen=True)
class PublishOptions:
    """How ``publish_source`` plays a source."""

    key: str  # key prefix, e.g. cam/kitti
    format: PublishFormat = "foxglove"
    image_format: ImageFormat = "raw"  # foxglove format: RawImage mono8 or PNG CompressedImage (both lossless)
    rate: float = 1.0  # multiple of the recorded rate; 0 = as fast as possible
    max_frames: int | None = None  # frames; None: all
    wait_for_subscriber: bool = True  # hold the first frame until something subscribes to the images


class CameraPublisher:
    """The publishers of one camera under ``key`` (declared on entering; a liveliness token with them)."""

    def __init__(self, session: bus.Session, key: str, sensor: SensorKind, fmt: PublishFormat, image_format: ImageFormat):
        self._session = session
        self.key = key.strip("/")
        self.sensor = sensor
        self.format = fmt
        self.image_format = image_format
        self._stack = ExitStack()
        self._publishers: dict[str, bus.Publisher] = {}

    def keys(self) -> dict[str, str]:
        """Key -> schema of every message this camera publishes."""
        if self.format == "zenslam":
            return {self.key: codec.SENSOR_FRAME}
        image = fox.RAW_IMAGE if self.image_format == "raw" else fox.COMPRESSED_IMAGE
        cameras = ("left", "right") if self.sensor == "stereo" else ("",)
        out = {}
        for camera in cameras:
            base = f"{self.key}/{camera}" if camera else self.key
            out[f"{base}/calibration"] = fox.CAMERA_CALIBRATION
            out[f"{base}/image"] = image
        if self.sensor == "rgbd":
            out[f"{self.key}/depth"] = fox.RAW_IMAGE
        return out

    @property
    def image_key(self) -> str:
        """The key of the (left) images: the one a subscriber to this camera surely takes."""
        if self.format == "zenslam":
            return self.key
        return f"{self.key}/left/image" if self.sensor == "stereo" else f"{self.key}/image"

    def __enter__(self) -> CameraPublisher:
        for key, schema in self.keys().items():
            # Lossless: every frame reaches a subscriber that keeps up (a zenoh: source's callback only queues
            # the bytes, and drops and counts what tracking cannot take): frames lost in transit would go uncounted.
            publisher = bus.declare_publisher(self._session, key, schema, "lossless")
            self._publishers[key] = self._stack.enter_context(publisher)
        self._stack.enter_context(bus.declare_token(self._session, self.key))
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def wait_for_subscriber(self, should_stop: Callable[[], bool], poll_s: float = 0.01) -> bool:
        """Wait until something subscribes to the images; False if ``should_stop()`` turned true first."""
        publisher = self._publishers[self.image_key]
        while not publisher.matching_status.matching:
            if should_stop():
                return False
            time.sleep(poll_s)
        return True

    def publish(self, frame: SensorFrame, calibration: PinholeCalibration, source_name: str = "") -> None:
        """Send ``frame``: its calibrations first, then its images, the left one last."""
        for key, payload in self.messages(frame, calibration, source_name).items():
            self._publishers[key].put(payload)

    def messages(self, frame: SensorFrame, calibration: PinholeCalibration, source_name: str = "") -> dict[str, bytes]:
        """Key -> payload of every message of ``frame``, in the order they are sent."""
        if self.format == "zenslam":
            return {self.key: codec.encode_sensor_frame(frame, calibration, self.sensor, source_name, image_encoding="png")}
        stamp, key = frame.stamp_ns, self.key
        encode = fox.encode_raw_image if self.image_format == "raw" else fox.encode_png_image
        if self.sensor == "stereo":
            return {
                f"{key}/left/calibration": fox.encode_camera_calibration(stamp, calibration, f"{key}/left"),
                f"{key}/right/calibration": fox.encode_camera_calibration(stamp, calibration, f"{key}/right", calibration.baseline_m),
                f"{key}/right/image": encode(stamp, frame.right, f"{key}/right"),
                f"{key}/left/image": encode(stamp, frame.left, f"{key}/left"),
            }
        virtual_baseline = calibration.baseline_m if self.sensor == "rgbd" else None
        out = {f"{key}/calibration": fox.encode_camera_calibration(stamp, calibration, key, virtual_baseline)}
        if self.sensor == "rgbd":
            out[f"{key}/depth"] = fox.encode_raw_image(stamp, frame.depth_m.astype("float32"), f"{key}/depth")
        out[f"{key}/image"] = encode(stamp, frame.left, key)
        return out


def publish_source(
    camera: CameraPublisher,
    source: Source,
    options: PublishOptions,
    should_stop: Callable[[], bool],
    on_frame: Callable[[SensorFrame], None] = lambda frame: None,
) -> int:
    """Send the frames of ``source`` through ``camera`` at ``options.rate`` times their recorded rate;
    returns the frames sent. A frame that cannot be read is skipped with a warning (a camera does not
    resend one it failed to capture). ``on_frame`` is called after each frame is sent."""
    if options.wait_for_subscriber and not camera.wait_for_subscriber(should_stop):
        return 0
    pacer = Pacer(options.rate, should_stop)
    count = len(source) if options.max_frames is None else min(len(source), options.max_frames)
    sent = 0
    for frame in readable_frames(source, count):
        if should_stop():
            break
        pacer.wait_for(frame.stamp_ns)
        camera.publish(frame, source.calibration, source.name)
        sent += 1
        on_frame(frame)
    return sent


def readable_frames(source: Source, count: int) -> Iterator[SensorFrame]:
    """The first ``count`` frames of ``source``, read as they are asked for; one that cannot be read
    is skipped with a warning, as a camera does not resend a frame it failed to capture."""
    for index in range(count):
        try:
            yield source.frame(index)
        except FrameReadError as exc:
            logger.warning("not publishing %s", exc)
