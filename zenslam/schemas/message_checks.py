"""What a decoded keyframe, map update or sensor frame must hold before a stage acts on it.

The decoders check sizes (every array field against its count); these check values, so that a
message whose bytes were damaged on the way, or sent by a faulty program, is refused whole with a
``MessageError`` naming the field, instead of failing deep inside tracking or mapping after it has
changed half the map. They are the checks that need no state: a stage adds its own (a keyframe id
already mapped, a camera other than the run's).
"""

from __future__ import annotations

import numpy as np

from zenslam.errors import MessageError

# Pyramids deeper than this are not ORB pyramids (ORB-SLAM uses 8 levels, 12 at most in practice).
MAX_PYRAMID_LEVELS = 32


def check_pose(T: np.ndarray, where: str) -> None:
    """A finite rigid transform (the decoders normalise quaternions, so only NaN can get in)."""
    if not np.all(np.isfinite(T)):
        raise MessageError(f"{where}: the pose is not finite (a zero or non-finite quaternion, or a non-finite translation)")


def _check_finite(values: np.ndarray, where: str, name: str) -> None:
    if not np.all(np.isfinite(values)):
        raise MessageError(f"{where}: {name} holds non-finite values")


def _check_ids(ids: np.ndarray, where: str, name: str, lowest: int) -> None:
    if len(ids) and int(ids.min()) < lowest:
        raise MessageError(f"{where}: {name} holds {int(ids.min())}; ids are >= {lowest}")


def _check_unique(ids: np.ndarray, where: str, name: str) -> None:
    if len(np.unique(ids)) != len(ids):
        raise MessageError(f"{where}: {name} repeats an id")


def check_keyframe_values(
    keyframe_id: int,
    T_world_cam: np.ndarray,
    width: int,
    height: int,
    keypoints_px: np.ndarray,
    levels: np.ndarray,
    angles_deg: np.ndarray,
    right_u: np.ndarray,
    depth_m: np.ndarray,
    map_point_ids: np.ndarray,
    scale_factors: np.ndarray,
    new_point_ids: np.ndarray,
    new_points_world: np.ndarray,
) -> None:
    """The values of a frontend/keyframe message (see the module docstring)."""
    where = f"keyframe {keyframe_id}"
    if keyframe_id < 0:
        raise MessageError(f"{where}: keyframe ids are >= 0")
    check_pose(T_world_cam, where)
    n_levels = len(scale_factors)
    if not 1 <= n_levels <= MAX_PYRAMID_LEVELS:
        raise MessageError(f"{where}: {n_levels} pyramid levels; a pyramid has 1 to {MAX_PYRAMID_LEVELS}")
    if not (np.all(np.isfinite(scale_factors)) and scale_factors[0] == 1.0 and np.all(np.diff(scale_factors) > 0)):
        raise MessageError(f"{where}: scale_factors must start at 1 and increase, got {scale_factors.tolist()}")
    if len(levels) and (int(levels.min()) < 0 or int(levels.max()) >= n_levels):
        raise MessageError(f"{where}: keypoint levels span {int(levels.min())}..{int(levels.max())}, the pyramid 0..{n_levels - 1}")
    _check_finite(keypoints_px, where, "keypoints_px")
    if len(keypoints_px) and (
        keypoints_px.min() < -1.0 or keypoints_px[:, 0].max() > width or keypoints_px[:, 1].max() > height
    ):
        raise MessageError(f"{where}: keypoints lie outside the {width}x{height} image")
    for name, values in (("angles_deg", angles_deg), ("right_u", right_u), ("depth_m", depth_m)):
        _check_finite(values, where, name)
    if np.any((depth_m < 0) & (depth_m != -1)):
        raise MessageError(f"{where}: depth_m holds negative depths other than -1 (none)")
    _check_ids(map_point_ids, where, "map_point_ids", -1)
    _check_ids(new_point_ids, where, "new_point_ids", 0)
    _check_unique(new_point_ids, where, "new_point_ids")
    _check_finite(new_points_world, where, "new_points_world")


def check_map_update_values(
    keyframe_id: int,
    keyframe_poses: list[tuple[int, np.ndarray, np.ndarray]],
    point_ids: np.ndarray,
    p_world: np.ndarray,
    normals: np.ndarray,
    min_distance_m: np.ndarray,
    max_distance_m: np.ndarray,
    removed_point_ids: np.ndarray,
    removed_keyframe_ids: np.ndarray,
) -> None:
    """The values of a backend/map_update message; ``keyframe_poses``: (id, T_world_cam, map_point_ids)."""
    where = f"map update of keyframe {keyframe_id}"
    for kf_id, T, ids in keyframe_poses:
        if kf_id < 0:
            raise MessageError(f"{where}: keyframe ids are >= 0, got {kf_id}")
        check_pose(T, f"{where}, keyframe {kf_id}")
        _check_ids(ids, f"{where}, keyframe {kf_id}", "map_point_ids", -1)
    _check_unique(np.array([kf_id for kf_id, _, _ in keyframe_poses], dtype=np.int64), where, "its keyframes")
    _check_ids(point_ids, where, "point_ids", 0)
    _check_unique(point_ids, where, "point_ids")
    for name, values in (("p_world", p_world), ("normals", normals), ("min_distance_m", min_distance_m), ("max_distance_m", max_distance_m)):
        _check_finite(values, where, name)
    if np.any(min_distance_m < 0) or np.any(max_distance_m < min_distance_m):
        raise MessageError(f"{where}: a point's distance range is negative or reversed")
    _check_ids(removed_point_ids, where, "removed_point_ids", 0)
    _check_ids(removed_keyframe_ids, where, "removed_keyframe_ids", 0)


def check_frame_values(
    index: int, stamp_ns: int, image_shape: tuple[int, int], width: int, height: int, sensor: str, has_right: bool, has_depth: bool
) -> None:
    """The values of a sensor/frame message: a frame number and stamp, the images its sensor needs,
    of the calibration's size."""
    where = f"sensor frame {index}"
    if index < 0 or stamp_ns < 0:
        raise MessageError(f"{where}: the frame index and stamp must be >= 0 (stamp {stamp_ns} ns)")
    if (sensor == "stereo" and not has_right) or (sensor == "rgbd" and not has_depth):
        raise MessageError(f"{where}: a {sensor} frame without its {'right image' if sensor == 'stereo' else 'depth'}")
    if image_shape != (height, width):
        raise MessageError(f"{where}: {image_shape[1]}x{image_shape[0]} images with a {width}x{height} calibration")
