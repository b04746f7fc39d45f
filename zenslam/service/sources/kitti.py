"""KITTI odometry sequences (rectified grey pairs, calib.txt, times.txt, poses/NN.txt).

Layout: ``<root>/sequences/NN/{image_0,image_1}/%06d.png``, ``calib.txt`` (rectified projection
matrices P0..P3, optionally Tr), ``times.txt`` (seconds, one per frame) and, when published,
``<root>/poses/NN.txt`` (3x4 row-major T_world_cam0 per frame, world = first camera). The image
size is taken from the first left image; every other image must match it.

Monocular clips are often shared as ``image_0`` alone (ORB-SLAM3's monocular KITTI example reads
nothing else): such a folder is a monocular source when the run asks for one (``--sensor mono``),
and then ``calib.txt`` needs only P0.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, DatasetError
from zenslam.service.sources.csv_util import check_increasing, parse_floats, parse_seconds_ns, read_rows
from zenslam.service.sources.frame import ImuSamples, SensorFrame, check_frame_index, reading_frame
from zenslam.service.sources.images import image_size, read_grey
from zenslam.trajectory import Trajectory

log = logging.getLogger(__name__)


def read_kitti_calibration(calib_path: Path, width: int, height: int, stereo: bool = True) -> PinholeCalibration:
    """Rectified left calibration from KITTI ``calib.txt``: fx = P0[0,0], baseline_m = -P1[0,3] / P1[0,0];
    with ``stereo`` False only P0 is needed and the calibration has no baseline."""
    calib_path = Path(calib_path)
    if not calib_path.is_file():
        raise CalibrationError(f"KITTI calibration {calib_path} does not exist; every sequence folder has a calib.txt")
    matrices: dict[str, np.ndarray] = {}
    for number, text in enumerate(calib_path.read_text().splitlines(), start=1):
        if not text.strip():
            continue
        key, _, values = text.partition(":")
        numbers = parse_floats(values.split(), calib_path, number)
        if numbers.size != 12:
            raise CalibrationError(
                f"KITTI calibration {calib_path}, line {number}: {key.strip()} has {numbers.size} values, "
                "expected 12 (3x4)"
            )
        matrices[key.strip()] = numbers.reshape(3, 4)
    needed = ("P0", "P1") if stereo else ("P0",)
    missing = [k for k in needed if k not in matrices]
    if missing:
        raise CalibrationError(
            f"KITTI calibration {calib_path} lacks {missing}; it needs the rectified {' and '.join(needed)}"
        )
    P0 = matrices["P0"]
    focal = {"P0[0,0]": P0[0, 0], "P0[1,1]": P0[1, 1]} | ({"P1[0,0]": matrices["P1"][0, 0]} if stereo else {})
    if not all(value > 0 for value in focal.values()):
        named = ", ".join(f"{key}={value}" for key, value in focal.items())
        raise CalibrationError(f"KITTI calibration {calib_path}: focal lengths {named} must be positive pixels")
    return PinholeCalibration(
        fx=float(P0[0, 0]),
        fy=float(P0[1, 1]),
        cx=float(P0[0, 2]),
        cy=float(P0[1, 2]),
        width=int(width),
        height=int(height),
        baseline_m=_baseline_m(calib_path, matrices["P1"]) if stereo else None,
    )


def _baseline_m(calib_path: Path, P1: np.ndarray) -> float:
    """Stereo baseline (m) from the rectified right projection P1 = K [I | (-fx * baseline, 0, 0)]."""
    baseline_m = -P1[0, 3] / P1[0, 0]
    if not baseline_m > 0:
        raise CalibrationError(
            f"KITTI calibration {calib_path}: P1[0,3]={P1[0, 3]} gives baseline {baseline_m} m; the right camera "
            "must be a positive distance to the right (P1[0,3] = -fx * baseline)"
        )
    return float(baseline_m)


def read_kitti_poses(path: Path) -> np.ndarray:
    """T_world_cam0 (N, 4, 4) from a KITTI pose file (one 3x4 row-major matrix per line)."""
    rows = read_rows(path, "KITTI pose file", 12)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    for k, row in enumerate(rows):
        if len(row.fields) != 12:
            raise DatasetError(f"KITTI pose file {path}, line {row.line}: expected 12 values, got {len(row.fields)}")
        poses[k, :3, :] = parse_floats(row.fields, path, row.line).reshape(3, 4)
    return poses


class KittiSource:
    """A KITTI odometry sequence as a lazy Source; ``sequence_dir`` is ``<root>/sequences/NN``.

    A stereo source when the folder has image_0 and image_1; with ``mono_allowed`` (the run plays
    the source as mono) a folder with image_0 alone is a monocular source instead of an error.
    """

    def __init__(self, sequence_dir: Path, mono_allowed: bool = False) -> None:
        self._dir = Path(sequence_dir).absolute()
        if not self._dir.is_dir():
            raise DatasetError(
                f"KITTI sequence folder {self._dir} does not exist; pass <root>/sequences/NN of the odometry dataset"
            )
        self._left = self._list_images("image_0")
        stereo = (self._dir / "image_1").exists() or not mono_allowed
        self._right = self._list_images("image_1") if stereo else None
        if self._right is not None and len(self._left) != len(self._right):
            raise DatasetError(
                f"KITTI sequence {self._dir}: image_0 has {len(self._left)} images but image_1 has "
                f"{len(self._right)}; every left image needs its right partner"
            )
        times_path = self._dir / "times.txt"
        rows = read_rows(times_path, "KITTI times file", 1)
        self._stamps = np.array([parse_seconds_ns(r.fields[0], times_path, r.line) for r in rows], dtype=np.int64)
        check_increasing(self._stamps, [r.line for r in rows], times_path)
        if len(self._left) != len(self._stamps):
            raise DatasetError(
                f"KITTI sequence {self._dir}: {len(self._left)} images in image_0 but {len(self._stamps)} stamps in "
                f"{times_path}; the counts must be equal"
            )
        self._check_names()
        height, width = image_size(self._left[0])
        self._shape = (height, width)
        self._calibration = read_kitti_calibration(self._dir / "calib.txt", width, height, stereo)

    def _list_images(self, folder: str) -> list[Path]:
        path = self._dir / folder
        if not path.is_dir():
            raise DatasetError(
                f"KITTI image folder {path} does not exist; a stereo sequence has image_0 and image_1, and "
                "`--sensor mono` (source.sensor: mono) runs a sequence with image_0 alone"
            )
        images = sorted(path.glob("*.png"))
        if not images:
            raise DatasetError(f"KITTI image folder {path} holds no .png images")
        return images

    def _check_names(self) -> None:
        expected = [f"{i:06d}.png" for i in range(len(self._stamps))]
        for images in [self._left] if self._right is None else [self._left, self._right]:
            names = [p.name for p in images]
            if names != expected:
                first = next(i for i, (a, b) in enumerate(zip(names, expected)) if a != b)
                raise DatasetError(
                    f"KITTI image folder {images[0].parent}: image {first} is {names[first]}, expected "
                    f"{expected[first]}; images must be numbered %06d.png from 0 without gaps"
                )

    @property
    def name(self) -> str:
        return f"kitti/{self._dir.name}"

    @property
    def sensor(self) -> SensorKind:
        return "stereo" if self._right is not None else "mono"

    @property
    def calibration(self) -> PinholeCalibration:
        return self._calibration

    def __len__(self) -> int:
        return len(self._stamps)

    def __iter__(self) -> Iterator[SensorFrame]:
        for i in range(len(self._stamps)):
            yield self.frame(i)

    def frame(self, index: int) -> SensorFrame:
        """Stereo pair (or left image) ``index``; FrameReadError names the image that cannot be read."""
        check_frame_index(self.name, index, len(self))
        with reading_frame(index):
            left = read_grey(self._left[index], self._shape)
            right = None if self._right is None else read_grey(self._right[index], self._shape)
        return SensorFrame(index=index, stamp_ns=int(self._stamps[index]), left=left, right=right)

    def stamps_ns(self) -> np.ndarray:
        """Frame stamps (N,) int64 ns from times.txt (seconds since the sequence start)."""
        return self._stamps.copy()

    def ground_truth(self) -> Trajectory | None:
        """T_world_cam0 from ``<root>/poses/NN.txt`` at the frame stamps, or None when absent."""
        path = self._dir.parent.parent / "poses" / f"{self._dir.name}.txt"
        if not path.is_file():
            log.info("no KITTI ground truth at %s", path)
            return None
        poses = read_kitti_poses(path)
        if len(poses) != len(self._stamps):
            raise DatasetError(
                f"KITTI pose file {path} has {len(poses)} poses but the sequence has {len(self._stamps)} frames; "
                "the counts must be equal"
            )
        return Trajectory(self._stamps.copy(), poses)

    def imu(self) -> ImuSamples | None:
        """KITTI odometry has no IMU."""
        return None
