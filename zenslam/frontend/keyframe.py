"""A keyframe: a tracked frame kept in the map, with its keypoints, depths, pose and point links."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.frontend.orb_extractor import Features
from zenslam.geometry import invert_T, transform_points


@dataclass(frozen=True, eq=False)
class KeyFrame:
    """A frame promoted to keyframe by the tracker; immutable once made.

    ``features`` are the frame's ORB keypoints (N of them: level-0 pixels, levels, angles,
    descriptors and the pyramid constants). Per keypoint: ``right_u`` the right-image (or virtual
    RGB-D) u coordinate in pixels and ``depth_m`` metres (-1 where none), ``map_point_ids`` the map
    point the keypoint observes (-1 none). ``new_point_ids`` are the points created at this
    keyframe, at keypoints ``new_point_keypoints``, with positions ``new_points_world`` (P, 3)
    metres in the world frame. ``T_world_cam`` maps camera coordinates (x right, y down,
    z forward) to world.
    """

    id: int
    frame_index: int
    stamp_ns: int
    T_world_cam: np.ndarray  # (4, 4)
    features: Features
    right_u: np.ndarray  # (N,) float32 pixels, -1 none
    depth_m: np.ndarray  # (N,) float32 metres, -1 none
    map_point_ids: np.ndarray  # (N,) int64, -1 none
    new_point_ids: np.ndarray  # (P,) int64
    new_point_keypoints: np.ndarray  # (P,) int64 keypoint index of each new point
    new_points_world: np.ndarray  # (P, 3) float64 metres, world frame

    @property
    def px(self) -> np.ndarray:
        """(N, 2) keypoint pixels at level 0."""
        return self.features.px

    @property
    def level(self) -> np.ndarray:
        """(N,) pyramid level of each keypoint."""
        return self.features.level

    @property
    def angle_deg(self) -> np.ndarray:
        """(N,) keypoint orientation, degrees."""
        return self.features.angle_deg

    @property
    def descriptors(self) -> np.ndarray:
        """(N, 32) uint8 ORB descriptors."""
        return self.features.descriptors

    @property
    def scale_factor(self) -> float:
        """Scale ratio between consecutive pyramid levels."""
        factors = self.features.scale_factors
        return float(factors[1]) if len(factors) > 1 else 1.0

    @property
    def n_levels(self) -> int:
        """Pyramid levels."""
        return len(self.features.scale_factors)

    @property
    def n_keypoints(self) -> int:
        """Number of keypoints N."""
        return int(self.px.shape[0])

    @property
    def T_cam_world(self) -> np.ndarray:
        """The pose as world -> camera transform (4, 4)."""
        return invert_T(self.T_world_cam)

    @property
    def centre_world(self) -> np.ndarray:
        """Camera centre (3,) metres in the world frame."""
        return np.asarray(self.T_world_cam)[:3, 3].copy()

    def n_tracked_points(self) -> int:
        """Keypoints linked to a map point."""
        return int(np.count_nonzero(self.map_point_ids >= 0))


def select_new_point_keypoints(
    depth_m: np.ndarray, has_point: np.ndarray, th_depth_m: float, min_points: int = 100
) -> np.ndarray:
    """Keypoints (int64 indices) that get a new map point when a stereo/RGB-D keyframe is made.

    ORB-SLAM2's ``CreateNewKeyFrame``: keypoints with depth are visited nearest first, counting
    those that already have a point too; every visited keypoint without a point gets one, and the
    visit stops after the first keypoint farther than ``th_depth_m`` once more than ``min_points``
    were counted. So all close keypoints get points, and at least ``min_points`` overall.
    """
    depth_m = np.asarray(depth_m, dtype=float)
    with_depth = np.flatnonzero(depth_m > 0)
    order = with_depth[np.argsort(depth_m[with_depth], kind="stable")]
    far_enough = np.flatnonzero((depth_m[order] > th_depth_m) & (np.arange(len(order)) >= min_points))
    visited = order if len(far_enough) == 0 else order[: far_enough[0] + 1]
    return np.sort(visited[~np.asarray(has_point, dtype=bool)[visited]])


def unproject_keypoints(
    px: np.ndarray, depth_m: np.ndarray, calibration: PinholeCalibration, T_world_cam: np.ndarray
) -> np.ndarray:
    """World points (K, 3) metres of keypoints at pixels ``px`` (K, 2) with depths ``depth_m`` (K,)."""
    px = np.asarray(px, dtype=float).reshape(-1, 2)
    z = np.asarray(depth_m, dtype=float).reshape(-1)
    p_cam = np.column_stack(
        [(px[:, 0] - calibration.cx) * z / calibration.fx, (px[:, 1] - calibration.cy) * z / calibration.fy, z]
    )
    return transform_points(np.asarray(T_world_cam, dtype=float), p_cam)
