"""Constant-velocity motion model: the next pose repeats the last inter-frame motion."""

from __future__ import annotations

import numpy as np

from zenslam.geometry import invert_T


class ConstantVelocityModel:
    """ORB-SLAM's motion model: velocity = T_cam_world[k] @ T_world_cam[k-1], per frame.

    The prediction for frame k+1 is velocity @ T_cam_world[k]. The velocity is per frame, not per
    second, as in ORB-SLAM: frames are assumed evenly spaced. After a tracking failure the model
    is reset and has no prediction until two consecutive frames are tracked again.
    """

    def __init__(self) -> None:
        self._velocity: np.ndarray | None = None  # T_cam_cur_cam_prev, (4, 4)

    @property
    def velocity(self) -> np.ndarray | None:
        """The last inter-frame motion T_camk_camk-1 (4, 4), or None after a reset."""
        return None if self._velocity is None else self._velocity.copy()

    @property
    def has_velocity(self) -> bool:
        """Whether a prediction is available."""
        return self._velocity is not None

    def update(self, T_cam_world_prev: np.ndarray, T_cam_world_cur: np.ndarray) -> None:
        """Set the velocity from the poses (world -> camera, 4x4) of two consecutive tracked frames."""
        self._velocity = np.asarray(T_cam_world_cur, dtype=float) @ invert_T(T_cam_world_prev)

    def predict(self, T_cam_world_last: np.ndarray) -> np.ndarray | None:
        """Predicted world -> camera pose (4x4) of the next frame, or None without a velocity."""
        if self._velocity is None:
            return None
        return self._velocity @ np.asarray(T_cam_world_last, dtype=float)

    def reset(self) -> None:
        """Forget the velocity (after a lost frame)."""
        self._velocity = None
