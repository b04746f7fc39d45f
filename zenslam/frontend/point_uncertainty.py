"""How well the map knows each point's position: its covariance from the keyframes that observe it.

Each observation of a point (a keyframe's keypoint: pixel (u, v), and u_right where stereo or
RGB-D matched) informs its position by J^T J / sigma^2, with J the derivative of the projection
into that keyframe with respect to the point and sigma^2 the keypoint level's pixel variance
(ORB-SLAM's scale_factor^(2 level)). The covariance is the inverse of the summed information, the
keyframes' poses taken as exact. A point seen from afar by keyframes that stand close together is
known well across their rays and poorly along them (stereo depth error grows with the square of
the distance); seen from elsewhere, that error is sideways and moves the point in the image.

Localisation mode weighs each map point by it (``pose_optimizer.optimize_pose``'s
``point_covariance``): the saved map's points are final, and a frame that sees them from another
side than the keyframes that made them would otherwise take their depth errors as exact
(benchmarks/saved_maps.md).
"""

from __future__ import annotations

import numpy as np

from zenslam.camera import PinholeCalibration
from zenslam.frontend.local_map import LocalMap
from zenslam.geometry import invert_T
from zenslam.pose_optimizer import point_jacobian


def point_covariances(
    local_map: LocalMap, rows: np.ndarray, calibration: PinholeCalibration, max_sigma_m: float
) -> np.ndarray:
    """(K, 3, 3) covariance (m^2, world frame) of the points in ``rows`` (K,) from every observation
    of them by the keyframes the cache holds. ``max_sigma_m`` bounds the standard deviation along
    any direction (a point seen along one ray only, mono, is unbounded along it). A point no held
    keyframe observes gets max_sigma_m^2 along every axis."""
    rows = np.asarray(rows, dtype=np.int64)
    information = np.zeros((len(rows), 3, 3))
    obs_rows, obs_slots, obs_keypoints = local_map.observation_arrays()
    position = np.full(local_map.n_points, -1, dtype=np.int64)
    position[rows] = np.arange(len(rows))
    of_rows = np.flatnonzero(position[obs_rows] >= 0)
    slots, first = np.unique(obs_slots[of_rows], return_inverse=True)
    for k, slot in enumerate(slots.tolist()):
        keyframe = local_map.keyframe(slot)
        if keyframe is None:
            continue
        these = of_rows[first == k]
        keypoints = obs_keypoints[these]
        stereo = keyframe.right_u[keypoints] >= 0
        inv_sigma2 = keyframe.features.inv_level_sigma2[keyframe.features.level[keypoints]]
        view = view_information(invert_T(keyframe.T_world_cam), local_map.p_world[obs_rows[these]], inv_sigma2, stereo, calibration)
        np.add.at(information, position[obs_rows[these]], view)
    return np.linalg.inv(information + np.eye(3) / max_sigma_m**2)


def view_information(
    T_cam_world: np.ndarray, p_world: np.ndarray, inv_sigma2: np.ndarray, stereo: np.ndarray, calibration: PinholeCalibration
) -> np.ndarray:
    """(K, 3, 3) information (1/m^2, world frame) of the points ``p_world`` (K, 3) from one view of
    each by the camera at ``T_cam_world``: pixel (u, v), and u_right where ``stereo`` (K,), with the
    keypoints' levels' ``inv_sigma2`` (K,)."""
    bf = calibration.bf if calibration.baseline_m is not None else 0.0
    J = point_jacobian(T_cam_world, p_world, calibration.fx, calibration.fy, bf)
    J[:, 2, :] *= np.asarray(stereo, dtype=bool)[:, None]  # a mono observation has no u_right
    return (J.transpose(0, 2, 1) @ J) * np.asarray(inv_sigma2, dtype=float)[:, None, None]
