"""A keyframe: a tracked frame kept in the map, with its keypoints, depths, pose and point links."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zenslam.geometry import invert_T


@dataclass(frozen=True, eq=False)
class KeyFrame:
    """A frame promoted to keyframe by the tracker; immutable once made.

    Arrays are per keypoint (N of them) in the frame's order: ``px`` level-0 pixels (u right,
    v down), ``level`` pyramid level, ``angle_deg`` orientation, ``descriptors`` (N, 32) uint8,
    ``right_u`` the right-image (or virtual RGB-D) u coordinate and ``depth_m`` metres (-1 where
    none), ``map_point_ids`` the map point each keypoint observes (-1 none). ``new_point_ids`` are
    the points created at this keyframe, at keypoints ``new_point_keypoints``, with positions
    ``new_points_world`` (P, 3) metres in the world frame. ``T_world_cam`` maps camera coordinates
    (x right, y down, z forward) to world.
    """

    id: int
    frame_index: int
    stamp_ns: int
    T_world_cam: np.ndarray  # (4, 4)
    px: np.ndarray  # (N, 2) float32 pixels
    level: np.ndarray  # (N,) int16
    angle_deg: np.ndarray  # (N,) float32 degrees
    response: np.ndarray  # (N,) float32
    descriptors: np.ndarray  # (N, 32) uint8
    right_u: np.ndarray  # (N,) float32 pixels, -1 none
    depth_m: np.ndarray  # (N,) float32 metres, -1 none
    map_point_ids: np.ndarray  # (N,) int64, -1 none
    new_point_ids: np.ndarray  # (P,) int64
    new_point_keypoints: np.ndarray  # (P,) int64 keypoint index of each new point
    new_points_world: np.ndarray  # (P, 3) float64 metres, world frame
    scale_factor: float = 1.2  # ratio between pyramid levels
    n_levels: int = 8  # pyramid levels

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
