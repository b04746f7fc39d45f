"""``zenoh:<prefix>``: frames another program publishes on zenoh, under one key prefix.

The key convention (what a camera driver publishes; ``zenslam publish`` does exactly this):

=============================  ==========================================================
key                            message
=============================  ==========================================================
``<prefix>/image``             mono or RGB-D camera: foxglove.RawImage or CompressedImage
``<prefix>/calibration``       its foxglove.CameraCalibration
``<prefix>/depth``             RGB-D: depth registered to ``image``, foxglove.RawImage 32FC1
                               (metres) or 16UC1 (millimetres), or a 16-bit PNG CompressedImage
``<prefix>/left/image``        stereo: the rectified left image
``<prefix>/left/calibration``  its calibration
``<prefix>/right/image``       the rectified right image, stamped like its left image
``<prefix>/right/calibration`` its calibration, ``P[0][3] = -fx * baseline`` (ROS's convention)
``<prefix>``                   a whole zenslam.SensorFrame (any sensor, calibration inside)
=============================  ==========================================================

Images are taken as rectified; intrinsics come from the calibration's P (K when P is all zeros,
which needs zero distortion). An RGB-D camera states ORB-SLAM's virtual baseline (``bf / fx``) in
its own calibration's ``P[0][3]``. ``--orbslam-settings`` replaces every calibration message.
Stereo images are paired by their stamps. A publisher declares a liveliness token on ``<prefix>``
(or any key under it): the stream ends when the tokens go away.

The message type is read from the zenoh encoding's schema (``application/protobuf;foxglove.RawImage``);
without one, image payloads are tried as RawImage then CompressedImage.
"""

from __future__ import annotations

from zenslam.errors import MessageError, SourceSpecError
from zenslam.schemas import codec
from zenslam.service.sources import foxglove_images as fox
from zenslam.service.sources.bus_messages import BusImage, BusMessage, Role

_SUFFIXES: dict[str, Role] = {
    "": "frame",
    "/image": "image",
    "/calibration": "calibration",
    "/depth": "depth",
    "/left/image": "left_image",
    "/left/calibration": "left_calibration",
    "/right/image": "right_image",
    "/right/calibration": "right_calibration",
}


def check_prefix(prefix: str, spec: str) -> str:
    """``prefix`` if it is a plain zenoh key (no wildcards, no empty chunks); SourceSpecError otherwise."""
    chunks = prefix.split("/")
    if not prefix or any(not chunk or set(chunk) & set("*$?#") for chunk in chunks):
        raise SourceSpecError(
            f"source {spec!r}: {prefix!r} is not a plain zenoh key; use zenoh:<key>, e.g. zenoh:cam/front "
            "(images on cam/front/image, cam/front/left/image, ...)"
        )
    return prefix


class ZenohFamily:
    """The foxglove/zenslam protobuf messages under ``prefix`` (spec ``zenoh:<prefix>``)."""

    def __init__(self, prefix: str):
        self.prefix = check_prefix(prefix.strip("/"), f"zenoh:{prefix}")

    @property
    def name(self) -> str:
        return f"zenoh:{self.prefix}"

    def subscriptions(self) -> dict[str, Role]:
        return {self.prefix + suffix: role for suffix, role in _SUFFIXES.items()}

    def liveliness_key(self) -> str:
        return f"{self.prefix}/**"

    def decode(self, role: Role, key: str, payload: bytes, schema: str | None) -> BusMessage | codec.EndOfStream:
        where = f"{key} ({schema or 'no schema'})"
        if role == "frame":
            if schema not in (None, codec.SENSOR_FRAME):
                raise MessageError(f"{where}: the key {key} carries {codec.SENSOR_FRAME} messages")
            return codec.decode_sensor_frame(payload)
        if role.endswith("calibration"):
            if schema not in (None, fox.CAMERA_CALIBRATION):
                raise MessageError(f"{where}: the key {key} carries {fox.CAMERA_CALIBRATION} messages")
            return fox.decode_camera_calibration(payload, where)
        return decode_image(payload, role == "depth", schema, where)


def decode_image(payload: bytes, depth: bool, schema: str | None, where: str) -> BusImage:
    """A RawImage or CompressedImage as ``schema`` says; without a schema, RawImage first (protobuf
    parses one message type as another without complaint, so the first one that decodes wins)."""
    if schema == fox.RAW_IMAGE:
        return fox.decode_raw_image(payload, depth, where)
    if schema == fox.COMPRESSED_IMAGE:
        return fox.decode_compressed_image(payload, depth, where)
    if schema is not None:
        raise MessageError(f"{where}: image keys carry {fox.RAW_IMAGE} or {fox.COMPRESSED_IMAGE} messages")
    try:
        return fox.decode_raw_image(payload, depth, where)
    except MessageError as raw_error:
        try:
            return fox.decode_compressed_image(payload, depth, where)
        except MessageError:
            raise raw_error from None
