"""``zenslam export run.mcap [--output DIR]``: trajectories and the final map from a recording, without running anything.

Writes ``trajectory.tum`` (every pose on /frontend/pose), ``trajectory_final.tum`` (ORB-SLAM's saved
trajectory, as ``zenslam run`` writes it: each frame tracked ok at its reference keyframe's latest
pose; recordings whose states carry reference keyframes), ``keyframes.tum`` (the keyframes still
in the map, at their latest poses: keyframes as sent, then the backend's map updates applied in
the order they were recorded) and ``points.ply`` (the final map points, world frame, metres).
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zenslam.schemas import codec
from zenslam.schemas.map_update import MapUpdate
from zenslam.service import mcap_io
from zenslam.service.evaluation.trajectory_io import write_tum
from zenslam.service.recorder import MapAccumulator
from zenslam.service.recorded_run import run_log_from_recording
from zenslam.service.run_output import FINAL_TRAJECTORY_FILENAME
from zenslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

POSE_TOPIC = "/frontend/pose"
STATE_TOPIC = "/frontend/state"
KEYFRAME_TOPIC = "/frontend/keyframe"
MAP_UPDATE_TOPIC = "/backend/map_update"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        help="write trajectory.tum, trajectory_final.tum, keyframes.tum and points.ply from a recording",
        description=__doc__.splitlines()[0].split(": ", 1)[-1],
    )
    parser.add_argument("recording", type=Path, help="a run.mcap (a killed recorder's file is read up to its last chunk)")
    parser.add_argument("--output", type=Path, default=None, help="folder to write to (default: <recording's folder>/export)")
    parser.set_defaults(handler=run)


@dataclass
class ExportResult:
    """The files written and what went into them."""

    written: dict[str, Path] = field(default_factory=dict)  # name -> path
    poses: int = 0
    keyframes: int = 0
    points: int = 0


def read_poses(recording: Path) -> Trajectory | None:
    """Every frame's pose on /frontend/pose in stamp order (None if there is none)."""
    poses = [codec.decode_pose_in_frame(m.data) for m in mcap_io.iter_messages(recording, [POSE_TOPIC])]
    if not poses:
        return None
    poses.sort(key=lambda p: p.stamp_ns)
    return Trajectory(np.array([p.stamp_ns for p in poses], dtype=np.int64), np.stack([p.T_world_cam for p in poses]))


def read_final_trajectory(recording: Path) -> Trajectory | None:
    """``RunLog.final_trajectory`` of the recorded states, poses and map updates (arrival order);
    None when no state names a reference keyframe (recordings made before states carried one)."""
    log = run_log_from_recording(recording)
    if not np.any(log.frames.states().reference_keyframe_id >= 0):
        return None
    return log.final_trajectory()


def read_map(recording: Path) -> MapAccumulator:
    """The map at the end of the recording: keyframes and map updates applied in recorded (arrival) order."""
    accumulator = MapAccumulator()
    for message in mcap_io.iter_messages(recording, [KEYFRAME_TOPIC, MAP_UPDATE_TOPIC], log_time_order=False):
        decoded = mcap_io.decode(message)
        if isinstance(decoded, codec.KeyframeMessage):
            accumulator.add_keyframe(decoded)
        elif isinstance(decoded, MapUpdate):
            accumulator.apply(decoded)
    return accumulator


def write_ply(path: Path, p_world: np.ndarray) -> Path:
    """An ASCII PLY of (P, 3) points (metres)."""
    header = ["ply", "format ascii 1.0", "comment zenslam map points, world frame, metres", f"element vertex {len(p_world)}"]
    header += ["property double x", "property double y", "property double z", "end_header"]
    rows = [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(p_world, dtype=float).reshape(-1, 3)]
    path.write_text("\n".join(header + rows) + "\n")
    return path


def export_recording(recording: str | Path, output: str | Path) -> ExportResult:
    """Write trajectory.tum, trajectory_final.tum, keyframes.tum and points.ply of ``recording`` into ``output``.

    A trajectory with no pose is not written (logged), so an old file is never mistaken for it.
    """
    recording, output = Path(recording), Path(output)
    output.mkdir(parents=True, exist_ok=True)
    result = ExportResult()
    trajectory = read_poses(recording)
    if trajectory is None:
        logger.warning("%s has no %s messages: no trajectory.tum", recording, POSE_TOPIC)
    else:
        result.written["trajectory.tum"] = write_tum(output / "trajectory.tum", trajectory)
        result.poses = len(trajectory)
    final = read_final_trajectory(recording)
    if final is not None:
        result.written[FINAL_TRAJECTORY_FILENAME] = write_tum(output / FINAL_TRAJECTORY_FILENAME, final)
    accumulator = read_map(recording)
    stamps_ns, poses = accumulator.keyframe_trajectory()
    if len(stamps_ns) == 0:
        logger.warning("%s has no keyframes on %s: no keyframes.tum", recording, KEYFRAME_TOPIC)
    else:
        result.written["keyframes.tum"] = write_tum(output / "keyframes.tum", Trajectory(stamps_ns, poses))
        result.keyframes = len(stamps_ns)
    _, p_world = accumulator.point_array()
    result.written["points.ply"] = write_ply(output / "points.ply", p_world)
    result.points = len(p_world)
    return result


def run(args: argparse.Namespace) -> int:
    output = args.output or args.recording.parent / "export"
    result = export_recording(args.recording, output)
    print(f"{result.poses} poses, {result.keyframes} keyframes, {result.points} map points from {args.recording}")
    for path in result.written.values():
        print(f"wrote {path}")
    return 0
