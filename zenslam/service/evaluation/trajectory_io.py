"""Trajectory files in the TUM, KITTI and EuRoC formats, read into and written from ``Trajectory``.

Formats (one pose per line, ``#`` starts a comment line):

- ``tum``: ``stamp_s tx ty tz qx qy qz qw``, whitespace-separated, T_world_cam with the quaternion
  in x, y, z, w order. Written with 9 decimals of seconds so integer-ns stamps survive exactly.
- ``kitti``: 12 numbers, the top 3x4 of T_world_cam row-major, no stamps. Stamps come from a
  KITTI ``times.txt`` (seconds, one line per pose) when given; otherwise ``stamps_ns`` is the
  0-based frame index (0, 1, 2, ... ns), so two such files are associated by index.
- ``euroc``: comma-separated ``timestamp_ns, x, y, z, qw, qx, qy, qz[, ...]`` as in EuRoC's
  ``state_groundtruth_estimate0/data.csv`` (the body/IMU pose; extra columns are ignored) and
  ``groundtruth_cam0.csv`` (the cam0 pose). The pose is read as given: the caller knows which
  frame a file describes.

Stamps are parsed as decimals, never through float64, which cannot hold 1.4e18 ns exactly.
"""

from __future__ import annotations

import logging
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Literal, get_args

import numpy as np

from zenslam.errors import TimestampError, TrajectoryError
from zenslam.geometry import R_to_quat_wxyz, quat_wxyz_to_R
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

TrajectoryFormat = Literal["tum", "kitti", "euroc"]
TRAJECTORY_FORMATS: tuple[str, ...] = get_args(TrajectoryFormat)

_NS_PER_S = 1_000_000_000


def detect_format(path: str | Path, fmt: str | None = None) -> TrajectoryFormat:
    """The format of a trajectory file: ``fmt`` when given, else from the extension, else the content.

    ``.csv`` is EuRoC; otherwise the first data line decides: commas mean EuRoC, 8 numbers TUM,
    12 numbers KITTI.
    """
    path = Path(path)
    if fmt is not None:
        if fmt not in TRAJECTORY_FORMATS:
            raise TrajectoryError(f"unknown trajectory format {fmt!r} for {path}; use one of {list(TRAJECTORY_FORMATS)}")
        return fmt  # type: ignore[return-value]
    if path.suffix.lower() == ".csv":
        return "euroc"
    if path.suffix.lower() == ".tum":
        return "tum"
    lines = _data_lines(path)
    if not lines:
        raise TrajectoryError(f"{path} holds no poses (only comments or blank lines); check the file")
    line_no, text = lines[0]
    if "," in text:
        return "euroc"
    count = len(text.split())
    if count == 8:
        return "tum"
    if count == 12:
        return "kitti"
    raise TrajectoryError(
        f"{path}:{line_no}: cannot tell the trajectory format from a line of {count} values "
        f"(TUM has 8, KITTI 12, EuRoC is comma-separated); give the format explicitly"
    )


def read_trajectory(path: str | Path, fmt: str | None = None, *, times_path: str | Path | None = None) -> Trajectory:
    """Read a trajectory file (T_world_cam, stamps in ns) in ``fmt`` or the detected format.

    ``times_path`` (a KITTI ``times.txt``, seconds) gives the stamps of a KITTI file.
    """
    fmt = detect_format(path, fmt)
    if times_path is not None and fmt != "kitti":
        raise TrajectoryError(f"a times file ({times_path}) only applies to KITTI files; {path} is read as {fmt}")
    if fmt == "tum":
        return read_tum(path)
    if fmt == "kitti":
        return read_kitti(path, times_path=times_path)
    return read_euroc(path)


def write_trajectory(path: str | Path, trajectory: Trajectory, fmt: str) -> Path:
    """Write ``trajectory`` to ``path`` in ``fmt`` (``tum``, ``kitti`` or ``euroc``); returns the path."""
    fmt = detect_format(path, fmt)
    if fmt == "tum":
        return write_tum(path, trajectory)
    if fmt == "kitti":
        return write_kitti(path, trajectory)
    return write_euroc(path, trajectory)


def read_tum(path: str | Path) -> Trajectory:
    """Read ``stamp_s tx ty tz qx qy qz qw`` lines (metres, T_world_cam) into a Trajectory."""
    path = Path(path)
    rows = _parse_rows(path, separator=None, min_values=8, max_values=8, what="stamp_s tx ty tz qx qy qz qw")
    stamps = [_parse_stamp_ns(path, line_no, tokens[0], _NS_PER_S) for line_no, tokens in rows]
    values = np.array([_parse_floats(path, line_no, tokens[1:8]) for line_no, tokens in rows])
    quat_wxyz = values[:, [6, 3, 4, 5]]
    poses = _poses_from_quat(path, [line_no for line_no, _ in rows], values[:, :3], quat_wxyz)
    return _make_trajectory(path, rows, stamps, poses)


def write_tum(path: str | Path, trajectory: Trajectory) -> Path:
    """Write ``stamp_s tx ty tz qx qy qz qw`` lines, stamps with 9 decimals (exact ns)."""
    lines = ["# stamp_s tx ty tz qx qy qz qw  (T_world_cam, metres)"]
    for stamp_ns, T in zip(np.asarray(trajectory.stamps_ns), np.asarray(trajectory.T_world_cam)):
        w, x, y, z = R_to_quat_wxyz(T[:3, :3])
        t = T[:3, 3]
        lines.append(f"{_format_stamp_s(int(stamp_ns))} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {x:.9f} {y:.9f} {z:.9f} {w:.9f}")
    return _write_lines(path, lines)


def read_kitti(path: str | Path, *, times_path: str | Path | None = None) -> Trajectory:
    """Read 12-number lines (3x4 row-major T_world_cam, metres); stamps from ``times_path`` or the index."""
    path = Path(path)
    rows = _parse_rows(path, separator=None, min_values=12, max_values=12, what="12 numbers of a 3x4 pose")
    values = np.array([_parse_floats(path, line_no, tokens) for line_no, tokens in rows])
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = values.reshape(-1, 3, 4)
    if times_path is None:
        stamps = list(range(len(rows)))
    else:
        stamps = read_kitti_times(times_path)
        if len(stamps) != len(rows):
            raise TrajectoryError(
                f"{times_path} has {len(stamps)} stamps but {path} has {len(rows)} poses; "
                f"use the times.txt of the same sequence (one line per pose)"
            )
    return _make_trajectory(path, rows, stamps, poses)


def read_kitti_times(path: str | Path) -> list[int]:
    """Read a KITTI ``times.txt`` (one stamp in seconds per line) as integer ns."""
    path = Path(path)
    rows = _parse_rows(path, separator=None, min_values=1, max_values=1, what="one stamp in seconds")
    return [_parse_stamp_ns(path, line_no, tokens[0], _NS_PER_S) for line_no, tokens in rows]


def write_kitti(path: str | Path, trajectory: Trajectory) -> Path:
    """Write the 3x4 row-major T_world_cam of each pose, 12 numbers a line; stamps are not kept."""
    poses = np.asarray(trajectory.T_world_cam)[:, :3, :].reshape(-1, 12)
    return _write_lines(path, [" ".join(f"{v:.12e}" for v in row) for row in poses])


def read_euroc(path: str | Path) -> Trajectory:
    """Read ``timestamp_ns, x, y, z, qw, qx, qy, qz[, ...]`` CSV lines (metres) into a Trajectory."""
    path = Path(path)
    rows = _parse_rows(path, separator=",", min_values=8, max_values=None, what="timestamp_ns, x, y, z, qw, qx, qy, qz")
    stamps = [_parse_stamp_ns(path, line_no, tokens[0], 1) for line_no, tokens in rows]
    values = np.array([_parse_floats(path, line_no, tokens[1:8]) for line_no, tokens in rows])
    poses = _poses_from_quat(path, [line_no for line_no, _ in rows], values[:, :3], values[:, 3:7])
    return _make_trajectory(path, rows, stamps, poses)


def write_euroc(path: str | Path, trajectory: Trajectory) -> Path:
    """Write ``timestamp_ns,x,y,z,qw,qx,qy,qz`` CSV lines with a ``#`` header."""
    lines = ["#timestamp [ns],x [m],y [m],z [m],qw [],qx [],qy [],qz []"]
    for stamp_ns, T in zip(np.asarray(trajectory.stamps_ns), np.asarray(trajectory.T_world_cam)):
        q = R_to_quat_wxyz(T[:3, :3])
        t = T[:3, 3]
        lines.append(f"{int(stamp_ns)},{t[0]:.9f},{t[1]:.9f},{t[2]:.9f},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f}")
    return _write_lines(path, lines)


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(1-based line number, stripped text) of every non-blank, non-comment line."""
    try:
        with path.open("r", encoding="utf-8") as handle:
            return [(i, s) for i, line in enumerate(handle, start=1) if (s := line.strip()) and not s.startswith("#")]
    except FileNotFoundError as exc:
        raise TrajectoryError(f"trajectory file {path} does not exist; check the path") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryError(f"cannot read trajectory file {path}: {exc}") from exc


def _parse_rows(
    path: Path, separator: str | None, min_values: int, max_values: int | None, what: str
) -> list[tuple[int, list[str]]]:
    rows = []
    for line_no, text in _data_lines(path):
        tokens = [t.strip() for t in text.split(separator)]
        if len(tokens) < min_values or (max_values is not None and len(tokens) > max_values):
            raise TrajectoryError(
                f"{path}:{line_no}: expected {what} ({min_values} values), got {len(tokens)}: {text[:80]!r}; "
                f"check the format of the file"
            )
        rows.append((line_no, tokens))
    if not rows:
        raise TrajectoryError(f"{path} holds no poses (only comments or blank lines); check the file")
    return rows


def _parse_floats(path: Path, line_no: int, tokens: list[str]) -> list[float]:
    try:
        values = [float(t) for t in tokens]
    except ValueError as exc:
        raise TrajectoryError(f"{path}:{line_no}: not a number in {' '.join(tokens)!r}: {exc}") from exc
    if not all(np.isfinite(values)):
        raise TrajectoryError(f"{path}:{line_no}: non-finite value in {' '.join(tokens)!r}")
    return values


def _parse_stamp_ns(path: Path, line_no: int, token: str, ns_per_unit: int) -> int:
    """Exact integer ns of a decimal stamp given in units of ``ns_per_unit`` ns."""
    try:
        value = Decimal(token)
    except InvalidOperation as exc:
        raise TimestampError(f"{path}:{line_no}: cannot parse the stamp {token!r}; expected a decimal number") from exc
    if not value.is_finite():
        raise TimestampError(f"{path}:{line_no}: the stamp {token!r} is not finite")
    return int((value * ns_per_unit).to_integral_value())


def _format_stamp_s(stamp_ns: int) -> str:
    sign = "-" if stamp_ns < 0 else ""
    seconds, ns = divmod(abs(stamp_ns), _NS_PER_S)
    return f"{sign}{seconds}.{ns:09d}"


def _poses_from_quat(path: Path, line_nos: list[int], p_world: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(quat_wxyz, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 0.1)
    if bad.size:
        i = int(bad[0])
        raise TrajectoryError(
            f"{path}:{line_nos[i]}: quaternion {quat_wxyz[i].tolist()} has norm {norms[i]:.3f}, not 1; "
            f"check the column order of the file"
        )
    poses = np.tile(np.eye(4), (len(p_world), 1, 1))
    for i, q in enumerate(quat_wxyz):
        poses[i, :3, :3] = quat_wxyz_to_R(q)
    poses[:, :3, 3] = p_world
    return poses


def _make_trajectory(path: Path, rows: list[tuple[int, list[str]]], stamps: list[int], poses: np.ndarray) -> Trajectory:
    """A Trajectory, after checking that stamps increase, naming the file and line when they do not."""
    for k in range(1, len(stamps)):
        if stamps[k] <= stamps[k - 1]:
            raise TimestampError(
                f"{path}:{rows[k][0]}: stamp {stamps[k]} ns does not increase on line {rows[k - 1][0]} "
                f"({stamps[k - 1]} ns); sort the file or remove the duplicate"
            )
    logger.debug("read %d poses from %s", len(stamps), path)
    return Trajectory(stamps_ns=np.array(stamps, dtype=np.int64), T_world_cam=poses)


def _write_lines(path: str | Path, lines: list[str]) -> Path:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    except OSError as exc:
        raise TrajectoryError(f"cannot write trajectory file {path}: {exc}") from exc
    return path
