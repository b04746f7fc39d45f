"""A keyframe as the backend keeps it: pose, calibration, keypoints and their map-point associations."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.geometry import invert_T, transform_points
from zenslam.schemas.codec import KeyframeMessage


@dataclass(eq=False)
class BackendKeyframe:
    """A keyframe as the backend keeps it; ``map_point_ids`` (N,) int64 (-1 none) and ``map_point_rows``
    (the points' rows in the map's ``PointStore``, -1 none) are owned by the map."""

    id: int
    stamp_ns: int
    T_world_cam: np.ndarray  # (4, 4) maps camera coordinates (x right, y down, z forward) to world
    calibration: PinholeCalibration
    sensor: SensorKind
    keypoints_px: np.ndarray  # (N, 2) float64 level-0 pixels
    levels: np.ndarray  # (N,) int64 pyramid level
    angles_deg: np.ndarray  # (N,) float64
    right_u: np.ndarray  # (N,) float64 right-image u, pixels; -1 none
    depth_m: np.ndarray  # (N,) float64 metres; -1 none
    descriptors: np.ndarray  # (N, 32) uint8
    scale_factors: np.ndarray  # (L,) float64, scale_factor**level
    map_point_ids: np.ndarray  # (N,) int64
    serial: int = -1  # insertion order in the map (0 for the first keyframe)
    map_point_rows: np.ndarray | None = None  # (N,) int64; None: none yet (all -1)
    # The inverse pose with the bytes of the pose it inverts: recomputed when the pose changes,
    # whether it was replaced or written in place.
    _inverse: tuple[bytes, np.ndarray] | None = field(default=None, init=False, repr=False)
    _u_order: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False, repr=False)
    _K_inv: tuple[PinholeCalibration, np.ndarray] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.map_point_rows is None:
            self.map_point_rows = np.full(len(self.map_point_ids), -1, dtype=np.int64)

    @classmethod
    def from_message(cls, msg: KeyframeMessage) -> BackendKeyframe:
        """Writable copies of a keyframe message's arrays; associations start empty (all -1)."""
        n = len(msg.keypoints_px)
        return cls(
            id=int(msg.id),
            stamp_ns=int(msg.stamp_ns),
            T_world_cam=np.array(msg.T_world_cam, dtype=float),
            calibration=msg.calibration,
            sensor=msg.sensor,
            keypoints_px=np.array(msg.keypoints_px, dtype=float).reshape(n, 2),
            levels=np.array(msg.levels, dtype=np.int64),
            angles_deg=np.array(msg.angles_deg, dtype=float),
            right_u=np.array(msg.right_u, dtype=float),
            depth_m=np.array(msg.depth_m, dtype=float),
            descriptors=np.array(msg.descriptors, dtype=np.uint8).reshape(n, 32),
            scale_factors=np.array(msg.scale_factors, dtype=float),
            map_point_ids=np.full(n, -1, dtype=np.int64),
        )

    @property
    def n_keypoints(self) -> int:
        """Number of keypoints N."""
        return len(self.keypoints_px)

    @property
    def scale_factor(self) -> float:
        """Scale ratio between consecutive pyramid levels."""
        return float(self.scale_factors[1]) if len(self.scale_factors) > 1 else 1.0

    @property
    def n_levels(self) -> int:
        """Pyramid levels L."""
        return len(self.scale_factors)

    @property
    def level_sigma2(self) -> np.ndarray:
        """(L,) keypoint position variance per level, px^2 (ORB-SLAM: scale_factor**(2 level))."""
        return self.scale_factors**2

    @property
    def T_cam_world(self) -> np.ndarray:
        """The pose as a world -> camera transform (4, 4) (a copy)."""
        return self._cam_world().copy()

    def _cam_world(self) -> np.ndarray:
        """The cached world -> camera transform (not to be written)."""
        key = np.asarray(self.T_world_cam, dtype=float).tobytes()
        if self._inverse is None or self._inverse[0] != key:
            self._inverse = (key, invert_T(self.T_world_cam))
        return self._inverse[1]

    @property
    def K_inv(self) -> np.ndarray:
        """The inverse (3, 3) of the calibration matrix (computed once per calibration; not to be written)."""
        if self._K_inv is None or self._K_inv[0] is not self.calibration:
            self._K_inv = (self.calibration, np.linalg.inv(self.calibration.K))
        return self._K_inv[1]

    def u_order(self) -> np.ndarray:
        """Keypoint indices (N,) by increasing u (stable), computed once per keypoint array."""
        if self._u_order is None or self._u_order[0] is not self.keypoints_px:
            self._u_order = (self.keypoints_px, np.argsort(self.keypoints_px[:, 0], kind="stable"))
        return self._u_order[1]

    @property
    def centre_world(self) -> np.ndarray:
        """Camera centre (3,) metres, world frame."""
        return np.asarray(self.T_world_cam)[:3, 3].copy()

    @property
    def has_right(self) -> np.ndarray:
        """(N,) bool: the keypoint has a right-image coordinate (stereo/RGB-D measurement)."""
        return self.right_u >= 0

    def project(self, p_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (M, 2), right-image u (M,) (nan for mono) and depth z (M,) metres of world points (M, 3)."""
        p_cam = transform_points(self._cam_world(), np.asarray(p_world, dtype=float).reshape(-1, 3))
        z = p_cam[:, 2]
        safe_z = np.where(np.abs(z) > 1e-12, z, 1e-12)
        c = self.calibration
        px = np.column_stack([c.fx * p_cam[:, 0] / safe_z + c.cx, c.fy * p_cam[:, 1] / safe_z + c.cy])
        right_u = px[:, 0] - c.bf / safe_z if c.baseline_m is not None else np.full(len(z), np.nan)
        return px, right_u, z

    def unproject(self, keypoints: np.ndarray) -> np.ndarray:
        """World points (K, 3) metres of keypoints (indices) with a depth, from their pixel and depth."""
        keypoints = np.asarray(keypoints, dtype=np.int64)
        c, z = self.calibration, self.depth_m[keypoints]
        uv = self.keypoints_px[keypoints]
        p_cam = np.column_stack([(uv[:, 0] - c.cx) * z / c.fx, (uv[:, 1] - c.cy) * z / c.fy, z])
        return transform_points(self.T_world_cam, p_cam)
