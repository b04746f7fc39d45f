"""TUM RGB-D sequences (rgb.txt, depth.txt, groundtruth.txt), and a writer for that layout.

Layout: ``rgb.txt`` and ``depth.txt`` list ``stamp_s filename`` (``#`` comments), depth PNGs are
uint16 with ``depth_scale`` (5000) units per metre and 0 for unknown, ``groundtruth.txt`` holds
``stamp_s tx ty tz qx qy qz qw`` (quaternion xyzw) of the colour camera in the mocap world.
Colour and depth are associated like TUM's ``associate.py``: one-to-one, greedily by smallest
stamp difference within ``max_difference_ns``; a frame carries the colour stamp. Listed files
that are missing are dropped at index time with one warning.

Intrinsics: an explicit PinholeCalibration wins; else the ``intrinsics`` preset (fr1/fr2/fr3, the
TUM / ORB-SLAM values; fr1 and fr2 images are undistorted, depth with nearest-neighbour); in
``auto`` a ``calibration.yaml`` written by :func:`write_tum_rgbd`, then the folder name
(``rgbd_dataset_freiburgN_*``). RGB-D has no real baseline: ``baseline_m`` is the virtual
``virtual_bf_px_m / fx`` that ORB-SLAM uses to make a right coordinate from depth.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import yaml

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError, DatasetError, TimestampError
from zenslam.geometry import R_to_quat_wxyz, make_T, quat_wxyz_to_R, quat_wxyz_to_xyzw, quat_xyzw_to_wxyz
from zenslam.service.sources.csv_util import (
    associate_stamps,
    check_increasing,
    format_seconds,
    parse_float_table,
    parse_seconds_ns,
    read_rows,
)
from zenslam.service.sources.frame import ImuSamples, SensorFrame, check_frame_index, reading_frame
from zenslam.service.sources.images import read_depth_u16, read_grey, write_png
from zenslam.trajectory import Trajectory

log = logging.getLogger(__name__)

CALIBRATION_FILE = "calibration.yaml"


@dataclass(frozen=True)
class TumConfig:
    """How a TUM RGB-D sequence is read."""

    # camera preset (pixels); auto = calibration.yaml in the folder, then freiburgN in the folder name
    intrinsics: Literal["auto", "fr1", "fr2", "fr3"] = "auto"
    max_difference_ns: int = 20_000_000  # ns; largest colour/depth stamp difference associated (associate.py: 0.02 s)
    virtual_bf_px_m: float = 40.0  # px*m; ORB-SLAM's bf for TUM, giving baseline_m = bf / fx
    depth_scale: float = 5000.0  # depth PNG units per metre


@dataclass(frozen=True)
class TumIntrinsics:
    """Raw intrinsics (px) and OpenCV distortion (k1 k2 p1 p2 k3) of a TUM camera, 640x480."""

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float]


# The TUM benchmark's published colour-camera calibrations (also ORB-SLAM's TUM1/2/3.yaml).
TUM_PRESETS = {
    "fr1": TumIntrinsics(
        517.306408, 516.469215, 318.643040, 255.313989, (0.262383, -0.953104, -0.005358, 0.002628, 1.163314)
    ),
    "fr2": TumIntrinsics(
        520.908620, 521.007327, 325.141442, 249.701764, (0.231222, -0.784899, -0.003257, -0.000105, 0.917205)
    ),
    "fr3": TumIntrinsics(535.4, 539.2, 320.1, 247.6, (0.0, 0.0, 0.0, 0.0, 0.0)),
}  # fmt: skip


def read_calibration_yaml(path: Path) -> PinholeCalibration:
    """A PinholeCalibration from a YAML mapping with fx, fy, cx, cy, width, height[, baseline_m]."""
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise CalibrationError(f"calibration file {path} cannot be read: {exc}") from exc
    keys = ("fx", "fy", "cx", "cy", "width", "height")
    if not isinstance(data, dict) or any(k not in data for k in keys):
        raise CalibrationError(f"calibration file {path} must be a mapping with keys {list(keys)} [and baseline_m]")
    try:
        return PinholeCalibration(
            *(float(data[k]) for k in keys[:4]), int(data["width"]), int(data["height"]), data.get("baseline_m")
        )
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"calibration file {path}: {exc}") from exc


def _file_list(path: Path, what: str) -> tuple[np.ndarray, list[Path]]:
    """Stamps (ns) and files of a TUM ``rgb.txt``/``depth.txt``, checked to strictly increase."""
    rows = read_rows(path, what, 2)
    stamps = np.array([parse_seconds_ns(r.fields[0], path, r.line) for r in rows], dtype=np.int64)
    check_increasing(stamps, [r.line for r in rows], path)
    return stamps, [path.parent / r.fields[1] for r in rows]


class TumSource:
    """A TUM RGB-D sequence as a lazy RGB-D Source; ``sequence_dir`` holds rgb.txt and depth.txt."""

    def __init__(
        self,
        sequence_dir: Path,
        config: TumConfig = TumConfig(),
        calibration: PinholeCalibration | None = None,
    ) -> None:
        self._dir = Path(sequence_dir).absolute()
        self._config = config
        if not self._dir.is_dir():
            raise DatasetError(f"TUM sequence folder {self._dir} does not exist; pass the folder holding rgb.txt")
        self._calibration, self._maps = self._resolve_calibration(calibration)
        self._shape = (self._calibration.height, self._calibration.width)
        self._stamps, self._rgb, self._depth = self._index()

    def _resolve_calibration(
        self, explicit: PinholeCalibration | None
    ) -> tuple[PinholeCalibration, tuple[np.ndarray, np.ndarray] | None]:
        preset = self._config.intrinsics
        if explicit is None and preset == "auto":
            path = self._dir / CALIBRATION_FILE
            if path.is_file():
                explicit = read_calibration_yaml(path)
            else:
                match = re.search(r"freiburg([123])", self._dir.name)
                if match is None:
                    raise CalibrationError(
                        f"cannot tell the camera of TUM sequence {self._dir}: no {CALIBRATION_FILE} and the folder "
                        "name has no 'freiburgN'; set intrinsics to fr1/fr2/fr3 or pass a calibration"
                    )
                preset = f"fr{match.group(1)}"
        if explicit is not None:
            if explicit.baseline_m is None:
                explicit = dataclasses.replace(explicit, baseline_m=self._config.virtual_bf_px_m / explicit.fx)
            return explicit, None
        raw = TUM_PRESETS[preset]
        calibration = PinholeCalibration(
            raw.fx, raw.fy, raw.cx, raw.cy, 640, 480, baseline_m=self._config.virtual_bf_px_m / raw.fx
        )
        if not any(raw.distortion):
            return calibration, None
        # Undistort onto the same K, as ORB-SLAM undistorts keypoints with the same intrinsics.
        K, d = calibration.K, np.array(raw.distortion)
        maps = cv2.initUndistortRectifyMap(K, d, None, K, (640, 480), cv2.CV_32FC1)
        return calibration, (maps[0], maps[1])

    def _index(self) -> tuple[np.ndarray, list[Path], list[Path]]:
        rgb_stamps, rgb_files = _file_list(self._dir / "rgb.txt", "TUM colour image list")
        depth_stamps, depth_files = _file_list(self._dir / "depth.txt", "TUM depth image list")
        rgb_ok = np.flatnonzero([p.is_file() for p in rgb_files])
        depth_ok = np.flatnonzero([p.is_file() for p in depth_files])
        missing = len(rgb_files) - len(rgb_ok) + len(depth_files) - len(depth_ok)
        if missing:
            log.warning(
                "TUM %s: dropped %d listed images whose file is missing (rgb %d, depth %d)",
                self._dir, missing, len(rgb_files) - len(rgb_ok), len(depth_files) - len(depth_ok),
            )  # fmt: skip
        ia, ib = associate_stamps(rgb_stamps[rgb_ok], depth_stamps[depth_ok], self._config.max_difference_ns)
        ia, ib = rgb_ok[ia], depth_ok[ib]
        log.info(
            "TUM %s: %d colour/depth pairs from %d colour and %d depth images",
            self._dir, len(ia), len(rgb_files), len(depth_files),
        )  # fmt: skip
        if len(ia) == 0:
            raise DatasetError(
                f"TUM sequence {self._dir}: no colour image has a depth image within "
                f"{self._config.max_difference_ns} ns ({len(rgb_files)} colour, {len(depth_files)} depth listed, "
                f"{missing} missing); check rgb.txt and depth.txt"
            )
        return rgb_stamps[ia], [rgb_files[i] for i in ia], [depth_files[j] for j in ib]

    @property
    def name(self) -> str:
        return f"tum/{self._dir.name}"

    @property
    def sensor(self) -> SensorKind:
        return "rgbd"

    @property
    def calibration(self) -> PinholeCalibration:
        return self._calibration

    def __len__(self) -> int:
        return len(self._stamps)

    def __iter__(self) -> Iterator[SensorFrame]:
        for i in range(len(self._stamps)):
            yield self.frame(i)

    def frame(self, index: int) -> SensorFrame:
        """Colour (as grey) and depth of frame ``index``; FrameReadError names the image that cannot be read."""
        check_frame_index(self.name, index, len(self))
        with reading_frame(index):
            grey = read_grey(self._rgb[index], self._shape)
            depth = read_depth_u16(self._depth[index], self._shape)
        if self._maps is not None:
            grey = cv2.remap(grey, self._maps[0], self._maps[1], cv2.INTER_LINEAR)
            # Nearest neighbour: blending depths across an object edge would invent surfaces.
            depth = cv2.remap(depth, self._maps[0], self._maps[1], cv2.INTER_NEAREST)
        depth_m = depth.astype(np.float32) / np.float32(self._config.depth_scale)
        return SensorFrame(index=index, stamp_ns=int(self._stamps[index]), left=grey, depth_m=depth_m)

    def stamps_ns(self) -> np.ndarray:
        """Colour-image stamps (N,) int64 ns of the associated frames."""
        return self._stamps.copy()

    def ground_truth(self) -> Trajectory | None:
        """T_world_cam of the colour camera from groundtruth.txt at its own stamps, or None when absent."""
        path = self._dir / "groundtruth.txt"
        if not path.is_file():
            log.info("no TUM ground truth at %s", path)
            return None
        rows = read_rows(path, "TUM ground truth", 8)
        stamps = np.array([parse_seconds_ns(r.fields[0], path, r.line) for r in rows], dtype=np.int64)
        check_increasing(stamps, [r.line for r in rows], path)
        values = parse_float_table(rows, 1, 7, path)
        poses = np.array([make_T(quat_wxyz_to_R(quat_xyzw_to_wxyz(v[3:7])), v[:3]) for v in values])
        return Trajectory(stamps, poses.reshape(-1, 4, 4))

    def imu(self) -> ImuSamples | None:
        """TUM RGB-D has no gyroscope; the Kinect accelerometer is not read."""
        return None


def _round_stamp_us(stamp_ns: int) -> int:
    """A stamp rounded to the nearest whole microsecond, in ns."""
    return (int(stamp_ns) + 500) // 1000 * 1000


def _round_stamps_us(stamps_ns: list[int], where: Path) -> list[int]:
    """Stamps rounded to whole microseconds (what 6 decimals of seconds keep), still strictly increasing."""
    rounded = [_round_stamp_us(s) for s in stamps_ns]
    changed = sum(a != b for a, b in zip(stamps_ns, rounded))
    if changed:
        log.warning("%s: TUM text keeps microseconds; %d of %d stamps rounded", where, changed, len(stamps_ns))
    for k in range(1, len(rounded)):
        if rounded[k] <= rounded[k - 1]:
            raise TimestampError(
                f"cannot write {where}: stamp {k} ({stamps_ns[k]} ns) does not follow stamp {k - 1} "
                f"({stamps_ns[k - 1]} ns) by at least 1 us, which the TUM text format needs"
            )
    return rounded


def _depth_units(depth_m: np.ndarray, depth_scale: float) -> tuple[np.ndarray, int]:
    """Depth in metres to uint16 PNG units (0 = unknown); also the count of pixels too far to store."""
    d = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    units = np.rint(np.clip(d, 0.0, None) * depth_scale)
    too_far = units > np.iinfo(np.uint16).max
    units[too_far] = 0
    return units.astype(np.uint16), int(too_far.sum())


def write_tum_rgbd(
    folder: Path,
    frames: Iterable[SensorFrame],
    ground_truth: Trajectory | None = None,
    calibration: PinholeCalibration | None = None,
    depth_scale: float = 5000.0,
) -> int:
    """Save frames (``left`` grey uint8 + ``depth_m`` metres) as a TUM RGB-D sequence; returns the frame count.

    Writes ``rgb/`` and ``depth/`` PNGs (depth rounded to 1/depth_scale m; beyond 65535 units it is
    stored as unknown), ``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` (T_world_cam, quaternion xyzw)
    and, when given, ``calibration.yaml`` so TumSource reads the sequence back unaided. Stamps are
    written in seconds with 6 decimals: ns stamps are rounded to the nearest microsecond.
    """
    folder = Path(folder)
    rgb_lines = ["# color images", "# written by zenslam", "# timestamp filename"]
    depth_lines = ["# depth maps", "# written by zenslam", "# timestamp filename"]
    too_far = 0
    count = 0
    rounded_count = 0
    previous: tuple[int, int] | None = None  # (stamp_ns, rounded) of the previous frame
    for frame in frames:  # streamed: a long sequence never sits in memory
        if frame.depth_m is None or frame.left.dtype != np.uint8:
            raise DatasetError(
                f"frame {frame.index} cannot be written to {folder} as TUM RGB-D: it needs a uint8 left image "
                "and depth_m"
            )
        stamp = _round_stamp_us(frame.stamp_ns)
        rounded_count += stamp != frame.stamp_ns
        if previous is not None and stamp <= previous[1]:
            raise TimestampError(
                f"cannot write {folder}: stamp {count} ({frame.stamp_ns} ns) does not follow stamp {count - 1} "
                f"({previous[0]} ns) by at least 1 us, which the TUM text format needs"
            )
        previous = (frame.stamp_ns, stamp)
        name = f"{format_seconds(stamp)}.png"
        write_png(folder / "rgb" / name, frame.left)
        units, far = _depth_units(frame.depth_m, depth_scale)
        too_far += far
        write_png(folder / "depth" / name, units)
        rgb_lines.append(f"{format_seconds(stamp)} rgb/{name}")
        depth_lines.append(f"{format_seconds(stamp)} depth/{name}")
        count += 1
    if rounded_count:
        log.warning("%s: TUM text keeps microseconds; %d of %d stamps rounded", folder, rounded_count, count)
    if too_far:
        log.warning("%s: %d depth pixels beyond %.2f m stored as unknown", folder, too_far, 65535 / depth_scale)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if ground_truth is not None:
        _write_groundtruth(folder / "groundtruth.txt", ground_truth)
    if calibration is not None:
        (folder / CALIBRATION_FILE).write_text(yaml.safe_dump(dataclasses.asdict(calibration), sort_keys=False))
    return count


def _write_groundtruth(path: Path, trajectory: Trajectory) -> None:
    """Write T_world_cam as TUM ``stamp_s tx ty tz qx qy qz qw`` lines."""
    stamps = _round_stamps_us([int(s) for s in trajectory.stamps_ns], path)
    lines = ["# ground truth trajectory", "# written by zenslam", "# timestamp tx ty tz qx qy qz qw"]
    for stamp, T in zip(stamps, np.asarray(trajectory.T_world_cam)):
        q_xyzw = quat_wxyz_to_xyzw(R_to_quat_wxyz(T[:3, :3]))
        values = " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q_xyzw))
        lines.append(f"{format_seconds(stamp)} {values}")
    path.write_text("\n".join(lines) + "\n")
