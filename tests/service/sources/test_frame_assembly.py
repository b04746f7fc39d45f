"""Frames from separate messages: stereo paired by stamp, the newest kept, the sensor and calibration found."""

from __future__ import annotations

import numpy as np
import pytest

from zenslam.camera import PinholeCalibration
from zenslam.schemas import codec
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.sources.bus_messages import BusCalibration, BusImage, projection_matrix
from zenslam.service.sources.frame_assembly import FrameAssembler
from zenslam.service.sources.zenoh_family import ZenohFamily

CAMERA = PinholeCalibration(50.0, 50.0, 15.5, 11.5, 32, 24, 0.2)
KEYS = {role: key for key, role in ZenohFamily("cam").subscriptions().items()}
MS = 1_000_000


def image(stamp_ns: int, value: int = 0, shape=(24, 32)) -> BusImage:
    return BusImage(stamp_ns, np.full(shape, value, np.uint8))


def calibration(baseline_m: float | None = None, camera: PinholeCalibration = CAMERA) -> BusCalibration:
    return BusCalibration(0, camera.width, camera.height, camera.K, np.zeros(5), projection_matrix(camera, baseline_m))


def stereo(tolerance_ns: int = MS, **kwargs) -> FrameAssembler:
    assembler = FrameAssembler("zenoh:cam", KEYS, pair_tolerance_ns=tolerance_ns, **kwargs)
    assembler.add("left_calibration", calibration())
    assembler.add("right_calibration", calibration(0.2))
    return assembler


def test_stereo_images_are_paired_by_stamp_whatever_their_order():
    assembler = stereo()
    assembler.add("right_image", image(100 * MS, 2))
    assert assembler.take_newest() is None  # a right image alone is no frame
    assembler.add("left_image", image(200 * MS, 3))
    assembler.add("right_image", image(200 * MS + MS // 2, 4))  # within the tolerance
    assembler.add("left_image", image(100 * MS, 1))
    frame = assembler.take_newest()
    assert frame.sensor == "stereo" and frame.calibration == CAMERA
    assert frame.frame.stamp_ns == 200 * MS and frame.frame.left[0, 0] == 3 and frame.frame.right[0, 0] == 4
    # the 100 ms pair was complete and older: dropped, not handed out later
    assert assembler.dropped == 1 and assembler.take_newest() is None


def test_newest_complete_frame_wins_and_a_left_image_waits_for_its_right():
    assembler = stereo()
    for k in range(3):
        assembler.add("left_image", image(k * 100 * MS, k))
        assembler.add("right_image", image(k * 100 * MS, k))
    assembler.add("left_image", image(300 * MS, 3))  # its right image is still on its way
    assert assembler.take_newest().frame.stamp_ns == 200 * MS
    assert assembler.dropped == 2
    assembler.add("right_image", image(300 * MS, 3))
    assert assembler.take_newest().frame.stamp_ns == 300 * MS


def test_an_image_without_partner_is_counted_unpaired():
    assembler = stereo(tolerance_ns=0)
    assembler.add("left_image", image(100 * MS))
    assembler.add("right_image", image(101 * MS))  # 1 ms apart, tolerance 0
    assembler.add("left_image", image(200 * MS))
    assembler.add("right_image", image(200 * MS))
    assert assembler.take_newest().frame.stamp_ns == 200 * MS
    assert assembler.rejected["unpaired"] == 1 and assembler.dropped == 0


def test_frames_wait_for_the_calibration_and_its_baseline():
    assembler = FrameAssembler("zenoh:cam", KEYS)
    assembler.add("left_image", image(0))
    assembler.add("right_image", image(0))
    assert assembler.take_newest() is None
    assembler.add("left_calibration", calibration())
    assert assembler.take_newest() is None and "P[0][3]" in assembler.calibration_problem
    assembler.add("right_calibration", calibration(0.2))
    assert assembler.take_newest().calibration.baseline_m == pytest.approx(0.2)


def test_an_override_replaces_the_calibration_messages_and_mono_takes_the_left_images():
    assembler = FrameAssembler("zenoh:cam", KEYS, calibration=CAMERA, sensor="mono")
    assembler.add("left_calibration", calibration(camera=PinholeCalibration(99.0, 99.0, 16, 12, 32, 24)))
    assembler.add("left_image", image(0, 7))
    frame = assembler.take_newest()
    assert frame.sensor == "mono" and frame.frame.right is None
    assert frame.calibration == PinholeCalibration(50.0, 50.0, 15.5, 11.5, 32, 24)  # override, without its baseline


def test_mono_and_rgbd_cameras_on_the_image_key():
    mono = FrameAssembler("zenoh:cam", KEYS)
    mono.add("calibration", calibration())
    mono.add("image", image(0))
    assert mono.take_newest() is None  # mono or RGB-D? a second image without depth says mono
    mono.add("image", image(MS))
    assert mono.take_newest().sensor == "mono" and mono.dropped == 1
    rgbd = FrameAssembler("zenoh:cam", KEYS)
    rgbd.add("calibration", calibration(0.08))  # RGB-D: the virtual baseline in the camera's own P
    rgbd.add("image", image(0))
    rgbd.add("depth", BusImage(0, np.ones((24, 32), np.float32)))
    frame = rgbd.take_newest()
    assert frame.sensor == "rgbd" and frame.calibration.baseline_m == pytest.approx(0.08) and frame.frame.depth_m is not None


def test_images_of_another_size_than_the_calibration_are_rejected():
    assembler = stereo()
    assembler.add("left_image", image(0, shape=(20, 30)))
    assembler.add("right_image", image(0, shape=(20, 30)))
    assert assembler.take_newest() is None
    assert assembler.rejected["wrong_size"] == 1 and "32x24" in assembler.calibration_problem


def test_zenslam_frames_keep_their_camera_and_another_camera_is_rejected():
    assembler = FrameAssembler("zenoh:cam", KEYS)
    frame = SensorFrame(0, 5, np.zeros((24, 32), np.uint8), np.zeros((24, 32), np.uint8))
    assembler.add("frame", codec.FrameMessage(frame, CAMERA, "stereo", "kitti"))
    taken = assembler.take_newest()
    assert (taken.sensor, taken.calibration, taken.source_name) == ("stereo", CAMERA, "kitti")
    other = PinholeCalibration(60.0, 60.0, 15.5, 11.5, 32, 24, 0.2)
    assembler.add("frame", codec.FrameMessage(SensorFrame(1, 6, frame.left, frame.right), other, "stereo"))
    assert assembler.take_newest() is None and assembler.rejected["camera_changed"] == 1
