"""Constant-velocity motion model: the next pose repeats the last inter-frame motion."""

from __future__ import annotations

from collections import deque

import numpy as np

from zenslam.geometry import invert_T, skew, so3_exp, so3_log


def se3_power(T: np.ndarray, exponent: float) -> np.ndarray:
    """``T`` (4x4 rigid transform) raised to a real power: exp(exponent * log(T)) on SE(3)."""
    R, t = T[:3, :3], T[:3, 3]
    w = so3_log(R)
    V = _left_jacobian(w)
    u = np.linalg.solve(V, t)  # the twist's translation part
    w_s, u_s = exponent * w, exponent * u
    out = np.eye(4)
    out[:3, :3] = so3_exp(w_s)
    out[:3, 3] = _left_jacobian(w_s) @ u_s
    return out


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    """SO(3)'s left Jacobian V(w) (3x3), which maps a twist's translation to the transform's."""
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-8:
        return np.eye(3) + 0.5 * W
    return np.eye(3) + (1 - np.cos(theta)) / theta**2 * W + (theta - np.sin(theta)) / theta**3 * (W @ W)


class ConstantVelocityModel:
    """ORB-SLAM's motion model: velocity = T_cam_world[k] @ T_world_cam[k-1], per frame.

    The prediction for frame k+1 is velocity @ T_cam_world[k]. The velocity is per frame, not per
    second, as in ORB-SLAM: frames are assumed evenly spaced. Live runs skip frames: across a gap
    of ``frames`` frame indices the velocity is the ``frames``-th root of the motion, and the
    prediction applies it ``frames`` times (SE(3) powers); a gap of 1 is ORB-SLAM's model exactly.
    A source that numbers only the frames it passes on (a bus source drops frames that arrive while
    tracking is busy) hides its gaps from the indices: ``frames_between`` reads them from the stamps.
    After a tracking failure the model is reset and has no prediction until two frames are tracked
    in a row again.
    """

    def __init__(self) -> None:
        self._velocity: np.ndarray | None = None  # T_cam_cur_cam_prev, (4, 4)
        # The camera's time per frame over the last updates; their median stands for it (stamps jitter).
        self._frame_intervals_ns: deque[float] = deque(maxlen=9)

    @property
    def velocity(self) -> np.ndarray | None:
        """The last inter-frame motion T_camk_camk-1 (4, 4), or None after a reset."""
        return None if self._velocity is None else self._velocity.copy()

    @property
    def has_velocity(self) -> bool:
        """Whether a prediction is available."""
        return self._velocity is not None

    def frames_between(self, index_gap: int, elapsed_ns: int) -> int:
        """Frames from the last tracked frame to one ``index_gap`` indices and ``elapsed_ns`` later:
        the index gap, or more when the stamps span more frames of the camera's interval."""
        frames = max(index_gap, 1)
        if not self._frame_intervals_ns or elapsed_ns <= 0:
            return frames
        return max(frames, round(elapsed_ns / float(np.median(self._frame_intervals_ns))))

    def update(self, T_cam_world_prev: np.ndarray, T_cam_world_cur: np.ndarray, frames: int = 1, elapsed_ns: int = 0) -> None:
        """Set the velocity from the poses (world -> camera, 4x4) of two tracked frames ``frames``
        frames apart (1: consecutive) and ``elapsed_ns`` apart in time (0: unknown)."""
        motion = np.asarray(T_cam_world_cur, dtype=float) @ invert_T(T_cam_world_prev)
        self._velocity = motion if frames == 1 else se3_power(motion, 1.0 / frames)
        if elapsed_ns > 0:
            self._frame_intervals_ns.append(elapsed_ns / frames)

    def predict(self, T_cam_world_last: np.ndarray, frames: int = 1) -> np.ndarray | None:
        """Predicted world -> camera pose (4x4) of the frame ``frames`` frame indices after the last
        one (1: the next frame), or None without a velocity."""
        if self._velocity is None:
            return None
        velocity = self._velocity if frames == 1 else se3_power(self._velocity, float(frames))
        return velocity @ np.asarray(T_cam_world_last, dtype=float)

    def reset(self) -> None:
        """Forget the velocity (after a lost frame)."""
        self._velocity = None
