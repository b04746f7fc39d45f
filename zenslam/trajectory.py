"""A timed sequence of camera poses, T_world_cam per stamp, with strictly increasing stamps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.errors import TimestampError, TrajectoryError


@dataclass(frozen=True)
class Trajectory:
    """Poses of one camera: ``T_world_cam[i]`` (4x4) maps camera coordinates to world at ``stamps_ns[i]``."""

    stamps_ns: np.ndarray  # (N,) int64
    T_world_cam: np.ndarray  # (N, 4, 4) float64

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_ns)
        poses = np.asarray(self.T_world_cam)
        if stamps.ndim != 1 or poses.shape != (len(stamps), 4, 4):
            raise TrajectoryError(
                f"a trajectory needs N stamps and N 4x4 poses; got stamps {stamps.shape} and poses {poses.shape}"
            )
        if len(stamps) > 1:
            steps = np.diff(stamps)
            if np.any(steps <= 0):
                i = int(np.argmax(steps <= 0))
                raise TimestampError(
                    f"trajectory stamps must strictly increase: stamp {i + 1} ({stamps[i + 1]} ns) "
                    f"follows {stamps[i]} ns; sort the file or remove the duplicate"
                )

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def positions(self) -> np.ndarray:
        """Camera centres in the world frame, (N, 3) metres."""
        return np.asarray(self.T_world_cam)[:, :3, 3]

    def path_length_m(self) -> float:
        """Sum of distances between consecutive camera centres, metres."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())
