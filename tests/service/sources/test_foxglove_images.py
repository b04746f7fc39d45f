"""foxglove images and calibrations, built with foxglove's own classes, decoded to what a frame needs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, MessageError
from zenslam.service.sources import foxglove_images as fox
from zenslam.service.sources.bus_messages import baseline_of, pinhole_of
from zenslam.service.sources.zenoh_family import ZenohFamily, decode_image

RNG = np.random.default_rng(3)
GREY = RNG.integers(0, 256, (6, 5), dtype=np.uint8)


def raw(pixels: np.ndarray, encoding: str, step: int | None = None, sec: int = 12, nsec: int = 345) -> bytes:
    height, width = pixels.shape[:2]
    data = np.ascontiguousarray(pixels).tobytes()
    row = len(data) // height
    if step is not None and step > row:  # padded rows, as some drivers send
        data = b"".join(data[r * row : (r + 1) * row] + b"\0" * (step - row) for r in range(height))
    msg = RawImage(width=width, height=height, encoding=encoding, step=step or row, data=data)
    msg.timestamp.seconds, msg.timestamp.nanos = sec, nsec
    return msg.SerializeToString()


def test_raw_mono8_with_padded_rows_keeps_pixels_and_stamp():
    image = fox.decode_raw_image(raw(GREY, "mono8", step=8), depth=False, where="k")
    assert image.stamp_ns == 12_000_000_345
    np.testing.assert_array_equal(image.pixels, GREY)


def test_raw_colour_becomes_opencv_grey():
    bgr = RNG.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    image = fox.decode_raw_image(raw(bgr, "bgr8"), depth=False, where="k")
    np.testing.assert_array_equal(image.pixels, cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    rgb = fox.decode_raw_image(raw(bgr[..., ::-1], "rgb8"), depth=False, where="k")
    np.testing.assert_array_equal(rgb.pixels, image.pixels)


def test_raw_depth_in_metres_or_millimetres():
    metres = np.array([[0.5, np.nan], [2.0, -1.0]], np.float32)
    decoded = fox.decode_raw_image(raw(metres, "32FC1"), depth=True, where="k").pixels
    np.testing.assert_array_equal(decoded, np.array([[0.5, 0], [2.0, 0]], np.float32))  # unknown depth is 0
    mm = np.array([[500, 0], [2000, 1234]], "<u2")
    decoded = fox.decode_raw_image(raw(mm, "16UC1"), depth=True, where="k").pixels
    np.testing.assert_allclose(decoded, mm / 1000.0, rtol=1e-6)


@pytest.mark.parametrize("fmt,ext", [("png", ".png"), ("jpeg", ".jpg")])
def test_compressed_png_and_jpeg(fmt, ext):
    data = cv2.imencode(ext, GREY)[1].tobytes()
    msg = CompressedImage(format=fmt, data=data)
    msg.timestamp.seconds = 3
    image = fox.decode_compressed_image(msg.SerializeToString(), depth=False, where="k")
    assert image.stamp_ns == 3_000_000_000 and image.pixels.shape == GREY.shape
    if fmt == "png":
        np.testing.assert_array_equal(image.pixels, GREY)


def test_encoders_round_trip_losslessly():
    for encode in (fox.encode_raw_image, fox.encode_png_image):
        payload = encode(7_000_000_001, GREY, "cam")
        np.testing.assert_array_equal(decode_image(payload, False, None, "k").pixels, GREY)  # no schema: tried in turn
    depth = RNG.uniform(0.5, 5.0, (4, 3)).astype(np.float32)
    np.testing.assert_array_equal(decode_image(fox.encode_raw_image(1, depth, "d"), True, fox.RAW_IMAGE, "k").pixels, depth)


def test_calibration_from_p_with_right_camera_baseline():
    msg = CameraCalibration(width=1226, height=370, K=[700, 0, 600, 0, 701, 180, 0, 0, 1], D=[0.1, 0, 0, 0, 0],
                            P=[707.09, 0, 601.89, -379.8, 0, 707.09, 183.11, 0, 0, 0, 1, 0])  # fmt: skip
    calibration = fox.decode_camera_calibration(msg.SerializeToString(), "k")
    pinhole = pinhole_of(calibration, "k")
    assert (pinhole.fx, pinhole.cx, pinhole.cy, pinhole.width) == (707.09, 601.89, 183.11, 1226)  # P, not K: rectified
    assert baseline_of(calibration) == pytest.approx(379.8 / 707.09)


def test_calibration_without_p_needs_zero_distortion():
    msg = CameraCalibration(width=64, height=48, K=[50, 0, 32, 0, 50, 24, 0, 0, 1], D=[0.2, 0, 0, 0, 0])
    calibration = fox.decode_camera_calibration(msg.SerializeToString(), "k")
    with pytest.raises(CalibrationError, match="rectified.*--orbslam-settings"):
        pinhole_of(calibration, "cam/calibration")
    msg.ClearField("D")
    assert pinhole_of(fox.decode_camera_calibration(msg.SerializeToString(), "k"), "k").fx == 50


def test_encoded_calibration_states_the_baseline():
    camera = PinholeCalibration(460.0, 460.0, 319.5, 239.5, 640, 480, 0.1)
    right = fox.decode_camera_calibration(fox.encode_camera_calibration(5, camera, "r", camera.baseline_m), "k")
    assert baseline_of(right) == pytest.approx(0.1) and pinhole_of(right, "k").fx == 460.0
    assert baseline_of(fox.decode_camera_calibration(fox.encode_camera_calibration(5, camera, "l"), "k")) is None


@pytest.mark.parametrize(
    "payload,match",
    [
        (raw(GREY, "mono8")[:-3], "not a foxglove.RawImage|needs"),
        (RawImage(width=100000, height=100000, encoding="mono8", step=100000).SerializeToString(), "larger than"),
        (raw(GREY, "yuv422"), "encoding"),
        (RawImage(width=5, height=6, encoding="mono8", step=2, data=b"\0" * 12).SerializeToString(), "step"),
    ],
)
def test_bad_raw_images_fail_with_message_error(payload, match):
    with pytest.raises(MessageError, match=match):
        fox.decode_raw_image(payload, depth=False, where="cam/image")


def test_compressed_image_claiming_a_huge_size_is_refused_before_decoding():
    png = bytearray(cv2.imencode(".png", GREY)[1].tobytes())
    png[16:24] = (60000).to_bytes(4, "big") * 2  # IHDR width and height
    with pytest.raises(MessageError, match="larger than"):
        fox.decode_compressed_image(CompressedImage(format="png", data=bytes(png)).SerializeToString(), False, "k")


def test_schema_must_match_the_key():
    family = ZenohFamily("cam")
    with pytest.raises(MessageError, match="carries foxglove.CameraCalibration"):
        family.decode("calibration", "cam/calibration", b"", fox.RAW_IMAGE)
    with pytest.raises(MessageError, match="carry foxglove.RawImage or foxglove.CompressedImage"):
        family.decode("image", "cam/image", b"", "foxglove.Log")
