"""CDR messages: bytes made by rosbags' serializer directly decode with zenslam's decoders, and what
zenslam's encoders make reads back through rosbags' deserializer with the values put in."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from zenslam.camera import PinholeCalibration
from zenslam.errors import CalibrationError, MessageError
from zenslam.geometry import make_T, so3_exp
from zenslam.service.ros2 import messages

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
STAMP_NS = 1_700_000_123_456_789_012 % (2**31 * 10**9)


def _header(stamp_ns=STAMP_NS, frame_id="cam"):
    sec, nanosec = divmod(stamp_ns, 10**9)
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id)


def _image_bytes(height, width, encoding, step, data, bigendian=0):
    msg = T["sensor_msgs/msg/Image"](
        header=_header(), height=height, width=width, encoding=encoding, is_bigendian=bigendian, step=step,
        data=np.asarray(data, dtype=np.uint8),
    )
    return bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/Image"))


def _camera_info_bytes(p, k=None, width=640, height=480, frame_id="left"):
    k = np.array([500.0, 0, 320, 0, 501, 240, 0, 0, 1]) if k is None else k
    msg = T["sensor_msgs/msg/CameraInfo"](
        header=_header(frame_id=frame_id), height=height, width=width, distortion_model="plumb_bob",
        d=np.array([0.1, -0.05, 0, 0, 0]), k=np.asarray(k, float), r=np.eye(3).reshape(-1), p=np.asarray(p, float),
        binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )
    return bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/CameraInfo"))


def test_mono8_with_padded_rows():
    pixels = np.arange(12, dtype=np.uint8).reshape(3, 4)
    padded = np.zeros((3, 6), np.uint8)
    padded[:, :4] = pixels
    image = messages.decode_image(_image_bytes(3, 4, "mono8", 6, padded.reshape(-1)))
    assert image.stamp_ns == STAMP_NS and image.frame_id == "cam" and image.encoding == "mono8"
    np.testing.assert_array_equal(image.image, pixels)
    np.testing.assert_array_equal(image.grey(), pixels)


def test_rgb8_comes_out_bgr_and_bgr8_as_is():
    rgb = np.random.default_rng(1).integers(0, 255, (2, 3, 3), dtype=np.uint8)
    image = messages.decode_image(_image_bytes(2, 3, "rgb8", 9, rgb.reshape(-1)))
    np.testing.assert_array_equal(image.image, rgb[:, :, ::-1])
    np.testing.assert_array_equal(image.grey(), cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    bgr = messages.decode_image(_image_bytes(2, 3, "bgr8", 9, rgb.reshape(-1)))
    np.testing.assert_array_equal(bgr.image, rgb)


@pytest.mark.parametrize("bigendian", [0, 1])
def test_16uc1_depth_in_millimetres_becomes_metres(bigendian):
    depth_mm = np.array([[0, 1000], [1500, 65535]], dtype=np.uint16)
    data = depth_mm.astype(">u2" if bigendian else "<u2").tobytes()
    image = messages.decode_image(_image_bytes(2, 2, "16UC1", 4, np.frombuffer(data, np.uint8), bigendian))
    assert image.is_depth and image.image.dtype == np.float32
    np.testing.assert_allclose(image.image, depth_mm / 1000.0, rtol=1e-6)
    with pytest.raises(MessageError, match="depth image has no grey"):
        image.grey()


def test_32fc1_depth_in_metres_with_unknown_as_zero():
    depth = np.array([[1.25, np.nan], [-1.0, 3.5]], dtype=np.float32)
    image = messages.decode_image(_image_bytes(2, 2, "32FC1", 8, np.frombuffer(depth.tobytes(), np.uint8)))
    np.testing.assert_array_equal(image.image, np.array([[1.25, 0.0], [0.0, 3.5]], np.float32))


def test_unsupported_encoding_and_short_data_name_the_topic():
    with pytest.raises(MessageError, match=r"/cam/image.*'yuv422'.*mono8"):
        messages.decode_image(_image_bytes(2, 2, "yuv422", 4, np.zeros(8)), topic="/cam/image")
    with pytest.raises(MessageError, match=r"/cam/image.*needs 4 <= step and 8 bytes of data, got 6"):
        messages.decode_image(_image_bytes(2, 4, "mono8", 4, np.zeros(6)), topic="/cam/image")


def test_compressed_png_jpeg_and_16bit_depth():
    grey = (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64)
    ramp = np.add.outer(np.arange(48) * 2, np.arange(64) * 2).astype(np.uint8)  # smooth: JPEG keeps it
    colour = np.dstack([ramp, 255 - ramp, ramp // 2])

    def compressed(fmt, ext, image):
        data = np.frombuffer(cv2.imencode(ext, image)[1].tobytes(), np.uint8)
        msg = T["sensor_msgs/msg/CompressedImage"](header=_header(), format=fmt, data=data)
        return bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/CompressedImage"))

    png = messages.decode_compressed_image(compressed("png", ".png", grey))
    assert png.encoding == "mono8" and png.stamp_ns == STAMP_NS
    np.testing.assert_array_equal(png.image, grey)
    jpeg = messages.decode_compressed_image(compressed("bgr8; jpeg compressed bgr8", ".jpg", colour))
    assert jpeg.encoding == "bgr8" and jpeg.image.shape == (48, 64, 3)
    assert np.abs(jpeg.image.astype(int) - colour).mean() < 3.0  # lossy
    depth = messages.decode_compressed_image(compressed("png", ".png", (grey.astype(np.uint16) * 100)))
    assert depth.is_depth
    np.testing.assert_allclose(depth.image, grey * 0.1, rtol=1e-6)
    with pytest.raises(MessageError, match="/cam/c.*not a PNG or JPEG"):
        msg = T["sensor_msgs/msg/CompressedImage"](header=_header(), format="png", data=np.arange(50, dtype=np.uint8))
        messages.decode_compressed_image(bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/CompressedImage")), "/cam/c")


def test_camera_info_mono_and_stereo_calibrations():
    left_p = [502.0, 0, 321, 0, 0, 503, 241, 0, 0, 0, 1, 0]
    right_p = [502.0, 0, 321, -502.0 * 0.12, 0, 503, 241, 0, 0, 0, 1, 0]
    left = messages.decode_camera_info(_camera_info_bytes(left_p))
    right = messages.decode_camera_info(_camera_info_bytes(right_p, frame_id="right"))
    assert (left.width, left.height, left.frame_id, left.stamp_ns) == (640, 480, "left", STAMP_NS)
    np.testing.assert_array_equal(left.k, [[500, 0, 320], [0, 501, 240], [0, 0, 1]])
    np.testing.assert_array_equal(left.d, [0.1, -0.05, 0, 0, 0])
    assert left.calibration() == PinholeCalibration(502.0, 503.0, 321.0, 241.0, 640, 480)
    stereo = left.stereo_calibration(right)
    assert (stereo.fx, stereo.cx, stereo.height) == (502.0, 321.0, 480)
    assert math.isclose(stereo.baseline_m, 0.12)
    unrectified = messages.decode_camera_info(_camera_info_bytes(np.zeros(12)))
    assert unrectified.calibration().fx == 500.0  # no P: K's intrinsics
    with pytest.raises(CalibrationError, match="-fx \\* baseline"):
        left.stereo_calibration(left)
    with pytest.raises(CalibrationError, match="image sizes differ"):
        left.stereo_calibration(messages.decode_camera_info(_camera_info_bytes(right_p, width=320)))


def test_imu():
    vector = T["geometry_msgs/msg/Vector3"]
    msg = T["sensor_msgs/msg/Imu"](
        header=_header(frame_id="imu"),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
        angular_velocity=vector(x=0.1, y=-0.2, z=0.3), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vector(x=0.0, y=9.81, z=-0.5), linear_acceleration_covariance=np.zeros(9),
    )
    imu = messages.decode_imu(bytes(TS.serialize_cdr(msg, "sensor_msgs/msg/Imu")))
    assert imu.stamp_ns == STAMP_NS and imu.frame_id == "imu"
    np.testing.assert_array_equal(imu.gyro_rad_s, [0.1, -0.2, 0.3])
    np.testing.assert_array_equal(imu.accel_m_s2, [0.0, 9.81, -0.5])
    np.testing.assert_array_equal(imu.orientation_xyzw, [0, 0, 0, 1])


def test_malformed_payloads_raise_message_error_only():
    """Truncations and random garbage of every input type: MessageError naming the topic, nothing else."""
    good = {
        messages.decode_image: _image_bytes(2, 2, "mono8", 2, np.arange(4)),
        messages.decode_camera_info: _camera_info_bytes(np.zeros(12)),
        messages.decode_compressed_image: bytes(TS.serialize_cdr(
            T["sensor_msgs/msg/CompressedImage"](header=_header(), format="png", data=np.zeros(3, np.uint8)),
            "sensor_msgs/msg/CompressedImage")),
    }
    rng = np.random.default_rng(7)
    for decode, payload in good.items():
        candidates = [payload[:n] for n in range(0, len(payload), 7)]
        candidates += [rng.integers(0, 256, rng.integers(0, 400), dtype=np.uint8).tobytes() for _ in range(100)]
        candidates += [payload[:4] + b"\xff\xff\xff\x7f" + payload[8:]]  # a huge sequence/string length
        for candidate in candidates:
            try:
                decode(candidate, topic="/fuzz")
            except MessageError as exc:
                assert "/fuzz" in str(exc)


def test_encoders_read_back_through_rosbags():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    msg = TS.deserialize_cdr(messages.encode_image(STAMP_NS, "cam", grey), "sensor_msgs/msg/Image")
    assert (msg.encoding, msg.height, msg.width, msg.step, msg.header.frame_id) == ("mono8", 3, 4, 4, "cam")
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == STAMP_NS
    np.testing.assert_array_equal(msg.data, grey.reshape(-1))
    depth = np.array([[0.5, 2.0]], np.float32)
    np.testing.assert_array_equal(messages.decode_image(messages.encode_image(1, "d", depth)).image, depth)
    colour = np.dstack([grey, grey + 1, grey + 2])
    np.testing.assert_array_equal(messages.decode_image(messages.encode_image(1, "c", colour)).image, colour)
    png = TS.deserialize_cdr(messages.encode_compressed_image(1, "c", grey), "sensor_msgs/msg/CompressedImage")
    assert png.format == "png"
    np.testing.assert_array_equal(cv2.imdecode(png.data, cv2.IMREAD_UNCHANGED), grey)

    calibration = PinholeCalibration(700.0, 701.0, 600.0, 180.0, 1226, 370, baseline_m=0.54)
    info = TS.deserialize_cdr(messages.encode_camera_info(5, "right", calibration, right=True), "sensor_msgs/msg/CameraInfo")
    assert (info.width, info.height) == (1226, 370)
    np.testing.assert_allclose(info.p, [700, 0, 600, -700 * 0.54, 0, 701, 180, 0, 0, 0, 1, 0])
    np.testing.assert_allclose(info.k, [700, 0, 600, 0, 701, 180, 0, 0, 1])


def test_pose_path_and_tf_read_back_through_rosbags():
    R = so3_exp(np.array([0.0, 0.0, math.pi / 2]))  # 90 degrees about z
    T_world_cam = make_T(R, np.array([1.0, 2.0, 3.0]))
    pose = TS.deserialize_cdr(messages.encode_pose_stamped(STAMP_NS, "map", T_world_cam), "geometry_msgs/msg/PoseStamped")
    assert pose.header.frame_id == "map"
    p, q = pose.pose.position, pose.pose.orientation
    assert (p.x, p.y, p.z) == (1.0, 2.0, 3.0)
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], [0, 0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-12)

    path = TS.deserialize_cdr(
        messages.encode_path(9, "map", [1, 2], np.stack([np.eye(4), T_world_cam])), "nav_msgs/msg/Path"
    )
    assert [s.header.stamp.nanosec for s in path.poses] == [1, 2] and path.poses[1].pose.position.z == 3.0
    empty = TS.deserialize_cdr(messages.encode_path(9, "map", [], np.zeros((0, 4, 4))), "nav_msgs/msg/Path")
    assert empty.poses == []

    tf = TS.deserialize_cdr(messages.encode_tf(STAMP_NS, "map", "camera", T_world_cam), "tf2_msgs/msg/TFMessage")
    (transform,) = tf.transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("map", "camera")
    assert transform.transform.translation.y == 2.0
    with pytest.raises(MessageError, match="finite 4x4"):
        messages.encode_pose_stamped(1, "map", np.full((4, 4), np.nan))
