"""EuRoC MAV (ASL layout) stereo + IMU sequences, undistorted and stereo-rectified on the fly.

Layout: ``<sequence>/mav0/{cam0,cam1}/data.csv`` (``#timestamp [ns],filename``) with images in
``data/``, ``sensor.yaml`` per sensor (``%YAML:1.0`` header, pinhole intrinsics, radial-tangential
distortion, resolution, ``T_BS`` sensor-to-body), ``mav0/imu0/data.csv`` (ns, gyro rad/s, accel
m/s^2). Ground truth is ``<sequence>/groundtruth_cam0.csv`` (cam0 poses: ns, x y z, qw qx qy qz)
when present, else ``mav0/state_groundtruth_estimate0/data.csv`` (body poses); both are turned
into poses of the rectified left camera. GT stamps need not coincide with image stamps.

Stereo pairing (decided for real, incomplete recordings): left and right rows are paired by
timestamp (the cameras are hardware-synchronised, so stamps are equal; ``stereo_max_gap_ns``
allows a small tolerance), rows whose image file is missing are dropped at index time, never
mid-iteration, and one warning names the ``mav0`` folder and counts every dropped row. No pair
left is a DatasetError.

Rectification: ``cv2.stereoRectify`` (alpha 0, CALIB_ZERO_DISPARITY) and
``cv2.initUndistortRectifyMap`` computed once; the calibration is the rectified left camera
(fx from P1, baseline from P2).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, DatasetError
from zenslam.geometry import invert_T, make_T, quat_wxyz_to_R
from zenslam.service.sources.csv_util import (
    associate_stamps,
    check_increasing,
    parse_float_table,
    parse_ns,
    read_rows,
)
from zenslam.service.sources.frame import ImuSamples, SensorFrame, check_frame_index, reading_frame
from zenslam.service.sources.images import read_grey
from zenslam.trajectory import Trajectory

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EurocConfig:
    """How EuRoC camera rows are paired into stereo frames."""

    stereo_max_gap_ns: int = 1_000_000  # ns; largest left/right stamp difference accepted as one stereo pair


@dataclass(frozen=True)
class AslCamera:
    """One ASL ``sensor.yaml`` camera: raw intrinsics K (3x3 px), distortion (k1 k2 p1 p2 [k3]), size, T_body_cam."""

    K: np.ndarray
    distortion: np.ndarray
    width: int
    height: int
    T_body_cam: np.ndarray


@dataclass(frozen=True)
class StereoRectification:
    """The rectified left camera and the maps that produce rectified images from raw ones."""

    calibration: PinholeCalibration
    T_cam0_rect: np.ndarray  # 4x4; maps rectified-left coordinates to raw cam0 coordinates (pure rotation)
    maps_left: tuple[np.ndarray, np.ndarray]
    maps_right: tuple[np.ndarray, np.ndarray]


def read_asl_yaml(path: Path) -> dict:
    """A ``sensor.yaml`` mapping; the OpenCV ``%YAML:1.0`` header line is stripped before parsing."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"EuRoC sensor file {path} does not exist; every ASL sensor folder has a sensor.yaml")
    text = path.read_text()
    if text.startswith("%YAML"):
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"EuRoC sensor file {path} is not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise CalibrationError(f"EuRoC sensor file {path} must hold a mapping of sensor parameters")
    return data


def _numbers(data: dict, key: str, count: tuple[int, ...], path: Path) -> np.ndarray:
    value = data.get(key)
    if value is None:
        raise CalibrationError(f"EuRoC sensor file {path} lacks '{key}'")
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"EuRoC sensor file {path}: '{key}' must be a list of numbers, got {value!r}") from None
    if array.size not in count or not np.all(np.isfinite(array)):
        raise CalibrationError(
            f"EuRoC sensor file {path}: '{key}' has {array.size} values {array.tolist()}, expected "
            f"{' or '.join(map(str, count))} finite numbers"
        )
    return array


def read_T_BS(data: dict, path: Path) -> np.ndarray:
    """The sensor-to-body transform ``T_BS`` (4x4) of a sensor.yaml mapping, checked to be rigid."""
    block = data.get("T_BS")
    if not isinstance(block, dict):
        raise CalibrationError(f"EuRoC sensor file {path} lacks the extrinsic 'T_BS' (rows, cols, data)")
    T = _numbers(block, "data", (16,), path).reshape(4, 4)
    R = T[:3, :3]
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-4) and np.linalg.det(R) > 0 and np.allclose(T[3], [0, 0, 0, 1])):
        raise CalibrationError(f"EuRoC sensor file {path}: T_BS is not a rigid transform:\n{T}")
    return T


def read_asl_camera(path: Path) -> AslCamera:
    """Parse a pinhole, radial-tangential ASL camera ``sensor.yaml``."""
    data = read_asl_yaml(path)
    model = data.get("camera_model", "pinhole")
    distortion_model = data.get("distortion_model", "radial-tangential")
    if model != "pinhole" or distortion_model not in ("radial-tangential", "radtan"):
        raise CalibrationError(
            f"EuRoC sensor file {path}: camera_model={model!r}, distortion_model={distortion_model!r}; only pinhole "
            "with radial-tangential distortion is supported"
        )
    fu, fv, cu, cv = _numbers(data, "intrinsics", (4,), path)
    if not (fu > 0 and fv > 0):
        raise CalibrationError(f"EuRoC sensor file {path}: focal lengths fu={fu}, fv={fv} must be positive pixels")
    width, height = _numbers(data, "resolution", (2,), path)
    if not (width > 0 and height > 0 and width == int(width) and height == int(height)):
        raise CalibrationError(f"EuRoC sensor file {path}: resolution {width}x{height} must be positive integers")
    distortion = _numbers(data, "distortion_coefficients", (4, 5), path)
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return AslCamera(K, distortion, int(width), int(height), read_T_BS(data, path))


def rectify_stereo(cam0: AslCamera, cam1: AslCamera, where: Path) -> StereoRectification:
    """Undistort-and-rectify maps for both cameras and the rectified left calibration (baseline in metres)."""
    if (cam0.width, cam0.height) != (cam1.width, cam1.height):
        raise CalibrationError(
            f"EuRoC sequence {where}: cam0 is {cam0.width}x{cam0.height} but cam1 is {cam1.width}x{cam1.height}; "
            "stereo rectification needs equal sizes"
        )
    size = (cam0.width, cam0.height)
    T_cam1_cam0 = invert_T(cam1.T_body_cam) @ cam0.T_body_cam
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        cam0.K, cam0.distortion, cam1.K, cam1.distortion, size,
        T_cam1_cam0[:3, :3].copy(), T_cam1_cam0[:3, 3].reshape(3, 1).copy(),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0,
    )  # fmt: skip
    baseline_m = -P2[0, 3] / P2[0, 0]
    calibration = PinholeCalibration(
        fx=float(P1[0, 0]),
        fy=float(P1[1, 1]),
        cx=float(P1[0, 2]),
        cy=float(P1[1, 2]),
        width=cam0.width,
        height=cam0.height,
        baseline_m=float(baseline_m),
    )
    maps_left = cv2.initUndistortRectifyMap(cam0.K, cam0.distortion, R1, P1, size, cv2.CV_32FC1)
    maps_right = cv2.initUndistortRectifyMap(cam1.K, cam1.distortion, R2, P2, size, cv2.CV_32FC1)
    # R1 rotates raw cam0 coordinates into the rectified frame: p_rect = R1 p_cam0.
    T_cam0_rect = make_T(R1.T, np.zeros(3))
    return StereoRectification(calibration, T_cam0_rect, tuple(maps_left), tuple(maps_right))


def read_camera_rows(cam_dir: Path) -> tuple[np.ndarray, list[Path], list[bool]]:
    """Stamps (ns), image paths and whether each file exists, from ``cam_dir/data.csv``."""
    csv_path = cam_dir / "data.csv"
    rows = read_rows(csv_path, "EuRoC camera list", 2, sep=",")
    stamps = np.array([parse_ns(r.fields[0], csv_path, r.line) for r in rows], dtype=np.int64)
    check_increasing(stamps, [r.line for r in rows], csv_path)
    data_dir = cam_dir / "data"
    if not data_dir.is_dir():
        raise DatasetError(f"EuRoC image folder {data_dir} does not exist; check the dataset folder is complete")
    present = set(os.listdir(data_dir))
    paths = [data_dir / r.fields[1] for r in rows]
    return stamps, paths, [p.name in present for p in paths]


def pose_rows_to_T(path: Path, what: str, min_columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (ns) and T_world_sensor (N, 4, 4) from rows ``ns, x, y, z, qw, qx, qy, qz[, ...]``."""
    rows = read_rows(path, what, min_columns, sep=",")
    stamps = np.array([parse_ns(r.fields[0], path, r.line) for r in rows], dtype=np.int64)
    check_increasing(stamps, [r.line for r in rows], path)
    values = parse_float_table(rows, 1, 7, path)
    poses = np.empty((len(rows), 4, 4))
    for k, row_values in enumerate(values):
        poses[k] = make_T(quat_wxyz_to_R(row_values[3:7]), row_values[:3])
    return stamps, poses


class EurocSource:
    """A EuRoC ASL sequence as a lazy, rectified stereo Source; ``sequence_dir`` contains ``mav0/``."""

    def __init__(self, sequence_dir: Path, config: EurocConfig = EurocConfig()) -> None:
        self._dir = Path(sequence_dir).absolute()
        self._config = config
        self._mav0 = self._dir / "mav0"
        if not self._mav0.is_dir():
            raise DatasetError(
                f"EuRoC sequence folder {self._dir} has no mav0/ folder; pass the folder that contains mav0"
            )
        self._cam0 = read_asl_camera(self._mav0 / "cam0" / "sensor.yaml")
        cam1 = read_asl_camera(self._mav0 / "cam1" / "sensor.yaml")
        self._rect = rectify_stereo(self._cam0, cam1, self._mav0)
        self._shape = (self._cam0.height, self._cam0.width)
        self._stamps, self._left, self._right = self._index_pairs()
        self._imu: ImuSamples | None = None

    def _index_pairs(self) -> tuple[np.ndarray, list[Path], list[Path]]:
        s0, p0, ok0 = read_camera_rows(self._mav0 / "cam0")
        s1, p1, ok1 = read_camera_rows(self._mav0 / "cam1")
        keep0, keep1 = np.flatnonzero(ok0), np.flatnonzero(ok1)
        i0, i1 = associate_stamps(s0[keep0], s1[keep1], self._config.stereo_max_gap_ns)
        i0, i1 = keep0[i0], keep1[i1]
        missing = (len(s0) - len(keep0), len(s1) - len(keep1))
        unpaired = (len(keep0) - len(i0), len(keep1) - len(i1))
        if sum(missing) + sum(unpaired):
            log.warning(
                "EuRoC %s: kept %d stereo pairs; dropped %d rows whose image file is missing (cam0 %d, cam1 %d) and "
                "%d rows without a partner within %d ns (cam0 %d, cam1 %d)",
                self._mav0, len(i0), sum(missing), *missing,
                sum(unpaired), self._config.stereo_max_gap_ns, *unpaired,
            )  # fmt: skip
        if len(i0) == 0:
            raise DatasetError(
                f"EuRoC sequence {self._mav0}: no stereo pair left ({len(s0)} cam0 rows, {len(s1)} cam1 rows, "
                f"{sum(missing)} with missing images); check cam0/cam1 data.csv and data/ folders"
            )
        return s0[i0], [p0[i] for i in i0], [p1[i] for i in i1]

    @property
    def name(self) -> str:
        return f"euroc/{self._dir.name}"

    @property
    def sensor(self) -> SensorKind:
        return "stereo"

    @property
    def calibration(self) -> PinholeCalibration:
        return self._rect.calibration

    @property
    def T_body_cam(self) -> np.ndarray:
        """4x4 pose of the rectified left camera in the body (IMU) frame."""
        return self._cam0.T_body_cam @ self._rect.T_cam0_rect

    def __len__(self) -> int:
        return len(self._stamps)

    def __iter__(self) -> Iterator[SensorFrame]:
        for i in range(len(self._stamps)):
            yield self.frame(i)

    def frame(self, index: int) -> SensorFrame:
        """Rectified stereo pair ``index``; FrameReadError names the image that cannot be read."""
        check_frame_index(self.name, index, len(self))
        (l1, l2), (r1, r2) = self._rect.maps_left, self._rect.maps_right
        with reading_frame(index):
            raw_left = read_grey(self._left[index], self._shape)
            raw_right = read_grey(self._right[index], self._shape)
        left = cv2.remap(raw_left, l1, l2, cv2.INTER_LINEAR)
        right = cv2.remap(raw_right, r1, r2, cv2.INTER_LINEAR)
        return SensorFrame(index=index, stamp_ns=int(self._stamps[index]), left=left, right=right)

    def stamps_ns(self) -> np.ndarray:
        """Stamps (N,) int64 ns of the kept stereo pairs (the cam0 stamps)."""
        return self._stamps.copy()

    def ground_truth(self) -> Trajectory | None:
        """Poses of the rectified left camera at the ground-truth file's own stamps, or None."""
        cam_file = self._dir / "groundtruth_cam0.csv"
        body_file = self._mav0 / "state_groundtruth_estimate0" / "data.csv"
        if cam_file.is_file():
            stamps, T_world_cam0 = pose_rows_to_T(cam_file, "EuRoC cam0 ground truth", 8)
        elif body_file.is_file():
            stamps, T_world_sensor = pose_rows_to_T(body_file, "EuRoC ground truth", 8)
            gt_yaml = body_file.parent / "sensor.yaml"
            T_body_sensor = read_T_BS(read_asl_yaml(gt_yaml), gt_yaml) if gt_yaml.is_file() else np.eye(4)
            T_world_cam0 = T_world_sensor @ invert_T(T_body_sensor) @ self._cam0.T_body_cam
        else:
            log.info("no EuRoC ground truth in %s or %s", cam_file, body_file)
            return None
        return Trajectory(stamps, T_world_cam0 @ self._rect.T_cam0_rect)

    def imu(self) -> ImuSamples | None:
        """IMU samples of ``mav0/imu0`` with T_cam_imu for the rectified left camera, or None when absent."""
        if self._imu is None:
            self._imu = self._read_imu()
        return self._imu

    def _read_imu(self) -> ImuSamples | None:
        imu_dir = self._mav0 / "imu0"
        csv_path = imu_dir / "data.csv"
        if not csv_path.is_file():
            log.info("no EuRoC IMU at %s", csv_path)
            return None
        yaml_path = imu_dir / "sensor.yaml"
        T_body_imu = read_T_BS(read_asl_yaml(yaml_path), yaml_path)
        rows = read_rows(csv_path, "EuRoC IMU file", 7, sep=",")
        stamps = np.array([parse_ns(r.fields[0], csv_path, r.line) for r in rows], dtype=np.int64)
        check_increasing(stamps, [r.line for r in rows], csv_path)
        values = parse_float_table(rows, 1, 6, csv_path)
        T_cam_imu = invert_T(self.T_body_cam) @ T_body_imu
        return ImuSamples(stamps, values[:, :3].copy(), values[:, 3:6].copy(), T_cam_imu)
